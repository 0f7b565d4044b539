"""Fault injection on the MCAP reader (issue 13): seeded mutations of small valid files, and
decompression bombs.

Every mutated file must give one of: an ``IngestError`` naming the file; a ``FlightLog`` with
``complete=False`` and an error issue that says where (byte offset); or a complete log that
has lost nothing -- bit-identical to the unmutated file's where chunk CRCs protect the data,
with every message where they do not (payload values may then differ and still pass the
contract checks). Never another exception type, and never more than a bounded amount of
memory (peak resident set, reset through ``/proc/self/clear_refs`` before each test).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType
from test_mcap_reader import make_log, top_records, write_with_library

from pospp.io import ros_messages as rm
from pospp.io.errors import IngestError
from pospp.io.mcap_reader import FlightLog, read_flight_log
from pospp.io.mcap_writer import write_flight_log

MIB = 1 << 20
SEEDS = {"pospp_zstd": 1301, "library_lz4": 1302, "library_plain_no_crc": 1303}
OPCODES = (0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x0B, 0x0E, 0x0F, 0x00, 0x80, 0xFF)


# --------------------------------------------------------------------------- memory


def _status_mib(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    pytest.skip(f"{key} not in /proc/self/status")
    return 0.0


def _reset_peak() -> float:
    """Reset the peak resident set (VmHWM) to the current one; return the current [MiB]."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError as exc:
        pytest.skip(f"cannot reset the peak resident set: {exc}")
    return _status_mib("VmRSS")


def _peak_growth_mib(since_mib: float) -> float:
    return _status_mib("VmHWM") - since_mib


# --------------------------------------------------------------------------- mutations


def _chunk_fields(data: bytes, off: int) -> dict[str, int]:
    """Byte offsets of a Chunk record's header fields (MCAP spec: message_start_time u64,
    message_end_time u64, uncompressed_size u64, uncompressed_crc u32, compression string
    (u32 length + bytes), records length u64)."""
    b = off + 9
    (clen,) = struct.unpack_from("<I", data, b + 28)
    return {"start": b, "end": b + 8, "usize": b + 16, "crc": b + 24,
            "records_length": b + 32 + clen}


