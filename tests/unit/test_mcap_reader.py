"""Checks made while reading MCAP flight logs, on small synthetic files (docs/formats.md).

Every file is written in ``tmp_path`` by :func:`pospp.io.mcap_writer.write_flight_log` (or by
``mcap``'s own Writer for what pospp's writer cannot produce), then broken in one way; the test
asserts the reader's verdict and that it names the file, topic, message index and stamps.
"""

from __future__ import annotations

import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from pospp.io import ros_messages as rm
from pospp.io.errors import IngestError
from pospp.io.mcap_reader import read_flight_log
from pospp.io.mcap_writer import write_flight_log
from pospp.types import FLU_TO_FRD, GnssFixes, GnssVelocities, ImuSamples

T0_NS = 1_717_200_000_000_000_000
G_MPS2 = 9.80665


def make_log(
    *, duration_s: float = 60.0, rate_hz: float = 100.0, seed: int = 7
) -> tuple[ImuSamples, GnssFixes, GnssVelocities]:
    """A level drive at 10 m/s, heading 30 deg, with a 3 deg/s turn from 20 s to 40 s.

    Body rates/forces are the kinematic ones of that motion (yaw rate, centripetal force) plus
    small noise; GNSS at 1 Hz. Precise enough for the reader's plausibility checks, not for
    navigation.
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    t_s = np.arange(1, n + 1) / rate_hz
    time_ns = T0_NS + np.round(t_s * 1e9).astype(np.int64)
    speed, r = 10.0, np.deg2rad(3.0)
    yaw_rate = np.where((t_s > 20.0) & (t_s <= 40.0), r, 0.0)
    w = np.column_stack([np.zeros(n), np.zeros(n), yaw_rate]) + rng.normal(0, 1e-4, (n, 3))
    f = np.column_stack([np.zeros(n), speed * yaw_rate, np.full(n, -G_MPS2)])
    f += rng.normal(0, 1e-2, (n, 3))
    imu = ImuSamples(time_ns, w, f, "imu_link")
    tg_s = np.arange(1, int(duration_s) + 1, dtype=float)
    psi = np.deg2rad(30.0) + r * np.clip(tg_s - 20.0, 0.0, 20.0)
    m = tg_s.size
    v_n = np.column_stack([speed * np.cos(psi), speed * np.sin(psi), np.zeros(m)])
    tg_ns = T0_NS + np.round(tg_s * 1e9).astype(np.int64)
    lat = np.deg2rad(40.0) + np.cumsum(v_n[:, 0]) / 6.37e6
    lon = np.deg2rad(116.0) + np.cumsum(v_n[:, 1]) / (6.37e6 * np.cos(np.deg2rad(40.0)))
    pos_cov = np.tile(np.diag([0.04, 0.09, 0.25]), (m, 1, 1))
    pos_cov[:, 0, 1] = pos_cov[:, 1, 0] = 0.01
    fix = GnssFixes(tg_ns, lat, lon, np.full(m, 120.0), pos_cov, np.zeros(m, np.int8))
    vel = GnssVelocities(tg_ns, v_n, np.tile(np.diag([4e-4, 4e-4, 9e-4]), (m, 1, 1)))
    return imu, fix, vel


def _imu_with(imu: ImuSamples, **changes: np.ndarray) -> ImuSamples:
    return replace(imu, **changes)


@pytest.fixture(scope="module")
def log_parts() -> tuple[ImuSamples, GnssFixes, GnssVelocities]:
    return make_log()


@pytest.fixture()
def good_file(tmp_path: Path, log_parts) -> Path:
    return write_flight_log(tmp_path / "good.mcap", *log_parts)


# --------------------------------------------------------------------------- the happy path


def test_clean_file_reads_without_issues(good_file: Path, log_parts) -> None:
    imu, fix, vel = log_parts
    log = read_flight_log(good_file)
    assert log.complete
    assert log.issues == ()
    assert len(log.imu) == len(imu) and len(log.fix) == len(fix) and len(log.vel) == len(vel)
    assert log.imu.frame_id == "imu_link"
    np.testing.assert_array_equal(log.imu.time_ns, imu.time_ns)


def test_time_window_keeps_stamps_in_half_open_interval(good_file: Path, log_parts) -> None:
    imu, fix, _ = log_parts
    start, end = int(imu.time_ns[1500]), int(imu.time_ns[3000])
    log = read_flight_log(good_file, start_ns=start, end_ns=end)
    np.testing.assert_array_equal(log.imu.time_ns, imu.time_ns[1500:3000])
    np.testing.assert_array_equal(log.imu.f_ib_b_mps2, imu.f_ib_b_mps2[1500:3000])
    expected_fix = fix.time_ns[(fix.time_ns >= start) & (fix.time_ns < end)]
    np.testing.assert_array_equal(log.fix.time_ns, expected_fix)


def test_window_in_seconds_after_the_first_imu_stamp(good_file: Path, log_parts) -> None:
    """``window_s`` (config ``[input] start_s, end_s``) counts from the first IMU stamp and
    intersects an absolute window; fewer than two IMU samples left is an error."""
    imu, fix, _ = log_parts
    t0 = int(imu.time_ns[0])
    t_s = (imu.time_ns - t0) * 1e-9
    lo_s, hi_s = float(t_s[1000]), float(t_s[2000])
    log = read_flight_log(good_file, window_s=(lo_s, hi_s))
    keep = (imu.time_ns >= t0 + round(lo_s * 1e9)) & (imu.time_ns < t0 + round(hi_s * 1e9))
    np.testing.assert_array_equal(log.imu.time_ns, imu.time_ns[keep])
    assert len(log.imu) == 1000
    fix_t = fix.time_ns
    in_window = (fix_t >= t0 + round(lo_s * 1e9)) & (fix_t < t0 + round(hi_s * 1e9))
    np.testing.assert_array_equal(log.fix.time_ns, fix_t[in_window])
    both = read_flight_log(good_file, start_ns=int(imu.time_ns[1500]), window_s=(lo_s, None))
    assert both.imu.time_ns[0] == imu.time_ns[1500]
    with pytest.raises(IngestError, match="IMU sample in the time window"):
        read_flight_log(good_file, window_s=(lo_s, lo_s + 1e-9))


def test_topic_names_and_mounting_from_config(tmp_path: Path, log_parts) -> None:
    """Custom topics and a non-permutation mounting (sensor yawed 30 deg, then FLU)."""
    imu, fix, vel = log_parts
    a = np.deg2rad(30.0)
    rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    c_bs = rz @ FLU_TO_FRD
    path = write_flight_log(tmp_path / "custom.mcap", imu, fix, vel, imu_topic="/pos/imu",
                            fix_topic="/pos/fix", vel_topic="/pos/vel", c_bs=c_bs)
    with pytest.raises(IngestError, match="not found"):
        read_flight_log(path)
    log = read_flight_log(path, imu_topic="/pos/imu", fix_topic="/pos/fix",
                          vel_topic="/pos/vel", c_bs=c_bs)
    np.testing.assert_allclose(log.imu.w_ib_b_radps, imu.w_ib_b_radps, rtol=0, atol=1e-15)
    np.testing.assert_allclose(log.imu.f_ib_b_mps2, imu.f_ib_b_mps2, rtol=0, atol=1e-14)
    # what is in the file is the sensor-frame vector C_sb @ v_b (independent check)
    with open(path, "rb") as fh:
        _, _, msg = next(make_reader(fh).iter_messages(topics=["/pos/imu"]))
    raw = np.frombuffer(msg.data, dtype=rm.cdr_dtype(rm.IMU_FIELDS, len("imu_link") + 1))[0]
    np.testing.assert_allclose(raw["linear_acceleration"], c_bs.T @ imu.f_ib_b_mps2[0],
                               atol=1e-14)


def test_bad_mounting_matrix_is_rejected(good_file: Path) -> None:
    with pytest.raises(ValueError, match="must be a rotation"):
        read_flight_log(good_file, c_bs=np.diag([1.0, 1.0, -1.0]))


def test_not_an_mcap_file(tmp_path: Path) -> None:
    p = tmp_path / "x.mcap"
    p.write_bytes(b"PAR1" + bytes(100))
    with pytest.raises(IngestError, match="not an MCAP file") as ei:
        read_flight_log(p)
    assert ei.value.file == str(p)
    with pytest.raises(FileNotFoundError):
        read_flight_log(tmp_path / "missing.mcap")


# --------------------------------------------------------------------------- contract errors


def test_missing_required_topic_lists_available(tmp_path: Path, log_parts) -> None:
    path = write_flight_log(tmp_path / "m.mcap", *log_parts, fix_topic="/gps/fix")
    with pytest.raises(IngestError) as ei:
        read_flight_log(path)
    err = ei.value
    assert err.topic == "/gnss/fix" and err.file == str(path)
    assert "/gps/fix (sensor_msgs/msg/NavSatFix)" in str(err)
    assert "/imu/data (sensor_msgs/msg/Imu)" in str(err)


def test_missing_optional_velocity_topic_is_a_warning(tmp_path: Path, log_parts) -> None:
    imu, fix, _ = log_parts
    log = read_flight_log(write_flight_log(tmp_path / "nv.mcap", imu, fix, None))
    assert len(log.vel) == 0
    [issue] = log.issues
    assert issue.severity == "warning" and issue.topic == "/gnss/vel"
    assert "not found" in issue.message


def test_wrong_message_type(tmp_path: Path, log_parts) -> None:
    """Topics swapped by the logger: IMU messages on /gnss/fix, fixes on /imu/data."""
    path = write_flight_log(tmp_path / "w.mcap", *log_parts, imu_topic="/gnss/fix",
                            fix_topic="/imu/data")
    with pytest.raises(IngestError, match="schema 'sensor_msgs/msg/Imu', expected "
                       "'sensor_msgs/msg/NavSatFix'") as ei:
        read_flight_log(path)
    assert ei.value.topic == "/gnss/fix"


def test_wrong_message_encoding(tmp_path: Path, log_parts) -> None:
    imu, _, _ = log_parts
    path = tmp_path / "json.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        sid = w.register_schema(name=rm.IMU_TYPE, encoding="ros2msg",
                                data=rm.IMU_MSGDEF.encode())
        cid = w.register_channel(topic="/imu/data", message_encoding="json", schema_id=sid)
        w.add_message(cid, log_time=int(imu.time_ns[0]), publish_time=int(imu.time_ns[0]),
                      data=b"{}")
        w.finish()
    with pytest.raises(IngestError, match="expected 'cdr'"):
        read_flight_log(path)


@pytest.mark.parametrize("kind", ["backwards", "duplicate"])
def test_imu_stamps_must_increase(tmp_path: Path, log_parts, kind: str) -> None:
    imu, fix, vel = log_parts
    t = imu.time_ns.copy()
    if kind == "backwards":
        t[2000], t[2001] = t[2001], t[2000]
        bad = 2001
    else:
        t[2000] = t[1999]
        bad = 2000
    path = write_flight_log(tmp_path / "t.mcap", _imu_with(imu, time_ns=t), fix, vel)
    with pytest.raises(IngestError) as ei:
        read_flight_log(path)
    err = ei.value
    assert (err.topic, err.index, err.time_ns) == ("/imu/data", bad, int(t[bad]))
    assert err.log_time_ns == int(t[bad])  # the writer logs at the stamp
    assert ("duplicates" if kind == "duplicate" else "goes back") in err.reason


def test_gnss_duplicate_dropped_backwards_rejected(tmp_path: Path, log_parts) -> None:
    imu, fix, vel = log_parts
    t = fix.time_ns.copy()
    t[10] = t[9]
    log = read_flight_log(write_flight_log(tmp_path / "d.mcap", imu, replace(fix, time_ns=t),
                                           vel))
    assert len(log.fix) == len(fix) - 1
    [issue] = [i for i in log.issues if i.topic == "/gnss/fix"]
    assert issue.severity == "warning" and issue.index == 10 and issue.time_ns == int(t[10])
    t = fix.time_ns.copy()
    t[10], t[11] = t[11], t[10]
    with pytest.raises(IngestError, match="goes back") as ei:
        read_flight_log(write_flight_log(tmp_path / "b.mcap", imu, replace(fix, time_ns=t),
                                         vel))
    assert (ei.value.topic, ei.value.index) == ("/gnss/fix", 11)


@pytest.mark.parametrize(("field", "value"), [("f_ib_b_mps2", np.nan),
                                              ("w_ib_b_radps", np.inf)])
def test_non_finite_imu_values(tmp_path: Path, log_parts, field: str, value: float) -> None:
    imu, fix, vel = log_parts
    arr = getattr(imu, field).copy()
    arr[1234, 1] = value
    arr[4000, 0] = value
    path = write_flight_log(tmp_path / "n.mcap", _imu_with(imu, **{field: arr}), fix, vel)
    with pytest.raises(IngestError, match="non-finite") as ei:
        read_flight_log(path)
    err = ei.value
    assert (err.topic, err.index, err.time_ns) == ("/imu/data", 1234, int(imu.time_ns[1234]))
    ros_name = "linear_acceleration" if field == "f_ib_b_mps2" else "angular_velocity"
    assert ros_name in err.reason and "2 bad message(s)" in err.reason


def test_non_finite_gnss_position(tmp_path: Path, log_parts) -> None:
    imu, fix, vel = log_parts
    h = fix.height_m.copy()
    h[5] = np.nan
    with pytest.raises(IngestError, match="altitude") as ei:
        read_flight_log(write_flight_log(tmp_path / "g.mcap", imu, replace(fix, height_m=h),
                                         vel))
    assert (ei.value.topic, ei.value.index) == ("/gnss/fix", 5)


def test_no_fix_status_dropped(tmp_path: Path, log_parts) -> None:
    imu, fix, vel = log_parts
    st = fix.status.copy()
    st[[3, 4]] = -1
    log = read_flight_log(write_flight_log(tmp_path / "s.mcap", imu, replace(fix, status=st),
                                           vel))
    assert len(log.fix) == len(fix) - 2
    [issue] = [i for i in log.issues if "NO_FIX" in i.message]
    assert issue.index == 3 and issue.severity == "warning"


# --------------------------------------------------------------------------- timing warnings


def test_imu_gap_is_reported_where_it_is(tmp_path: Path, log_parts) -> None:
    imu, fix, vel = log_parts
    keep = np.r_[0:1000, 1100:len(imu)]
    gapped = ImuSamples(imu.time_ns[keep], imu.w_ib_b_radps[keep], imu.f_ib_b_mps2[keep])
    log = read_flight_log(write_flight_log(tmp_path / "gap.mcap", gapped, fix, vel))
    [gap] = [i for i in log.issues if "gap" in i.message]
    assert gap.severity == "warning" and gap.topic == "/imu/data"
    assert gap.index == 1000 and gap.time_ns == int(imu.time_ns[1100])
    assert "1.010000 s" in gap.message and "101.0 nominal intervals" in gap.message


def test_imu_rate_change_is_reported(tmp_path: Path, log_parts) -> None:
    """100 Hz for 4000 samples, then 50 Hz: a rate change, not a gap."""
    imu, fix, vel = log_parts
    t = imu.time_ns.copy()
    t[4000:] = t[3999] + 20_000_000 * np.arange(1, len(t) - 3999)
    path = write_flight_log(tmp_path / "r.mcap", _imu_with(imu, time_ns=t), fix, vel)
    log = read_flight_log(path)
    msgs = [i for i in log.issues if i.topic == "/imu/data"]
    assert not any("gap" in i.message for i in msgs)
    [change] = [i for i in msgs if "changes" in i.message]
    assert "20.000 ms" in change.message and "10.000 ms" in change.message
    assert change.index == 4000 and change.time_ns == int(t[4000])


# --------------------------------------------------------------------------- units


def test_specific_force_in_g_is_rejected(tmp_path: Path, log_parts) -> None:
    imu, fix, vel = log_parts
    path = write_flight_log(tmp_path / "g.mcap",
                            _imu_with(imu, f_ib_b_mps2=imu.f_ib_b_mps2 / G_MPS2), fix, vel)
    with pytest.raises(IngestError, match="looks like g"):
        read_flight_log(path)
    assert len(read_flight_log(path, check_units=False).imu) == len(imu)


def test_rates_in_deg_per_s_are_rejected_via_gnss_course(tmp_path: Path, log_parts) -> None:
    """A 3 deg/s turn logged in deg/s: magnitudes alone look fine, the course rate does not."""
    imu, fix, vel = log_parts
    path = write_flight_log(
        tmp_path / "d.mcap", _imu_with(imu, w_ib_b_radps=np.rad2deg(imu.w_ib_b_radps)), fix, vel
    )
    with pytest.raises(IngestError, match="deg/s") as ei:
        read_flight_log(path)
    assert "57." in ei.value.reason and ei.value.topic == "/imu/data"
    assert read_flight_log(path, check_units=False).complete


def test_large_rates_in_deg_per_s_rejected_without_gnss_velocity(
    tmp_path: Path, log_parts
) -> None:
    imu, fix, _ = log_parts
    w = imu.w_ib_b_radps.copy()
    w[3000:3100, 0] = 1.5  # a 86 deg/s roll burst: 1.5 rad/s is fine...
    path = write_flight_log(tmp_path / "a.mcap", _imu_with(imu, w_ib_b_radps=w), fix, None)
    assert len(read_flight_log(path).imu) == len(imu)
    path = write_flight_log(tmp_path / "b.mcap", _imu_with(imu, w_ib_b_radps=np.rad2deg(w)),
                            fix, None)
    with pytest.raises(IngestError, match="looks like deg/s") as ei:  # ...85.9 is not
        read_flight_log(path)
    assert 3000 <= ei.value.index < 3100


# --------------------------------------------------------------------------- broken files


def _chunk_offsets(path: Path) -> list[tuple[int, int, int]]:
    """(chunk record offset, its length, first log time) from the file's summary, read by the
    mcap library (independent of pospp's framing)."""
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    return sorted((c.chunk_start_offset, c.chunk_length, c.message_start_time)
                  for c in summary.chunk_indexes)


@pytest.mark.parametrize("keep_fraction", [0.35, 0.8])
def test_truncated_file_yields_prefix_and_says_where(
    tmp_path: Path, good_file: Path, log_parts, keep_fraction: float
) -> None:
    imu = log_parts[0]
    data = good_file.read_bytes()
    chunks = _chunk_offsets(good_file)
    data_end = chunks[-1][0] + chunks[-1][1]
    cut = int(data_end * keep_fraction)
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[:cut])
    log = read_flight_log(p, check_units=False)
    assert not log.complete
    [err] = [i for i in log.issues if i.severity == "error"]
    assert err.byte_offset is not None and err.byte_offset <= cut
    assert f"of {cut}" in err.message
    n = len(log.imu)
    assert 0 < n < len(imu)
    np.testing.assert_array_equal(log.imu.time_ns, imu.time_ns[:n])
    np.testing.assert_array_equal(log.imu.w_ib_b_radps, imu.w_ib_b_radps[:n])
    # the break is located at the chunk that holds the cut, and the readable (decompressible)
    # part of that chunk is kept: the data go beyond the last chunk that ended before the cut
    cut_chunk = [c for c in chunks if c[0] <= cut < c[0] + c[1]][0]
    assert err.byte_offset == cut_chunk[0]
    assert log.imu.time_ns[-1] >= cut_chunk[2]
    assert err.log_time_ns == log.imu.time_ns[-1]


