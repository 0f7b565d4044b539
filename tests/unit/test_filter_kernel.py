"""The compiled parts of algorithm A's forward pass, each against a plain numpy statement of its
equation (pospp/nav/_filter_kernel.py, issue 17 item 3). Seeded random states; the margins are a
few ulp of the quantities compared."""

from __future__ import annotations

import numpy as np
import pytest

from pospp import earth, rotation
from pospp.nav import _filter_kernel as fk
from pospp.nav.error_model import I_BA, I_BG, I_DR, I_DV, I_PHI, f_matrix

RNG = np.random.default_rng(20260517)
N = 24  # 15 + Gauss-Markov (6) + lever arm (3)
I_GM, I_SF, I_L = 15, -1, 21


def _skew(v: np.ndarray) -> np.ndarray:
    return rotation.skew(v)


def _state() -> np.ndarray:
    q = rotation.quat_from_euler(np.radians([2.0, -3.0, 40.0]))
    return np.concatenate([[np.radians(34.2), np.radians(-118.1), 250.0], [20.0, -5.0, 0.4], q])


def _spd(n: int) -> np.ndarray:
    a = RNG.standard_normal((n, n)) * 0.1
    return a @ a.T + np.eye(n) * 1e-3


def test_correct_increments_and_gauss_markov_decay():
    w, f = RNG.standard_normal(3) * 0.1, RNG.standard_normal(3) + [0, 0, -9.8]
    sens = RNG.standard_normal(fk.N_SENS) * 1e-3
    dt = 0.01
    dth, dv = np.empty(3), np.empty(3)
    fk.correct_increments(w, f, sens, dt, dth, dv)
    s = fk
    np.testing.assert_allclose(dth, (w - sens[s.SENS_BG:s.SENS_BG + 3]
                                     - sens[s.SENS_GM_G:s.SENS_GM_G + 3]) * dt
                               / (1 + sens[s.SENS_SG:s.SENS_SG + 3]), rtol=1e-15)
    np.testing.assert_allclose(dv, (f - sens[s.SENS_BA:s.SENS_BA + 3]
                                    - sens[s.SENS_GM_A:s.SENS_GM_A + 3]) * dt
                               / (1 + sens[s.SENS_SA:s.SENS_SA + 3]), rtol=1e-15)
    before = sens.copy()
    fk.decay_gauss_markov(sens, dt, np.array([1 / 300.0, 1 / 600.0]))
    np.testing.assert_allclose(sens[12:15], before[12:15] * np.exp(-dt / 300.0), rtol=1e-15)
    np.testing.assert_allclose(sens[15:18], before[15:18] * np.exp(-dt / 600.0), rtol=1e-15)
    assert np.array_equal(sens[:12], before[:12])


