"""pospp: POS post-processing with double-strapdown online calibration (Liu & Fang 2012).

Conventions (the full sheet is docs/method.md)
----------------------------------------------
Frames: i inertial, e ECEF, n local NED, b body FRD, s sensor as logged (FLU for ROS),
a GNSS antenna. Vectors carry their frame (``v_n``, ``lever_b``); DCMs are destination-first
(``C_nb``: ``v_n = C_nb @ v_b``); quaternions are scalar-first ``[w, x, y, z]``.
Units: SI and radians in the numeric core; degrees, deg/h, ug and arcsec only at the edges,
always named in the suffix (``_deg``, ``_dph``, ``_ug``). Time: int64 ``time_ns`` in files,
float64 ``t_s`` from a per-run epoch in numeric code.
Errors are computed minus true: ``dv_n = v_hat - v``; the misalignment phi (NED) satisfies
``C_nb_hat = (I - [phi x]) C_nb``; sensors read ``true + bias``.

Public API (docs/api.md), loaded on first use (``import pospp`` imports neither numpy nor
pandas): processing, ``pospp.process_flight(mcap, pospp.load_config(toml), out_dir)`` ->
``RunOutcome`` with ``PipelineConfig``; reading, ``pospp.open_run(path)`` -> ``Run``,
``pospp.open_archive(root)`` -> ``Archive``, ``pospp.diff_paths(a, b)`` and the rest of
``pospp.api.__all__``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # for type checkers and editors only: nothing is imported at run time
    from pospp.api import (
        Archive,
        DiffResult,
        Run,
        SchemaError,
        Summary,
        TableNotInRun,
        Tolerances,
        diff_paths,
        diff_runs,
        load_tolerances,
        open_archive,
        open_run,
    )
    from pospp.config import PipelineConfig, load_config
    from pospp.pipeline import RunOutcome, process_flight

__version__ = "0.1.0"

_HOME = {
    **dict.fromkeys(["Archive", "DiffResult", "Run", "SchemaError", "Summary", "TableNotInRun",
                     "Tolerances", "diff_paths", "diff_runs", "load_tolerances", "open_archive",
                     "open_run"], "pospp.api"),
    "PipelineConfig": "pospp.config", "load_config": "pospp.config",
    "RunOutcome": "pospp.pipeline", "process_flight": "pospp.pipeline",
}
"""Each public name and the module that defines it, imported on first access (PEP 562)."""

__all__ = ["Archive", "DiffResult", "PipelineConfig", "Run", "RunOutcome", "SchemaError",
           "Summary", "TableNotInRun", "Tolerances", "__version__", "diff_paths", "diff_runs",
           "load_config", "load_tolerances", "open_archive", "open_run", "process_flight"]


def __getattr__(name: str) -> Any:
    if name in _HOME:
        value = getattr(importlib.import_module(_HOME[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pospp' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOME))
