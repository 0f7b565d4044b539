"""Initial alignment for the integrated filter: static (levelling + gyrocompassing) or in motion.

Frames: body FRD (b), navigation NED (n); angles in rad, [roll, pitch, yaw] with yaw clockwise
from north (pospp.rotation). Inputs are the IMU mean rates over the interval ending at each
epoch, ``w_ib_b`` [rad/s] and ``f_b`` [m/s^2], and screened GNSS fixes and velocities.

Static coarse alignment (Titterton & Weston 2004, Sec. 10.3; Groves 2013, Sec. 5.6.2)
-------------------------------------------------------------------------------------------
At rest f_b = C_bn [0, 0, -g] and w_ib_b = C_bn [Omega cos L, 0, -Omega sin L]. With the means
over the static period::

    roll  = atan2(-f_y, -f_z),   pitch = atan2(f_x, sqrt(f_y^2 + f_z^2))
    w_h   = R_y(pitch) R_x(roll) w_ib_b           (the rate in the levelled frame)
    yaw   = atan2(-w_h,y, w_h,x)                  (gyrocompassing)

Error budget used for the initial covariance: a tilt of sigma_ba / g (+ white noise averaged over
the period) and a heading of sqrt(sigma_bg^2 + ARW^2 / T) / (Omega cos L) (the east gyro bias is
indistinguishable from a heading error at rest). A 1 deg/h gyro at 40 deg latitude gives about
5 deg; when the predicted heading sigma exceeds ``max_gyrocompass_sigma_deg`` the gyro cannot
resolve Earth rate and the in-motion alignment is used instead. Fine alignment is the filter
itself: it starts at the first IMU epoch with zero-velocity pseudo-measurements over the static
period and the GNSS updates; heading becomes observable in the turns and accelerations.

In-motion alignment
-------------------
Where no usable static period exists the filter starts at the first GNSS velocity epoch with a
steady horizontal speed above ``min_speed_mps`` whose fix agrees with the next fix moved
back by the GNSS velocity (within ``max_fix_mismatch_m``): yaw = atan2(v_E, v_N) (track;
crab/sideslip covered by a large sigma), pitch = atan2(-v_D, |v_h|) (flight path), roll = 0.

The static alignment's position is the median of the fixes over the period (robust to
outliers).

Static detection: windows of ``window_s`` whose accelerometer and gyro standard deviations and
|mean f| - g are below thresholds, and whose GNSS velocities (where present) do not show motion;
the initial static period is the run of such windows from the start.

GNSS velocity test (:func:`gnss_moving_windows`). At rest a record is its noise, v = e with
e ~ N(0, C) (C the reported covariance, its diagonal s_N^2, s_E^2, s_D^2 used), so::

    d^2 = v_N^2 / s_N^2 + v_E^2 / s_E^2 + v_D^2 / s_D^2  ~  chi^2(3)
    P(d^2 > c) = alpha,   c = chi^2_3 quantile 1 - alpha  (alpha = 1e-6: c = 30.66, sqrt c = 5.54)

For equal sigmas s per axis |v| / s follows the chi distribution with 3 dof, and the test is
|v| > sqrt(c) s. A record is moving when d^2 > c AND |v| > ``max_static_speed_mps``, or when
|v| > ``max_noisy_static_speed_mps`` whatever its sigma; i.e. about |v| > max(0.1 m/s, 5.54 s),
at most 0.5 m/s. The same test is applied to each window's mean velocity (covariance
sum C_i / n^2), which sees a slow creep that single records at a higher rate do not. With the
simulator's receiver (0.02, 0.02, 0.03 m/s; 0.041 m/s RMS in 3-D) one record passed 0.1 m/s
within ten minutes on most seeds; at alpha = 1e-6 per record and per window mean a 20-minute
static log is cut falsely with probability at most 1200 x 1e-6 = 0.12 % at 1 Hz (the mean of
a window of one record is that record) and (12000 + 1200) x 1e-6 = 1.3 % at 10 Hz (less with
the 0.1 m/s condition).
Without covariances the test is |v| > ``max_static_speed_mps`` alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth, rotation
from pospp.distributions import chi2_isf
from pospp.nav.tuning import NoiseParameters
from pospp.units import G0_MPS2


@dataclass(frozen=True)
class AlignmentOptions:
    """Thresholds of the alignment (units in the names)."""

    window_s: float = 1.0
    max_accel_std_mps2: float = 0.05
    max_gyro_std_radps: float = math.radians(0.5)
    max_gravity_mismatch_mps2: float = 0.1
    max_static_speed_mps: float = 0.1
    static_speed_false_alarm: float = 1e-6
    max_noisy_static_speed_mps: float = 0.5
    min_static_s: float = 30.0
    max_static_alignment_s: float = 600.0
    max_gyrocompass_sigma_deg: float = 10.0
    min_speed_mps: float = 5.0
    max_accel_for_motion_mps2: float = 0.5
    motion_heading_sigma_deg: float = 5.0
    motion_tilt_sigma_deg: float = 3.0
    static_velocity_sigma_mps: float = 0.05
    motion_velocity_sigma_mps: float = 0.5
    max_fix_mismatch_m: float = 5.0


@dataclass(frozen=True)
class AlignmentResult:
    """Initial state of the filter and how it was found.

    Attributes
    ----------
    method : str
        "static" (levelling + gyrocompassing) or "motion" (GNSS track).
    k_start : int
        IMU epoch index (into the epochs ``t_s`` given to :func:`align`) where the filter starts.
    t_s : float
        Time of that epoch [s].
    lat_rad, lon_rad, height_m : float
        IMU position at the start (GNSS antenna minus C_nb lever arm).
    v_n_mps : ndarray, shape (3,)
    rpy_rad, rpy_sigma_rad : ndarray, shape (3,)
        Initial attitude and its 1-sigma uncertainty (roll/pitch tilt and heading).
    pos_sigma_ned_m, vel_sigma_ned_mps : ndarray, shape (3,)
    static_end_s : float or None
        End of the initial static period (None if there is none).
    heading_sigma_gyrocompass_rad : float
        Predicted gyrocompassing heading sigma (inf when no static period).
    """

    method: str
    k_start: int
    t_s: float
    lat_rad: float
    lon_rad: float
    height_m: float
    v_n_mps: NDArray
    rpy_rad: NDArray
    rpy_sigma_rad: NDArray
    pos_sigma_ned_m: NDArray
    vel_sigma_ned_mps: NDArray
    static_end_s: float | None
    heading_sigma_gyrocompass_rad: float


def static_windows(
    t_s: ArrayLike,
    w_ib_b_radps: ArrayLike,
    f_b_mps2: ArrayLike,
    *,
    options: AlignmentOptions = AlignmentOptions(),
    gnss_vel_t_s: ArrayLike | None = None,
    gnss_v_n_mps: ArrayLike | None = None,
    gnss_vel_cov_ned_m2ps2: ArrayLike | None = None,
    leading_only: bool = False,
) -> tuple[NDArray, NDArray]:
    """Classify consecutive windows of IMU samples as static or not (module docstring).

    The GNSS velocities (times [s], NED [m/s], optional NED covariances [m^2/s^2]) end a
    window when :func:`gnss_moving_windows` says it moves. ``leading_only``: only the
    windows up to and including the first that is not static (each window is classified on
    its own samples, so these are the same as the first ones of the whole list; the
    alignment needs no more, and a 1.5 h flight's 0.1 s per A run goes).

    Returns
    -------
    window_end_s : ndarray, shape (W,)
        End time of each window [s].
    is_static : ndarray of bool, shape (W,)
    """
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(w_ib_b_radps, dtype=float)
    f = np.asarray(f_b_mps2, dtype=float)
    if t.shape[0] < 2:
        return np.zeros(0), np.zeros(0, dtype=bool)
    dt = float(np.median(np.diff(t)))
    m = max(2, int(round(options.window_s / dt)))
    nw = t.shape[0] // m
    if nw == 0:
        return np.zeros(0), np.zeros(0, dtype=bool)
    gnss = None
    if gnss_vel_t_s is not None and gnss_v_n_mps is not None and np.size(gnss_vel_t_s):
        gnss = (gnss_vel_t_s, gnss_v_n_mps, gnss_vel_cov_ned_m2ps2)
    if not leading_only:
        return _classify_windows(t, w, f, m, 0, nw, gnss, options)
    ends, flags = [], []
    a, b = 0, min(nw, 64)
    while a < nw:
        e, ok = _classify_windows(t, w, f, m, a, b, gnss, options)
        if not ok.all():
            n = int(np.argmin(ok)) + 1
            ends.append(e[:n])
            flags.append(ok[:n])
            break
        ends.append(e)
        flags.append(ok)
        a, b = b, min(nw, 2 * b)
    return np.concatenate(ends), np.concatenate(flags)


def _classify_windows(t: NDArray, w: NDArray, f: NDArray, m: int, a: int, b: int,
                      gnss: tuple | None, options: AlignmentOptions) -> tuple[NDArray, NDArray]:
    """Windows a .. b-1 of m samples each: (end time [s], static)."""
    sl = slice(a * m, b * m)
    fw = f[sl].reshape(b - a, m, 3)
    ww = w[sl].reshape(b - a, m, 3)
    tw = t[sl].reshape(b - a, m)
    lat_g = G0_MPS2
    ok = (
        (fw.std(axis=1).max(axis=1) < options.max_accel_std_mps2)
        & (ww.std(axis=1).max(axis=1) < options.max_gyro_std_radps)
        & (np.abs(np.linalg.norm(fw.mean(axis=1), axis=1) - lat_g)
           < options.max_gravity_mismatch_mps2)
    )
    if gnss is not None:
        ok &= ~gnss_moving_windows(tw[:, 0], tw[:, -1], gnss[0], gnss[1], gnss[2], options)
    return tw[:, -1], ok


def gnss_moving_windows(
    win_start_s: ArrayLike,
    win_end_s: ArrayLike,
    vel_t_s: ArrayLike,
    v_n_mps: ArrayLike,
    vel_cov_ned_m2ps2: ArrayLike | None,
    options: AlignmentOptions,
) -> NDArray:
    """Windows [start, end] (s) whose GNSS velocities show motion (module docstring).

    Parameters
    ----------
    win_start_s, win_end_s : array_like, shape (W,)
        First and last IMU time of each window [s] (increasing).
    vel_t_s, v_n_mps : array_like, shapes (V,), (V, 3)
        GNSS antenna velocity times [s] and NED velocities [m/s].
    vel_cov_ned_m2ps2 : array_like, shape (V, 3, 3), or None
        Reported NED covariances [m^2/s^2] (diagonal used); None: speed threshold alone.

    Returns
    -------
    ndarray of bool, shape (W,)
        True where a record, or the window's mean velocity, is moving:
        (d^2 > chi^2_3 quantile 1 - ``static_speed_false_alarm`` and
        |v| > ``max_static_speed_mps``) or |v| > ``max_noisy_static_speed_mps``.
    """
    t0 = np.asarray(win_start_s, dtype=float)
    t1 = np.asarray(win_end_s, dtype=float)
    tv = np.asarray(vel_t_s, dtype=float)
    v = np.asarray(v_n_mps, dtype=float).reshape(-1, 3)
    nw = t0.shape[0]
    idx = np.searchsorted(t0, tv, side="right") - 1
    inside = (idx >= 0) & (tv <= t1[np.clip(idx, 0, max(nw - 1, 0))])
    idx, v = idx[inside], v[inside]
    if vel_cov_ned_m2ps2 is None:
        var = np.zeros_like(v)  # no sigma: d^2 is infinite, the speed threshold decides
    else:
        cov = np.asarray(vel_cov_ned_m2ps2, dtype=float).reshape(-1, 3, 3)[inside]
        var = np.diagonal(cov, axis1=1, axis2=2)
        var = np.where(np.isfinite(var) & (var > 0.0), var, 0.0)
    c = chi2_isf(options.static_speed_false_alarm, 3)
    moving = np.zeros(nw, dtype=bool)
    np.logical_or.at(moving, idx, _is_moving(v, var, c, options))
    n = np.bincount(idx, minlength=nw).astype(float)
    v_sum = np.stack([np.bincount(idx, v[:, i], minlength=nw) for i in range(3)], axis=1)
    var_sum = np.stack([np.bincount(idx, var[:, i], minlength=nw) for i in range(3)], axis=1)
    has = n > 0
    moving[has] |= _is_moving(v_sum[has] / n[has, None], var_sum[has] / n[has, None] ** 2,
                              c, options)
    return moving


def _is_moving(v: NDArray, var: NDArray, c: float, options: AlignmentOptions) -> NDArray:
    """Velocities (K, 3) [m/s] with per-axis variances [m^2/s^2] (0: unknown) that move."""
    speed = np.linalg.norm(v, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = np.where(var > 0.0, v**2 / np.where(var > 0.0, var, 1.0), np.inf).sum(axis=1)
    return (((d2 > c) & (speed > options.max_static_speed_mps))
            | (speed > options.max_noisy_static_speed_mps))


def static_attitude_rpy(w_mean_b_radps: ArrayLike, f_mean_b_mps2: ArrayLike
                        ) -> tuple[float, float, float]:
    """(roll, pitch, yaw) [rad] of levelling and gyrocompassing from mean sensor outputs at
    rest (module docstring)."""
    f = np.asarray(f_mean_b_mps2, dtype=float)
    w = np.asarray(w_mean_b_radps, dtype=float)
    roll = math.atan2(-f[1], -f[2])
    pitch = math.atan2(f[0], math.hypot(f[1], f[2]))
    c_level = rotation.dcm_from_euler([roll, pitch, 0.0])  # C_hb, h = levelled body frame
    w_h = c_level @ w
    return roll, pitch, math.atan2(-w_h[1], w_h[0]) % (2.0 * math.pi)


def static_attitude_jacobian(w_mean_b_radps: ArrayLike, f_mean_b_mps2: ArrayLike) -> NDArray:
    """The static alignment's attitude error per change of its mean rate and specific force:
    (3, 6), ``phi = J [dw_b; df_b]`` (phi NED [rad] with ``C_nb_hat = (I - [phi x]) C_nb``,
    dw [rad/s], df [m/s^2], body FRD), by central differences of
    :func:`static_attitude_rpy` (steps 1e-9 rad/s and 1e-5 m/s^2: truncation and rounding
    below 1e-6 of the result)."""
    x0 = np.concatenate([np.asarray(w_mean_b_radps, float), np.asarray(f_mean_b_mps2, float)])
    c0_t = rotation.dcm_from_euler(static_attitude_rpy(x0[:3], x0[3:])).T
    jac = np.empty((3, 6))
    for i in range(6):
        h = 1e-9 if i < 3 else 1e-5
        phis = []
        for sign in (1.0, -1.0):
            x = x0.copy()
            x[i] += sign * h
            m = np.eye(3) - rotation.dcm_from_euler(static_attitude_rpy(x[:3], x[3:])) @ c0_t
            phis.append(np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) / 2)
        jac[:, i] = (phis[0] - phis[1]) / (2.0 * h)
    return jac


def coarse_static_alignment(
    w_mean_b_radps: ArrayLike,
    f_mean_b_mps2: ArrayLike,
    lat_rad: float,
    duration_s: float,
    noise: NoiseParameters,
) -> tuple[NDArray, NDArray, float]:
    """Levelling and gyrocompassing from mean sensor outputs at rest (module docstring).

    Returns
    -------
    rpy_rad : ndarray, shape (3,)
    rpy_sigma_rad : ndarray, shape (3,)
        Predicted 1-sigma errors (tilt from the accelerometer bias, heading from the gyro bias
        and ARW over ``duration_s``).
    heading_sigma_rad : float
        The gyrocompassing heading sigma (also rpy_sigma_rad[2]).
    """
    f = np.asarray(f_mean_b_mps2, dtype=float)
    roll, pitch, yaw = static_attitude_rpy(w_mean_b_radps, f)
    g = float(np.linalg.norm(f))
    t = max(duration_s, 1e-3)
    tilt_sigma = math.hypot(noise.accel_bias_sigma_mps2, noise.accel_vrw_mpspsqrts / math.sqrt(t))
    tilt_sigma = max(tilt_sigma / g, 1e-5)
    horiz_rate = earth.EARTH_RATE_RADPS * math.cos(lat_rad)
    gyro_sigma = math.hypot(noise.gyro_bias_sigma_radps, noise.gyro_arw_radpsqrts / math.sqrt(t))
    heading_sigma = gyro_sigma / horiz_rate
    heading_sigma = max(heading_sigma, 1e-4)
    return (
        np.array([roll, pitch, yaw]),
        np.array([tilt_sigma, tilt_sigma, heading_sigma]),
        heading_sigma,
    )


def motion_attitude(v_n_mps: ArrayLike) -> NDArray:
    """[roll=0, pitch=flight-path angle, yaw=track] (rad) from a NED velocity."""
    v = np.asarray(v_n_mps, dtype=float)
    vh = math.hypot(v[0], v[1])
    return np.array([0.0, math.atan2(-v[2], vh), math.atan2(v[1], v[0]) % (2.0 * math.pi)])


def _nearest(t_grid: NDArray, t: float) -> int:
    k = int(np.searchsorted(t_grid, t))
    if k >= t_grid.shape[0]:
        return t_grid.shape[0] - 1
    if k > 0 and abs(t_grid[k - 1] - t) <= abs(t_grid[k] - t):
        return k - 1
    return k


def _imu_position(lat, lon, h, c_nb, lever_b, v_ant_n, dt_s):
    """IMU position from an antenna fix: subtract C_nb l_b, then move by v * dt_s."""
    d_ned = -(c_nb @ lever_b) + np.asarray(v_ant_n) * dt_s
    r_m, r_n = earth.principal_radii_m(lat)
    return (
        lat + d_ned[0] / (r_m + h),
        lon + d_ned[1] / ((r_n + h) * math.cos(lat)),
        h - d_ned[2],
    )


def _motion_alignment(t: NDArray, ft: NDArray, fllh: NDArray, fcov: NDArray, vt: NDArray,
                      vv: NDArray, lever: NDArray, options: AlignmentOptions,
                      static_end: float | None, sigma_gc: float) -> AlignmentResult | None:
    """Alignment at the first steady GNSS velocity above ``min_speed_mps`` whose fix agrees
    with the next one (attitude from the velocity); None when there is none."""
    if vt.shape[0] < 2:
        raise ValueError("alignment: no static period and fewer than 2 GNSS velocities")
    speed_h = np.hypot(vv[:, 0], vv[:, 1])
    acc = np.zeros(vt.shape[0])
    acc[1:] = np.linalg.norm(np.diff(vv, axis=0), axis=1) / np.maximum(np.diff(vt), 1e-3)
    acc_next = np.append(acc[1:], np.inf)
    cand = np.flatnonzero(
        (speed_h > options.min_speed_mps)
        & (acc_next < options.max_accel_for_motion_mps2)
        & (vt >= t[0]) & (vt <= t[-1])
    )
    for i in cand:
        jf = _nearest(ft, vt[i])
        if abs(ft[jf] - vt[i]) > 0.5 or jf + 1 >= ft.shape[0]:
            continue
        # the fix must agree with the next one moved back by the GNSS velocity (no outlier)
        r_m, r_n = earth.principal_radii_m(fllh[jf, 0])
        d_ned = np.array([(fllh[jf + 1, 0] - fllh[jf, 0]) * (r_m + fllh[jf, 2]),
                          (fllh[jf + 1, 1] - fllh[jf, 1]) * (r_n + fllh[jf, 2])
                          * math.cos(fllh[jf, 0]),
                          -(fllh[jf + 1, 2] - fllh[jf, 2])])
        if np.linalg.norm(d_ned - vv[i] * (ft[jf + 1] - ft[jf])) > options.max_fix_mismatch_m:
            continue
        k = _nearest(t, vt[i])
        rpy = motion_attitude(vv[i])
        c_nb = rotation.dcm_from_euler(rpy)
        lat, lon, h = _imu_position(fllh[jf, 0], fllh[jf, 1], fllh[jf, 2], c_nb, lever, vv[i],
                                    t[k] - ft[jf])
        tilt = math.radians(options.motion_tilt_sigma_deg)
        return AlignmentResult(
            method="motion", k_start=k, t_s=float(t[k]), lat_rad=float(lat), lon_rad=float(lon),
            height_m=float(h), v_n_mps=vv[i].copy(), rpy_rad=rpy,
            rpy_sigma_rad=np.array([tilt, tilt, math.radians(options.motion_heading_sigma_deg)]),
            pos_sigma_ned_m=np.sqrt(np.clip(np.diag(fcov[jf]), 1e-6, None)) + 0.5,
            vel_sigma_ned_mps=np.full(3, options.motion_velocity_sigma_mps),
            static_end_s=static_end, heading_sigma_gyrocompass_rad=sigma_gc,
        )
    return None


def align(
    t_s: ArrayLike,
    w_ib_b_radps: ArrayLike,
    f_b_mps2: ArrayLike,
    fix_t_s: ArrayLike,
    fix_llh: ArrayLike,
    fix_cov_ned_m2: ArrayLike,
    vel_t_s: ArrayLike,
    vel_n_mps: ArrayLike,
    noise: NoiseParameters,
    *,
    lever_arm_b_m: ArrayLike = (0.0, 0.0, 0.0),
    options: AlignmentOptions = AlignmentOptions(),
    vel_cov_ned_m2ps2: ArrayLike | None = None,
) -> AlignmentResult:
    """Choose the alignment (static or in motion) and the filter's initial state.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        IMU epochs [s]; ``w_ib_b_radps[k]``, ``f_b_mps2[k]`` are the mean rates over the interval
        ending at ``t_s[k]`` (row 0 is ignored).
    fix_t_s, fix_llh, fix_cov_ned_m2 : array_like, shapes (M,), (M, 3), (M, 3, 3)
        Screened GNSS antenna fixes: times [s], [lat_rad, lon_rad, height_m], NED covariance.
    vel_t_s, vel_n_mps : array_like, shapes (V,), (V, 3)
        Screened GNSS antenna velocities [s], NED [m/s].
    noise : NoiseParameters
        IMU noise model (sets the initial covariance).
    lever_arm_b_m : array_like, shape (3,)
        Antenna position in the body frame FRD [m].
    vel_cov_ned_m2ps2 : array_like, shape (V, 3, 3), optional
        The velocities' NED covariances [m^2/s^2]: the static test then allows their noise
        (module docstring); without them a record above ``max_static_speed_mps`` moves.

    Raises
    ------
    ValueError
        When neither a static period nor a steady moving GNSS epoch is found.
    """
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(w_ib_b_radps, dtype=float)
    f = np.asarray(f_b_mps2, dtype=float)
    ft = np.asarray(fix_t_s, dtype=float)
    fllh = np.asarray(fix_llh, dtype=float)
    fcov = np.asarray(fix_cov_ned_m2, dtype=float)
    vt = np.asarray(vel_t_s, dtype=float)
    vv = np.asarray(vel_n_mps, dtype=float)
    lever = np.asarray(lever_arm_b_m, dtype=float)
    if ft.shape[0] == 0:
        raise ValueError("alignment: no usable GNSS fix (expected at least one, got 0)")

    # ---- static period from the start ---------------------------------------------------------
    w_end, is_static = static_windows(t[1:], w[1:], f[1:], options=options,
                                      gnss_vel_t_s=vt, gnss_v_n_mps=vv,
                                      gnss_vel_cov_ned_m2ps2=vel_cov_ned_m2ps2,
                                      leading_only=True)
    n_static = int(np.argmin(is_static)) if (~is_static).any() else is_static.shape[0]
    static_end = float(w_end[n_static - 1]) if n_static > 0 else None
    static_len = (static_end - t[0]) if static_end is not None else 0.0
    sigma_gc = math.inf
    # at most max_static_alignment_s of the period is used, and at least min_static_s is
    # needed: 0 (or less than min_static_s) means "align in motion", never a mean of nothing
    used_len = min(static_len, options.max_static_alignment_s)
    if static_end is not None and used_len >= options.min_static_s and ft[0] <= static_end:
        t_stop = min(static_end, t[0] + options.max_static_alignment_s)
        sel = (t > t[0]) & (t <= t_stop)
        rpy, rpy_sig, sigma_gc = coarse_static_alignment(
            w[sel].mean(axis=0), f[sel].mean(axis=0), float(fllh[0, 0]), t_stop - t[0], noise
        )
        if math.degrees(sigma_gc) <= options.max_gyrocompass_sigma_deg:
            # the antenna is at rest: the median of the fixes of the period resists outliers
            at_rest = ft <= t_stop
            llh = np.median(fllh[at_rest], axis=0)
            c_nb = rotation.dcm_from_euler(rpy)
            lat, lon, h = _imu_position(llh[0], llh[1], llh[2], c_nb, lever, np.zeros(3), 0.0)
            pos_sig = np.sqrt(np.clip(np.median(np.diagonal(fcov[at_rest], axis1=1, axis2=2),
                                                axis=0), 1e-6, None))
            return AlignmentResult(
                method="static", k_start=0, t_s=float(t[0]), lat_rad=float(lat),
                lon_rad=float(lon), height_m=float(h), v_n_mps=np.zeros(3), rpy_rad=rpy,
                rpy_sigma_rad=rpy_sig, pos_sigma_ned_m=pos_sig,
                vel_sigma_ned_mps=np.full(3, options.static_velocity_sigma_mps),
                static_end_s=static_end, heading_sigma_gyrocompass_rad=sigma_gc,
            )

    # ---- in motion: first steady GNSS velocity above min speed -------------------------------
    result = _motion_alignment(t, ft, fllh, fcov, vt, vv, lever, options, static_end, sigma_gc)
    if result is not None:
        return result
    raise ValueError(
        "alignment: no static period of at least "
        f"{options.min_static_s} s with a resolvable heading and no steady GNSS velocity above "
        f"{options.min_speed_mps} m/s"
    )
