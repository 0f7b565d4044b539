"""Unit conversions and the time base: each small fact of pospp written once.

SI and radians inside pospp; the units below appear only at the edges (config keys, table
columns, messages), as the suffix of each boundary name: ``_dph`` deg/h, ``_dpsh`` deg/sqrt(h),
``_ug`` micro-g, ``_arcsec`` arc seconds. A value in such a unit times the constant here is SI:
``w_radps = w_dph * DEG_PER_H_RADPS``; SI divided by it is the edge unit.

Time: files hold int64 ``time_ns`` (UTC ns, header stamps); numeric code works in float64
``t_s`` from a per-run epoch ``epoch_ns``. :func:`t_s_from_time_ns` and :func:`time_ns_from_t_s`
are the conversions (the difference is taken in integers first, so no precision is lost).

Sources: standard gravity g0 = 9.80665 m/s^2 (3rd CGPM, 1901; BIPM SI brochure, 9th ed.).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ARCSEC_RAD",
    "DEG_PER_H_RADPS",
    "DEG_PER_SQRT_H_RAD_PER_SQRT_S",
    "G0_MPS2",
    "MPS_PER_SQRT_H_MPS_PER_SQRT_S",
    "NS_PER_S",
    "S_PER_NS",
    "UG_MPS2",
    "t_s_from_time_ns",
    "time_ns_from_t_s",
]

G0_MPS2 = 9.80665
"""Standard gravity g0 [m/s^2] (3rd CGPM 1901): the g of 'g' and 'ug' units, not the local
gravity (that is ``pospp.earth.normal_gravity``)."""
UG_MPS2 = 1e-6 * G0_MPS2
"""One micro-g [m/s^2]."""
DEG_PER_H_RADPS = np.pi / 180.0 / 3600.0
"""One degree per hour [rad/s]."""
DEG_PER_SQRT_H_RAD_PER_SQRT_S = np.pi / 180.0 / 60.0
"""One deg/sqrt(h) (angle random walk) [rad/sqrt(s)]: (pi/180) / sqrt(3600 s)."""
MPS_PER_SQRT_H_MPS_PER_SQRT_S = 1.0 / 60.0
"""One m/s/sqrt(h) (velocity random walk) [m/s/sqrt(s)]."""
ARCSEC_RAD = np.pi / 180.0 / 3600.0
"""One arc second [rad]."""
NS_PER_S = 1_000_000_000
"""Nanoseconds per second (integer)."""
S_PER_NS = 1e-9
"""Seconds per nanosecond."""


def t_s_from_time_ns(time_ns: ArrayLike, epoch_ns: int) -> NDArray[np.float64]:
    """int64 nanoseconds -> float64 seconds from the epoch: ``(time_ns - epoch_ns) * 1e-9``.

    The difference is taken in int64 first, so a stamp near 1.7e18 ns keeps its nanoseconds.
    """
    return (np.asarray(time_ns, dtype=np.int64) - np.int64(epoch_ns)).astype(float) * S_PER_NS


def time_ns_from_t_s(t_s: ArrayLike, epoch_ns: int) -> NDArray[np.int64]:
    """float64 seconds from the epoch -> int64 nanoseconds: ``epoch_ns + round(t_s * 1e9)``."""
    return np.int64(epoch_ns) + np.round(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
