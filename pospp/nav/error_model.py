"""Linear INS error model: the 15-state continuous-time F(t) and transition matrices.

State (15, NED, computed minus true; docs/method.md "Error definitions")::

    dx = [phi_n (3) rad, dv_n (3) m/s, dr_n (3) m, b_g (3) rad/s, b_a (3) m/s^2]

phi is the misalignment with C_nb_hat = (I - [phi x]) C_nb; dr_n is the position error in
local NED metres; b_g, b_a are the body-frame (FRD) gyro and accelerometer biases
(measured = true + bias), modelled as first-order Gauss-Markov processes (random constants
when the correlation time is infinite).

Continuous-time model (Titterton & Weston 2004 Ch. 12; Shin 2005 Eq. 2.44-2.54), with
w_in = w_ie + w_en, f_n = C_nb f_b:

    phi'  = -w_in x phi + dw_in(dr, dv) - C_nb b_g
    dv'   = f_n x phi + C_nb b_a - (2 w_ie + w_en) x dv - (2 dw_ie + dw_en) x v + dg(dr)
    dr'   = F_rr dr + dv
    b_g'  = -b_g / tau_g,   b_a' = -b_a / tau_a

``fill_f_matrix`` is plain arithmetic compiled by numba; the integrated filter, algorithm B's
numerical transition matrices and the tests all use this one implementation.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from pospp.earth import EARTH_RATE_RADPS, gravity_formula, radii_formula

_radii = njit(cache=True)(radii_formula)
_gravity = njit(cache=True)(gravity_formula)

N_STATES = 15
PHI, DV, DR, BG, BA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
"""Slices of the 15-state error vector."""


@njit(cache=True)
def fill_f_matrix(lat, h, v_n, c_nb, f_b, inv_tau_g, inv_tau_a, f_out):
    """Fill ``f_out`` (15x15, zeroed here) with the continuous-time error dynamics F.

    Parameters
    ----------
    lat, h : float
        Geodetic latitude [rad] and height [m].
    v_n : float64[3]
        Velocity NED [m/s].
    c_nb : float64[3, 3]
        Attitude DCM body FRD -> NED.
    f_b : float64[3]
        Specific force, body [m/s^2].
    inv_tau_g, inv_tau_a : float
        1 / correlation time of the gyro and accelerometer bias processes [1/s] (0: constant).
    f_out : float64[15, 15]
    """
    for i in range(15):
        for j in range(15):
            f_out[i, j] = 0.0
    r_m, r_n = _radii(lat)
    rm = r_m + h
    rn = r_n + h
    sl = math.sin(lat)
    cl = math.cos(lat)
    tl = sl / cl
    vn, ve, vd = v_n[0], v_n[1], v_n[2]
    om = EARTH_RATE_RADPS
    wie = (om * cl, 0.0, -om * sl)
    wen = (ve / rn, -vn / rm, -ve * tl / rn)
    win = (wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2])
    # partial derivatives of w_ie, w_en w.r.t. dr (NED m) and dv (NED m/s); dh = -dr_D
    dwie_dr = np.zeros((3, 3))
    dwie_dr[0, 0] = -om * sl / rm
    dwie_dr[2, 0] = -om * cl / rm
    dwen_dr = np.zeros((3, 3))
    dwen_dr[0, 2] = ve / (rn * rn)
    dwen_dr[1, 2] = -vn / (rm * rm)
    dwen_dr[2, 0] = -ve / (cl * cl * rn * rm)
    dwen_dr[2, 2] = -ve * tl / (rn * rn)
    dwen_dv = np.zeros((3, 3))
    dwen_dv[0, 1] = 1.0 / rn
    dwen_dv[1, 0] = -1.0 / rm
    dwen_dv[2, 1] = -tl / rn
    f_n = np.zeros(3)
    for i in range(3):
        f_n[i] = c_nb[i, 0] * f_b[0] + c_nb[i, 1] * f_b[1] + c_nb[i, 2] * f_b[2]
    # skew(v)
    sv = np.zeros((3, 3))
    sv[0, 1] = -vd
    sv[0, 2] = ve
    sv[1, 0] = vd
    sv[1, 2] = -vn
    sv[2, 0] = -ve
    sv[2, 1] = vn
    # --- attitude rows ----------------------------------------------------------------------
    # -[w_in x]
    f_out[0, 1] = win[2]
    f_out[0, 2] = -win[1]
    f_out[1, 0] = -win[2]
    f_out[1, 2] = win[0]
    f_out[2, 0] = win[1]
    f_out[2, 1] = -win[0]
    for i in range(3):
        for j in range(3):
            f_out[i, 3 + j] = dwen_dv[i, j]
            f_out[i, 6 + j] = dwie_dr[i, j] + dwen_dr[i, j]
            f_out[i, 9 + j] = -c_nb[i, j]
    # --- velocity rows ----------------------------------------------------------------------
    # [f_n x]
    f_out[3, 1] = -f_n[2]
    f_out[3, 2] = f_n[1]
    f_out[4, 0] = f_n[2]
    f_out[4, 2] = -f_n[0]
    f_out[5, 0] = -f_n[1]
    f_out[5, 1] = f_n[0]
    c = (2.0 * wie[0] + wen[0], 2.0 * wie[1] + wen[1], 2.0 * wie[2] + wen[2])
    # -[(2 w_ie + w_en) x] + [v x] dwen_dv
    f_out[3, 4] = c[2]
    f_out[3, 5] = -c[1]
    f_out[4, 3] = -c[2]
    f_out[4, 5] = c[0]
    f_out[5, 3] = c[1]
    f_out[5, 4] = -c[0]
    for i in range(3):
        for j in range(3):
            acc_v = 0.0
            acc_r = 0.0
            for k in range(3):
                acc_v += sv[i, k] * dwen_dv[k, j]
                acc_r += sv[i, k] * (2.0 * dwie_dr[k, j] + dwen_dr[k, j])
            f_out[3 + i, 3 + j] += acc_v
            f_out[3 + i, 6 + j] = acc_r
            f_out[3 + i, 12 + j] = c_nb[i, j]
    # gravity with height: dg_D = (2 g / R) dr_D (unstable vertical channel)
    f_out[5, 8] += 2.0 * _gravity(lat, h) / (math.sqrt(r_m * r_n) + h)
    # --- position rows (NED metres) ---------------------------------------------------------
    f_out[6, 6] = -vd / rm
    f_out[6, 8] = vn / rm
    f_out[7, 6] = ve * tl / rn
    f_out[7, 7] = -(vd + vn * tl) / rn
    f_out[7, 8] = ve / rn
    for i in range(3):
        f_out[6 + i, 3 + i] = 1.0
    # --- sensor biases ----------------------------------------------------------------------
    for i in range(3):
        f_out[9 + i, 9 + i] = -inv_tau_g
        f_out[12 + i, 12 + i] = -inv_tau_a


def f_matrix(
    lat_rad: float,
    height_m: float,
    v_n_mps: ArrayLike,
    c_nb: ArrayLike,
    f_b_mps2: ArrayLike,
    *,
    gyro_tau_s: float = math.inf,
    accel_tau_s: float = math.inf,
) -> NDArray:
    """Continuous-time error dynamics F (15x15) at one epoch; see the module docstring."""
    out = np.empty((N_STATES, N_STATES))
    fill_f_matrix(
        float(lat_rad),
        float(height_m),
        np.asarray(v_n_mps, dtype=float),
        np.ascontiguousarray(c_nb, dtype=float),
        np.asarray(f_b_mps2, dtype=float),
        0.0 if math.isinf(gyro_tau_s) else 1.0 / gyro_tau_s,
        0.0 if math.isinf(accel_tau_s) else 1.0 / accel_tau_s,
        out,
    )
    return out
