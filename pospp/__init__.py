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

Public API (docs/api.md): ``pospp.open_run(path)`` -> ``Run``, ``pospp.open_archive(root)`` ->
``Archive``, ``pospp.diff_paths(a, b)`` and the rest of ``pospp.api.__all__``, loaded on first
use (``import pospp`` imports neither numpy nor pandas).
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

__version__ = "0.1.0"

__all__ = ["Archive", "DiffResult", "Run", "SchemaError", "Summary", "TableNotInRun",
           "Tolerances", "__version__", "diff_paths", "diff_runs", "load_tolerances",
           "open_archive", "open_run"]

_API = frozenset(__all__) - {"__version__"}
"""Names of ``pospp.api`` re-exported here, imported on first access (PEP 562)."""


def __getattr__(name: str) -> Any:
    if name in _API:
        value = getattr(importlib.import_module("pospp.api"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pospp' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
