"""Statistics every flight has, for comparing a measured flight with its simulation.

Frames and units: body FRD, NED, SI inside. Every statistic is the mean of a per-record (or
per-sample) series over the flight, or an estimate of algorithm A with A's own 1-sigma; its
sigma is then (docs/compare_sim.md):

* batch means: the flight (from A's start) is cut into ``n_blocks`` equal time blocks, the
  series is averaged per block, and sigma = std(block means) / sqrt(n_blocks) (the block
  means of a stationary series with correlation much shorter than a block are independent);
* slow statistics (A's attitude offsets, A's bias wander) use 4 blocks and never a sigma
  below A's own typical 1-sigma, since A's errors are correlated over the whole flight;
* A's estimates (lever arm, scale factors, accelerometer bias trend) carry A's 1-sigma.

Statistics (name: series, unit)
-------------------------------
``gnss_pos_nis`` / ``gnss_vel_nis``
    Normalised innovation squared of the GNSS position / velocity records A used (3 dof;
    3 when A's model matches the data).
``gnss_pos_lag1`` / ``gnss_vel_lag1``
    Whiteness: z_k z_k-1 averaged over N and E, z the horizontal innovation divided by its
    flight RMS, for consecutive records (lag-1 autocorrelation; 0 for white innovations).
``gnss_vel_dot_accel``
    dz_v,h . a_h [m^2/s^3]: the horizontal velocity innovation (predicted minus measured)
    times A's smoothed acceleration at the record; a receiver stamping late by tau gives
    dz_v = tau a, so this is tau |a_h|^2 on average.
``imu_hf_accel_var`` / ``imu_hf_gyro_var``
    Mean over axes of the squared IMU sample minus its centred 1 s moving average
    [m^2/s^4], [rad^2/s^2]: white noise and vibration, the trajectory removed.
``att_offset_roll`` / ``_pitch`` / ``_yaw``
    A's smoothed roll, pitch, and yaw minus the track angle [rad] at speeds above
    ``min_speed_mps``, minus the zero of the simulation's attitude model (``aircraft``: the
    coordinated-turn bank; ``car``: level): what a mounting rotation shifts.
``a_gyro_bias_wander``
    Mean over axes of (b_g(t) - mean b_g)^2 of A's smoothed gyro bias [rad^2/s^2].
``a_accel_trend_x/y/z``
    Least-squares slope of A's smoothed accelerometer bias over time [m/s^3], sigma from A's
    bias sigma at the two ends.
``a_lever_x/y/z``, ``a_gyro_sf_x/y/z``, ``a_accel_sf_x/y/z``
    The final estimates of a forward pass of A with lever-arm and scale-factor states
    [m, -], with A's 1-sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter1d

from pospp import rotation
from pospp.nav.filter import FilterResult
from pospp.units import G0_MPS2

__all__ = ["FlightStats", "Stat", "STAT_UNITS", "flight_stats", "dominant_frequency_hz"]

N_BLOCKS = 10
"""Blocks of the batch-means sigma for fast statistics."""
N_BLOCKS_SLOW = 4
"""Blocks for slow statistics (attitude offsets, bias wander)."""

STAT_UNITS = {
    "gnss_pos_nis": "-", "gnss_vel_nis": "-", "gnss_pos_lag1": "-", "gnss_vel_lag1": "-",
    "gnss_vel_dot_accel": "m2/s3", "imu_hf_accel_var": "m2/s4", "imu_hf_gyro_var": "rad2/s2",
    "att_offset_roll": "rad", "att_offset_pitch": "rad", "att_offset_yaw": "rad",
    "a_gyro_bias_wander": "rad2/s2",
    **{f"a_accel_trend_{a}": "m/s3" for a in "xyz"},
    **{f"a_lever_{a}": "m" for a in "xyz"},
    **{f"a_gyro_sf_{a}": "-" for a in "xyz"},
    **{f"a_accel_sf_{a}": "-" for a in "xyz"},
}
"""Every statistic and its unit (SI)."""


@dataclass(frozen=True)
class Stat:
    """One statistic of one flight: value, 1-sigma, degrees of freedom of the sigma (inf for
    A's own sigma)."""

    value: float
    sigma: float
    dof: float


@dataclass(frozen=True)
class FlightStats:
    """The statistics of one flight (name -> Stat) and the IMU's dominant high-frequency
    line [Hz] (the vibration's aliased frequency, NaN when none)."""

    stats: dict[str, Stat]
    hf_peak_hz: float


def _batch(t: NDArray, x: NDArray, t0: float, t1: float, n_blocks: int,
           floor: float = 0.0) -> Stat:
    ok = np.isfinite(x) & (t >= t0) & (t <= t1)
    t, x = t[ok], x[ok]
    if x.size < 2 * n_blocks:
        return Stat(float(np.mean(x)) if x.size else np.nan, np.nan, 0.0)
    b = np.minimum(((t - t0) / (t1 - t0) * n_blocks).astype(int), n_blocks - 1)
    means = np.array([x[b == i].mean() for i in range(n_blocks) if np.any(b == i)])
    k = means.size
    sig = float(np.std(means, ddof=1) / np.sqrt(k)) if k > 1 else np.nan
    return Stat(float(x.mean()), max(sig, floor), float(k - 1))


def dominant_frequency_hz(x: NDArray, dt_s: float) -> float:
    """Frequency [Hz] of the largest line of the high-passed series' mean power spectrum
    (Welch, 4 s segments) above 1 Hz; NaN for short series."""
    from scipy.signal import welch

    if x.shape[0] < 8 / dt_s:
        return np.nan
    hp = x - uniform_filter1d(x, max(3, round(1.0 / dt_s)), axis=0, mode="nearest")
    f, p = welch(hp, fs=1.0 / dt_s, nperseg=min(hp.shape[0], round(4.0 / dt_s)), axis=0)
    p = p.sum(axis=1) if p.ndim > 1 else p
    m = f > 1.0
    return float(f[m][np.argmax(p[m])]) if m.any() else np.nan


def _innov(nav: FilterResult, kind: int) -> tuple[NDArray, NDArray, NDArray]:
    inn = nav.innovations
    m = (inn.kind == kind) & ((inn.status == 0) | (inn.status == 2)) & np.isfinite(inn.nis)
    return inn.t_s[m], inn.nis[m], inn.dz_ned[m]


def _lag1(t: NDArray, dz: NDArray) -> tuple[NDArray, NDArray]:
    if t.size < 3:
        return t[:0], t[:0]
    z = dz[:, :2] / np.sqrt(np.mean(dz[:, :2] ** 2, axis=0))
    dt = np.diff(t)
    ok = dt < 1.5 * np.median(dt)
    prod = np.mean(z[1:] * z[:-1], axis=1)
    return t[1:][ok], prod[ok]


def flight_stats(imu_time_s: NDArray, w_ib_b_radps: NDArray, f_ib_b_mps2: NDArray,
                 nav: FilterResult, nav_est: FilterResult | None, *,
                 vehicle: str = "car", min_speed_mps: float = 2.0,
                 n_blocks: int = N_BLOCKS) -> FlightStats:
    """Every statistic of the module docstring for one flight.

    Parameters
    ----------
    imu_time_s : (N,) IMU stamps [s] on A's time axis (``nav.forward.t_s``).
    w_ib_b_radps, f_ib_b_mps2 : (N, 3) body FRD IMU samples.
    nav : FilterResult
        A as configured (smoothed solution and biases, innovations).
    nav_est : FilterResult, optional
        A forward pass with lever-arm and scale-factor states (the ``a_lever``/``a_*_sf``
        statistics; left out when None).
    vehicle : {"car", "aircraft"}
        The simulation's attitude model (``att_offset``).
    """
    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    bias = nav.smoothed_biases if nav.smoothed_biases is not None else nav.forward_biases
    t0, t1 = float(sol.t_s[0]), float(sol.t_s[-1])
    out: dict[str, Stat] = {}
    # --- GNSS innovations ---------------------------------------------------------------------
    acc = np.gradient(sol.v_n_mps, sol.t_s, axis=0)
    for name, kind in (("pos", 0), ("vel", 1)):
        t, nis, dz = _innov(nav, kind)
        out[f"gnss_{name}_nis"] = _batch(t, nis, t0, t1, n_blocks)
        tl, pl = _lag1(t, dz)
        out[f"gnss_{name}_lag1"] = _batch(tl, pl, t0, t1, n_blocks)
        if name == "vel":
            a = np.stack([np.interp(t, sol.t_s, acc[:, i]) for i in range(2)], axis=1)
            out["gnss_vel_dot_accel"] = _batch(t, np.sum(dz[:, :2] * a, axis=1), t0, t1,
                                               n_blocks)
    # --- IMU high-frequency content ----------------------------------------------------------
    dt = float(np.median(np.diff(imu_time_s)))
    win = max(3, round(1.0 / dt) | 1)
    for name, x in (("accel", f_ib_b_mps2), ("gyro", w_ib_b_radps)):
        hp = x - uniform_filter1d(x, win, axis=0, mode="nearest")
        out[f"imu_hf_{name}_var"] = _batch(imu_time_s, np.mean(hp ** 2, axis=1), t0, t1,
                                           n_blocks)
    peak = dominant_frequency_hz(f_ib_b_mps2, dt)
    # --- A's attitude against the simulation's attitude model (mounting) --------------------
    rpy = rotation.euler_from_quat(sol.q_nb)
    v = sol.v_n_mps
    speed = np.hypot(v[:, 0], v[:, 1])
    track = np.arctan2(v[:, 1], v[:, 0])
    if vehicle == "aircraft":
        turn = np.gradient(np.unwrap(track), sol.t_s)
        roll0 = np.arctan(speed * turn / G0_MPS2)
    else:
        roll0 = np.zeros_like(speed)
    pitch0 = np.zeros_like(speed) if vehicle == "car" else np.arctan2(-v[:, 2], speed)
    mov = speed > min_speed_mps
    att_sig = np.median(sol.rpy_sigma_rad, axis=0) if len(sol.t_s) else np.full(3, np.nan)
    offs = (rpy[:, 0] - roll0, rpy[:, 1] - pitch0,
            np.angle(np.exp(1j * (rpy[:, 2] - track))))
    for i, name in enumerate(("roll", "pitch", "yaw")):
        x = np.where(mov, offs[i], np.nan)
        out[f"att_offset_{name}"] = _batch(sol.t_s, x, t0, t1, N_BLOCKS_SLOW,
                                           floor=float(att_sig[i]))
    # --- A's sensor-error estimates over time --------------------------------------------------
    bg = bias.gyro_b_radps
    out["a_gyro_bias_wander"] = _batch(
        bias.t_s, np.mean((bg - bg.mean(axis=0)) ** 2, axis=1), float(bias.t_s[0]),
        float(bias.t_s[-1]), N_BLOCKS_SLOW)
    tb = bias.t_s - bias.t_s.mean()
    span = float(bias.t_s[-1] - bias.t_s[0])
    for i, a in enumerate("xyz"):
        ba = bias.accel_b_mps2[:, i]
        slope = float(np.sum(tb * (ba - ba.mean())) / np.sum(tb ** 2)) if span > 0 else np.nan
        s_end = np.hypot(bias.accel_sigma_b_mps2[0, i], bias.accel_sigma_b_mps2[-1, i])
        out[f"a_accel_trend_{a}"] = Stat(slope, float(s_end / span) if span > 0 else np.nan,
                                         np.inf)
    if nav_est is not None:
        la = nav_est.lever_arm
        fb = nav_est.forward_biases
        for i, a in enumerate("xyz"):
            out[f"a_lever_{a}"] = Stat(float(la.lever_b_m[i]), float(la.sigma_b_m[i]), np.inf)
            out[f"a_gyro_sf_{a}"] = Stat(float(fb.gyro_sf[-1, i]), float(fb.gyro_sf_sigma[-1, i]),
                                         np.inf)
            out[f"a_accel_sf_{a}"] = Stat(float(fb.accel_sf[-1, i]),
                                          float(fb.accel_sf_sigma[-1, i]), np.inf)
    return FlightStats(out, peak)
