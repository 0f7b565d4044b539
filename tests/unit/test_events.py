"""Trigger events: the events topic through the writer and the reader, and the sensor's pose at
every event against closed forms, the independent reference cases' truth and the simulator's
truth through algorithm A."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from mcap_ros2.reader import read_ros2_messages
from scipy.spatial.transform import Rotation, Slerp

from pospp import earth, rotation
from pospp.config import config_from_dict
from pospp.io.mcap_reader import read_flight_log
from pospp.io.simulation_files import write_simulation
from pospp.nav.events import sensor_poses
from pospp.nav.smoother import pack_symmetric
from pospp.nav.solution import NavSolution
from pospp.sim.api import simulate
from pospp.sim.gnss import GnssModel

LEVER_B_M = np.array([1.2, -0.4, 0.7])
BORESIGHT_RPY_DEG = (1.0, -2.0, 90.0)
GNSS = GnssModel(rate_hz=1.0, lever_arm_b_m=(0.5, 0.2, -1.2))


def _solution(t_s, lat, lon, h, v_n, q_nb, *, sigma_scale=0.0) -> NavSolution:
    n = len(t_s)
    eye = np.tile(np.eye(3), (n, 1, 1))
    return NavSolution(
        time_ns=np.round(np.asarray(t_s) * 1e9).astype(np.int64), t_s=np.asarray(t_s, float),
        lat_rad=lat, lon_rad=lon, height_m=h, v_n_mps=v_n, q_nb=q_nb,
        pos_cov_packed_ned_m2=pack_symmetric(eye * sigma_scale**2),
        vel_cov_packed_ned_m2ps2=pack_symmetric(eye * 0.0),
        att_cov_packed_ned_rad2=pack_symmetric(eye * (1e-3) ** 2))


def test_lever_arm_and_boresight_closed_form():
    """Level, heading east, turning at 0.1 rad/s: a sensor 1 m forward sits 1 m east of the
    IMU, moves 0.1 m/s faster to the south, and its yaw is the body's plus the boresight's."""
    t = np.arange(11) * 0.1
    yaw = np.pi / 2 + 0.1 * t
    q = rotation.quat_from_euler(np.column_stack([0 * t, 0 * t, yaw]))
    lat0, lon0 = np.radians(45.0), np.radians(10.0)
    sol = _solution(t, np.full(11, lat0), np.full(11, lon0), np.full(11, 100.0),
                    np.zeros((11, 3)), q)
    c_bs = rotation.dcm_from_euler(np.radians([0.0, 0.0, 90.0]))
    p = sensor_poses(sol, [0.0, 0.55], lever_b_m=[1.0, 0.0, 0.0], c_bs=c_bs)
    ned = earth.llh_to_ned_m(p.lat_rad[0], p.lon_rad[0], p.height_m[0], lat0, lon0, 100.0)
    np.testing.assert_allclose(ned, [0.0, 1.0, 0.0], atol=1e-6)
    # rotating at w_z = 0.1 rad/s: v = w x l = 0.1 to the body's right, which points south
    yaw_mid = np.pi / 2 + 0.055
    v_expect = 0.1 * np.array([np.cos(yaw_mid + np.pi / 2), np.sin(yaw_mid + np.pi / 2), 0.0])
    np.testing.assert_allclose(p.v_n_mps[1], v_expect, atol=1e-6)
    np.testing.assert_allclose(np.degrees(p.rpy_rad[:, 2]), [180.0, 180.0 + np.degrees(0.055)],
                               atol=1e-9)
    # the attitude error (1 mrad per axis) moves a 1 m lever by 1 mm across it
    np.testing.assert_allclose(p.pos_sigma_ned_m[0], [1e-3, 0.0, 1e-3], atol=1e-12)
    out = sensor_poses(sol, [-1.0, 2.0])
    assert not out.inside.any() and np.isnan(out.lat_rad).all()


REF_CASE = "flight_survey_errors"


def test_interpolation_against_the_reference_case_truth(reference_cases):
    """A 5 Hz solution made of the independent simulator's truth, interpolated at the 10 Hz
    epochs in between, against the truth there (climb, transit, survey lines and turns)."""
    truth = pd.read_parquet(reference_cases / f"{REF_CASE}.truth.parquet")
    t_s = (truth.time_ns.to_numpy() - truth.time_ns.iloc[0]) * 1e-9
    lat, lon = np.radians(truth.lat_deg.to_numpy()), np.radians(truth.lon_deg.to_numpy())
    rpy = np.radians(truth[["roll_deg", "pitch_deg", "yaw_deg"]].to_numpy())
    v = truth[["vn_mps", "ve_mps", "vd_mps"]].to_numpy()
    h = truth.height_m.to_numpy()
    even, odd = slice(0, None, 2), slice(1, -1, 2)
    sol = _solution(t_s[even], lat[even], lon[even], h[even], v[even],
                    rotation.quat_from_euler(rpy[even]))
    p = sensor_poses(sol, t_s[odd])
    err = earth.llh_difference_ned_m(p.lat_rad, p.lon_rad, p.height_m, lat[odd], lon[odd],
                                     h[odd])
    # measured: 0.016 m, 0.0068 m/s, 0.028 deg max (roll-in of the turns), 0.0025 deg RMS
    assert np.abs(err).max() < 0.03  # m; chord of a 60 m/s, 3 deg/s turn over 0.2 s: 0.016
    assert np.abs(p.v_n_mps - v[odd]).max() < 0.015  # m/s
    ang = np.degrees(rotation.angle_between_rad(rotation.dcm_from_quat(p.q_ns),
                                                rotation.dcm_from_euler(rpy[odd])))
    assert ang.max() < 0.05 and np.sqrt(np.mean(ang**2)) < 0.005


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory):
    """A 700 s sample flight with triggers at 2 Hz, read back and navigated by algorithm A."""
    from pospp import pipeline

    sim = simulate("sample", imu_grade="paper_flight", gnss=GNSS, seed=5, imu_rate_hz=50.0,
                   duration_s=700.0)
    out = tmp_path_factory.mktemp("events")
    paths = write_simulation(sim, out, "ev", events_rate_hz=2.0)
    cfg = config_from_dict({"gnss": {"lever_arm_m": list(GNSS.lever_arm_b_m)},
                            "sensor": {"lever_arm_m": LEVER_B_M.tolist(),
                                       "boresight_rpy_deg": list(BORESIGHT_RPY_DEG)}})
    log = pipeline.ingest(paths["mcap"], cfg)
    nav = pipeline.navigate(log, cfg)
    return sim, paths, log, nav


def test_events_topic_round_trip(sim_run):
    sim, paths, log, _ = sim_run
    want = sim.trigger_stamps_ns(2.0)
    assert len(want) == 1400  # 700 s at 2 Hz, from 0.02 + 0.123 s on
    assert np.array_equal(log.events_ns, want)
    got = [m.ros_msg for m in read_ros2_messages(str(paths["mcap"]), topics=["/events"])]
    assert got[0].source == "trigger"
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in got]
    refs = [m.time_ref.sec * 10**9 + m.time_ref.nanosec for m in got]
    assert stamps == want.tolist() and refs == want.tolist()
    none = read_flight_log(paths["mcap"], events_topic="/camera/trigger")
    assert len(none.events_ns) == 0
    assert any(i.severity == "info" and "/camera/trigger" in i.message for i in none.issues)


def _truth_sensor(sim, events_ns):
    """The simulator's truth at the events, moved to the sensor through ECEF (exact)."""
    tt = sim.truth_time_ns.astype(np.int64)
    x = (events_ns - tt[0]) * 1e-9
    xs = (tt - tt[0]) * 1e-9
    tr = sim.truth
    lat, lon, h = (np.interp(x, xs, a) for a in (tr.lat_rad, tr.lon_rad, tr.height_m))
    rot = Slerp(xs, Rotation.from_quat(np.roll(tr.q_nb, -1, axis=1)))(x)
    c_nb = rot.as_matrix()
    r_e = earth.llh_to_ecef_m(lat, lon, h) + np.einsum(
        "kij,kj->ki", earth.dcm_en(lat, lon), c_nb @ LEVER_B_M)
    c_bs = Rotation.from_euler("ZYX", np.radians(BORESIGHT_RPY_DEG[::-1])).as_matrix()
    return earth.ecef_to_llh(r_e), c_nb @ c_bs


