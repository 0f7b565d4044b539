"""QC check of the GNSS-IMU time offset: the GNSS course changes against the integrated IMU yaw
rate, searched over seconds to tens of seconds, and the joint estimate with the lever arm for
the milliseconds (arrays in, a frozen :class:`pospp.qc.check_record.Check` out; no I/O). Times
``t_s`` are seconds from the run epoch; rates rad/s; velocities NED m/s.

The check fails when the offset is significant against its own sigma (beyond
``TIME_OFFSET_SIGMAS``) and above the practical floor
(:data:`pospp.qc.lever_time.TIME_OFFSET_FLOOR_S`): no fixed threshold, so a measured
50 +- 2 ms offset cannot pass. A whole number of seconds is named: 18 s is the GPS-UTC
difference (leap seconds since 1980), 37 s TAI-UTC, 19 s TAI-GPS (:data:`CLOCK_SLIPS_S`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp.qc.check_record import Check, skip
from pospp.qc.lever_time import TIME_OFFSET_FLOOR_S, LeverTime, lever_time_verdict

TIME_OFFSET_MAX_S = 0.1
"""The offset above which a lever arm cannot stand for it (6 m along the track at 60 m/s) and
the course method alone decides: the joint estimate with the lever arm is made below it."""
TIME_OFFSET_SIGMAS = 5.0
"""An offset fails when it is this many of its sigmas away from 0 (and above the floor)."""
TIME_OFFSET_SEARCH_S = 60.0
"""Offsets searched: [-60, 60] s (a leap-second slip is 18 s, TAI-UTC 37 s)."""
TIME_OFFSET_COARSE_S = 0.25
"""Step of the coarse search [s]; the fine search steps 0.01 s within +-0.5 s of its best."""
TIME_OFFSET_MIN_SPEED_MPS = 3.0
"""Course over ground is used where the horizontal speed is above this."""
TIME_OFFSET_MIN_EXPLAINED = 0.5
"""The check applies only when the yaw rate explains at least this share (R^2) of the course
changes: a vehicle that flies sideways (multirotor) turns its course without its heading."""
CLOCK_SLIPS_S = {18: ("GPS time", "UTC"), 19: ("TAI", "GPS time"), 37: ("TAI", "UTC")}
"""Whole-second offsets with a known cause: n -> (the time scale n s ahead, the other).
GPS - UTC = 18 s (the leap seconds since 1980), TAI - UTC = 37 s (IERS Bulletin C, since
2017-01-01), TAI - GPS = 19 s."""


@dataclass(frozen=True)
class TimeOffsetEstimate:
    """GNSS stamp minus true measurement time [s] (positive: GNSS lags the IMU)."""

    offset_s: float
    sigma_s: float
    n_intervals: int
    residual_rms_rad: float
    explained: float
    """Share of the course changes' variance the integrated yaw rate explains (R^2)."""


