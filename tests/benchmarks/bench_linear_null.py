"""The linear null against the A re-runs it replaces, on one flight (on demand).

    PYTHONPATH=. python tests/benchmarks/bench_linear_null.py [MCAP PIPELINE | --mc SEED ...]
        [--reruns 60]

A as the pipeline runs it (recording its gains), the calibration, then B minus A's null two
ways: the linear null's exact covariance (pospp.calib.linear_null, made also where the
pipeline refuses it: a leg before A's heading converged) and ``--reruns``
realisations of the re-run null (``[pairs] null_reruns``: A re-run on noisy logs), with the
same injected noise. Compared on linear functionals of B minus A: the calibration's estimate
(its gain: gyro bias x, y and every tilt) and, per leg and horizontal channel, the projections
on the first three Legendre polynomials of time. Prints, per functional, the re-runs' sample
sigma over the exact one (a ratio whose own spread is about 1 / sqrt(2 R)), their RMS, and the
likelihood-ratio statistic of "the re-runs' covariance is the exact one" (Bartlett-corrected)
with its p-value (chi-square, p (p + 1) / 2 dof). ``--mc SEED``: the null Monte Carlo's
flight of that seed (tests/unit/test_diagnose_null_mc.py); ``--case NAME``: a reference case,
with the gyro bias's error against the bias it injected (its params.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

sys.path[:0] = [str(Path.cwd()), str(Path.cwd() / "tests" / "unit"),
                str(Path.cwd() / "tests" / "benchmarks")]

from pospp import pipeline  # noqa: E402
from pospp.calib.linear_null import linear_null  # noqa: E402
from pospp.config import load_config  # noqa: E402
from pospp.null_stage import null_noise, null_realisations  # noqa: E402
from pospp.units import DEG_PER_H_RADPS  # noqa: E402


def legendre_weights(model) -> np.ndarray:
    """(6 L, J, 3): per leg and horizontal channel, the projections on Legendre 0-2."""
    rows = []
    start = np.cumsum([0, *model.leg_sizes[:-1]])
    for j0, m in zip(start, model.leg_sizes, strict=True):
        x = np.linspace(-1.0, 1.0, m)
        for c in range(2):
            for deg in range(3):
                w = np.zeros((model.n_samples, 3))
                w[j0:j0 + m, c] = np.polynomial.legendre.legval(x, np.eye(3)[deg]) / m
                rows.append(w)
    return np.array(rows)


def compare(name: str, log, cfg, n_reruns: int, truth_b_radps=None) -> None:
    t0 = time.process_time()
    nav = pipeline.navigate(log, cfg, record_gains=True)
    imu = pipeline.imu_increments(log)
    run, _ = pipeline.calibrate_from_a(imu, nav, cfg)
    assert run.calibrated, run.reason
    c0 = time.process_time()
    # the linear system itself, also where the pipeline would refuse it (a leg before A's
    # heading converged): the comparison shows why it refuses
    model = linear_null(nav.gain_replay, nav.smoothed.trajectory, imu.t_s, imu.w_ib_b_radps,
                        imu.f_ib_b_mps2, [run.replays[i] for i in sorted(run.replays)],
                        null_noise(log, nav, run, cfg))
    t_conv = nav.gain_replay.t_s[nav.gain_replay.k_from]
    early = min(r.t0_s for r in run.replays.values()) < t_conv
    cal = run.chosen
    w_cal = model.fit_weights(cal.leg_ids, cal.gain)
    keep = [i for i, n in enumerate(cal.names) if n.startswith(("gyro_bias", "phi_n", "phi_e"))]
    w = np.concatenate([w_cal[keep], legendre_weights(model)])
    names = [cal.names[i] for i in keep] + [f"leg{k // 6}_{'NE'[(k // 3) % 2]}_P{k % 3}"
                                            for k in range(w.shape[0] - len(keep))]
    exact = model.covariance(w)
    c_lin = time.process_time() - c0
    c0 = time.process_time()
    cfg_r = dataclasses.replace(cfg, pairs=dataclasses.replace(cfg.pairs, null_reruns=True))
    reruns = null_realisations(log, nav, run, cfg_r, n_reruns, seed=7)
    c_rr = time.process_time() - c0
    d = np.stack([np.concatenate(r) for r in reruns])
    f = np.einsum("pja,rja->rp", w, d)
    n, p = f.shape
    s = f.T @ f / n
    ratio = np.sqrt(np.diag(s) / np.diag(exact))
    m = np.linalg.solve(exact, s)
    # Bartlett's correction of the likelihood ratio (known zero mean; Anderson 2003, 10.8)
    bartlett = 1.0 - (2 * p**2 + 3 * p - 1) / (6.0 * n * (p + 1))
    lr = bartlett * n * (np.trace(m) - np.linalg.slogdet(m)[1] - p)
    print(f"\n{name}: {len(run.replays)} legs, {model.n_samples} samples, {n} re-runs"
          f"{' (a leg before A converged: the pipeline takes the re-runs)' if early else ''}; "
          f"A + calibration {c0 - t0 - c_lin:.1f} s CPU, linear null {c_lin:.2f} s, "
          f"re-runs {c_rr:.1f} s")
    for k, i in enumerate(keep):
        if cal.names[i].startswith("gyro_bias"):
            sig = np.sqrt(exact[k, k]) / DEG_PER_H_RADPS
            line = f"  {cal.names[i]}: exact sigma {sig:.4f} deg/h, re-runs' {ratio[k] * sig:.4f}"
            if truth_b_radps is not None:
                err = (cal.x[i] - truth_b_radps["xyz".index(cal.names[i][-1])]) / DEG_PER_H_RADPS
                line += f"; error against the injected {err:+.4f} deg/h ({err / sig:+.2f} sigma)"
            print(line)
    print("  re-runs' sigma / exact: " + ", ".join(f"{nm} {r:.2f}"
                                                    for nm, r in zip(names, ratio, strict=True)))
    print(f"  RMS of the ratios {np.sqrt(np.mean(ratio**2)):.3f} (spread of one: "
          f"{1 / np.sqrt(2 * n):.3f}); LR {lr:.0f} on {p * (p + 1) // 2} dof, "
          f"p = {stats.chi2.sf(lr, p * (p + 1) / 2):.2g}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mcap", nargs="?", default="sample_data/sample_flight.mcap")
    ap.add_argument("pipeline", nargs="?", default="pipelines/sample.toml")
    ap.add_argument("--mc", type=int, nargs="*", default=None)
    ap.add_argument("--reruns", type=int, default=60)
    ap.add_argument("--case", nargs="*", default=None,
                    help="reference cases (../shared/reference_cases; pipelines/flight.toml with "
                         "each one's lever arm): also the error against its injected bias")
    args = ap.parse_args()
    if args.case is not None:
        from bench_diagnose_noise import CASES, case_config

        for name in args.case:
            cfg, params = case_config(name)
            truth = np.radians(np.asarray(params["imu_errors"]["gyro_bias_dph"], float)) / 3600
            compare(name, pipeline.ingest(CASES / f"{name}.mcap", cfg), cfg, args.reruns, truth)
        return
    if args.mc is not None:
        from test_diagnose_null_mc import GRADES, null_flight

        for seed in args.mc:
            _, log, cfg = null_flight(seed)
            compare(f"null Monte Carlo seed {seed} ({GRADES[seed % 3]})", log, cfg, args.reruns)
        return
    cfg = load_config(args.pipeline)
    compare(args.mcap, pipeline.ingest(args.mcap, cfg), cfg, args.reruns)


if __name__ == "__main__":
    main()
