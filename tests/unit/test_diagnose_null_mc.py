"""False alarms of the null-calibrated diagnosis and the honesty of the calibration's sigmas:
a seeded Monte Carlo on pospp's simulator with pospp's own A as the reference (issue 12,
items 2 and 6).

Each seed: a short survey flight (three 180 s legs at 60 m/s, two headings 180 deg apart and
one 90 deg off, 50 Hz IMU) with one of the grades' errors (constant bias, Gauss-Markov drift,
ARW: pospp/presets/imu.toml), GNSS at 1-10 Hz with horizontal noise log-uniform in 0.02-1 m
(vertical twice, velocity half that in m/s); A and the calibration as the pipeline runs them
(the grade's drift configured under [imu]); the pipeline's ``diagnose`` calibrated on 10 null
realisations (the linear null from A's gains, pospp.calib.linear_null; A re-runs,
pospp.diagnose.null_model, where a leg starts before A's heading converged), with the log and
A's result as ``pospp run`` gives them (so the A re-run candidates, lever arm and GNSS time
offset, are tested too); the same null gives the calibration its covariance
(pospp.null_stage.null_stage). Nothing outside the base model is present, so the
closing row should be ``none`` at alpha = 0.05 (body bias, vertical drift and Earth-rate
coupling may be named), and the calibrated body gyro bias should sit within its sigma of the
simulated constant bias as often as a normal error would.
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from _missions import SimLog, three_leg_survey

from pospp import pipeline
from pospp.config import config_from_dict
from pospp.diagnosis_stage import refit_and_check
from pospp.sim.api import simulate
from pospp.sim.gnss import GnssModel
from pospp.sim.profile import parse_profile

GRADES = ("paper_flight", "paper_vehicle", "tactical")
FILTER_GRADE = {"paper_flight": "flight", "paper_vehicle": "vehicle", "tactical": "tactical"}
DRIFT = {"paper_flight": (0.5, 300.0), "paper_vehicle": (0.05, 300.0), "tactical": (0.5, 600.0)}
"""The simulator grades' Gauss-Markov gyro drift (sigma deg/h, tau s), configured under [imu]."""
ACCEL_DRIFT = {"paper_flight": (0.0, 600.0), "paper_vehicle": (0.0, 600.0),
               "tactical": (50.0, 600.0)}
"""The same for the accelerometer bias (sigma ug, tau s)."""
N_NULL = 10
MAY_BE_NAMED = {"body_fixed_gyro_bias", "vertical_gyro_drift", "earth_rate_coupling"}

PROFILE = three_leg_survey("null_mc", 180.0, lat_deg=40.0, lon_deg=116.0, height_m=1000.0,
                           heading_deg=30.0)


def null_flight(seed: int, reruns: bool = False):
    """(simulation, log, config) of one seeded null flight (``reruns``: ``[pairs]
    null_reruns``, the null from A re-runs)."""
    grade = GRADES[seed % len(GRADES)]
    rng = np.random.default_rng(1000 + seed)
    lvl = float(np.exp(rng.uniform(np.log(0.02), np.log(1.0))))
    rate = [1.0, 2.0, 5.0, 10.0][rng.integers(4)]
    gnss = GnssModel(rate_hz=rate, pos_noise_m=(lvl, 2 * lvl), vel_noise_mps=(lvl / 2, lvl))
    sim = simulate(parse_profile(PROFILE), imu_grade=grade, gnss=gnss, seed=seed)
    cfg = config_from_dict({
        "imu": {"grade": FILTER_GRADE[grade], "gyro_gm_sigma_dph": DRIFT[grade][0],
                "gyro_gm_tau_s": DRIFT[grade][1], "accel_gm_sigma_ug": ACCEL_DRIFT[grade][0],
                "accel_gm_tau_s": ACCEL_DRIFT[grade][1]},
        "filter": {"output_rate_hz": 10.0, "smoother": True},
        "legs": {"min_duration_s": 120.0, "min_speed_mps": 20.0},
        "replay": {"reference": "smoothed", "horizon_s": 180.0},
        "pairs": {"diagnose_alpha": 0.05, "null_reruns": reruns}})
    return sim, SimLog(sim.imu, sim.fix, sim.vel), cfg


