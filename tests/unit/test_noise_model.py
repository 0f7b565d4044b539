"""The noise model of B minus A (pospp.calib.noise_model.NoiseModel) against closed forms.

- B's velocity error driven by white gyro noise on a short level leg is an integrated
  Brownian motion: Var dv(t) = g^2 q t^3 / 3, Cov(dv(s), dv(t)) = g^2 q (s^2 t / 2 - s^3 / 6)
  for s <= t (Schuler terms below 0.5 % over 60 s).
- B's velocity error driven by white accelerometer noise is a Brownian motion:
  Cov(dv(s), dv(t)) = q min(s, t) per channel (Schuler terms below 0.5 % over 60 s).
- A's own coloured error enters B minus A as Phi_v,v(t) e(t0) - e(t): checked against a Monte
  Carlo of a Matern-3/2 process simulated through its state-space form (exact discretisation
  by the matrix exponential, scipy), not through pospp's correlation function.
- Data drawn from the model: the workflow with ``noise="full"`` (REML on the model) closes
  with ``none``; the white-noise model on the same data cries wolf.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _synthetic import survey_flight
from scipy import linalg

from pospp.calib.noise_model import (
    NoiseModel,
    accel_noise_covariance,
    gyro_noise_covariance,
    reference_error_covariance,
)
from pospp.calib.replay import replay_leg
from pospp.calib.solve import fit_noise_model
from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays

G_MPS2 = 9.80


@pytest.fixture(scope="module")
def flight():
    return survey_flight(headings_deg=(0.0, 180.0, 90.0), leg_duration_s=200.0, rate_hz=50.0)


@pytest.fixture(scope="module")
def replays(flight):
    ref = flight.solution_a(0.002)
    return [replay_leg(flight.imu, ref, leg, sigma_floor_mps=0.002) for leg in flight.legs]


def test_gyro_noise_covariance_is_integrated_brownian_motion(replays):
    rep = replays[0]  # heading north: dv_N from the east tilt, dv_E from the north tilt
    rows = np.array([1, 2, 5, 10, 30, 60])
    k = gyro_noise_covariance(rep, rows).reshape(rows.size, 2, rows.size, 2)
    t = rep.t_s[rows]
    s, u = np.minimum.outer(t, t), np.maximum.outer(t, t)
    want = G_MPS2**2 * (s**2 * u / 2.0 - s**3 / 6.0)
    for ch in range(2):
        # 1 % margin: Schuler and Earth-rate terms are < 0.5 % at 60 s; a left Riemann sum
        # misses by 200 % at t = 1 s and by 5 % at 30 s
        np.testing.assert_allclose(k[:, ch, :, ch], want, rtol=0.01)
    assert np.abs(k[:, 0, :, 1]).max() < 1e-3 * want.max()


def test_accel_noise_covariance_is_brownian_motion(replays):
    """The same quadrature with the accelerometer's forcing C_nb w_a (issue 18 rewrote it as
    g_i S(min(t_i, t_j)) g_j^T): unit white noise gives Cov(dv_i, dv_j) = min(t_i, t_j)."""
    rep = replays[2]  # heading east
    rows = np.array([1, 2, 5, 10, 30, 60])
    k = accel_noise_covariance(rep, rows).reshape(rows.size, 2, rows.size, 2)
    want = np.minimum.outer(rep.t_s[rows], rep.t_s[rows])
    for ch in range(2):
        np.testing.assert_allclose(k[:, ch, :, ch], want, rtol=0.01)
    assert np.abs(k[:, 0, :, 1]).max() < 1e-2 * want.max()
    # symmetric, and the rows' order does not matter
    np.testing.assert_array_equal(k, k.transpose(2, 3, 0, 1))
    perm = np.array([3, 0, 5, 1, 4, 2])
    kp = accel_noise_covariance(rep, rows[perm]).reshape(rows.size, 2, rows.size, 2)
    np.testing.assert_allclose(kp, k[perm][:, :, perm], rtol=1e-12, atol=1e-15)


def _matern32_paths(t_s: np.ndarray, length_s: float, n: int, rng) -> np.ndarray:
    """Unit-variance Matern-3/2 paths at t_s (n, T) from its 2-state SDE (exact steps)."""
    lam = np.sqrt(3.0) / length_s
    f = np.array([[0.0, 1.0], [-lam**2, -2.0 * lam]])
    qc = 4.0 * lam**3
    p_inf = np.diag([1.0, lam**2])
    x = rng.multivariate_normal(np.zeros(2), p_inf, size=n)
    out = np.empty((n, t_s.size))
    out[:, 0] = x[:, 0]
    for i in range(1, t_s.size):
        dt = t_s[i] - t_s[i - 1]
        vl = linalg.expm(np.block([[-f, np.diag([0.0, qc])], [np.zeros((2, 2)), f.T]]) * dt)
        phi = vl[2:, 2:].T
        q = phi @ vl[:2, 2:]
        x = x @ phi.T + rng.multivariate_normal(np.zeros(2), 0.5 * (q + q.T), size=n)
        out[:, i] = x[:, 0]
    return out


def test_reference_error_covariance_matches_monte_carlo(replays):
    rep = replays[1]
    rows = np.array([1, 3, 10, 25, 60, 150])
    length = 20.0
    c = reference_error_covariance(rep, length, rows)
    rng = np.random.default_rng(12)
    n = 6000
    t_all = np.concatenate([[0.0], rep.t_s[rows]])
    e = np.stack([_matern32_paths(t_all, length, n, rng) for _ in range(2)], axis=2)  # (n,T,2)
    p = rep.phi[rows][:, 3:5, 3:5]
    d = np.einsum("iab,nb->nia", p, e[:, 0, :]) - e[:, 1:, :]
    x = d.reshape(n, -1)
    emp = x.T @ x / n
    # sampling sigma of a covariance entry <= sqrt(2 / n) * 2 = 0.037
    assert np.abs(emp - c).max() < 0.15
    # the propagated start error matters: ignoring it (Cov = r(t_i - t_j) I) is far off
    assert np.abs(emp[0, 0] - 1.0) > 0.5


@pytest.mark.slow
def test_full_model_closes_none_on_data_drawn_from_it(replays):
    model = NoiseModel(white_scale=0.01, gyro_arw_radpsqrts=3e-6,
                       reference_sigma_mps=1e-3, reference_length_s=20.0)
    rng = np.random.default_rng(5)
    closing, closing_white = [], []
    for _ in range(3):
        reps = []
        for rep in replays:
            cov = model.leg_covariance(rep)
            w = np.linalg.cholesky(cov) @ rng.standard_normal(cov.shape[0])
            dv = rep.dv_n_mps.copy()
            dv[1:, 0:2] += w.reshape(-1, 2)
            reps.append(dataclasses.replace(rep, dv_n_mps=dv))
        fitted = fit_noise_model(tuple(reps), noise_step_s=4.0, reference_lengths_s=(20.0,),
                                 reference_kinds=("matern32",))
        # REML recovers A's error level within a factor 2 and the ARW within 30 %
        assert 0.5e-3 < fitted.reference_sigma_mps < 2e-3
        assert fitted.gyro_arw_radpsqrts == pytest.approx(3e-6, rel=0.3)
        effects = ("accel_bias_change", "gravity_disturbance")
        closing.append(diagnose_replays(reps, DiagnosisOptions(noise="full", effects=effects),
                                        noise_model=fitted).conclusion)
        closing_white.append(diagnose_replays(
            reps, DiagnosisOptions(noise="white", effects=effects)).conclusion)
    assert closing == ["none"] * 3
    assert closing_white.count("unexplained") >= 2


@pytest.mark.parametrize("tau_s", [30.0, 300.0, 3000.0, np.inf])
def test_the_drift_s_mean_over_a_leg_is_the_mean_of_its_samples(tau_s):
    # DriftSmoother.mean_over_b_radps factors the bins outside the leg out of the sum: the
    # same mean as the samples' drift averaged, before, across and after the bins
    from pospp.calib.noise_model import DriftSmoother

    rng = np.random.default_rng(2)
    drift = DriftSmoother(np.sort(rng.uniform(0.0, 5000.0, 600)),
                          rng.standard_normal((600, 3)), 1e-10, tau_s)
    for t0 in (-350.0, 1000.0, 4990.0):
        t = t0 + np.arange(0.0, 300.0, 0.1)
        expected = drift.mean_b_radps(t).mean(axis=0)
        np.testing.assert_allclose(drift.mean_over_b_radps(t), expected, rtol=1e-12,
                                   atol=1e-12 * np.abs(expected).max())


def test_the_drift_at_many_times_is_made_a_block_at_a_time_as_at_once(monkeypatch):
    # DriftSmoother.mean_b_radps makes its (N, J) kernel matrix DRIFT_ROWS times at a time
    # (a 1.5 h flight's 1 s grid against its 1100 bins is 50 MB): the same values as the
    # whole matrix at once, whatever the block
    from pospp.calib import noise_model
    from pospp.calib.noise_model import DriftSmoother

    rng = np.random.default_rng(3)
    drift = DriftSmoother(np.sort(rng.uniform(0.0, 5000.0, 300)),
                          rng.standard_normal((300, 3)), 1e-10, 300.0)
    t = np.arange(-100.0, 5400.0, 1.0)
    whole = drift.sigma2 * (np.exp(-np.abs(t[:, None] - drift.tau_bin_s[None, :])
                                   / drift.tau_s) @ drift.u)
    for rows in (1, 7, 512, 10**6):
        monkeypatch.setattr(noise_model, "DRIFT_ROWS", rows)
        np.testing.assert_allclose(drift.mean_b_radps(t), whole, rtol=1e-13,
                                   atol=1e-13 * np.abs(whole).max())
