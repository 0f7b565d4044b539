"""Which thread runs what, and when, in one ``pospp run``: every A pass (algorithm A, with the
stack that asked for it), the calibration's null refits, the diagnosis's tests and the QC
checks, each with its thread, start and end; then each thread's busy time.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_timeline.py [MCAP] [--pipeline P] [--threads N]

Default MCAP: the 1.5 h, 200 Hz flight of bench_pipeline.py (/tmp/pospp_bench, made by
``python tests/benchmarks/bench_pipeline.py --minutes 90`` once). Times are seconds from the
call of ``pipeline.process_flight`` (imports not included). What a two-thread run waits for
shows as a gap on the main thread while the lane works (issue 18's ninth round found the main
thread waiting 0.9 s for the lane's last re-runs this way). Results: docs/benchmarks.md,
"Speed and memory, ninth round".
"""

from __future__ import annotations

import argparse
import functools
import os
import tempfile
import threading
import time
import traceback
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI (pospp.cli)

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mcap", nargs="?", default="/tmp/pospp_bench/flight_90min_200hz.mcap")
    ap.add_argument("--pipeline", default=str(REPO / "pipelines" / "flight.toml"))
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    from pospp import diagnosis_stage, passes_ahead, pipeline
    from pospp.config import load_config
    from pospp.nav import filter as nav_filter

    t0 = [0.0]
    rows: list[tuple[str, float, float, str]] = []

    def timed(module, name: str, label: str | None = None) -> None:
        fn = getattr(module, name)

        @functools.wraps(fn)
        def wrapper(*a, **k):
            start = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                what = label or name
                if label == "A":
                    callers = [f.name for f in traceback.extract_stack(limit=6)[:-1]]
                    what = "A < " + " < ".join(reversed(callers[-3:]))
                rows.append((threading.current_thread().name, start - t0[0],
                             time.perf_counter() - t0[0], what))

        setattr(module, name, wrapper)

    timed(nav_filter, "run_integrated_navigation", "A")
    timed(pipeline, "null_stage")
    timed(diagnosis_stage, "diagnose_replays")
    timed(passes_ahead, "quality_checks")
    config = load_config(args.pipeline)
    with tempfile.TemporaryDirectory() as tmp:
        t0[0] = time.perf_counter()
        pipeline.process_flight(args.mcap, config, Path(tmp) / "run", threads=args.threads)
        total = time.perf_counter() - t0[0]
    print(f"{args.mcap}, {args.threads} thread(s): {total:.2f} s\n")
    print("| thread | start [s] | end [s] | [s] | what |\n|---|---:|---:|---:|---|")
    for name, a, b, what in sorted(rows, key=lambda r: r[1]):
        print(f"| {name} | {a:.2f} | {b:.2f} | {b - a:.2f} | {what} |")
    busy: dict[str, float] = {}
    for name, a, b, _ in rows:
        busy[name] = busy.get(name, 0.0) + (b - a)
    print("\n| thread | time in the calls above [s] |\n|---|---:|")
    for name, s in sorted(busy.items()):
        print(f"| {name} | {s:.2f} |")


if __name__ == "__main__":
    main()
