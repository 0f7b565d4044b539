"""One flight of a batch, as a worker runs it: skip a finished run, else run the pipeline.

Takes plain arguments and never raises, so it pickles for a process pool or a Dask worker and
a failed flight is one manifest row, not the end of the batch.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from pospp.batch.outcome import FlightOutcome, error_line, headline_values, run_folder_names
from pospp.config import PipelineConfig, config_from_dict
from pospp.io import parquet_tables, run_folder
from pospp.io.files import sha256_file
from pospp.threads import available_cores


def finished_status(run_dir: Path, config: PipelineConfig, sha256: str) -> str | None:
    """The status of the finished run of this input and configuration in ``run_dir`` ("ok",
    "partial" or "degraded"), or None when there is none to keep.

    Both the marker and the summary must match the input's SHA-256 and the configuration's
    hash, and the run must not have failed.
    """
    marker = run_folder.read_marker(run_dir)
    summary = run_dir / "summary.parquet"
    if marker is None or not summary.is_file():
        return None
    cfg_json = config.to_json()
    if marker.get("input_sha256") != sha256 or marker.get("status") == "failed" or \
            marker.get("config_sha256") != run_folder.config_sha256(cfg_json):
        return None
    try:
        meta = parquet_tables.read_metadata(summary)
        status = parquet_tables.read_table(summary).get("status")
    except Exception:  # noqa: BLE001 - an unreadable summary is simply not done
        return None
    if meta.get("input_sha256") != sha256:
        return None
    if json.dumps(meta.get("config"), sort_keys=True) != cfg_json:  # tuples -> lists
        return None
    if status is None or str(status.iloc[0]) in ("failed", "None", "nan"):
        return None
    return str(status.iloc[0])


def already_done(run_dir: Path, config: PipelineConfig, sha256: str) -> bool:
    """True when ``run_dir`` holds a finished run of this input and this configuration
    (:func:`finished_status`)."""
    return finished_status(run_dir, config, sha256) is not None


def process_one(mcap_path: str, config_dict: dict[str, Any], out_root: str,
                force: bool = False, run_name: str | None = None,
                flights_at_once: int | None = None, threads: int | None = None,
                queued: bool = False) -> FlightOutcome:
    """Run the pipeline on one flight; never raises (the error goes in the outcome).

    ``flights_at_once``: flights this machine runs at once; the flight makes its A re-runs on
    its share of the cores (``pipeline.process_flight``'s ``threads``); None: one at a time
    (a Dask worker's own threads share its cores). ``threads``: that number instead.
    ``queued``: an earlier batch queued this flight and stopped before it finished (the
    outcome's action is then "resumed" when it runs).
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
        status = None if force else finished_status(run_dir, config, sha)
        if status is not None:
            done = parquet_tables.read_table(run_dir / "summary.parquet").iloc[0]
            return FlightOutcome(shown, sha, status, time.perf_counter() - t0, None,
                                 run_dir=name, action="skipped", **headline_values(done))
        # the batch owns its root: an earlier run of this flight is replaced (never a folder
        # holding files pospp did not write)
        if threads is None:
            threads = (1 if flights_at_once is None
                       else max(1, available_cores() // flights_at_once))
        outcome = pipeline.process_flight(path, config, run_dir, force=True, threads=threads)
        return FlightOutcome(shown, sha, outcome.status, time.perf_counter() - t0, None,
                             run_dir=name, action="resumed" if queued else "ran",
                             **headline_values(outcome.summary))
    except Exception as exc:  # noqa: BLE001 - a batch records every failure and goes on
        return FlightOutcome(shown, sha, "failed", time.perf_counter() - t0, error_line(exc),
                             run_dir=name, action="resumed" if queued else "ran")
