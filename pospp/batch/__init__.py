"""Re-processing archives of flights: one run folder per flight, a manifest, idempotent.

Every flight is independent, so the archive is embarrassingly parallel: local worker
processes by default (:mod:`pospp.batch.workers`: a worker killed fails its flight alone,
named, and the batch goes on), or Dask distributed when a scheduler address is given (an
existing engine, not a home-made one; extra ``pospp[dask]``).

Run folders: ``OUT_ROOT/<name>``, the name derived from the file's path relative to the
archive (:func:`pospp.batch.outcome.run_folder_names`); a flight already in the manifest keeps
its folder, and no folder whose marker names another input is ever given to a new one.

Idempotence: a flight whose run folder's marker and summary match the input's SHA-256 and the
configuration's hash, with a status other than failed, is skipped. ``manifest.parquet`` at the
root (:mod:`pospp.batch.outcome`) keeps each flight's result (``ok``, ``degraded``,
``partial``, ``failed``, the words of ``pospp run``) and what this batch did (``ran``,
``skipped``, ``resumed``, ``queued``); it is written before the first flight (every flight of
the batch ``queued``) and after every flight, atomically, so a batch killed at any moment
leaves each flight's result. Rows of flights outside this batch are kept. A manifest another
tool wrote, or a damaged one, is refused (:mod:`pospp.io.manifest`). A lock
(``OUT_ROOT/.pospp-batch.lock``) stops a second batch from working on the root. With a
``baseline`` root, the batch ends with :func:`pospp.api.diff.diff_paths` against it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pospp.batch.flight import already_done, finished_status, process_one
from pospp.batch.outcome import (
    MAX_RUN_NAME_LEN,
    FlightOutcome,
    assign_names,
    queued,
    read_rows,
    run_folder_names,
    write_rows,
)
from pospp.batch.workers import Task, clean_leftovers, run_dask, run_local
from pospp.config import PipelineConfig
from pospp.io import run_folder

if TYPE_CHECKING:
    from pospp.api.diff import DiffResult, Tolerances

__all__ = ["MAX_RUN_NAME_LEN", "SCHEDULER_TIMEOUT_S", "BatchError", "FlightOutcome",
           "already_done", "baseline_diff", "find_flight_logs", "finished_status", "process_one",
           "run_batch", "run_folder_names"]

SCHEDULER_TIMEOUT_S = 10.0
"""How long ``run_batch`` waits for a Dask scheduler before giving up [s]."""


class BatchError(RuntimeError):
    """A batch-level problem (scheduler unreachable, manifest not writable): one clear line."""


def find_flight_logs(inputs: Iterable[str | Path], out_root: str | Path) -> list[Path]:
    """The MCAP files among ``inputs`` (files, and folders searched recursively for
    ``*.mcap`` in any case), leaving out anything under ``out_root`` (a root inside the archive
    holds pospp's own ``trajectory.mcap`` files: never inputs)."""
    root = Path(os.path.realpath(out_root))
    files: list[Path] = []
    for item in map(Path, inputs):
        found = (sorted(f for f in item.rglob("*") if f.suffix.lower() == ".mcap"
                        and not f.is_dir()) if item.is_dir() else [item])
        files.extend(f for f in found if root not in Path(os.path.realpath(f)).parents)
    return files


def run_batch(
    files: Iterable[str | Path],
    config: PipelineConfig,
    out_root: str | Path,
    *,
    workers: int = 2,
    scheduler: str | None = None,
    scheduler_timeout_s: float = SCHEDULER_TIMEOUT_S,
    force: bool = False,
    on_result: Callable[[FlightOutcome], None] | None = None,
    threads: int | None = None,
) -> list[FlightOutcome]:
    """Process many flight logs, one run folder each; returns this batch's manifest rows.

    Parameters
    ----------
    files : iterable of path-like
        MCAP flight logs.
    config : PipelineConfig
        Applied to every flight.
    out_root : path-like
        Root folder; each flight goes to ``out_root/<name>`` (:func:`run_folder_names`), the
        manifest to ``out_root/manifest.parquet``.
    workers : int
        Local processes (ignored with ``scheduler``); 1 runs in this process.
    scheduler : str, optional
        Dask distributed scheduler address (``tcp://host:8786``); requires ``pospp[dask]``.
    scheduler_timeout_s : float
        How long to wait for the scheduler [s].
    force : bool
        Re-run flights that are already done.
    on_result : callable, optional
        Called with each outcome as it arrives (progress display).
    threads : int, optional
        A re-runs each flight makes at once (``pipeline.process_flight``); default: the
        machine's cores shared out among the ``workers`` (a Dask worker's flight: 1). The
        outputs do not depend on it.

    Raises
    ------
    pospp.io.run_folder.RunFolderError
        Another batch holds the root's lock.
    BatchError
        The scheduler cannot be reached, or the manifest could not be written (the flights'
        own outcomes are in their run folders, and the error names the cause).
    """
    root = Path(out_root)
    run_folder.refuse_symlink_loop(root)
    root.mkdir(parents=True, exist_ok=True)
    paths = sorted({os.path.abspath(os.fspath(f)) for f in files})
    with run_folder.BatchLock(root):
        return _run_locked(paths, config, root, workers=workers, scheduler=scheduler,
                           scheduler_timeout_s=scheduler_timeout_s, force=force,
                           on_result=on_result, threads=threads)


def _run_locked(paths: list[str], config: PipelineConfig, root: Path, *, workers: int,
                scheduler: str | None, scheduler_timeout_s: float, force: bool,
                on_result: Callable[[FlightOutcome], None] | None,
                threads: int | None = None) -> list[FlightOutcome]:
    cfg = config.to_dict()
    known = read_rows(root)
    clean_leftovers(root)  # staging folders of runs killed in an earlier batch
    names = assign_names(paths, known, root)
    was_queued = {p for p in paths
                  if getattr(known.get(run_folder.display_path(p)), "action", "") == "queued"}
    rows: list[FlightOutcome] = []
    manifest_error: list[str] = []
    manifest = queued(known, paths, names)

    def write() -> None:
        try:
            write_rows(root, sorted(manifest.values(), key=lambda r: r.file), config)
            manifest_error.clear()
        except OSError as exc:
            manifest_error[:] = [f"{exc.strerror or exc}"]

    def record(outcome: FlightOutcome) -> None:
        rows.append(outcome)
        manifest[outcome.file] = outcome
        write()
        if on_result is not None:
            on_result(outcome)

    write()
    at_once = 1 if scheduler is None and workers <= 1 else (None if scheduler else workers)
    tasks: list[Task] = [(p, cfg, str(root), force, names[p], at_once, threads,
                          p in was_queued) for p in paths]
    if scheduler is not None:
        with _dask_client(scheduler, scheduler_timeout_s) as client:
            run_dask(tasks, client, record)
    elif workers <= 1:
        for t in tasks:
            record(process_one(*t))
    else:
        run_local(tasks, workers, root, record)
    if manifest_error:
        raise BatchError(f"could not write {run_folder.display_path(root / 'manifest.parquet')}:"
                         f" {manifest_error[0]}; each flight's outcome is in its run folder's "
                         "summary.parquet")
    return sorted(rows, key=lambda r: r.file)


def _dask_client(scheduler: str, timeout_s: float) -> Any:
    try:
        from dask.distributed import Client
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise BatchError("a Dask scheduler was given but dask.distributed is not "
                         "installed: pip install 'pospp[dask]'") from exc
    try:
        return Client(scheduler, timeout=timeout_s)
    except (OSError, TimeoutError, ValueError) as exc:
        raise BatchError(f"cannot reach the Dask scheduler {scheduler} within "
                         f"{timeout_s:g} s ({type(exc).__name__})") from None


def baseline_diff(out_root: str | Path, baseline_root: str | Path,
                  tolerances: Tolerances | None = None) -> DiffResult:
    """Compare a batch root with an earlier one (``pospp batch --baseline``): every flight's
    headline and trajectory against the baseline's (:func:`pospp.api.diff.diff_paths`, the
    baseline as A), written to ``ROOT/diff.parquet`` and ``ROOT/diff.html``."""
    from pospp.api.diff import diff_paths, write_diff

    result = diff_paths(baseline_root, out_root, tolerances)
    write_diff(result, out_root)
    return result