def test_sensor_pose_at_events_against_the_simulator_truth(sim_run):
    sim, _, log, nav = sim_run
    sol = nav.smoothed
    epoch = int(log.imu.time_ns[0])
    c_bs = rotation.dcm_from_euler(np.radians(BORESIGHT_RPY_DEG))
    p = sensor_poses(sol, (log.events_ns - epoch) * 1e-9, lever_b_m=LEVER_B_M, c_bs=c_bs)
    assert p.inside.all()
    (lat, lon, h), c_ns_true = _truth_sensor(sim, log.events_ns)
    skip = p.t_s > 120.0  # after the alignment and the first GNSS minutes
    err = earth.llh_difference_ned_m(p.lat_rad, p.lon_rad, p.height_m, lat, lon, h)[skip]
    z = err / p.pos_sigma_ned_m[skip]
    assert np.sqrt(np.mean(z**2)) < 1.5, np.sqrt(np.mean(z**2, axis=0))
    assert np.abs(err).max() < 0.1  # m (measured 0.023)
    phi = rotation.attitude_error_n_rad(rotation.dcm_from_quat(p.q_ns), c_ns_true)[skip]
    za = phi / p.att_sigma_ned_rad[skip]
    assert np.sqrt(np.mean(za**2)) < 1.5, np.sqrt(np.mean(za**2, axis=0))
    # without the boresight the sensor's yaw would be off by 90 deg: the test sees it
    wrong = rotation.angle_between_rad(rotation.dcm_from_quat(p.q_ns), c_ns_true @ c_bs.T)
    assert np.degrees(wrong).min() > 80.0


