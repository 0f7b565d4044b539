"""Mounting estimation: recover a known sensor rotation, on synthetic and independent data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pospp import earth, rotation
from pospp.nav.mounting import MountingOptions, estimate_mounting

LAT = np.radians(45.0)


def _synthetic(c_sb: np.ndarray, *, noise_mps2: float, seed: int):
    """A car at rest 30 s, then accelerating / turning on level ground; f_s = C_sb C_bn f_n."""
    rng = np.random.default_rng(seed)
    dt = 0.01
    t = np.arange(0.0, 150.0, dt)
    speed = np.where(t < 30, 0.0, np.minimum((t - 30) * 1.0, 15.0))
    accel = np.where((t >= 30) & (t < 45), 1.0, 0.0)
    yaw_rate = np.where(t > 60, 0.1 * np.sin(2 * np.pi * (t - 60) / 30.0), 0.0)
    yaw = 0.3 + np.cumsum(yaw_rate) * dt
    v_n = np.column_stack([speed * np.cos(yaw), speed * np.sin(yaw), np.zeros_like(t)])
    a_n = np.column_stack([
        accel * np.cos(yaw) - speed * yaw_rate * np.sin(yaw),
        accel * np.sin(yaw) + speed * yaw_rate * np.cos(yaw),
        np.zeros_like(t),
    ])
    g = float(earth.normal_gravity_mps2(LAT, 0.0))
    f_n = a_n - np.array([0.0, 0.0, g])
    c_bn = np.swapaxes(rotation.dcm_from_euler(
        np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw])), -1, -2)
    f_b = np.einsum("kij,kj->ki", c_bn, f_n)
    f_s = f_b @ c_sb.T + noise_mps2 * rng.standard_normal(f_b.shape)
    k = slice(None, None, 10)  # 10 Hz velocity
    return t, f_s, t[k], v_n[k]


@pytest.mark.parametrize("rpy_deg", [(0.0, 0.0, 0.0), (180.0, 0.0, 0.0), (3.0, -4.0, 90.0),
                                     (-100.0, 30.0, 200.0)])
def test_recovers_known_rotation_noise_free(rpy_deg):
    c_sb = rotation.dcm_from_euler(np.radians(rpy_deg))
    t, f_s, tv, v = _synthetic(c_sb, noise_mps2=0.0, seed=1)
    est = estimate_mounting(t, f_s, tv, v, lat_rad=LAT)
    # closed form of the data-generating model: C_bs = C_sb^T
    assert np.degrees(rotation.angle_between_rad(est.c_bs, c_sb.T)) < 0.05
    assert est.levelling_residual_rad < 1e-3  # window discretisation only


def test_sigma_consistent_with_error_under_noise():
    c_sb = rotation.dcm_from_euler(np.radians([2.0, -3.0, 30.0]))
    errs_tilt, errs_head, sig_tilt, sig_head = [], [], [], []
    for seed in range(8):
        t, f_s, tv, v = _synthetic(c_sb, noise_mps2=0.5, seed=seed)
        est = estimate_mounting(t, f_s, tv, v, lat_rad=LAT)
        d = rotation.rotvec_from_dcm(est.c_bs @ c_sb)  # body-frame error rotation
        errs_tilt.append(np.hypot(d[0], d[1]))
        errs_head.append(abs(d[2]))
        sig_tilt.append(est.tilt_sigma_rad)
        sig_head.append(est.heading_sigma_rad)
    # errors within a few sigma (tilt has two components: Rayleigh, mean ~1.25 sigma)
    assert np.mean(errs_tilt) < 4.0 * np.mean(sig_tilt)
    assert np.sqrt(np.mean(np.square(errs_head))) < 3.0 * np.mean(sig_head)
    assert np.degrees(np.max(errs_head)) < 1.0


def test_too_few_windows_are_refused():
    c_sb = np.eye(3)
    t, f_s, tv, v = _synthetic(c_sb, noise_mps2=0.0, seed=1)
    with pytest.raises(ValueError, match="levelling needs"):
        estimate_mounting(t, f_s, tv, v, lat_rad=LAT,
                          options=MountingOptions(min_static_windows=10_000))
    with pytest.raises(ValueError, match="forward axis needs"):
        rest = t < 29.0
        estimate_mounting(t[rest], f_s[rest], tv[tv < 29.0], v[tv < 29.0], lat_rad=LAT)


@pytest.mark.reference
def test_recovers_rotation_on_independent_simulator(reference_cases):
    """The independent simulator's error-free drive, rotated by a known mounting."""
    from pospp.io.mcap_reader import read_flight_log

    log = read_flight_log(reference_cases / "vehicle_errorfree.mcap")
    params = json.loads((reference_cases / "vehicle_errorfree.params.json").read_text())
    assert params  # the case documents its conventions; body FRD, NED
    c_sb = rotation.dcm_from_euler(np.radians([17.0, -11.0, 115.0]))
    f_s = log.imu.f_ib_b_mps2 @ c_sb.T
    e0 = log.imu.time_ns[0]
    est = estimate_mounting((log.imu.time_ns - e0) * 1e-9, f_s, (log.vel.time_ns - e0) * 1e-9,
                            log.vel.v_n_mps, lat_rad=float(log.fix.lat_rad[0]),
                            height_m=float(log.fix.height_m[0]))
    err_deg = np.degrees(rotation.angle_between_rad(est.c_bs, c_sb.T))
    assert err_deg < 0.05
    assert est.n_static_windows > 200 and est.n_moving_windows > 10


@pytest.mark.reference
def test_aircraft_needs_its_attitude_and_scatter_says_so(reference_cases):
    """Survey flight (accelerometer bias, banked turns): true attitude vs default assumption."""
    import pandas as pd

    from pospp.io.mcap_reader import read_flight_log

    log = read_flight_log(reference_cases / "flight_survey_errors.mcap")
    truth = pd.read_parquet(reference_cases / "flight_survey_errors.truth.parquet")
    c_sb = rotation.dcm_from_euler(np.radians([-60.0, 5.0, 250.0]))
    f_s = log.imu.f_ib_b_mps2 @ c_sb.T
    e0 = log.imu.time_ns[0]
    t_i = (log.imu.time_ns - e0) * 1e-9
    t_t = (truth["time_ns"].to_numpy() - e0) * 1e-9
    v = truth[["vn_mps", "ve_mps", "vd_mps"]].to_numpy()
    rpy = np.radians(truth[["roll_deg", "pitch_deg", "yaw_deg"]].to_numpy())
    kw = dict(lat_rad=float(log.fix.lat_rad[0]), height_m=float(log.fix.height_m[0]))
    good = estimate_mounting(t_i, f_s, t_t, v, body_rpy_rad=rpy, **kw)
    # accelerometer bias of the case (params.json) tilts by about bias / g: < 0.1 deg
    assert np.degrees(rotation.angle_between_rad(good.c_bs, c_sb.T)) < 0.1
    assert np.degrees(good.heading_scatter_rad) < 1.0
    naive = estimate_mounting(t_i, f_s, t_t, v, **kw)
    assert np.degrees(naive.heading_scatter_rad) > 30.0
