"""The drift grid: the compensation modes' reach, in-sample and held out, and both sigmas.

    python tests/benchmarks/bench_drift_grid.py [--seeds N] [--null R]

pospp's simulator drift grid (tests/reference/_reach.py: a survey flight of five 300 s lines,
``paper_flight`` errors with a 0.3 deg/h Gauss-Markov gyro drift of tau 100 s, 300 s, 1 h,
10 h, or none), through the pipeline's stages (``pipelines/flight.toml``: A, legs, B, the fit
with the drift from the flight, ``R`` null realisations). Per tau, over seeds 0..N-1:

- B's reach at 300 s, ratio of the medians over the legs before / after, velocity x /
  position x, for the constant, causal and smoothed compensations (median over seeds):
  in-sample (every leg in the joint fit) and held out (the fit on the middle three legs, the
  reach on the first and last: back and ahead);
- error / sigma RMS (x and y, all seeds) of the turn-on constant against the simulated
  constant and of the flight's gyro bias against the realised mean gyro error over the
  fitted legs (constant, drift and white noise), each with its own sigma.

docs/calibration.md quotes the table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "reference")]  # this tree's pospp, _reach
import _reach  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--null", type=int, default=10)
    args = ap.parse_args()
    modes = " | ".join(_reach.MODES)
    print(f"| tau | where | {modes} | error/sigma RMS: turn-on constant, flight's bias "
          "(x and y) |")
    print("|---|---|" + "---|" * len(_reach.MODES) + "---|")
    for tau in _reach.GRID_TAUS_S:
        t0 = time.perf_counter()
        runs = [_reach.grid_flight(tau, seed, n_null=args.null)
                for seed in range(args.seeds)]
        for r, seed in zip(runs, range(args.seeds), strict=True):
            print(f"  tau {tau} seed {seed}: {r['source']}, drift {r['drift_dph']:.3f} "
                  f"deg/h {r['drift_tau_s']:.0f} s; constant err {r['err_const_dph']} "
                  f"sigma {r['sigma_const_dph']}; flight err {r['err_flight_dph']} sigma "
                  f"{r['sigma_flight_dph']}", file=sys.stderr)
        zc = np.concatenate([r["z_const"] for r in runs])
        zf = np.concatenate([r["z_flight"] for r in runs])
        label = "none" if tau is None else f"{tau:g} s"
        for where, text in (("in", "in-sample"), ("held", "held out")):
            cells = []
            for m in _reach.MODES:
                v = np.median([r[where][m][0] for r in runs])
                p = np.median([r[where][m][1] for r in runs])
                cells.append(f"{v:.1f}x / {p:.1f}x")
            rms = (f"{np.sqrt(np.mean(zc**2)):.2f}, {np.sqrt(np.mean(zf**2)):.2f}"
                   if where == "in" else "")
            print(f"| {label} | {text} | " + " | ".join(cells) + f" | {rms} |", flush=True)
        print(f"(tau {label}: {time.perf_counter() - t0:.0f} s wall)", file=sys.stderr)


if __name__ == "__main__":
    main()
