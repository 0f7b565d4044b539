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
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pospp.nav._filter_kernel import (
    FLAG_NODE,
    FLAG_OUTPUT,
    MEAS_KINDS,
    MEAS_POSITION,
    MEAS_VELOCITY,
    MEAS_ZUPT,
)
from pospp.types import GnssFixes, GnssVelocities
from pospp.units import t_s_from_time_ns, time_ns_from_t_s

if TYPE_CHECKING:
    from pospp.nav.filter import FilterOptions


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
    # one flat pass each in the usual case (the per-row test, 30 ms at 1 M samples, only to
    # name the first bad sample)
    if not (np.isfinite(w).all() and np.isfinite(f).all()):
        k = int(np.argmax(~(np.isfinite(w).all(axis=1) & np.isfinite(f).all(axis=1))))
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


def gnss_arrays(fixes: GnssFixes, vels: GnssVelocities | None, use_velocity: bool
                ) -> tuple[tuple[NDArray, NDArray, NDArray], tuple[NDArray, NDArray, NDArray]]:
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


@dataclass(frozen=True)
class ScreenedGnss:
    """The GNSS records kept by :func:`screen_gnss` (covariances floored), by time."""

    fix_time_ns: NDArray
    fix_t_s: NDArray
    fix_llh: NDArray
    """[lat_rad, lon_rad, height_m] (M, 3)."""
    fix_cov: NDArray
    vel_time_ns: NDArray
    vel_t_s: NDArray
    vel_n: NDArray
    vel_cov: NDArray


def screened_gnss(fixes: GnssFixes, vels: GnssVelocities | None, t: NDArray, epoch_ns: int,
                  options: FilterOptions, rejections: list[GnssRejection]) -> ScreenedGnss:
    """Entry checks of the fixes and velocities (``options``: floors, sigma limits, the IMU
    span widened by ``max_gnss_imu_offset_s``); refused records go to ``rejections``."""
    (fix_t_ns, fix_val, fix_cov), (vel_t_ns, vel_val, vel_cov) = gnss_arrays(
        fixes, vels, options.use_velocity)
    t_lo, t_hi = t[0] - options.max_gnss_imu_offset_s, t[-1] + options.max_gnss_imu_offset_s
    keep_f = screen_gnss(
        "position", fix_t_ns, fix_val, fix_cov, options.pos_sigma_floor_m,
        options.max_pos_sigma_m, t_lo, t_hi, epoch_ns, rejections)
    keep_v = screen_gnss(
        "velocity", vel_t_ns, vel_val, vel_cov, options.vel_sigma_floor_mps,
        options.max_vel_sigma_mps, t_lo, t_hi, epoch_ns, rejections)
    return ScreenedGnss(
        fix_time_ns=fix_t_ns[keep_f], fix_t_s=t_s_from_time_ns(fix_t_ns[keep_f], epoch_ns),
        fix_llh=fix_val[keep_f], fix_cov=fix_cov[keep_f],
        vel_time_ns=vel_t_ns[keep_v], vel_t_s=t_s_from_time_ns(vel_t_ns[keep_v], epoch_ns),
        vel_n=vel_val[keep_v], vel_cov=vel_cov[keep_v])


@dataclass(frozen=True)
class MeasurementRecords:
    """The measurement records of the forward pass, sorted by (IMU epoch, kind).

    ``kind`` (``MEAS_POSITION`` / ``MEAS_VELOCITY`` / ``MEAS_ZUPT``), ``t_s`` record time,
    ``time_ns`` its stamp, ``z`` value ([lat, lon, h] or v_n, zero for ZUPTs), ``r`` its NED
    covariance, ``k`` the nearest IMU epoch and ``dt_s`` = record time - epoch time.
    """

    kind: NDArray
    t_s: NDArray
    time_ns: NDArray
    z: NDArray
    r: NDArray
    k: NDArray
    dt_s: NDArray


