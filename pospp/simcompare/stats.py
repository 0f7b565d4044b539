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
``gnss_pos_gated``
    Share of the GNSS position records A's gate rejected (batch means; 1e-4 when A's model
    matches the data): it rises with a GNSS error several times its reported sigma, whose
    censored NIS (the gate drops the largest; the filter resets) does not.
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
    Least-squares slope of the accelerometer bias over time [m/s^3]: horizontal (x, y), of
    A's pass with lever-arm and scale-factor states, whose accelerometer biases carry loose
    Gauss-Markov states (``nav_est``; a horizontal bias shows only at the turns, between
    which A-as-configured's tight bias model hardly lets it move; :func:`trend`: sigma for
    residuals correlated as a first-order autoregression; a span of ``TREND_MIN_SPAN_S`` at
    least); vertical (and all three without that pass or on a shorter flight), of A's
    smoothed bias, sigma from A's bias sigma at the two ends.
``a_lever_x/y/z``, ``a_gyro_sf_x/y/z``, ``a_accel_sf_x/y/z``
    The final estimates of a forward pass of A with lever-arm and scale-factor states (and
    loose accelerometer Gauss-Markov states) [m, -], with A's 1-sigma.
``gnss_pos_norm_n/e/d``, ``gnss_vel_norm_n/e/d``
    Per channel, the innovation normalised by the record's reported sigma, squared:
    (dz_i / sigma_i)^2 (batch means; only when the reported sigmas are given).
``gnss_pos_lb_n/e/d``, ``gnss_vel_lb_n/e/d``
    Whiteness per channel, Ljung-Box: in each block, Q = n (n + 2) sum_k=1..h r_k^2 / (n - k)
    of the block's innovations (consecutive records, h = ``LB_LAGS``), divided by h; the
    mean over the blocks (batch means; at most ``n_blocks`` blocks, with at least
    ``LB_MIN_RECORDS_PER_LAG`` x h records each). For white innovations each block's Q is chi-square
    with h dof, so the statistic has mean 1 (Ljung and Box 1978).
``gnss_pos_lowband`` / ``gnss_vel_lowband``
    Spectrum of the innovations: per block and horizontal channel, the share of the
    periodogram's power (mean included) below a quarter of the record rate's Nyquist
    frequency, averaged over N and E and over the blocks. White innovations: 1/4.
``imu_avar_gyro_1s`` / ``_10s``, ``imu_avar_accel_1s`` / ``_10s``
    Allan variance of the IMU at 1 s and 10 s [rad^2/s^2, m^2/s^4], on its steady parts
    (static included): the stretches where A's smoothed acceleration is below
    ``STEADY_ACCEL_MPS2`` and its yaw rate below ``STEADY_RATE_RADPS``. Within each stretch
    the samples are averaged in consecutive clusters of tau, and each pair of neighbouring
    clusters gives (y_j+1 - y_j)^2 / 2 (mean over the axes); batch means of these (4 blocks
    at 10 s). White noise of variance s^2 per sample gives s^2 dt / tau.
``imu_avar_gyro_static``
    Allan variance of the gyros at ``STATIC_AVAR_TAU_S`` on the static parts only, where the
    trajectory adds nothing and a bias drift shows alone: white noise N^2 / tau, a
    Gauss-Markov drift of sigma s and correlation time T >> tau about (2 s^2 / T) tau / 3
    (its random-walk part). The static parts: A's initial static period (the alignment's,
    also before A's span when A aligned in motion after it; its last
    ``STATIC_END_MARGIN_S`` left out) and A's smoothed solution below ``STATIC_SPEED_MPS``.
    Products as ``imu_avar_*``; sigma = std(products) / sqrt(n) x sqrt(1.5) (neighbouring
    products of white noise share a cluster: correlation 1/4), n - 1 dof; only when the
    flight has at least ``STATIC_MIN_PRODUCTS`` products (a static start of about a minute).
``imu_band_accel_lo`` / ``_hi``, ``imu_band_gyro_lo`` / ``_hi``
    Spectrum of the high-passed IMU (as ``imu_hf_*``): per block, the Welch power of the
    mean over axes integrated over [1 Hz, f_s / 4) and [f_s / 4, f_s / 2] [m^2/s^4,
    rad^2/s^2]; batch means. A vibration line moves the band it falls in.
