"""Benchmark of the whole ``pospp run``: wall time, CPU time and peak memory versus duration.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_pipeline.py [--minutes 15 45 90] [--rate-hz 200] [--threads N]
        [--methods linear rerun] [--repeat 2]

For each duration, the ``flight`` preset (paper_flight IMU, 1 Hz GNSS 0.05/0.1 m,
0.02/0.03 m/s) is simulated once into /tmp/pospp_bench (cached), then the pipeline runs in a
fresh process (so its peak RSS is its own): ingest, A forward + smoother, legs, every B replay,
pairs, calibration, B re-run, A re-run with the calibrated bias, diagnosis, all tables, the
trajectory MCAP and the HTML report. Numba's cache is warm (the first untimed call compiles).
Results go to stdout as a markdown table for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CACHE = Path("/tmp/pospp_bench")

_CHILD = r"""
import json, sys, time
s0 = time.perf_counter(); sc0 = time.process_time()
from pospp import pipeline
from pospp.config import load_config
def hwm_mib():
    # the process's peak resident set so far (VmHWM), MiB; not getrusage's ru_maxrss, which
    # a child keeps from its parent across fork and exec (a parent that simulated a long
    # flight first reported its own 1.8 GiB as the run's)
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
imports = {"wall_s": time.perf_counter() - s0, "cpu_s": time.process_time() - sc0,
           "peak_rss_mib": hwm_mib()}
t0 = time.perf_counter(); c0 = time.process_time()
stages, stages_cpu, stages_hwm = {}, {}, {}
last = [t0, None, c0]
def progress(stage, frac):
    now, cpu = time.perf_counter(), time.process_time()
    if last[1] is not None:
        stages[last[1]] = stages.get(last[1], 0.0) + now - last[0]
        stages_cpu[last[1]] = stages_cpu.get(last[1], 0.0) + cpu - last[2]
        stages_hwm[last[1]] = hwm_mib()  # peak so far, read when the stage ends
    last[0], last[1], last[2] = now, stage, cpu
out = pipeline.process_flight(sys.argv[1], load_config(sys.argv[2]), sys.argv[3], progress=progress,
                   force=True, threads=int(sys.argv[4]) if sys.argv[4] != "auto" else None)
progress(None, 1.0)
print(json.dumps({"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                  "peak_rss_mib": hwm_mib(),
                  "n_imu": out.summary["n_imu_samples"], "n_legs": out.summary.get("n_legs"),
                  "status": out.status, "stages_s": stages, "stages_cpu_s": stages_cpu,
                  "stages_peak_rss_mib": stages_hwm, "imports": imports,
                  "summary_wall_s": out.summary.get("wall_time_s")}))
