"""Calibration least squares against data from the strapdown mechanization on exact IMU data.

The legs are exact IMU increments of an ideal rhumb line or a weaving flight
(tests/unit/_truth_imu.py, independent of pospp's mechanization) with a known body gyro bias,
accelerometer bias, gyro white noise and initial misalignment injected; B is pospp's nonlinear
strapdown kernel and A the exact truth. The calibration's linear model must recover what was
injected, with the signs of pospp's conventions (errors computed minus true,
C_nb_hat = (I - [phi x]) C_nb, sensors read true + bias).
"""

from __future__ import annotations

import numpy as np
import pytest
from _truth_imu import rhumb_line, weaving_flight, weaving_truth_state

from pospp import rotation, units
from pospp.calib.design import leg_sensitivities
from pospp.calib.replay import ImuIncrements, replay_leg, solution_a_from_trajectory
from pospp.calib.segment import Leg
from pospp.calib.solve import FitOptions, fit_calibration
from pospp.nav.strapdown import Trajectory

DPH = units.DEG_PER_H_RADPS
ASEC = units.ARCSEC_RAD
LAT = np.radians(40.0)
H_M = 2600.0
V_MPS = 60.0
RATE_HZ = 20.0
BIAS_B = np.array([0.5, -0.4, 0.2]) * DPH
ACCEL_B = np.array([20.0, -10.0, 15.0]) * 9.80665e-6
ARW = 0.002 * np.pi / 180 / 60  # 0.002 deg/sqrt(h) in rad/sqrt(s)


def _leg(leg_id, heading_deg, *, phi_n_rad, rng=None, weave_amp_deg=0.0, accel=True,
         duration_s=301.0):
    """(LegReplay, C_nb at the start) of one leg with the injected errors."""
    hd = np.radians(heading_deg)
    if weave_amp_deg:
        tr = weaving_flight(LAT, H_M, V_MPS, hd, np.radians(weave_amp_deg), 100.0, RATE_HZ,
                            duration_s)
        v, c = weaving_truth_state(tr, hd, np.radians(weave_amp_deg), 100.0, V_MPS)
        q = rotation.quat_from_dcm(c)
    else:
        tr = rhumb_line(LAT, H_M, V_MPS, hd, RATE_HZ, duration_s)
        n = tr.t_s.size
        v = np.tile(tr.v_n_mps, (n, 1))
        q = np.tile(rotation.quat_from_dcm(tr.c_nb), (n, 1))
    traj = Trajectory(tr.t_s, tr.lat_rad, tr.lon_rad, np.full(tr.t_s.size, H_M), v, q)
    dt = np.diff(tr.t_s)[:, None]
    dth = tr.dtheta_b_rad + BIAS_B * dt
    if rng is not None:
        dth = dth + ARW * np.sqrt(dt) * rng.standard_normal(dth.shape)
    dv = tr.dv_b_mps + (ACCEL_B * dt if accel else 0.0)
    imu = ImuIncrements(tr.t_s, dth, dv)
    ref = solution_a_from_trajectory(traj, v_sigma_n_mps=[0.02, 0.03, 0.05])
    leg = Leg(leg_id, 1.0, duration_s, hd % (2 * np.pi), V_MPS, H_M, 0.0, 0.0, 0.0, 0.0)
    # C_nb_hat = (I - [phi x]) C_nb: B starts from exp(-[phi x]) C_nb_A
    rep = replay_leg(imu, ref, leg, attitude_correction_n_rad=-np.asarray(phi_n_rad))
    c0 = rotation.dcm_from_quat(traj.q_nb[int(np.searchsorted(tr.t_s, 1.0))])
    return rep, c0


PHI0 = np.array([3.0, -2.0, 0.0]) * ASEC
PHI1 = np.array([-1.0, 4.0, 0.0]) * ASEC


@pytest.fixture(scope="module")
def reversal_pair():
    rng = np.random.default_rng(7)
    a = _leg(0, 20.0, phi_n_rad=PHI0, rng=rng)
    b = _leg(1, 200.0, phi_n_rad=PHI1, rng=rng)
    return a, b