def estimate_time_offset(imu_t_s: ArrayLike, w_d_radps: ArrayLike, vel_t_s: ArrayLike,
                         v_n_mps: ArrayLike, *, search_s: float = TIME_OFFSET_SEARCH_S
                         ) -> TimeOffsetEstimate | None:
    """GNSS-IMU time offset from the turns: course change against integrated yaw rate.

    The course over ground chi = atan2(v_E, v_N) of the GNSS velocity turns with the vehicle:
    between records k and k+1, chi_k+1 - chi_k = Psi(t_k+1 - tau) - Psi(t_k - tau), where
    Psi(t) = integral of the IMU's vertical rotation rate w_d (body w.r.t. NED about down, from
    A's attitude) and tau the GNSS stamp minus the true time. tau minimises the sum of squared
    misfits: a coarse grid over +-``search_s`` (``TIME_OFFSET_COARSE_S``), a fine grid of
    0.01 s within +-0.5 s of its best, a parabola through the best three, one refit without
    6-MAD outliers (a jump or a course flip at low speed). sigma from the residual scatter and
    the sensitivity d(misfit)/d tau. Only the records whose interval, shifted by any offset
    searched, lies inside the IMU span count. None when fewer than 20 usable intervals.

    The velocity should be the IMU's (the antenna's less the lever arm's ``C_nb (w x l)``): a
    forward lever arm l_x moves the antenna's course like an offset of -l_x / v.

    Parameters
    ----------
    imu_t_s : (N,) IMU interval ends [s]
    w_d_radps : (N,) mean rotation rate about the NED down axis over each interval [rad/s]
    vel_t_s, v_n_mps : (K,), (K, 3) GNSS velocity (NED) [s, m/s]
    search_s : float
        Largest |offset| searched [s].
    """
    t = np.asarray(imu_t_s, dtype=float)
    wd = np.asarray(w_d_radps, dtype=float)
    tv = np.asarray(vel_t_s, dtype=float)
    v = np.asarray(v_n_mps, dtype=float)
    if t.shape[0] < 3 or tv.shape[0] < 3:
        return None
    psi = np.concatenate([[0.0], np.cumsum(wd[1:] * np.diff(t))])
    speed = np.hypot(v[:, 0], v[:, 1])
    chi = np.arctan2(v[:, 1], v[:, 0])
    dchi = np.angle(np.exp(1j * np.diff(chi)))
    dtv = np.diff(tv)
    med = float(np.median(dtv))
    moving = ((speed[:-1] > TIME_OFFSET_MIN_SPEED_MPS) & (speed[1:] > TIME_OFFSET_MIN_SPEED_MPS)
              & (dtv < 1.5 * med))
    # the search shrinks to what the IMU span allows a quarter of the moving records
    span = float(min(search_s, max(0.5 * (t[-1] - t[0]) - 1.0, 1.0)))
    ok = moving & (tv[:-1] - span > t[0]) & (tv[1:] + span < t[-1])
    while int(ok.sum()) < max(20, moving.sum() // 4) and span > 5.0:
        span *= 0.5
        ok = moving & (tv[:-1] - span > t[0]) & (tv[1:] + span < t[-1])
    if int(ok.sum()) < 20:
        return None
    t0, t1, dchi = tv[:-1][ok], tv[1:][ok], dchi[ok]

    def resid(tau: float, keep: NDArray) -> NDArray:
        return dchi[keep] - (np.interp(t1[keep] - tau, t, psi) - np.interp(t0[keep] - tau, t,
                                                                            psi))

    made: dict[tuple[float, int], NDArray] = {}  # the refit without outliers reuses them

    def best_of(grid: NDArray, keep: NDArray) -> tuple[int, NDArray]:
        key = (float(grid[0]), grid.shape[0])
        if key not in made:
            made[key] = _grid_squares(grid, t, psi, t0, t1, dchi)
        cost = np.array([np.sum(row[keep]) for row in made[key]])
        return int(np.clip(np.argmin(cost), 1, grid.shape[0] - 2)), cost

    def fit(keep: NDArray) -> float:
        coarse = np.arange(-span, span + 1e-9, TIME_OFFSET_COARSE_S)
        i, _ = best_of(coarse, keep)
        grid = coarse[i] + np.arange(-0.5, 0.5 + 1e-9, 0.01)
        i, cost = best_of(grid, keep)
        c0, c1, c2 = cost[i - 1], cost[i], cost[i + 1]
        den = c0 - 2.0 * c1 + c2
        shift = 0.5 * (c0 - c2) / den if den > 0 else 0.0
        return float(grid[i] + np.clip(shift, -1.0, 1.0) * 0.01)

    keep = np.ones(dchi.shape[0], dtype=bool)
    tau = fit(keep)
    r = resid(tau, keep)
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    keep = np.abs(r) <= max(6.0 * mad, 1e-6)
    if int(keep.sum()) < 20:
        return None
    tau = fit(keep)
    r = resid(tau, keep)
    h = 0.05
    sens = (resid(tau + h, keep) - resid(tau - h, keep)) / (2.0 * h)
    info = float(np.sum(sens**2))
    rms = float(np.sqrt(np.mean(r**2)))
    sigma = rms / math.sqrt(info) if info > 0 else math.inf
    tot = float(np.sum((dchi[keep] - dchi[keep].mean()) ** 2))
    explained = 1.0 - float(np.sum(r**2)) / tot if tot > 0 else 0.0
    return TimeOffsetEstimate(tau, sigma, int(keep.sum()), rms, explained)


def _grid_squares(grid: NDArray, t: NDArray, psi: NDArray, t0: NDArray, t1: NDArray,
                  dchi: NDArray, chunk: int = 64) -> NDArray:
    """``(dchi - (Psi(t1 - tau) - Psi(t0 - tau)))^2`` per ``tau`` of ``grid`` (rows) and record
    (columns): a row's sum over any records is the misfit of those records at that tau, bit
    for bit as if only they had been interpolated. The queries are laid out record by record,
    tau descending (each record's queries then increase a few IMU samples apart, and
    ``np.interp`` finds each next to the last one found instead of bisecting the whole
    flight; ``chunk`` taus at a time)."""
    out = np.empty((grid.shape[0], t1.shape[0]))
    for c in range(0, grid.shape[0], chunk):
        taus = grid[c:c + chunk][::-1]
        psi1 = np.interp((t1[:, None] - taus[None, :]).ravel(), t, psi)
        psi0 = np.interp((t0[:, None] - taus[None, :]).ravel(), t, psi)
        r = dchi[:, None] - (psi1 - psi0).reshape(t1.shape[0], taus.shape[0])
        out[c:c + taus.shape[0]] = (r[:, ::-1].T) ** 2  # a row per tau, as grid's
    return out


def clock_slip(tau_s: float, sigma_s: float) -> str:
    """The offset named when it is a whole number of seconds (within 3 sigma or 20 ms): the
    time scales of :data:`CLOCK_SLIPS_S` (a GNSS ``tau_s`` late is stamped in the scale that
    is ahead), or a clock slip; '' below 0.5 s or off the whole seconds."""
    n = round(abs(tau_s))
    if n < 1 or abs(abs(tau_s) - n) > max(3.0 * sigma_s, 0.02):
        return ""
    if n not in CLOCK_SLIPS_S:
        return f"{n} s, a clock or epoch slip of whole seconds"
    ahead, behind = CLOCK_SLIPS_S[n]
    gnss, imu = (ahead, behind) if tau_s > 0 else (behind, ahead)
    return (f"{n} s, the {ahead} - {behind} difference: the GNSS stamped in {gnss} where the "
            f"IMU is in {imu}")


def _suggest(tau_s: float, sigma_s: float, how: str, verdict: str) -> str:
    """The failed check's suggestion: the joint estimate's reading below
    ``TIME_OFFSET_MAX_S`` (both readings, with the lever arm), else the offset, named when a
    whole number of seconds."""
    if verdict:
        return verdict
    word = "lags" if tau_s > 0 else "leads"
    size = (f"{abs(tau_s):.1f} s" if abs(tau_s) >= 0.05 else f"{1e3 * abs(tau_s):.0f} ms")
    slip = clock_slip(tau_s, sigma_s)
    slip = f"; a whole-second offset of {slip}" if slip else ""
    return (f"GNSS {word} the IMU by about {size} ({tau_s:+.3f} +- {sigma_s:.3f} s {how})"
            f"{slip}: fix the GNSS stamps (receiver latency, clock, time scale) before the run")


def gnss_time_offset(est: TimeOffsetEstimate | None, joint: LeverTime | None = None) -> Check:
    """The GNSS time offset: fails when |tau| exceeds ``TIME_OFFSET_SIGMAS`` of its sigma
    and the practical floor (threshold = the larger of the two).

    ``est`` (:func:`estimate_time_offset`, the turns) measures the offset over +-60 s; it
    reads a forward lever-arm error dl_x as an offset of -dl_x / v, like every measurement
    at constant speed. Below ``TIME_OFFSET_MAX_S``, ``joint`` (the joint estimate with the
    lever arm, :func:`pospp.qc.lever_time.lever_time_joint`), when made, gives the offset
    instead, and its reading (:func:`pospp.qc.lever_time.lever_time_verdict`) the
    suggestion. Not applicable when there is no estimate, or when the course does not
    follow the heading (R^2 below ``TIME_OFFSET_MIN_EXPLAINED``: sideways flight).
    """
    name = "gnss_time_offset"
    if est is None and joint is None:
        return skip(name, "navigate", "too few GNSS velocities while moving", "s",
                    TIME_OFFSET_FLOOR_S)
    if est is not None and not est.explained >= TIME_OFFSET_MIN_EXPLAINED and joint is None:
        return skip(name, "navigate", f"the course does not follow the heading (R^2 "
                    f"{est.explained:.2f}; sideways flight?)", "s", TIME_OFFSET_FLOOR_S)
    small = est is None or abs(est.offset_s) < TIME_OFFSET_MAX_S
    verdict = lever_time_verdict(joint, sigmas=TIME_OFFSET_SIGMAS) if joint else None
    text = (verdict.text if verdict is not None and small
            and verdict.kind in ("time_offset", "both", "confounded") else "")
    turns = f"; the turns alone: {est.offset_s:+.4f} +- {est.sigma_s:.4f} s" if est else ""
    if joint is not None and small and math.isfinite(joint.sigma_tau_s):
        tau, sig = joint.tau_s, joint.sigma_tau_s
        what = ("GNSS stamp minus true time, jointly with the lever arm (A's lever-arm pass "
                f"at trial offsets, {joint.n_records} records{turns})")
        how = "jointly with the lever arm"
    elif joint is not None and small and math.isfinite(joint.tau_lever_only_s):
        # the flight does not separate them: the offset that alone explains A's apparent
        # forward lever arm (the turns read the same combination, and read a turn's
        # sideslip as an offset too: 87 +- 6 ms on a clean simulated flight, bench_qc)
        tau = joint.tau_lever_only_s
        sig = float(joint.sigma_apparent_b_m[0] / max(abs(joint.speed_mps), 1e-9))
        what = ("GNSS stamp minus true time that alone explains A's apparent forward lever "
                "arm (the flight does not separate the two; A's lever-arm pass, "
                f"{joint.n_records} records{turns})")
        how = "as the apparent lever arm's"
    elif est is not None:
        tau, sig = est.offset_s, est.sigma_s
        what = ("|GNSS stamp minus IMU time| from course changes against the integrated yaw "
                f"rate ({est.n_intervals} intervals, sigma {est.sigma_s:.3f} s)")
        how = "from the turns"
    else:
        return skip(name, "navigate", "the joint estimate with the lever arm does not "
                    "determine the offset and the turns give none", "s", TIME_OFFSET_FLOOR_S)
    thr = max(TIME_OFFSET_FLOOR_S, TIME_OFFSET_SIGMAS * sig) if math.isfinite(sig) else math.inf
    passed = not abs(tau) > thr
    sug = "" if passed else _suggest(tau, sig, how, text)
    return Check(name, "navigate", f"{what}; fails beyond {TIME_OFFSET_SIGMAS:.0f} sigma and "
                 f"{1e3 * TIME_OFFSET_FLOOR_S:.0f} ms", abs(tau), thr, "s", passed, "degraded",
                 sug)