def test_pipeline_writes_events_and_biases_tables(sim_run, tmp_path):
    from pospp import outputs

    _, _, log, nav = sim_run
    cfg = config_from_dict({"sensor": {"lever_arm_m": LEVER_B_M.tolist()}})
    table = outputs.event_poses_table(log.events_ns, nav.smoothed, "smoothed",
                                      int(log.imu.time_ns[0]), cfg.sensor, print)
    assert len(table) == len(log.events_ns) and table.inside.all()
    assert np.array_equal(table.time_ns.to_numpy(), log.events_ns)
    epoch = int(log.imu.time_ns[0])
    b = outputs.bias_table({"forward": nav.forward_biases, "smoothed": nav.smoothed_biases},
                           epoch)
    assert set(b.solution) == {"forward", "smoothed"}
    last = b[b.solution == "smoothed"].iloc[-1]
    # the sample's injected gyro bias is [1, -1, 1] deg/h plus a 0.5 deg/h Gauss-Markov drift
    for ax, val in zip("xyz", (1.0, -1.0, 1.0), strict=True):
        assert abs(last[f"gyro_bias_{ax}_dph"] - val) < 3 * last[f"gyro_bias_{ax}_sigma_dph"] \
            + 1.0
    assert "gyro_sf_x_ppm" not in b  # scale factors not estimated: no columns (null on disk)


