"""A batch's manifest rows: each flight's result and what this batch did, and its folder name.

``status`` is the result of the run that made the flight's folder, in the words of
``pospp run`` (``ok``, ``degraded``, ``partial``, ``failed``; null while a new flight is
queued); ``action`` is what this batch did: ``ran``, ``skipped`` (the folder already held a
finished run of this input and configuration), ``resumed`` (an earlier batch queued it and was
stopped before it finished) or ``queued`` (not reached yet: the state a killed batch leaves).
``error`` is one line, without the exception's class path.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import pandas as pd

from pospp.config import PipelineConfig
from pospp.io import parquet_tables, run_folder
from pospp.io.manifest import MANIFEST, is_run_name, read_manifest, run_markers

MAX_RUN_NAME_LEN = 160
"""Longest run-folder name (longer ones keep their start and end in a path hash)."""
ACTIONS = ("ran", "skipped", "resumed", "queued")
"""What a batch did with a flight."""
_OLD_STATUS = {"done": "ok", "skipped": None}
"""Status words of manifests written before the result and the action were told apart."""


@dataclass(frozen=True)
class FlightOutcome:
    """One manifest row."""

    file: str
    sha256: str
    status: str | None
    """The result of the run in the flight's folder: "ok", "partial", "degraded" or "failed"
    (None: not known yet)."""
    duration_s: float
    error: str | None
    """One line, without the exception's class path (None when the run did not fail)."""
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
    action: str = "ran"
    """What this batch did: "ran", "skipped", "resumed" or "queued" (:data:`ACTIONS`)."""


HEADLINE_COLUMNS = ("n_legs", "dv_after_mps", "dp_after_m", "qc_failed_checks",
                    "dv_before_mps", "gyro_bias_x_dph", "gyro_bias_x_sigma_dph",
                    "gyro_bias_y_dph", "gyro_bias_y_sigma_dph", "gap_heldout_mps",
                    "not_observable")
"""Summary columns a manifest row repeats."""


def headline_values(summary: pd.Series | dict[str, Any]) -> dict[str, Any]:
    """The manifest's copies of a run's summary columns (None for null or absent ones)."""
    out: dict[str, Any] = {}
    for k in HEADLINE_COLUMNS:
        v = summary.get(k)
        out[k] = None if v is None or (not isinstance(v, str) and pd.isna(v)) else v
    if out["n_legs"] is not None:
        out["n_legs"] = int(out["n_legs"])
    return out


def error_line(exc: BaseException) -> str:
    """An exception as the manifest keeps it: its message on one line (undecodable bytes of
    names escaped), the class name only when the message is empty."""
    text = " ".join(str(exc).split())
    return run_folder.display_text(text[:2000] if text else type(exc).__name__)


def _safe_part(part: str) -> str:
    out = []
    raw = os.fsencode(part)
    for i, byte in enumerate(raw):
        ch = chr(byte)
        keep = byte < 128 and (ch.isalnum() or ch in "-_" or (ch == "." and 0 < i < len(raw) - 1))
        out.append(ch if keep else f"%{byte:02X}")
    return "".join(out) or "%00"


def _digest(path: str) -> str:
    return hashlib.sha256(os.fsencode(os.path.abspath(path))).hexdigest()[:8]


