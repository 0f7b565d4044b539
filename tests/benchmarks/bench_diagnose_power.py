"""Power of the null-calibrated diagnosis and detection limits (issue 12, item 3).

    PYTHONPATH=. python tests/benchmarks/bench_diagnose_power.py limits [--seeds 5]
    PYTHONPATH=. python tests/benchmarks/bench_diagnose_power.py power [--seeds 6]
        [--warmup --n-legs 4] [--leg-s 600] [--crossing --n-legs 4]
    PYTHONPATH=. python tests/benchmarks/bench_diagnose_power.py trigger [--seeds 10]

Flights: tests/unit/test_diagnose_power.py (pospp's simulator, paper_vehicle grade, three
wandering legs at 60 m/s, 1 Hz GNSS, pospp's own A, 6 null realisations, the pipeline's
``diagnose`` with A re-run signatures).

``limits``: per GNSS noise level (horizontal position sigma; vertical twice, velocity half in
m/s) and leg length, null flights (seeds 1..N) into whose B minus A each effect is added at a
grid of sizes through its signature (first order: the signature the workflow itself uses, so
the size is right by construction; this measures what the noise lets through, not whether the
signature is right). The detection limit is the smallest grid size named with its size within
20 % in at least 90 % of the seeds.

``power``: each effect hidden by the simulator itself (GNSS lever arm and time offset, gyro
scale factor, a z gyro bias beyond the grade's, a gravity gradient: pospp.sim.gravity) or in
the IMU samples (accelerometer warm-up) at two sizes, seeds 1..N: how often it is named, and
with its size within 20 % (the vertical drift's against the whole z bias B carries, the
grade's 0.1 deg/h plus the hidden one). ``--warmup`` flies the warm-up mission (first leg 170
s after power-up, a loiter, the later legs after T = 1200 s; test_diagnose_power.profile),
``--crossing`` the gravity gradient's (a box of crossing lines at 40 and 80 m/s),
``--leg-s`` the legs' length.

``trigger``: on flights with another effect hidden (lever arm, GNSS time offset) or none, A's
own gyro scale-factor estimate (``flight_stages.scale_factor_estimate`` at A's lever-arm
estimate) and whether the pipeline would make the scale factor's Gauss-Newton signature
(``flight_stages.scale_factor_start``), and the same for A's warm-up pass
(``flight_stages.warmup_estimate``, ``warmup_start``): how often their Gauss-Newton starts
where no such effect is hidden; with ``--mc``, on the 40 flights of the null Monte Carlo
(tests/unit/test_diagnose_null_mc.py) instead; with ``--warmup`` on the warm-up mission.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "unit")]

import test_diagnose_power as tp  # noqa: E402

from pospp import flight_stages, pipeline  # noqa: E402
from pospp.diagnose import effects as fx  # noqa: E402
from pospp.diagnose.rerun import rerun_signatures  # noqa: E402
from pospp.units import UG_MPS2  # noqa: E402

GRID = {
    "time_offset": (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0),  # ms
    "lever_arm": (0.025, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6),  # m
    "gyro_scale_factor": (12.5, 25.0, 50.0, 100.0, 200.0, 400.0, 800.0),  # ppm (z)
    "accel_bias_change": (25.0, 50.0, 100.0, 200.0, 400.0, 800.0),  # ug (x)
}
DIRECTION = {"time_offset": np.array([1e-3]), "lever_arm": tp.LEVER_DIRECTION,
             "gyro_scale_factor": np.array([0.0, 0.0, 1e-6]),
             "accel_bias_change": np.array([UG_MPS2, 0.0])}
"""SI parameter vector of one display unit of each effect as hidden."""


def null_case(seed: int, gnss_pos_m: float, leg_s: float):
    log, cfg = tp.simulate_flight(None, 0.0, seed, gnss_pos_m=gnss_pos_m, leg_s=leg_s)
    nav = pipeline.navigate(log, cfg, record_gains=pipeline.null_needs_gains(cfg))
    imu = pipeline.imu_increments(log)
    run, ref = pipeline.calibrate_from_a(imu, nav, cfg)
    null = pipeline.null_realisations(log, nav, run, cfg, tp.N_NULL, seed=seed)
    sigs = rerun_signatures(log, nav, run, cfg,
                            navigate=lambda lg, lever_arm_b_m=None: pipeline.navigate(
                                lg, cfg, lever_arm_b_m=lever_arm_b_m))
    return run, ref, imu, cfg, null, sigs


def _diagnose(run, ref, imu, cfg, null, sigs, replays=None):
    from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays

    reps = replays if replays is not None else [run.replays[i] for i in sorted(run.replays)]
    return diagnose_replays(reps, DiagnosisOptions(
        replay_kwargs={"accel_compensation": cfg.replay.accel_compensation},
        base_formulation=cfg.pairs.formulation, base_transition=cfg.pairs.transition,
        noise="gyro_rw",
        gyro_arw_radpsqrts=flight_stages.imu_tuning(cfg).noise().gyro_arw_radpsqrts),
        imu=imu, solution_a=ref, null_dv=null, signatures=sigs)


def limits(seeds: int, cells) -> None:
    print("| GNSS pos sigma (m) | leg (s) | effect | named within 20 % per size (of "
          f"{seeds}) | detection limit |")
    print("|---|---|---|---|---|")
    for gnss, leg_s in cells:
        cases = []
        for s in range(1, seeds + 1):
            t0 = time.time()
            cases.append(null_case(s, gnss, leg_s))
            print(f"  null flight seed {s}: {time.time() - t0:.1f} s", file=sys.stderr)
        for eff, grid in GRID.items():
            counts = []
            for size in grid:
                ok = 0
                for run, ref, imu, cfg, null, sigs in cases:
                    reps = [run.replays[i] for i in sorted(run.replays)]
                    if eff in sigs:
                        sg = sigs[eff]
                    else:
                        sg = fx.signatures(eff, reps, accel_settling_s=tp.ACCEL_SETTLING_S)
                    p = size * DIRECTION[eff]
                    hidden = []
                    for r, s_leg in zip(reps, sg, strict=True):
                        dv = r.dv_n_mps.copy()
                        dv[:, 0:2] += s_leg @ p
                        hidden.append(dataclasses.replace(r, dv_n_mps=dv))
                    d = _diagnose(run, ref, imu, cfg, null, sigs, hidden)
                    if eff in d.named:
                        est = abs(d.step_of(eff).value)
                        ok += abs(est - size) <= 0.2 * size
                counts.append(ok)
            lim = next((g for g, c in zip(grid, counts, strict=True) if c >= 0.9 * seeds),
                       float("nan"))
            print(f"| {gnss} | {leg_s:.0f} | {eff} | "
                  + ", ".join(f"{g:g}: {c}" for g, c in zip(grid, counts, strict=True))
                  + f" | {lim:g} {tp.EFFECT_UNITS[eff]} |", flush=True)


def power(seeds: int, sizes, **mission) -> None:
    print(f"| effect | size | named (of {seeds}) | within 20 % | estimates | conclusions |")
    print("|---|---|---|---|---|---|")
    for eff, size in sizes:
        runs = []
        for s in range(1, seeds + 1):
            t0 = time.time()
            runs.append(tp.power_run(None if eff == "none" else eff, size, s, **mission))
            d = runs[-1].diagnosis
            print(f"    named {d.named}, {eff} read {runs[-1].estimate:.4g}, closing "
                  f"{d.conclusion} (p = {d.steps[-1].p_value:.3g})", file=sys.stderr)
            if eff == "none":
                d = runs[-1].diagnosis
                print(f"  null seed {s}: named {d.named}, closing {d.conclusion} "
                      f"(p = {d.steps[-1].p_value:.3g})", file=sys.stderr)
            print(f"  {eff} {size} seed {s}: {time.time() - t0:.1f} s", file=sys.stderr)
        named = sum(r.named for r in runs)
        ok = sum(r.within_20pct for r in runs)
        est = ", ".join(f"{r.estimate:.3g}" for r in runs)
        concl = ", ".join(f"{c} {sum(r.diagnosis.conclusion == c for r in runs)}"
                          for c in sorted({r.diagnosis.conclusion for r in runs}))
        unit = tp.EFFECT_UNITS.get(eff, "")
        truth = tp.true_size(None if eff == "none" else eff, size)
        tag = f" ({truth:g} in B)" if truth != size else ""
        print(f"| {eff} | {size:g} {unit}{tag} | {named} | {ok} | {est} | {concl} |", flush=True)


TRIGGER_CASES = (("lever_arm", 0.5), ("lever_arm", 1.0), ("lever_arm", 1.5), ("lever_arm", 3.0),
                 ("time_offset", 4.0), ("time_offset", 8.0), ("time_offset", 12.0),
                 ("time_offset", 24.0), ("none", 0.0))


def _triggered(log, cfg) -> tuple[bool, float, bool, float]:
    """(the scale factor's Gauss-Newton started, A's largest axis / sigma, the warm-up's
    started, its pass's |db| in ug, A's gate in excess) on one flight."""
    nav = pipeline.navigate(log, cfg)
    lever = flight_stages.lever_arm_estimate(log, nav, cfg).lever_b_m
    sf, sigma = flight_stages.scale_factor_estimate(log, cfg, lever)
    start = flight_stages.scale_factor_start(log, cfg, lever)
    db = flight_stages.warmup_estimate(log, cfg, lever)
    warm = flight_stages.warmup_start(log, nav, cfg, lever)
    return (start is not None, float(np.max(np.abs(sf) / sigma)), warm is not None,
            float(np.linalg.norm(db)) / UG_MPS2,
            flight_stages.gate_excess(nav, cfg.filter_options().gate_probability))


def _trigger_row(label: str, res: list) -> str:
    return (f"{label} | {sum(r[0] for r in res)} | {max(r[1] for r in res):.1f} | "
            f"{sum(r[4] for r in res)} | {sum(r[2] for r in res)} | "
            f"{max(r[3] for r in res):.0f} |")


def trigger(seeds: int, mc: bool, warmup: bool = False) -> None:
    print(f"| hidden | size | scale factor triggered (of {40 if mc else seeds}) | largest axis "
          "/ sigma | A's gate in excess | warm-up triggered | largest warm-up pass (ug) |")
    print("|---|---|---|---|---|---|---|")
    if mc:
        import test_diagnose_null_mc as tm

        res = [_triggered(*tm.null_flight(s)[1:]) for s in range(40)]
        print(_trigger_row("| none (null Monte Carlo) | -", res))
        return
    for eff, size in TRIGGER_CASES:
        res = [_triggered(*tp.simulate_flight(None if eff == "none" else eff, size, s,
                                              **({"n_legs": 4, "warmup": True} if warmup
                                                 else {})))
               for s in range(1, seeds + 1)]
        print(_trigger_row(f"| {eff} | {size:g} {tp.EFFECT_UNITS.get(eff, '')}", res),
              flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("limits", "power", "trigger"))
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--cells", default="0.05:180,0.5:180,0.05:360",
                    help="GNSS pos sigma [m]:leg length [s], comma-separated")
    ap.add_argument("--sizes", default="time_offset:2,time_offset:6,lever_arm:0.4,"
                    "lever_arm:1.2,gyro_scale_factor:200,gyro_scale_factor:600,"
                    "accel_bias_change:200,accel_bias_change:600",
                    help="effect:size (display unit), comma-separated")
    ap.add_argument("--mc", action="store_true",
                    help="trigger: the null Monte Carlo's 40 flights")
    ap.add_argument("--warmup", action="store_true",
                    help="the warm-up mission (power, trigger)")
    ap.add_argument("--crossing", action="store_true",
                    help="crossing lines at 40 / 80 m/s (power only; the gravity gradient)")
    ap.add_argument("--n-legs", type=int, default=3)
    ap.add_argument("--leg-s", type=float, default=180.0)
    a = ap.parse_args()
    if a.what == "limits":
        cells = [(float(c.split(":")[0]), float(c.split(":")[1])) for c in a.cells.split(",")]
        limits(a.seeds, cells)
    elif a.what == "trigger":
        trigger(a.seeds, a.mc, a.warmup)
    else:
        sizes = [(s.split(":")[0], float(s.split(":")[1])) for s in a.sizes.split(",")]
        power(a.seeds, sizes, warmup=a.warmup, n_legs=a.n_legs, leg_s=a.leg_s,
              crossing=a.crossing)


if __name__ == "__main__":
    main()
