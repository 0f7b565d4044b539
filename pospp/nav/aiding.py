"""Where algorithm A was aided by GNSS: arrays of A's result in, a frozen
:class:`GnssAiding` out (no I/O).

A without GNSS is a free inertial solution: its trajectory is not GNSS-controlled, and over a
leg it drifts with B rather than holding B to the truth, so B minus A there is not B's error
(docs/qc.md "gnss_coverage"). Two facts of A's own result say where it was aided:

- the GNSS position and velocity records it received after its start (its innovation record:
  used, gated, or used after a covariance reset), whose gaps longer than
  :data:`GNSS_GAP_MAX_S` are the stretches with no GNSS to aid it;
- its horizontal velocity sigma, sqrt(P_vN + P_vE): GNSS records that are present but aid
  nothing (a huge covariance, or records A's gate rejects) leave A's sigma growing as in a
  gap. The level where A is aided is the median of the forward pass's sigma outside the gaps.

Gated records count as present for the gaps: A rejecting records is what the ``gnss_gate``
check judges, and over a stretch of them (up to ``[filter] gate_reset_s``, 30 s) the smoothed
reference is bridged from both sides; its sigma says whether it still holds.

Times ``t_s`` are seconds from the run epoch (A's time axis); sigmas m/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp.nav._filter_kernel import STATUS_GATED, STATUS_RESET, STATUS_USED

if TYPE_CHECKING:
    from pospp.nav.filter import FilterResult

__all__ = ["AIDED_SIGMA_FACTOR", "GNSS_GAP_MAX_S", "GnssAiding", "aiding_of", "gnss_aiding",
           "leg_aiding_problem"]

GNSS_GAP_MAX_S = 10.0
"""Longest stretch of A's span without a GNSS record that still counts as aided [s]:
ten 1 Hz epochs; a nav-grade A drifts millimetres per second in it, a MEMS A decimetres.
Receivers drop a few epochs, so a 2-3 s stretch is common on clean data."""
AIDED_SIGMA_FACTOR = 5.0
"""A is taken as GNSS-aided at an epoch when its horizontal velocity sigma is at most this
many times the level where it is aided (the sample flight: the smoothed sigma on its legs
0.2-0.8 times the forward pass's median where aided, its last leg, which ends with the data
and so gets no smoothing from after it, 0.8; without GNSS after 350 s, 50-1500 times)."""


@dataclass(frozen=True)
class GnssAiding:
    """Where A had GNSS over its span.

    Attributes
    ----------
    span_s : (float, float)
        A's first and last epoch [s].
    gaps_s : ndarray, shape (K, 2)
        [start, end] of each stretch of the span longer than :data:`GNSS_GAP_MAX_S` without a
        GNSS record (the span's ends count as edges) [s].
    longest_gap_s, longest_at_s : float
        The longest such stretch of any length, and where it starts [s].
    aided_vel_sigma_mps : float
        Median horizontal velocity sigma of A's forward pass outside the gaps [m/s] (NaN when
        it was aided nowhere).
    """

    span_s: tuple[float, float]
    gaps_s: NDArray
    longest_gap_s: float
    longest_at_s: float
    aided_vel_sigma_mps: float

    def gaps_in(self, start_s: float, end_s: float) -> NDArray:
        """The gaps that overlap [start_s, end_s], shape (k, 2)."""
        g = self.gaps_s
        return g[(g[:, 1] > start_s) & (g[:, 0] < end_s)]


def _horizontal(sigma_n: NDArray) -> NDArray:
    return np.hypot(sigma_n[:, 0], sigma_n[:, 1])


def gnss_aiding(used_t_s: ArrayLike, t_s: ArrayLike, vel_sigma_n_mps: ArrayLike
                ) -> GnssAiding:
    """Where A was GNSS-aided.

    Parameters
    ----------
    used_t_s : (M,) times of the GNSS position and velocity records A received [s]
    t_s : (N,) A's forward epochs [s]
    vel_sigma_n_mps : (N, 3) A's forward velocity sigma, NED [m/s]
    """
    t = np.asarray(t_s, dtype=float)
    sig = _horizontal(np.asarray(vel_sigma_n_mps, dtype=float))
    span = (float(t[0]), float(t[-1])) if t.size else (0.0, 0.0)
    used = np.unique(np.asarray(used_t_s, dtype=float))
    used = used[(used > span[0]) & (used < span[1])]
    edges = np.concatenate([[span[0]], used, [span[1]]])
    d = np.diff(edges)
    k = int(np.argmax(d)) if d.size else 0
    long = np.flatnonzero(d > GNSS_GAP_MAX_S)
    gaps = np.column_stack([edges[long], edges[long + 1]]) if long.size else np.zeros((0, 2))
    inside = np.zeros(t.shape, dtype=bool)
    for a, b in gaps:
        inside |= (t > a) & (t < b)
    level = float(np.median(sig[~inside])) if (~inside).any() else float("nan")
    return GnssAiding(span, gaps, float(d[k]) if d.size else 0.0, float(edges[k]), level)


def leg_aiding_problem(aiding: GnssAiding, start_s: float, end_s: float, ref_t_s: ArrayLike,
                       ref_vel_sigma_n_mps: ArrayLike) -> str | None:
    """Why A (the reference solution, epochs ``ref_t_s`` with velocity sigma NED
    ``ref_vel_sigma_n_mps``) is not GNSS-aided over the leg [start_s, end_s]; None when it is.

    Not aided: a gap of :data:`GNSS_GAP_MAX_S` or more overlaps the leg, or A's horizontal
    velocity sigma on the leg exceeds :data:`AIDED_SIGMA_FACTOR` times its aided level.
    """
    gaps = aiding.gaps_in(start_s, end_s)
    if gaps.shape[0]:
        a, b = gaps[0]
        inside = float(np.sum(np.minimum(gaps[:, 1], end_s) - np.maximum(gaps[:, 0], start_s)))
        to = "the end of the data" if b >= aiding.span_s[1] else f"t = {b:.0f} s"
        return (f"reference A not GNSS-aided: no GNSS record from t = {a:.0f} s to {to} "
                f"({b - a:.0f} s), {inside:.0f} s of the leg's {end_s - start_s:.0f} s")
    t = np.asarray(ref_t_s, dtype=float)
    on = (t >= start_s) & (t <= end_s)
    level = aiding.aided_vel_sigma_mps
    if not on.any() or not np.isfinite(level) or level <= 0.0:
        return None
    sig = _horizontal(np.asarray(ref_vel_sigma_n_mps, dtype=float)[on])
    worst = int(np.argmax(sig))
    if sig[worst] > AIDED_SIGMA_FACTOR * level:
        return (f"reference A not GNSS-aided: its horizontal velocity sigma reaches "
                f"{sig[worst]:.3g} m/s at t = {t[on][worst]:.0f} s, {sig[worst] / level:.0f} "
                f"times its {level:.2g} m/s where GNSS aids it")
    return None


def aiding_of(result: FilterResult) -> GnssAiding:
    """:func:`gnss_aiding` of an A run: the GNSS position and velocity records its forward
    pass received after its start (used, gated or used after a covariance reset), its
    forward epochs and velocity sigmas.
    Without an innovation record (never, from :func:`pospp.nav.filter.
    run_integrated_navigation`), every epoch counts as aided."""
    rec, fwd = result.innovations, result.forward
    if rec is None:
        used = np.asarray(fwd.t_s, dtype=float)
    else:
        used = rec.t_s[(rec.kind <= 1) & np.isin(rec.status, (STATUS_USED, STATUS_GATED,
                                                               STATUS_RESET))]
    return gnss_aiding(used, fwd.t_s, fwd.vel_sigma_ned_mps)
