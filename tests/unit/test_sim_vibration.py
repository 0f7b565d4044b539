"""IMU vibration (pospp.sim.sensors): a sensor error integrated exactly over each interval.

Independent checks: scipy.integrate.quad of the sinusoid, the closed-form sample RMS of an
interval-averaged sinusoid (rms |sinc(f dt)|), the alias frequency |f - f_s| seen by an FFT, and
a zero mean over whole periods of a static segment of pospp.sim.api.simulate.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from pospp.sim.api import imu_error_model_from_params, simulate
from pospp.sim.profile import parse_profile
from pospp.sim.sensors import ImuErrorModel, apply_imu_errors, imu_grade, vibration_increments

STATIC = parse_profile({
    "name": "static_60s",
    "start": {"lat_deg": 34.0, "lon_deg": 108.0, "height_m": 400.0, "heading_deg": 30.0},
    "segment": [{"type": "static", "duration_s": 60.0}],
})


def test_increments_are_the_exact_integral():
    rms, f, ph = np.array([2.0, 0.5, 7.0]), 47.0, np.array([0.3, 2.0, -1.0])
    for t0, t1 in ((0.0, 0.01), (0.01, 0.02), (0.05, 0.3), (1000.0, 1000.005),
                   (2469.99, 2470.0)):
        got = vibration_increments(np.array([t0, t1]), rms, f, ph)[0]
        for j in range(3):
            ref, _ = quad(lambda s, j=j: np.sqrt(2) * rms[j] * np.sin(2 * np.pi * f * s + ph[j]),
                          t0, t1, epsabs=1e-14, epsrel=1e-12, limit=200)
            assert got[j] == pytest.approx(ref, abs=1e-11)


def test_static_mean_unchanged_and_rms_measured_back():
    """47 Hz x 60 s = 2820 whole periods: the mean specific force and rate of the static
    segment are the error-free ones; the sample RMS is rms |sinc(f dt)| per axis."""
    vib = ImuErrorModel(accel_vibration_rms_mps2=(4.0, 6.0, 8.0),
                        gyro_vibration_rms_dps=(0.5, 1.0, 2.0), vibration_freq_hz=47.0)
    clean = simulate(STATIC, imu_grade="errorfree", seed=3, imu_rate_hz=100.0)
    shaky = simulate(STATIC, imu_grade=vib, seed=3, imu_rate_hz=100.0)
    df = shaky.imu.f_ib_b_mps2 - clean.imu.f_ib_b_mps2
    dw = np.rad2deg(shaky.imu.w_ib_b_radps - clean.imu.w_ib_b_radps)
    assert len(df) == 6000
    np.testing.assert_allclose(df.mean(axis=0), 0.0, atol=1e-10)
    np.testing.assert_allclose(dw.mean(axis=0), 0.0, atol=1e-12)
    gain = abs(np.sinc(47.0 * 0.01))  # np.sinc(x) = sin(pi x) / (pi x)
    np.testing.assert_allclose(np.sqrt((df**2).mean(axis=0)), np.array([4.0, 6.0, 8.0]) * gain,
                               rtol=1e-3)
    np.testing.assert_allclose(np.sqrt((dw**2).mean(axis=0)), np.array([0.5, 1.0, 2.0]) * gain,
                               rtol=1e-3)
    # the realised bias (and so NAME.bias.parquet) does not contain the vibration
    np.testing.assert_array_equal(shaky.imu_errors.accel_bias_mps2,
                                  clean.imu_errors.accel_bias_mps2)


def test_vibration_above_nyquist_aliases():
    """97 Hz sampled at 100 Hz shows up at |97 - 100| = 3 Hz, with gain |sinc(0.97)|."""
    t = np.arange(6001) * 0.01
    z = np.zeros((6000, 3))
    m = ImuErrorModel(accel_vibration_rms_mps2=(10.0, 0.0, 0.0), vibration_freq_hz=97.0)
    _, dv, _ = apply_imu_errors(t, z, z, m, 5)
    f = dv[:, 0] / 0.01
    spec = np.abs(np.fft.rfft(f))
    freqs = np.fft.rfftfreq(f.size, 0.01)
    assert freqs[np.argmax(spec)] == pytest.approx(3.0)
    assert np.sqrt((f**2).mean()) == pytest.approx(10.0 * abs(np.sinc(0.97)), rel=1e-3)
    np.testing.assert_array_equal(dv[:, 1:], 0.0)


def test_other_errors_keep_their_bits_and_seed_is_deterministic():
    base = dict(gyro_arw_dpsh=(0.6,) * 3, accel_vrw_mpsph=(0.3,) * 3,
                gyro_gm_sigma_dph=(10.0,) * 3, accel_gm_sigma_ug=(300.0,) * 3)
    t = np.arange(2001) * 0.005
    rng = np.random.default_rng(11)
    dth, dv = rng.normal(0, 1e-3, (2000, 3)), rng.normal(0, 1e-2, (2000, 3))
    off = apply_imu_errors(t, dth, dv, ImuErrorModel(**base), 9)
    on = ImuErrorModel(**base, accel_vibration_rms_mps2=(5.0,) * 3,
                       gyro_vibration_rms_dps=(1.0,) * 3, vibration_freq_hz=33.0)
    a, b = apply_imu_errors(t, dth, dv, on, 9), apply_imu_errors(t, dth, dv, on, 9)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    # the difference to the run without vibration is the vibration alone (same other streams)
    vib_a = a[1] - off[1]
    assert np.sqrt(((vib_a / 0.005)**2).mean()) == pytest.approx(
        5.0 * abs(np.sinc(33.0 * 0.005)), rel=2e-2)
    np.testing.assert_allclose(vib_a.sum(axis=0), 0.0, atol=1e-11)  # 330 whole periods
    np.testing.assert_array_equal(off[2].gyro_bias_radps, a[2].gyro_bias_radps)
    c = apply_imu_errors(t, dth, dv, on, 10)
    assert not np.array_equal(a[1], c[1])


def test_parameters_validation_and_params_round_trip():
    m = ImuErrorModel(accel_vibration_rms_mps2=(5.0, 5.0, 6.0), vibration_freq_hz=47.0)
    d = m.as_dict()
    assert d["accel_vibration_rms_mps2"] == [5.0, 5.0, 6.0] and d["vibration_freq_hz"] == 47.0
    assert not m.is_error_free() and m.has_vibration()
    params = {"config": {"imu_errors": d}}
    assert imu_error_model_from_params(params) == m
    # vibration-free models write no vibration keys (older params files stay identical)
    assert not any("vibration" in k for k in ImuErrorModel().as_dict())
    assert ImuErrorModel(vibration_freq_hz=10.0).is_error_free()
    with pytest.raises(ValueError, match="rms"):
        ImuErrorModel(gyro_vibration_rms_dps=(-1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="vibration_freq_hz"):
        ImuErrorModel(vibration_freq_hz=0.0)


def test_mems_grade_vibrates_like_the_ardupilot_log():
    """docs/results.md: about 5-10 m/s^2 RMS accelerometer vibration (norm) in flight."""
    m = imu_grade("mems")
    t = np.arange(12001) * 0.01
    z = np.zeros((12000, 3))
    mv = ImuErrorModel(accel_vibration_rms_mps2=m.accel_vibration_rms_mps2,
                       gyro_vibration_rms_dps=m.gyro_vibration_rms_dps,
                       vibration_freq_hz=m.vibration_freq_hz)
    _, dv, _ = apply_imu_errors(t, z, z, mv, 1)
    rms_norm = np.sqrt(((dv / 0.01) ** 2).sum(axis=1).mean())
    assert 5.0 <= rms_norm <= 10.0, rms_norm
    for g in ("errorfree", "paper_vehicle", "paper_flight", "tactical"):
        assert not imu_grade(g).has_vibration()


def test_band_limited_vibration_rms_and_band():
    """Band-limited vibration (16 seeded tones per axis in [f - B/2, f + B/2]): total RMS is
    the configured one and the power sits in the band (1 kHz IMU: sinc gain > 0.99)."""
    t = np.arange(120_001) * 0.001
    z = np.zeros((120_000, 3))
    m = ImuErrorModel(accel_vibration_rms_mps2=(6.0, 6.0, 6.0), vibration_freq_hz=47.0,
                      vibration_bandwidth_hz=20.0)
    _, dv, _ = apply_imu_errors(t, z, z, m, 21)
    f = dv / 0.001
    np.testing.assert_allclose(np.sqrt((f**2).mean(axis=0)), 6.0, rtol=0.05)
    spec = np.abs(np.fft.rfft(f, axis=0)) ** 2
    freqs = np.fft.rfftfreq(f.shape[0], 0.001)
    band = (freqs >= 36.9) & (freqs <= 57.1)
    assert (spec[band].sum(axis=0) / spec.sum(axis=0) > 0.99).all()
    # more than one tone per axis: no single FFT bin holds most of the power
    assert (spec.max(axis=0) / spec.sum(axis=0) < 0.5).all()
    _, again, _ = apply_imu_errors(t, z, z, m, 21)
    np.testing.assert_array_equal(dv, again)
    with pytest.raises(ValueError, match="bandwidth"):
        ImuErrorModel(vibration_freq_hz=10.0, vibration_bandwidth_hz=25.0)
