"""A batch root, for analysts and CI: ``pospp.open_archive(root)`` -> :class:`Archive`.

The root's ``manifest.parquet`` (written by ``pospp batch``; pospp's only when marked so,
:mod:`pospp.io.manifest`) lists each flight: its input, result status (``ok``, ``degraded``,
``partial``, ``failed``), what the last batch did and its run folder. A folder name is used only
when it is one plain path component (never an absolute or ``..`` path read from the file).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pandas as pd

from pospp.api.run import Run, open_run
from pospp.io import run_folder
from pospp.io.manifest import MANIFEST, is_run_name, read_manifest

__all__ = ["Archive", "open_archive"]


class Archive:
    """A batch root: its manifest and the run folder of each flight. Open with
    :func:`open_archive`."""

    def __init__(self, root: Path, manifest: pd.DataFrame) -> None:
        self.root = root
        """The batch root folder."""
        self.manifest = manifest
        """One row per flight (table ``manifest`` of docs/formats.md); ``run_dir`` is null
        where the manifest named no plain folder."""

    def __repr__(self) -> str:
        counts = self.manifest.status.fillna("queued").value_counts()
        text = ", ".join(f"{n} {s}" for s, n in counts.items())
        return f"<pospp Archive {run_folder.display_path(self.root)}: {text or 'empty'}>"

    def __len__(self) -> int:
        return len(self.manifest)

    @property
    def flights(self) -> list[str]:
        """Run folder names of the flights that have one, in manifest order."""
        return [str(n) for n in self.manifest.run_dir.dropna()]

    def run(self, flight: str) -> Run:
        """The run of one flight, by run folder name or by input file (as in the manifest).

        Raises
        ------
        KeyError
            No such flight in the manifest.
        pospp.io.run_folder.RunFolderError
            Its folder holds no pospp run (never written, or removed).
        """
        m = self.manifest
        hit = m[(m.run_dir == flight) | (m.file == flight)]
        if hit.empty or pd.isna(hit.run_dir.iloc[0]):
            raise KeyError(f"{run_folder.display_path(self.root)}: no flight {flight!r} in "
                           f"{MANIFEST}")
        return open_run(self.root / str(hit.run_dir.iloc[0]))

    def runs(self) -> Iterator[tuple[str, Run]]:
        """(folder name, run) of every flight whose folder holds a run."""
        for name in self.flights:
            if run_folder.read_marker(self.root / name) is not None:
                yield name, open_run(self.root / name)

    def summaries(self) -> pd.DataFrame:
        """One summary row per flight with a run, indexed by folder name (columns by name:
        flights from different pospp versions may differ in their extra columns)."""
        rows = {name: run.table("summary").iloc[0] for name, run in self.runs()}
        return pd.DataFrame.from_dict(rows, orient="index")


def open_archive(root: str | Path) -> Archive:
    """Open a batch root by its manifest.

    Raises
    ------
    FileNotFoundError
        No such folder, or no manifest in it.
    pospp.io.manifest.ManifestError
        A manifest another tool wrote, or a damaged one.
    """
    folder = Path(root)
    if not folder.is_dir():
        raise FileNotFoundError(f"batch root not found: {run_folder.display_path(folder)}")
    table = read_manifest(folder)
    if table is None:
        raise FileNotFoundError(f"{run_folder.display_path(folder)}: no {MANIFEST}; give a "
                                "root written by pospp batch (or a run folder to open_run)")
    table = table.copy()
    table["run_dir"] = [n if is_run_name(n) else None for n in table.run_dir]
    return Archive(folder, table)
