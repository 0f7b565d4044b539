"""IMU grade presets -> SI filter noise (unit conversions against hand-computed values)."""

from __future__ import annotations

import math

import pytest

from pospp.config import ImuConfig
from pospp.nav.tuning import PRESETS, ImuTuning, tuning_preset


def test_unit_conversions():
    tun = tuning_preset("flight", gyro_bias_sigma_dph=1.0, gyro_gm_sigma_dph=0.0,
                        gyro_arw_dpsh=0.6, accel_bias_sigma_ug=100.0, accel_gm_sigma_ug=0.0,
                        accel_vrw_mpsph=0.06, gyro_sf_sigma_ppm=20.0)
    nz = tun.noise()
    # 1 deg/h = 4.8481368e-6 rad/s; 0.6 deg/sqrt(h) = 0.6 * 0.0174533 / 60 rad/sqrt(s)
    assert nz.gyro_bias_sigma_radps == pytest.approx(4.84813681e-6, rel=1e-8)
    assert nz.gyro_arw_radpsqrts == pytest.approx(1.74532925e-4, rel=1e-8)
    assert nz.accel_bias_sigma_mps2 == pytest.approx(9.80665e-4, rel=1e-12)
    assert nz.accel_vrw_mpspsqrts == pytest.approx(1e-3, rel=1e-12)
    assert nz.gyro_sf_sigma == pytest.approx(2e-5)
    assert nz.gyro_bias_psd_radps2ps == 0.0


def test_gauss_markov_drift_sets_the_random_walk_and_adds_to_the_sigma():
    tun = tuning_preset("tactical")
    nz = tun.noise()
    gm = tun.gyro_gm_sigma_dph * math.radians(1.0) / 3600.0
    assert nz.gyro_bias_psd_radps2ps == pytest.approx(2.0 * gm**2 / tun.gyro_gm_tau_s)
    turn_on = tun.gyro_bias_sigma_dph * math.radians(1.0) / 3600.0
    assert nz.gyro_bias_sigma_radps == pytest.approx(math.hypot(turn_on, gm))


def test_presets_and_aliases():
    assert {"flight", "vehicle", "tactical", "mems"} <= set(PRESETS)
    assert tuning_preset("consumer") == PRESETS["mems"]
    # grades are ordered by gyro quality
    g = [PRESETS[k].gyro_bias_sigma_dph for k in ("vehicle", "flight", "tactical", "mems")]
    assert g == sorted(g)
    with pytest.raises(ValueError, match="unknown IMU grade 'navy'"):
        tuning_preset("navy")


def test_overrides_are_validated():
    with pytest.raises(ValueError, match="unknown field"):
        tuning_preset("flight", gyro_bias_dph=1.0)
    with pytest.raises(ValueError, match="gyro_arw_dpsh: expected a finite number >= 0"):
        tuning_preset("flight", gyro_arw_dpsh=-1.0)
    with pytest.raises(ValueError, match="gyro_gm_tau_s: expected > 0"):
        tuning_preset("flight", gyro_gm_tau_s=0.0)
    assert tuning_preset("flight", gyro_arw_dpsh=None) == PRESETS["flight"]


def test_from_pipeline_config():
    cfg = ImuConfig(grade="vehicle", accel_bias_sigma_ug=7.0)
    tun = cfg.tuning()
    assert isinstance(tun, ImuTuning)
    assert tun.accel_bias_sigma_ug == 7.0
    assert tun.gyro_bias_sigma_dph == PRESETS["vehicle"].gyro_bias_sigma_dph
