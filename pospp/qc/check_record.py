"""A run's self-check record (:class:`Check`) and the run status it implies (no I/O).

The checks themselves are in :mod:`pospp.qc.checks` (which re-exports these names);
``severity`` is the run status a failure imposes: "partial" (a stage produced nothing),
"degraded" (the answer is suspect) or "failed" (the answer is wrong); the run status is the
worst severity among the failed checks (:func:`run_status`). Times in ``time_ns_offset`` are
nanoseconds from the run epoch (the first IMU stamp).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pospp.units import NS_PER_S

__all__ = ["STATUS_ORDER", "Check", "comparison_text", "run_status", "skip", "time_offset_ns"]

STATUS_ORDER = ("ok", "partial", "degraded", "failed")
"""Run statuses from best to worst."""

@dataclass(frozen=True)
class Check:
    """One named check and its outcome.

    Attributes
    ----------
    name : str
        Check name (``gravity_direction``, ``gnss_time_offset``, ...).
    stage : str
        Pipeline stage whose data or result it checks.
    statistic : str
        What ``value`` is (or why the check was not applicable).
    value, threshold : float
        The statistic and the limit it is compared with (fail when value > threshold, unless
        the statistic says otherwise); NaN value when not applicable.
    unit : str
    passed : bool
    severity : str
        Run status a failure imposes ("partial", "degraded" or "failed").
    suggestion : str
        What the data suggest (empty when passed or nothing can be estimated).
    time_ns_offset : int or None
        Time of the worst sample, as nanoseconds from the run epoch (None if not timed).
    """

    name: str
    stage: str
    statistic: str
    value: float
    threshold: float
    unit: str
    passed: bool
    severity: str
    suggestion: str = ""
    time_ns_offset: int | None = None


def comparison_text(value: float, threshold: float, unit: str) -> str:
    """``"4985 > 30 m"``: a check's value against its threshold, for messages and the console.

    Most checks fail above their threshold; a few (``calibration``: pairs used) below it.
    """
    op = "<" if value < threshold else ">"
    return f"{value:.4g} {op} {threshold:.4g}" + ("" if unit in ("", "1") else f" {unit}")


def run_status(checks: tuple[Check, ...] | list[Check]) -> str:
    """The worst severity among the failed checks ("ok" when all passed)."""
    worst = 0
    for c in checks:
        if not c.passed:
            worst = max(worst, STATUS_ORDER.index(c.severity))
    return STATUS_ORDER[worst]


def skip(name: str, stage: str, why: str, unit: str, threshold: float = math.nan) -> Check:
    """A check not applicable on the data: passed, NaN value, ``why`` in its statistic."""
    return Check(name, stage, f"not applicable: {why}", math.nan, threshold, unit, True,
                 "degraded")


def time_offset_ns(t_s: float | None) -> int | None:
    """Seconds from the run epoch as integer nanoseconds (None when unknown or not finite)."""
    return None if t_s is None or not math.isfinite(t_s) else int(round(t_s * NS_PER_S))
