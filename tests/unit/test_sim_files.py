"""Simulation files: MCAP round trip (mcap_ros2 decoder and pospp's reader), truth Parquet,
params JSON, and bit-identical reproduction from a seed."""

from __future__ import annotations

import numpy as np
import pytest
from mcap_ros2.reader import read_ros2_messages

from pospp.io.mcap_reader import read_flight_log
from pospp.io.parquet_tables import read_reference_trajectory
from pospp.io.simulation_files import read_bias_table, read_params, write_simulation
from pospp.sim.api import gnss_model_from_params, imu_error_model_from_params, simulate
from pospp.sim.gnss import GnssModel

GNSS = GnssModel(rate_hz=2.0, lever_arm_b_m=(0.5, 0.2, -1.2), time_offset_s=0.01,
                 outages_s=((20.0, 25.0),))


@pytest.fixture(scope="module")
def sim():
    return simulate("sample", imu_grade="paper_flight", gnss=GNSS, seed=42, imu_rate_hz=50.0,
                    duration_s=700.0)


@pytest.fixture(scope="module")
def short():
    return simulate("sample", imu_grade="paper_flight", gnss=GNSS, seed=42, imu_rate_hz=50.0,
                    duration_s=100.0)


def test_same_seed_same_bits_other_seed_other_bits(sim):
    again = simulate("sample", imu_grade="paper_flight", gnss=GNSS, seed=42, imu_rate_hz=50.0,
                     duration_s=700.0)
    for a, b in ((sim.imu.w_ib_b_radps, again.imu.w_ib_b_radps),
                 (sim.imu.f_ib_b_mps2, again.imu.f_ib_b_mps2),
                 (sim.fix.lat_rad, again.fix.lat_rad), (sim.vel.v_n_mps, again.vel.v_n_mps),
                 (sim.truth.q_nb, again.truth.q_nb)):
        assert np.array_equal(a, b)
    other = simulate("sample", imu_grade="paper_flight", gnss=GNSS, seed=43, imu_rate_hz=50.0,
                     duration_s=700.0)
    assert not np.array_equal(sim.imu.w_ib_b_radps, other.imu.w_ib_b_radps)
    assert np.array_equal(sim.truth.q_nb, other.truth.q_nb)  # the truth does not depend on it


def test_mcap_round_trip_through_the_ros2_decoder_and_pospp_reader(short, tmp_path):
    sim = short
    paths = write_simulation(sim, tmp_path, "case")
    flu = np.array([1.0, -1.0, -1.0])
    imu, fix, vel = [], [], []
    for m in read_ros2_messages(str(paths["mcap"])):
        msg = m.ros_msg
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if m.channel.topic == "/imu/data":
            imu.append((stamp, msg.angular_velocity.x, msg.angular_velocity.y,
                        msg.angular_velocity.z, msg.linear_acceleration.x,
                        msg.linear_acceleration.y, msg.linear_acceleration.z))
        elif m.channel.topic == "/gnss/fix":
            fix.append((stamp, msg.latitude, msg.longitude, msg.altitude))
        elif m.channel.topic == "/gnss/vel":
            v = msg.twist.twist.linear
            vel.append((stamp, v.x, v.y, v.z))
    imu, fix, vel = np.array(imu), np.array(fix), np.array(vel)
    assert np.array_equal(imu[:, 0].astype(np.int64), sim.imu.time_ns)
    assert np.array_equal(imu[:, 1:4], sim.imu.w_ib_b_radps * flu)  # FLU in the file
    assert np.array_equal(imu[:, 4:7], sim.imu.f_ib_b_mps2 * flu)
    assert np.array_equal(fix[:, 1], np.rad2deg(sim.fix.lat_rad))
    assert np.array_equal(fix[:, 2], np.rad2deg(sim.fix.lon_rad))
    assert np.array_equal(fix[:, 3], sim.fix.height_m)
    assert np.array_equal(vel[:, 1:], sim.vel.v_n_mps[:, [1, 0, 2]] * [1.0, 1.0, -1.0])  # ENU
    log = read_flight_log(paths["mcap"])
    assert log.complete and not [i for i in log.issues if i.severity == "error"]
    assert np.array_equal(log.imu.time_ns, sim.imu.time_ns)
    assert np.array_equal(log.imu.w_ib_b_radps, sim.imu.w_ib_b_radps)
    assert np.array_equal(log.imu.f_ib_b_mps2, sim.imu.f_ib_b_mps2)
    assert np.array_equal(log.fix.time_ns, sim.fix.time_ns)
    np.testing.assert_allclose(log.fix.lat_rad, sim.fix.lat_rad, rtol=0, atol=1e-15)
    np.testing.assert_allclose(log.fix.pos_cov_ned_m2, sim.fix.pos_cov_ned_m2, rtol=1e-15)
    np.testing.assert_allclose(log.vel.v_n_mps, sim.vel.v_n_mps, rtol=0, atol=1e-15)


