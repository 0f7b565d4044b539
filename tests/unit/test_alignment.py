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
