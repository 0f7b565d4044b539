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

with dg(dr) = [0, 0, d gamma/d lat dr_N / (R_M + h) - d gamma/d h dr_D] (normal gravity at the
computed position, exact gradients from :func:`pospp.earth.gravity_gradient_formula`). Every
entry is checked against a finite-difference Jacobian of the nonlinear NED navigation equations
(tests/unit/test_error_model.py).
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

from pospp import rotation
from pospp.earth import EARTH_RATE_RADPS, gravity_gradient_formula, radii_formula
from pospp.nav._kernels import dcm_from_quat_into

_radii = njit(cache=True)(radii_formula)
_gravity_gradient = njit(cache=True)(gravity_gradient_formula)

N_STATES = 15
I_PHI, I_DV, I_DR, I_BG, I_BA = 0, 3, 6, 9, 12
"""First index of each 3-state block of the 15-state error vector (the names every kernel
uses): misalignment phi_n, velocity error dv_n, position error dr_n (NED m), gyro bias, accel
bias."""
PHI, DV, DR, BG, BA = (slice(i, i + 3) for i in (I_PHI, I_DV, I_DR, I_BG, I_BA))
"""Slices of the 15-state error vector."""
N_NAV = I_BG
"""The navigation errors (phi_n, dv_n, dr_n) come first: the states after them (biases,
Gauss-Markov biases, scale factors, lever arm) have F rows holding their own decay alone."""


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
            f_out[I_PHI + i, I_DV + j] = dwen_dv[i, j]
            f_out[I_PHI + i, I_DR + j] = dwie_dr[i, j] + dwen_dr[i, j]
            f_out[I_PHI + i, I_BG + j] = -c_nb[i, j]
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
            f_out[I_DV + i, I_DV + j] += acc_v
            f_out[I_DV + i, I_DR + j] = acc_r
            f_out[I_DV + i, I_BA + j] = c_nb[i, j]
    # normal gravity at the computed position: dg_D = dgamma/dlat dlat + dgamma/dh dh with
    # dlat = dr_N / (R_M + h), dh = -dr_D (exact gradients; dgamma/dh ~ -3.08e-6 /s^2 gives the
    # unstable vertical channel)
    dg_dlat, dg_dh = _gravity_gradient(lat, h)
    f_out[5, 6] += dg_dlat / rm
    f_out[5, 8] -= dg_dh
    # --- position rows (NED metres) ---------------------------------------------------------
    f_out[6, 6] = -vd / rm
    f_out[6, 8] = vn / rm
    f_out[7, 6] = ve * tl / rn
    f_out[7, 7] = -(vd + vn * tl) / rn
    f_out[7, 8] = ve / rn
    for i in range(3):
        f_out[I_DR + i, I_DV + i] = 1.0
    # --- sensor biases ----------------------------------------------------------------------
    for i in range(3):
        f_out[I_BG + i, I_BG + i] = -inv_tau_g
        f_out[I_BA + i, I_BA + i] = -inv_tau_a


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


@njit(cache=True, nogil=True)
def _transition_kernel(t_s, lat, h, v_n, q_nb, f_b, step, inv_tau_g, inv_tau_a, out):
    """Fill ``out`` (M, 15, 15) with Phi(t_j, t_0) at the nodes t_j = t_s[j * step].

    Each node-to-node step uses F at the segment's middle epoch with the mean specific force of
    the segment, and Phi_step = exp(F dt) by a 4th-order Taylor series (|F dt| << 1 for the
    sub-second steps used here; the error is O((F dt)^5)).
    """
    n_nodes = out.shape[0]
    f_mat = np.empty((15, 15))
    c_nb = np.empty((3, 3))
    fb = np.empty(3)
    a = np.empty((15, 15))
    term = np.empty((15, 15))
    phi_step = np.empty((15, 15))
    for i in range(15):
        for j in range(15):
            out[0, i, j] = 1.0 if i == j else 0.0
    for node in range(1, n_nodes):
        k0 = (node - 1) * step
        k1 = node * step
        dt = t_s[k1] - t_s[k0]
        for j in range(3):
            acc = 0.0
            for k in range(k0, k1):
                acc += f_b[k, j]
            fb[j] = acc / (k1 - k0)
        # F at the segment's middle epoch
        km = (k0 + k1) // 2
        dcm_from_quat_into(q_nb[km], c_nb)
        fill_f_matrix(lat[km], h[km], v_n[km], c_nb, fb, inv_tau_g, inv_tau_a, f_mat)
        # phi_step = I + A + A^2/2 + A^3/6 + A^4/24, A = F dt
        for i in range(15):
            for j in range(15):
                a[i, j] = f_mat[i, j] * dt
                term[i, j] = a[i, j]
                phi_step[i, j] = (1.0 if i == j else 0.0) + a[i, j]
        for order in range(2, 5):
            nxt = term @ a
            for i in range(15):
                for j in range(15):
                    term[i, j] = nxt[i, j] / order
                    phi_step[i, j] += term[i, j]
        out[node] = phi_step @ out[node - 1]


