"""How far the compensation modes reach as the gyro drift's correlation time changes (on demand).

    python tests/benchmarks/bench_drift_sensitivity.py [--seeds N] [--kind flight|vehicle]

The Gauss-Markov missions of tests/unit/_gm_mission.py (three 300 s legs, 180 deg turns,
100 Hz; ``paper_flight``: constant [1, -1, 1] deg/h + Gauss-Markov 0.5 deg/h, ARW 0.01
deg/sqrt(h)) with the drift's correlation time set to 100 s, 300 s, 1 h and 10 h, the
calibration's noise model and the filter given that same tau (the matched case). For each
tau and each mode (constant bias, per-leg smoothed drift, oracle = true per-leg mean bias,
causal = A's forward bias estimate fused with the calibrated bias), the median over seeds of
the ratio of B's horizontal error at 300 s before / after, velocity and position, in-sample
(RMS over the three legs of the joint fit) and held out (the last leg, predicted from a fit
of the first two). Seeded (seeds 0..N-1): the table is reproducible. docs/calibration.md
section 9 quotes its output.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "unit")]  # this tree's pospp, the missions
from _gm_mission import MODES, run_modes  # noqa: E402

TAUS_S = (100.0, 300.0, 3600.0, 36000.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--kind", default="flight", choices=("flight", "vehicle"))
    args = ap.parse_args()
    print(f"{args.kind}, seeds 0..{args.seeds - 1}; median ratio before / after at 300 s, "
          "velocity x / position x")
    print(f"| tau | where | before | {' | '.join(MODES)} |")
    print("|---|---|---|" + "---|" * len(MODES))
    with tempfile.TemporaryDirectory() as folder:
        for tau in TAUS_S:
            t0 = time.perf_counter()
            runs = [run_modes(args.kind, seed, Path(folder), gm_tau_s=tau)
                    for seed in range(args.seeds)]
            def med(key: str, runs=runs) -> float:
                return float(np.median([r[key] for r in runs]))

            for where, label in (("in", "in-sample"), ("held", "held out")):
                cells = [f"{med(f'{where}_{m}_v'):.1f}x / {med(f'{where}_{m}_p'):.1f}x"
                         for m in MODES]
                before = f"{med(f'{where}_before_v'):.2f} m/s, {med(f'{where}_before_p'):.0f} m"
                print(f"| {tau:g} s | {label} | {before} | {' | '.join(cells)} |")
            print(f"(tau {tau:g} s: {time.perf_counter() - t0:.0f} s wall)", file=sys.stderr)


if __name__ == "__main__":
    main()
