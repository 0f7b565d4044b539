"""Re-processing archives of flights: one run folder per flight, a manifest, idempotent.

Every flight is independent, so the archive is embarrassingly parallel: a local process pool
by default (``concurrent.futures.ProcessPoolExecutor``), or Dask distributed when a scheduler
address is given (an existing engine, not a home-made one; extra ``pospp[dask]``).

Idempotence: a flight whose run folder already holds a ``summary.parquet`` written from the
same input hash and the same configuration is skipped. Every flight's outcome (done, failed
with its error text, skipped) is recorded in ``manifest.parquet`` at the archive output root,
rewritten atomically after every flight, so an interrupted batch loses nothing and a re-run
picks up where it stopped.
"""

from __future__ import annotations

import json
import time
import traceback
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from pospp.config import PipelineConfig, config_from_dict
from pospp.io import parquet_tables


@dataclass(frozen=True)
class FlightOutcome:
    """One manifest row."""

    file: str
    sha256: str
    status: str
    """"done", "partial", "failed" or "skipped"."""
    duration_s: float
    error: str | None
    n_legs: int | None = None
    dv_after_mps: float | None = None
    dp_after_m: float | None = None


def run_folder_for(mcap_path: Path, out_root: Path) -> Path:
    """The run folder of one flight: OUT_ROOT/<file stem>."""
    return out_root / mcap_path.stem


def already_done(mcap_path: Path, run_dir: Path, config: PipelineConfig, sha256: str) -> bool:
    """True when ``run_dir`` holds a finished run of this input and this configuration."""
    summary = run_dir / "summary.parquet"
    if not summary.is_file():
        return False
    meta = parquet_tables.read_metadata(summary)
    if meta.get("input_sha256") != sha256:
        return False
    if json.dumps(meta.get("config"), sort_keys=True) != config.to_json():  # tuples -> lists
        return False
    status = parquet_tables.read_table(summary).get("status")
    return status is not None and str(status.iloc[0]) in ("ok", "partial")


def process_one(mcap_path: str, config_dict: dict[str, Any], out_root: str,
                force: bool = False) -> FlightOutcome:
    """Run the pipeline on one flight; never raises (the error goes in the outcome).

    Takes plain arguments so it pickles for a process pool or a Dask worker.
    """
    from pospp import pipeline  # local: keeps worker start-up light and avoids a cycle

    path = Path(mcap_path)
    config = config_from_dict(config_dict, source="batch")
    t0 = time.perf_counter()
    sha = ""
    try:
        sha = parquet_tables.sha256_file(path)
        run_dir = run_folder_for(path, Path(out_root))
        if not force and already_done(path, run_dir, config, sha):
            return FlightOutcome(str(path), sha, "skipped", time.perf_counter() - t0, None)
        outcome = pipeline.run(path, config, run_dir)
        s = outcome.summary
        return FlightOutcome(
            str(path), sha, "done" if outcome.status == "ok" else outcome.status,
            time.perf_counter() - t0, None, s.get("n_legs"), s.get("dv_after_mps"),
            s.get("dp_after_m"),
        )
    except Exception as exc:  # noqa: BLE001 - a batch records every failure and goes on
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return FlightOutcome(str(path), sha, "failed", time.perf_counter() - t0, last)


def _write_manifest(out_root: Path, rows: list[FlightOutcome], config: PipelineConfig) -> None:
    df = pd.DataFrame([vars(r) for r in rows])
    for c in ("n_legs",):
        df[c] = df[c].astype("Int64")
    parquet_tables.write_table(out_root / "manifest.parquet", df, "manifest",
                               metadata={"config": config.to_dict()})


def run_batch(
    files: Iterable[str | Path],
    config: PipelineConfig,
    out_root: str | Path,
    *,
    workers: int = 2,
    scheduler: str | None = None,
    force: bool = False,
    on_result: Callable[[FlightOutcome], None] | None = None,
) -> list[FlightOutcome]:
    """Process many flight logs, one run folder each; returns the manifest rows.

    Parameters
    ----------
    files : iterable of path-like
        MCAP flight logs.
    config : PipelineConfig
        Applied to every flight.
    out_root : path-like
        Root folder; each flight goes to ``out_root/<stem>``, the manifest to
        ``out_root/manifest.parquet``.
    workers : int
        Local processes (ignored with ``scheduler``); 1 runs in this process.
    scheduler : str, optional
        Dask distributed scheduler address (``tcp://host:8786``); requires ``pospp[dask]``.
    force : bool
        Re-run flights that are already done.
    on_result : callable, optional
        Called with each outcome as it arrives (progress display).
    """
    root = Path(out_root)
    root.mkdir(parents=True, exist_ok=True)
    paths = sorted(str(Path(f)) for f in files)
    stems = [Path(p).stem for p in paths]
    dup = sorted({s for s in stems if stems.count(s) > 1})
    if dup:
        raise ValueError(f"input files share run-folder names {dup}: rename them or split the "
                         "batch (each flight's folder is OUT_ROOT/<file stem>)")
    cfg = config.to_dict()
    rows: list[FlightOutcome] = []

    def record(outcome: FlightOutcome) -> None:
        rows.append(outcome)
        _write_manifest(root, sorted(rows, key=lambda r: r.file), config)
        if on_result is not None:
            on_result(outcome)

    if scheduler is not None:
        try:
            from dask.distributed import Client
            from dask.distributed import as_completed as dask_completed
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise RuntimeError("a Dask scheduler was given but dask.distributed is not "
                               "installed: pip install 'pospp[dask]'") from exc
        with Client(scheduler) as client:
            futures = [client.submit(process_one, p, cfg, str(root), force, pure=False)
                       for p in paths]
            for fut in dask_completed(futures):
                record(fut.result())
    elif workers <= 1:
        for p in paths:
            record(process_one(p, cfg, str(root), force))
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(process_one, p, cfg, str(root), force) for p in paths]
            for fut in as_completed(futures):
                record(fut.result())
    return sorted(rows, key=lambda r: r.file)