def test_cut_in_summary_section_keeps_all_data(tmp_path: Path, good_file: Path,
                                               log_parts) -> None:
    data = good_file.read_bytes()
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[:-40])  # inside the summary offsets / footer
    log = read_flight_log(p)
    assert log.complete
    assert len(log.imu) == len(log_parts[0])
    [w] = log.issues
    assert w.severity == "warning" and "summary section" in w.message


def test_corrupt_chunk_is_skipped_and_located(tmp_path: Path, good_file: Path,
                                              log_parts) -> None:
    imu = log_parts[0]
    chunks = _chunk_offsets(good_file)
    assert len(chunks) >= 3
    off, length, start_ns = chunks[len(chunks) // 2]
    data = bytearray(good_file.read_bytes())
    mid = off + length // 2
    data[mid : mid + 16] = bytes(b ^ 0xFF for b in data[mid : mid + 16])
    p = tmp_path / "flip.mcap"
    p.write_bytes(bytes(data))
    log = read_flight_log(p, check_units=False)
    assert not log.complete
    err, count = [i for i in log.issues if i.severity == "error"]
    assert err.byte_offset == off and err.log_time_ns == start_ns
    assert "corrupt chunk" in err.message
    assert 0 < len(log.imu) < len(imu)
    # the summary's Statistics then also say how many messages are missing
    assert f"{len(imu)} messages on /imu/data, read {len(log.imu)}" in count.message
    assert log.imu.time_ns[-1] == imu.time_ns[-1]  # reading went on after the bad chunk
    assert np.all(np.isin(log.imu.time_ns, imu.time_ns))
    assert any("gap" in i.message for i in log.issues)  # the hole shows as an IMU gap


def top_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, body length) of the top-level records up to the Footer, framed by hand
    from the MCAP specification (opcode u8, length u64 little-endian, body)."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        op, ln = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, ln))
        if op == 0x02:
            break
        pos += 9 + ln
    return out


