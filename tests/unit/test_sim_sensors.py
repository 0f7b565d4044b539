"""IMU error models: every injected parameter is measured back from generated data."""

from __future__ import annotations

import numpy as np
import pytest

from pospp.sim.imu import exact_increments
from pospp.sim.profile import parse_profile, plan_mission
from pospp.sim.sensors import ImuErrorModel, apply_imu_errors, grade_names, imu_grade
from pospp.sim.trajectory import ProfileMotion
from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS, UG_MPS2


def _static(n, dt):
    """Exact-looking static increments: constant true rates (values do not matter here)."""
    t = np.arange(n + 1) * dt
    dth = np.tile([1e-5, -2e-5, 3e-5], (n, 1)) * dt
    dv = np.tile([0.01, -0.02, -9.8], (n, 1)) * dt
    return t, dth, dv


def _allan_dev(rate, dt, m):
    """Non-overlapping Allan deviation of a rate series at cluster size m (tau = m dt)."""
    k = rate.shape[0] // m
    means = rate[: k * m].reshape(k, m, -1).mean(axis=1)
    return np.sqrt(0.5 * np.mean(np.diff(means, axis=0) ** 2, axis=0))


def test_constant_biases_are_the_mean_increment_error():
    model = ImuErrorModel(gyro_bias_dph=(1.0, -0.5, 0.2), gyro_arw_dpsh=(0.01,) * 3,
                          accel_bias_ug=(50.0, -20.0, 10.0), accel_vrw_mpsph=(0.01,) * 3)
    t, dth, dv = _static(360_000, 0.01)  # one hour at 100 Hz
    m_th, m_dv, _ = apply_imu_errors(t, dth, dv, model, seed=7)
    bg = (m_th - dth).sum(axis=0) / t[-1] / DEG_PER_H_RADPS
    ba = (m_dv - dv).sum(axis=0) / t[-1] / UG_MPS2
    # ARW 0.01 deg/sqrt(h) over 1 h: sigma of the mean 0.01 deg/h; VRW 0.01 m/s/sqrt(h): 1 ug
    np.testing.assert_allclose(bg, [1.0, -0.5, 0.2], atol=0.04)
    np.testing.assert_allclose(ba, [50.0, -20.0, 10.0], atol=4.0)


def test_random_walks_by_allan_deviation_and_increment_variance():
    arw_dpsh, vrw_mpsph = 0.05, 0.02
    model = ImuErrorModel(gyro_arw_dpsh=(arw_dpsh,) * 3, accel_vrw_mpsph=(vrw_mpsph,) * 3)
    dt = 0.005
    t, dth, dv = _static(400_000, dt)
    m_th, m_dv, _ = apply_imu_errors(t, dth, dv, model, seed=3)
    wg = (m_th - dth) / dt
    wa = (m_dv - dv) / dt
    n_g = np.deg2rad(arw_dpsh) / 60.0  # rad/sqrt(s)
    n_a = vrw_mpsph / 60.0  # m/s/sqrt(s)
    # white noise: Allan deviation N / sqrt(tau) at tau = 1 s (m = 200, ~2000 clusters: 2 %)
    np.testing.assert_allclose(_allan_dev(wg, dt, 200), n_g, rtol=0.06)
    np.testing.assert_allclose(_allan_dev(wa, dt, 200), n_a, rtol=0.06)
    # and the increment variance is N^2 dt
    np.testing.assert_allclose((m_th - dth).std(axis=0), n_g * np.sqrt(dt), rtol=0.01)
    np.testing.assert_allclose((m_dv - dv).std(axis=0), n_a * np.sqrt(dt), rtol=0.01)


def test_gauss_markov_sigma_and_correlation_time():
    sigma_dph, tau = 0.5, 5.0
    model = ImuErrorModel(gyro_gm_sigma_dph=(sigma_dph,) * 3, gyro_gm_tau_s=tau,
                          accel_gm_sigma_ug=(30.0,) * 3, accel_gm_tau_s=tau)
    dt = 0.1
    t, dth, dv = _static(400_000, dt)  # 8000 correlation times
    _, _, real = apply_imu_errors(t, dth, dv, model, seed=11)
    x = real.gyro_bias_radps / DEG_PER_H_RADPS
    np.testing.assert_allclose(x.std(axis=0), sigma_dph, rtol=0.05)
    a = (x[1:] * x[:-1]).sum(axis=0) / (x[:-1] ** 2).sum(axis=0)
    np.testing.assert_allclose(-dt / np.log(a), tau, rtol=0.05)
    xa = real.accel_bias_mps2 / UG_MPS2
    np.testing.assert_allclose(xa.std(axis=0), 30.0, rtol=0.05)
    # stationary from the first sample: the ensemble of x_0 over seeds has sigma too
    x0 = [apply_imu_errors(t[:3], dth[:2], dv[:2], model, seed=s)[2].gyro_bias_radps[0, 0]
          for s in range(400)]
    assert np.std(x0) / DEG_PER_H_RADPS == pytest.approx(sigma_dph, rel=0.1)


