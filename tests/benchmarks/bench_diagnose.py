"""Benchmark: the model-discrepancy workflow on simulated flights (results and cost).

Run on demand (not part of the test suite):  python tests/benchmarks/bench_diagnose.py
Prints a markdown table; the numbers recorded in docs/benchmarks.md ("Diagnose") and in
docs/diagnose.md come from this script.

Each scenario hides one effect (or none, or one outside the library) in the IMU increments of
a synthetic survey flight (``tests/unit/_synthetic.py``, 50 Hz, 4 legs) on top of a
body-frame horizontal gyro bias of [0.02, -0.015] deg/h; A is the truth with white velocity
noise of 3 mm/s. Columns: what the workflow named, its estimate and the truth (display unit),
the RMS gap and the leave-one-leg-out (held-out) gap before and after, and the CPU time of
``diagnose`` alone (signatures, all fits and tests) and of the replays.
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "unit")]  # this tree's pospp, the test flights

from _synthetic import noisy_replays, survey_flight  # noqa: E402

from pospp import earth  # noqa: E402
from pospp.calib.replay import ImuIncrements  # noqa: E402
from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays  # noqa: E402
from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS, G0_MPS2, UG_MPS2  # noqa: E402

SIGMA = 0.003
BIAS = np.array([0.02, -0.015, 0.0]) * DEG_PER_H_RADPS


def _flights():
    return {
        "reversal": survey_flight(headings_deg=(0.0, 180.0, 0.0, 180.0), rate_hz=50.0),
        "crossing": survey_flight(headings_deg=(0.0, 180.0, 90.0, 270.0),
                                  speeds_mps=(40.0, 80.0, 80.0, 40.0), rate_hz=50.0),
        "long": survey_flight(headings_deg=(0.0, 180.0, 0.0, 180.0), leg_duration_s=600.0,
                              rate_hz=50.0),
        "wander": survey_flight(headings_deg=(0.0, 180.0, 0.0, 180.0), rate_hz=50.0,
                                wander_heading_deg=2.0, wander_pitch_deg=1.0),
    }


def _scenarios(fl):
    def base(f, b=BIAS):
        dt = np.diff(f.imu.t_s)[:, None]
        return f.imu.dtheta_b_rad + b * dt, f.imu.dv_b_mps.copy()

    def tm_dt(f):
        t = f.imu.t_s
        return 0.5 * (t[1:] + t[:-1]), np.diff(t)

    out = []
    f = fl["reversal"]
    out.append(("null", f, *base(f), {}, "-"))
    dth, dv = base(f)
    tm, dt = tm_dt(f)
    db = np.array([250.0, -150.0])
    dv[:, 0:2] += np.outer(np.exp(-tm / 1200.0), db * UG_MPS2) * dt[:, None]
    out.append(("accel warm-up 292 ug", f, dth, dv, {}, f"{np.linalg.norm(db):.4g}"))
    dth, dv = base(f)
    for leg, j in zip(f.legs, [[0.01, 0.005], [-0.008, 0.01], [0.012, -0.006], [-0.01, -0.008]],
                      strict=True):
        m = (tm >= leg.start_s - 30.0) & (tm < leg.end_s + 30.0)
        dth[m, 0:2] += np.array(j) * DEG_PER_H_RADPS * dt[m, None]
    out.append(("gyro bias jumps (outside)", f, dth, dv, {}, "unexplained"))
    dth, dv = base(f)
    dv[:, 0] += 300.0 * UG_MPS2 * np.sin(2 * np.pi * tm / 90.0) * dt
    out.append(("accel 90 s sine (outside)", f, dth, dv, {}, "unexplained"))
    f = fl["crossing"]
    b = np.array([0.05, -0.03, 0.0])
    out.append(("body bias vs paper base", f, *base(f, b * DEG_PER_H_RADPS),
                {"base_formulation": "paper"}, f"{np.linalg.norm(b):.4g}"))
    dth, dv = base(f)
    tr, t = f.truth, f.imu.t_s
    gg = np.array([0.3, 0.1, -0.2])
    g = gg * G0_MPS2 * ARCSEC_RAD / 1000.0
    d_n = earth.llh_to_ned_m(tr.lat_rad[:-1], tr.lon_rad[:-1], tr.height_m[:-1],
                             tr.lat_rad[0], tr.lon_rad[0], tr.height_m[0])
    dg = np.zeros((t.size - 1, 3))
    dg[:, 0:2] = d_n[:, 0:2] @ np.array([[g[0], g[1]], [g[1], g[2]]]).T
    dv -= np.einsum("kji,kj->ki", tr.c_nb[:-1], dg) * np.diff(t)[:, None]
    out.append(("gravity gradient", f, dth, dv, {}, f"{np.linalg.norm(gg):.4g}"))
    f = fl["long"]
    out.append(("vertical drift 1 deg/h", f,
                *base(f, BIAS + np.array([0, 0, 1.0]) * DEG_PER_H_RADPS), {}, "1"))
    out.append(("closed-form base", f, *base(f, np.array([0.3, -0.2, 0]) * DEG_PER_H_RADPS),
                {"base_transition": "closed_form"}, "1"))
    f = fl["wander"]
    dth, dv = base(f)
    t = f.imu.t_s
    tau = 0.02

    def shift(arr):
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(arr, axis=0)])
        return np.diff(np.stack([np.interp(t - tau, t, cum[:, c]) for c in range(3)], 1), axis=0)

    out.append(("time offset 20 ms, wander", f, shift(dth), shift(dv), {}, "20"))
    return out


def main() -> None:
    fl = _flights()
    print("| scenario | named | estimate (unit) | truth | gap before -> after [mm/s] | "
          "held-out before -> after [mm/s] | confounded with | diagnose CPU [s] | "
          "replays CPU [s] |")
    print("|---|---|---|---:|---|---|---|---:|---:|")
    for name, f, dth, dv, kw, truth in _scenarios(fl):
        imu = ImuIncrements(f.imu.t_s, dth, dv)
        ref = f.solution_a(SIGMA)
        c0 = time.process_time()
        reps = noisy_replays(f, imu, sigma_mps=SIGMA, rng=np.random.default_rng(7),
                             solution_a=ref)
        c1 = time.process_time()
        d = diagnose_replays(reps, DiagnosisOptions(**kw), imu=imu, solution_a=ref)
        c2 = time.process_time()
        first, last = d.steps[0], d.steps[-1]
        named = ", ".join(d.named) + ("; " if d.named else "") + d.conclusion
        est = "; ".join(f"{s.value:.3g} +- {s.sigma:.2g} ({s.unit})" for s in d.steps[:-1])
        conf = "; ".join(",".join(s.confounded_with) for s in d.steps[:-1] if s.confounded_with)
        print(f"| {name} | {named} | {est or '-'} | {truth} | "
              f"{first.gap_before_mps * 1e3:.2f} -> {last.gap_after_mps * 1e3:.2f} | "
              f"{first.heldout_gap_before_mps * 1e3:.2f} -> "
              f"{last.heldout_gap_after_mps * 1e3:.2f} | {conf or '-'} | {c2 - c1:.2f} | "
              f"{c1 - c0:.2f} |")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\nprocess peak RSS: {rss:.0f} MiB")


if __name__ == "__main__":
    main()