def _mutate(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    recs = top_records(data)
    chunks = [r for r in recs if r[1] == 0x06]
    d = bytearray(data)
    kind = int(rng.integers(6))
    if kind == 0:
        i = int(rng.integers(8, len(d)))
        d[i] ^= int(rng.integers(1, 256))
        return f"flip byte {i}", bytes(d)
    if kind == 1:
        n = int(rng.integers(8, len(d)))
        return f"cut at {n}", bytes(d[:n])
    if kind == 2:
        off = recs[int(rng.integers(len(recs)))][0]
        op = int(rng.choice(OPCODES))
        d[off] = op
        return f"opcode at {off} -> {op:#04x}", bytes(d)
    if kind == 3:
        off, _, ln = recs[int(rng.integers(len(recs)))]
        new = int(rng.choice([ln + int(rng.integers(1, 64)), max(ln - int(rng.integers(1, 9)), 0),
                              2 * ln + 1, (1 << 32) + ln, (1 << 63) - 1]))
        struct.pack_into("<Q", d, off + 1, new)
        return f"length at {off}: {ln} -> {new}", bytes(d)
    if kind == 4 and chunks:
        off = chunks[int(rng.integers(len(chunks)))][0]
        name = str(rng.choice(["usize", "records_length", "crc", "start"]))
        pos = _chunk_fields(data, off)[name]
        fmt = "<I" if name == "crc" else "<Q"
        (old,) = struct.unpack_from(fmt, d, pos)
        new = int(rng.choice([old + 1, max(old - 1, 0), 0, 1 << 28, 1 << 33, (1 << 63) - 1]))
        struct.pack_into(fmt, d, pos, new & (0xFFFFFFFF if name == "crc" else (1 << 64) - 1))
        return f"chunk at {off}: {name} {old} -> {new}", bytes(d)
    i = int(rng.integers(8, len(d) - 16))
    d[i : i + 16] = rng.bytes(16)
    return f"16 random bytes at {i}", bytes(d)


def _arrays(log: FlightLog) -> list[np.ndarray]:
    return [log.imu.time_ns, log.imu.w_ib_b_radps, log.imu.f_ib_b_mps2, log.fix.time_ns,
            log.fix.lat_rad, log.fix.lon_rad, log.fix.height_m, log.fix.pos_cov_ned_m2,
            log.vel.time_ns, log.vel.v_n_mps]


def _check_one(path: Path, ref: FlightLog, crc_protected: bool) -> tuple[str, str | None]:
    """(outcome, None) when the reader's verdict on ``path`` is acceptable, else (outcome,
    what is wrong); outcome is "error", "partial", "complete" or "changed" (complete, values
    differ)."""
    try:
        log = read_flight_log(path)
    except IngestError as exc:
        ok = exc.file == str(path) and exc.reason
        return "error", None if ok else f"IngestError without file: {exc}"
    except Exception as exc:  # noqa: BLE001 - the point of the test
        return "other", f"{type(exc).__name__}: {exc}"
    errors = [i for i in log.issues if i.severity == "error"]
    if not log.complete:
        if not errors or any(e.byte_offset is None or e.file != str(path) for e in errors):
            return "partial", f"incomplete without a located error: {list(map(str, log.issues))}"
        return "partial", None
    if errors:
        return "complete", f"complete with errors: {[str(e) for e in errors]}"
    same = all(a.shape == b.shape and np.array_equal(a, b)
               for a, b in zip(_arrays(log), _arrays(ref), strict=True))
    if crc_protected:
        return "complete", None if same else "complete, but the data differ from the original"
    dropped = any("dropped" in i.message for i in log.issues)
    if len(log.imu) != len(ref.imu) or (len(log.fix) != len(ref.fix) and not dropped):
        return "complete", (f"complete with {len(log.imu)}/{len(ref.imu)} IMU and "
                            f"{len(log.fix)}/{len(ref.fix)} fix messages")
    return "complete" if same else "changed", None


@pytest.fixture(scope="module")
def small_log():
    return make_log(duration_s=20.0, seed=3)


@pytest.mark.parametrize(
    ("base", "n", "crc_protected"),
    [("pospp_zstd", 200, True), ("library_lz4", 60, True), ("library_plain_no_crc", 100, False)],
)
def test_mutated_files_fail_clearly(tmp_path: Path, small_log, base: str, n: int,
                                    crc_protected: bool) -> None:
    """Byte flips, cuts, opcode changes, record lengths and chunk header fields changed,
    random patches: every outcome acceptable (see the module docstring), memory bounded."""
    imu, fix, vel = small_log
    src = tmp_path / "src.mcap"
    if base == "pospp_zstd":
        write_flight_log(src, imu, fix, vel)
    elif base == "library_lz4":
        write_with_library(src, imu, fix, compression=CompressionType.LZ4, chunk_size=16384)
    else:
        write_with_library(src, imu, fix, compression=CompressionType.NONE, chunk_size=16384,
                           enable_crcs=False)
    data = src.read_bytes()
    ref = read_flight_log(src)
    assert ref.complete and len(ref.imu) == len(imu)
    rng = np.random.default_rng(SEEDS[base])
    p = tmp_path / "mutated.mcap"
    before = _reset_peak()
    failures, outcomes = [], set()
    for _ in range(n):
        desc, mutated = _mutate(data, rng)
        p.write_bytes(mutated)
        outcome, wrong = _check_one(p, ref, crc_protected)
        outcomes.add(outcome)
        if wrong:
            failures.append(f"{desc}: {wrong}")
    growth = _peak_growth_mib(before)
    assert not failures, f"{len(failures)} of {n} mutations: " + "\n".join(failures[:8])
    # the mutations reach every verdict; without CRCs, some change payload values only
    assert {"error", "partial", "complete"} <= outcomes
    assert ("changed" in outcomes) == (not crc_protected)
    assert growth < 200.0, f"peak resident set grew by {growth:.0f} MiB"


# --------------------------------------------------------------------------- bombs


def _zeros_compressed(compression: str, n_bytes: int) -> bytes:
    """``n_bytes`` zero bytes compressed in 16 MiB pieces (never held uncompressed)."""
    piece = bytes(16 * MIB)
    if compression == "zstd":
        import zstandard

        c = zstandard.ZstdCompressor(level=1, write_content_size=False).compressobj()
        return b"".join(c.compress(piece) for _ in range(n_bytes // len(piece))) + c.flush()
    import lz4.frame

    c = lz4.frame.LZ4FrameCompressor()
    out = [c.begin()] + [c.compress(piece) for _ in range(n_bytes // len(piece))]
    return b"".join(out) + c.flush()


def _chunk_record(data: bytes, usize: int, compression: str, t_ns: int) -> bytes:
    comp = compression.encode()
    body = (struct.pack("<QQQII", t_ns, t_ns, usize, 0, len(comp)) + comp
            + struct.pack("<Q", len(data)) + data)
    return struct.pack("<BQ", 0x06, len(body)) + body


@pytest.fixture(scope="module")
def bombs() -> dict[str, bytes]:
    return {c: _zeros_compressed(c, 1024 * MIB) for c in ("zstd", "lz4")}


@pytest.mark.parametrize("cut", [False, True], ids=["whole", "cut"])
@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_decompression_bomb_is_bounded(tmp_path: Path, small_log, bombs, compression: str,
                                       cut: bool) -> None:
    """A chunk of 1 GiB of zeros (zstd 33 KB, lz4 4 MB) whose header claims 64 MiB (below
    the default cap), after the first chunk of a valid file, whole or cut short. Unbounded
    decompression would take over 1 GiB; the reader may take at most what the header claims
    (plus lz4's 16 MiB pieces)."""
    data = write_flight_log(tmp_path / "src.mcap", *small_log).read_bytes()
    first = [r for r in top_records(data) if r[1] == 0x06][0]
    head = data[: first[0] + 9 + first[2]]
    rec = _chunk_record(bombs[compression], 64 * MIB, compression, int(small_log[0].time_ns[-1]))
    p = tmp_path / "bomb.mcap"
    p.write_bytes(head + rec[: len(rec) * 2 // 3] if cut else head + rec + data[len(head) :])
    before = _reset_peak()
    try:
        log = read_flight_log(p, check_units=False)
    except IngestError as exc:
        pytest.fail(f"the chunks around the bomb are readable: {exc}")
    growth = _peak_growth_mib(before)
    assert growth < 64 + 80, f"peak resident set grew by {growth:.0f} MiB"
    assert not log.complete
    errors = [i for i in log.issues if i.severity == "error"]
    if cut:
        assert "truncated or corrupt" in errors[0].message
    else:
        assert f"more than the {64 * MIB} bytes its header claims" in errors[0].message
        assert len(log.imu) == len(small_log[0])  # every real chunk read


def test_chunk_size_claim_over_the_cap_is_rejected_unread(tmp_path: Path, small_log,
                                                          bombs) -> None:
    """Header claims of 8 GiB (over the default 256 MiB cap) and of 64 MiB with
    ``max_chunk_bytes`` at 32 MiB: the chunk is skipped before any decompression."""
    data = write_flight_log(tmp_path / "src.mcap", *small_log).read_bytes()
    first = [r for r in top_records(data) if r[1] == 0x06][0]
    end = first[0] + 9 + first[2]
    t = int(small_log[0].time_ns[-1])
    for claim, cap in ((8 << 30, None), (64 * MIB, 32 * MIB)):
        p = tmp_path / "claim.mcap"
        p.write_bytes(data[:end] + _chunk_record(bombs["zstd"], claim, "zstd", t) + data[end:])
        before = _reset_peak()
        log = read_flight_log(p, check_units=False,
                              **({} if cap is None else {"max_chunk_bytes": cap}))
        assert _peak_growth_mib(before) < 32
        assert not log.complete
        cap_text = f"over the cap of {cap or 256 * MIB}"
        assert any(f"claims {claim} uncompressed bytes, {cap_text}" in i.message
                   for i in log.issues)
        assert len(log.imu) == len(small_log[0])  # every real chunk read
    with pytest.raises(ValueError, match="max_chunk_bytes"):
        read_flight_log(p, max_chunk_bytes=0)


# --------------------------------------------------------------------------- issue 38


def _plain_file(tmp_path: Path, small_log, *, crcs: bool) -> tuple[bytearray, int, int]:
    """A file of uncompressed chunks (mcap's Writer) as bytes, the offset of its third chunk's
    records_length field and of its records."""
    imu, fix, _ = small_log
    src = write_with_library(tmp_path / "plain.mcap", imu, fix,
                             compression=CompressionType.NONE, chunk_size=16384,
                             enable_crcs=crcs)
    data = bytearray(src.read_bytes())
    off = [r for r in top_records(bytes(data)) if r[1] == 0x06][2][0]
    rl_at = _chunk_fields(bytes(data), off)["records_length"]
    return data, rl_at, rl_at + 8


def _replace_accel(data: bytearray, start: int, imu, value: float) -> int:
    """Put ``value`` in place of the first IMU z specific force (as logged, FLU) found after
    ``start``; returns the message's index."""
    for k in range(len(imu)):
        at = bytes(data).find(struct.pack("<d", -imu.f_ib_b_mps2[k, 2]), start)
        if at >= 0:
            data[at : at + 8] = struct.pack("<d", value)
            return k
    raise AssertionError("no IMU value found")


def test_overstated_records_length_still_checks_the_chunk_crc(tmp_path: Path, small_log):
    """A chunk whose records_length claims more than its record holds used to be read as a
    cut-off chunk, unchecked: a changed value then passed (issue 38 item 4). Its records are
    checked by size and CRC like any chunk's: a changed byte skips the chunk."""
    imu = small_log[0]
    data, rl_at, rec_at = _plain_file(tmp_path, small_log, crcs=True)
    (rl,) = struct.unpack_from("<Q", data, rl_at)
    struct.pack_into("<Q", data, rl_at, rl + 1000)
    intact = tmp_path / "overstated.mcap"
    intact.write_bytes(bytes(data))
    log = read_flight_log(intact)  # the records match their CRC: kept, with a warning
    assert log.complete and len(log.imu) == len(imu)
    assert any("records_length claims 1000 bytes more" in i.message and i.severity == "warning"
               for i in log.issues)
    _replace_accel(data, rec_at, imu, 1e-300)  # finite, in range: only the CRC can tell
    changed = tmp_path / "changed.mcap"
    changed.write_bytes(bytes(data))
    log = read_flight_log(changed, check_units=False)
    assert not log.complete
    assert any("chunk CRC mismatch" in i.message and i.byte_offset is not None
               for i in log.issues if i.severity == "error")
    assert np.abs(log.imu.f_ib_b_mps2[:, 2]).min() > 9.0  # the changed value is not read


@pytest.mark.parametrize(("value", "field"), [(3e206, "linear_acceleration"),
                                              (-1e5, "linear_acceleration")])
def test_a_value_beyond_its_physical_limit_is_refused(tmp_path: Path, small_log, value, field):
    """Without a CRC nothing vouches for a chunk's bytes: a flipped exponent bit gave a 3e206
    m/s^2 sample that the reader passed on (issue 38 item 4). Every decoded value is bounded
    (docs/formats.md, "Physical limits")."""
    data, _, rec_at = _plain_file(tmp_path, small_log, crcs=False)
    k = _replace_accel(data, rec_at, small_log[0], value)
    p = tmp_path / "huge.mcap"
    p.write_bytes(bytes(data))
    with pytest.raises(IngestError) as err:
        read_flight_log(p, check_units=False)
    e = err.value
    assert e.file == str(p) and e.topic == "/imu/data" and e.index == k
    assert f"{field} = " in e.reason and "outside its physical range [-2000, 2000] m/s^2" \
        in e.reason


def _repeated_imu_chunk(imu, n_messages: int) -> bytes:
    """A zstd Chunk record of ``n_messages`` identical IMU Message records on channel 1 (the
    IMU channel of pospp's writer; 360 bytes each, compressed about 1000-fold)."""
    import zstandard

    payload = rm.encode_batch(rm.IMU_FIELDS, imu.time_ns[:1], "imu_link", {
        "angular_velocity": imu.w_ib_b_radps[:1], "linear_acceleration": imu.f_ib_b_mps2[:1]})
    body = struct.pack("<HIQQ", 1, 0, int(imu.time_ns[0]), int(imu.time_ns[0])) + \
        payload[0].tobytes()
    record = struct.pack("<BQ", 0x05, len(body)) + body
    raw = record * n_messages
    comp = zstandard.ZstdCompressor(level=1).compress(raw)
    t = int(imu.time_ns[-1])
    head = struct.pack("<QQQII", t, t, len(raw), 0, 4) + b"zstd" + struct.pack("<Q", len(comp))
    return struct.pack("<BQ", 0x06, len(head) + len(comp)) + head + comp


def test_decoded_size_is_bounded_by_the_file_size(tmp_path: Path, small_log):
    """Chunks of repeated messages decode to thousands of times their size: a 2 MB file
    decoded to 4.1 GB (issue 38 item 11). Here 25 chunks of 100,000 IMU messages (a 2.2 MB
    file, 160 MiB of samples): refused in one line when the decoded arrays would pass 64 x
    the file's size (64 MiB at least), the memory bounded by that (the reader took 294 MiB
    and ended on the stamps before)."""
    data = write_flight_log(tmp_path / "src.mcap", *small_log).read_bytes()
    first = [r for r in top_records(data) if r[1] == 0x06][0]
    end = first[0] + 9 + first[2]
    chunk = _repeated_imu_chunk(small_log[0], 100_000)
    p = tmp_path / "repeated.mcap"
    p.write_bytes(data[:end] + chunk * 25 + data[end:])
    before = _reset_peak()
    with pytest.raises(IngestError) as err:
        read_flight_log(p)
    growth = _peak_growth_mib(before)
    assert err.value.file == str(p) and err.value.topic == "/imu/data"
    assert "decode to more than 64 times the file's size" in err.value.reason
    assert "decompression bomb" in err.value.reason and "\n" not in str(err.value)
    # the arrays at the budget, their last doubling's copy and one chunk: 294 MiB before
    assert growth < 2 * 64 + 64, f"peak resident set grew by {growth:.0f} MiB"


def test_a_named_pipe_is_refused_not_read(tmp_path: Path, make_fifo):
    """A FIFO named like a log blocked the reader forever (issue 38 item 12)."""
    from pospp.io.files import NotRegularFileError, sha256_file

    fifo = make_fifo(tmp_path / "pipe.mcap")
    for read in (read_flight_log, sha256_file):
        with pytest.raises(NotRegularFileError, match="pipe.mcap: is a named pipe"):
            read(fifo)
