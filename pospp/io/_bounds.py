"""Physical limits of every decoded value of a flight log (private to :mod:`pospp.io.mcap_reader`).

A value may be finite and still impossible: a flipped bit in an exponent turns 9.8 m/s^2 into
3e206 m/s^2 (issue 38 item 4), which a chunk without a CRC cannot reveal and which no later
check catches before it reaches algorithm A. Every field the reader keeps is bounded here by a
limit beyond any sensor or vehicle pospp serves (docs/formats.md, "Physical limits"); a value
outside it stops ingestion with an :class:`~pospp.io.errors.IngestError` naming the file, the
topic, the first bad message, the field, the value and the limit, as a NaN does.

Units as decoded (on the wire, before any rotation): rad/s, m/s^2, m, m^2, m/s, (m/s)^2, ns.
The checks take no (N, 3) temporary in the usual case (one ``min`` and one ``max`` per field).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pospp.io.errors import IngestError

__all__ = ["BOUNDS", "Bound", "check_values"]


@dataclass(frozen=True)
class Bound:
    """Range of one decoded field (every element, or the columns ``cols`` of each row)."""

    field: str
    lo: float
    hi: float
    unit: str
    why: str
    step: int = 1
    """The range applies to every ``step``-th column of the (N, K) field (4 on a row-major
    3x3 matrix: its diagonal)."""


_STAMP = Bound("time_ns", 0, np.iinfo(np.int64).max, "ns",
               "header stamps are nanoseconds since 1970 (ROS time), never negative")
BOUNDS: dict[str, tuple[Bound, ...]] = {
    "imu": (
        _STAMP,
        Bound("angular_velocity", -200.0, 200.0, "rad/s",
              "11,500 deg/s: beyond any gyro's range (MEMS 2000-4000 deg/s)"),
        Bound("linear_acceleration", -2000.0, 2000.0, "m/s^2",
              "about 200 g: beyond any accelerometer's range on a vehicle (MEMS up to 200 g)"),
    ),
    "fix": (
        _STAMP,
        Bound("altitude", -1.0e4, 1.0e5, "m",
              "ellipsoidal height from 10 km below the ellipsoid to 100 km above it"),
        Bound("position_covariance", 0.0, 1.0e12, "m^2", "variances of 0 to (1000 km)^2",
              4),
        Bound("position_covariance", -1.0e12, 1.0e12, "m^2",
              "covariances of at most (1000 km)^2"),
    ),
    "vel": (
        _STAMP,
        Bound("linear", -3000.0, 3000.0, "m/s", "3 km/s per axis: beyond any aircraft"),
        Bound("cov", 0.0, 1.0e8, "(m/s)^2", "variances of 0 to (10 km/s)^2", 4),
        Bound("cov", -1.0e8, 1.0e8, "(m/s)^2", "covariances of at most (10 km/s)^2"),
    ),
    "events": (_STAMP,),
}
"""The physical limits per role (``imu``, ``fix``, ``vel``, ``events``); ``vel`` ``cov`` is the
linear 3x3 block of the twist covariance (the only part read)."""


def _rows(a: dict, name: str) -> np.ndarray:
    v = a[name]
    return v.reshape(len(v), -1)


def _check_finite(a: dict, names: tuple[str, ...], topic: str, path: str) -> None:
    if all(np.isfinite(a[name]).all() for name in names):  # the usual case, one pass each
        return
    bad = np.zeros(len(a["time_ns"]), bool)
    for name in names:
        bad |= ~np.isfinite(_rows(a, name)).all(axis=1)
    i = int(np.argmax(bad))
    fields = [n for n in names if not np.isfinite(a[n][i]).all()]
    raise IngestError(
        f"non-finite value (NaN or inf) in {', '.join(fields)} = "
        f"{[a[n][i].tolist() for n in fields]} ({int(bad.sum())} bad message(s) in total)",
        file=path, topic=topic, index=_index(a, i), time_ns=int(a["time_ns"][i]),
        log_time_ns=int(a["log_time_ns"][i]),
    )


def _index(a: dict, i: int) -> int:
    """File-order index of sample ``i`` (``a["index"]``: None while it is the identity)."""
    idx = a.get("index")
    return int(i) if idx is None else int(idx[i])


def check_values(a: dict, role: str, names: tuple[str, ...], topic: str, path: str) -> None:
    """NaN or inf in the fields ``names`` of ``a``, then every :data:`BOUNDS` row of ``role``
    (whose field ``a`` holds): the first offending message raises :class:`IngestError`."""
    _check_finite(a, names, topic, path)
    for b in BOUNDS[role]:
        if b.field not in a or len(a[b.field]) == 0:
            continue
        v = _rows(a, b.field)[:, :: b.step]
        if v.min() >= b.lo and v.max() <= b.hi:  # the usual case: no temporary
            continue
        bad = ((v < b.lo) | (v > b.hi)).any(axis=1)
        i = int(np.argmax(bad))
        row = a[b.field][i]
        shown = int(row) if b.field == "time_ns" else np.asarray(row).tolist()
        raise IngestError(
            f"{b.field} = {shown} outside its physical range [{b.lo:g}, {b.hi:g}] {b.unit} "
            f"({b.why}; docs/formats.md) ({int(bad.sum())} bad message(s) in total): a "
            "corrupt value or the wrong unit", file=path, topic=topic, index=_index(a, i),
            time_ns=int(a["time_ns"][i]), log_time_ns=int(a["log_time_ns"][i]),
        )
