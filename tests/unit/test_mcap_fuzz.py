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