def null_flight_diagnosis(seed: int, n_null: int = N_NULL, reruns: bool = False):
    """(calibrated Diagnosis, nominal Diagnosis, bias error / sigma (x, y), the run's
    ``model_fit`` check, the calibration's sigma source) of one seeded null flight."""
    sim, log, cfg = null_flight(seed, reruns)
    nav = pipeline.navigate(log, cfg, record_gains=not reruns)
    imu = pipeline.imu_increments(log)
    run, ref = pipeline.calibrate_from_a(imu, nav, cfg)
    assert run.calibrated and len(run.replays) >= 2, run.reason
    stage = pipeline.null_stage(log, nav, run, cfg, n=n_null, seed=seed)
    null, honest = stage.realisations, stage.calibration
    # the linear null, or A re-runs where it refuses (a leg before A's heading converged)
    assert honest.sigma_source == "linear_null" or honest.sigma_source == "null_realisations" \
        and (reruns or any("no linear null" in m for m in honest.messages))
    true_b = np.radians(np.asarray(sim.params["imu_errors"]["gyro_bias_dph"], float)) / 3600.0
    z = ((honest.gyro_bias_b_radps - true_b) / honest.gyro_bias_sigma_b_radps)[:2]
    # the pipeline's whole path: with the log and A's result, the lever arm and the GNSS time
    # offset are candidates with their A re-run signatures (Gauss-Newton from A's own lever-arm
    # estimate), the null's drift may be re-estimated under the alternative, and the sensor
    # families are fitted on A's innovations; then the refit and the model_fit check as a run
    # makes them
    d = pipeline.diagnose_calibration(honest, imu, ref, cfg, null_dv=null, log=log, nav=nav)
    fit = refit_and_check(log, honest, d, imu, ref, cfg, compensate=False)
    return (d, pipeline.diagnose_calibration(run, imu, ref, cfg), z, fit.checks[0],
            honest.sigma_source)


def _seed_summary(seed: int) -> tuple[str, str, tuple[str, ...], str, list[float], bool, str,
                                      str]:
    """(grade, closing row, named, nominal closing row, bias error / sigma x, y, model_fit
    passed, its suggestion, the calibration's sigma source) of a seed."""
    d, d0, z, check, source = null_flight_diagnosis(seed)
    return (GRADES[seed % 3], d.conclusion, d.named, d0.conclusion, [float(v) for v in z],
            check.passed, check.suggestion, source)


@pytest.mark.slow
def test_null_flights_close_none_at_the_stated_rate_and_sigmas_are_honest():
    # measured (these draws): none in 40 of 40 (the linear null on 21 flights, the A re-runs
    # on the 19 whose first leg starts before A's heading converged), the nominal F-test
    # unexplained in 39 of 40; calibrated bias error / sigma RMS 1.08, 80 of 80 within 3
    # sigma (the A re-runs' null on all 40, 10 realisations: see docs/diagnose.md, "The
    # linear null"). The issue asks for >= 95 % none (38 of 40), error / sigma RMS in 0.7-1.5
    # and >= 95 % within 3 sigma: asserted as stated. The seeds are independent: two worker
    # processes (the machine's two cores) share them.
    with ProcessPoolExecutor(max_workers=2, mp_context=mp.get_context("fork")) as pool:
        rows = list(pool.map(_seed_summary, range(40)))
    closing = {g: [c for gg, c, *_ in rows if gg == g] for g in GRADES}
    for seed, row in enumerate(rows):
        print(seed, *row)
    for _, _, named, *_ in rows:
        assert set(named) <= MAY_BE_NAMED
    assert sum(r[7] == "linear_null" for r in rows) >= 15  # the linear null is what is tested
    nominal = [r[3] for r in rows]
    assert nominal.count("unexplained") >= 34
    total = sum(c.count("none") for c in closing.values())
    assert total >= 38, closing
    z = np.asarray([r[4] for r in rows])
    assert 0.7 <= float(np.sqrt(np.mean(z**2))) <= 1.5, z
    assert np.mean(np.abs(z) < 3.0) >= 0.95, z
    # model_fit (issue 34): false alarms at most 2 % of the clean flights
    alarms = [(seed, r[6]) for seed, r in enumerate(rows) if not r[5]]
    assert len(alarms) <= 0.02 * len(rows), alarms
