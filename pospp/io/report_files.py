"""Run folders on disk: read a run's tables back, write its report page atomically."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from pospp.io.files import atomic_path
from pospp.io.parquet_tables import TABLES, read_table

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

__all__ = ["read_run_tables", "write_figure", "write_text"]


def read_run_tables(run_dir: str | Path) -> dict[str, pd.DataFrame]:
    """Every documented table present in ``run_dir`` (``NAME.parquet``), by name."""
    folder = Path(run_dir)
    if not folder.is_dir():
        raise FileNotFoundError(f"run folder not found: {folder}")
    return {name: read_table(folder / f"{name}.parquet") for name in TABLES
            if (folder / f"{name}.parquet").is_file()}


def write_text(path: str | Path, text: str) -> Path:
    """Write a text file (UTF-8) atomically: a temporary name, then a rename."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return Path(path)


def write_figure(path: str | Path, figure: Figure, *, dpi: int = 100) -> Path:
    """Save a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png", dpi=dpi)
    plt.close(figure)
    return Path(path)
