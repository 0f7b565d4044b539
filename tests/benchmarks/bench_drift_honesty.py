"""Do the calibration's sigmas follow the flight's drift? (issue 16 item 3; on demand)

    PYTHONPATH=. python tests/benchmarks/bench_drift_honesty.py [--seeds N] [--taus 100,300,...]
        [--sigma-dph 0.3] [--null 6] [--reruns]

Simulated flights (tests/unit/test_drift_honesty.py's mission: three 300 s survey legs at
60 m/s joined by 180 deg turns plus one 90 deg off, 50 Hz, ``paper_flight`` errors with the
Gauss-Markov drift replaced by ``--sigma-dph`` and each tau of ``--taus``), GNSS at 1 Hz;
A is pospp's filter + smoother run as the pipeline runs it (``[imu] grade = "flight"``: the
grade's drift 0.5 deg/h, 300 s configured), the calibration, its null realisations and
``with_null_covariance`` as in pospp.pipeline. Prints, per tau, the body x / y bias error
(estimate minus the simulated constant bias) over its sigma: RMS and the share within 3
sigma, and the drift the calibration estimated (level, tau). Run it from a tree to measure
that tree (the before: the same command from a checkout without the flight's drift).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path.cwd()), str(Path.cwd() / "tests" / "unit")]
from test_drift_honesty import drift_flight_z  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--taus", default="100,300,3600,36000")
    ap.add_argument("--sigma-dph", type=float, default=0.3)
    ap.add_argument("--null", type=int, default=6)
    ap.add_argument("--reruns", action="store_true")
    args = ap.parse_args()
    print("| tau [s] | error/sigma RMS | within 3 sigma | against the realised mean: RMS, "
          "within 3 sigma | drift estimate: sigma [deg/h], tau [s] "
          "(median, range) | sigma x [deg/h] (median) |")
    print("|---|---|---|---|---|---|")
    for tau in (float(v) for v in args.taus.split(",")):
        t0 = time.perf_counter()
        rows = [drift_flight_z(s, tau, args.sigma_dph if np.isfinite(tau) else 0.0,
                               n_null=args.null, reruns=args.reruns)
                for s in range(args.seed0, args.seed0 + args.seeds)]
        z = np.array([r["z"] for r in rows])
        zm = np.array([r["z_mean"] for r in rows])
        for r in rows:
            print(f"  seed {r['seed']}: z {r['z'][0]:+.2f} {r['z'][1]:+.2f}, err "
                  f"{r['err_dph'][0]:+.3f} {r['err_dph'][1]:+.3f} deg/h (realised mean "
                  f"{r['err_mean_dph'][0]:+.3f} {r['err_mean_dph'][1]:+.3f}), sigma "
                  f"{r['sigma_dph'][0]:.3f}, drift {r['drift_sigma_dph']:.3f} deg/h "
                  f"{r['drift_tau_s']:.0f} s ({r['drift_source']})", file=sys.stderr)
        ds = [r["drift_sigma_dph"] for r in rows]
        dt = [r["drift_tau_s"] for r in rows]
        print(f"| {tau:g} | {np.sqrt(np.mean(z**2)):.2f} | {np.mean(np.abs(z) < 3):.0%} "
              f"({int(np.sum(np.abs(z) < 3))}/{z.size}) | {np.sqrt(np.mean(zm**2)):.2f}, "
              f"{int(np.sum(np.abs(zm) < 3))}/{zm.size} | {np.median(ds):.3f} "
              f"({min(ds):.3f}-{max(ds):.3f}), {np.median(dt):.0f} ({min(dt):.0f}-{max(dt):.0f})"
              f" | {np.median([r['sigma_dph'][0] for r in rows]):.3f} |", flush=True)
        print(f"(tau {tau:g} s: {time.perf_counter() - t0:.0f} s wall)", file=sys.stderr)


if __name__ == "__main__":
    main()