def _library_statistics(path: Path):
    with open(path, "rb") as fh:
        return make_reader(fh).get_summary().statistics


def _last_log_time_before(parts, t_ns: int) -> int:
    """Latest message time before ``t_ns`` over all topics (pospp writes log time = stamp)."""
    return max(int(p.time_ns[p.time_ns < t_ns].max()) for p in parts)


def test_footer_opcode_inside_the_data_is_corruption(tmp_path: Path, good_file: Path,
                                                     log_parts) -> None:
    """A Footer opcode where a chunk was: reading used to stop there silently, complete."""
    imu = log_parts[0]
    off, _, start_ns = _chunk_offsets(good_file)[len(_chunk_offsets(good_file)) // 2]
    data = bytearray(good_file.read_bytes())
    data[off] = 0x02
    p = tmp_path / "footer.mcap"
    p.write_bytes(bytes(data))
    log = read_flight_log(p, check_units=False)
    assert not log.complete
    footer, counts = [i for i in log.issues if i.severity == "error"]
    assert "Footer record" in footer.message and footer.file == str(p)
    assert footer.byte_offset == off
    assert footer.log_time_ns == _last_log_time_before(log_parts, start_ns)
    assert log.imu.time_ns[-1] == imu.time_ns[-1]  # read on after the bad record
    assert f"{len(imu)} messages on /imu/data, read {len(log.imu)}" in counts.message


def test_skipped_record_is_caught_by_the_summary_statistics(tmp_path: Path, good_file: Path,
                                                            log_parts) -> None:
    """A chunk's opcode turned into a MessageIndex one: the framing skips it without a word;
    the summary's per-channel counts (read here by the mcap library) say what is missing."""
    off, _, _ = _chunk_offsets(good_file)[1]
    data = bytearray(good_file.read_bytes())
    data[off] = 0x07
    p = tmp_path / "skipped.mcap"
    p.write_bytes(bytes(data))
    log = read_flight_log(p, check_units=False)
    assert not log.complete
    [err] = [i for i in log.issues if i.severity == "error"]
    stats = _library_statistics(good_file)
    assert stats.channel_message_counts  # per-channel counts are what is compared
    n_imu = max(stats.channel_message_counts.values())
    assert n_imu == len(log_parts[0])
    assert f"{n_imu} messages on /imu/data, read {len(log.imu)}" in err.message
    assert len(log.imu) < n_imu


def test_summary_crc_guards_the_statistics(tmp_path: Path, good_file: Path, log_parts) -> None:
    """An altered per-channel count in the Statistics: the summary CRC says the summary is
    corrupt (warning, counts not used, all data read); with the Footer's CRC zeroed (not
    available), the altered count is believed and the log is not complete."""
    data = bytearray(good_file.read_bytes())
    [(stats_off, _, _)] = [r for r in top_records(bytes(data)) if r[1] == 0x0B]
    data[stats_off + 9 + 46 + 2] ^= 0x01  # low byte of the first channel's count
    p = tmp_path / "stats.mcap"
    p.write_bytes(bytes(data))
    log = read_flight_log(p, check_units=False)
    assert log.complete and len(log.imu) == len(log_parts[0])
    [w] = log.issues
    assert w.severity == "warning" and "summary CRC mismatch" in w.message
    footer_off = top_records(bytes(data))[-1][0]
    data[footer_off + 9 + 16 : footer_off + 9 + 20] = bytes(4)
    p.write_bytes(bytes(data))
    log = read_flight_log(p, check_units=False)
    assert not log.complete
    [err] = [i for i in log.issues if i.severity == "error"]
    assert "Statistics say" in err.message


def test_data_section_crc_checked_when_present(tmp_path: Path, log_parts) -> None:
    """mcap's Writer with data CRCs: a byte changed in a MessageIndex record (outside every
    chunk CRC, not used by pospp) still makes the file not complete."""
    imu, fix, _ = log_parts
    path = write_with_library(tmp_path / "crc.mcap", imu, fix, enable_data_crcs=True,
                              chunk_size=64 * 1024)
    log = read_flight_log(path, check_units=False)
    assert log.complete and log.issues[0].severity == "warning"  # (no velocity topic)
    data = bytearray(path.read_bytes())
    off, _, ln = [r for r in top_records(bytes(data)) if r[1] == 0x07][3]
    data[off + 9 + ln - 1] ^= 0x10
    path.write_bytes(bytes(data))
    log = read_flight_log(path, check_units=False)
    assert not log.complete and len(log.imu) == len(imu)
    [err] = [i for i in log.issues if i.severity == "error"]
    assert "data section CRC mismatch" in err.message


@pytest.mark.parametrize("opcode", [0x01, 0x02, 0x07, 0x0B, 0x0E, 0x0F, 0x42])
def test_chunk_opcode_changed_is_never_complete(tmp_path: Path, good_file: Path,
                                                log_parts, opcode: int) -> None:
    """Whatever a chunk's opcode turns into (Header, Footer, MessageIndex, Statistics,
    SummaryOffset, DataEnd, unknown), the log is not complete and an error names the place."""
    off, _, _ = _chunk_offsets(good_file)[2]
    data = bytearray(good_file.read_bytes())
    data[off] = opcode
    p = tmp_path / "op.mcap"
    p.write_bytes(bytes(data))
    log = read_flight_log(p, check_units=False)
    assert not log.complete
    errors = [i for i in log.issues if i.severity == "error"]
    assert errors and all(e.byte_offset is not None for e in errors)
    assert all(e.file == str(p) for e in errors)


def test_truncated_sample_flight_is_not_complete(tmp_path: Path) -> None:
    """The cut of issue 13 (``head -c 8931240 sample_flight.mcap``): 1316 s of 1634 s read;
    not complete, and the error gives the byte offset and the log time reached."""
    sample = Path(__file__).resolve().parents[2] / "sample_data" / "sample_flight.mcap"
    if not sample.is_file():
        pytest.skip(f"{sample} not found")
    cut = 8_931_240
    p = tmp_path / "cut.mcap"
    with open(sample, "rb") as fh:
        p.write_bytes(fh.read(cut))
    log = read_flight_log(p)
    assert not log.complete
    [err] = [i for i in log.issues if i.severity == "error"]
    assert err.byte_offset is not None and err.byte_offset <= cut and f"of {cut}" in err.message
    assert err.log_time_ns >= log.imu.time_ns[-1]
    stats = _library_statistics(sample)
    read_s = (err.log_time_ns - stats.message_start_time) * 1e-9
    assert 1000.0 < read_s < (stats.message_end_time - stats.message_start_time) * 1e-9 - 100
    assert f"({read_s:.1f} s after the first message)" in err.message


def test_issue_text_names_the_facts(tmp_path: Path, log_parts) -> None:
    imu, fix, vel = log_parts
    keep = np.r_[0:1000, 1100:len(imu)]
    gapped = ImuSamples(imu.time_ns[keep], imu.w_ib_b_radps[keep], imu.f_ib_b_mps2[keep])
    path = write_flight_log(tmp_path / "gap.mcap", gapped, fix, vel)
    [gap] = read_flight_log(path).issues
    text = str(gap)
    for fact in (f"file={path}", "topic=/imu/data", "index=1000",
                 f"stamp_ns={imu.time_ns[1100]}", f"log_time_ns={imu.time_ns[1100]}"):
        assert fact in text


# --------------------------------------------------------------------------- other MCAP shapes


def write_with_library(path: Path, imu: ImuSamples, fix: GnssFixes, **writer_kwargs) -> Path:
    """IMU and fix topics written by mcap's own ``Writer`` (sensor frame FLU)."""
    c_sb = FLU_TO_FRD.T
    with open(path, "wb") as fh:
        w = Writer(fh, **writer_kwargs)
        w.start(profile="ros2", library="test")
        for topic, typ, msgdef, fields, t, vals in (
            ("/imu/data", rm.IMU_TYPE, rm.IMU_MSGDEF, rm.IMU_FIELDS, imu.time_ns,
             {"angular_velocity": imu.w_ib_b_radps @ c_sb.T,
              "linear_acceleration": imu.f_ib_b_mps2 @ c_sb.T}),
            ("/gnss/fix", rm.NAVSATFIX_TYPE, rm.NAVSATFIX_MSGDEF, rm.NAVSATFIX_FIELDS,
             fix.time_ns, {"latitude": np.rad2deg(fix.lat_rad),
                           "longitude": np.rad2deg(fix.lon_rad), "altitude": fix.height_m}),
        ):
            sid = w.register_schema(name=typ, encoding="ros2msg", data=msgdef.encode())
            cid = w.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)
            payloads = rm.encode_batch(fields, t, "sensor", vals)
            for i, ti in enumerate(t.tolist()):
                w.add_message(cid, log_time=ti, publish_time=ti, data=payloads[i].tobytes())
        w.finish()
    return path


