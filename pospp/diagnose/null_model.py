"""Null realisations of B minus A, made by pospp itself along the flight.

The noise of B minus A is not B's IMU noise plus an independent A error: A integrates the same
increments as B between GNSS fixes, and its GNSS corrections drive what is left. Rather than
modelling that process in closed form, the workflow's statistics are calibrated against null
realisations of it made with pospp's own A (a parametric bootstrap by perturbation):

1. The base: the flight's log with its GNSS fixes and velocities replaced by A's own solution
   at the antenna (:func:`gnss_on_solution`); the IMU is the flight's. Noise added on top of
   the flight's own GNSS noise is noise at 1.4 times the level A is tuned for, and A's
   response to it is not linear (its gate and resets): the null statistics then collapse.
2. Add to the base, from A's alignment point on (the alignment is a decision, not a
   response), white gyro and accelerometer noise at the density read from the samples
   (:attr:`pospp.types.ImuSamples.white_noise`) or the grade's, the Gauss-Markov gyro drift the
   calibration estimated on the flight (level and tau by REML, the grade a weak prior; the
   configured one when it did not) and the configured accelerometer drift
   (:func:`gauss_markov_path`), and GNSS white noise at the level of
   the flight's GNSS minus A (:func:`gnss_noise_from_residuals`).
3. Run A on the perturbed log exactly as on the flight (same configuration) and replay B on the
   SAME legs (same start and end times). The realisation is the perturbed B minus A less the
   base's::

       d_r(t) = (B - A)[base + noise_r](t) - (B - A)[base](t)

   Everything the flight holds (biases, misalignment, effects in and outside the library)
   cancels to first order, and d_r is a draw of B minus A's response to the noise, with the
   flight's own trajectory, GNSS rate, stamps and gaps, A's own gains and the legs' coupling
   through A.

The workflow (:func:`pospp.diagnose.workflow.diagnose_replays`, ``null_dv``) computes each
statistic it uses (lack-of-fit F, each candidate's nested F) on the R realisations with the same
design (the whitening re-estimated on each), and turns the flight's statistic into a p-value by
the predictive Student t of log F (:func:`calibrated_p_value`). The calibration re-runs its
least squares on each (:func:`pospp.calib.null_covariance.with_null_covariance`) for its covariance.

Assumed: the injected levels are the flight's (a drift the null carries and the data do not
hold makes it conservative, one they hold and the null lacks makes it cry wolf; a drift slower
than the flight is invisible to the estimate and absorbed by the fitted bias), and A is
linear over the noise's size around the base. Checked against an oracle (the same flight
simulated anew) and by the null Monte Carlo: docs/diagnose.md, "The null, third
version".

No I/O. SI units.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pospp.calib.linear_null import NullNoise
from pospp.distributions import f_sf, t_sf
from pospp.earth import principal_radii_m
from pospp.nav.events import sensor_poses
from pospp.nav.solution import NavSolution

POSITION_KIND, VELOCITY_KIND = 0, 1
"""Indices into ``pospp.nav.filter.MEAS_KINDS`` ("position", "velocity")."""


def gnss_noise_from_residuals(log: Any, base: Any) -> tuple[NDArray, NDArray]:
    """GNSS position and velocity white-noise sigma per NED axis: the flight's GNSS minus A.

    ``base`` is :func:`gnss_on_solution` of ``log`` (A's smoothed solution at the antenna at
    every GNSS stamp). The residual of a record is measured minus smoothed; its variance is
    ``R - H P_s H^T`` (the smoother's own error is correlated with the measurement), slightly
    below R, where A's innovations (``R + H P^- H^T``) read above it. Measured on pospp's
    simulator (1-10 Hz, 2-15 cm): residuals within 1-4 % of the true sigma, innovations
    5-14 % above it; the null's statistics move by about 1.5 times the level's error, so the
    residual is the estimator. Records outside A's span (unchanged in ``base``) and records
    beyond 5 robust sigmas (a jump A gated) are left out::

        sigma_k = sqrt(mean(r_k^2)),  |r_k| <= 5 * 1.4826 MAD(r_k)

    Returns
    -------
    pos_sigma_ned_m, vel_sigma_ned_mps : ndarray, shape (3,)
    """
    fix, fix0 = log.fix, base.fix
    rm, rn = principal_radii_m(fix.lat_rad)
    dp = np.column_stack([(fix.lat_rad - fix0.lat_rad) * (rm + fix.height_m),
                          (fix.lon_rad - fix0.lon_rad) * (rn + fix.height_m)
                          * np.cos(fix.lat_rad), -(fix.height_m - fix0.height_m)])
    inside_p = np.any(dp != 0.0, axis=1)
    dv = np.asarray(log.vel.v_n_mps, dtype=float) - np.asarray(base.vel.v_n_mps, dtype=float)
    inside_v = np.any(dv != 0.0, axis=1)
    return _robust_rms(dp[inside_p]), _robust_rms(dv[inside_v])


def _robust_rms(r: NDArray) -> NDArray:
    """Per column, the RMS of the values within 5 robust sigmas of 0 (zeros: no rows)."""
    r = r[np.all(np.isfinite(r), axis=1)]
    if r.shape[0] < 3:
        return np.zeros(r.shape[1])
    mad = 1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0)
    keep = np.abs(r) <= 5.0 * np.where(mad > 0, mad, np.inf)
    return np.array([np.sqrt(np.mean(r[keep[:, k], k] ** 2)) if keep[:, k].any() else 0.0
                     for k in range(r.shape[1])])


def perturb_log(log: Any, noise: NullNoise, rng: np.random.Generator,
                from_time_ns: int | None = None) -> Any:
    """The flight log with white IMU and GNSS noise added (one null realisation's input).

    IMU: samples are mean rates / specific forces over the interval dt ending at the stamp, so
    white noise of ARW has sigma ``ARW / sqrt(dt)`` per sample (likewise the VRW); a
    Gauss-Markov gyro drift and accelerometer bias (:func:`gauss_markov_path`'s draws and
    arithmetic) are added when given; each IMU channel in one compiled pass
    (:func:`_noisy_rates`), its draws freed before the next channel's are made. GNSS: NED
    position noise enters latitude / longitude through the principal radii
    (``dlat = dN / (M + h)``, ``dlon = dE / ((N + h) cos lat)``), height ``- dD``. The draws
    from ``rng``, in order: gyro white (N, 3), gyro Gauss-Markov path (N, 3) and start (3,),
    the same for the accelerometer, fixes (M, 3), velocities (V, 3).

    Parameters
    ----------
    log : pospp.io.mcap_reader.FlightLog (or any frozen dataclass with ``imu``, ``fix``, ``vel``)
    noise : NullNoise
    rng : numpy.random.Generator
    from_time_ns : int, optional
        Only records stamped at or after this time get noise (the flight's alignment point:
        A's alignment then starts where the flight's did; its start time is a decision, not a
        linear response to the noise). A motion alignment, which ends at that point, sees the
        flight's own data; a static one starts there and levels and gyrocompasses over the
        static data after it, noise included: its heading moves with the draw (0.01-0.33 deg
        on the sample flight, whose gyrocompass sigma is 5 deg; measured 2026-11-26).

    Returns
    -------
    Same type as ``log``, with ``imu``, ``fix``, ``vel`` replaced.
    """
    imu, fix, vel = log.imu, log.fix, log.vel
    t = np.asarray(imu.time_ns, dtype=np.int64)
    dt = np.diff(t) * 1e-9
    dt = np.concatenate([dt[:1], dt]) if dt.size else np.ones(1)
    dt = np.clip(dt, np.median(dt) * 0.1, None)
    t0 = np.iinfo(np.int64).min if from_time_ns is None else int(from_time_ns)

    def on(time_ns: NDArray) -> NDArray:
        return (np.asarray(time_ns, dtype=np.int64) >= t0)[:, None]

    def noisy(rate: NDArray, level: float, sigma: float, tau_s: float) -> NDArray:
        rate = np.asarray(rate, dtype=float)
        white = rng.standard_normal(rate.shape)
        a = q = np.zeros(0)
        g0, path = np.zeros(3), np.zeros((0, 3))
        if sigma > 0 and np.isfinite(tau_s):
            a = np.exp(-dt / tau_s)
            q = sigma * np.sqrt(1.0 - a**2)
            path = rng.standard_normal((dt.size, 3))
            g0 = rng.standard_normal(3) * sigma
        return _noisy_rates(rate, white, level / np.sqrt(dt), path, a, q, g0, t >= t0)

    w = noisy(imu.w_ib_b_radps, noise.gyro_arw_radpsqrts, noise.gyro_gm_sigma_radps,
              noise.gyro_gm_tau_s)
    f = noisy(imu.f_ib_b_mps2, noise.accel_vrw_mpspsqrts, noise.accel_gm_sigma_mps2,
              noise.accel_gm_tau_s)
    e_pos = rng.standard_normal((len(fix.time_ns), 3)) * np.asarray(
        noise.pos_sigma_ned_m) * on(fix.time_ns)
    rm, rn = principal_radii_m(fix.lat_rad)
    lat = fix.lat_rad + e_pos[:, 0] / (rm + fix.height_m)
    lon = fix.lon_rad + e_pos[:, 1] / ((rn + fix.height_m) * np.cos(fix.lat_rad))
    h = fix.height_m - e_pos[:, 2]
    v = vel.v_n_mps + rng.standard_normal(vel.v_n_mps.shape) * np.asarray(
        noise.vel_sigma_ned_mps) * on(vel.time_ns)
    return replace(log, imu=replace(imu, w_ib_b_radps=w, f_ib_b_mps2=f),
                   fix=replace(fix, lat_rad=lat, lon_rad=lon, height_m=h),
                   vel=replace(vel, v_n_mps=v))


@njit(cache=True, nogil=True)
def _noisy_rates(rate, white, white_sigma, path, a, q, g0, mask):
    """``rate + mask * (white * white_sigma + x)`` per sample and axis, x the Gauss-Markov
    path ``x_0 = g0``, ``x_k = a_k x_k-1 + q_k path_k`` (none when ``path`` is empty): the
    arithmetic of :func:`gauss_markov_path` and the white noise in one pass."""
    out = np.empty_like(rate)
    x = g0.copy()
    with_gm = path.shape[0] > 0
    for k in range(rate.shape[0]):
        for j in range(rate.shape[1]):
            e = white[k, j] * white_sigma[k]
            if with_gm:
                if k > 0:
                    x[j] = a[k] * x[j] + path[k, j] * q[k]
                e = e + x[j]
            out[k, j] = rate[k, j] + e * (1.0 if mask[k] else 0.0)
    return out


_GROUPS = 16384
"""Groups of samples :func:`decimate_imu` sums at once."""


def decimate_imu(log: Any, factor: int, keep_time_ns: NDArray | None = None) -> Any:
    """The log with its IMU samples summed in groups of ``factor`` (the null's lower rate).

    The samples kept end at the flight's stamps with indices ``0, factor, 2 factor, ...``
    and at the stamps in ``keep_time_ns`` (the legs' first and last epochs: B then starts and
    ends where the flight's B did, on the same sample grid); each holds the mean rate and
    specific force over the interval since the previous one kept, ``sum_j w_j dt_j /
    sum_j dt_j`` over the flight's samples j in it, so the increments (``w dt``) are the
    flight's summed exactly, gaps included. The first sample is kept as it is; samples after
    the last one kept are dropped. ``factor`` 1: the log itself.
    """
    if factor <= 1:
        return log
    imu = log.imu
    t = np.asarray(imu.time_ns, dtype=np.int64)
    kept = np.zeros(t.size, dtype=bool)
    kept[::factor] = True
    if keep_time_ns is not None and np.size(keep_time_ns):
        at = np.searchsorted(t, np.asarray(keep_time_ns, dtype=np.int64))
        kept[at[at < t.size]] = True
    keep = np.flatnonzero(kept)

    def mean_over_groups(rate: NDArray) -> NDArray:
        out = np.empty((keep.size, 3))
        out[0] = rate[0]
        # _GROUPS groups at a time (the increments of every sample are an (N, 3) array)
        for i0 in range(0, keep.size - 1, _GROUPS):
            i1 = min(i0 + _GROUPS, keep.size - 1)
            a, b = keep[i0], keep[i1]
            # the increment of each interval (t[j-1], t[j]] of the groups' samples
            inc = np.asarray(rate)[a + 1:b + 1] * (np.diff(t[a:b + 1]).astype(float)
                                                   * 1e-9)[:, None]
            out[i0 + 1:i1 + 1] = np.add.reduceat(inc, keep[i0:i1] - a, axis=0) / (
                (t[keep[i0 + 1:i1 + 1]] - t[keep[i0:i1]]) * 1e-9)[:, None]
        return out

    return replace(log, imu=replace(imu, time_ns=t[keep],
                                    w_ib_b_radps=mean_over_groups(imu.w_ib_b_radps),
                                    f_ib_b_mps2=mean_over_groups(imu.f_ib_b_mps2)))


def gnss_on_solution(log: Any, solution: NavSolution, epoch_ns: int, lever_b_m: NDArray) -> Any:
    """The flight log with its GNSS replaced by A's solution at the antenna (the null's base).

    Each fix becomes A's position moved to the antenna at the fix's stamp, each GNSS velocity
    A's antenna velocity (``v + C_nb (w_nb^b x l_b)``) at its stamp
    (:func:`pospp.nav.events.sensor_poses`); stamps, covariances and the IMU are kept.
    Records outside the solution's span keep their measured values.

    Why: the null realisations add GNSS noise to this base, not to the flight's own fixes.
    Noise added on top of the flight's noise is noise at 1.4 times the level A is tuned for,
    and A's response to it is no longer linear (its innovation gate, the covariance resets):
    the null F statistics then collapse (docs/diagnose.md, "The null's base").

    Parameters
    ----------
    log : FlightLog (or a frozen dataclass with ``imu``, ``fix``, ``vel``)
    solution : NavSolution
        A's solution (smoothed when there is one); t_s from ``epoch_ns``.
    epoch_ns : int
        The run's time origin (the first IMU stamp) [ns].
    lever_b_m : ndarray, shape (3,)
        Antenna position in the body frame FRD [m] (configured or estimated).
    """
    fix, vel = log.fix, log.vel
    pf = sensor_poses(solution, (np.asarray(fix.time_ns, dtype=np.int64) - epoch_ns) * 1e-9,
                      lever_b_m=lever_b_m)
    pv = sensor_poses(solution, (np.asarray(vel.time_ns, dtype=np.int64) - epoch_ns) * 1e-9,
                      lever_b_m=lever_b_m)
    return replace(log,
                   fix=replace(fix, lat_rad=np.where(pf.inside, pf.lat_rad, fix.lat_rad),
                               lon_rad=np.where(pf.inside, pf.lon_rad, fix.lon_rad),
                               height_m=np.where(pf.inside, pf.height_m, fix.height_m)),
                   vel=replace(vel, v_n_mps=np.where(pv.inside[:, None], pv.v_n_mps,
                                                     vel.v_n_mps)))


def gauss_markov_path(dt_s: NDArray, sigma: float, tau_s: float, rng: np.random.Generator
                      ) -> NDArray:
    """Three independent first-order Gauss-Markov paths, stationary start, shape (N, 3).

    Exact discretisation: ``x_k = e^(-dt_k / tau) x_k-1 + sigma sqrt(1 - e^(-2 dt_k / tau)) n_k``
    with ``x_0 = sigma n_0`` (varying steps: the decay and the increment's sigma per step).
    """
    dt = np.asarray(dt_s, dtype=float)
    a = np.exp(-dt / tau_s)
    q = sigma * np.sqrt(1.0 - a**2)
    e = rng.standard_normal((dt.size, 3)) * q[:, None]
    e[0] = rng.standard_normal(3) * sigma
    return _first_order_recursion(a, e)


@njit(cache=True, nogil=True)
def _first_order_recursion(a: NDArray, e: NDArray) -> NDArray:
    """``x_0 = e_0``, ``x_k = a_k x_k-1 + e_k`` per column."""
    x = np.empty_like(e)
    x[0] = e[0]
    for k in range(1, e.shape[0]):
        for j in range(e.shape[1]):
            x[k, j] = a[k] * x[k - 1, j] + e[k, j]
    return x


def calibrated_p_value(statistic: float, null_statistics: NDArray) -> float:
    """p-value of a statistic against its R null realisations: the predictive Student t of
    log F.

    The log of each null statistic is taken as a normal draw of unknown mean and variance,
    both estimated from the R draws (mean m, standard deviation s); a new draw from the same
    distribution then follows the predictive Student t with R - 1 degrees of freedom::

        t = (log F - m) / (s sqrt(1 + 1 / R)),   p = P(T_(R-1) > t)

    The unknown mean and variance are integrated out: with few realisations (R = 6-10) the
    tail widens to what R draws can pin down, where a fitted distribution used as if known
    reads too liberal (measured on the simulated null Monte Carlo: docs/diagnose.md). The
    log-normal shape has a heavier right tail than the log of a scaled chi-square, which
    suits the null statistics of drift-dominated flights (spread over two decades).
    A NaN statistic gives p = 1; fewer than 3 finite positive null statistics give NaN (not
    calibrated: the caller keeps the nominal p).
    """
    if not np.isfinite(statistic):
        return 1.0
    s = np.asarray(null_statistics, dtype=float)
    s = s[np.isfinite(s) & (s > 0)]
    if s.size < 3:
        return float("nan")
    if not statistic > 0:
        return 1.0
    lg = np.log(s)
    m, sd = float(np.mean(lg)), float(np.std(lg, ddof=1))
    if sd <= 0:
        return 0.0 if statistic > float(np.exp(m)) else 1.0
    t = (np.log(statistic) - m) / (sd * np.sqrt(1.0 + 1.0 / s.size))
    return t_sf(t, s.size - 1)


def few_parameter_p_value(statistic: float, null_statistics: NDArray) -> float:
    """p-value of a nested F of few parameters against its R null realisations: the
    predictive F(1, R) of the statistic over the null statistics' mean.

    The F's numerator is a Gaussian quadratic form of the noise (the RSS the r parameters take
    out), ``sum_j lambda_j chi2_1``; with the whitening re-estimated on each realisation the
    denominator is close to 1. For r = 1 the statistic is ``c chi2_1`` (the square of the
    noise's projection on the candidate, of variance c, mean zero by construction of the
    perturbation); c is estimated by the mean of the R null statistics (R degrees of
    freedom), so that the statistic over that mean follows F(1, R) exactly (the predictive
    Student t of the projection). For r > 1 the same rule is conservative: for a given mean,
    ``sum_j lambda_j chi2_1`` has the heaviest right tail when one lambda carries it all,
    and its mean is pinned by R r degrees of freedom, not R.

    Why not :func:`calibrated_p_value` here: the log of a chi-square of one degree of freedom
    has a long left tail (null statistics spread over three decades: 0.1 to 140 on a
    paper_vehicle flight), so a log-normal fitted to R of them has an inflated spread and a
    right tail far too heavy: a 12 ms GNSS offset at F = 17800, 127 times the largest of six
    null statistics, read p = 0.016 against a 0.01 bar (docs/diagnose.md, "Power"). The many-
    parameter lack-of-fit statistics keep the log-normal predictive. A NaN statistic gives
    p = 1; fewer than 3 finite positive null statistics give NaN (not calibrated).
    """
    if not np.isfinite(statistic):
        return 1.0
    s = np.asarray(null_statistics, dtype=float)
    s = s[np.isfinite(s) & (s >= 0)]
    if s.size < 3 or not np.mean(s) > 0:
        return float("nan")
    if not statistic > 0:
        return 1.0
    return f_sf(statistic / float(np.mean(s)), 1, s.size)