def test_body_formulation_recovers_injected_bias_and_tilts(reversal_pair):
    (ra, ca), (rb, cb) = reversal_pair
    cal = fit_calibration((ra, rb), "body")
    for i, ax in enumerate("xy"):
        est, sig = cal.value(f"gyro_bias_{ax}"), cal.sigma_of(f"gyro_bias_{ax}")
        assert np.sign(est) == np.sign(BIAS_B[i])
        assert abs(est - BIAS_B[i]) < 3 * sig, (ax, est / DPH, sig / DPH)
        assert abs(est - BIAS_B[i]) < 0.05 * abs(BIAS_B[i])
    # the fitted tilt is the injected tilt plus the accelerometer bias's equivalent tilt
    # (dv_N' = g phi_E + (C b_a)_N, dv_E' = -g phi_N + (C b_a)_E): why b_a drops out
    g = 9.80
    for rep, c, phi in ((ra, ca, PHI0), (rb, cb, PHI1)):
        fa = c @ ACCEL_B
        expect = np.array([phi[0] - fa[1] / g, phi[1] + fa[0] / g])
        lid = rep.leg.leg_id
        got = np.array([cal.value(f"phi_n_leg{lid}"), cal.value(f"phi_e_leg{lid}")])
        assert np.all(np.abs(got - expect) < 1.0 * ASEC), (got / ASEC, expect / ASEC)
    # the gyro noise model's angle random walk, estimated by REML, is the injected one
    assert 0.6 * ARW < cal.gyro_arw_radpsqrts < 1.5 * ARW


def test_paper_formulation_cannot_follow_a_body_fixed_drift_on_a_reversal(reversal_pair):
    (ra, ca), (rb, cb) = reversal_pair
    body = fit_calibration((ra, rb), "body")
    paper = fit_calibration((ra, rb), "paper")
    eps_a = (ca @ BIAS_B)[0:2]  # nav-frame drift on leg a; leg b sees about -eps_a
    eps_p = np.array([paper.value("eps_n"), paper.value("eps_e")])
    assert np.linalg.norm(eps_p - eps_a) > 0.5 * np.linalg.norm(eps_a)
    assert np.linalg.norm(eps_p + eps_a) > 0.5 * np.linalg.norm(eps_a)
    assert paper.residual_rms_mps > 20 * body.residual_rms_mps


def test_closed_form_and_numerical_transitions_agree_on_an_ideal_leg(reversal_pair):
    (ra, _), (rb, _) = reversal_pair
    for rep in (ra, rb):
        num = leg_sensitivities(rep, "numerical")
        cf = leg_sensitivities(rep, "closed_form")
        for a, b in zip(num, cf, strict=True):
            # tilt and horizontal-bias columns (phi_D and b_z act through Earth rate only)
            a, b = a[:, :, 0:2], b[:, :, 0:2]
            scale = np.abs(a).max(axis=(0, 2), keepdims=True)  # per velocity component
            # the closed forms drop terms worth a few per cent over 300 s (closed_form docs)
            assert np.max(np.abs(a - b) / scale) < 0.05
    c_num = fit_calibration((ra, rb), "body", FitOptions(transition="numerical"))
    c_cf = fit_calibration((ra, rb), "body", FitOptions(transition="closed_form"))
    for ax in "xy":
        assert abs(c_num.value(f"gyro_bias_{ax}") - c_cf.value(f"gyro_bias_{ax}")) < 0.05 * DPH


def test_numerical_transition_beats_closed_form_on_a_weaving_leg():
    a = _leg(0, 20.0, phi_n_rad=PHI0, weave_amp_deg=8.0, accel=False)
    b = _leg(1, 200.0, phi_n_rad=PHI1, weave_amp_deg=8.0, accel=False)
    err = {}
    for tr in ("numerical", "closed_form"):
        cal = fit_calibration((a[0], b[0]), "body", FitOptions(transition=tr, noise="white"))
        err[tr] = np.hypot(*(cal.gyro_bias_b_radps()[0:2] - BIAS_B[0:2])) / DPH
    assert err["numerical"] < 0.01  # deg/h, of a 0.64 deg/h bias
    assert err["numerical"] < 0.2 * err["closed_form"], err
