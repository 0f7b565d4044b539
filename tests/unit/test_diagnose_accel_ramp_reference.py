"""flight_accel_ramp_100hz (independent simulator): an in-run accelerometer ramp the
calibration's model does not hold (issue 34).

The case's IMU has a linear accelerometer-bias change of (900, -400, 0) ug/h (FRD,
params.json ``imu_errors.accel_bias_drift_ugph``) besides its constant biases. Inside a level
leg such a ramp forces B exactly as a horizontal gyro bias ``r / g`` does, so the calibration
took it in (gyro bias (0.368, -0.350) deg/h for the true (0.4, -0.3)) and the run said ``ok``.
Here: the pipeline as ``pospp run`` runs it names ``accel_bias_change`` with shape ``ramp`` from
A's innovations, the ``model_fit`` check fails naming it, the calibration refitted with it
gives the gyro bias within 3 % (or 2 sigma) and the report shows both fits; and the signature
the refit removes is checked against the case's truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_diagnose_null_reference import case_config

from pospp import pipeline
from pospp.diagnose.sensor_families import accel_response_along_b
from pospp.units import UG_MPS2

NAME = "flight_accel_ramp_100hz"


def _config(cases: Path):
    return case_config(cases, NAME)


@pytest.fixture(scope="module")
def ramp_run(reference_cases, tmp_path_factory):
    """The case through ``pospp run``'s pipeline (its tables and report), and its params."""
    cfg, params = _config(reference_cases)
    out = tmp_path_factory.mktemp("ramp") / "run"
    run = pipeline.process_flight(reference_cases / f"{NAME}.mcap", cfg, out)
    tables = {n: pd.read_parquet(out / f"{n}.parquet")
              for n in ("diagnosis", "qc", "summary")}
    return run, tables, (out / "report.html").read_text(), params


@pytest.mark.slow
@pytest.mark.reference
def test_the_accelerometer_family_is_named_with_shape_ramp_and_its_rate(ramp_run):
    # measured: step 1 accel_bias_change, shape ramp, (896, -408) +- 42 ug/h, norm 985 for
    # the true 985, F 280 on A's innovations; the closing row stays unexplained (p 4e-4: a
    # gap the ramp does not make, it lies in the base model's span)
    _, t, _, params = ramp_run
    d = t["diagnosis"]
    row = d[d.effect == "accel_bias_change"]
    assert len(row) == 1, d[["effect", "shape", "value"]]
    row = row.iloc[0]
    assert row["shape"] == "ramp" and row.unit == "ug_per_h"
    true = np.asarray(params["imu_errors"]["accel_bias_drift_ugph"], dtype=float)[:2]
    vals = np.array([float(v) for v in row.parameter_values.split(";")])
    assert np.all(np.abs(vals - true) <= 0.25 * np.abs(true)), vals
    assert row.value == pytest.approx(float(np.linalg.norm(true)), rel=0.25)
    assert row.p_value < 1e-6
    # the responses from one linear pass give the fit of the 48 replays of A it replaced,
    # (896, -408) +- (42, 43) ug/h, within a sigma (measured (896.5, -407.2) +- (41.7, 42.5))
    sig = np.array([float(v) for v in row.parameter_sigmas.split(";")])
    assert np.all(np.abs(vals - [896.0, -408.0]) < sig), (vals, sig)


@pytest.mark.slow
@pytest.mark.reference
def test_the_run_is_not_ok_and_model_fit_names_the_effect(ramp_run):
    run, t, _, _ = ramp_run
    assert run.status != "ok"
    qc = t["qc"].set_index("check")
    assert not qc.loc["model_fit", "passed"]
    assert "accel_bias_change (ramp" in qc.loc["model_fit", "suggestion"]
    assert "model_fit" in t["summary"].qc_failed_checks.iloc[0]


@pytest.mark.slow
@pytest.mark.reference
def test_the_refit_gives_the_gyro_bias_and_the_report_shows_both_fits(ramp_run):
    # measured: the calibration (0.368, -0.350) +- (0.023, 0.017) deg/h, the refit with the
    # ramp removed (0.391, -0.299) +- (0.023, 0.017): 2.2 % and 0.4 % off the true (0.4, -0.3)
    _, t, report, params = ramp_run
    s = t["summary"].iloc[0]
    true = np.asarray(params["imu_errors"]["gyro_bias_dph"], dtype=float)
    assert s.refit_effects == "accel_bias_change"
    for i, ax in enumerate("xy"):
        refit, sigma = s[f"gyro_bias_{ax}_refit_dph"], s[f"gyro_bias_{ax}_refit_sigma_dph"]
        assert abs(refit - true[i]) <= max(0.03 * abs(true[i]), 2.0 * sigma), (ax, refit)
        assert np.isfinite(s[f"gyro_bias_{ax}_dph"])  # the calibration as fitted, kept
    # the calibration's y is 17 % off; the refit's is not
    assert abs(s.gyro_bias_y_dph - true[1]) > 0.1 * abs(true[1])
    assert "refitted with accel_bias_change removed from B minus A" in report
    assert report.count("gyro_bias_y") >= 2


@pytest.mark.slow
@pytest.mark.reference
def test_the_ramp_response_along_b_is_what_the_truth_shows(reference_cases):
    # B's true error on each leg (A plus B minus A, minus the case's 10 Hz truth) against the
    # ramp's response along B from each leg start plus the true gyro bias's (the Phi BG block)
    # and a fitted initial tilt and heading: measured 0.6, 3.2 and 1.9 mm/s RMS left, where
    # the ramp's response alone is 37-65 mm/s RMS
    cfg, params = _config(reference_cases)
    log = pipeline.ingest(reference_cases / f"{NAME}.mcap", cfg)
    nav = pipeline.navigate(log, cfg)
    run, ref = pipeline.calibrate_from_a(pipeline.imu_increments(log), nav, cfg)
    truth = pd.read_parquet(reference_cases / f"{NAME}.truth.parquet")
    tt = (truth.time_ns.to_numpy() - int(log.imu.time_ns[0])) * 1e-9
    r = np.asarray(params["imu_errors"]["accel_bias_drift_ugph"], float)[:2] * UG_MPS2 / 3600
    bg = np.radians(np.asarray(params["imu_errors"]["gyro_bias_dph"], float)) / 3600.0
    for rep in run.replays.values():
        t = rep.t0_s + rep.t_s
        v_true = np.stack([np.interp(t, tt, truth[c]) for c in ("vn_mps", "ve_mps")], axis=1)
        v_a = np.stack([np.interp(t, ref.trajectory.t_s, ref.trajectory.v_n_mps[:, k])
                        for k in range(2)], axis=1)
        err_b = v_a + rep.dv_n_mps[:, 0:2] - v_true
        ramp = accel_response_along_b(rep, t[:, None] * r, t[0] * r)
        model = ramp + rep.phi[:, 3:5, 9:12] @ bg
        tilt = rep.phi[:, 3:5, 0:3].reshape(-1, 3)
        y = (err_b - model).reshape(-1)
        res = y - tilt @ np.linalg.lstsq(tilt, y, rcond=None)[0]
        rms, size = float(np.sqrt(np.mean(res**2))), float(np.sqrt(np.mean(ramp**2)))
        assert size > 0.03 and rms < 4e-3, (rep.leg.leg_id, rms, size)
