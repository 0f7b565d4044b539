"""The MCAP reader against the independent simulator's reference cases (../shared).

Independent sides: the file's own summary statistics (counts), ``mcap_ros2``'s generic CDR
decoder (values of single messages), the simulator's truth Parquet and params.json (frames and
signs: static specific force and Earth rate, GNSS velocity versus true velocity), and WGS-84
normal gravity written out here from NIMA TR8350.2 rather than taken from pospp.earth.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from pospp.io.mcap_reader import FlightLog, read_flight_log

pytestmark = pytest.mark.reference

CASES = ("vehicle_errorfree", "flight_survey_errors")
T0_NS = 1_717_200_000_000_000_000  # README: stamps start here plus one IMU interval
EARTH_RATE_RADPS = 7.292115e-5  # WGS-84
DPH = np.deg2rad(1.0) / 3600.0
UG_MPS2 = 9.80665e-6


def somigliana_gravity_mps2(lat_rad: float, h_m: float) -> float:
    """WGS-84 normal gravity with the second-order height term (NIMA TR8350.2, Eq. 4-1, 4-3)."""
    a, f, m = 6378137.0, 1 / 298.257223563, 0.00344978650684
    ge, k, e2 = 9.7803253359, 0.00193185265241, 0.00669437999013
    s2 = np.sin(lat_rad) ** 2
    g0 = ge * (1 + k * s2) / np.sqrt(1 - e2 * s2)
    return float(g0 * (1 - 2 / a * (1 + f + m - 2 * f * s2) * h_m + 3 * h_m**2 / a**2))


@pytest.fixture(scope="module", params=CASES)
def case(request, reference_cases: Path) -> dict:
    name = request.param
    log = read_flight_log(reference_cases / f"{name}.mcap")
    return {
        "name": name,
        "path": reference_cases / f"{name}.mcap",
        "log": log,
        "truth": pd.read_parquet(reference_cases / f"{name}.truth.parquet"),
        "params": json.loads((reference_cases / f"{name}.params.json").read_text()),
    }


def test_counts_and_first_last_stamps(case: dict) -> None:
    log: FlightLog = case["log"]
    assert log.complete and log.issues == ()
    with open(case["path"], "rb") as fh:
        summary = make_reader(fh).get_summary()
    counts = {summary.channels[c].topic: n
              for c, n in summary.statistics.channel_message_counts.items()}
    assert counts == {"/imu/data": len(log.imu), "/gnss/fix": len(log.fix),
                      "/gnss/vel": len(log.vel)}
    cfg = case["params"]["config"]
    imu_dt_ns = round(1e9 / cfg["imu_rate_hz"])
    gnss_dt_ns = round(1e9 / cfg["gnss"]["rate_hz"])
    duration_ns = int(case["truth"].time_ns.iloc[-1] - case["truth"].time_ns.iloc[0])
    assert log.imu.time_ns[0] == T0_NS + imu_dt_ns
    assert log.imu.time_ns[-1] == T0_NS + duration_ns
    assert len(log.imu) == duration_ns // imu_dt_ns
    assert np.all(np.diff(log.imu.time_ns) == imu_dt_ns)
    assert log.fix.time_ns[0] == T0_NS and log.fix.time_ns[-1] == T0_NS + duration_ns
    assert np.all(np.diff(log.fix.time_ns) == gnss_dt_ns)
    np.testing.assert_array_equal(log.vel.time_ns, log.fix.time_ns)


def test_values_match_generic_decoder(case: dict) -> None:
    """Single messages fetched by log time with mcap's index and decoded by mcap_ros2."""
    log: FlightLog = case["log"]
    picks = {"/imu/data": [0, 1, 12345, len(log.imu) // 2, len(log.imu) - 1],
             "/gnss/fix": [0, len(log.fix) // 3, len(log.fix) - 1],
             "/gnss/vel": [0, len(log.vel) // 3, len(log.vel) - 1]}
    stamps = {"/imu/data": log.imu.time_ns, "/gnss/fix": log.fix.time_ns,
              "/gnss/vel": log.vel.time_ns}
    with open(case["path"], "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for topic, idx in picks.items():
            for i in idx:
                t = int(stamps[topic][i])
                [m] = [d.decoded_message for d in reader.iter_decoded_messages(
                    topics=[topic], starting_at=t, ending_at=t)]
                assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == t
                if topic == "/imu/data":
                    w = m.angular_velocity
                    f = m.linear_acceleration
                    # FLU -> FRD written out: [x, -y, -z]
                    assert log.imu.w_ib_b_radps[i].tolist() == [w.x, -w.y, -w.z]
                    assert log.imu.f_ib_b_mps2[i].tolist() == [f.x, -f.y, -f.z]
                elif topic == "/gnss/fix":
                    assert log.fix.lat_rad[i] == np.deg2rad(m.latitude)
                    assert log.fix.lon_rad[i] == np.deg2rad(m.longitude)
                    assert log.fix.height_m[i] == m.altitude
                    c = np.array(m.position_covariance).reshape(3, 3)
                    p = log.fix.pos_cov_ned_m2[i]
                    assert (p[0, 0], p[1, 1], p[2, 2]) == (c[1, 1], c[0, 0], c[2, 2])
                    assert (p[0, 1], p[0, 2], p[1, 2]) == (c[1, 0], -c[1, 2], -c[0, 2])
                else:
                    v = m.twist.twist.linear  # ENU -> NED written out: [N, E, -U]
                    assert log.vel.v_n_mps[i].tolist() == [v.y, v.x, -v.z]


def _static_mask(case: dict) -> np.ndarray:
    seg = case["params"]["config"]["mission"]["segment"][0]
    assert seg["type"] == "static"
    t_s = (case["log"].imu.time_ns - T0_NS) * 1e-9
    return t_s <= seg["duration_s"] - 1.0


def test_static_specific_force_points_up_in_flu_and_down_in_frd(case: dict) -> None:
    """Level and static: the accelerometer reads -g_b = [0, 0, -gamma] in FRD (+gamma up in the
    FLU message), plus the injected accelerometer bias (sensors read true + bias)."""
    log: FlightLog = case["log"]
    static = _static_mask(case)
    truth0 = case["truth"].iloc[0]
    gamma = somigliana_gravity_mps2(np.deg2rad(truth0.lat_deg), truth0.height_m)
    bias = np.array(case["params"]["config"]["imu_errors"]["accel_bias_ug"]) * UG_MPS2
    mean_f = log.imu.f_ib_b_mps2[static].mean(axis=0)
    np.testing.assert_allclose(mean_f, np.array([0.0, 0.0, -gamma]) + bias, rtol=0, atol=2e-7)
    assert mean_f[2] < -9.7  # about [0, 0, -g] in FRD ...
    with open(case["path"], "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        first = next(reader.iter_decoded_messages(topics=["/imu/data"])).decoded_message
    assert first.linear_acceleration.z > 9.7  # ... and [0, 0, +g] in the FLU message


def test_static_gyro_reads_earth_rate_in_frd(case: dict) -> None:
    """w_ib_b = C_bn [W cos L, 0, -W sin L] + gyro bias, with C_nb from the truth's z-y-x
    Euler angles (scipy, intrinsic 'ZYX' = yaw, pitch, roll)."""
    log: FlightLog = case["log"]
    static = _static_mask(case)
    truth0 = case["truth"].iloc[0]
    lat = np.deg2rad(truth0.lat_deg)
    c_nb = Rotation.from_euler(
        "ZYX", [truth0.yaw_deg, truth0.pitch_deg, truth0.roll_deg], degrees=True
    ).as_matrix()
    w_ie_n = EARTH_RATE_RADPS * np.array([np.cos(lat), 0.0, -np.sin(lat)])
    bias = np.array(case["params"]["config"]["imu_errors"]["gyro_bias_dph"]) * DPH
    mean_w = log.imu.w_ib_b_radps[static].mean(axis=0)
    np.testing.assert_allclose(mean_w, c_nb.T @ w_ie_n + bias, rtol=0, atol=0.03 * DPH)
    assert mean_w[2] < 0  # the Earth turns about -down in the northern hemisphere


def test_gnss_velocity_agrees_with_truth_within_noise(case: dict) -> None:
    """GNSS (antenna) velocity minus truth velocity at the same stamps, minus the lever-arm
    term C_nb (w_nb_b x l_b) with w from the IMU: residual RMS consistent with the injected
    noise (an axis swap or sign error would be tens of m/s)."""
    log: FlightLog = case["log"]
    truth = case["truth"].set_index("time_ns")
    gnss = case["params"]["config"]["gnss"]
    t = log.vel.time_ns
    on_truth = np.isin(t, truth.index.to_numpy())
    t = t[on_truth]
    tr = truth.loc[t]
    v_true = tr[["vn_mps", "ve_mps", "vd_mps"]].to_numpy()
    c_nb = Rotation.from_euler(
        "ZYX", tr[["yaw_deg", "pitch_deg", "roll_deg"]].to_numpy(), degrees=True
    ).as_matrix()
    k = np.searchsorted(log.imu.time_ns, t)
    k = np.clip(k, 1, len(log.imu) - 1)
    w_b = 0.5 * (log.imu.w_ib_b_radps[k - 1] + log.imu.w_ib_b_radps[k])
    lever_b = np.array(gnss["lever_arm_m"])
    v_lever = np.einsum("nij,nj->ni", c_nb, np.cross(w_b, lever_b))
    res = log.vel.v_n_mps[on_truth] - v_true - v_lever
    h_sig, v_sig = (max(s, 1e-4) for s in gnss["vel_noise_mps"])
    rms = np.sqrt(np.mean(res**2, axis=0))
    assert np.all(rms[:2] < 1.5 * h_sig) and rms[2] < 1.5 * v_sig
    assert np.all(np.abs(res.mean(axis=0)) < 0.2 * np.array([h_sig, h_sig, v_sig]) + 1e-6)
    moving = np.hypot(v_true[:, 0], v_true[:, 1]) > 5.0
    assert moving.sum() > 100  # the check covers motion in several headings
    headings = np.rad2deg(np.arctan2(v_true[moving, 1], v_true[moving, 0])) % 360
    assert np.ptp(headings) > 150