def test_propagate_covariance_matches_numpy():
    x = _state()
    fm, wm, t_acc = np.array([0.3, -0.2, -9.7]), np.array([0.01, 0.02, -0.03]), 0.1
    inv_tau = np.array([1 / 300.0, 1 / 600.0])
    p, phi_acc = _spd(N), np.eye(N) + 0.01 * RNG.standard_normal((N, N))
    qc = np.diag(RNG.uniform(0, 1e-6, N))
    p_new, phi_new = fk.propagate_covariance(p, phi_acc, x, fm, wm, t_acc, qc, I_GM, I_SF,
                                             inv_tau)
    c_nb = rotation.dcm_from_quat(x[6:10])
    f = np.zeros((N, N))
    f[:15, :15] = f_matrix(x[0], x[2], x[3:6], c_nb, fm)
    f[I_PHI:I_PHI + 3, I_GM:I_GM + 3] = -c_nb
    f[I_DV:I_DV + 3, I_GM + 3:I_GM + 6] = c_nb
    f[I_GM:I_GM + 6, I_GM:I_GM + 6] = np.diag(np.repeat(-inv_tau, 3))
    ft = f * t_acc
    phi = np.eye(N) + ft + ft @ ft / 2
    want = phi @ p @ phi.T + t_acc / 2 * (phi @ qc @ phi.T + qc)
    np.testing.assert_allclose(p_new, 0.5 * (want + want.T), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(phi_new, phi @ phi_acc, rtol=1e-12, atol=1e-15)


A_N = np.array([0.8, -1.5, 0.1])
"""The epoch's last interval's mean acceleration, NED [m/s^2] (a turn's)."""


def _model(kind: int, z: np.ndarray, dt_meas: float = 0.0):
    x, lever, w_b = _state(), np.array([0.5, -0.2, -1.1]), np.array([0.02, -0.01, 0.05])
    h_mat, dz = np.full((3, N), np.nan), np.empty(3)
    fk.measurement_model(kind, x, lever, w_b, A_N, z, dt_meas, I_GM, I_SF, I_L, h_mat, dz)
    return x, lever, w_b, h_mat, dz


def _nav_rates(x: np.ndarray) -> np.ndarray:
    lat, h, vn, ve = x[0], x[2], x[3], x[4]
    r_m, r_n = (float(r) for r in earth.principal_radii_m(lat))
    w_ie = earth.EARTH_RATE_RADPS * np.array([np.cos(lat), 0.0, -np.sin(lat)])
    w_en = np.array([ve / (r_n + h), -vn / (r_m + h), -ve * np.tan(lat) / (r_n + h)])
    return w_ie + w_en


def test_position_model_matches_numpy():
    z = _state()[:3] + [1e-7, -2e-7, 3.0]
    x, lever, w_b, h_mat, dz = _model(fk.MEAS_POSITION, z, dt_meas=0.02)
    c_nb = rotation.dcm_from_quat(x[6:10])
    cl = c_nb @ lever
    r_m, r_n = (float(r) for r in earth.principal_radii_m(x[0]))
    d_ned = np.array([(z[0] - x[0]) * (r_m + x[2]), (z[1] - x[1]) * (r_n + x[2]) * np.cos(x[0]),
                      -(z[2] - x[2])])
    v_ant = x[3:6] + c_nb @ np.cross(w_b, lever) - np.cross(_nav_rates(x), cl)
    np.testing.assert_allclose(dz, cl - d_ned + v_ant * 0.02, rtol=1e-9, atol=1e-9)
    want = np.zeros((3, N))
    want[:, I_PHI:I_PHI + 3] = _skew(cl)
    want[:, I_DR:I_DR + 3] = np.eye(3)
    want[:, I_L:I_L + 3] = c_nb
    np.testing.assert_allclose(h_mat, want, rtol=1e-15, atol=1e-15)


def test_velocity_model_matches_numpy():
    z = np.array([19.9, -5.1, 0.3])
    # a record 0.02 s after its epoch: the velocity there, with the epoch's mean acceleration
    x, lever, w_b, h_mat, dz = _model(fk.MEAS_VELOCITY, z, dt_meas=0.02)
    c_nb = rotation.dcm_from_quat(x[6:10])
    w_in = _nav_rates(x)
    cwl = c_nb @ np.cross(w_b, lever)
    np.testing.assert_allclose(dz, x[3:6] + cwl - np.cross(w_in, c_nb @ lever) + A_N * 0.02 - z,
                               rtol=1e-12, atol=1e-12)
    want = np.zeros((3, N))
    want[:, I_PHI:I_PHI + 3] = _skew(cwl)
    want[:, I_DV:I_DV + 3] = np.eye(3)
    want[:, I_BG:I_BG + 3] = -c_nb @ _skew(lever)
    want[:, I_GM:I_GM + 3] = -c_nb @ _skew(lever)
    want[:, I_L:I_L + 3] = c_nb @ _skew(w_b) - _skew(w_in) @ c_nb
    np.testing.assert_allclose(h_mat, want, rtol=1e-13, atol=1e-15)
    assert not h_mat[:, I_BA:I_BA + 3].any()


def test_innovation_covariance_update_and_reset_match_numpy():
    p, h_mat = _spd(N), RNG.standard_normal((3, N))
    r, dz = _spd(3), RNG.standard_normal(3)
    s_inv = np.empty((3, 3))
    ph, ok = fk.innovation_covariance(p, h_mat, r, s_inv)
    s = h_mat @ p @ h_mat.T + r
    assert ok
    np.testing.assert_allclose(s_inv, np.linalg.inv(s), rtol=1e-10)
    assert fk.normalised_innovation(dz, s_inv) == pytest.approx(dz @ np.linalg.solve(s, dz),
                                                                rel=1e-12)
    p_new, dx = fk.kalman_update(p, ph, s_inv, h_mat, dz, r)
    k = p @ h_mat.T @ np.linalg.inv(s)
    ikh = np.eye(N) - k @ h_mat
    joseph = ikh @ p @ ikh.T + k @ r @ k.T
    np.testing.assert_allclose(dx, k @ dz, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(p_new, 0.5 * (joseph + joseph.T), rtol=1e-9, atol=1e-14)
    # the Joseph form equals (I - K H) P for the optimal gain
    np.testing.assert_allclose(p_new, ikh @ p, rtol=1e-7, atol=1e-12)
    fk.reset_block(p, I_DR, dz, r)
    assert not p[I_DR:I_DR + 3, :I_DR].any() and not p[:I_DR, I_DR:I_DR + 3].any()
    np.testing.assert_array_equal(np.diag(p)[I_DR:I_DR + 3], dz**2 + np.diag(r))
    assert not fk.innovation_covariance(p, np.zeros((3, N)), np.zeros((3, 3)), s_inv)[1]


def test_feedback_and_store_output():
    x, xp = _state(), _state() - 1e-9
    sens, lever = np.zeros(fk.N_SENS), np.array([0.5, 0.0, -1.0])
    dx = RNG.standard_normal(N) * 1e-6
    xp_before = xp.copy()
    x_before = x.copy()
    fk.feedback(x, xp, sens, lever, dx, I_GM, I_SF, I_L)
    np.testing.assert_allclose(x[3:6], x_before[3:6] - dx[I_DV:I_DV + 3], rtol=1e-15)
    np.testing.assert_allclose(xp[:3] - xp_before[:3], x[:3] - x_before[:3], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(sens[fk.SENS_BG:fk.SENS_BG + 3], dx[I_BG:I_BG + 3])
    np.testing.assert_array_equal(sens[fk.SENS_BA:fk.SENS_BA + 3], dx[I_BA:I_BA + 3])
    np.testing.assert_array_equal(sens[fk.SENS_GM_G:fk.SENS_GM_G + 6], dx[I_GM:I_GM + 6])
    assert not sens[fk.SENS_SG:fk.SENS_SA + 3].any()  # no scale-factor states
    np.testing.assert_allclose(lever, [0.5, 0.0, -1.0] - dx[I_L:I_L + 3], rtol=1e-15)
    p = _spd(N)
    outs = (np.empty((1, 10)), np.empty((1, N)), np.empty((1, 3, 3, 3)), np.empty((1, 12)),
            np.empty((1, 6)), np.empty((1, 3)))
    fk.store_output(0, x, p, sens, lever, I_GM, outs)
    out_x, out_diag, out_blk, out_sens, out_bvar, out_lever = (a[0] for a in outs)
    np.testing.assert_array_equal(out_x, x)
    np.testing.assert_array_equal(out_diag, np.diag(p))
    for i, b in enumerate((I_PHI, I_DV, I_DR)):
        np.testing.assert_array_equal(out_blk[i], p[b:b + 3, b:b + 3])
    np.testing.assert_allclose(out_sens[:6], sens[:6] + sens[12:18], rtol=1e-15)
    np.testing.assert_array_equal(out_sens[6:], sens[6:12])
    pb = p[I_BG:I_BG + 6, I_BG:I_BG + 6] + p[I_GM:I_GM + 6, I_GM:I_GM + 6] \
        + 2 * p[I_BG:I_BG + 6, I_GM:I_GM + 6]
    np.testing.assert_allclose(out_bvar, np.diag(pb), rtol=1e-14)
    np.testing.assert_array_equal(out_lever, lever)
