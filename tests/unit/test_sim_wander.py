"""Non-uniform legs: heading and speed wander on straight legs (profile.py, ramps.py).

Checks: the closed-form derivatives of the wander against finite differences, smoothness at
the window ends, the true legs' heading spread and speed std against the configured
amplitudes, closure of error-free IMU data along wandering legs (so the increments follow the
wandering truth), and pospp's leg segmentation finding small-wander legs and rejecting the
``flight_wander`` preset's legs with the default thresholds.
"""

from __future__ import annotations

import numpy as np
import pytest

from pospp import rotation
from pospp.calib.segment import LegThresholds, find_legs
from pospp.sim.api import simulate
from pospp.sim.profile import load_profile, parse_profile, plan_mission
from pospp.sim.ramps import WanderSchedule
from pospp.sim.trajectory import ProfileMotion


def _profile(hw_deg, hp_s, sw_mps, sp_s, leg_s=300.0, legs=3):
    return parse_profile({
        "name": "wander",
        "start": {"lat_deg": 34.0, "lon_deg": 108.0, "height_m": 500.0, "heading_deg": 0.0},
        "segment": [
            {"type": "static", "duration_s": 5.0},
            {"type": "accelerate", "to_speed_mps": 50.0, "duration_s": 20.0},
            {"type": "survey", "legs": legs, "heading_deg": 45.0, "leg_duration_s": leg_s,
             "turn_rate_dps": 3.0, "heading_wander_deg": hw_deg,
             "heading_wander_period_s": hp_s, "speed_wander_mps": sw_mps,
             "speed_wander_period_s": sp_s},
        ]})


def test_wander_schedule_derivatives_and_smooth_ends():
    w = WanderSchedule.build([(10.0, 100.0, 2.0, 30.0), (150.0, 40.0, -1.0, 50.0)])
    t = np.linspace(0.0, 200.0, 400_001)
    x, x1, x2 = w.evaluate(t)
    h = t[1] - t[0]
    np.testing.assert_allclose(np.gradient(x, h)[1:-1], x1[1:-1], atol=1e-6)
    np.testing.assert_allclose(np.gradient(x1, h)[1:-1], x2[1:-1], atol=1e-5)
    # zero outside, and value, slope and curvature vanish at every window end
    ends = np.array([10.0, 110.0, 150.0, 190.0])
    for arr in w.evaluate(ends):
        np.testing.assert_allclose(arr, 0.0, atol=1e-12)
    assert np.all(x[(t < 10.0) | ((t > 110.0) & (t < 150.0)) | (t > 190.0)] == 0.0)
    # full amplitude between the tapers (tau = min(P/2, T/4) = 15 s on the first window)
    mid = (t > 25.0) & (t < 95.0)
    assert x[mid].max() == pytest.approx(2.0, abs=1e-9)
    with pytest.raises(ValueError, match="overlap"):
        WanderSchedule.build([(0.0, 10.0, 1.0, 5.0), (5.0, 10.0, 1.0, 5.0)])


def test_no_wander_keys_no_wander():
    plan = plan_mission(load_profile("sample"))
    assert plan.heading_wander is None and plan.speed_wander is None
    assert all(lg.heading_wander_rad == 0.0 and lg.speed_wander_mps == 0.0
               for lg in plan.legs)


@pytest.mark.parametrize("hw, hp, sw, sp", [(1.5, 60.0, 1.0, 45.0), (3.0, 100.0, 0.5, 80.0)])
def test_true_legs_spread_and_speed_std_match_the_amplitudes(hw, hp, sw, sp):
    plan = plan_mission(_profile(hw, hp, sw, sp))
    m = ProfileMotion(plan)
    assert len(plan.legs) == 3
    for lg in plan.legs:
        t = np.arange(lg.start_s, lg.end_s, 0.05)
        smp = m.evaluate(t)
        psi = np.rad2deg(np.unwrap(smp.rpy_rad[:, 2]))
        speed = np.hypot(smp.v_n_mps[:, 0], smp.v_n_mps[:, 1])
        assert psi.max() - psi.min() == pytest.approx(2.0 * hw, rel=1e-3)
        assert np.rad2deg(lg.heading_rad) % 360 == pytest.approx(45.0 if lg.leg_id != 1
                                                                 else 225.0)
        # track = heading: the wander turns the velocity with the nose
        track = np.rad2deg(np.unwrap(np.arctan2(smp.v_n_mps[:, 1], smp.v_n_mps[:, 0])))
        np.testing.assert_allclose((track - psi + 180.0) % 360.0 - 180.0, 0.0, atol=1e-9)
        # a tapered sinusoid: std a little below A / sqrt(2), extremes exactly +-A
        assert 0.9 * sw / np.sqrt(2) < speed.std() <= sw / np.sqrt(2)
        assert speed.max() - speed.min() == pytest.approx(2.0 * sw, rel=1e-3)
        # heading rate is the derivative of the heading (finite difference)
        np.testing.assert_allclose(np.gradient(smp.rpy_rad[:, 2], 0.05)[1:-1],
                                   smp.rpy_rate_radps[1:-1, 2], atol=1e-7)


