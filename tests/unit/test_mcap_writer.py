"""write_flight_log -> read_flight_log round trips, and what pospp writes read by ROS 2 tools.

The independent side is ``mcap_ros2``'s generic CDR decoder (``mcap_ros2.decoder``), which knows
nothing of pospp's structured-dtype layouts, and REP-103 / ENU conventions written out by hand
here (FLU = [x, -y, -z] of FRD; ENU = [v_E, v_N, -v_D] of NED).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pospp.io.mcap_reader import read_flight_log
from pospp.io.mcap_writer import write_flight_log
from pospp.types import (
    ENU_TO_NED,
    FLU_TO_FRD,
    GnssFixes,
    GnssVelocities,
    ImuSamples,
    apply_rotation,
)

sys.path.insert(0, str(Path(__file__).parent))
from test_mcap_reader import make_log  # noqa: E402


@pytest.fixture(scope="module")
def parts() -> tuple[ImuSamples, GnssFixes, GnssVelocities]:
    imu, fix, vel = make_log(duration_s=30.0, seed=11)
    rng = np.random.default_rng(3)
    # full, correlated covariances so that the ENU <-> NED mapping of every entry is exercised
    a = rng.normal(size=(len(fix), 3, 3))
    fix = GnssFixes(fix.time_ns, fix.lat_rad, fix.lon_rad, fix.height_m,
                    a @ np.swapaxes(a, 1, 2), fix.status)
    b = rng.normal(scale=0.01, size=(len(vel), 3, 3))
    vel = GnssVelocities(vel.time_ns, vel.v_n_mps + rng.normal(size=vel.v_n_mps.shape),
                         b @ np.swapaxes(b, 1, 2))
    # signed zeros must survive the FRD <-> FLU permutation
    w = imu.w_ib_b_radps.copy()
    w[0] = [-0.0, 0.0, -0.0]
    return ImuSamples(imu.time_ns, w, imu.f_ib_b_mps2, "imu_link"), fix, vel


@pytest.fixture(scope="module")
def written(tmp_path_factory, parts) -> Path:
    path = tmp_path_factory.mktemp("rt") / "rt.mcap"
    return write_flight_log(path, *parts, metadata={"made_by": "test_mcap_writer", "seed": 11})


def _same_bits(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()


def test_round_trip_is_bit_identical(written: Path, parts) -> None:
    imu, fix, vel = parts
    log = read_flight_log(written)
    assert log.complete and log.issues == ()
    _same_bits(log.imu.time_ns, imu.time_ns)
    _same_bits(log.imu.w_ib_b_radps, imu.w_ib_b_radps)  # -0.0 included
    _same_bits(log.imu.f_ib_b_mps2, imu.f_ib_b_mps2)
    _same_bits(log.fix.time_ns, fix.time_ns)
    _same_bits(log.fix.height_m, fix.height_m)
    _same_bits(log.fix.pos_cov_ned_m2, fix.pos_cov_ned_m2)
    _same_bits(log.fix.status, fix.status)
    _same_bits(log.vel.time_ns, vel.time_ns)
    _same_bits(log.vel.v_n_mps, vel.v_n_mps)
    _same_bits(log.vel.vel_cov_ned_m2ps2, vel.vel_cov_ned_m2ps2)
    # degrees on the wire: rad -> deg -> rad is exact to within one rounding of each step
    np.testing.assert_allclose(log.fix.lat_rad, fix.lat_rad, rtol=4e-16, atol=0)
    np.testing.assert_allclose(log.fix.lon_rad, fix.lon_rad, rtol=4e-16, atol=0)


def _decoded(path: Path, topic: str) -> list:
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        return [m.decoded_message for m in reader.iter_decoded_messages(topics=[topic])]


def test_ros2_generic_decoder_reads_what_pospp_wrote(written: Path, parts) -> None:
    imu, fix, vel = parts
    msgs = _decoded(written, "/imu/data")
    assert len(msgs) == len(imu)
    for i in (0, 1, 1500, len(imu) - 1):
        m = msgs[i]
        assert m.header.frame_id == "imu_link"
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == imu.time_ns[i]
        w, f = imu.w_ib_b_radps[i], imu.f_ib_b_mps2[i]
        # REP-103 FLU from FRD by hand: x forward, y left = -right, z up = -down
        got_w = [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
        got_f = [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
        assert got_w == [w[0], -w[1], -w[2]]
        assert got_f == [f[0], -f[1], -f[2]]
        assert (m.orientation.w, m.orientation_covariance[0]) == (1.0, -1.0)  # "no orientation"
    fixes = _decoded(written, "/gnss/fix")
    assert len(fixes) == len(fix)
    for i in (0, len(fix) - 1):
        m = fixes[i]
        assert m.latitude == np.rad2deg(fix.lat_rad[i])
        assert m.longitude == np.rad2deg(fix.lon_rad[i])
        assert m.altitude == fix.height_m[i]
        p = fix.pos_cov_ned_m2[i]
        enu = np.array(m.position_covariance).reshape(3, 3)
        # ENU index (0 E, 1 N, 2 U) from NED index (1, 0, 2) with the sign of U = -D
        s = np.array([1.0, 1.0, -1.0])
        ned_of = [1, 0, 2]
        for r in range(3):
            for c in range(3):
                assert enu[r, c] == s[r] * s[c] * p[ned_of[r], ned_of[c]]
        assert m.position_covariance_type == 3
    vels = _decoded(written, "/gnss/vel")
    for i in (0, len(vel) - 1):
        lin = vels[i].twist.twist.linear
        v = vel.v_n_mps[i]
        assert [lin.x, lin.y, lin.z] == [v[1], v[0], -v[2]]


def test_metadata_record(written: Path) -> None:
    with open(written, "rb") as fh:
        meta = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
    assert meta["pospp"] == {"made_by": "test_mcap_writer", "seed": "11"}


def test_messages_are_in_log_time_order(written: Path) -> None:
    with open(written, "rb") as fh:
        times = [msg.log_time for _, _, msg in make_reader(fh).iter_messages(
            log_time_order=False)]
    assert times == sorted(times)


def test_failed_write_leaves_nothing(tmp_path: Path, parts) -> None:
    imu, fix, vel = parts
    bad = ImuSamples(imu.time_ns + 2**62, imu.w_ib_b_radps, imu.f_ib_b_mps2)  # > int32 sec
    target = tmp_path / "out.mcap"
    target.write_bytes(b"previous")
    with pytest.raises(ValueError, match="int32"):
        write_flight_log(target, bad, fix, vel)
    assert target.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap"]


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.float64, (5, 3), elements=finite))
def test_permutation_rotations_are_exact_and_invertible(v: np.ndarray) -> None:
    for c in (FLU_TO_FRD, ENU_TO_NED):
        there = apply_rotation(c, v)
        _same_bits(apply_rotation(c.T, there), v)
        np.testing.assert_array_equal(there, v @ c.T)  # same values as the matrix product


def test_general_mounting_rotation_matches_matrix_product() -> None:
    rng = np.random.default_rng(5)
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    c = q * np.sign(np.diag(r))
    if np.linalg.det(c) < 0:
        c[:, 0] *= -1
    v = rng.normal(size=(10, 3))
    np.testing.assert_allclose(apply_rotation(c, v), np.einsum("ij,nj->ni", c, v), atol=1e-15)


@pytest.mark.parametrize("k", range(0, 9))
def test_every_frame_id_alignment_decodes_on_the_fast_path(tmp_path: Path, k: int) -> None:
    """The CDR padding after header.frame_id depends on its length mod 8: for each residue the
    batched numpy layout agrees with mcap_ros2's decoder (no fallback needed) and with the
    data written."""
    imu, fix, vel = make_log(duration_s=12.0, seed=k)
    path = write_flight_log(tmp_path / "f.mcap", imu, fix, vel, imu_frame_id="i" * k,
                            gnss_frame_id="g" * (8 - k))
    log = read_flight_log(path)
    assert not any("generic decoder" in i.message for i in log.issues)
    assert log.imu.frame_id == "i" * k
    _same_bits(log.imu.f_ib_b_mps2, imu.f_ib_b_mps2)
    _same_bits(log.vel.vel_cov_ned_m2ps2, vel.vel_cov_ned_m2ps2)
    m = _decoded(path, "/gnss/fix")[3]
    assert (m.header.frame_id, m.altitude) == ("g" * (8 - k), fix.height_m[3])


def test_big_endian_messages_go_through_the_generic_decoder(tmp_path: Path) -> None:
    """CDR_BE payloads (encapsulation 00 00) are valid ROS 2 messages pospp never writes; the
    reader decodes them with mcap_ros2 and says how many it did so."""
    from mcap.writer import Writer

    from pospp.io import ros_messages as rm

    imu, fix, _ = make_log(duration_s=12.0)
    path = tmp_path / "be.mcap"
    flu = FLU_TO_FRD.T
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        for topic, typ, msgdef, fields, t, vals, big in (
            ("/imu/data", rm.IMU_TYPE, rm.IMU_MSGDEF, rm.IMU_FIELDS, imu.time_ns,
             {"angular_velocity": imu.w_ib_b_radps @ flu.T,
              "linear_acceleration": imu.f_ib_b_mps2 @ flu.T}, True),
            ("/gnss/fix", rm.NAVSATFIX_TYPE, rm.NAVSATFIX_MSGDEF, rm.NAVSATFIX_FIELDS,
             fix.time_ns, {"latitude": np.rad2deg(fix.lat_rad),
                           "longitude": np.rad2deg(fix.lon_rad), "altitude": fix.height_m},
             False),
        ):
            sid = w.register_schema(name=typ, encoding="ros2msg", data=msgdef.encode())
            cid = w.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)
            le = rm.encode_batch(fields, t, "imu", vals)
            if big:  # same layout, every primitive byte-swapped, big-endian encapsulation
                be = le.astype(le.dtype.newbyteorder(">"))
                be["encap"] = [0, 0, 0, 0]
                le = be
            for i, ti in enumerate(t.tolist()):
                w.add_message(cid, log_time=ti, publish_time=ti, data=le[i].tobytes())
        w.finish()
    log = read_flight_log(path)
    [info] = [i for i in log.issues if i.severity == "info"]
    assert info.topic == "/imu/data" and info.message.startswith(f"{len(imu)} message(s)")
    _same_bits(log.imu.time_ns, imu.time_ns)
    _same_bits(log.imu.w_ib_b_radps, imu.w_ib_b_radps)
    _same_bits(log.imu.f_ib_b_mps2, imu.f_ib_b_mps2)
