"""Re-processing archives of flights: one run folder per flight, a manifest, idempotent.

Every flight is independent, so the archive is embarrassingly parallel: a local process pool
by default (``concurrent.futures.ProcessPoolExecutor``, workers die with the batch: Linux
``PR_SET_PDEATHSIG`` plus a watchdog thread), or Dask distributed when a scheduler address is
given (an existing engine, not a home-made one; extra ``pospp[dask]``).

Run folders: ``OUT_ROOT/<name>``, the name derived from the file's path relative to the
archive (the common folder of the inputs): sub-folders joined by ``__``, every character other
than letters, digits, ``-``, ``_`` and inner dots escaped as ``%XX`` of its bytes (so no
``..``, no separator, no undecodable byte); a flight already in the manifest keeps its folder.

Idempotence: a flight whose run folder's marker and summary match the input's SHA-256 and the
configuration's hash, with a status other than failed, is skipped. Every flight's outcome
(done, partial, failed with its error text, skipped) is recorded in ``manifest.parquet`` at
the root, rewritten atomically after every flight; rows of flights outside this batch are
kept. A lock (``OUT_ROOT/.pospp-batch.lock``) stops a second batch from working on the root.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import pandas as pd

from pospp.config import PipelineConfig, config_from_dict
from pospp.io import parquet_tables, run_folder
from pospp.io.files import sha256_file
from pospp.threads import available_cores

MAX_RUN_NAME_LEN = 160
"""Longest run-folder name (longer ones keep their start and end in a path hash)."""
SCHEDULER_TIMEOUT_S = 10.0
"""How long ``run_batch`` waits for a Dask scheduler before giving up [s]."""


class BatchError(RuntimeError):
    """A batch-level problem (scheduler unreachable, manifest not writable): one clear line."""


@dataclass(frozen=True)
class FlightOutcome:
    """One manifest row."""

    file: str
    sha256: str
    status: str
    """"done" (run status ok), "partial", "degraded", "failed" (run status or an error) or
    "skipped" (done before; ``qc_failed_checks`` then kept from its summary)."""
    duration_s: float
    error: str | None
    n_legs: int | None = None
    dv_after_mps: float | None = None
    dp_after_m: float | None = None
    run_dir: str | None = None
    """Run folder name under the batch root."""
    qc_failed_checks: str | None = None
    dv_before_mps: float | None = None
    gyro_bias_x_dph: float | None = None
    gyro_bias_x_sigma_dph: float | None = None
    gyro_bias_y_dph: float | None = None
    gyro_bias_y_sigma_dph: float | None = None
    gap_heldout_mps: float | None = None
    not_observable: str | None = None
    """The answer first: QC verdict, calibrated bias, held-out gap (summary columns)."""


_HEADLINE_COLUMNS = ("qc_failed_checks", "dv_before_mps", "gyro_bias_x_dph",
                     "gyro_bias_x_sigma_dph", "gyro_bias_y_dph", "gyro_bias_y_sigma_dph",
                     "gap_heldout_mps", "not_observable")


def _safe_part(part: str) -> str:
    out = []
    raw = os.fsencode(part)
    for i, byte in enumerate(raw):
        ch = chr(byte)
        keep = byte < 128 and (ch.isalnum() or ch in "-_" or (ch == "." and 0 < i < len(raw) - 1))
        out.append(ch if keep else f"%{byte:02X}")
    return "".join(out) or "%00"


def run_folder_names(paths: list[str]) -> dict[str, str]:
    """A safe, unique run-folder name per input file (see the module docstring).

    The name is the path relative to the inputs' common folder, without ``.mcap``; two files
    that would still share a name, or a name longer than ``MAX_RUN_NAME_LEN``, get the first 8
    hex digits of their path's SHA-256 appended.
    """
    if not paths:
        return {}
    absolute = [os.path.abspath(p) for p in paths]
    common = os.path.commonpath([os.path.dirname(p) for p in absolute])
    names = {}
    for p, ap in zip(paths, absolute, strict=True):
        rel = os.path.relpath(ap, common)
        if rel.lower().endswith(".mcap") and len(os.path.basename(rel)) > len(".mcap"):
            rel = rel[: -len(".mcap")]
        names[p] = "__".join(_safe_part(x) for x in rel.split(os.sep))
    for p, n in names.items():  # file systems allow 255 bytes; the staging name adds ~40
        if len(n) > MAX_RUN_NAME_LEN:
            digest = hashlib.sha256(os.fsencode(os.path.abspath(p))).hexdigest()[:8]
            names[p] = f"{n[:MAX_RUN_NAME_LEN - 9]}-{digest}"
    counts: dict[str, int] = {}
    for n in names.values():
        counts[n] = counts.get(n, 0) + 1
    for p, n in names.items():
        if counts[n] > 1:
            digest = hashlib.sha256(os.fsencode(os.path.abspath(p))).hexdigest()[:8]
            names[p] = f"{n}-{digest}"
    return names


def already_done(run_dir: Path, config: PipelineConfig, sha256: str) -> bool:
    """True when ``run_dir`` holds a finished run of this input and this configuration.

    Both the marker and the summary must match the input's SHA-256 and the configuration's
    hash, and the run must not have failed.
    """
    marker = run_folder.read_marker(run_dir)
    summary = run_dir / "summary.parquet"
    if marker is None or not summary.is_file():
        return False
    cfg_json = config.to_json()
    if marker.get("input_sha256") != sha256 or marker.get("status") == "failed" or \
            marker.get("config_sha256") != run_folder.config_sha256(cfg_json):
        return False
    try:
        meta = parquet_tables.read_metadata(summary)
        status = parquet_tables.read_table(summary).get("status")
    except Exception:  # noqa: BLE001 - an unreadable summary is simply not done
        return False
    if meta.get("input_sha256") != sha256:
        return False
    if json.dumps(meta.get("config"), sort_keys=True) != cfg_json:  # tuples -> lists
        return False
    return status is not None and str(status.iloc[0]) not in ("failed",)


def process_one(mcap_path: str, config_dict: dict[str, Any], out_root: str,
                force: bool = False, run_name: str | None = None,
                flights_at_once: int | None = None, threads: int | None = None
                ) -> FlightOutcome:
    """Run the pipeline on one flight; never raises (the error goes in the outcome).

    Takes plain arguments so it pickles for a process pool or a Dask worker.
    ``flights_at_once``: flights this machine runs at once; the flight makes its A re-runs on
    its share of the cores (``pipeline.process_flight``'s ``threads``); None: one at a time
    (a Dask worker's own threads share its cores). ``threads``: that number instead.
    """
    from pospp import pipeline  # local: keeps worker start-up light and avoids a cycle

    path = Path(mcap_path)
    shown = run_folder.display_path(path)
    name = run_name or run_folder_names([mcap_path])[mcap_path]
    config = config_from_dict(config_dict, source="batch")
    t0 = time.perf_counter()
    sha = ""
    try:
        sha = sha256_file(path)
        run_dir = Path(out_root) / name
        if not force and already_done(run_dir, config, sha):
            done = parquet_tables.read_table(run_dir / "summary.parquet").iloc[0]
            kept: dict[str, Any] = {
                k: (None if pd.isna(done.get(k)) else done.get(k))
                for k in ("n_legs", "dv_after_mps", "dp_after_m", *_HEADLINE_COLUMNS)
                if k in done}
            if kept.get("n_legs") is not None:
                kept["n_legs"] = int(kept["n_legs"])
            return FlightOutcome(shown, sha, "skipped", time.perf_counter() - t0, None,
                                 run_dir=name, **kept)
        # the batch owns its root: an earlier run of this flight is replaced (never a folder
        # holding files pospp did not write)
        if threads is None:
            threads = (1 if flights_at_once is None
                       else max(1, available_cores() // flights_at_once))
        outcome = pipeline.process_flight(path, config, run_dir, force=True, threads=threads)
        s = outcome.summary
        return FlightOutcome(
            shown, sha, "done" if outcome.status == "ok" else outcome.status,
            time.perf_counter() - t0, None, s.get("n_legs"), s.get("dv_after_mps"),
            s.get("dp_after_m"), name,
            **{k: s.get(k) for k in _HEADLINE_COLUMNS},
        )
    except Exception as exc:  # noqa: BLE001 - a batch records every failure and goes on
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return FlightOutcome(shown, sha, "failed", time.perf_counter() - t0,
                             run_folder.display_path(last), run_dir=name)


def _die_with_parent(parent_pid: int) -> None:
    """Process-pool initializer: end this worker when the batch process dies (even kill -9)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:  # other platforms, and a second line of defence
        while True:
            time.sleep(1.0)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="pospp-parent-watch", daemon=True).start()


def _read_manifest(out_root: Path) -> dict[str, FlightOutcome]:
    """Rows of an earlier manifest at ``out_root`` by file (empty when absent/unreadable)."""
    path = out_root / "manifest.parquet"
    if not path.is_file():
        return {}
    try:
        df = parquet_tables.read_table(path)
    except Exception:  # noqa: BLE001 - a damaged manifest is rebuilt from this batch
        return {}
    names = [f.name for f in fields(FlightOutcome)]
    rows = {}
    for rec in df.to_dict("records"):
        kw: dict[str, Any] = {k: (None if pd.isna(rec.get(k)) else rec.get(k))
                              if k in rec else None for k in names}
        if kw["n_legs"] is not None:
            kw["n_legs"] = int(kw["n_legs"])
        rows[str(kw["file"])] = FlightOutcome(**kw)
    return rows


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
    known = _read_manifest(root)
    names = run_folder_names(paths)
    taken = {r.run_dir: f for f, r in known.items() if r.run_dir}
    for p in paths:  # a flight already in the manifest keeps its folder
        old = known.get(run_folder.display_path(p))
        if old is not None and old.run_dir:
            names[p] = old.run_dir
        elif taken.get(names[p], run_folder.display_path(p)) != run_folder.display_path(p):
            digest = hashlib.sha256(os.fsencode(p)).hexdigest()[:8]
            names[p] = f"{names[p]}-{digest}"
    rows: list[FlightOutcome] = []
    manifest_error: list[str] = []

    def record(outcome: FlightOutcome) -> None:
        rows.append(outcome)
        known[outcome.file] = outcome
        try:
            _write_manifest(root, sorted(known.values(), key=lambda r: r.file), config)
            manifest_error.clear()
        except OSError as exc:
            manifest_error[:] = [f"{exc.strerror or exc}"]
        if on_result is not None:
            on_result(outcome)

    if scheduler is not None:
        try:
            from dask.distributed import Client
            from dask.distributed import as_completed as dask_completed
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise BatchError("a Dask scheduler was given but dask.distributed is not "
                             "installed: pip install 'pospp[dask]'") from exc
        try:
            client = Client(scheduler, timeout=scheduler_timeout_s)
        except (OSError, TimeoutError, ValueError) as exc:
            raise BatchError(f"cannot reach the Dask scheduler {scheduler} within "
                             f"{scheduler_timeout_s:g} s ({type(exc).__name__})") from None
        with client:
            dask_futures = [client.submit(process_one, p, cfg, str(root), force, names[p],
                                          None, threads, pure=False) for p in paths]
            for dask_fut in dask_completed(dask_futures):
                record(dask_fut.result())
    elif workers <= 1:
        for p in paths:
            record(process_one(p, cfg, str(root), force, names[p], 1, threads))
    else:
        with ProcessPoolExecutor(max_workers=workers, initializer=_die_with_parent,
                                 initargs=(os.getpid(),)) as pool:
            futures = [pool.submit(process_one, p, cfg, str(root), force, names[p], workers,
                                   threads)
                       for p in paths]
            for fut in as_completed(futures):
                record(fut.result())
    if manifest_error:
        raise BatchError(f"could not write {run_folder.display_path(root / 'manifest.parquet')}:"
                         f" {manifest_error[0]}; each flight's outcome is in its run folder's "
                         "summary.parquet")
    return sorted(rows, key=lambda r: r.file)
