"""Ingestion benchmark: MCAP decode rate and peak memory on a 1.5 h, 200 Hz flight log.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_decode.py            # builds /tmp/pospp_bench_1p5h.mcap once
    python tests/benchmarks/bench_decode.py --path F --methods pospp,library_stream
    python tests/benchmarks/bench_decode.py --methods pospp --trees /work/main,. --repeat 7

``--bombs`` instead reads decompression bombs (a 20 s log plus one chunk of 2 GiB of zeros,
zstd or lz4, whole or cut, its header claiming 200 MiB or 2 GiB) and prints the peak resident
set above the baseline of each read (per tree, with a 120 s limit per file).

``--memory FILE`` prints, for each tree, the peak resident set of reading FILE (default: the
reference case ``flight_null_200hz.mcap``) above the set just before the read, next to the
decoded arrays' size and the largest chunk (compressed + decompressed). A small log is read
first in the same process, so that the one-time costs (numba's LLVM initialisation and
loading the cached kernels, the generic decoder's schema parsing) are outside the peak; they
are printed apart.

``--warm`` measures in ONE process per tree, after a first read (the pipeline's situation:
numba initialised, kernels loaded): the floor, ``read_flight_log``, and ``read_flight_log``
with the chunk CRC check switched off, interleaved ``--repeat`` times; best CPU and wall.

``--trees`` runs each method with the ``pospp`` of each given source tree, interleaved run by
run (so that a change of machine load hits both alike), to compare two versions of the reader.

The file (1.08 M IMU messages, 5400 GNSS fixes and velocities, zstd chunks) is written with
``pospp.io.mcap_writer.write_flight_log``. Each method runs in a fresh subprocess so that its
peak resident memory is its own; the baseline is the same process after its imports. CPU time
(user + system of the process) is the figure compared, as wall time on the shared machine
depends on the load (peak = VmHWM of the subprocess). Methods:

- ``pospp``: ``pospp.io.mcap_reader.read_flight_log`` (own record framing, batched numpy CDR
  decoding, all the checks, rotation to FRD/NED).
- ``pospp_data_crc``: the same on a copy of the file whose DataEnd record carries the data
  section CRC (``write_flight_log``, like mcap's ``Writer`` by default, writes 0 there), so
  that the CRC is verified; the running CRC is computed either way.
- ``library_stream``: ``mcap.reader.NonSeekingReader(f).iter_messages(topics,
  log_time_order=False)`` (the mcap library's framing: chunks, CRCs, decompression), the raw
  payloads of each topic collected in batches of 65536 and decoded with pospp's structured
  dtypes (``ros_messages.cdr_dtype``), keeping only the wanted fields. No checks.
- ``library_seeking``: the same with ``make_reader(f)`` (index-driven ``SeekingReader``,
  default ``log_time_order=True``).
- ``library_records``: the floor of any library-based path: ``mcap.stream_reader.StreamReader``
  yielding records, payloads only appended to lists (no decoding at all).
- ``floor``: the floor of any reader: the file's bytes read (one ``read`` of the whole file)
  and every chunk zstd-decompressed (top-level records framed with ``struct``; nothing in
  the chunks is looked at).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

_TREE = Path(__file__).resolve().parents[2]
if "--tree" in sys.argv:
    _TREE = Path(sys.argv[sys.argv.index("--tree") + 1]).resolve()
sys.path.insert(0, str(_TREE))  # this (or the given) tree's pospp, not the installed one

DEFAULT_PATH = Path("/tmp/pospp_bench_1p5h.mcap")
TOPICS = ("/imu/data", "/gnss/fix", "/gnss/vel")


def build(path: Path, *, duration_s: float = 5400.0, rate_hz: float = 200.0) -> None:
    from pospp.io.mcap_writer import write_flight_log
    from pospp.types import GnssFixes, GnssVelocities, ImuSamples

    rng = np.random.default_rng(20240601)
    n = int(duration_s * rate_hz)
    t0 = 1_717_200_000_000_000_000
    t = t0 + np.arange(1, n + 1, dtype=np.int64) * int(round(1e9 / rate_hz))
    w = rng.normal(0.0, 1e-3, (n, 3))
    f = rng.normal(0.0, 0.05, (n, 3)) + [0.0, 0.0, -9.80665]
    m = int(duration_s)
    tg = t0 + np.arange(1, m + 1, dtype=np.int64) * 1_000_000_000
    fix = GnssFixes(tg, 0.7 + rng.normal(0, 1e-7, m), np.full(m, 2.0), np.full(m, 100.0),
                    np.tile(np.diag([0.01, 0.01, 0.04]), (m, 1, 1)), np.zeros(m, np.int8))
    vel = GnssVelocities(tg, rng.normal(0, 0.02, (m, 3)), np.tile(np.eye(3) * 4e-4, (m, 1, 1)))
    t_start = time.perf_counter()
    write_flight_log(path, ImuSamples(t, w, f, "imu_link"), fix, vel)
    print(f"built {path} ({path.stat().st_size / 1e6:.1f} MB, {n} IMU messages) in "
          f"{time.perf_counter() - t_start:.1f} s", file=sys.stderr)


def with_data_crc(path: Path) -> Path:
    """A copy of ``path`` with the data section CRC (CRC-32 of every byte before the DataEnd
    record, leading magic included) written into its DataEnd record."""
    import struct
    import zlib

    out = path.with_name(path.stem + "_datacrc.mcap")
    if out.exists():
        return out
    data = bytearray(path.read_bytes())
    pos = 8
    while data[pos] != 0x0F:
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    struct.pack_into("<I", data, pos + 9, zlib.crc32(memoryview(data)[:pos]))
    out.write_bytes(bytes(data))
    return out


def bomb_files(folder: Path) -> list[Path]:
    """The decompression-bomb files of ``--bombs`` (built once in ``folder``)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
    from test_mcap_fuzz import MIB, _chunk_record, _zeros_compressed
    from test_mcap_reader import make_log, top_records

    from pospp.io.mcap_writer import write_flight_log

    folder.mkdir(parents=True, exist_ok=True)
    parts = make_log(duration_s=20.0, seed=3)
    data = write_flight_log(folder / "src.mcap", *parts).read_bytes()
    first = [r for r in top_records(data) if r[1] == 0x06][0]
    head = data[: first[0] + 9 + first[2]]
    out = []
    for comp in ("zstd", "lz4"):
        bomb = None
        for claim in (200 * MIB, 2048 * MIB):
            for cut in (False, True):
                p = folder / f"{comp}_{claim // MIB}MiB_{'cut' if cut else 'whole'}.mcap"
                out.append(p)
                if p.exists():
                    continue
                bomb = bomb or _zeros_compressed(comp, 2048 * MIB)
                rec = _chunk_record(bomb, claim, comp, int(parts[0].time_ns[-1]))
                p.write_bytes(head + rec[: len(rec) * 2 // 3] if cut
                              else head + rec + data[len(head) :])
    return out


def read_bomb(path: Path) -> str:
    """Peak resident set growth [MiB] of one read, and its verdict."""
    from pospp.io.errors import IngestError
    from pospp.io.mcap_reader import read_flight_log

    Path("/proc/self/clear_refs").write_text("5")
    base = _status_mib("VmRSS")
    try:
        verdict = f"complete={read_flight_log(path, check_units=False).complete}"
    except IngestError:
        verdict = "IngestError"
    grown = _status_mib("VmHWM") - base
    return f"| {path.name} ({path.stat().st_size / 1e3:.0f} kB) | {grown:.0f} | {verdict} |"


def _largest_chunk_bytes(path: Path) -> int:
    """Compressed + decompressed size of the file's largest chunk [bytes]."""
    import struct

    data, pos, best = path.read_bytes(), 8, 0
    while pos < len(data) - 8:
        op, ln = struct.unpack_from("<BQ", data, pos)
        if op == 0x02:
            break
        if op == 0x06:
            best = max(best, ln + struct.unpack_from("<Q", data, pos + 25)[0])
        pos += 9 + ln
    return best


def read_memory(path: Path) -> str:
    """One table row: the read's peak above the set before it, with the one-time costs apart."""
    import numpy as np

    from pospp.io.mcap_reader import read_flight_log

    small = Path("/tmp/pospp_bench_bombs/src.mcap")
    if not small.exists():
        bomb_files(small.parent)
    after_imports = _status_mib("VmRSS")
    read_flight_log(small, check_units=False)  # numba init, kernels loaded, decoders built
    before = _status_mib("VmRSS")
    Path("/proc/self/clear_refs").write_text("5")  # VmHWM := VmRSS
    log = read_flight_log(path)
    peak = _status_mib("VmHWM") - before
    decoded = sum(v.nbytes for part in (log.imu, log.fix, log.vel)
                  for v in vars(part).values() if isinstance(v, np.ndarray)) / 2**20
    chunk = _largest_chunk_bytes(path) / 2**20
    return (f"| {path.name} | {before - after_imports:.0f} | {peak:.0f} | {decoded:.1f} | "
            f"{chunk:.1f} | {peak - decoded - chunk:+.1f} |")


def warm_rows(path: Path, repeat: int) -> list[str]:
    """``--warm``: floor / reader / reader without chunk CRCs, interleaved in this process."""
    import pospp.io._mcap_scan as scan
    from pospp.io.mcap_reader import read_flight_log

    parse = scan.parse_chunk

    def no_crc(body: bytes, truncated: bool):  # the stored CRC set to 0: not checked
        chunk = parse(body, truncated)
        return scan.RawChunk(chunk.start_ns, chunk.end_ns, chunk.uncompressed_size, 0,
                              chunk.compression, chunk.data, chunk.truncated)

    def reader_no_crc() -> None:
        scan.parse_chunk = no_crc
        try:
            read_flight_log(path)
        finally:
            scan.parse_chunk = parse

    methods = {"floor": lambda: _floor(path), "read_flight_log": lambda: read_flight_log(path),
               "read_flight_log, chunk CRCs not checked": reader_no_crc}
    read_flight_log(path)
    best = {k: (9e9, 9e9) for k in methods}
    for _ in range(repeat):
        for name, fn in methods.items():
            t, c = time.perf_counter(), time.process_time()
            fn()
            c, t = time.process_time() - c, time.perf_counter() - t
            best[name] = (min(best[name][0], c), min(best[name][1], t))
    floor_cpu, floor_wall = best["floor"]
    return [f"| {k} | {c:.3f} | {c / floor_cpu:.1f} | {w:.3f} | {w / floor_wall:.1f} |"
            for k, (c, w) in best.items()]


def _library_decode(path: Path, *, seeking: bool) -> int:
    from mcap.reader import NonSeekingReader, make_reader

    from pospp.io import ros_messages as rm

    layouts = {"/imu/data": (rm.IMU_FIELDS, ("angular_velocity", "linear_acceleration")),
               "/gnss/fix": (rm.NAVSATFIX_FIELDS, ("latitude", "longitude", "altitude")),
               "/gnss/vel": (rm.TWIST_COV_STAMPED_FIELDS, ("linear",))}
    pending: dict[str, list[bytes]] = {tp: [] for tp in TOPICS}
    blocks: dict[str, list[dict[str, np.ndarray]]] = {tp: [] for tp in TOPICS}

    def flush(topic: str) -> None:
        payloads = pending[topic]
        if not payloads:
            return
        fields, wanted = layouts[topic]
        by_len: dict[int, list[bytes]] = {}
        for p in payloads:
            by_len.setdefault(len(p), []).append(p)
        for group in by_len.values():
            flen = int.from_bytes(group[0][12:16], "little")
            arr = np.frombuffer(b"".join(group), dtype=rm.cdr_dtype(fields, flen))
            out = {k: arr[k].copy() for k in wanted}
            out["time_ns"] = rm.stamp_ns(arr["sec"], arr["nanosec"])
            blocks[topic].append(out)
        pending[topic] = []

    with open(path, "rb") as fh:
        reader = make_reader(fh) if seeking else NonSeekingReader(fh)
        it = reader.iter_messages(topics=list(TOPICS), log_time_order=seeking)
        for _, channel, message in it:
            lst = pending[channel.topic]
            lst.append(message.data)
            if len(lst) >= 65536:
                flush(channel.topic)
    for tp in TOPICS:
        flush(tp)
    imu = {k: np.concatenate([b[k] for b in blocks["/imu/data"]]) for k in blocks["/imu/data"][0]}
    return int(imu["time_ns"].shape[0])


def _records_only(path: Path) -> int:
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    payloads: dict[int, list[bytes]] = {}
    with open(path, "rb") as fh:
        for rec in StreamReader(fh).records:
            if type(rec) is Message:
                payloads.setdefault(rec.channel_id, []).append(rec.data)
    return max(len(v) for v in payloads.values())


def _floor(path: Path) -> int:
    """Read the bytes and decompress every chunk; returns the decompressed byte count."""
    import struct

    import zstandard

    data = path.read_bytes()
    dec = zstandard.ZstdDecompressor()
    pos, total, n = 8, 0, len(data) - 8
    while pos < n:
        op, ln = struct.unpack_from("<BQ", data, pos)
        if op == 0x06:  # Chunk: start, end, uncompressed size, crc, compression, records
            usize = struct.unpack_from("<Q", data, pos + 25)[0]
            clen = struct.unpack_from("<I", data, pos + 37)[0]
            p = pos + 41 + clen
            rlen = struct.unpack_from("<Q", data, p)[0]
            total += len(dec.decompress(data[p + 8 : p + 8 + rlen], max_output_size=usize))
        pos += 9 + ln
    return total


def _status_mib(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _peak_rss_mb() -> float:
    """Peak resident set of this process image (VmHWM; unlike ru_maxrss, not inherited from
    the parent across exec)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_one(method: str, path: Path) -> dict:
    import mcap  # noqa: F401  (imports counted in the baseline)

    from pospp.io.mcap_reader import read_flight_log

    base_mb = _peak_rss_mb()
    t = time.perf_counter()
    cpu = time.process_time()
    if method in ("pospp", "pospp_data_crc"):
        log = read_flight_log(path)
        assert log.complete, log.issues
        n_imu = len(log.imu)
    elif method == "library_stream":
        n_imu = _library_decode(path, seeking=False)
    elif method == "library_seeking":
        n_imu = _library_decode(path, seeking=True)
    elif method == "library_records":
        n_imu = _records_only(path)
    elif method == "floor":
        _floor(path)
        n_imu = 1_080_000
    else:
        raise ValueError(f"unknown method {method!r}")
    wall = time.perf_counter() - t
    cpu = time.process_time() - cpu
    peak_mb = _peak_rss_mb()
    n_all = n_imu + 2 * 5400
    return {"method": method, "wall_s": wall, "cpu_s": cpu, "imu_messages": n_imu,
            "messages_per_s": n_all / cpu, "peak_rss_mb": peak_mb, "baseline_rss_mb": base_mb}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--path", type=Path, default=DEFAULT_PATH)
    ap.add_argument("--methods", default="pospp,library_stream,library_seeking,library_records")
    ap.add_argument("--repeat", type=int, default=2, help="runs per method (best is reported)")
    ap.add_argument("--trees", default=str(_TREE),
                    help="comma-separated source trees whose pospp is measured (interleaved)")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--tree", help=argparse.SUPPRESS)
    ap.add_argument("--bombs", action="store_true", help="peak memory on decompression bombs")
    ap.add_argument("--bomb", help=argparse.SUPPRESS)
    ap.add_argument("--memory", nargs="?", type=Path, help="peak memory of one read",
                    const=Path("../shared/reference_cases/flight_null_200hz.mcap"))
    ap.add_argument("--memory-one", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--warm", action="store_true", help="floor and reader in one warm process")
    ap.add_argument("--warm-one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.warm_one:
        print("\n".join(warm_rows(args.path, args.repeat)))
        return
    if args.warm:
        if not args.path.exists():
            build(args.path)
        print(f"file: {args.path}, best of {args.repeat}, one process per tree after a first "
              "read\n\n| method | CPU [s] | CPU x floor | wall [s] | wall x floor |\n"
              "|---|---:|---:|---:|---:|")
        for tree in [str(Path(t).resolve()) for t in args.trees.split(",")]:
            out = subprocess.run([sys.executable, __file__, "--warm-one", "--path",
                                  str(args.path), "--repeat", str(args.repeat), "--tree", tree],
                                 capture_output=True, text=True, timeout=600)
            print(f"| {tree} | | | | |\n" + (out.stdout.strip() or out.stderr[-400:]))
        return
    if args.memory_one:
        print(read_memory(args.memory_one))
        return
    if args.memory:
        print("| file | one-time init [MiB] | read peak above the set before it [MiB] | "
              "decoded arrays [MiB] | largest chunk [MiB] | peak - arrays - chunk [MiB] |\n"
              "|---|---:|---:|---:|---:|---:|")
        for tree in [str(Path(t).resolve()) for t in args.trees.split(",")]:
            out = subprocess.run([sys.executable, __file__, "--memory-one",
                                  str(args.memory.resolve()), "--tree", tree],
                                 capture_output=True, text=True, timeout=300)
            print(out.stdout.strip() or out.stderr[-400:], f"({tree})")
        return
    if args.bomb:
        print(read_bomb(Path(args.bomb)))
        return
    if args.bombs:
        files = bomb_files(Path("/tmp/pospp_bench_bombs"))
        for tree in [str(Path(t).resolve()) for t in args.trees.split(",")]:
            print(f"\n{tree}\n\n| file | peak RSS growth [MiB] | verdict |\n|---|---:|---|")
            for f in files:
                try:
                    out = subprocess.run([sys.executable, __file__, "--bomb", str(f), "--tree",
                                          tree], capture_output=True, text=True, timeout=120)
                    print(out.stdout.strip() or f"| {f.name} | failed | {out.stderr[-200:]} |")
                except subprocess.TimeoutExpired:
                    print(f"| {f.name} | - | not finished in 120 s |")
        return
    if args.one:
        print(json.dumps(run_one(args.one, args.path)))
        return
    if not args.path.exists():
        build(args.path)
    size_mb = args.path.stat().st_size / 1e6
    rows = []
    trees = [str(Path(t).resolve()) for t in args.trees.split(",")]
    for method in args.methods.split(","):
        runs: dict[str, list[dict]] = {t: [] for t in trees}
        path = with_data_crc(args.path) if method == "pospp_data_crc" else args.path
        for _ in range(args.repeat):
            for tree in trees:
                out = subprocess.run([sys.executable, __file__, "--path", str(path), "--one",
                                      method, "--tree", tree],
                                     check=True, capture_output=True, text=True)
                runs[tree].append(json.loads(out.stdout))
        for tree in trees:
            best = min(runs[tree], key=lambda r: r["cpu_s"])
            if len(trees) > 1:
                best["method"] = f"{method} ({tree})"
            rows.append(best)
    ref = rows[0]["cpu_s"]
    print(f"file: {args.path} ({size_mb:.1f} MB), best of {args.repeat}\n")
    print("| method | CPU [s] | wall [s] | CPU x first | messages/CPU-s | peak RSS [MB] | "
          "baseline RSS [MB] |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['method']} | {r['cpu_s']:.2f} | {r['wall_s']:.2f} | {r['cpu_s'] / ref:.1f} | "
              f"{r['messages_per_s']:,.0f} | {r['peak_rss_mb']:.0f} | "
              f"{r['baseline_rss_mb']:.0f} |")


if __name__ == "__main__":
    main()