``a_gyro_trend_x/y/z``
    Least-squares slope of A's smoothed gyro bias [rad/s^2], sigma as ``a_accel_trend``.
``a_accel_bias_wander``
    Mean over axes of (b_a(t) - mean b_a)^2 of A's smoothed accelerometer bias [m^2/s^4]
    (as ``a_gyro_bias_wander``, 4 blocks).
``lt_time_offset``
    The GNSS stamp minus true time [s] of the joint estimate with the lever arm
    (:mod:`pospp.qc.lever_time`) on the measured flight, with its sigma; on a simulated
    flight the model's own offset (the estimate's expectation) with sigma 0. Only when the
    joint estimate determines the offset (a finite sigma). The GNSS time offset's most
    sensitive reading: A's lever-arm estimate sees it only as much as its forward pass
    converges (a 10 ms offset moved it by 0.1 of its 0.5 m on a 14 min flight).
``lt_lever_x/y/z``
    The lever arm minus the configured one [m] of the same joint estimate (at its offset, with
    the offset's uncertainty in its sigma; the apparent one where the offset is not
    determined), on the axes A's attitude history reveals; on a simulated flight the model's
    own (0 for the configured lever arm), sigma 0. A's lever-arm estimate alone (one forward
    pass) read 0.19 m of a 0.3 m error on the 14 min Monte Carlo flight.