def run_folder_names(paths: list[str]) -> dict[str, str]:
    """A safe, unique run-folder name per input file.

    The name is the path relative to the inputs' common folder, without ``.mcap`` (any case):
    sub-folders joined by ``__``, every character other than letters, digits, ``-``, ``_`` and
    inner dots escaped as ``%XX`` of its bytes (so no ``..``, separator or undecodable byte);
    two files that would still share a name, or a name longer than ``MAX_RUN_NAME_LEN``, get
    the first 8 hex digits of their path's SHA-256 appended.
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
            names[p] = f"{n[:MAX_RUN_NAME_LEN - 9]}-{_digest(p)}"
    counts: dict[str, int] = {}
    for n in names.values():
        counts[n] = counts.get(n, 0) + 1
    for p, n in names.items():
        if counts[n] > 1:
            names[p] = f"{n}-{_digest(p)}"
    return names


def read_rows(root: Path) -> dict[str, FlightOutcome]:
    """The rows of the root's manifest by file; without a manifest, one row per run folder
    from its marker (so that no folder is handed to another input). Folder names that are not
    plain run names (absolute, ``..``) are dropped: never trusted.

    Raises
    ------
    pospp.io.manifest.ManifestError
        A manifest another tool wrote, or a damaged one.
    """
    table = read_manifest(root)
    if table is None:
        return {run_folder.display_path(m.get("input_file", "?")): FlightOutcome(
            run_folder.display_path(m.get("input_file", "?")), str(m.get("input_sha256", "")),
            m.get("status"), 0.0, None, run_dir=name, action="skipped")
            for name, m in run_markers(root).items()}
    names = [f.name for f in fields(FlightOutcome)]
    rows = {}
    for rec in table.to_dict("records"):
        kw: dict[str, Any] = {k: (None if pd.isna(rec.get(k)) else rec.get(k))
                              if k in rec else None for k in names}
        if kw["n_legs"] is not None:
            kw["n_legs"] = int(kw["n_legs"])
        kw["status"] = _OLD_STATUS.get(kw["status"], kw["status"])
        kw["action"] = kw["action"] if kw["action"] in ACTIONS else "ran"
        kw["duration_s"] = float(kw["duration_s"] or 0.0)
        if not is_run_name(kw["run_dir"]):
            kw["run_dir"] = None
        rows[str(kw["file"])] = FlightOutcome(**kw)
    return rows


def assign_names(paths: list[str], known: dict[str, FlightOutcome], root: Path
                 ) -> dict[str, str]:
    """Each input's run folder: the one the manifest gives it, else a new name that neither
    the manifest nor a run folder's marker gives to another input."""
    names = run_folder_names(paths)
    markers = run_markers(root)
    owner = {r.run_dir: f for f, r in known.items() if r.run_dir}
    for name, m in markers.items():
        owner.setdefault(name, run_folder.display_path(m.get("input_file", "?")))
    for p in paths:
        shown = run_folder.display_path(p)
        old = known.get(shown)
        if old is not None and old.run_dir and owner.get(old.run_dir) == shown:
            names[p] = old.run_dir
            continue
        name = names[p]
        if owner.get(name, shown) != shown:
            name = f"{name}-{_digest(p)}"
        if owner.get(name, shown) != shown:
            raise run_folder.RunFolderError(
                f"{run_folder.display_path(root / name)}: holds a run of "
                f"{owner[name]}, not of {shown}; pospp will not replace it")
        names[p] = name
        owner[name] = shown
    return names


def queued(known: dict[str, FlightOutcome], paths: list[str], names: dict[str, str]
           ) -> dict[str, FlightOutcome]:
    """The manifest's rows with this batch's flights marked ``queued`` (their last result
    kept), written before any flight runs: a batch killed later leaves each flight's result
    and which ones it had not reached."""
    rows = dict(known)
    for p in paths:
        shown = run_folder.display_path(p)
        old = rows.get(shown)
        rows[shown] = (replace(old, action="queued", run_dir=names[p]) if old is not None else
                       FlightOutcome(shown, "", None, 0.0, None, run_dir=names[p],
                                     action="queued"))
    return rows


def write_rows(root: Path, rows: list[FlightOutcome], config: PipelineConfig) -> None:
    """Write ``ROOT/manifest.parquet`` atomically (schema ``manifest``)."""
    df = pd.DataFrame([vars(r) for r in rows], columns=[f.name for f in fields(FlightOutcome)])
    df["n_legs"] = df["n_legs"].astype("Int64")
    parquet_tables.write_table(root / MANIFEST, df, "manifest",
                               metadata={"config": config.to_dict()})
