"""Memory of one ``pospp run``, stage by stage: resident set, its peak, and what Python holds.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_stage_memory.py [MCAP] [--pipeline P] [--trace]

Default MCAP: the 1.5 h, 200 Hz flight of bench_pipeline.py (/tmp/pospp_bench, made by
``python tests/benchmarks/bench_pipeline.py --minutes 90`` once). At each stage's end it prints
the process's resident set (VmRSS), its peak so far (VmHWM) and, with ``--trace``, what
tracemalloc saw allocated then and at its peak within the stage (numpy's arrays included;
tracing slows the run). One thread by default, so that one A pass is in flight at a time;
``--threads 2`` shows what the parallel loops (B's replays, the null's A re-runs) hold at once.
Results: docs/history/speed_rounds.md, "Speed and memory, fifth round".
"""

from __future__ import annotations

import argparse
import tempfile
import tracemalloc
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _status_mib() -> dict[str, int]:
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(("VmRSS", "VmHWM")):
                key, value = line.split(":")
                out[key] = int(value.split()[0]) // 1024
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mcap", nargs="?", default="/tmp/pospp_bench/flight_90min_200hz.mcap")
    ap.add_argument("--pipeline", default=str(REPO / "pipelines" / "flight.toml"))
    ap.add_argument("--trace", action="store_true", help="also tracemalloc (slower)")
    ap.add_argument("--threads", type=int, default=1,
                    help="the run's threads (above 1: the parallel loops' workers "
                         "hold their passes at once)")
    a = ap.parse_args()
    from pospp import pipeline
    from pospp.config import load_config

    if a.trace:
        tracemalloc.start()
    print("| stage ends | RSS [MiB] | HWM [MiB] |" + (" traced [MiB] | traced peak [MiB] |"
                                                      if a.trace else ""))
    print("|---|---:|---:|" + ("---:|---:|" if a.trace else ""))
    last: list[str | None] = [None]

    def progress(stage: str, frac: float) -> None:
        if stage == last[0]:
            return
        s = _status_mib()
        row = f"| {last[0] or 'imports'} | {s['VmRSS']} | {s['VmHWM']} |"
        if a.trace:
            cur, peak = tracemalloc.get_traced_memory()
            row += f" {cur >> 20} | {peak >> 20} |"
            tracemalloc.reset_peak()
        print(row, flush=True)
        last[0] = stage

    with tempfile.TemporaryDirectory() as out:
        pipeline.process_flight(a.mcap, load_config(a.pipeline), out, progress=progress,
                                force=True, threads=a.threads)
    progress("done", 1.0)


if __name__ == "__main__":
    main()