``legs_bma_ms`` / ``legs_bma_heldout_ms``
    Only on flights with straight legs: B minus A on the legs, the leg-based workflow's own
    statistics (:class:`pospp.diagnose.workflow.LegGap`): per leg, the mean square of the
    horizontal velocity residual after the base calibration model, and of the
    leave-one-leg-out prediction error [m^2/s^2]; batch means over the legs
    (:func:`leg_stats`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter1d

from pospp import rotation
from pospp.nav.filter import (
    STATUS_GATED,
    STATUS_RESET,
    STATUS_USED,
    BiasHistory,
    FilterResult,
    NavSolution,
)
from pospp.units import G0_MPS2

__all__ = ["FlightStats", "Stat", "STAT_UNITS", "flight_stats", "dominant_frequency_hz",
           "ljung_box", "lowband_share", "allan_products", "steady_mask", "leg_stats",
           "static_and_steady"]

N_BLOCKS = 10
"""Blocks of the batch-means sigma for fast statistics."""
N_BLOCKS_SLOW = 4
"""Blocks for slow statistics (attitude offsets, bias wander)."""
LB_LAGS = 5
"""Lags h of the Ljung-Box whiteness statistics."""
LB_MIN_RECORDS_PER_LAG = 6
"""Ljung-Box blocks: as many as ``n_blocks``, but at least this many records per lag in each
(a 180 s flight at 1 Hz gets 6 blocks of 30 records)."""
STEADY_ACCEL_MPS2 = 0.5
"""A's smoothed acceleration below this (and its yaw rate below ``STEADY_RATE_RADPS``):
the steady parts of the flight where the IMU's Allan variance is taken."""
STEADY_RATE_RADPS = np.radians(3.0)
AVAR_TAUS_S = (1.0, 10.0)
"""Cluster times of the Allan-variance statistics [s]."""
STATIC_SPEED_MPS = 0.1
"""A's smoothed speed below this (and steady): static (as the alignment's static test)."""
STATIC_AVAR_TAU_S = 10.0
"""Cluster time of ``imu_avar_gyro_static`` [s]."""
STATIC_END_MARGIN_S = 20.0
"""The last seconds of A's initial static period are left out (the start of the motion)."""
STATIC_MIN_PRODUCTS = 5
"""``imu_avar_gyro_static`` needs at least this many Allan products (60 s static at 10 s)."""

STAT_UNITS = {
    "gnss_pos_nis": "-", "gnss_vel_nis": "-", "gnss_pos_lag1": "-", "gnss_vel_lag1": "-",
    "gnss_pos_gated": "-",
    "gnss_vel_dot_accel": "m2/s3", "imu_hf_accel_var": "m2/s4", "imu_hf_gyro_var": "rad2/s2",
    "att_offset_roll": "rad", "att_offset_pitch": "rad", "att_offset_yaw": "rad",
    "a_gyro_bias_wander": "rad2/s2",
    **{f"a_accel_trend_{a}": "m/s3" for a in "xyz"},
    **{f"a_lever_{a}": "m" for a in "xyz"},
    **{f"a_gyro_sf_{a}": "-" for a in "xyz"},
    **{f"a_accel_sf_{a}": "-" for a in "xyz"},
    **{f"gnss_{k}_norm_{a}": "-" for k in ("pos", "vel") for a in "ned"},
    **{f"gnss_{k}_lb_{a}": "-" for k in ("pos", "vel") for a in "ned"},
    "gnss_pos_lowband": "-", "gnss_vel_lowband": "-",
    "imu_avar_gyro_1s": "rad2/s2", "imu_avar_gyro_10s": "rad2/s2",
    "imu_avar_accel_1s": "m2/s4", "imu_avar_accel_10s": "m2/s4",
    "imu_avar_gyro_static": "rad2/s2",
    "imu_band_accel_lo": "m2/s4", "imu_band_accel_hi": "m2/s4",
    "imu_band_gyro_lo": "rad2/s2", "imu_band_gyro_hi": "rad2/s2",
    **{f"a_gyro_trend_{a}": "rad/s2" for a in "xyz"},
    "a_accel_bias_wander": "m2/s4",
    "legs_bma_ms": "m2/s2", "legs_bma_heldout_ms": "m2/s2",
    "lt_time_offset": "s",
    **{f"lt_lever_{a}": "m" for a in "xyz"},
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


def _from_blocks(values: Sequence[float | np.floating]) -> Stat:
    """Batch means of per-block values: mean, std / sqrt(k), k - 1 dof."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < 2:
        return Stat(float(v.mean()) if v.size else np.nan, np.nan, 0.0)
    return Stat(float(v.mean()), float(np.std(v, ddof=1) / np.sqrt(v.size)), float(v.size - 1))


def _block_of(t: NDArray, t0: float, t1: float, n_blocks: int) -> NDArray:
    return np.minimum(((t - t0) / (t1 - t0) * n_blocks).astype(int), n_blocks - 1)


def ljung_box(x: NDArray, t_s: NDArray, lags: int = LB_LAGS) -> float:
    """Ljung-Box Q / h of one series (Ljung and Box 1978).

    Q = n (n + 2) sum_{k=1..h} r_k^2 / (n - k), r_k = sum (x_i - xbar)(x_i+k - xbar) /
    sum (x_i - xbar)^2, summed over the pairs whose stamps are k record intervals apart
    (median interval, +- half of it: pairs across a gap are left out). For a white series
    Q is chi-square with h dof, so Q / h has mean 1 and variance 2 / h. NaN when n < 4 h.
    """
    n = x.size
    if n < 4 * lags:
        return np.nan
    y = x - x.mean()
    den = float(np.sum(y * y))
    if not den > 0:
        return np.nan
    dt = float(np.median(np.diff(t_s)))
    q = 0.0
    for k in range(1, lags + 1):
        ok = np.abs(t_s[k:] - t_s[:-k] - k * dt) < 0.5 * dt
        r = float(np.sum(y[k:][ok] * y[:-k][ok])) / den
        q += r * r / (n - k)
    return n * (n + 2) * q / lags


def lowband_share(x: NDArray) -> float:
    """Share of a series' one-sided periodogram power (mean included) at frequencies below a
    quarter of the Nyquist frequency (records taken as equally spaced); about 1/4 for a
    zero-mean white series. NaN for fewer than 8 samples."""
    from scipy.signal import periodogram

    if x.size < 8:
        return np.nan
    f, p = periodogram(x, detrend=False, scaling="spectrum")
    tot = float(p.sum())
    return float(p[f < 0.125].sum() / tot) if tot > 0 else np.nan


def steady_mask(sol_t_s: NDArray, v_n_mps: NDArray, yaw_rad: NDArray, t_s: NDArray, *,
                max_accel_mps2: float = STEADY_ACCEL_MPS2,
                max_rate_radps: float = STEADY_RATE_RADPS) -> NDArray:
    """True at the times ``t_s`` where A's smoothed acceleration |dv_n/dt| [m/s^2] and yaw
    rate |dpsi/dt| [rad/s] are below the limits (static and steady parts)."""
    if sol_t_s.size < 3:
        return np.zeros(t_s.shape, bool)
    acc = np.linalg.norm(np.gradient(v_n_mps, sol_t_s, axis=0), axis=1)
    rate = np.abs(np.gradient(np.unwrap(yaw_rad), sol_t_s))
    ok = ((acc < max_accel_mps2) & (rate < max_rate_radps)).astype(float)
    return np.interp(t_s, sol_t_s, ok, left=0.0, right=0.0) > 0.999


def static_and_steady(t_s: NDArray, sol: NavSolution, static_end_s: float | None
                      ) -> tuple[NDArray, NDArray]:
    """(static, steady) at the times ``t_s`` [s]: steady where A's smoothed acceleration and
    yaw rate are low (:func:`steady_mask`); static where steady and A's speed is below
    ``STATIC_SPEED_MPS``, or before A's initial static period ends (``static_end_s``, its
    last ``STATIC_END_MARGIN_S`` left out; also before A's span)."""
    rpy = rotation.euler_from_quat(sol.q_nb)
    steady = steady_mask(sol.t_s, sol.v_n_mps, rpy[:, 2], t_s)
    speed = np.linalg.norm(sol.v_n_mps, axis=1)
    still = steady & (np.interp(t_s, sol.t_s, speed) < STATIC_SPEED_MPS)
    if static_end_s is not None:
        still |= t_s < static_end_s - STATIC_END_MARGIN_S
    return still, steady


def allan_products(t_s: NDArray, x: NDArray, mask: NDArray, tau_s: float
                   ) -> tuple[NDArray, NDArray]:
    """Allan-variance products of a sampled signal on the stretches where ``mask`` holds.

    Each stretch (consecutive samples, no gap above 1.5 intervals) is cut into clusters of
    m = round(tau / dt) samples; neighbouring cluster means y_j give (y_j+1 - y_j)^2 / 2,
    averaged over the columns of ``x`` (N, K). Their mean is the Allan variance at tau
    (non-overlapping estimator). Returns the products and the times of the cluster
    boundaries [s].
    """
    if t_s.size < 3:
        return t_s[:0], t_s[:0]
    dt = float(np.median(np.diff(t_s)))
    m = max(1, round(tau_s / dt))
    brk = np.flatnonzero(~mask[1:] | ~mask[:-1] | (np.diff(t_s) > 1.5 * dt)) + 1
    starts = np.concatenate([[0], brk])
    ends = np.concatenate([brk, [t_s.size]])
    out_t, out_d = [], []
    for a, b in zip(starts, ends, strict=True):
        if not mask[a]:
            continue
        c = (b - a) // m
        if c < 2:
            continue
        y = x[a:a + c * m].reshape(c, m, -1).mean(axis=1)
        out_d.append(0.5 * np.mean(np.diff(y, axis=0) ** 2, axis=1))
        out_t.append(t_s[a + m * np.arange(1, c)])
    if not out_d:
        return t_s[:0], t_s[:0]
    return np.concatenate(out_t), np.concatenate(out_d)


def _band_blocks(t_s: NDArray, hp: NDArray, t0: float, t1: float, n_blocks: int,
                 dt_s: float) -> tuple[list[float], list[float]]:
    """Per block, the Welch power of the high-passed IMU (mean over axes) over [1 Hz, fs/4)
    and [fs/4, fs/2]."""
    from scipy.signal import welch

    b = _block_of(t_s, t0, t1, n_blocks)
    inside = (t_s >= t0) & (t_s <= t1)
    fs = 1.0 / dt_s
    lo, hi = [], []
    for i in range(n_blocks):
        x = hp[inside & (b == i)]
        if x.shape[0] < 8 / dt_s:
            continue
        f, p = welch(x, fs=fs, nperseg=min(x.shape[0], round(4.0 / dt_s)), axis=0)
        p = p.mean(axis=1)
        df = f[1] - f[0]
        lo.append(float(p[(f >= 1.0) & (f < fs / 4)].sum() * df))
        hi.append(float(p[f >= fs / 4].sum() * df))
    return lo, hi


def leg_stats(gap_mps: NDArray, heldout_gap_mps: NDArray) -> dict[str, Stat]:
    """``legs_bma_ms`` and ``legs_bma_heldout_ms`` from the per-leg residual RMS of B minus A
    after the base model and of its held-out prediction [m/s] (one value per leg; batch
    means over the legs, legs - 1 dof)."""
    return {"legs_bma_ms": _from_blocks(list(np.square(gap_mps))),
            "legs_bma_heldout_ms": _from_blocks(list(np.square(heldout_gap_mps)))}


def _nearest(ts: NDArray, t: NDArray) -> NDArray:
    """Index of the nearest element of the sorted ``ts`` to each ``t``."""
    if ts.size < 2:
        return np.zeros(t.shape, int)
    j = np.clip(np.searchsorted(ts, t), 1, ts.size - 1)
    return j - ((t - ts[j - 1]) < (ts[j] - t))


def _innov(nav: FilterResult, kind: int) -> tuple[NDArray, NDArray, NDArray]:
    inn = nav.innovations
    assert inn is not None  # the filter's result of a run with GNSS updates
    m = (inn.kind == kind) & ((inn.status == 0) | (inn.status == 2)) & np.isfinite(inn.nis)
    return inn.t_s[m], inn.nis[m], inn.dz_ned[m]


def _gated_share(nav: FilterResult, t0: float, t1: float, n_blocks: int) -> Stat:
    """``gnss_pos_gated``: per position record after the filter's start, 1 when gated, 0
    when used (or used after a reset); batch means."""
    inn = nav.innovations
    assert inn is not None  # the filter's result of a run with GNSS updates
    m = (inn.kind == 0) & np.isin(inn.status, (STATUS_USED, STATUS_GATED, STATUS_RESET))
    return _batch(inn.t_s[m], (inn.status[m] == STATUS_GATED).astype(float), t0, t1,
                  n_blocks)


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
                 n_blocks: int = N_BLOCKS,
                 gnss_sigma: dict[int, tuple[NDArray, NDArray]] | None = None
                 ) -> FlightStats:
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
    gnss_sigma : dict, optional
        Measurement kind (0 position, 1 velocity) -> (record times [s], (M, 3) reported NED
        sigmas [m, m/s]) for the ``gnss_*_norm_*`` statistics (left out when None).
    """
    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    bias = nav.smoothed_biases if nav.smoothed_biases is not None else nav.forward_biases
    t0, t1 = float(sol.t_s[0]), float(sol.t_s[-1])
    out: dict[str, Stat] = {}
    out.update(_innovation_stats(nav, sol, t0, t1, n_blocks, gnss_sigma))
    imu, peak = _imu_stats(imu_time_s, w_ib_b_radps, f_ib_b_mps2, sol, t0, t1, n_blocks,
                           nav.alignment.static_end_s)
    out.update(imu)
    out.update(_attitude_stats(sol, t0, t1, vehicle, min_speed_mps))
    out.update(_bias_stats(bias))
    if nav_est is not None:
        out.update(_estimate_stats(nav_est))
        fb = nav_est.forward_biases
        if fb.t_s[-1] - fb.t_s[0] >= TREND_MIN_SPAN_S:
            for i, a in enumerate("xy"):  # horizontal: seen at the turns only (docstring)
                out[f"a_accel_trend_{a}"] = trend(fb.t_s, fb.accel_b_mps2[:, i])
    return FlightStats(out, peak)


TREND_MIN_SPAN_S = 600.0
"""The estimate pass's horizontal accelerometer trends need a span of this many seconds: the
residuals' autoregression is read on too few samples below it (a 180 s car track with 0.1 m/s
of GNSS velocity noise read a slope 3.9 of its sigmas without a ramp); shorter, A's own."""
TREND_DECIMATE_S = 10.0
"""The bias series of :func:`trend` is taken every this many seconds (at 1 s the first-order
autoregression read the residuals' correlation shorter than it is: sigmas 20-40 % smaller on
the reference cases)."""


