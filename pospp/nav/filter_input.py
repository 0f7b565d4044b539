"""Entry checks of algorithm A's inputs: IMU samples and GNSS records (pospp.nav.filter).

IMU samples that break the data contract raise ``ValueError`` naming the sample, its time and
what is wrong (wrong shapes, non-finite values, time not increasing, a gap longer than a few
nominal intervals). GNSS records are screened one by one: non-finite values or covariances,
variances not positive, covariances not positive definite or absurdly large, duplicate stamps
(the first is kept) and records outside the IMU span are refused and reported as
:class:`GnssRejection` (time, kind, reason, offending value); the kept covariances are
symmetrised and floored per axis. Units: SI, NED covariances [m^2], [m^2/s^2].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp.units import t_s_from_time_ns


@dataclass(frozen=True)
class GnssRejection:
    """A GNSS (or pseudo-) measurement that was not used, and why."""

    time_ns: int
    t_s: float
    kind: str
    """"position", "velocity" or "zupt"."""
    reason: str
    value: float = math.nan
    """The offending quantity (NIS for the gate, sigma for covariance checks), else NaN."""


def imu_epochs(
    time_ns: NDArray, w: NDArray, f: NDArray, epoch_ns: int, max_gap_intervals: float,
    max_gap_s: float,
) -> tuple[NDArray, tuple[tuple[float, float], ...]]:
    """Check the IMU samples (N mean rates over the intervals ending at their stamps).

    Returns
    -------
    t_s : ndarray, shape (N,)
        Epochs [s] from ``epoch_ns``.
    gaps : tuple of (t_s, duration_s)
        Intervals longer than ``max_gap_intervals`` median intervals (but at most
        ``max_gap_s``): the end of the gap and its length. The filter bridges them, holding
        the rate of the sample after the gap, and reports them.

    Raises
    ------
    ValueError
        Wrong shapes, non-finite samples, time not increasing, or a gap longer than
        ``max_gap_s``, naming the sample and its time.
    """
    n = time_ns.shape[0]
    if n < 3 or w.shape != (n, 3) or f.shape != (n, 3):
        raise ValueError(f"imu: expected N >= 3 stamps with (N, 3) rates, got {time_ns.shape}, "
                         f"{w.shape}, {f.shape}")
    bad = ~(np.isfinite(w).all(axis=1) & np.isfinite(f).all(axis=1))
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"imu: non-finite rate in sample {k} (time_ns {time_ns[k]}): "
                         f"w {w[k].tolist()}, f {f[k].tolist()}")
    dt_ns = np.diff(time_ns)
    if (dt_ns <= 0).any():
        k = int(np.argmax(dt_ns <= 0)) + 1
        raise ValueError(f"imu: time not increasing at sample {k}: time_ns {time_ns[k]} after "
                         f"{time_ns[k - 1]}")
    t = t_s_from_time_ns(time_ns, epoch_ns)
    dt = np.diff(t)
    dt_med = float(np.median(dt))
    too_long = dt > max_gap_s
    if too_long.any():
        k = int(np.argmax(too_long)) + 1
        raise ValueError(
            f"imu: gap of {dt[k - 1]:.6f} s ({dt[k - 1] / dt_med:.1f} nominal intervals of "
            f"{dt_med:.6f} s) ending at sample {k}, t = {t[k]:.6f} s (time_ns {time_ns[k]}); "
            f"expected at most max_imu_gap_s = {max_gap_s:g} s"
        )
    gap = np.flatnonzero(dt > max_gap_intervals * dt_med)
    return t, tuple((float(t[k + 1]), float(dt[k])) for k in gap)


def screen_gnss(
    kind: str, time_ns: NDArray, values: NDArray, cov: NDArray, floor: float, max_sigma: float,
    t_lo_s: float, t_hi_s: float, epoch_ns: int, rejections: list[GnssRejection],
) -> NDArray:
    """Entry checks of GNSS records; returns the indices kept (sorted by time), floors cov."""
    n = time_ns.shape[0]
    t_s = t_s_from_time_ns(time_ns, epoch_ns)
    reason = np.full(n, "", dtype=object)
    value = np.full(n, math.nan)
    bad_val = ~np.isfinite(values).all(axis=1)
    reason[bad_val] = "non-finite value"
    bad_cov = ~np.isfinite(cov).all(axis=(1, 2)) & (reason == "")
    reason[bad_cov] = "non-finite covariance"
    fin = reason == ""
    diag = np.full((n, 3), np.nan)
    diag[fin] = np.diagonal(cov[fin], axis1=1, axis2=2)
    nonpos = fin & ~(diag > 0.0).all(axis=1)
    reason[nonpos] = "covariance not positive (zero or negative variance)"
    value[nonpos] = np.nanmin(np.where(np.isfinite(diag), diag, np.inf), axis=1)[nonpos]
    ok = reason == ""
    if ok.any():
        eig_min = np.full(n, np.inf)
        sym_cov = 0.5 * (cov[ok] + np.swapaxes(cov[ok], 1, 2))
        eig_min[ok] = np.linalg.eigvalsh(sym_cov)[:, 0]
        not_pd = ok & (eig_min <= 0.0)
        reason[not_pd] = "covariance not positive definite"
        value[not_pd] = eig_min[not_pd]
    big = (reason == "") & (np.sqrt(np.nanmax(np.where(np.isfinite(diag), diag, 0.0), axis=1))
                            > max_sigma)
    reason[big] = f"covariance too large (sigma > {max_sigma:g})"
    value[big] = np.sqrt(np.nanmax(diag[big], axis=1)) if big.any() else value[big]
    outside = (reason == "") & ((t_s < t_lo_s) | (t_s > t_hi_s))
    reason[outside] = "outside the IMU time span"
    # duplicates: the first record of a time stamp is kept, later ones are rejected
    order = np.argsort(time_ns, kind="stable")
    cand = order[reason[order] == ""]
    dup = np.zeros(n, dtype=bool)
    if cand.shape[0] > 1:
        same = np.diff(time_ns[cand]) == 0
        dup[cand[1:][same]] = True
    reason[dup] = "duplicate time"
    for i in np.flatnonzero(reason != ""):
        rejections.append(GnssRejection(int(time_ns[i]), float(t_s[i]), kind, str(reason[i]),
                                        float(value[i])))
    keep = cand[~dup[cand]]
    c = cov[keep]
    d = np.diagonal(c, axis1=1, axis2=2)
    add = np.clip(floor**2 - d, 0.0, None)
    c = c + add[:, :, None] * np.eye(3)[None]
    cov[keep] = 0.5 * (c + np.swapaxes(c, 1, 2))
    return keep


def gnss_arrays(fixes, vels, use_velocity: bool):
    """Raw GNSS arrays: (fix time_ns, [lat, lon, h], cov), (vel time_ns, v_n, cov)."""
    fix_t = np.asarray(fixes.time_ns, dtype=np.int64)
    fix_val = np.column_stack([np.asarray(fixes.lat_rad, dtype=float),
                               np.asarray(fixes.lon_rad, dtype=float),
                               np.asarray(fixes.height_m, dtype=float)]).reshape(-1, 3)
    fix_cov = np.array(fixes.pos_cov_ned_m2, dtype=float).reshape(-1, 3, 3)
    if vels is None or not use_velocity:
        return (fix_t, fix_val, fix_cov), (np.zeros(0, np.int64), np.zeros((0, 3)),
                                           np.zeros((0, 3, 3)))
    vel_t = np.asarray(vels.time_ns, dtype=np.int64)
    vel_val = np.asarray(vels.v_n_mps, dtype=float).reshape(-1, 3)
    vel_cov = np.array(vels.vel_cov_ned_m2ps2, dtype=float).reshape(-1, 3, 3)
    return (fix_t, fix_val, fix_cov), (vel_t, vel_val, vel_cov)
