"""The whitened least squares of the workflow (pospp.diagnose._linear): a problem re-whitened
through its shared eigenbasis fits exactly as the Cholesky factor of the same covariance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _synthetic import noisy_replays, survey_flight
from scipy import linalg

from pospp.calib.noise_model import gyro_noise_covariance
from pospp.calib.replay import ImuIncrements
from pospp.diagnose._linear import Problem, Term


def _replays():
    fl = survey_flight(headings_deg=(0.0, 180.0, 0.0), rate_hz=20.0, leg_duration_s=120.0)
    imu = ImuIncrements(fl.imu.t_s, fl.imu.dtheta_b_rad, fl.imu.dv_b_mps.copy())
    ref = fl.solution_a(0.003)
    return noisy_replays(fl, imu, sigma_mps=0.003, rng=np.random.default_rng(3), solution_a=ref)


def test_per_leg_term_is_zero_on_the_other_legs():
    # Problem.wblocks shares those zero blocks instead of whitening them
    with pytest.raises(ValueError, match="zero on the other legs"):
        Term("local", [np.ones((4, 1)), np.ones((4, 1))], local_leg=0)
    assert Term("local", [np.ones((4, 1)), np.zeros((4, 1))], local_leg=0).local_leg == 0


def test_kalman_whitening_is_the_cholesky_factors():
    # the Kalman filter's normalised innovations are L^-1 y, L the Cholesky factor of
    # Sigma = a S^2 + q K written out (gyro_noise_covariance), on the flight's problem and on
    # a re-whitened one (the null realisations': other data, another a and q)
    reps = _replays()
    a0, arw0 = 1.3, 2e-6
    flight = Problem(reps, a0, arw0)
    rng = np.random.default_rng(7)
    other = tuple(replace(r, dv_n_mps=r.dv_n_mps + rng.normal(0, 0.004, r.dv_n_mps.shape))
                  for r in reps)
    a1, arw1 = 0.7, 5e-6
    shared = flight.rewhitened(other, a1, arw1)
    chol = []
    for prob, a, arw in ((flight, a0, arw0), (shared, a1, arw1)):
        factors = []
        for i, r in enumerate(prob.reps):
            s = r.sigma_v_n_mps[1:, 0:2].reshape(-1)
            cov = arw**2 * gyro_noise_covariance(r) + np.diag(a * s**2)
            ll = linalg.cholesky(cov, lower=True)
            y = rng.normal(size=(s.size, 3))
            np.testing.assert_allclose(prob.whiten(i, y),
                                       linalg.solve_triangular(ll, y, lower=True),
                                       rtol=1e-8, atol=1e-8 * np.abs(y).max() / s.min())
            w_l = prob.whiten(i, ll)  # W Sigma W^T = I
            np.testing.assert_allclose(w_l @ w_l.T, np.eye(s.size), atol=1e-8)
            factors.append(ll)
        chol.append(factors)
    terms = [Term("cols", [rng.normal(size=(z.size, 3)) for z in flight.z]),
             Term("local", [rng.normal(size=(z.size, 1)) * (i == 1)
                            for i, z in enumerate(flight.z)], local_leg=1)]
    for sub in (terms[:1], terms):
        # the fit against least squares whitened by the Cholesky factors
        f_s = shared.fit(sub)
        hw = np.vstack([linalg.solve_triangular(ll, np.hstack([t.blocks[i] for t in sub]),
                                                lower=True) for i, ll in enumerate(chol[1])])
        zw = np.concatenate([linalg.solve_triangular(ll, z, lower=True)
                             for ll, z in zip(chol[1], shared.z, strict=True)])
        x, rss, rank, _ = np.linalg.lstsq(hw, zw, rcond=None)
        assert f_s.rank == rank
        np.testing.assert_allclose(f_s.rss_w, rss[0], rtol=1e-9)
        np.testing.assert_allclose(f_s.x, x, rtol=1e-7, atol=1e-12)
    direct = Problem(other, a1, arw1)
    res = [np.ravel(r) for r in shared.fit(terms).res_raw]
    np.testing.assert_allclose(shared.whitened_rms(res, [0, 1, 2]),
                               direct.whitened_rms(res, [0, 1, 2]), rtol=1e-9)


def test_fit_with_every_legs_own_terms_is_the_stacked_least_squares():
    # Problem.fit adds each leg's normal equations over its own columns only (the common
    # terms and its per-leg ones, as the lack-of-fit terms): against least squares on the
    # whole stacked design with its zero blocks, whitened by the sigmas, on all legs and on
    # some (the held-out fits')
    reps = _replays()
    prob = Problem(reps, 1.0, 0.0)
    rng = np.random.default_rng(11)
    terms = [Term("common", [rng.normal(size=(z.size, 2)) for z in prob.z])]
    terms += [Term(f"own{j}", [rng.normal(size=(z.size, 2 + j)) * (i == j)
                               for i, z in enumerate(prob.z)], local_leg=j)
              for j in range(len(prob.z))]
    for legs in ([0, 1, 2], [0, 2]):
        fit = prob.fit(terms, legs)
        hw = np.vstack([np.hstack([t.blocks[i] for t in terms]) / prob.sig[i][:, None]
                        for i in legs])
        zw = np.concatenate([prob.z[i] / prob.sig[i] for i in legs])
        x, rss, rank, _ = np.linalg.lstsq(hw, zw, rcond=None)
        assert fit.rank == rank  # leg 1's own columns are all zero without leg 1: minimum norm
        np.testing.assert_allclose(fit.rss_w, np.sum((zw - hw @ x) ** 2), rtol=1e-9)
        np.testing.assert_allclose(fit.x, x, rtol=1e-7, atol=1e-12 * np.abs(x).max())
        for i, res in zip(legs, fit.res_raw, strict=True):
            np.testing.assert_allclose(res, prob.z[i] - np.hstack([t.blocks[i] for t in terms])
                                       @ x, rtol=1e-9, atol=1e-12 * np.abs(prob.z[i]).max())


def test_kalman_whitening_refuses_a_covariance_that_is_not_positive_definite():
    from pospp.diagnose._linear import _kalman_gains

    g = np.zeros((3, 2, 15))
    g[:, 0, 0] = g[:, 1, 1] = 1.0
    ds = np.zeros((3, 15, 15))
    with pytest.raises(ValueError, match="not positive definite"):
        _kalman_gains(g, ds, 1.0, np.zeros(6))  # no noise at all: a singular covariance
    gains, chol = _kalman_gains(g, ds, 1.0, np.ones(6))
    np.testing.assert_allclose(chol, [[1.0, 0.0, 1.0]] * 3)
    assert not gains.any()
