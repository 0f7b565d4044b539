"""Benchmark of the bundled sample run: ``pospp run`` wall and CPU, and each stage's time.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_sample.py [--repeat 3] [--null 10 0] [--threads 1 2]
        [--methods linear rerun]

``pospp run sample_data/sample_flight.mcap -p pipelines/sample.toml -o /tmp/... --force`` in a
fresh process each time (numba's cache warm: one untimed run first), with ``[pairs]
null_realisations`` set to each ``--null`` value and ``null_reruns`` to each ``--methods``
(``linear``: the null from A's gains, ``rerun``: from A re-runs; a copy of the pipeline file),
so that the null's share shows; the settings' runs interleaved (one of each, then again).
Per run: the command's wall time from outside, its CPU time (user + system of the child, from
``wait4``), the summary's ``wall_time_s`` (``pipeline.process_flight`` only: start-up and
imports are the difference) and every ``stage_<name>_s`` column. Best run (by CPU) per
setting; the load average beside it. Prints markdown for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_data" / "sample_flight.mcap"
PIPELINE = REPO / "pipelines" / "sample.toml"


def _pipeline(n_null: int, folder: Path, method: str = "linear") -> Path:
    text = PIPELINE.read_text()
    reruns = "true" if method == "rerun" else "false"
    text = re.sub(r"\[pairs\]\n",
                  f"[pairs]\nnull_realisations = {n_null}\nnull_reruns = {reruns}\n", text,
                  count=1)
    out = folder / f"sample_null{n_null}_{method}.toml"
    out.write_text(text)
    return out


def _one(pipeline: Path, out: Path, threads: str = "auto") -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "pospp.cli", "run", str(SAMPLE), "-p", str(pipeline), "-o",
           str(out), "--force", *(() if threads == "auto" else ("--threads", threads))]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)} failed")
    s = pd.read_parquet(out / "summary.parquet").iloc[0]
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "peak_mib": usage.ru_maxrss / 1024, "run_s": float(s.wall_time_s),
            "stages": {k[6:-2]: float(v) for k, v in s.items() if k.startswith("stage_")},
            "load": os.getloadavg()[0]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--null", type=int, nargs="+", default=[10, 0])
    ap.add_argument("--threads", nargs="+", default=["auto"],
                    help="pospp run --threads values (auto: the process's cores)")
    ap.add_argument("--methods", nargs="+", default=["linear"], choices=["linear", "rerun"])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        _one(PIPELINE, folder / "warm")  # numba's cache, page cache
        settings = [(n, t, m) for n in args.null for t in args.threads for m in args.methods]
        runs: dict = {k: [] for k in settings}
        for _ in range(args.repeat):  # interleaved: the load drifts alike for every setting
            for n_null, threads, method in settings:
                runs[(n_null, threads, method)].append(_one(
                    _pipeline(n_null, folder, method), folder / f"run_{n_null}", threads))
        rows = []
        for (n_null, threads, method), rs in runs.items():
            best = min(rs, key=lambda r: r["cpu_s"])
            best["null"] = f"{n_null} {method}, threads {threads}"
            best["walls"] = " / ".join(f"{r['wall_s']:.1f}" for r in rs)
            rows.append(best)
    stages = list(dict.fromkeys(k for r in rows for k in r["stages"]))
    print("| null realisations, threads | command wall [s] (runs) | CPU [s] | run() [s] | start-up "
          "[s] | " + " | ".join(stages) + " | peak RSS [MiB] | load |")
    print("|---:|---|---:|---:|---:|" + "---:|" * len(stages) + "---:|---:|")
    for r in rows:
        print(f"| {r['null']} | {r['wall_s']:.1f} ({r['walls']}) | {r['cpu_s']:.1f} | "
              f"{r['run_s']:.1f} | {r['wall_s'] - r['run_s']:.1f} | "
              + " | ".join(f"{r['stages'].get(k, float('nan')):.2f}" for k in stages)
              + f" | {r['peak_mib']:.0f} | {r['load']:.1f} |")


if __name__ == "__main__":
    main()