def test_flight_wander_preset_is_sample_plus_wander():
    a, b = load_profile("sample"), load_profile("flight_wander")
    pa, pb = plan_mission(a), plan_mission(b)
    assert pa.duration_s == pb.duration_s
    assert [(lg.start_s, lg.end_s, lg.heading_rad) for lg in pa.legs] == \
           [(lg.start_s, lg.end_s, lg.heading_rad) for lg in pb.legs]
    assert all(np.rad2deg(lg.heading_wander_rad) == pytest.approx(1.5)
               and lg.speed_wander_mps == 1.0 for lg in pb.legs)


def test_closure_along_wandering_legs():
    """Error-free IMU data of a wandering leg integrate back to the truth (the brief's bounds
    of test_sim_closure: 1 m, 0.05 m/s, 5 arcsec), so the increments follow the wander."""
    from tests.unit.test_sim_closure import ATT_TOL_ARCSEC, POS_TOL_M, VEL_TOL_MPS, _closure

    sim = simulate(_profile(2.0, 30.0, 1.0, 20.0, leg_s=120.0, legs=1), imu_grade="errorfree",
                   seed=1, imu_rate_hz=100.0)
    pos, vel, att = _closure(sim)
    assert pos < POS_TOL_M and vel < VEL_TOL_MPS and att < ATT_TOL_ARCSEC, (pos, vel, att)
    legs = sim.params["legs"]
    assert legs[0]["heading_wander_deg"] == 2.0 and legs[0]["speed_wander_period_s"] == 20.0
    # the true heading really wanders on the leg
    sl = (sim.truth.t_s > legs[0]["start_s"]) & (sim.truth.t_s < legs[0]["end_s"])
    yaw = np.rad2deg(np.unwrap(rotation.euler_from_quat(sim.truth.q_nb[sl])[:, 2]))
    assert yaw.max() - yaw.min() == pytest.approx(4.0, rel=1e-3)


def _truth_1hz(plan):
    m = ProfileMotion(plan)
    t = np.arange(0.0, plan.duration_s, 1.0)
    smp = m.evaluate(t)
    return t, smp.v_n_mps, smp.height_m


def test_segmentation_finds_small_wander_legs():
    plan = plan_mission(_profile(0.4, 120.0, 0.2, 150.0))
    t, v, h = _truth_1hz(plan)
    found = find_legs(t, v, h, thresholds=LegThresholds(min_duration_s=250.0))
    assert len(found) == 3
    for lg, f in zip(plan.legs, found, strict=True):
        assert f.start_s >= lg.start_s - 1.0 and f.end_s <= lg.end_s + 1.0
        assert f.duration_s > lg.duration_s - 30.0
        assert np.rad2deg(f.heading_spread_rad) == pytest.approx(0.8, abs=0.1)
        assert 0.1 < f.speed_std_mps < 0.2 / np.sqrt(2) + 1e-9


def test_segmentation_rejects_flight_wander_legs_and_says_which_threshold():
    """The preset's 1.5 deg / 1 m/s wander: heading spread 3 deg (> 2 deg), along-track
    accelerations of 1 m/s x 2 pi / 45 s = 0.14 m/s^2 (> 0.05) and a speed std of about
    0.67 m/s (> 0.5): no leg passes the defaults; relaxing exactly those three thresholds
    gives the four lines back."""
    plan = plan_mission(load_profile("flight_wander"))
    t, v, h = _truth_1hz(plan)
    th = LegThresholds(min_duration_s=200.0)
    assert find_legs(t, v, h, thresholds=th) == ()
    relaxed = LegThresholds(min_duration_s=200.0, max_acceleration_mps2=0.2,
                            max_heading_spread_deg=3.5, max_speed_std_mps=0.8)
    found = find_legs(t, v, h, thresholds=relaxed)
    assert len(found) == len(plan.legs) == 4
    for f in found:
        assert np.rad2deg(f.heading_spread_rad) == pytest.approx(3.0, abs=0.1)
        assert f.speed_std_mps < 1.0 / np.sqrt(2)
