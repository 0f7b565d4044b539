"""Compiled strapdown kernel (numba, ``cache=True``): the one mechanization of pospp.

Algorithms A (integrated filter), B (pure-inertial replay) and the simulator's self-checks
all step through :func:`strapdown_step`. The public, validated entry point is
:func:`pospp.nav.strapdown.integrate`.

State vector layout (float64[10]), the only place it is defined::

    x = [lat_rad, lon_rad, height_m, vn_mps, ve_mps, vd_mps, qw, qx, qy, qz]

with q = q_nb scalar-first (body FRD -> NED). Earth formulas come from
``pospp.earth.radii_formula`` / ``gravity_formula`` (and their sin^2 forms, so that one
sin/cos/sqrt per latitude serves radii, gravity and rates in the step) compiled here, so numpy
and numba share one source of the physics.

Mechanization (Savage 1998, Shin 2001, two-sample "one plus previous" corrections), for the
interval k-1 -> k with increments dtheta_k, dv_k (body, rad and m/s) and length dt:

- coning:      phi_k  = dtheta_k + (dtheta_{k-1} x dtheta_k) / 12
- velocity rotation and sculling (second-order rotation term included):
               dv_b   = dv_k + (dtheta_k x dv_k) / 2 + dtheta_k x (dtheta_k x dv_k) / 6
                        + (dtheta_{k-1} x dv_k + dv_{k-1} x dtheta_k) / 12
- velocity:    v_k = v_{k-1} + (I - [zeta x] / 2) C_nb,{k-1} dv_b
                     + (g_n - (2 w_ie + w_en) x v) dt,        zeta = (w_ie + w_en) dt
  with position/velocity-dependent terms at the mid-interval, extrapolated from k-2, k-1;
- position:    trapezoidal in velocity, geodetic (lat, lon, h);
- attitude:    q_k = exp(-zeta') * q_{k-1} * exp(phi_k), zeta' from the mid-interval of the
  updated position and velocity.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pospp.earth import (
    EARTH_RATE_RADPS,
    gravity_formula,
    gravity_from_sin2,
    radii_formula,
    radii_from_sin2,
)

radii = njit(cache=True)(radii_formula)
"""Compiled :func:`pospp.earth.radii_formula`: (R_M, R_N) [m] of geodetic latitude [rad]."""
_gravity = njit(cache=True)(gravity_formula)
_radii_s2 = njit(cache=True)(radii_from_sin2)
_gravity_s2 = njit(cache=True)(gravity_from_sin2)

_SERIES_A2 = 1e-6
"""Below this squared angle [rad^2] the quaternion exponential uses its 4th-order series: the
first omitted terms, a^6 / 46080 and a^6 / 645120, are under 3e-23, far below double precision."""

STATE_SIZE = 10

X_POS, X_VEL, X_QUAT = 0, 3, 6
"""First index of [lat_rad, lon_rad, height_m], v_n_mps and q_nb in the state vector."""


@njit(cache=True)
def quat_mul(p0, p1, p2, p3, q0, q1, q2, q3):
    """Hamilton product of scalar-first quaternions given as scalars; returns a 4-tuple."""
    return (
        p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
        p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
        p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
        p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
    )


@njit(cache=True)
def quat_from_rotvec(x, y, z):
    """Quaternion (scalar-first) of the rotation vector (x, y, z) [rad]; series near zero."""
    a2 = x * x + y * y + z * z
    if a2 < _SERIES_A2:
        # cos(a/2) and sin(a/2)/a to 4th order
        c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        a = math.sqrt(a2)
        c = math.cos(0.5 * a)
        s = math.sin(0.5 * a) / a
    return c, s * x, s * y, s * z


@njit(cache=True)
def dcm_from_quat_into(q, c):
    """Fill the 3x3 array ``c`` with C_nb of the scalar-first quaternion ``q``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    c[0, 0] = w * w + x * x - y * y - z * z
    c[0, 1] = 2.0 * (x * y - w * z)
    c[0, 2] = 2.0 * (x * z + w * y)
    c[1, 0] = 2.0 * (x * y + w * z)
    c[1, 1] = w * w - x * x + y * y - z * z
    c[1, 2] = 2.0 * (y * z - w * x)
    c[2, 0] = 2.0 * (x * z - w * y)
    c[2, 1] = 2.0 * (y * z + w * x)
    c[2, 2] = w * w - x * x - y * y + z * z


@njit(cache=True)
def nav_rates(lat, h, vn, ve):
    """(w_ie_n, w_en_n) components in NED [rad/s] as two 3-tuples (Groves Eq. 2.123, 5.44)."""
    r_m, r_n = radii(lat)
    sl = math.sin(lat)
    cl = math.cos(lat)
    wie = (EARTH_RATE_RADPS * cl, 0.0, -EARTH_RATE_RADPS * sl)
    wen = (ve / (r_n + h), -vn / (r_m + h), -ve * sl / cl / (r_n + h))
    return wie, wen


