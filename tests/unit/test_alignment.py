"""Static coarse alignment (levelling + gyrocompassing) and in-motion attitude, from sensor
outputs built here from the attitude and the Earth rate (closed forms, no strapdown)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pospp import earth, rotation
from pospp.nav.alignment import (
    AlignmentOptions,
    align,
    coarse_static_alignment,
    motion_attitude,
    static_windows,
)
from pospp.nav.tuning import tuning_preset


def _at_rest(rpy, lat):
    c_bn = rotation.dcm_from_euler(rpy).T
    g = float(earth.normal_gravity_mps2(lat, 0.0))
    w_ie_n = earth.EARTH_RATE_RADPS * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    return c_bn @ w_ie_n, c_bn @ np.array([0.0, 0.0, -g])


@settings(max_examples=60, deadline=None)
@given(
    roll=st.floats(-0.3, 0.3), pitch=st.floats(-0.3, 0.3), yaw=st.floats(0.0, 2 * math.pi - 1e-9),
    lat=st.floats(-1.2, 1.2),
)
def test_noise_free_alignment_recovers_the_attitude(roll, pitch, yaw, lat):
    w, f = _at_rest([roll, pitch, yaw], lat)
    rpy, sig, sig_h = coarse_static_alignment(w, f, lat, 300.0, tuning_preset("flight").noise())
    ang = rotation.angle_between_rad(rotation.dcm_from_euler(rpy),
                                     rotation.dcm_from_euler([roll, pitch, yaw]))
    assert ang < 1e-9
    assert sig[2] == sig_h and sig[0] == sig[1] > 0.0


def test_heading_error_from_an_east_gyro_bias_is_bias_over_horizontal_earth_rate():
    """A bias eps on the east axis (heading north, level) rotates the estimated heading by
    -eps / (Omega cos L): the textbook gyrocompassing error (Titterton & Weston Sec. 10.3)."""
    lat = math.radians(40.0)
    w, f = _at_rest([0.0, 0.0, 0.0], lat)
    eps = math.radians(0.5) / 3600.0
    w = w + np.array([0.0, eps, 0.0])  # body y = east when heading north
    rpy, _, _ = coarse_static_alignment(w, f, lat, 300.0, tuning_preset("flight").noise())
    dpsi = (rpy[2] + math.pi) % (2 * math.pi) - math.pi
    expected = -math.atan2(eps, earth.EARTH_RATE_RADPS * math.cos(lat))
    assert dpsi == pytest.approx(expected, rel=1e-9)


def test_tilt_from_an_accelerometer_bias_is_bias_over_g():
    lat = math.radians(40.0)
    w, f = _at_rest([0.0, 0.0, 0.0], lat)
    b = 50e-6 * 9.80665
    rpy, _, _ = coarse_static_alignment(w, f + [b, 0.0, 0.0], lat, 300.0,
                                        tuning_preset("flight").noise())
    g = float(earth.normal_gravity_mps2(lat, 0.0))
    assert rpy[1] == pytest.approx(math.atan2(b, g), rel=1e-9)


def test_heading_sigma_follows_the_gyro_grade():
    lat = math.radians(45.0)
    w, f = _at_rest([0.0, 0.0, 1.0], lat)
    sig = {g: coarse_static_alignment(w, f, lat, 600.0, tuning_preset(g).noise())[2]
           for g in ("vehicle", "flight", "tactical", "mems")}
    assert sig["vehicle"] < sig["flight"] < sig["tactical"] < sig["mems"]
    # 1.1 deg/h at 45 deg: about 6 deg -> usable; consumer MEMS: Earth rate unresolvable
    assert math.degrees(sig["flight"]) < AlignmentOptions().max_gyrocompass_sigma_deg
    assert math.degrees(sig["mems"]) > 90.0


def test_motion_attitude_is_track_and_flight_path():
    rpy = motion_attitude([10.0, -10.0, -2.0])
    assert rpy[0] == 0.0
    assert rpy[1] == pytest.approx(math.atan2(2.0, math.hypot(10.0, 10.0)))
    assert rpy[2] == pytest.approx(math.radians(315.0))


def _record(static_s, moving_s, rate=100.0, seed=0):
    rng = np.random.default_rng(seed)
    n = int((static_s + moving_s) * rate) + 1
    t = np.arange(n) / rate
    w0, f0 = _at_rest([0.0, 0.0, 0.5], math.radians(45.0))
    w = np.tile(w0, (n, 1)) + rng.normal(0.0, 1e-5, (n, 3))
    f = np.tile(f0, (n, 1)) + rng.normal(0.0, 1e-3, (n, 3))
    moving = t > static_s
    f[moving] += rng.normal(0.0, 0.5, (int(moving.sum()), 3))  # vibration
    return t, w, f


def test_static_windows_find_the_initial_static_period():
    t, w, f = _record(40.0, 20.0)
    end, ok = static_windows(t, w, f)
    assert ok[end <= 40.0].all()
    assert not ok[end > 41.0].any()


@pytest.mark.parametrize("static_s", [3.0, 40.0, 300.0, 400.0])
def test_leading_static_windows_are_a_prefix_of_all(static_s):
    # leading_only reads windows in growing chunks (64, 128, ...) and stops at the first
    # that is not static: the same classification as the whole list's first windows
    t, w, f = _record(static_s, 100.0)
    tv = np.arange(0.0, t[-1], 1.0)
    vel = np.where((tv > static_s)[:, None], [5.0, 0.0, 0.0], 0.0)
    end, ok = static_windows(t, w, f, gnss_vel_t_s=tv, gnss_v_n_mps=vel)
    end1, ok1 = static_windows(t, w, f, gnss_vel_t_s=tv, gnss_v_n_mps=vel, leading_only=True)
    n = int(np.argmin(ok)) + 1
    assert not ok[n - 1] and ok[:n - 1].all() and n == ok1.size
    np.testing.assert_array_equal(end1, end[:n])
    np.testing.assert_array_equal(ok1, ok[:n])
    t, w, f = _record(200.0, 0.0)  # static throughout: every window
    end, ok = static_windows(t, w, f)
    end1, ok1 = static_windows(t, w, f, leading_only=True)
    assert ok.all()
    np.testing.assert_array_equal(end1, end)
    np.testing.assert_array_equal(ok1, ok)


def test_mems_at_rest_without_motion_data_is_a_clear_error():
    t, w, f = _record(60.0, 0.0)
    lat = math.radians(45.0)
    fix_t = np.arange(0.0, 60.0, 1.0)
    llh = np.tile([lat, 0.1, 100.0], (fix_t.shape[0], 1))
    cov = np.tile(np.eye(3) * 0.01, (fix_t.shape[0], 1, 1))
    with pytest.raises(ValueError, match="alignment: no static period"):
        align(t, w, f, fix_t, llh, cov, np.zeros(0), np.zeros((0, 3)),
              tuning_preset("mems").noise())
    al = align(t, w, f, fix_t, llh, cov, np.zeros(0), np.zeros((0, 3)),
               tuning_preset("flight").noise())
    assert al.method == "static" and al.k_start == 0


def test_static_position_resists_an_outlier_fix():
    t, w, f = _record(60.0, 0.0)
    lat = math.radians(45.0)
    fix_t = np.arange(0.0, 60.0, 1.0)
    llh = np.tile([lat, 0.1, 100.0], (fix_t.shape[0], 1))
    llh[0, 0] += 1000.0 / 6.37e6  # the first fix 1 km off
    cov = np.tile(np.eye(3) * 0.01, (fix_t.shape[0], 1, 1))
    al = align(t, w, f, fix_t, llh, cov, np.zeros(0), np.zeros((0, 3)),
               tuning_preset("flight").noise())
    assert al.lat_rad == pytest.approx(lat, abs=1e-9)


def _gnss_vel(static_s, total_s, rate_hz, seed, v_after=lambda dt: np.zeros((dt.size, 3))):
    """GNSS velocities with the simulator's receiver noise (GnssModel defaults), reported
    sigmas in the covariances; after ``static_s`` the true velocity is ``v_after(t - static)``."""
    from pospp.sim.gnss import GnssModel

    h, v = GnssModel().vel_noise_mps
    sig = np.array([h, h, v])
    rng = np.random.default_rng(1000 + seed)
    t = np.arange(1.0 / rate_hz, total_s, 1.0 / rate_hz)
    vel = rng.standard_normal((t.size, 3)) * sig
    after = t > static_s
    vel[after] += v_after(t[after] - static_s)
    cov = np.tile(np.diag(sig**2), (t.size, 1, 1))
    return t, vel, cov


@pytest.mark.parametrize("rate_hz", [1.0, 10.0])
def test_twenty_static_minutes_stay_static_under_gnss_velocity_noise(rate_hz):
    """20 minutes at rest, the simulator's receiver (pospp.sim.gnss defaults: velocity noise
    0.02, 0.02, 0.03 m/s, 0.041 m/s RMS in 3-D, reported as such): static to the end on 6
    seeds with the chi^2(3) test (alpha 1e-6 per record), while the speed threshold alone
    (no covariances) cuts it on most of them."""
    from pospp.sim.gnss import GnssModel, simulate_gnss
    from pospp.sim.trajectory import MotionSample

    class Still:  # the receiver at rest: its velocities are its noise
        def evaluate(self, ts):
            n = np.asarray(ts).size
            z3 = np.zeros((n, 3))
            return MotionSample(np.asarray(ts), np.full(n, 0.8), np.full(n, 0.1),
                                np.full(n, 100.0), z3, z3, z3, z3)

    t, w, f = _record(1200.0, 0.0, rate=50.0)
    cut_by_speed_alone = 0
    for seed in range(1, 7):
        _, v = simulate_gnss(Still(), 1200.0, GnssModel(rate_hz=rate_hz), start_time_ns=0,
                             seed=seed)
        tv, vel, cov = v.time_ns * 1e-9, v.v_n_mps, v.vel_cov_ned_m2ps2
        _, ok = static_windows(t, w, f, gnss_vel_t_s=tv, gnss_v_n_mps=vel,
                               gnss_vel_cov_ned_m2ps2=cov)
        assert ok.all(), (seed, np.flatnonzero(~ok))
        _, ok0 = static_windows(t, w, f, gnss_vel_t_s=tv, gnss_v_n_mps=vel)
        cut_by_speed_alone += int(not ok0.all())
    assert cut_by_speed_alone >= 4


@pytest.mark.parametrize("rate_hz", [1.0, 10.0])
@pytest.mark.parametrize("motion", ["creep 0.3 m/s", "accelerate 0.5 m/s^2"])
def test_a_start_of_motion_ends_the_static_period_within_two_windows(rate_hz, motion):
    """A creep at 0.3 m/s or an acceleration of 0.5 m/s^2 (north) from 300 s, which the IMU
    windows do not see (no vibration; 0.5 m/s^2 changes |f| by 0.013 m/s^2 < 0.1), ends the
    static period by the GNSS velocity within two 1 s windows, on 6 seeds."""
    def creep(dt):
        return np.tile([0.3, 0.0, 0.0], (dt.size, 1))

    def accelerate(dt):
        return np.column_stack([0.5 * dt, np.zeros(dt.size), np.zeros(dt.size)])

    v_after = creep if motion.startswith("creep") else accelerate
    t, w, f = _record(330.0, 0.0, rate=50.0)
    for seed in range(1, 7):
        tv, vel, cov = _gnss_vel(300.0, 330.0, rate_hz, seed, v_after)
        end, ok = static_windows(t, w, f, gnss_vel_t_s=tv, gnss_v_n_mps=vel,
                                 gnss_vel_cov_ned_m2ps2=cov)
        first_moving = float(end[np.argmin(ok)])
        assert ok[end <= 300.0].all() and 300.0 < first_moving <= 302.0, (seed, first_moving)


def test_a_large_reported_sigma_does_not_hide_half_a_metre_per_second():
    """A receiver reporting 1 m/s: a record at 0.6 m/s moves (``max_noisy_static_speed_mps``),
    one at 0.4 m/s does not; without covariances 0.12 m/s moves, 0.08 m/s does not
    (``max_static_speed_mps``)."""
    t, w, f = _record(10.0, 0.0, rate=50.0)
    tv = np.array([2.5, 5.5])
    vel = np.array([[0.4, 0.0, 0.0], [0.6, 0.0, 0.0]])
    cov = np.tile(np.eye(3), (2, 1, 1))
    end, ok = static_windows(t, w, f, gnss_vel_t_s=tv, gnss_v_n_mps=vel,
                             gnss_vel_cov_ned_m2ps2=cov)
    assert ok[2] and not ok[5] and ok[[0, 1, 3, 4, 6, 7, 8]].all()
    _, ok0 = static_windows(t, w, f, gnss_vel_t_s=tv, gnss_v_n_mps=vel * 0.2)
    assert ok0[2] and not ok0[5]