@pytest.mark.parametrize(
    ("compression", "chunked"),
    [(CompressionType.NONE, True), (CompressionType.LZ4, True), (CompressionType.NONE, False)],
)
def test_other_chunk_compressions_and_unchunked(tmp_path: Path, log_parts, compression,
                                                chunked: bool) -> None:
    """Files written by mcap's own Writer: lz4, uncompressed, and messages outside chunks."""
    imu, fix, _ = log_parts
    path = write_with_library(tmp_path / "other.mcap", imu, fix, compression=compression,
                              use_chunking=chunked, chunk_size=64 * 1024)
    log = read_flight_log(path)
    assert log.complete
    np.testing.assert_array_equal(log.imu.time_ns, imu.time_ns)
    np.testing.assert_array_equal(log.imu.f_ib_b_mps2, imu.f_ib_b_mps2)
    np.testing.assert_array_equal(log.fix.height_m, fix.height_m)
    assert log.imu.frame_id == "sensor"


def test_error_on_a_broken_file_says_where_it_broke(tmp_path: Path, good_file: Path) -> None:
    """Cut inside the first chunk before any GNSS message: the missing-topic error carries the
    break (offset, and the issues so far for messages.parquet)."""
    data = good_file.read_bytes()
    first = _chunk_offsets(good_file)[0]
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[: first[0] + 200])
    with pytest.raises(IngestError, match="truncated or corrupt") as ei:
        read_flight_log(p)
    err = ei.value
    assert err.byte_offset == first[0]
    assert [i.severity for i in err.issues] == ["error"]