@njit(cache=True)
def strapdown_step(x, x_prev, dth, dvel, dth_prev, dv_prev, dt, extrap, x_out):
    """One mechanization interval: state ``x`` (time k-1) -> ``x_out`` (time k).

    Parameters
    ----------
    x, x_prev : float64[10]
        State at k-1 and at k-2 (for mid-interval extrapolation; ignored if ``extrap`` is 0).
    dth, dvel : float64[3]
        Bias-corrected increments of interval k, body FRD [rad], [m/s].
    dth_prev, dv_prev : float64[3]
        Increments of interval k-1 (zeros at the first step).
    dt : float
        Interval length [s].
    extrap : float
        Weight of the linear extrapolation to the mid-interval: 0.5 * dt_k / dt_{k-1}, or 0
        when no previous state exists.
    x_out : float64[10]
        Output state at k (may not alias ``x``).
    """
    lat, lon, h = x[0], x[1], x[2]
    vn, ve, vd = x[3], x[4], x[5]
    # --- mid-interval extrapolation for the velocity update --------------------------------
    lat_m = lat + extrap * (lat - x_prev[0])
    h_m = h + extrap * (h - x_prev[2])
    vn_m = vn + extrap * (vn - x_prev[3])
    ve_m = ve + extrap * (ve - x_prev[4])
    vd_m = vd + extrap * (vd - x_prev[5])
    # Earth terms at the extrapolated mid-interval: one sin/cos/sqrt serves radii, gravity and
    # the rates (same formulas as nav_rates, radii, _gravity)
    sl_m = math.sin(lat_m)
    cl_m = math.cos(lat_m)
    s2_m = sl_m * sl_m
    r_m_m, r_n_m = _radii_s2(s2_m)
    wie = (EARTH_RATE_RADPS * cl_m, 0.0, -EARTH_RATE_RADPS * sl_m)
    wen = (ve_m / (r_n_m + h_m), -vn_m / (r_m_m + h_m), -ve_m * sl_m / cl_m / (r_n_m + h_m))
    zx = (wie[0] + wen[0]) * dt
    zy = (wie[1] + wen[1]) * dt
    zz = (wie[2] + wen[2]) * dt
    # --- sculling and rotation compensation (body frame) ------------------------------------
    tx, ty, tz = dth[0], dth[1], dth[2]
    ax, ay, az = dvel[0], dvel[1], dvel[2]
    px, py, pz = dth_prev[0], dth_prev[1], dth_prev[2]
    bx, by, bz = dv_prev[0], dv_prev[1], dv_prev[2]
    # dtheta x dv and dtheta x (dtheta x dv) (second-order rotation term, Savage 1998)
    cx1 = ty * az - tz * ay
    cy1 = tz * ax - tx * az
    cz1 = tx * ay - ty * ax
    sx = ax + 0.5 * cx1 + (ty * cz1 - tz * cy1) / 6.0
    sy = ay + 0.5 * cy1 + (tz * cx1 - tx * cz1) / 6.0
    sz = az + 0.5 * cz1 + (tx * cy1 - ty * cx1) / 6.0
    sx += ((py * az - pz * ay) + (by * tz - bz * ty)) / 12.0
    sy += ((pz * ax - px * az) + (bz * tx - bx * tz)) / 12.0
    sz += ((px * ay - py * ax) + (bx * ty - by * tx)) / 12.0
    # --- rotate to n with C_nb(k-1), then (I - [zeta x]/2) ----------------------------------
    w, qx, qy, qz = x[6], x[7], x[8], x[9]
    c00 = w * w + qx * qx - qy * qy - qz * qz
    c01 = 2.0 * (qx * qy - w * qz)
    c02 = 2.0 * (qx * qz + w * qy)
    c10 = 2.0 * (qx * qy + w * qz)
    c11 = w * w - qx * qx + qy * qy - qz * qz
    c12 = 2.0 * (qy * qz - w * qx)
    c20 = 2.0 * (qx * qz - w * qy)
    c21 = 2.0 * (qy * qz + w * qx)
    c22 = w * w - qx * qx - qy * qy + qz * qz
    fn = c00 * sx + c01 * sy + c02 * sz
    fe = c10 * sx + c11 * sy + c12 * sz
    fd = c20 * sx + c21 * sy + c22 * sz
    dfn = fn - 0.5 * (zy * fd - zz * fe)
    dfe = fe - 0.5 * (zz * fn - zx * fd)
    dfd = fd - 0.5 * (zx * fe - zy * fn)
    # --- gravity and Coriolis at mid-interval ------------------------------------------------
    g = _gravity_s2(s2_m, h_m)
    cx = 2.0 * wie[0] + wen[0]
    cy = 2.0 * wie[1] + wen[1]
    cz = 2.0 * wie[2] + wen[2]
    gcn = -(cy * vd_m - cz * ve_m)
    gce = -(cz * vn_m - cx * vd_m)
    gcd = g - (cx * ve_m - cy * vn_m)
    vn1 = vn + dfn + gcn * dt
    ve1 = ve + dfe + gce * dt
    vd1 = vd + dfd + gcd * dt
    # --- position (trapezoidal velocity, geodetic) -------------------------------------------
    h1 = h - 0.5 * (vd + vd1) * dt
    hm = 0.5 * (h + h1)
    lat1 = lat + 0.5 * (vn + vn1) * dt / (r_m_m + hm)
    latm = 0.5 * (lat + lat1)
    sl2 = math.sin(latm)
    cl2 = math.cos(latm)
    r_m2, r_n2 = _radii_s2(sl2 * sl2)
    lon1 = lon + 0.5 * (ve + ve1) * dt / ((r_n2 + hm) * cl2)
    # --- attitude ------------------------------------------------------------------------------
    vn_a = 0.5 * (vn + vn1)
    ve_a = 0.5 * (ve + ve1)
    ex = -(EARTH_RATE_RADPS * cl2 + ve_a / (r_n2 + hm)) * dt
    ey = vn_a / (r_m2 + hm) * dt
    ez = -(-EARTH_RATE_RADPS * sl2 - ve_a * sl2 / cl2 / (r_n2 + hm)) * dt
    phx = tx + (py * tz - pz * ty) / 12.0
    phy = ty + (pz * tx - px * tz) / 12.0
    phz = tz + (px * ty - py * tx) / 12.0
    qb = quat_from_rotvec(phx, phy, phz)
    qn = quat_from_rotvec(ex, ey, ez)
    q1 = quat_mul(w, qx, qy, qz, qb[0], qb[1], qb[2], qb[3])
    q2 = quat_mul(qn[0], qn[1], qn[2], qn[3], q1[0], q1[1], q1[2], q1[3])
    nrm = math.sqrt(q2[0] * q2[0] + q2[1] * q2[1] + q2[2] * q2[2] + q2[3] * q2[3])
    if q2[0] < 0.0:
        nrm = -nrm
    x_out[0] = lat1
    x_out[1] = lon1
    x_out[2] = h1
    x_out[3] = vn1
    x_out[4] = ve1
    x_out[5] = vd1
    x_out[6] = q2[0] / nrm
    x_out[7] = q2[1] / nrm
    x_out[8] = q2[2] / nrm
    x_out[9] = q2[3] / nrm