def test_truth_and_params_files(sim, tmp_path):
    paths = write_simulation(sim, tmp_path, "case")
    ref = read_reference_trajectory(paths["truth"])
    want = sim.truth_reference(10.0)
    assert np.array_equal(ref.time_ns, want.time_ns)
    assert np.diff(ref.time_ns).tolist() == [100_000_000] * (len(ref) - 1)
    np.testing.assert_allclose(ref.lat_rad, want.lat_rad, rtol=0, atol=1e-15)
    np.testing.assert_allclose(ref.v_n_mps, want.v_n_mps, rtol=0, atol=1e-12)
    params = read_params(paths["params"])
    assert imu_error_model_from_params(params) == __import__(
        "pospp.sim.sensors", fromlist=["imu_grade"]).imu_grade("paper_flight")
    assert gnss_model_from_params(params) == GNSS
    assert params["seed"] == 42 and params["time"]["imu_dt_ns"] == 20_000_000
    assert params["outputs"]["message_counts"]["/imu/data"] == len(sim.imu)
    assert set(params["conventions"]) >= {"nav_frame", "body_frame", "random_drift"}
    legs = params["legs"]
    assert legs and {"start_ns", "end_ns", "heading_deg", "speed_mps", "height_m"} <= set(legs[0])
    # the true legs really are straight and level at the stated speed in the truth
    leg = sim.legs[0]
    k = (sim.truth_time_ns >= leg.start_ns) & (sim.truth_time_ns <= leg.end_ns)
    v = sim.truth.v_n_mps[k]
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), leg.speed_mps, atol=1e-9)
    np.testing.assert_allclose(np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360,
                               leg.heading_deg, atol=1e-9)
    np.testing.assert_allclose(sim.truth.height_m[k], leg.height_m, atol=1e-6)
    # realised biases at 10 Hz: the constant part plus a Gauss-Markov of the grade's sigma
    bias = read_bias_table(paths["bias"])
    assert np.array_equal(bias["time_ns"], ref.time_ns)
    g = np.column_stack([bias[f"gyro_bias_{a}_dph"] for a in "xyz"])
    assert np.abs(g.mean(axis=0) - [1.0, -1.0, 1.0]).max() < 3 * 0.5
    assert 0.0 < g.std(axis=0).min() and g.std(axis=0).max() < 1.0
    np.testing.assert_allclose([bias[f"accel_bias_{a}_ug"][5] for a in "xyz"], [5, -5, 5])


def _arrays_close(a: object, b: object, what: str, rtol: float = 1e-12) -> None:
    """Every array field of two dataclasses (or columns of two tables) equal, floats within
    ``rtol`` of the field's RMS; integers (time stamps) exactly."""
    import dataclasses

    import pandas as pd

    if isinstance(a, pd.DataFrame):
        assert list(a.columns) == list(b.columns), what
        pairs = [(str(c), a[c].to_numpy(), b[c].to_numpy()) for c in a.columns]
    else:
        pairs = [(f.name, getattr(a, f.name), getattr(b, f.name))
                 for f in dataclasses.fields(a) if isinstance(getattr(a, f.name), np.ndarray)]
    assert pairs, what
    for name, x, y in pairs:
        assert x.shape == y.shape and x.dtype == y.dtype, (what, name)
        if x.dtype.kind == "f":
            scale = float(np.sqrt(np.nanmean(y.astype(float) ** 2))) if y.size else 0.0
            np.testing.assert_allclose(x, y, rtol=0.0, atol=rtol * max(scale, 1e-300),
                                       err_msg=f"{what}.{name}")
        else:
            assert np.array_equal(x, y), (what, name)


@pytest.mark.slow
def test_committed_sample_data_regenerates(tmp_path):
    """sample_data/README.md's recipe reproduces the committed files: every message, stamp
    and table value, floats to 1e-12 of each field's RMS. Bit for bit on one installation;
    across numpy / numba versions the last bits move (measured: a fresh install of numpy
    2.4.6 moved the truth's velocities and attitudes by 1e-15 of their RMS and so every byte
    comparison), which is not a change of the data. The files are compared decoded, never as
    bytes through pytest's assertion diff (which spent 20 minutes diffing 10 MB)."""
    from pathlib import Path

    import pandas as pd

    root = Path(__file__).resolve().parents[2] / "sample_data"
    sim = simulate(
        "sample", imu_grade="paper_flight",
        gnss=GnssModel(rate_hz=1.0, pos_noise_m=(0.05, 0.1), vel_noise_mps=(0.02, 0.03),
                       lever_arm_b_m=(0.3, 0.1, -1.5)),
        seed=2012, imu_rate_hz=100.0,
    )
    paths = write_simulation(sim, tmp_path, "sample_flight")
    new_log, old_log = read_flight_log(paths["mcap"]), read_flight_log(root / "sample_flight.mcap")
    for part in ("imu", "fix", "vel"):
        _arrays_close(getattr(new_log, part), getattr(old_log, part), f"mcap {part}")
    for key in ("truth", "bias"):
        _arrays_close(pd.read_parquet(paths[key]), pd.read_parquet(root / paths[key].name), key)
    new, old = read_params(paths["params"]), read_params(root / "sample_flight.params.json")
    for p in (new, old):
        p["numerics"].pop("timings_s")
        p["outputs"].pop("sizes_bytes")  # compressed sizes move with the last bits
    assert new == old