@pytest.mark.parametrize("seed", [0, 1])
def test_random_damage_never_escapes_as_another_exception(tmp_path: Path, log_parts,
                                                         seed: int) -> None:
    """Byte flips, random 16-byte patches and cuts anywhere: the reader returns what it can
    (``complete`` telling whether it is all) or raises IngestError, nothing else."""
    imu, fix, vel = make_log(duration_s=20.0, seed=seed)
    data = write_flight_log(tmp_path / "src.mcap", imu, fix, vel).read_bytes()
    rng = np.random.default_rng(seed)
    p = tmp_path / "damaged.mcap"
    outcomes = set()
    for _ in range(40):
        d = bytearray(data)
        mode = int(rng.integers(3))
        if mode == 0:
            d[int(rng.integers(8, len(d)))] ^= int(rng.integers(1, 256))
        elif mode == 1:
            i = int(rng.integers(8, len(d) - 16))
            d[i : i + 16] = rng.bytes(16)
        else:
            d = d[: int(rng.integers(8, len(d)))]
        p.write_bytes(bytes(d))
        try:
            log = read_flight_log(p, check_units=False)
        except IngestError as exc:
            outcomes.add("error")
            assert exc.file == str(p)
            continue
        outcomes.add("complete" if log.complete else "partial")
        if not log.complete:
            assert any(i.severity == "error" and i.byte_offset is not None for i in log.issues)
        assert np.all(np.isin(log.imu.time_ns, imu.time_ns))
    assert {"error", "partial"} <= outcomes


def test_corrupt_chunk_is_reported_but_a_reader_bug_propagates(
        good_file: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What corrupt bytes raise (here a ValueError from decompression) is a skipped chunk, an
    error issue naming the byte offset, and ``complete`` False; anything else (a TypeError: a
    bug in pospp) propagates instead of being reported as the file's fault."""
    from pospp.io import _mcap_scan

    def corrupt(*_args, **_kwargs):
        raise ValueError("bad zstd frame")

    monkeypatch.setattr(_mcap_scan, "decompress", corrupt)
    with pytest.raises(IngestError) as err:  # every chunk skipped: no IMU left
        read_flight_log(good_file)
    assert "corrupt chunk at byte 34 skipped" in str(err.value)
    assert "bad zstd frame" in str(err.value)

    def bug(*_args, **_kwargs):
        raise TypeError("unsupported operand")

    monkeypatch.setattr(_mcap_scan, "decompress", bug)
    with pytest.raises(TypeError, match="unsupported operand"):
        read_flight_log(good_file)