"""


def _simulate(minutes: float, rate_hz: float) -> Path:
    path = CACHE / f"flight_{minutes:g}min_{rate_hz:g}hz.mcap"
    if path.is_file():
        return path
    from pospp.io.simulation_files import write_simulation
    from pospp.sim.api import simulate

    t0 = time.perf_counter()
    sim = simulate("flight", imu_grade="paper_flight", seed=7, imu_rate_hz=rate_hz,
                   duration_s=minutes * 60.0)
    t1 = time.perf_counter()
    write_simulation(sim, CACHE, path.stem)
    print(f"  simulated {minutes:g} min at {rate_hz:g} Hz in {t1 - t0:.1f} s, written in "
          f"{time.perf_counter() - t1:.1f} s", file=sys.stderr)
    return path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, nargs="+", default=[15.0, 45.0, 90.0])
    ap.add_argument("--rate-hz", type=float, default=200.0)
    ap.add_argument("--pipeline", default=str(REPO / "pipelines" / "flight.toml"))
    ap.add_argument("--threads", default="auto",
                    help="pospp run --threads (A re-runs at once); auto: the process's cores")
    ap.add_argument("--methods", nargs="+", default=["linear"], choices=["linear", "rerun"],
                    help="the null: from A's gains, or from A re-runs ([pairs] null_reruns)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs per method, interleaved (one of each, then again)")
    args = ap.parse_args()
    CACHE.mkdir(parents=True, exist_ok=True)
    # as the CLI does (pospp/cli.py): one OpenBLAS thread
    env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    pipelines = {m: _with_null_method(Path(args.pipeline), m) for m in args.methods}
    rows = []
    for minutes in args.minutes:
        mcap = _simulate(minutes, args.rate_hz)
        out = CACHE / f"run_{mcap.stem}"
        # warm numba's on-disk cache once (not timed)
        if not rows:
            subprocess.run([sys.executable, "-c", _CHILD, str(mcap), args.pipeline, str(out),
                            args.threads], check=True, capture_output=True, env=env)
        for _, method in [(k, m) for k in range(args.repeat) for m in args.methods]:
            res = subprocess.run([sys.executable, "-c", _CHILD, str(mcap), pipelines[method],
                                  str(out), args.threads], check=True, capture_output=True,
                                 text=True, env=env)
            _row(rows, json.loads(res.stdout.strip().splitlines()[-1]), minutes, method,
                 args.rate_hz)
    _print(rows)


def _with_null_method(pipeline: Path, method: str) -> str:
    """A copy of the pipeline file with ``[pairs] null_reruns`` set for ``method``."""
    text = pipeline.read_text()
    line = f"null_reruns = {'true' if method == 'rerun' else 'false'}\n"
    text = text.replace("[pairs]\n", "[pairs]\n" + line, 1) if "[pairs]\n" in text \
        else text + "\n[pairs]\n" + line
    out = CACHE / f"{pipeline.stem}_{method}.toml"
    out.write_text(text)
    return str(out)


def _row(rows: list, r: dict, minutes: float, method: str, rate_hz: float) -> None:
    """Label one run's result and keep it."""
    r["method"] = method
    # the simulator's flight mission ends at 137.5 min: a longer request gets the whole
    # mission, labelled by what was flown
    r["minutes"] = round(r["n_imu"] / rate_hz / 60.0, 1)
    if r["minutes"] < minutes - 0.1:
        print(f"  asked for {minutes:g} min: the mission ends at {r['minutes']:g} min",
              file=sys.stderr)
    rows.append(r)
    print(f"  {r['minutes']:g} min, {method} null: {r['wall_s']:.1f} s wall, "
          f"{r['cpu_s']:.1f} s CPU, {r['peak_rss_mib']:.0f} MiB, {r['n_legs']} legs, "
          f"{r['status']}", file=sys.stderr)


def _print(rows: list) -> None:
    """The runs as markdown tables, then as JSON."""
    print("| duration | null | IMU epochs | legs | wall [s] | CPU [s] | wall per epoch [us] | "
          "peak RSS [MiB] | slowest stages [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        top = sorted(r["stages_s"].items(), key=lambda kv: -kv[1])[:3]
        stages = ", ".join(f"{k} {v:.1f}" for k, v in top)
        print(f"| {r['minutes']:g} min | {r['method']} | {r['n_imu']} | {r['n_legs']} | "
              f"{r['wall_s']:.1f} | "
              f"{r['cpu_s']:.1f} | {1e6 * r['wall_s'] / r['n_imu']:.1f} | "
              f"{r['peak_rss_mib']:.0f} | {stages} |")
    print()
    print("Per stage: wall / CPU [s], peak RSS of the process at the stage's end [MiB] "
          "(imports: before pipeline.process_flight)")
    names = list(dict.fromkeys(k for r in rows for k in r["stages_s"]))
    print("| duration | null | imports | " + " | ".join(names) + " |")
    print("|---|---|---|" + "---|" * len(names))
    for r in rows:
        imp = r["imports"]
        cells = [f"{r['stages_s'].get(k, 0):.2f} / {r['stages_cpu_s'].get(k, 0):.2f}, "
                 f"{r['stages_peak_rss_mib'].get(k, 0):.0f}" for k in names]
        print(f"| {r['minutes']:g} min | {r['method']} | {imp['wall_s']:.2f} / "
              f"{imp['cpu_s']:.2f}, "
              f"{imp['peak_rss_mib']:.0f} | " + " | ".join(cells) + " |")
    print()
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