def test_bias_ramp_by_regression():
    model = ImuErrorModel(gyro_bias_dph=(0.1, 0.0, 0.0), gyro_bias_drift_dphph=(0.3, -0.2, 0.0),
                          accel_bias_drift_ugph=(10.0, 0.0, -5.0))
    t, dth, dv = _static(36_000, 0.1)
    m_th, m_dv, _ = apply_imu_errors(t, dth, dv, model, seed=0)
    t_mid_h = 0.5 * (t[1:] + t[:-1]) / 3600.0
    rate_g = (m_th - dth) / 0.1 / DEG_PER_H_RADPS
    rate_a = (m_dv - dv) / 0.1 / UG_MPS2
    slope_g = np.polyfit(t_mid_h, rate_g, 1)[0]
    slope_a = np.polyfit(t_mid_h, rate_a, 1)[0]
    np.testing.assert_allclose(slope_g, [0.3, -0.2, 0.0], atol=1e-9)
    np.testing.assert_allclose(slope_a, [10.0, 0.0, -5.0], atol=1e-7)


def test_scale_factor_and_misalignment_by_regression_on_a_turning_climb():
    prof = parse_profile({
        "start": {"lat_deg": 30.0, "lon_deg": 100.0, "height_m": 500.0, "heading_deg": 0.0},
        "segment": [{"type": "static", "duration_s": 2.0},
                    {"type": "accelerate", "to_speed_mps": 50.0, "duration_s": 10.0},
                    {"type": "turn", "angle_deg": 120.0, "rate_dps": 8.0, "blend_s": 3.0},
                    {"type": "climb", "rate_mps": 6.0, "delta_m": 60.0, "blend_s": 3.0},
                    {"type": "turn", "angle_deg": -200.0, "rate_dps": 10.0, "blend_s": 4.0}]})
    plan = plan_mission(prof)
    t = np.arange(0.0, plan.duration_s, 0.01)
    dth, dv = exact_increments(ProfileMotion(plan), t)
    sf_g, mis_g = (300.0, -150.0, 500.0), (20.0, -30.0, 40.0, 10.0, -25.0, 35.0)
    sf_a, mis_a = (-200.0, 100.0, 400.0), (15.0, 0.0, -20.0, 30.0, 5.0, -10.0)
    model = ImuErrorModel(gyro_sf_ppm=sf_g, gyro_misalign_arcsec=mis_g, accel_sf_ppm=sf_a,
                          accel_misalign_arcsec=mis_a, gyro_arw_dpsh=(0.001,) * 3)
    m_th, m_dv, _ = apply_imu_errors(t, dth, dv, model, seed=5)
    est_g = np.linalg.lstsq(dth, m_th, rcond=None)[0].T - np.eye(3)  # meas = (I + M) true
    est_a = np.linalg.lstsq(dv, m_dv, rcond=None)[0].T - np.eye(3)
    np.testing.assert_allclose(np.diag(est_g) * 1e6, sf_g, atol=20.0)
    np.testing.assert_allclose(np.diag(est_a) * 1e6, sf_a, atol=1e-3)
    off = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]
    np.testing.assert_allclose([est_g[i, j] / ARCSEC_RAD for i, j in off], mis_g, atol=5.0)
    np.testing.assert_allclose([est_a[i, j] / ARCSEC_RAD for i, j in off], mis_a, atol=1e-3)


def test_grades_hold_the_paper_values():
    assert {"errorfree", "paper_vehicle", "paper_flight"} <= set(grade_names())
    v, f = imu_grade("paper_vehicle"), imu_grade("paper_flight")
    assert np.abs(v.gyro_bias_dph).tolist() == [0.1] * 3 and v.gyro_gm_sigma_dph == (0.05,) * 3
    assert np.abs(f.gyro_bias_dph).tolist() == [1.0] * 3 and f.gyro_gm_sigma_dph == (0.5,) * 3
    assert np.abs(v.accel_bias_ug).tolist() == [5.0] * 3 == np.abs(f.accel_bias_ug).tolist()
    assert imu_grade("errorfree").is_error_free()
    with pytest.raises(ValueError, match="unknown IMU grade"):
        imu_grade("navigation_grade_x")
    with pytest.raises(ValueError, match="unknown IMU error parameter"):
        ImuErrorModel.from_dict({"gyro_bias_degph": [1, 2, 3]})
    with pytest.raises(ValueError, match=">= 0"):
        ImuErrorModel(gyro_arw_dpsh=(-1.0, 0.0, 0.0))


def test_error_free_model_leaves_increments_bit_identical():
    t, dth, dv = _static(1000, 0.01)
    m_th, m_dv, _ = apply_imu_errors(t, dth, dv, ImuErrorModel(), seed=1)
    assert np.array_equal(m_th, dth) and np.array_equal(m_dv, dv)
