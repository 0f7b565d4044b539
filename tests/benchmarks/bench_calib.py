"""Calibration stage: wall time and the figures of docs/calibration.md (run on demand).

    python tests/benchmarks/bench_calib.py [--threads-note]

Uses ../shared/reference_cases/flight_survey_errors (independent simulator) with its truth as
algorithm A. Prints the stage's wall time (and its parts), peak memory, the calibrated values
of both formulations per pair and jointly, B's error at 300 s before and after compensation,
and the held-out-leg prediction of a single pair.
"""

from __future__ import annotations

import json
import resource
import time
from pathlib import Path

import numpy as np

from pospp import rotation, units
from pospp.calib.compensate import compensate_legs
from pospp.calib.replay import ImuIncrements, replay_leg, solution_a_from_trajectory
from pospp.calib.solve import fit_calibration
from pospp.calib.stage import calibrate_flight
from pospp.calib.tables import calibration_rows
from pospp.io.mcap_reader import read_flight_log
from pospp.io.parquet_tables import read_reference_trajectory
from pospp.nav.strapdown import Trajectory, increments_from_rates

REF = Path(__file__).resolve().parents[2].parent / "shared" / "reference_cases"
NAME = "flight_survey_errors"
DPH = units.DEG_PER_H_RADPS


def main() -> None:
    params = json.loads((REF / f"{NAME}.params.json").read_text())
    epoch = int(params["time"]["start_time_ns"])
    log = read_flight_log(REF / f"{NAME}.mcap")
    t, dth, dv = increments_from_rates(log.imu.time_ns, log.imu.w_ib_b_radps,
                                       log.imu.f_ib_b_mps2, epoch_ns=epoch)
    imu = ImuIncrements(t, dth, dv)
    ref = read_reference_trajectory(REF / f"{NAME}.truth.parquet")
    traj = Trajectory((ref.time_ns - epoch) * 1e-9, ref.lat_rad, ref.lon_rad, ref.height_m,
                      ref.v_n_mps, rotation.quat_from_euler(ref.rpy_rad))
    a = solution_a_from_trajectory(traj, v_sigma_n_mps=[0.02, 0.02, 0.03])
    calibrate_flight(imu, a)  # warm-up (numba caches)
    walls, cpus = [], []
    for _ in range(3):
        t0, c0 = time.perf_counter(), time.process_time()
        run = calibrate_flight(imu, a)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    wall = min(walls)
    n_imu = int(sum(np.searchsorted(t, g.end_s) - np.searchsorted(t, g.start_s)
                    for g in run.legs))
    print(f"stage wall {min(walls):.2f}-{max(walls):.2f} s, CPU {min(cpus):.2f}-{max(cpus):.2f} s"
          f" (3 runs, CPU counts all BLAS threads)")
    print(f"stage wall time {wall:.2f} s for {len(run.legs)} legs, {n_imu} IMU epochs in legs "
          f"({1e6 * wall / n_imu:.1f} us per leg epoch, 2 replays + 6 calibrations per leg "
          f"set); peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    print(f"injected gyro bias (FRD) {params['imu_errors']['gyro_bias_dph']} deg/h, ARW "
          f"{params['imu_errors']['gyro_arw_dpsh'][0]} deg/sqrt(h)")
    for p in run.pairs:
        print(f"pair {p.pair_id} legs {p.leg_a},{p.leg_b} dH {np.degrees(p.dheading_rad):.1f} "
              f"cond_raw {p.cond_raw:.3g} cond_scaled {p.cond_scaled:.3g} gate "
              f"{p.cond_gate:.3g} {p.reason}")
    for label, cals in [(f"pair {p.pair_id}", p.calibrations) for p in run.pairs] + [
            ("joint", run.joint)]:
        for c in cals:
            rows = ", ".join(f"{n} {v:.4g}±{s:.2g}" for n, v, s, _ in calibration_rows(c))
            print(f"{label} {c.formulation}: {rows}; residual RMS {c.residual_rms_mps:.4f} "
                  f"m/s; ARW {c.gyro_arw_radpsqrts * 180 / np.pi * 60:.4f} deg/sqrt(h)")
    for i in run.improvements:
        print(f"leg {i.leg_id} at {i.horizon_s:.0f} s: |dv| {i.vel_before_mps:.3f} -> "
              f"{i.vel_after_mps:.4f} m/s ({i.vel_before_mps / i.vel_after_mps:.0f}x), |dr| "
              f"{i.pos_before_m:.1f} -> {i.pos_after_m:.2f} m "
              f"({i.pos_before_m / i.pos_after_m:.0f}x)")
    s = run.summary()
    print(f"RMS over legs: {s['dv_before_mps']:.3f} -> {s['dv_after_mps']:.4f} m/s "
          f"({s['dv_before_mps'] / s['dv_after_mps']:.0f}x); {s['dp_before_m']:.1f} -> "
          f"{s['dp_after_m']:.2f} m ({s['dp_before_m'] / s['dp_after_m']:.0f}x)")
    ba = np.array(params["imu_errors"]["accel_bias_ug"]) * 9.80665e-6
    for label, aa in (("A = truth", a), ("A = truth + accel bias known", solution_a_from_trajectory(
            traj, v_sigma_n_mps=[0.02, 0.02, 0.03], accel_bias_b_mps2=ba))):
        reps = {g.leg_id: replay_leg(imu, aa, g) for g in run.legs}
        for form in ("body", "paper"):
            cal = fit_calibration((reps[0], reps[1]), form)
            _, imp = compensate_legs(imu, aa, {2: reps[2]}, cal)
            i = imp[0]
            print(f"held-out leg 2, {label}, {form} from pair (0,1): |dv| "
                  f"{i.vel_before_mps:.3f} -> {i.vel_after_mps:.4f} m/s, |dr| "
                  f"{i.pos_before_m:.1f} -> {i.pos_after_m:.2f} m")


if __name__ == "__main__":
    main()
