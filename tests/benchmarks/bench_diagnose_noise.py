"""Noise model of B minus A on the independent reference cases, with pospp's own A (issue 12).

Not a CI test. For each case: A (filter + smoother, pipelines/flight.toml with the case's lever
arm from its params.json), the calibration stage (body bias error and sigma against the
params), then the discrepancy workflow with the ARW-only model (``gyro_rw``) and the full
model (``full``: REML on A's coloured error, ARW, accelerometer noise); on the null case also
with A's true error removed from B minus A exactly (``Phi_v,v e_A(t0) - e_A(t)``, from the
truth), which separates what A's error does from what B's own error does.

    PYTHONPATH=. python tests/benchmarks/bench_diagnose_noise.py [case ...]

Prints one block per case. Slow (about 2-4 minutes per case: the REML profile).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pospp import flight_stages, pipeline, rotation
from pospp.config import load_config
from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays
from pospp.io.parquet_tables import read_reference_trajectory
from pospp.nav import strapdown
from pospp.nav.strapdown import interpolate_trajectory

ROOT = Path(__file__).resolve().parents[2]
CASES = ROOT.parent / "shared" / "reference_cases"
DPH = np.pi / 180.0 / 3600.0
EFFECTS = ("vertical_gyro_drift", "accel_bias_change", "gravity_disturbance", "lever_arm",
           "time_offset", "gyro_scale_factor")


def run_case(name: str) -> None:
    cfg, params = case_config(name)
    log = pipeline.ingest(CASES / f"{name}.mcap", cfg)
    nav = pipeline.navigate(log, cfg)
    imu = pipeline.imu_increments(log)
    run, ref = pipeline.calibrate_from_a(imu, nav, cfg)
    truth_b = np.array(params["imu_errors"]["gyro_bias_dph"][:2])
    err = run.gyro_bias_b_radps[:2] / DPH - truth_b
    sig = run.gyro_bias_sigma_b_radps[:2] / DPH
    print(f"{name}: {len(run.replays)} legs; {run.messages[-1] if run.messages else ''}")
    print(f"  body bias error {np.round(err, 4)} deg/h, sigma {np.round(sig, 4)}, "
          f"error/sigma {np.round(err / sig, 2)}")
    reps = [run.replays[i] for i in sorted(run.replays)]
    tr = read_reference_trajectory(CASES / f"{name}.truth.parquet")
    epoch = int(log.imu.time_ns[0])
    truth = strapdown.Trajectory((tr.time_ns - epoch) * 1e-9, tr.lat_rad, tr.lon_rad,
                                 tr.height_m, tr.v_n_mps, rotation.quat_from_euler(tr.rpy_rad))

    def without_a_error(rep):
        t = rep.t0_s + rep.t_s
        ea = (interpolate_trajectory(ref.trajectory, t).v_n_mps
              - interpolate_trajectory(truth, t).v_n_mps)
        dv = rep.dv_n_mps + ea - np.einsum("tij,j->ti", rep.phi[:, 3:6, 3:6], ea[0])
        return dataclasses.replace(rep, dv_n_mps=dv), ea[:, 0:2]

    pairs = [without_a_error(r) for r in reps]
    ea = np.concatenate([p[1] for p in pairs])
    print(f"  A's true horizontal velocity error: RMS {np.sqrt(np.mean(ea**2)) * 1e3:.2f} mm/s")
    variants = [("B-A", reps)]
    if params["gnss"]["time_offset_s"] == 0.0:
        variants.append(("B-A with A's true error removed", [p[0] for p in pairs]))
    for label, rr in variants:
        for noise in ("gyro_rw", "full"):
            t0 = time.perf_counter()
            d = diagnose_replays(rr, DiagnosisOptions(
                base_formulation="body", noise=noise, effects=EFFECTS,
                replay_kwargs={"accel_compensation": cfg.replay.accel_compensation}),
                imu=imu, solution_a=ref)
            rows = [(s.effect, f"{s.value:.4g} {s.unit}".strip(), f"F={s.statistic:.2f}",
                     f"p={s.p_value:.2g}") for s in d.steps]
            print(f"  {label:32s} {noise:8s} {rows} ({time.perf_counter() - t0:.0f} s)")


def case_config(name: str):
    params = json.loads((CASES / f"{name}.params.json").read_text())
    lever = params["gnss"]["lever_arm_m"]
    toml = (ROOT / "pipelines" / "flight.toml").read_text().replace(
        "lever_arm_m = [0.0, 0.0, 0.0]", f"lever_arm_m = [{lever[0]}, {lever[1]}, {lever[2]}]")
    with tempfile.TemporaryDirectory() as tmp:
        cfg_path = Path(tmp) / "case.toml"
        cfg_path.write_text(toml)
        return load_config(cfg_path), params


def run_null(name: str, n_null: int) -> None:
    """The workflow with its tests calibrated on ``n_null`` null realisations (null_model)."""
    cfg, params = case_config(name)
    log = pipeline.ingest(CASES / f"{name}.mcap", cfg)
    t0 = time.perf_counter()
    nav = pipeline.navigate(log, cfg, record_gains=pipeline.null_needs_gains(cfg))
    t_a = time.perf_counter() - t0
    imu = pipeline.imu_increments(log)
    run, ref = pipeline.calibrate_from_a(imu, nav, cfg)
    t0 = time.perf_counter()
    null = pipeline.null_realisations(log, nav, run, cfg, n_null, seed=1)
    t_null = time.perf_counter() - t0
    ch = run.chosen
    print(f"  calibration: GM drift {np.degrees(ch.gyro_gm_sigma_radps) * 3600:.3g} deg/h, "
          f"tau {ch.gyro_gm_tau_s} s")
    print(f"{name}: {len(run.replays)} legs, A {t_a:.1f} s, {n_null} null realisations "
          f"{t_null:.1f} s; time offset {params['gnss']['time_offset_s']} s")
    for effects in (None, EFFECTS):
        for nd in (None, null):
            t0 = time.perf_counter()
            d = pipeline.diagnose_calibration(run, imu, ref, cfg, null_dv=nd) \
                if effects is None else diagnose_replays(
                    [run.replays[i] for i in sorted(run.replays)], DiagnosisOptions(
                        replay_kwargs={"accel_compensation": cfg.replay.accel_compensation},
                        noise="gyro_rw", effects=effects,
                        gyro_arw_radpsqrts=np.radians(flight_stages.imu_tuning(cfg).gyro_arw_dpsh)
                        / 60.0), imu=imu, solution_a=ref, null_dv=nd)
            rows = [(s.effect, f"{s.value:.4g} {s.unit}".strip(), f"F={s.statistic:.2f}",
                     f"p={s.p_value:.2g}") for s in d.steps]
            lab = "pipeline" if effects is None else "bench effects"
            print(f"  {lab:14s} null={'none' if nd is None else len(nd)} {rows} "
                  f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    args = sys.argv[1:]
    if args and args[0] == "--null":
        for case in args[2:] or ("flight_null_200hz", "flight_survey_errors",
                                 "flight_time_offset_200hz"):
            run_null(case, int(args[1]))
    else:
        for case in args or ("flight_null_200hz", "flight_survey_errors",
                             "flight_time_offset_200hz"):
            run_case(case)