def trend(t_s: NDArray, x: NDArray) -> Stat:
    """Least-squares slope of ``x`` over ``t_s`` (its unit per s) with its standard error
    for residuals correlated as a first-order autoregression: sqrt(s_r^2 / sum (t - tbar)^2)
    x sqrt((1 + rho) / (1 - rho)), rho the residuals' lag-1 autocorrelation on the series
    taken every ``TREND_DECIMATE_S`` (normal: the series is long)."""
    dt = float(np.median(np.diff(t_s))) if t_s.size > 1 else 1.0
    k = max(1, round(TREND_DECIMATE_S / dt))
    t, y = t_s[::k], x[::k]
    if t.size < 10:
        return Stat(np.nan, np.nan, 0.0)
    tc = t - t.mean()
    slope = float(np.sum(tc * (y - y.mean())) / np.sum(tc ** 2))
    r = y - y.mean() - slope * tc
    rho = min(float(np.sum(r[1:] * r[:-1]) / max(np.sum(r * r), 1e-300)), 0.9999)
    se = float(np.sqrt(np.mean(r * r) / np.sum(tc ** 2) * (1.0 + rho) / (1.0 - rho)))
    return Stat(slope, se, np.inf)


def _innovation_stats(nav: FilterResult, sol: NavSolution, t0: float, t1: float,
                      n_blocks: int, gnss_sigma: dict[int, tuple[NDArray, NDArray]] | None
                      ) -> dict[str, Stat]:
    """A's GNSS innovations: NIS, lag-1 products, velocity x acceleration, normalised per
    channel, Ljung-Box per channel, low-band share (module docstring)."""
    out: dict[str, Stat] = {}
    acc = np.gradient(sol.v_n_mps, sol.t_s, axis=0)
    out["gnss_pos_gated"] = _gated_share(nav, t0, t1, n_blocks)
    for name, kind in (("pos", 0), ("vel", 1)):
        t, nis, dz = _innov(nav, kind)
        out[f"gnss_{name}_nis"] = _batch(t, nis, t0, t1, n_blocks)
        tl, pl = _lag1(t, dz)
        out[f"gnss_{name}_lag1"] = _batch(tl, pl, t0, t1, n_blocks)
        if name == "vel":
            acc_ne = np.stack([np.interp(t, sol.t_s, acc[:, i]) for i in range(2)], axis=1)
            out["gnss_vel_dot_accel"] = _batch(t, np.sum(dz[:, :2] * acc_ne, axis=1), t0, t1,
                                               n_blocks)
        if gnss_sigma is not None and kind in gnss_sigma and t.size:
            ts, sg = gnss_sigma[kind]
            j = _nearest(ts, t)
            zn = dz / np.where(sg[j] > 0, sg[j], np.nan)
            for i, a in enumerate("ned"):
                out[f"gnss_{name}_norm_{a}"] = _batch(t, zn[:, i] ** 2, t0, t1, n_blocks)
        nb = min(n_blocks, t.size // (LB_MIN_RECORDS_PER_LAG * LB_LAGS))
        bl = _block_of(t, t0, t1, max(nb, 1))
        for i, a in enumerate("ned"):
            out[f"gnss_{name}_lb_{a}"] = _from_blocks(
                [ljung_box(dz[bl == b, i], t[bl == b]) for b in range(nb)])
        bl = _block_of(t, t0, t1, n_blocks)
        out[f"gnss_{name}_lowband"] = _from_blocks(
            [np.mean([lowband_share(dz[bl == b, i]) for i in range(2)])
             for b in range(n_blocks)])
    return out


def _imu_stats(imu_time_s: NDArray, w_ib_b_radps: NDArray, f_ib_b_mps2: NDArray,
               sol: NavSolution, t0: float, t1: float, n_blocks: int,
               static_end_s: float | None = None) -> tuple[dict[str, Stat], float]:
    """The IMU's high-frequency content, band powers and Allan variance on steady parts, and
    the dominant vibration frequency [Hz]."""
    out: dict[str, Stat] = {}
    dt = float(np.median(np.diff(imu_time_s)))
    win = max(3, round(1.0 / dt) | 1)
    still, steady = static_and_steady(imu_time_s, sol, static_end_s)
    for name, x in (("accel", f_ib_b_mps2), ("gyro", w_ib_b_radps)):
        hp = x - uniform_filter1d(x, win, axis=0, mode="nearest")
        out[f"imu_hf_{name}_var"] = _batch(imu_time_s, np.mean(hp ** 2, axis=1), t0, t1,
                                           n_blocks)
        lo, hi = _band_blocks(imu_time_s, hp, t0, t1, n_blocks, dt)
        out[f"imu_band_{name}_lo"] = _from_blocks(lo)
        out[f"imu_band_{name}_hi"] = _from_blocks(hi)
        for tau in AVAR_TAUS_S:
            ta, da = allan_products(imu_time_s, x, steady, tau)
            out[f"imu_avar_{name}_{tau:.0f}s"] = _batch(
                ta, da, t0, t1, n_blocks if tau < 5.0 else N_BLOCKS_SLOW)
    _, ds = allan_products(imu_time_s, w_ib_b_radps, still, STATIC_AVAR_TAU_S)
    if ds.size >= STATIC_MIN_PRODUCTS:
        out["imu_avar_gyro_static"] = Stat(float(ds.mean()), float(
            np.std(ds, ddof=1) / np.sqrt(ds.size) * np.sqrt(1.5)), float(ds.size - 1))
    peak = dominant_frequency_hz(f_ib_b_mps2, dt)
    return out, peak


def _attitude_stats(sol: NavSolution, t0: float, t1: float, vehicle: str,
                    min_speed_mps: float) -> dict[str, Stat]:
    """A's attitude against the simulation's attitude model (the mounting statistics)."""
    out: dict[str, Stat] = {}
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
    return out


def _bias_stats(bias: BiasHistory) -> dict[str, Stat]:
    """A's sensor-error estimates over time: wander and trend per axis."""
    out: dict[str, Stat] = {}
    bg = bias.gyro_b_radps
    out["a_gyro_bias_wander"] = _batch(
        bias.t_s, np.mean((bg - bg.mean(axis=0)) ** 2, axis=1), float(bias.t_s[0]),
        float(bias.t_s[-1]), N_BLOCKS_SLOW)
    ba_ = bias.accel_b_mps2
    out["a_accel_bias_wander"] = _batch(
        bias.t_s, np.mean((ba_ - ba_.mean(axis=0)) ** 2, axis=1), float(bias.t_s[0]),
        float(bias.t_s[-1]), N_BLOCKS_SLOW)
    tb = bias.t_s - bias.t_s.mean()
    span = float(bias.t_s[-1] - bias.t_s[0])
    for kind, b, sb in (("accel", bias.accel_b_mps2, bias.accel_sigma_b_mps2),
                        ("gyro", bias.gyro_b_radps, bias.gyro_sigma_b_radps)):
        for i, a in enumerate("xyz"):
            bi = b[:, i]
            slope = (float(np.sum(tb * (bi - bi.mean())) / np.sum(tb ** 2)) if span > 0
                     else np.nan)
            s_end = np.hypot(sb[0, i], sb[-1, i])
            out[f"a_{kind}_trend_{a}"] = Stat(slope, float(s_end / span) if span > 0
                                              else np.nan, np.inf)
    return out


def _estimate_stats(nav_est: FilterResult) -> dict[str, Stat]:
    """Lever arm and scale factors of A's forward pass with those states."""
    out: dict[str, Stat] = {}
    la = nav_est.lever_arm
    fb = nav_est.forward_biases
    for i, a in enumerate("xyz"):
        out[f"a_lever_{a}"] = Stat(float(la.lever_b_m[i]), float(la.sigma_b_m[i]), np.inf)
        out[f"a_gyro_sf_{a}"] = Stat(float(fb.gyro_sf[-1, i]), float(fb.gyro_sf_sigma[-1, i]),
                                     np.inf)
        out[f"a_accel_sf_{a}"] = Stat(float(fb.accel_sf[-1, i]),
                                      float(fb.accel_sf_sigma[-1, i]), np.inf)
    return out
