"""Estimate an unknown IMU mounting rotation C_bs from specific force and GNSS velocity.

Frames: s the sensor as logged, b the vehicle body FRD, n local NED. Units SI, rad. The result
``C_bs`` takes sensor vectors to body vectors, ``f_b = C_bs @ f_s`` (destination-first, as the
mounting argument of ``pospp.io.mcap_reader.read_flight_log``).

Model
-----
Over a window of a few tenths of a second to a second the mean specific force is::

    f_s = C_sb C_bn (a_n - g_n)                 (g_n = [0, 0, g] NED, a_n = dv_n/dt)

where a_n is the window's mean acceleration from the GNSS (or reference) velocity and C_nb the
body attitude: by default roll = pitch = 0 and yaw = course atan2(v_E, v_N) (a land vehicle
without sideslip, "forward axis from GNSS velocity"); for a vehicle whose nose does not point
along its track (a quadrotor flying sideways) pass the body's own roll, pitch and yaw.

Two steps, each with its own quality figure:

1. Levelling. On quasi-static windows (|a_n| small) the direction of the specific force fixes
   the body's "up" in the sensor frame. The shortest-arc rotation ``C_1`` with
   ``C_1 u_s = u_b`` (u: mean unit specific-force directions, sensor and expected body) fixes
   two of the three mounting angles. Levelling residual: RMS over the static windows of the
   angle between ``C_bs u_s,k`` and ``u_b,k`` (final rotation; equal to the step-1 residual
   for a level body); tilt sigma: residual / sqrt(number of windows).
2. Forward axis. The remaining rotation is a turn psi about u_b. On windows with horizontal
   acceleration (speeding up, braking, turning) the measured specific force, levelled by
   ``C_1`` and projected on the plane normal to u_b, must turn by psi into the expected one.
   psi is the acceleration-weighted circular mean of the per-window angles (a 2-D orthogonal
   Procrustes / Wahba solution); heading scatter: weighted circular standard deviation of the
   per-window angles; heading sigma: scatter / sqrt(effective number of windows).

The default body attitude fits land vehicles only. An aircraft banks into its turns (its
specific force stays near body z, with no lateral component) and flies nose-up, so pass its
attitude. If it is not passed, the heading scatter exposes the error: on the independent
simulator's survey flight, the scatter is 97 deg with the default attitude and 0.05 deg with the
true attitude.

Result: ``C_bs = R(u_b, psi) C_1``. The sigmas assume independent windows; vibration,
accelerometer bias (about bias / g in tilt) and errors of the assumed body attitude (sideslip,
non-level rest) are not in them, so read them as a lower bound and compare with the residuals.

References: Groves (2013), Principles of GNSS, Inertial, and Multisensor Integrated Navigation
Systems, 2nd ed., Sec. 5.6.2 (levelling) and 14.2 (IMU mounting and body-frame alignment);
Wahba's problem (SIAM Review 7, 1965) for step 2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth, rotation

__all__ = ["MountingEstimate", "MountingOptions", "estimate_mounting", "window_means"]


@dataclass(frozen=True)
class MountingOptions:
    """Window length and thresholds of :func:`estimate_mounting` (units in the names)."""

    window_s: float = 1.0
    max_static_accel_mps2: float = 0.3
    min_horizontal_accel_mps2: float = 0.3
    min_speed_mps: float = 1.0
    min_static_windows: int = 3
    min_moving_windows: int = 3


@dataclass(frozen=True)
class MountingEstimate:
    """An estimated mounting rotation and how well the data fix it.

    Attributes
    ----------
    c_bs : ndarray, shape (3, 3)
        Sensor -> body (FRD) DCM, ``f_b = C_bs @ f_s``.
    rpy_rad : ndarray, shape (3,)
        The same rotation as z-y-x Euler angles [roll, pitch, yaw] of the sensor axes with
        respect to the body axes (``C_bs = Rz(yaw) Ry(pitch) Rx(roll)``), yaw in [0, 2 pi).
    tilt_sigma_rad : float
        1-sigma of the levelled ("up") axis direction, from the levelling residual.
    heading_sigma_rad : float
        1-sigma of the rotation about the up axis (forward-axis heading).
    levelling_residual_rad : float
        RMS angle between the levelled measured and expected specific-force directions over
        the static windows.
    heading_scatter_rad : float
        Weighted circular standard deviation of the per-window forward-axis angles.
    n_static_windows, n_moving_windows : int
        Windows used in step 1 and step 2.
    """

    c_bs: NDArray
    rpy_rad: NDArray
    tilt_sigma_rad: float
    heading_sigma_rad: float
    levelling_residual_rad: float
    heading_scatter_rad: float
    n_static_windows: int
    n_moving_windows: int


def window_means(t_s: ArrayLike, x: ArrayLike, edges_s: ArrayLike) -> tuple[NDArray, NDArray]:
    """Mean of samples ``x`` (N, k) in each window [edges[j], edges[j+1]).

    Returns
    -------
    mean : ndarray, shape (W, k)
        NaN where a window holds no sample.
    count : ndarray of int, shape (W,)
    """
    t = np.asarray(t_s, dtype=float)
    xv = np.asarray(x, dtype=float)
    if xv.ndim == 1:
        xv = xv[:, None]
    edges = np.asarray(edges_s, dtype=float)
    idx = np.searchsorted(edges, t, side="right") - 1
    ok = (idx >= 0) & (idx < edges.size - 1)
    nw = edges.size - 1
    count = np.bincount(idx[ok], minlength=nw)
    sums = np.stack([np.bincount(idx[ok], weights=xv[ok, c], minlength=nw)
                     for c in range(xv.shape[1])], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / count[:, None]
    return mean, count


def _shortest_arc(u_from: NDArray, u_to: NDArray) -> NDArray:
    """DCM of the smallest rotation taking unit vector u_from to unit vector u_to."""
    axis = np.cross(u_from, u_to)
    s = np.linalg.norm(axis)
    c = float(np.dot(u_from, u_to))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # 180 deg: any axis normal to u_from
        trial = np.eye(3)[int(np.argmin(np.abs(u_from)))]
        axis = np.cross(u_from, trial)
        return rotation.dcm_from_rotvec(math.pi * axis / np.linalg.norm(axis))
    return rotation.dcm_from_rotvec(axis / s * math.atan2(s, c))


def _unit(v: NDArray) -> NDArray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclass(frozen=True)
class _Windows:
    """Per-window means: measured specific force (sensor), expected (body), NED acceleration,
    usable windows (full, no data gap) and windows whose heading is known."""

    f_s: NDArray
    f_b_expected: NDArray
    a_n: NDArray
    valid: NDArray
    yaw_known: NDArray


def _windows(imu_t_s: ArrayLike, f_s_mps2: ArrayLike, vel_t_s: ArrayLike, v_n_mps: ArrayLike,
             lat_rad: float, height_m: float, body_rpy_rad: ArrayLike | None,
             opt: MountingOptions) -> _Windows:
    """Window means of ``f_s`` and of ``f_b = C_bn (a_n - g_n)`` (module docstring)."""
    t = np.asarray(imu_t_s, dtype=float)
    f = np.asarray(f_s_mps2, dtype=float)
    tv = np.asarray(vel_t_s, dtype=float)
    v = np.asarray(v_n_mps, dtype=float)
    if f.shape != (t.size, 3):
        raise ValueError(f"f_s_mps2 must have shape ({t.size}, 3); got {f.shape}")
    if v.shape != (tv.size, 3):
        raise ValueError(f"v_n_mps must have shape ({tv.size}, 3); got {v.shape}")
    start = max(t[0], tv[0])
    stop = min(t[-1], tv[-1])
    edges = np.arange(start, stop + 1e-9, opt.window_s)
    if edges.size < 3:
        raise ValueError(f"IMU and velocity overlap only {stop - start:.2f} s; need at least "
                         f"{2 * opt.window_s} s")
    f_w, n_w = window_means(t, f, edges)
    # mean acceleration over each window from the velocity at its ends
    v0 = np.stack([np.interp(edges[:-1], tv, v[:, i]) for i in range(3)], axis=1)
    v1 = np.stack([np.interp(edges[1:], tv, v[:, i]) for i in range(3)], axis=1)
    a_n = (v1 - v0) / opt.window_s
    centre = 0.5 * (edges[:-1] + edges[1:])
    v_c = np.stack([np.interp(centre, tv, v[:, i]) for i in range(3)], axis=1)
    g = float(earth.normal_gravity_mps2(lat_rad, height_m))
    f_n = a_n - np.array([0.0, 0.0, g])
    if body_rpy_rad is None:
        yaw = np.arctan2(v_c[:, 1], v_c[:, 0])
        rpy = np.column_stack([np.zeros_like(yaw), np.zeros_like(yaw), yaw])
        yaw_known = np.hypot(v_c[:, 0], v_c[:, 1]) > opt.min_speed_mps
    else:
        rpy_in = np.asarray(body_rpy_rad, dtype=float)
        if rpy_in.shape != (tv.size, 3):
            raise ValueError(f"body_rpy_rad must have shape ({tv.size}, 3); got {rpy_in.shape}")
        rpy = np.column_stack([
            np.interp(centre, tv, rpy_in[:, 0]),
            np.interp(centre, tv, rpy_in[:, 1]),
            np.interp(centre, tv, np.unwrap(rpy_in[:, 2])),
        ])
        yaw_known = np.ones(centre.size, dtype=bool)
    c_bn = np.swapaxes(rotation.dcm_from_euler(rpy), -1, -2)
    f_b_exp = np.einsum("kij,kj->ki", c_bn, f_n)
    # windows must be (nearly) full: a window straddling a data gap has a wrong mean, and the
    # velocity interpolated across a gap gives a wrong acceleration
    valid = n_w >= 0.8 * np.median(n_w[n_w > 0]) if np.any(n_w > 0) else n_w > 0
    if tv.size > 1:
        dt_v = np.diff(tv)
        gap = dt_v > 3.0 * np.median(dt_v)
        for lo, hi in zip(tv[:-1][gap], tv[1:][gap], strict=True):
            valid &= (edges[1:] <= lo) | (edges[:-1] >= hi)
    return _Windows(f_w, f_b_exp, a_n, valid, yaw_known)


def _forward_axis(win: _Windows, c_1: NDArray, k: NDArray, opt: MountingOptions
                  ) -> tuple[float, float, float, int]:
    """Turn psi about the levelled up axis ``k`` (weighted circular mean of the per-window
    angles), its scatter and sigma, and the number of windows used."""
    x = win.f_s @ c_1.T
    y = win.f_b_expected
    x_h = x - np.outer(x @ k, k)
    y_h = y - np.outer(y @ k, k)
    acc_h = np.linalg.norm(y_h, axis=1)
    moving = win.valid & win.yaw_known & (acc_h > opt.min_horizontal_accel_mps2)
    n_moving = int(moving.sum())
    if n_moving < opt.min_moving_windows:
        raise ValueError(f"the forward axis needs at least {opt.min_moving_windows} windows "
                         f"with horizontal acceleration > {opt.min_horizontal_accel_mps2} m/s^2 "
                         f"at known heading; found {n_moving}")
    xm, ym = x_h[moving], y_h[moving]
    psi_k = np.arctan2(np.cross(xm, ym) @ k, np.sum(xm * ym, axis=1))
    w = acc_h[moving] ** 2
    cs = np.sum(w * np.cos(psi_k)) / w.sum()
    sn = np.sum(w * np.sin(psi_k)) / w.sum()
    psi = math.atan2(sn, cs)
    dpsi = (psi_k - psi + np.pi) % (2.0 * np.pi) - np.pi
    scatter = float(np.sqrt(np.sum(w * dpsi**2) / w.sum()))
    n_eff = float(w.sum() ** 2 / np.sum(w**2))
    return psi, scatter, scatter / math.sqrt(n_eff), n_moving


def estimate_mounting(
    imu_t_s: ArrayLike,
    f_s_mps2: ArrayLike,
    vel_t_s: ArrayLike,
    v_n_mps: ArrayLike,
    *,
    lat_rad: float,
    height_m: float = 0.0,
    body_rpy_rad: ArrayLike | None = None,
    options: MountingOptions = MountingOptions(),
) -> MountingEstimate:
    """Estimate the sensor-to-body rotation C_bs (module docstring: levelling + forward axis).

    Parameters
    ----------
    imu_t_s : ndarray, shape (N,)
        IMU times [s] on the same time base as ``vel_t_s``.
    f_s_mps2 : ndarray, shape (N, 3)
        Specific force in the sensor frame [m/s^2] (gravity included: about +g on the up axis).
    vel_t_s : ndarray, shape (M,)
        Velocity epochs [s].
    v_n_mps : ndarray, shape (M, 3)
        Velocity NED [m/s] (GNSS or reference).
    lat_rad, height_m : float
        Where gravity is evaluated (normal gravity, WGS-84).
    body_rpy_rad : ndarray, shape (M, 3), optional
        Body attitude [roll, pitch, yaw] at ``vel_t_s``. Default: roll = pitch = 0 and
        yaw = course (no sideslip); the yaw is then only meaningful above ``min_speed_mps``.
    options : MountingOptions

    Returns
    -------
    MountingEstimate

    Raises
    ------
    ValueError
        Shapes wrong, or too few static windows (levelling) or too few windows with
        horizontal acceleration (forward axis), with the counts found.
    """
    win = _windows(imu_t_s, f_s_mps2, vel_t_s, v_n_mps, lat_rad, height_m, body_rpy_rad,
                   options)
    opt = options
    static = win.valid & (np.linalg.norm(win.a_n, axis=1) < opt.max_static_accel_mps2)
    n_static = int(static.sum())
    if n_static < opt.min_static_windows:
        raise ValueError(f"levelling needs at least {opt.min_static_windows} windows with "
                         f"|a_n| < {opt.max_static_accel_mps2} m/s^2; found {n_static}")
    # step 1: levelling (shortest arc between mean directions)
    u_s = _unit(win.f_s[static])
    u_b = _unit(win.f_b_expected[static])
    u_b_mean = _unit(u_b.mean(axis=0))
    c_1 = _shortest_arc(_unit(u_s.mean(axis=0)), u_b_mean)
    # step 2: forward axis, rotation psi about u_b_mean
    psi, scatter, heading_sigma, n_moving = _forward_axis(win, c_1, u_b_mean, opt)
    c_bs = rotation.dcm_from_rotvec(psi * u_b_mean) @ c_1
    # levelling residual with the final rotation (psi turns about k, so for a level body it
    # equals the step-1 residual; with a varying body attitude it is the honest figure)
    lev = u_s @ c_bs.T
    ang = np.arctan2(np.linalg.norm(np.cross(lev, u_b), axis=1), np.sum(lev * u_b, axis=1))
    lev_rms = float(np.sqrt(np.mean(ang**2)))
    tilt_sigma = lev_rms / math.sqrt(n_static)
    return MountingEstimate(
        c_bs=c_bs,
        rpy_rad=rotation.euler_from_dcm(c_bs),
        tilt_sigma_rad=tilt_sigma,
        heading_sigma_rad=heading_sigma,
        levelling_residual_rad=lev_rms,
        heading_scatter_rad=scatter,
        n_static_windows=n_static,
        n_moving_windows=n_moving,
    )
