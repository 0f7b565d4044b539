"""The null Monte Carlo with either null (on demand; tests/unit/test_diagnose_null_mc.py's).

    PYTHONPATH=. python tests/benchmarks/bench_null_mc.py [--reruns] [--n-null 10]
        [--seeds 0 40]

The slow test's 40 seeded null flights (three grades, GNSS 0.02-1 m at 1-10 Hz, the whole
diagnosis with the log and A's result), with the linear null (default: A's gains, the re-runs
where a leg starts before A's heading converged) or, ``--reruns``, the A re-runs everywhere
(``[pairs] null_reruns``). Prints one line per seed (grade, closing row, named effects, the
calibrated bias error / sigma x and y, the closing p-value, the
calibration's sigma source, CPU seconds) and the totals: closing rows ``none``, named effects,
error / sigma RMS and the share within 3 sigma, CPU. Two worker processes.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path.cwd()), str(Path.cwd() / "tests" / "unit")]

import test_diagnose_null_mc as mc  # noqa: E402


def one(args: tuple[int, bool, int]) -> tuple:
    seed, reruns, n_null = args
    t0 = time.process_time()
    d, _, z, _, source = mc.null_flight_diagnosis(seed, n_null=n_null, reruns=reruns)
    return (seed, mc.GRADES[seed % 3], d.conclusion, d.named, [float(v) for v in z],
            float(d.steps[-1].p_value), source, time.process_time() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reruns", action="store_true")
    ap.add_argument("--n-null", type=int, default=mc.N_NULL)
    ap.add_argument("--seeds", type=int, nargs=2, default=[0, 40])
    args = ap.parse_args()
    jobs = [(s, args.reruns, args.n_null) for s in range(*args.seeds)]
    with ProcessPoolExecutor(max_workers=2, mp_context=mp.get_context("fork")) as pool:
        rows = list(pool.map(one, jobs))
    for r in rows:
        print(f"seed {r[0]} ({r[1]}): {r[2]}, named {list(r[3])}, z {r[4][0]:+.2f} "
              f"{r[4][1]:+.2f}, p {r[5]:.3g}, {r[6]}, {r[7]:.1f} s CPU")
    z = np.array([r[4] for r in rows])
    linear = [r for r in rows if r[6] == "linear_null"]
    print(f"{'re-run' if args.reruns else 'linear'} null, {args.n_null} realisations: none "
          f"{sum(r[2] == 'none' for r in rows)} / {len(rows)} (on the linear null's "
          f"{len(linear)} flights: {sum(r[2] == 'none' for r in linear)}), named "
          f"{[(r[0], list(r[3])) for r in rows if r[3]]}, error / sigma RMS "
          f"{np.sqrt(np.mean(z**2)):.2f}, within 3 sigma {int(np.sum(np.abs(z) < 3))} / "
          f"{z.size}, CPU {sum(r[7] for r in rows):.0f} s")


if __name__ == "__main__":
    main()
