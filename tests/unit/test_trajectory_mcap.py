"""trajectory.mcap for Foxglove: /tf, /pospp/odom, /pospp/legs and the metadata record, read
back with the ``mcap`` and ``mcap_ros2`` libraries (independent decoders), checked on a
trajectory whose ROS values are known in closed form (level flight due east: base_link's x
axis points east, the map's x axis)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap_ros2.reader import read_ros2_messages

from pospp import rotation
from pospp.io.trajectory_mcap import write_trajectory_mcap
from pospp.nav.smoother import pack_symmetric
from pospp.nav.solution import NavSolution

T0_NS = 1_717_200_000_000_000_000
N, RATE_HZ, SPEED_MPS = 600, 10.0, 50.0


def _solution() -> NavSolution:
    t = np.arange(N) / RATE_HZ
    lat0, lon0 = np.radians(47.0), np.radians(8.0)
    r_n = 6378137.0 / np.sqrt(1 - 0.00669437999014 * np.sin(lat0) ** 2)
    q = rotation.quat_from_euler(np.tile([0.0, 0.0, np.pi / 2], (N, 1)))  # heading east
    pos_cov = np.tile(np.diag([0.01, 0.04, 0.09]), (N, 1, 1))  # N, E, D variances
    vel_cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (N, 1, 1))
    att_cov = np.tile(np.diag([1e-8, 4e-8, 9e-8]), (N, 1, 1))
    return NavSolution(
        time_ns=T0_NS + np.round(t * 1e9).astype(np.int64), t_s=t,
        lat_rad=np.full(N, lat0), lon_rad=lon0 + SPEED_MPS * t / ((r_n + 500.0) * np.cos(lat0)),
        height_m=np.full(N, 500.0), v_n_mps=np.tile([0.0, SPEED_MPS, 0.0], (N, 1)), q_nb=q,
        pos_cov_packed_ned_m2=pack_symmetric(pos_cov),
        vel_cov_packed_ned_m2ps2=pack_symmetric(vel_cov),
        att_cov_packed_ned_rad2=pack_symmetric(att_cov))


@pytest.fixture(scope="module")
def mcap_file(tmp_path_factory):
    legs = pd.DataFrame({"leg_id": [0, 1], "start_ns": [T0_NS + 5 * 10**9, T0_NS + 30 * 10**9],
                         "end_ns": [T0_NS + 25 * 10**9, T0_NS + 55 * 10**9]})
    path = tmp_path_factory.mktemp("mcap") / "trajectory.mcap"
    write_trajectory_mcap(path, _solution(), T0_NS, rate_hz=2.0, legs=legs,
                          metadata={"input_sha256": "ab" * 32, "status": "ok"})
    return path


def _messages(path, topic):
    return [m for m in read_ros2_messages(str(path), topics=[topic])]


def test_tf_follows_the_body_map_to_base_link(mcap_file):
    msgs = _messages(mcap_file, "/tf")
    assert len(msgs) == N // 5  # 10 Hz thinned to 2 Hz
    assert msgs[0].schema.name == "tf2_msgs/msg/TFMessage"
    tf = msgs[10].ros_msg.transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("map", "base_link")
    assert tf.header.stamp.sec * 10**9 + tf.header.stamp.nanosec == T0_NS + 5 * 10**9
    # 5 s east at 50 m/s from the map origin (ENU, a tangent plane: below 1 mm off at 250 m)
    tr = tf.transform.translation
    assert (tr.x, tr.y, tr.z) == pytest.approx((250.0, 0.0, 0.0), abs=0.01)
    r = tf.transform.rotation  # FLU heading east == ENU axes: identity
    assert abs(r.w) == pytest.approx(1.0, abs=1e-12)


def test_odometry_carries_pose_twist_and_covariances(mcap_file):
    msgs = _messages(mcap_file, "/pospp/odom")
    assert len(msgs) == N // 5 and msgs[0].schema.name == "nav_msgs/msg/Odometry"
    od = msgs[3].ros_msg
    assert (od.header.frame_id, od.child_frame_id) == ("map", "base_link")
    v = od.twist.twist.linear  # forward in FLU
    assert (v.x, v.y, v.z) == pytest.approx((SPEED_MPS, 0.0, 0.0), abs=1e-9)
    pc = np.reshape(od.pose.covariance, (6, 6))
    np.testing.assert_allclose(np.diag(pc), [0.04, 0.01, 0.09, 4e-8, 1e-8, 9e-8])  # E, N, U
    tc = np.reshape(od.twist.covariance, (6, 6))
    # body FLU heading east: x = east, y = north, z = up
    np.testing.assert_allclose(np.diag(tc)[:3], [4e-4, 1e-4, 9e-4], rtol=1e-12)
    assert np.allclose(pc, pc.T) and np.allclose(tc, tc.T)


def test_leg_paths_and_metadata(mcap_file):
    msgs = _messages(mcap_file, "/pospp/legs")
    assert [m.schema.name for m in msgs] == ["nav_msgs/msg/Path"] * 2
    poses = msgs[0].ros_msg.poses
    assert len(poses) == 21  # 5 s .. 25 s at 1 Hz
    assert poses[0].pose.position.x == pytest.approx(250.0, abs=0.01)
    assert poses[-1].pose.position.x == pytest.approx(1250.0, abs=0.05)
    with open(mcap_file, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["pospp"]["input_sha256"] == "ab" * 32 and meta["pospp"]["status"] == "ok"
    assert meta["pospp"]["pospp_version"]
    topics = {m.channel.topic for m in read_ros2_messages(str(mcap_file))}
    assert topics == {"/pospp/fix", "/pospp/pose", "/tf", "/pospp/odom", "/pospp/legs"}


def test_messages_written_before_the_metadata_is_known(tmp_path):
    # a run writes the messages while it works out its status (trajectory_messages), then the
    # metadata record and the file (finish): the file is the one-call writer's, byte for byte
    from pospp.io.trajectory_mcap import trajectory_messages

    sol, meta = _solution(), {"status": "failed", "solution": "smoothed"}
    pending = trajectory_messages(sol, T0_NS, rate_hz=2.0)
    assert not any(tmp_path.iterdir())  # nothing on disk until finished
    later = pending.finish(tmp_path / "later.mcap", meta)
    once = write_trajectory_mcap(tmp_path / "once.mcap", sol, T0_NS, rate_hz=2.0, metadata=meta)
    assert later.read_bytes() == once.read_bytes()
    with open(later, "rb") as f:
        assert {m.name: m.metadata for m in make_reader(f).iter_metadata()}["pospp"][
            "status"] == "failed"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["later.mcap", "once.mcap"]
    with pytest.raises(RuntimeError, match="already finished"):
        pending.finish(tmp_path / "again.mcap", meta)
