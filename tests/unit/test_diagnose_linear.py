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


def test_rewhitened_eigenbasis_matches_the_cholesky_factor():
    reps = _replays()
    a0, arw0 = 1.3, 2e-6
    flight = Problem(reps, a0, arw0)
    rng = np.random.default_rng(7)
    other = tuple(replace(r, dv_n_mps=r.dv_n_mps + rng.normal(0, 0.004, r.dv_n_mps.shape))
                  for r in reps)
    a1, arw1 = 0.7, 5e-6
    shared = flight.rewhitened(other, a1, arw1)
    direct = Problem(other, a1, arw1)  # its own Cholesky factors
    assert shared.eig is not None and direct.eig is None
    # W Sigma W^T = I on every leg (Sigma = a S^2 + q K written out)
    for i, r in enumerate(other):
        s = r.sigma_v_n_mps[1:, 0:2].reshape(-1)
        cov = arw1**2 * gyro_noise_covariance(r) + np.diag(a1 * s**2)
        w_l = shared.whiten(i, linalg.cholesky(cov, lower=True))
        np.testing.assert_allclose(w_l @ w_l.T, np.eye(s.size), atol=1e-8)
    terms = [Term("cols", [rng.normal(size=(z.size, 3)) for z in flight.z]),
             Term("local", [rng.normal(size=(z.size, 1)) * (i == 1)
                            for i, z in enumerate(flight.z)], local_leg=1)]
    for sub in (terms[:1], terms):
        f_s, f_d = shared.fit(sub), direct.fit(sub)
        assert f_s.rank == f_d.rank
        np.testing.assert_allclose(f_s.rss_w, f_d.rss_w, rtol=1e-9)
        np.testing.assert_allclose(f_s.x, f_d.x, rtol=1e-7, atol=1e-12)
    res = [np.ravel(r) for r in shared.fit(terms).res_raw]
    np.testing.assert_allclose(shared.whitened_rms(res, [0, 1, 2]),
                               direct.whitened_rms(res, [0, 1, 2]), rtol=1e-9)