def test_run_writes_events_and_biases_and_exports_them(sim_run, tmp_path):
    """The whole pipeline on the simulated flight with triggers, then ``pospp export``."""
    import json

    from click.testing import CliRunner

    from pospp import pipeline
    from pospp.cli import main
    from pospp.io import exports, parquet_tables

    sim, paths, log, _ = sim_run
    cfg = config_from_dict({"gnss": {"lever_arm_m": list(GNSS.lever_arm_b_m)},
                            "sensor": {"lever_arm_m": LEVER_B_M.tolist(),
                                       "boresight_rpy_deg": list(BORESIGHT_RPY_DEG)},
                            "outputs": {"report": False, "diagnose": False}})
    run = pipeline.process_flight(paths["mcap"], cfg, tmp_path / "run").out_dir
    ev = parquet_tables.read_table(run / "events.parquet")
    assert len(ev) == 1400 and ev.inside.all()
    (lat, lon, h), _ = _truth_sensor(sim, ev.time_ns.to_numpy())
    late = ev.time_ns.to_numpy() > log.imu.time_ns[0] + 120 * 10**9
    err = earth.llh_difference_ned_m(np.radians(ev.lat_deg), np.radians(ev.lon_deg),
                                     ev.height_m, lat, lon, h)[late]
    assert np.abs(err).max() < 0.1
    b = parquet_tables.read_table(run / "biases.parquet")
    assert set(b.solution) == {"forward", "smoothed"} and b.gyro_sf_x_ppm.isna().all()
    res = CliRunner().invoke(main, ["export", str(run), "--format", "csv", "--events"])
    assert res.exit_code == 0, res.output
    csv_rows = pd.read_csv(run / "events.csv")
    week, sow = exports.gps_week_seconds(ev.time_ns.to_numpy())
    assert (csv_rows.gps_week == week).all()
    np.testing.assert_allclose(csv_rows.gps_sow_s, sow, atol=1e-9)
    res = CliRunner().invoke(main, ["export", str(run), "--format", "geojson", "--rate", "1"])
    assert res.exit_code == 0, res.output
    doc = json.loads((run / "trajectory.geojson").read_text())
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds.count("event") == 1400 and kinds[0] == "track"


def test_any_stamped_trigger_type_is_read(sim_run, tmp_path):
    """A trigger topic of another type (std_msgs/msg/Header itself), written by the mcap_ros2
    library beside IMU and GNSS copied from the simulated file: its stamps are the events."""
    from mcap_ros2.writer import Writer

    from pospp.io import ros_messages as rm

    _, paths, _, _ = sim_run
    src = list(read_ros2_messages(str(paths["mcap"]), topics=["/imu/data", "/gnss/fix"],
                                  end_time=int(3e9) + 1_717_200_000_000_000_000))
    stamps = [1_717_200_000_000_000_000 + k * 250_000_000 + 1234 for k in range(1, 11)]
    out = tmp_path / "header_trigger.mcap"
    with open(out, "wb") as f:
        w = Writer(f)
        schemas = {"/imu/data": w.register_msgdef(rm.IMU_TYPE, rm.IMU_MSGDEF),
                   "/gnss/fix": w.register_msgdef(rm.NAVSATFIX_TYPE, rm.NAVSATFIX_MSGDEF)}
        hdr = w.register_msgdef("std_msgs/msg/Header", "builtin_interfaces/Time stamp\n"
                                "string frame_id\n================================================"
                                "================================\nMSG: builtin_interfaces/Time"
                                "\nint32 sec\nuint32 nanosec\n")
        for m in src:
            w.write_message(m.channel.topic, schemas[m.channel.topic], m.ros_msg,
                            log_time=m.log_time_ns, publish_time=m.log_time_ns)
        for t in stamps:
            w.write_message("/events", hdr, {"stamp": {"sec": t // 10**9,
                                                       "nanosec": t % 10**9},
                                             "frame_id": "cam"}, log_time=t, publish_time=t)
        w.finish()
    log = read_flight_log(out, events_topic="/events", check_units=False)
    assert log.events_ns.tolist() == stamps