def transition_matrices(
    trajectory,
    f_b_mps2: ArrayLike,
    *,
    step: int = 10,
    gyro_tau_s: float = math.inf,
    accel_tau_s: float = math.inf,
) -> NDArray:
    """Numerical transition matrices Phi(t_j, t_0) of F(t) along an actual trajectory.

    dx(t_j) = Phi(t_j, t_0) dx(t_0), with dx the 15-state error of the module docstring and
    F(t) evaluated along the trajectory (this is what lets the calibration follow real,
    wandering legs rather than the ideal constant-velocity leg of paper Eq. 3-14).

    Parameters
    ----------
    trajectory : pospp.nav.strapdown.Trajectory
        N + 1 epochs (e.g. algorithm B's pure-inertial solution over one leg).
    f_b_mps2 : array_like, shape (N, 3)
        Mean specific force of each interval, body FRD [m/s^2].
    step : int
        IMU intervals per transition step; the nodes are epochs ``0, step, 2 step, ...``.
    gyro_tau_s, accel_tau_s : float
        Bias correlation times [s] (inf: random constants).

    Returns
    -------
    ndarray, shape (M, 15, 15)
        Phi at the M = N // step + 1 nodes, ``Phi[0] = I``.
    """
    if step < 1:
        raise ValueError(f"step: expected an integer >= 1, got {step}")
    t = np.ascontiguousarray(trajectory.t_s, dtype=float)
    f_b = np.ascontiguousarray(f_b_mps2, dtype=float)
    n = t.shape[0] - 1
    if f_b.shape != (n, 3):
        raise ValueError(f"f_b_mps2: expected shape ({n}, 3), got {f_b.shape}")
    out = np.empty((n // step + 1, N_STATES, N_STATES))
    _transition_kernel(
        t,
        np.ascontiguousarray(trajectory.lat_rad, dtype=float),
        np.ascontiguousarray(trajectory.height_m, dtype=float),
        np.ascontiguousarray(trajectory.v_n_mps, dtype=float),
        np.ascontiguousarray(trajectory.q_nb, dtype=float),
        f_b,
        int(step),
        0.0 if math.isinf(gyro_tau_s) else 1.0 / gyro_tau_s,
        0.0 if math.isinf(accel_tau_s) else 1.0 / accel_tau_s,
        out,
    )
    return out


def rpy_covariance(q_nb: NDArray, att_cov: NDArray) -> NDArray:
    """Covariance of [roll, pitch, yaw] errors from the phi covariance (d rpy = -E^-1 phi).

    E's columns are the roll, pitch and yaw axes in NED (``Rz Ry e_x``, ``Rz e_y``, ``e_z``),
    so ``phi = E d rpy`` up to sign and, with det E = cos(pitch), in closed form::

        E^-1 = [[ cz / cy,      sz / cy,      0],
                [-sz,           cz,           0],
                [ sy cz / cy,   sy sz / cy,   1]]

    (c, s of yaw z and pitch y; singular at pitch +-90 deg, where roll and yaw merge).
    """
    rpy = rotation.euler_from_quat(q_nb)
    cz, sz = np.cos(rpy[:, 2]), np.sin(rpy[:, 2])
    cy, sy = np.cos(rpy[:, 1]), np.sin(rpy[:, 1])
    e_inv = np.zeros((q_nb.shape[0], 3, 3))
    e_inv[:, 0, 0] = cz / cy
    e_inv[:, 0, 1] = sz / cy
    e_inv[:, 1, 0] = -sz
    e_inv[:, 1, 1] = cz
    e_inv[:, 2, 0] = sy * e_inv[:, 0, 0]
    e_inv[:, 2, 1] = sy * e_inv[:, 0, 1]
    e_inv[:, 2, 2] = 1.0
    return e_inv @ att_cov @ np.swapaxes(e_inv, 1, 2)