def measurement_records(gnss: ScreenedGnss, zupt_t_s: NDArray | None, zupt_sigma_mps: float,
                        t: NDArray, epoch_ns: int, max_offset_s: float,
                        rejections: list[GnssRejection]) -> MeasurementRecords:
    """Fixes, velocities and ZUPTs (at ``zupt_t_s``) as one list at their nearest IMU epochs;
    a record further than ``max_offset_s`` from every epoch is refused (``rejections``)."""
    kinds = [np.full(gnss.fix_t_s.shape[0], MEAS_POSITION),
             np.full(gnss.vel_t_s.shape[0], MEAS_VELOCITY)]
    times = [gnss.fix_t_s, gnss.vel_t_s]
    zs = [gnss.fix_llh, gnss.vel_n]
    rs = [gnss.fix_cov, gnss.vel_cov]
    src = [gnss.fix_time_ns, gnss.vel_time_ns]
    if zupt_t_s is not None:
        kinds.append(np.full(zupt_t_s.shape[0], MEAS_ZUPT))
        times.append(zupt_t_s)
        zs.append(np.zeros((zupt_t_s.shape[0], 3)))
        rs.append(np.tile(np.eye(3) * zupt_sigma_mps**2, (zupt_t_s.shape[0], 1, 1)))
        src.append(time_ns_from_t_s(zupt_t_s, epoch_ns))
    m_type = np.concatenate(kinds).astype(np.int64)
    m_t = np.concatenate(times)
    m_src = np.concatenate(src)
    k_near = np.clip(np.searchsorted(t, m_t), 1, t.shape[0] - 1)
    k_near = np.where(np.abs(t[k_near - 1] - m_t) <= np.abs(t[k_near] - m_t), k_near - 1, k_near)
    m_dt = m_t - t[k_near]
    far = np.abs(m_dt) > max_offset_s
    for i in np.flatnonzero(far):
        rejections.append(GnssRejection(int(m_src[i]), float(m_t[i]), MEAS_KINDS[m_type[i]],
                                        "no IMU epoch within max_gnss_imu_offset_s",
                                        float(m_dt[i])))
    order = np.lexsort((m_type, k_near))
    order = order[~far[order]]
    return MeasurementRecords(
        kind=m_type[order], t_s=m_t[order], time_ns=m_src[order],
        z=np.ascontiguousarray(np.concatenate(zs)[order]),
        r=np.ascontiguousarray(np.concatenate(rs)[order]),
        k=k_near[order].astype(np.int64), dt_s=np.ascontiguousarray(m_dt[order]))


def grid_epochs(t: NDArray, k0: int, interval_s: float | None) -> NDArray:
    """IMU epoch indices (>= k0, unique) nearest the multiples of ``interval_s`` in t_s."""
    if interval_s is None:
        return np.arange(k0, t.shape[0])
    g0 = math.ceil(t[k0] / interval_s - 1e-9)
    g1 = math.floor(t[-1] / interval_s + 1e-9)
    grid = np.arange(g0, g1 + 1) * interval_s
    k = np.clip(np.searchsorted(t, grid), 1, t.shape[0] - 1)
    k = np.where(np.abs(t[k - 1] - grid) <= np.abs(t[k] - grid), k - 1, k)
    return np.unique(np.maximum(k, k0))


def epoch_flags(t: NDArray, k0: int, m_k: NDArray, output_rate_hz: float | None,
                 node_interval_s: float) -> tuple[NDArray, NDArray]:
    """Per-epoch ``FLAG_OUTPUT`` / ``FLAG_NODE`` bits, and the output epochs."""
    flags = np.zeros(t.shape[0], dtype=np.int64)
    out_k = grid_epochs(t, k0, None if output_rate_hz is None else 1.0 / output_rate_hz)
    flags[out_k] |= FLAG_OUTPUT
    flags[grid_epochs(t, k0, node_interval_s)] |= FLAG_NODE
    flags[t.shape[0] - 1] |= FLAG_NODE
    flags[m_k[m_k >= k0]] |= FLAG_NODE
    flags[k0] |= FLAG_NODE
    return flags, out_k
