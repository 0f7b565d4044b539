"""The calibration refitted with a named effect (issue 34): on a synthetic survey flight whose
accelerometer ramps in-run, the calibration reads the ramp as gyro bias (r / g, 90 deg
rotated); refitted with the ramp's response removed from B minus A it reads the true gyro
bias, and its sigma carries the ramp's uncertainty."""

from __future__ import annotations

import numpy as np
import pytest
from _synthetic import survey_flight

from pospp.calib.replay import ImuIncrements, solution_a_from_trajectory
from pospp.calib.stage import CalibrationOptions, calibrate_flight
from pospp.diagnose.refit import refit_calibration
from pospp.diagnose.results import EffectResponse
from pospp.diagnose.sensor_families import accel_response_along_b
from pospp.units import DEG_PER_H_RADPS, G0_MPS2, UG_MPS2


@pytest.fixture(scope="module")
def ramp_run():
    fl = survey_flight(headings_deg=(0.0, 90.0, 180.0, 270.0), leg_duration_s=300.0,
                       rate_hz=50.0, lead_in_s=300.0)
    imu = fl.imu
    bg = np.array([0.3, -0.2, 0.0]) * DEG_PER_H_RADPS
    r = np.array([900.0, -400.0]) * UG_MPS2 / 3600.0  # per second
    t_mid = 0.5 * (imu.t_s[1:] + imu.t_s[:-1])
    ba = np.zeros((t_mid.size, 3))
    ba[:, 0:2] = t_mid[:, None] * r
    dt = np.diff(imu.t_s)[:, None]
    pert = ImuIncrements(imu.t_s, imu.dtheta_b_rad + bg * dt, imu.dv_b_mps + ba * dt)
    hist = np.zeros((fl.truth.t_s.size, 3))  # A holds the bias: B carries b(t) - b(t0)
    hist[:, 0:2] = fl.truth.t_s[:, None] * r
    ref = solution_a_from_trajectory(fl.truth, v_sigma_n_mps=np.full(3, 0.003),
                                     accel_bias_b_mps2=hist)
    run = calibrate_flight(pert, ref,
                           CalibrationOptions(formulations=("body",), gyro_arw_dpsh=1e-4),
                           legs=fl.legs)
    assert run.calibrated, run.reason
    return run, bg, r


def _ramp_response(run, r, sigma_per_s):
    reps = [run.replays[i] for i in sorted(run.replays)]
    cols = tuple(np.stack([accel_response_along_b(rep, np.outer(rep.t0_s + rep.t_s, e),
                                                  rep.t0_s * e) for e in np.eye(2)], axis=-1)
                 for rep in reps)
    return EffectResponse("accel_bias_change", cols, r, np.diag(np.full(2, sigma_per_s**2)))


def test_the_calibration_reads_the_ramp_as_gyro_bias_and_the_refit_does_not(ramp_run):
    run, bg, r = ramp_run
    alias = np.hypot(*r) / G0_MPS2  # |r| / g, rad/s
    err = run.gyro_bias_b_radps[:2] - bg[:2]
    assert np.hypot(*err) == pytest.approx(alias, rel=0.15)  # measured 1.0008 of it
    refit = refit_calibration(run, [_ramp_response(run, r, 1e-12)])
    assert refit is not None and refit.effects == ("accel_bias_change",)
    assert np.hypot(*(refit.bias_b_radps[:2] - bg[:2])) < 0.02 * alias  # measured 1.8e-5
    np.testing.assert_allclose(refit.change_b_radps[:2], -err, atol=0.02 * alias)
    np.testing.assert_allclose(refit.run.gyro_bias_b_radps, refit.bias_b_radps)


def test_the_refit_sigma_carries_the_effects_uncertainty(ramp_run):
    run, _, r = ramp_run
    sure = refit_calibration(run, [_ramp_response(run, r, 1e-12)])
    loose_sigma = 100.0 * UG_MPS2 / 3600.0  # 100 ug/h on each axis
    loose = refit_calibration(run, [_ramp_response(run, r, loose_sigma)])
    assert sure is not None and loose is not None
    # a 100 ug/h uncertainty moves the bias by about (100 ug/h) / g: 5.7e-3 deg/h
    expect = loose_sigma / G0_MPS2
    assert loose.effect_sigma_b_radps[:2] == pytest.approx([expect, expect], rel=0.25)  # 1.001
    assert np.all(loose.sigma_b_radps[:2] > sure.sigma_b_radps[:2])
    assert np.all(sure.effect_sigma_b_radps[:2] < 1e-3 * expect)
    assert refit_calibration(run, []) is None
