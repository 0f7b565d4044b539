"""False-alarm rate and detection power of the QC checks (docs/qc.md), by seeded Monte Carlo.

    python tests/benchmarks/bench_qc.py clean [N_SEEDS]   # clean short flights, every grade
    python tests/benchmarks/bench_qc.py faults [N_SEEDS]  # issue 13's faults, a few seeds
    python tests/benchmarks/bench_qc.py model_fit [N_SEEDS]  # the diagnosis's check (issue 34)

A clean flight is simulated by pospp's simulator (:func:`pospp.sim.api.simulate`): an optional
static start, a take-off, a straight line, a 180 deg turn and the line back (a few minutes),
with the IMU grade, GNSS rate and noise of the case and the lever arm configured right. Then
algorithm A and ``pipeline.quality_control`` (no calibration) run on it, in memory. A false
alarm is a failed check on such a flight. Cases are drawn from a seeded grid (grade x GNSS
rate x GNSS noise x static start) so a run of N seeds covers it evenly.

``model_fit``: the same cases with three 180 s lines (legs from 120 s, the horizon 180 s), the
calibration, the null realisations (6), the diagnosis with the log and A (the sensor families
on A's innovations included), the refit and the ``model_fit`` check as ``pospp run`` makes
them: its false alarms on clean flights (issue 34: at most 2 %).
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from pospp import pipeline  # noqa: E402
from pospp.calib.null_covariance import with_null_covariance  # noqa: E402
from pospp.config import PipelineConfig, config_from_dict  # noqa: E402
from pospp.io.mcap_reader import FlightLog  # noqa: E402
from pospp.sim.api import simulate  # noqa: E402
from pospp.sim.gnss import GnssModel  # noqa: E402
from pospp.sim.profile import parse_profile  # noqa: E402

GRADES = {"paper_flight": "flight", "paper_vehicle": "vehicle", "tactical": "tactical",
          "mems": "mems"}
"""Simulator grade -> pipeline [imu] grade."""
GNSS_NOISE = (((0.02, 0.04), (0.01, 0.02)), ((0.3, 0.6), (0.1, 0.15)), ((1.0, 2.0), (0.5, 0.5)))
"""(horizontal, vertical) position [m] and velocity [m/s] sigmas: 0.02 m / 0.01 m/s to 1 m /
0.5 m/s."""
GNSS_RATES_HZ = (1.0, 5.0, 10.0)
LEVER_B_M = (0.3, 0.1, -1.5)


def profile(static_s: float, line_s: float = 60.0, n_lines: int = 2):
    """Static start (or none), take-off to 50 m/s, a line, a 180 deg turn, the line back (and
    ``n_lines`` - 2 more lines, each after a 180 deg turn)."""
    seg = [{"type": "static", "duration_s": static_s}] if static_s > 0 else []
    seg += [{"type": "accelerate", "to_speed_mps": 50.0, "duration_s": 40.0},
            {"type": "climb", "rate_mps": 5.0, "delta_m": 100.0},
            {"type": "straight", "duration_s": line_s}]
    for _ in range(n_lines - 1):
        seg += [{"type": "turn", "angle_deg": 180.0, "rate_dps": 3.0},
                {"type": "straight", "duration_s": line_s}]
    return parse_profile({"name": "qc_mc", "start": {"lat_deg": 40.0, "lon_deg": 116.0,
                                                     "height_m": 60.0, "heading_deg": 60.0},
                          "options": {"turn_bank": "coordinated", "blend_s": 5.0},
                          "segment": seg})


def case(i: int) -> dict:
    """The i-th clean case: grade i % 4, static start (i // 4) % 2, GNSS noise, GNSS rate and
    IMU rate (50 or 100 Hz) drawn by a generator seeded with i."""
    rng = np.random.default_rng(i)
    return {"grade": tuple(GRADES)[i % 4], "noise": GNSS_NOISE[rng.integers(3)],
            "rate_hz": GNSS_RATES_HZ[rng.integers(3)],
            "static_s": 150.0 if (i // 4) % 2 else 0.0,
            "imu_rate_hz": (50.0, 100.0)[rng.integers(2)], "seed": 1000 + i}


def config_for(grade: str, lever_b_m=LEVER_B_M) -> PipelineConfig:
    return config_from_dict({"input": {"sensor_frame": "frd"},
                             "imu": {"grade": GRADES[grade]},
                             "gnss": {"lever_arm_m": list(lever_b_m)},
                             "outputs": {"mcap": False, "report": False, "diagnose": False}})


def clean_log(c: dict, line_s: float = 60.0, n_lines: int = 2) -> FlightLog:
    """The simulated flight of case ``c`` as a FlightLog (body FRD, in memory)."""
    gnss = GnssModel(rate_hz=c["rate_hz"], pos_noise_m=c["noise"][0],
                     vel_noise_mps=c["noise"][1], lever_arm_b_m=LEVER_B_M,
                     time_offset_s=c.get("time_offset_s", 0.0))
    sim = simulate(profile(c["static_s"], line_s, n_lines), imu_grade=c["grade"], gnss=gnss,
                   seed=c["seed"], imu_rate_hz=c["imu_rate_hz"])
    return FlightLog(sim.imu, sim.fix, sim.vel, path=f"sim:{c['seed']}")


def qc_of(log: FlightLog, cfg: PipelineConfig):
    nav = pipeline.navigate(log, cfg)
    return pipeline.quality_control(log, nav, None, cfg)


def false_alarms(seeds: range) -> tuple[Counter, int, list]:
    """Failed checks per name over clean cases ``seeds``; runs with any failure; details."""
    per_check: Counter = Counter()
    any_fail = 0
    detail = []
    for i in seeds:
        c = case(i)
        try:
            rep = qc_of(clean_log(c), config_for(c["grade"]))
        except ValueError as exc:  # algorithm A refused the flight: not a QC verdict
            detail.append((c, str(exc)))
            continue
        names = [x.name for x in rep.failed]
        per_check.update(names)
        any_fail += bool(names)
        detail.append((c, rep))
    return per_check, any_fail, detail


def model_fit_of(c: dict):
    """The ``model_fit`` check of case ``c`` flown with 180 s lines (None: no calibration or
    diagnosis), and the diagnosis."""
    from pospp.diagnosis_stage import refit_and_check

    cfg = config_from_dict({**config_for(c["grade"]).to_dict(),
                            "legs": {"min_duration_s": 120.0, "min_speed_mps": 20.0},
                            "replay": {"reference": "smoothed", "horizon_s": 180.0},
                            "pairs": {"null_realisations": 6}})
    log = clean_log(c, 180.0, 3)
    nav = pipeline.navigate(log, cfg)
    imu = pipeline.imu_increments(log)
    run, ref = pipeline.calibrate_from_a(imu, nav, cfg)
    if not run.calibrated:
        return None, run.reason
    null = pipeline.null_realisations(log, nav, run, cfg, 6, seed=c["seed"])
    run = with_null_covariance(run, null)
    d = pipeline.diagnose_calibration(run, imu, ref, cfg, log=log, nav=nav, null_dv=null)
    return refit_and_check(log, run, d, imu, ref, cfg, compensate=False).checks[0], d


def model_fit_alarms(seeds: range) -> None:
    """The model_fit check over clean cases ``seeds`` (printed per case and in total)."""
    n = alarms = 0
    for i in seeds:
        c = case(i)
        try:
            check, d = model_fit_of(c)
        except ValueError as exc:  # algorithm A refused the flight: not a QC verdict
            print(f"  seed {c['seed']} {c['grade']}: A failed: {exc}", flush=True)
            continue
        if check is None:
            print(f"  seed {c['seed']} {c['grade']}: no calibration ({d})", flush=True)
            continue
        n += 1
        alarms += not check.passed
        print(f"  seed {c['seed']} {c['grade']} {c['rate_hz']} Hz {c['noise'][0]}: named "
              f"{d.named}, closing {d.conclusion} (p = {d.steps[-1].p_value:.3g}); model_fit "
              f"{'passed' if check.passed else 'FAILED: ' + check.suggestion}", flush=True)
    print(f"model_fit false alarms over {n} clean runs: {alarms} ({alarms / max(n, 1):.1%})")


def _late(log: FlightLog, s: float) -> FlightLog:
    dt = np.int64(round(s * 1e9))
    return replace(log, fix=replace(log.fix, time_ns=log.fix.time_ns + dt),
                   vel=replace(log.vel, time_ns=log.vel.time_ns + dt))


def _jump(log: FlightLog) -> FlightLog:
    t = (log.fix.time_ns - log.imu.time_ns[0]) * 1e-9
    mid = 0.5 * float(t[-1])
    return replace(log, fix=replace(log.fix, lat_rad=log.fix.lat_rad
                                    + np.where(t > mid, 5000.0 / 6.37e6, 0.0)))


def _flu(log: FlightLog) -> FlightLog:  # an FLU IMU read as FRD: y and z flipped
    flip = np.array([1.0, -1.0, -1.0])
    return replace(log, imu=replace(log.imu, w_ib_b_radps=log.imu.w_ib_b_radps * flip,
                                    f_ib_b_mps2=log.imu.f_ib_b_mps2 * flip))


def _truncate(log: FlightLog) -> FlightLog:  # what the reader reports for a cut-off file
    n = int(0.8 * len(log.imu.time_ns))
    cut = int(log.imu.time_ns[n])

    def keep(obj):
        m = obj.time_ns < cut
        return replace(obj, **{k: v[m] for k, v in vars(obj).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == m.shape})
    return replace(log, imu=keep(log.imu), fix=keep(log.fix), vel=keep(log.vel),
                   complete=False)


FAULTS = {
    "late 2 s": (lambda log: _late(log, 2.0), LEVER_B_M),
    "late 0.2 s": (lambda log: _late(log, 0.2), LEVER_B_M),
    "lever arm 0 (true 1.5 m)": (lambda log: log, (0.0, 0.0, 0.0)),
    "FLU declared FRD": (_flu, LEVER_B_M),
    "5 km jump": (_jump, LEVER_B_M),
    "truncated": (_truncate, LEVER_B_M),
}


def detection(seeds: range, grade: str = "paper_flight") -> dict[str, list[str]]:
    """Failed checks per fault and seed on a clean flight of ``grade`` (0.3 m / 0.1 m/s GNSS,
    1 Hz, 150 s static start)."""
    out: dict[str, list[str]] = {k: [] for k in FAULTS}
    for i in seeds:
        c = {"grade": grade, "noise": GNSS_NOISE[1], "rate_hz": 1.0, "static_s": 150.0,
             "imu_rate_hz": 100.0, "seed": 2000 + i}
        log = clean_log(c)
        for name, (fault, lever) in FAULTS.items():
            rep = qc_of(fault(log), config_for(grade, lever))
            out[name].append(f"{rep.status}:{rep.failed_names}")
    return out


def main() -> None:
    what = sys.argv[1] if len(sys.argv) > 1 else "clean"
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 48
    t0 = time.perf_counter()
    if what == "clean":
        per_check, any_fail, detail = false_alarms(range(n))
        for c, rep in detail:
            if isinstance(rep, str):
                print(f"  seed {c['seed']} {c} A failed: {rep}")
            elif rep.failed:
                print(f"  seed {c['seed']} {c['grade']} {c['rate_hz']} Hz noise {c['noise']} "
                      f"static {c['static_s']}: "
                      + "; ".join(f"{x.name} {x.value:.4g}/{x.threshold:.4g}"
                                  for x in rep.failed))
        for g in GRADES:
            runs = [rep for c, rep in detail if c["grade"] == g and not isinstance(rep, str)]
            worst = {}
            for rep in runs:
                for x in rep.checks:
                    if np.isfinite(x.value) and x.threshold > 0:
                        worst[x.name] = max(worst.get(x.name, -np.inf), x.value / x.threshold)
            print(f"{g}: {len(runs)} runs, worst value/threshold: "
                  + ", ".join(f"{k} {v:.2f}" for k, v in worst.items()))
        n = sum(not isinstance(rep, str) for _, rep in detail)
        print(f"false alarms over {n} clean runs: any check {any_fail} ({any_fail / n:.1%}); "
              + (", ".join(f"{k} {v}" for k, v in per_check.items()) or "none"))
    elif what == "model_fit":
        model_fit_alarms(range(n))
    else:
        for name, res in detection(range(n)).items():
            hits = sum(not r.startswith("ok") for r in res)
            print(f"{name}: detected {hits}/{len(res)}: {res}")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
