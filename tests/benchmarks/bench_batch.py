"""Benchmark of an archive: N sample-size flights through ``pospp batch -j 1`` and ``-j 2``.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_batch.py [--flights 20] [--workers 1 2] [--threads N]

The archive is ``--flights`` copies (symbolic links, each its own run folder) of the bundled
sample flight (27 min at 100 Hz, 4 legs) in /tmp/pospp_bench_batch. Each ``pospp batch`` runs
in a fresh process into an empty root with pipelines/sample.toml; numba's cache is warm (one
untimed ``import pospp.pipeline`` first). Per flight the manifest's ``duration_s`` is the
worker's time in ``process_one`` (hash, pipeline, report); the batch's overhead is what the
wall time adds to that: start-up, imports and compiled-cache loading (once per process: the
pool's workers are reused), the manifest. One ``pospp run`` of the same flight gives the
single-flight overhead (its wall time minus the summary's ``wall_time_s``). CPU time (user +
system of the batch process and its pool workers, which is what the load of the shared
machine does not change much) is shown beside the wall time: with the same CPU per flight at
``-j 2`` as at ``-j 1``, two free cores give twice the throughput. Prints markdown for
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parents[2]
WORK = Path("/tmp/pospp_bench_batch")
SAMPLE = REPO / "sample_data" / "sample_flight.mcap"
PIPELINE = REPO / "pipelines" / "sample.toml"


def _env() -> dict[str, str]:
    return {**os.environ, "OPENBLAS_NUM_THREADS": "1"}


def _archive(n: int) -> Path:
    folder = WORK / f"archive_{n}"
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        link = folder / f"flight_{i:02d}.mcap"
        if not link.exists():
            link.symlink_to(SAMPLE)
    return folder


_CPU = [0.0]
"""CPU time [s] (user + system) of the last command timed, its pool workers included (the
children's usage accrues to the batch process when it waits for them, then to us)."""


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _timed(cmd: list[str]) -> float:
    c0 = _children_cpu_s()
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=REPO, env=_env(), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    _CPU[0] = _children_cpu_s() - c0
    if res.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)} failed ({res.returncode}): {res.stderr[-2000:]}")
    return wall


def single_run() -> tuple[float, float]:
    """(wall of ``pospp run`` from outside, the run's own summary wall_time_s)."""
    out = WORK / "single"
    wall = _timed([sys.executable, "-m", "pospp.cli", "run", str(SAMPLE), "-p", str(PIPELINE),
                   "-o", str(out), "--force"])
    inner = float(pd.read_parquet(out / "summary.parquet").wall_time_s.iloc[0])
    return wall, inner


def batch(archive: Path, workers: int, threads: str = "auto") -> tuple[float, pd.DataFrame]:
    out = WORK / f"out_j{workers}"
    shutil.rmtree(out, ignore_errors=True)
    wall = _timed([sys.executable, "-m", "pospp.cli", "batch", str(archive), "-p",
                   str(PIPELINE), "-o", str(out), "-j", str(workers),
                   *(() if threads == "auto" else ("--threads", threads))])
    return wall, pd.read_parquet(out / "manifest.parquet")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=20)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--threads", default="auto",
                    help="pospp batch --threads (auto: the cores shared out among the workers)")
    args = ap.parse_args()
    subprocess.run([sys.executable, "-c", "import pospp.pipeline"], cwd=REPO, env=_env(),
                   check=True)
    archive = _archive(args.flights)
    load = lambda: " ".join(f"{x:.1f}" for x in os.getloadavg())  # noqa: E731
    wall, inner = single_run()
    print(f"single `pospp run`: wall {wall:.2f} s, CPU {_CPU[0]:.2f} s, summary wall_time_s "
          f"{inner:.2f} s, start-up + imports + cache loading + console {wall - inner:.2f} s "
          f"(load average {load()})")
    print()
    print("| workers | flights | wall [s] | flights/min | vs -j 1 | median flight in worker [s] "
          "| sum in workers [s] | overhead [s] | CPU [s] | CPU per flight [s] | "
          "load average after |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    base = None
    for j in args.workers:
        wall, manifest = batch(archive, j, args.threads)
        n_ok = int((manifest.status != "failed").sum())
        rate = 60.0 * n_ok / wall
        base = base or rate
        per = manifest.duration_s.to_numpy(dtype=float)
        overhead = wall - per.sum() / j
        print(f"| {j} | {n_ok}/{len(manifest)} | {wall:.1f} | {rate:.2f} | {rate / base:.2f}x "
              f"| {statistics.median(per):.2f} | {per.sum():.1f} | {overhead:.1f} | "
              f"{_CPU[0]:.1f} | {_CPU[0] / max(1, n_ok):.2f} | {load()} |")


if __name__ == "__main__":
    main()
