"""simulate_along: smooth true motion through a given lat/lon/height series."""

from __future__ import annotations

import numpy as np
import pytest

from pospp import earth, rotation, units
from pospp.nav.strapdown import increments_from_rates, integrate
from pospp.sim.api import simulate_along
from pospp.sim.profile import parse_profile, plan_mission
from pospp.sim.trajectory import ProfileMotion


@pytest.fixture(scope="module")
def drive():
    """A 'measured' drive at 10 Hz with 1 cm noise: start at rest, stop midway, turns."""
    prof = parse_profile({
        "start": {"lat_deg": 48.0, "lon_deg": 11.0, "height_m": 520.0, "heading_deg": 70.0},
        "options": {"turn_bank": "none"},
        "segment": [{"type": "static", "duration_s": 20.0},
                    {"type": "accelerate", "to_speed_mps": 12.0, "duration_s": 10.0},
                    {"type": "straight", "duration_s": 60.0},
                    {"type": "turn", "angle_deg": 90.0, "rate_dps": 10.0, "blend_s": 2.0},
                    {"type": "accelerate", "to_speed_mps": 0.0, "duration_s": 8.0},
                    {"type": "static", "duration_s": 15.0},
                    {"type": "accelerate", "to_speed_mps": 8.0, "duration_s": 8.0},
                    {"type": "turn", "angle_deg": -135.0, "rate_dps": 12.0, "blend_s": 2.0},
                    {"type": "straight", "duration_s": 60.0}]})
    plan = plan_mission(prof)
    m = ProfileMotion(plan)
    t = 1000.0 + np.arange(0.0, plan.duration_s, 0.1)
    s = m.evaluate(t - 1000.0)
    rng = np.random.default_rng(8)
    noise = rng.normal(0.0, 0.01, (t.size, 3))
    r_m, r_n = earth.principal_radii_m(s.lat_rad)
    lat = s.lat_rad + noise[:, 0] / (r_m + s.height_m)
    lon = s.lon_rad + noise[:, 1] / ((r_n + s.height_m) * np.cos(s.lat_rad))
    return t, lat, lon, s.height_m + noise[:, 2], s


def test_car_along_a_drive_closes_and_follows_the_input(drive):
    t, lat, lon, h, clean = drive
    sim = simulate_along(t, lat, lon, h, vehicle="car", imu_rate_hz=100.0, seed=0,
                         position_sigma_m=0.01)
    assert sim.truth.t_s[-1] == pytest.approx(t[-1] - t[0], abs=0.01)
    # the true motion follows the noise-free path the noisy input was made from
    tt = sim.truth.t_s[::10]
    k = np.searchsorted(t - t[0], tt[tt <= t[-1] - t[0]] - 1e-9)
    k = k[np.isclose(t[k] - t[0], tt[: k.size])]
    idx = np.round((t[k] - t[0]) * 100.0).astype(int)
    d = earth.llh_difference_ned_m(sim.truth.lat_rad[idx], sim.truth.lon_rad[idx],
                                   sim.truth.height_m[idx], clean.lat_rad[k], clean.lon_rad[k],
                                   clean.height_m[k])
    rms = np.sqrt((d**2).mean(axis=0))
    assert rms.max() < 0.01 and np.abs(d).max() < 0.05, (rms, np.abs(d).max(axis=0))
    # car: zero roll and pitch; heading follows the track (held through the stop)
    rpy = sim.truth.rpy_rad
    assert np.abs(rpy[:, :2]).max() < 1e-12
    dyaw = np.angle(np.exp(1j * (rpy[idx, 2] - clean.rpy_rad[k, 2])))
    assert np.degrees(np.abs(dyaw)).max() < 3.0
    # the increments are exact for this truth: strapdown closure over the whole drive
    t_s, dth, dv = increments_from_rates(sim.imu.time_ns, sim.imu.w_ib_b_radps,
                                         sim.imu.f_ib_b_mps2, epoch_ns=sim.start_time_ns)
    out = integrate(t_s, dth, dv, sim.truth.state(1))
    dp = earth.llh_difference_ned_m(out.lat_rad, out.lon_rad, out.height_m,
                                    sim.truth.lat_rad[1:], sim.truth.lon_rad[1:],
                                    sim.truth.height_m[1:])
    att = rotation.angle_between_rad(out.c_nb, rotation.dcm_from_quat(sim.truth.q_nb[1:]))
    assert np.abs(dp).max() < 0.01
    assert np.abs(out.v_n_mps - sim.truth.v_n_mps[1:]).max() < 1e-3
    assert att.max() / units.ARCSEC_RAD < 0.5


def test_aircraft_mode_banks_in_turns(drive):
    t, lat, lon, h, clean = drive
    sim = simulate_along(t, lat, lon, h, vehicle="aircraft", imu_rate_hz=50.0, seed=0)
    roll = sim.truth.rpy_rad[:, 0]
    v = sim.truth.v_n_mps
    speed = np.hypot(v[:, 0], v[:, 1])
    yaw = np.unwrap(sim.truth.rpy_rad[:, 2])
    yaw_rate = np.gradient(yaw, sim.truth.t_s)
    moving = speed > 5.0
    np.testing.assert_allclose(np.tan(roll[moving]), (speed * yaw_rate / 9.80665)[moving],
                               atol=2e-4)
    assert np.degrees(np.abs(roll)).max() > 5.0


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="strictly increasing"):
        simulate_along(np.zeros(20), np.zeros(20), np.zeros(20), np.zeros(20))