@njit(cache=True, nogil=True)
def integrate_kernel(x0, dt_s, dtheta, dvel, gyro_bias, accel_bias, dth_prev0, dv_prev0, out):
    """Run :func:`strapdown_step` over all intervals.

    Parameters
    ----------
    x0 : float64[10]
        Initial state.
    dt_s : float64[N]
        Interval lengths [s].
    dtheta, dvel : float64[N, 3]
        Raw increments, body FRD [rad], [m/s].
    gyro_bias, accel_bias : float64[M, 3]
        Biases to remove [rad/s], [m/s^2]; M == 1 (constant) or M == N (per interval).
    dth_prev0, dv_prev0 : float64[3]
        Bias-corrected increments of the interval before the first (zeros if unknown).
    out : float64[N + 1, 10]
        States at the N + 1 epochs; row 0 receives x0.
    """
    n = dt_s.shape[0]
    out[0, :] = x0
    dth_p = dth_prev0.copy()
    dv_p = dv_prev0.copy()
    dth_c = np.empty(3)
    dv_c = np.empty(3)
    per_sample_g = gyro_bias.shape[0] > 1
    per_sample_a = accel_bias.shape[0] > 1
    for k in range(n):
        dt = dt_s[k]
        ig = k if per_sample_g else 0
        ia = k if per_sample_a else 0
        for j in range(3):
            dth_c[j] = dtheta[k, j] - gyro_bias[ig, j] * dt
            dv_c[j] = dvel[k, j] - accel_bias[ia, j] * dt
        if k == 0:
            extrap = 0.0
            strapdown_step(out[0], out[0], dth_c, dv_c, dth_p, dv_p, dt, extrap, out[1])
        else:
            extrap = 0.5 * dt / dt_s[k - 1]
            strapdown_step(out[k], out[k - 1], dth_c, dv_c, dth_p, dv_p, dt, extrap, out[k + 1])
        for j in range(3):
            dth_p[j] = dth_c[j]
            dv_p[j] = dv_c[j]


@njit(cache=True)
def first_invalid_sample(t_s, dtheta, dvel):
    """Scan an increment series once: (code, index) of the first problem, (0, -1) if none.

    Codes, in the order they are checked: 1 non-finite ``dtheta[k]``, 2 non-finite
    ``dvel[k]``, 3 non-finite ``t_s[k]``, 4 ``t_s[k] <= t_s[k - 1]``.
    """
    n = dtheta.shape[0]
    for k in range(n):
        for j in range(3):
            if not math.isfinite(dtheta[k, j]):
                return 1, k
    for k in range(n):
        for j in range(3):
            if not math.isfinite(dvel[k, j]):
                return 2, k
    for k in range(t_s.shape[0]):
        if not math.isfinite(t_s[k]):
            return 3, k
    for k in range(1, t_s.shape[0]):
        if not t_s[k] > t_s[k - 1]:
            return 4, k
    return 0, -1
