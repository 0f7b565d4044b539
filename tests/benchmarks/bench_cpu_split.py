"""Where one ``pospp run``'s CPU goes, on one thread and without a profiler: every compiled A
pass (its IMU epochs, states, whether it replays another pass's gains, its CPU) and the
inclusive CPU of the pipeline's main functions.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_cpu_split.py [MCAP] [--pipeline P]

Default MCAP: the 1.5 h, 200 Hz flight of bench_pipeline.py (/tmp/pospp_bench, made by
``python tests/benchmarks/bench_pipeline.py --minutes 90`` once). The functions are wrapped
with a timer (``time.thread_time``; one thread, so the run's CPU is the main thread's): a
profiler such as cProfile inflates Python-heavy code several times over (the trajectory
MCAP's messages: 0.97 s under cProfile, 0.24 s without) and would mislead. Numba's cache must
be warm (one run first). Results: docs/history/speed_rounds.md, "Speed, eleventh round".
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI (pospp.cli)

REPO = Path(__file__).resolve().parents[2]
FUNCTIONS = (
    "pospp.flight_stages:ingest", "pospp.flight_stages:navigate",
    "pospp.flight_stages:calibration_replays", "pospp.flight_stages:calibrate_from_a",
    "pospp.null_stage:null_base", "pospp.null_stage:null_realisations",
    "pospp.null_stage:linear_null_model", "pospp.null_stage:with_null_sigmas",
    "pospp.flight_stages:lever_arm_passes", "pospp.flight_stages:scale_factor_estimate",
    "pospp.diagnosis_stage:rerun_base", "pospp.diagnosis_stage:diagnosis_reruns",
    "pospp.diagnose.workflow:diagnose_replays", "pospp.calib.solve:fit_calibration",
    "pospp.nav.filter:run_integrated_navigation",
    "pospp.nav.filter_state:forward_pass", "pospp.nav.filter_state:smoothed_backward",
    "pospp.io.trajectory_mcap:trajectory_messages", "pospp.qc.stage:quality_checks",
    "pospp.pipeline:report_from_tables",
)


def _wrap_everywhere(spec: str, totals: dict) -> None:
    """Replace the function in its module and in every pospp module that imported it."""
    modname, name = spec.split(":")
    orig = getattr(importlib.import_module(modname), name)

    @functools.wraps(orig)
    def timed(*a, **k):
        c0, t0 = time.thread_time(), time.perf_counter()
        try:
            return orig(*a, **k)
        finally:
            row = totals[f"{modname.rsplit('.', 1)[-1]}.{name}"]
            row[0] += 1
            row[1] += time.thread_time() - c0
            row[2] += time.perf_counter() - t0

    for mod in list(sys.modules.values()):
        if getattr(mod, "__name__", "").startswith("pospp") and getattr(mod, name, None) is orig:
            setattr(mod, name, timed)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mcap", nargs="?", default="/tmp/pospp_bench/flight_90min_200hz.mcap")
    ap.add_argument("--pipeline", default=str(REPO / "pipelines" / "flight.toml"))
    args = ap.parse_args()

    from pospp import pipeline
    from pospp.config import load_config
    from pospp.nav import filter_state

    passes: list[tuple[int, int, bool, float]] = []
    kernel = filter_state.forward_kernel

    def counted_kernel(*a):
        c0 = time.thread_time()
        out = kernel(*a)
        t, k0, p0, replay_from = a[0], a[3], a[5], a[19]
        passes.append((t.shape[0] - k0, p0.shape[0], replay_from >= 0, time.thread_time() - c0))
        return out

    filter_state.forward_kernel = counted_kernel
    totals: dict = defaultdict(lambda: [0, 0.0, 0.0])
    for spec in FUNCTIONS:
        _wrap_everywhere(spec, totals)
    config = load_config(args.pipeline)
    with tempfile.TemporaryDirectory() as tmp:
        c0, t0 = time.process_time(), time.perf_counter()
        pipeline.process_flight(args.mcap, config, Path(tmp) / "run", threads=1)
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    print(f"{args.mcap}, one thread: {wall:.2f} s wall, {cpu:.2f} s CPU\n")
    print("| A pass | IMU epochs | states | replays gains | kernel CPU [s] | [us / epoch] |")
    print("|---:|---:|---:|---|---:|---:|")
    for i, (n, states, rep, c) in enumerate(passes, 1):
        print(f"| {i} | {n} | {states} | {'yes' if rep else 'no'} | {c:.3f} | "
              f"{c / max(n, 1) * 1e6:.2f} |")
    print(f"\nall A kernels: {sum(p[3] for p in passes):.2f} s CPU\n")
    print("| function (inclusive) | calls | CPU [s] | wall [s] |\n|---|---:|---:|---:|")
    for name, (n, c, w) in sorted(totals.items(), key=lambda kv: -kv[1][1]):
        print(f"| {name} | {n} | {c:.3f} | {w:.3f} |")


if __name__ == "__main__":
    main()
