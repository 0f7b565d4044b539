"""Gauss-Markov gyro drift in the calibration's noise model (pospp.calib.solve).

The drift operator S (B's velocity error per unit piecewise-constant body drift) is checked
against pospp's nonlinear strapdown on exact IMU data of a rhumb line (tests/unit/_truth_imu.py)
with a time-varying gyro bias injected, and, for an infinite correlation time, against the
transition matrices' own gyro-bias block Phi_v,bg. The stage with the drift model runs once on
a short simulated survey with the paper's vehicle IMU (tests/unit/_gm_mission.py); the Monte
Carlo is tests/unit/test_calib_gm_montecarlo.py (slow).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _gm_mission import run_once
from _truth_imu import rhumb_line

from pospp import rotation, units
from pospp.calib.noise_model import gm_covariance, gm_noise_operator, noise_basis
from pospp.calib.replay import ImuIncrements, replay_leg, solution_a_from_trajectory
from pospp.calib.segment import Leg
from pospp.calib.solve import FitOptions, fit_calibration
from pospp.calib.stage import CalibrationOptions, calibrate_flight
from pospp.nav.error_model import BG
from pospp.nav.strapdown import Trajectory

DPH = units.DEG_PER_H_RADPS
LAT = np.radians(40.0)
H_M = 2600.0
V_MPS = 60.0
RATE_HZ = 20.0


def _bias(t_s):
    """A drifting body gyro bias [rad/s], shape (N, 3): constant + slow sinusoids."""
    t = np.asarray(t_s)[:, None]
    return (np.array([0.5, -0.4, 0.2]) + np.array([0.6, 0.5, 0.3])
            * np.sin(2 * np.pi * t / np.array([250.0, 400.0, 180.0]) + 0.3)) * DPH


def _leg(leg_id, heading_deg, bias_fn=None, duration_s=301.0):
    hd = np.radians(heading_deg)
    tr = rhumb_line(LAT, H_M, V_MPS, hd, RATE_HZ, duration_s)
    n = tr.t_s.size
    traj = Trajectory(tr.t_s, tr.lat_rad, tr.lon_rad, np.full(n, H_M),
                      np.tile(tr.v_n_mps, (n, 1)),
                      np.tile(rotation.quat_from_dcm(tr.c_nb), (n, 1)))
    dt = np.diff(tr.t_s)[:, None]
    dth = tr.dtheta_b_rad.copy()
    if bias_fn is not None:
        dth += bias_fn(0.5 * (tr.t_s[1:] + tr.t_s[:-1])) * dt
    imu = ImuIncrements(tr.t_s, dth, tr.dv_b_mps)
    ref = solution_a_from_trajectory(traj, v_sigma_n_mps=[0.02, 0.02, 0.05])
    leg = Leg(leg_id, 1.0, duration_s, hd % (2 * np.pi), V_MPS, H_M, 0.0, 0.0, 0.0, 0.0)
    return replay_leg(imu, ref, leg)


def test_drift_operator_matches_strapdown_with_a_drifting_bias():
    rep = _leg(0, 20.0, _bias)
    rows = np.arange(10, rep.t_s.size, 10)
    s, tau_bin = gm_noise_operator(rep, rows, bin_s=5.0)
    # the drift on each 5 s bin: its mean over the bin (run time = rep.t0_s + leg time)
    tt = rep.t0_s + np.linspace(0.0, rep.t_s[-1], 20001)
    b = _bias(tt)
    edges = rep.t0_s + np.arange(0.0, rep.t_s[-1] + 5.0, 5.0)
    x = np.array([b[(tt >= lo) & (tt < hi)].mean(axis=0)
                  for lo, hi in zip(edges[:-1], edges[1:], strict=True)][:tau_bin.size])
    pred = (s @ x.reshape(-1)).reshape(-1, 2)
    meas = rep.dv_n_mps[rows, 0:2]
    scale = np.abs(meas).max()
    assert scale > 0.3  # a real signal (m/s)
    assert np.abs(pred - meas).max() < 0.02 * scale, (np.abs(pred - meas).max(), scale)


def test_drift_covariance_with_infinite_tau_is_a_random_constant():
    """tau -> inf: the drift is one random constant, Cov = sum over axes of P_a P_a^T with
    P = Phi_v,bg (the transition matrices' own gyro-bias block), coupling the two legs."""
    reps = [_leg(0, 20.0), _leg(1, 200.0)]
    ops, blocks = [], []
    for r in reps:
        rows = noise_basis(r).samples
        ops.append(gm_noise_operator(r, rows))
        blocks.append(r.phi[rows, 3:5, BG].reshape(-1, 3))
    p = np.vstack(blocks)
    g = gm_covariance(ops, 1e15)
    ref = p @ p.T
    assert np.abs(g - ref).max() < 0.02 * np.abs(ref).max()
    # a finite tau: a symmetric positive semi-definite covariance, smaller in trace
    g300 = gm_covariance(ops, 300.0)
    assert np.allclose(g300, g300.T, rtol=0, atol=1e-9 * np.abs(g300).max())
    assert np.linalg.eigvalsh(g300).min() > -1e-9 * np.abs(g300).max()
    assert np.trace(g300) < np.trace(g)


def test_validation_messages():
    reps = (_leg(0, 20.0, _bias), _leg(1, 200.0, _bias))
    with pytest.raises(ValueError, match="gyro_gm_tau_s: expected > 0 s"):
        fit_calibration(reps, "body", FitOptions(gyro_gm_tau_s=0.0))
    with pytest.raises(ValueError, match="compensation"):
        calibrate_flight(ImuIncrements(np.zeros(2), np.zeros((1, 3)), np.zeros((1, 3))), None,
                         CalibrationOptions(compensation="per_leg"))


def test_stage_with_drift_model_on_paper_vehicle_grade(tmp_path):
    """One short survey (paper_vehicle IMU: 0.1 deg/h constant + 0.05 deg/h GM drift):
    honest sigma (about the drift's spread, not the ARW's), smoothed per-leg drift closer to
    the true per-leg mean than the constant, per-leg compensation at least as good."""
    r = run_once("vehicle", 3, tmp_path)
    assert np.all(r.sigma_b_radps > 0.02 * DPH)  # was ~0.003 deg/h without the drift model
    assert np.all(np.abs(r.err_b_radps) < 3 * r.sigma_b_radps)
    assert np.sqrt(np.mean(r.leg_drift_err_radps**2)) < np.sqrt(np.mean(r.leg_const_err_radps**2))
    assert r.dv_mps["per_leg"] < r.dv_mps["constant"] < 0.5 * r.dv_mps["before"]


def test_stage_estimates_the_drift_sigma_by_reml(tmp_path):
    """Without the sigma, REML on the joint fit (paper_flight: 0.5 deg/h injected; over 20
    seeds REML gave 0.37-0.66 deg/h). On the paper_vehicle grade it is not stable (it can
    collapse towards 0): pass the grade's sigma there (docs/calibration.md)."""
    r = run_once("flight", 5, tmp_path, estimate_gm_sigma=True)
    assert 0.25 * DPH < r.gm_sigma_radps < 1.0 * DPH, r.gm_sigma_radps / DPH
    assert np.all(np.abs(r.err_b_radps) < 3 * r.sigma_b_radps)


def test_shared_eigendecomposition_gives_the_cholesky_fit():
    # fit_calibration(noise_cache=...) with the ARW and drift sigma given (only A's scale
    # fitted): the fixed part q K + s2 G factored once by eigh and shared by the calls; the
    # same fit as the Cholesky of every REML step, here with an interior optimum
    legs = (_leg(1, 0.0, _bias), _leg(2, 180.0, _bias))
    rng = np.random.default_rng(5)
    draws = [tuple(replace(r, dv_n_mps=r.dv_n_mps + rng.normal(0.0, 0.01, r.dv_n_mps.shape))
                   for r in legs) for _ in range(2)]
    kw = dict(gyro_arw_radpsqrts=np.radians(0.01) / 60.0, gyro_gm_sigma_radps=0.5 * DPH,
              gyro_gm_tau_s=300.0)
    cache: dict = {}
    for reps in draws:  # the second call reuses the first's decomposition and leg bases
        plain = fit_calibration(reps, "body", FitOptions(**kw))
        shared = fit_calibration(reps, "body", FitOptions(**kw), noise_cache=cache)
        # one decomposition; each leg's noise basis and drift operator; the drift's S E S^T
        assert len([k for k in cache if k[0] not in ("basis", "gm_op", "gm_cov")]) == 1
        assert sorted(str(k[0]) for k in cache if isinstance(k[0], str)) == [
            "basis", "basis", "gm_cov", "gm_op", "gm_op"]
        assert np.log(plain.variance_factor) > np.log(1e-6) + 0.1  # not at the bound
        np.testing.assert_allclose(shared.variance_factor, plain.variance_factor, rtol=1e-6)
        np.testing.assert_allclose(shared.x, plain.x, rtol=1e-6, atol=1e-14)
        np.testing.assert_allclose(shared.cov, plain.cov, rtol=1e-5)


def test_shared_noise_bases_without_the_drift_give_the_same_fit():
    # the diagnosis's null whitening (gyro_rw, ARW given, no drift) shares a noise_cache over
    # its realisations: each leg's noise basis made once, the fits those without it
    legs = (_leg(1, 0.0, _bias), _leg(2, 180.0, _bias))
    rng = np.random.default_rng(8)
    cache: dict = {}
    for _ in range(2):
        reps = tuple(replace(r, dv_n_mps=r.dv_n_mps + rng.normal(0.0, 0.01, r.dv_n_mps.shape))
                     for r in legs)
        kw = dict(noise="gyro_rw", gyro_arw_radpsqrts=np.radians(0.01) / 60.0)
        plain = fit_calibration(reps, "body", FitOptions(**kw))
        shared = fit_calibration(reps, "body", FitOptions(**kw), noise_cache=cache)
        assert sorted(k[:2] for k in cache) == [("basis", 1), ("basis", 2)]
        assert shared.variance_factor == plain.variance_factor
        np.testing.assert_array_equal(shared.x, plain.x)
