"""GNSS simulation: lever arm kinematics, noise, time offset, outages."""

from __future__ import annotations

import numpy as np
import pytest

from pospp import earth
from pospp.sim.gnss import GnssModel, antenna_state, simulate_gnss
from pospp.sim.imu import dcm_nb_from_euler
from pospp.sim.profile import parse_profile, plan_mission
from pospp.sim.trajectory import ProfileMotion

T0_NS = 1_700_000_000_000_000_000


@pytest.fixture(scope="module")
def motion():
    prof = parse_profile({
        "start": {"lat_deg": 50.0, "lon_deg": 10.0, "height_m": 200.0, "heading_deg": 45.0},
        "segment": [{"type": "static", "duration_s": 5.0},
                    {"type": "accelerate", "to_speed_mps": 50.0, "duration_s": 15.0},
                    {"type": "turn", "angle_deg": 90.0, "rate_dps": 6.0, "blend_s": 3.0},
                    {"type": "climb", "rate_mps": 5.0, "delta_m": 50.0, "blend_s": 3.0},
                    {"type": "turn", "angle_deg": -180.0, "rate_dps": 9.0, "blend_s": 3.0}]})
    plan = plan_mission(prof)
    return ProfileMotion(plan), plan.duration_s


def test_antenna_velocity_is_the_derivative_of_antenna_position(motion):
    """v_a = v + C_nb (w_eb_b x lever) checked against a numerical derivative of r_a (ECEF)."""
    m, dur = motion
    lever = np.array([1.5, -0.8, -2.0])
    t = np.linspace(21.0, dur - 1.0, 300)
    h = 1e-3
    lat, lon, hh, v = antenna_state(m.evaluate(t), lever)
    r_p = earth.llh_to_ecef_m(*antenna_state(m.evaluate(t + h), lever)[:3])
    r_m = earth.llh_to_ecef_m(*antenna_state(m.evaluate(t - h), lever)[:3])
    v_e = (r_p - r_m) / (2 * h)
    v_n = np.einsum("nji,nj->ni", earth.dcm_en(lat, lon), v_e)
    np.testing.assert_allclose(v, v_n, atol=2e-5)
    # lever arm visible: the antenna moves differently from the IMU in the turns
    assert np.abs(v - m.evaluate(t).v_n_mps).max() > 0.1
    # and its position is the IMU's plus C_nb lever, measured in the local NED
    s = m.evaluate(t)
    d = earth.llh_difference_ned_m(lat, lon, hh, s.lat_rad, s.lon_rad, s.height_m)
    np.testing.assert_allclose(d, dcm_nb_from_euler(s.rpy_rad) @ lever, atol=1e-6)


def test_noise_statistics_and_reported_covariance(motion):
    m, dur = motion
    model = GnssModel(rate_hz=50.0, pos_noise_m=(0.3, 0.6), vel_noise_mps=(0.05, 0.1))
    fix, vel = simulate_gnss(m, dur, model, start_time_ns=T0_NS, seed=4)
    s = m.evaluate((fix.time_ns - T0_NS) * 1e-9)
    dp = earth.llh_difference_ned_m(fix.lat_rad, fix.lon_rad, fix.height_m, s.lat_rad,
                                    s.lon_rad, s.height_m)
    np.testing.assert_allclose(dp.std(axis=0), [0.3, 0.3, 0.6], rtol=0.08)
    np.testing.assert_allclose((vel.v_n_mps - s.v_n_mps).std(axis=0), [0.05, 0.05, 0.1],
                               rtol=0.08)
    np.testing.assert_allclose(fix.pos_cov_ned_m2[0], np.diag([0.09, 0.09, 0.36]))
    np.testing.assert_allclose(vel.vel_cov_ned_m2ps2[0], np.diag([0.0025, 0.0025, 0.01]))


def test_time_offset_and_outages(motion):
    m, dur = motion
    clean = GnssModel(rate_hz=10.0, pos_noise_m=(0.0, 0.0), vel_noise_mps=(0.0, 0.0))
    late = GnssModel(rate_hz=10.0, pos_noise_m=(0.0, 0.0), vel_noise_mps=(0.0, 0.0),
                     time_offset_s=0.3, outages_s=((30.0, 40.0),))
    f0, v0 = simulate_gnss(m, dur, clean, start_time_ns=T0_NS, seed=0)
    f1, v1 = simulate_gnss(m, dur, late, start_time_ns=T0_NS, seed=0)
    t1 = (f1.time_ns - T0_NS) * 1e-9
    assert not ((t1 >= 30.0) & (t1 < 40.0)).any() and (t1 >= 40.0).any()
    # the fix stamped t is the state at t - 0.3 s: it equals the clean fix stamped t - 0.3 s
    idx = np.searchsorted(f0.time_ns, f1.time_ns - 300_000_000)
    assert np.array_equal(f0.time_ns[idx], f1.time_ns - 300_000_000)
    np.testing.assert_allclose(f1.lat_rad, f0.lat_rad[idx], rtol=0, atol=1e-15)
    np.testing.assert_allclose(v1.v_n_mps, v0.v_n_mps[idx], atol=1e-12)


def test_bad_settings_say_what_is_wrong():
    with pytest.raises(ValueError, match="rate_hz"):
        GnssModel(rate_hz=0.0)
    with pytest.raises(ValueError, match="lever_arm_b_m"):
        GnssModel(lever_arm_b_m=(1.0, 2.0))
    with pytest.raises(ValueError, match="outage"):
        GnssModel(outages_s=((10.0, 5.0),))


@pytest.mark.reference
def test_lever_arm_convention_matches_the_independent_simulator(reference_cases):
    """The reference case's fixes sit at truth + C_nb lever_b (FRD), as our antenna model says."""
    import json

    from pospp.io.mcap_reader import read_flight_log
    from pospp.io.parquet_tables import read_reference_trajectory
    from pospp.sim.trajectory import MotionSample

    name = "flight_survey_errors"
    params = json.loads((reference_cases / f"{name}.params.json").read_text())
    lever = np.array(params["gnss"]["lever_arm_m"])
    log = read_flight_log(reference_cases / f"{name}.mcap")
    ref = read_reference_trajectory(reference_cases / f"{name}.truth.parquet")
    k = np.searchsorted(ref.time_ns, log.fix.time_ns)
    ok = (k < len(ref)) & (ref.time_ns[np.minimum(k, len(ref) - 1)] == log.fix.time_ns)
    k = k[ok]
    zero = np.zeros((k.size, 3))
    m = MotionSample(np.zeros(k.size), ref.lat_rad[k], ref.lon_rad[k], ref.height_m[k],
                     ref.v_n_mps[k], zero, ref.rpy_rad[k], zero)
    lat, lon, h, _ = antenna_state(m, lever)
    d = earth.llh_difference_ned_m(log.fix.lat_rad[ok], log.fix.lon_rad[ok],
                                   log.fix.height_m[ok], lat, lon, h)
    sigma = np.array(params["gnss"]["pos_noise_m"])[[0, 0, 1]]
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=float(4 * sigma.max() / np.sqrt(k.size)))
    np.testing.assert_allclose(d.std(axis=0), sigma, rtol=0.1)
    # and without the lever arm the fixes would be visibly off (the check has teeth)
    lat0, lon0, h0, _ = antenna_state(m, np.zeros(3))
    d0 = earth.llh_difference_ned_m(log.fix.lat_rad[ok], log.fix.lon_rad[ok],
                                    log.fix.height_m[ok], lat0, lon0, h0)
    assert np.abs(d0.mean(axis=0)).max() > 0.5
