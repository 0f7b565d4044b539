"""Null realisations of B minus A, made by pospp itself along the flight (issue 12).

The noise of B minus A is not B's IMU noise plus an independent A error: A integrates the same
increments as B between GNSS fixes, and its GNSS corrections drive what is left. Rather than
modelling that process in closed form, the workflow's statistics are calibrated against null
realisations of it made with pospp's own A (a parametric bootstrap by perturbation):

1. Add to the flight's own IMU samples white gyro and accelerometer noise at the configured
   grade's angle / velocity random walk, and to its GNSS fixes and velocities white noise at
   the level A's own innovations show (:func:`gnss_noise_from_innovations`).
2. Run A on the perturbed log exactly as on the flight (same configuration) and replay B on the
   SAME legs (same start and end times).
3. The realisation is the perturbed B minus A less the flight's B minus A::

       d_r(t) = (B - A)[log + noise_r](t) - (B - A)[log](t)

   To first order in the noise, everything the flight holds (biases, misalignment, effects in
   and outside the library) cancels and d_r is a draw of B minus A's noise response to the
   injected noise, with the flight's own trajectory, GNSS rate, stamps and gaps, A's own gains
   and the legs' coupling through A.

The workflow (:func:`pospp.diagnose.workflow.diagnose`, ``null_dv``) computes each statistic it
uses (lack-of-fit F, each candidate's nested F) on the R realisations with the same design and
whitening, and turns the flight's statistic into a p-value with the null distribution fitted by
moments (:func:`calibrated_p_value`).

Assumed: the injected noise levels are the flight's (grade ARW / VRW as configured; GNSS from
the innovations, which also carry A's predicted error, so they read high: conservative), the
noise is white (no in-run drift: the grade's Gauss-Markov drift is not injected by default),
and A is linear enough over the noise's size that the difference is the noise response.

No I/O. SI units.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, special, stats

from pospp.earth import principal_radii_m

POSITION_KIND, VELOCITY_KIND = 0, 1
"""Indices into ``pospp.nav.filter.MEAS_KINDS`` ("position", "velocity")."""


@dataclass(frozen=True)
class NullNoise:
    """White noise levels injected into one null realisation.

    Attributes
    ----------
    gyro_arw_radpsqrts : float
        Gyro angle random walk [rad/s^0.5] (rate noise sigma = ARW / sqrt(dt)).
    accel_vrw_mpspsqrts : float
        Accelerometer velocity random walk [m/s / s^0.5].
    pos_sigma_ned_m : ndarray, shape (3,)
        GNSS position noise, NED [m].
    vel_sigma_ned_mps : ndarray, shape (3,)
        GNSS velocity noise, NED [m/s].
    gyro_gm_sigma_radps, gyro_gm_tau_s : float
        First-order Gauss-Markov gyro drift per axis (steady-state sigma [rad/s], correlation
        time [s]); 0 / inf: none.
    """

    gyro_arw_radpsqrts: float
    accel_vrw_mpspsqrts: float
    pos_sigma_ned_m: NDArray
    vel_sigma_ned_mps: NDArray
    gyro_gm_sigma_radps: float = 0.0
    gyro_gm_tau_s: float = float("inf")


def gnss_noise_from_innovations(t_s: NDArray, kind: NDArray, status: NDArray, dz_ned: NDArray
                                ) -> tuple[NDArray, NDArray]:
    """GNSS position and velocity noise per NED axis from A's innovations.

    The RMS innovation of the used records (``status`` 0), per axis::

        sigma_k = sqrt(mean(dz_k^2)),   dz = predicted - measured

    Its variance is ``H P H^T + R``: A's predicted error is included, so the level reads high
    (a conservative null). Without records of a kind its sigma is 0.

    Parameters
    ----------
    t_s, kind, status, dz_ned : arrays of :class:`pospp.nav.filter.InnovationRecord`

    Returns
    -------
    pos_sigma_ned_m, vel_sigma_ned_mps : ndarray, shape (3,)
    """
    del t_s
    out = []
    for k in (POSITION_KIND, VELOCITY_KIND):
        m = (np.asarray(kind) == k) & (np.asarray(status) == 0)
        dz = np.asarray(dz_ned, dtype=float)[m]
        dz = dz[np.all(np.isfinite(dz), axis=1)]
        out.append(np.sqrt(np.mean(dz**2, axis=0)) if dz.size else np.zeros(3))
    return out[0], out[1]


def perturb_log(log: Any, noise: NullNoise, rng: np.random.Generator) -> Any:
    """The flight log with white IMU and GNSS noise added (one null realisation's input).

    IMU: samples are mean rates / specific forces over the interval dt ending at the stamp, so
    white noise of ARW has sigma ``ARW / sqrt(dt)`` per sample (likewise the VRW); a
    Gauss-Markov gyro drift (:func:`gauss_markov_path`) is added when given. GNSS: NED
    position noise enters latitude / longitude through the principal radii
    (``dlat = dN / (M + h)``, ``dlon = dE / ((N + h) cos lat)``), height ``- dD``.

    Parameters
    ----------
    log : pospp.io.mcap_reader.FlightLog (or any frozen dataclass with ``imu``, ``fix``, ``vel``)
    noise : NullNoise
    rng : numpy.random.Generator

    Returns
    -------
    Same type as ``log``, with ``imu``, ``fix``, ``vel`` replaced.
    """
    imu, fix, vel = log.imu, log.fix, log.vel
    t = np.asarray(imu.time_ns, dtype=np.int64)
    dt = np.diff(t) * 1e-9
    dt = np.concatenate([dt[:1], dt]) if dt.size else np.ones(1)
    dt = np.clip(dt, np.median(dt) * 0.1, None)[:, None]
    w = imu.w_ib_b_radps + rng.standard_normal(imu.w_ib_b_radps.shape) * (
        noise.gyro_arw_radpsqrts / np.sqrt(dt))
    if noise.gyro_gm_sigma_radps > 0 and np.isfinite(noise.gyro_gm_tau_s):
        w = w + gauss_markov_path(dt[:, 0], noise.gyro_gm_sigma_radps, noise.gyro_gm_tau_s,
                                  rng)
    f = imu.f_ib_b_mps2 + rng.standard_normal(imu.f_ib_b_mps2.shape) * (
        noise.accel_vrw_mpspsqrts / np.sqrt(dt))
    e_pos = rng.standard_normal((len(fix.time_ns), 3)) * np.asarray(noise.pos_sigma_ned_m)
    rm, rn = principal_radii_m(fix.lat_rad)
    lat = fix.lat_rad + e_pos[:, 0] / (rm + fix.height_m)
    lon = fix.lon_rad + e_pos[:, 1] / ((rn + fix.height_m) * np.cos(fix.lat_rad))
    h = fix.height_m - e_pos[:, 2]
    v = vel.v_n_mps + rng.standard_normal(vel.v_n_mps.shape) * np.asarray(
        noise.vel_sigma_ned_mps)
    return replace(log, imu=replace(imu, w_ib_b_radps=w, f_ib_b_mps2=f),
                   fix=replace(fix, lat_rad=lat, lon_rad=lon, height_m=h),
                   vel=replace(vel, v_n_mps=v))


def gauss_markov_path(dt_s: NDArray, sigma: float, tau_s: float, rng: np.random.Generator
                      ) -> NDArray:
    """Three independent first-order Gauss-Markov paths, stationary start, shape (N, 3).

    Exact discretisation: ``x_k = e^(-dt_k / tau) x_k-1 + sigma sqrt(1 - e^(-2 dt_k / tau)) n_k``
    (varying steps: the recursion by cumulative products of the decay, in blocks of 20
    correlation times to stay within floating range).
    """
    dt = np.asarray(dt_s, dtype=float)
    a = np.exp(-dt / tau_s)
    q = sigma * np.sqrt(1.0 - a**2)
    e = rng.standard_normal((dt.size, 3)) * q[:, None]
    e[0] = rng.standard_normal(3) * sigma
    x = np.empty_like(e)
    prev = np.zeros(3)
    block = max(1, int(20.0 * tau_s / max(float(np.median(dt)), 1e-12)))
    for s0 in range(0, dt.size, block):
        sl = slice(s0, min(s0 + block, dt.size))
        la = np.log(a[sl])
        if s0 == 0:
            la[0] = 0.0  # x_0 = e_0 (stationary start)
        c = np.exp(np.cumsum(la))  # x_j = c_j (prev + sum_i<=j e_i / c_i)
        x[sl] = c[:, None] * (prev + np.cumsum(e[sl] / c[:, None], axis=0))
        prev = x[sl][-1]
    return x


def null_difference(perturbed_dv_n_mps: dict[int, NDArray], flight_dv_n_mps: dict[int, NDArray]
                    ) -> dict[int, NDArray]:
    """d_r = perturbed B minus A less the flight's, per leg id (module docstring, step 3)."""
    return {k: np.asarray(perturbed_dv_n_mps[k]) - np.asarray(flight_dv_n_mps[k])
            for k in flight_dv_n_mps}


def calibrated_p_value(statistic: float, null_statistics: NDArray) -> float:
    """p-value of a statistic against its null realisations, by a scaled chi2 fitted by moments.

    The null distribution is taken as ``c chi2_nu / nu`` and (c, nu) matched to the mean and
    variance of the LOGARITHMS of the R null statistics (robust to the heavy upper tail a
    correlated drift gives, where the plain variance of a few draws reads low)::

        Var log F = psi'(nu / 2),   E log F = log c + psi(nu / 2) + log(2 / nu)
        p = P(chi2_nu > nu F / c)

    This keeps the tail usable with few realisations (an empirical quantile at alpha = 0.05
    over R = 20 draws is one draw). A NaN statistic gives p = 1; fewer than 3 finite positive
    null statistics give NaN (not calibrated: the caller keeps the nominal p).
    """
    if not np.isfinite(statistic):
        return 1.0
    s = np.asarray(null_statistics, dtype=float)
    s = s[np.isfinite(s) & (s > 0)]
    if s.size < 3:
        return float("nan")
    lg = np.log(s)
    m, v = float(np.mean(lg)), float(np.var(lg, ddof=1))
    if v <= 0:
        return 0.0 if statistic > float(np.exp(m)) else 1.0
    # psi'(x) decreases from inf to 0: solve psi'(nu / 2) = v on a log bracket
    half = optimize.brentq(lambda lx: float(special.polygamma(1, np.exp(lx))) - v, -20.0, 30.0)
    nu = 2.0 * float(np.exp(half))
    log_c = m - float(special.digamma(nu / 2.0)) - np.log(2.0 / nu)
    return float(stats.chi2.sf(nu * statistic / np.exp(log_c), nu))


def imu_white_noise_from_samples(time_ns: NDArray, w_ib_b_radps: NDArray, f_ib_b_mps2: NDArray
                                 ) -> tuple[float, float]:
    """The IMU's white noise density (gyro ARW, accelerometer VRW) read from its own samples.

    Second differences of the samples remove smooth motion; for white noise of per-sample
    sigma s they have variance 6 s^2. Robustly (median absolute deviation, per axis, the
    median over the three axes)::

        s = 1.4826 MAD(w_k+1 - 2 w_k + w_k-1) / sqrt(6),   ARW = s sqrt(dt)

    Vibration and quantisation above the motion's bandwidth count as noise here, so on real
    data the level reads high (a conservative null).

    Returns
    -------
    gyro_arw_radpsqrts, accel_vrw_mpspsqrts : float
    """
    t = np.asarray(time_ns, dtype=np.int64)
    dt = float(np.median(np.diff(t))) * 1e-9 if t.size > 1 else 1.0
    out = []
    for a in (w_ib_b_radps, f_ib_b_mps2):
        d2 = np.diff(np.asarray(a, dtype=float), n=2, axis=0)
        if d2.shape[0] < 10:
            out.append(float("nan"))
            continue
        mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
        out.append(float(np.median(1.4826 * mad / np.sqrt(6.0)) * np.sqrt(dt)))
    return out[0], out[1]
