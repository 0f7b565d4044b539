"""The calibration's sigmas follow the flight's own gyro drift (issue 16 item 3).

Seeded flights from pospp's simulator (three 300 s survey legs at 60 m/s, 180 deg and 90 deg
turns between them, 50 Hz, ``paper_flight`` errors: constant bias [1, -1, 1] deg/h, ARW 0.01
deg/sqrt(h), 5 ug) whose Gauss-Markov gyro drift is NOT the grade's (level and correlation
time set per case), GNSS at 1 Hz; algorithm A is pospp's own filter and smoother as the
pipeline runs it with the grade's drift (0.5 deg/h, 300 s) configured under [imu]; the
calibration (drift level and tau by REML on the flight, the grade a weak prior), its null
realisations (the estimated drift injected) and the null's covariance as in pospp.pipeline
(pospp.null_stage.null_stage). The calibrated body bias is compared with the simulated
constant bias: error / sigma should be about standard normal.
tests/benchmarks/bench_drift_honesty.py prints the full table (docs/calibration.md, "The drift
from the flight").
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from _missions import SimLog, three_leg_survey

from pospp import pipeline
from pospp.config import config_from_dict
from pospp.sim.api import simulate
from pospp.sim.gnss import GnssModel
from pospp.sim.profile import parse_profile
from pospp.sim.sensors import imu_grade
from pospp.units import DEG_PER_H_RADPS

PROFILE = three_leg_survey("drift_honesty", 300.0, lat_deg=34.25, lon_deg=108.95, height_m=2600.0,
                           heading_deg=0.0)


def drift_flight_z(seed: int, tau_s: float, sigma_dph: float, *, n_null: int = 6,
                   reruns: bool = False) -> dict:
    """Calibrate one seeded flight with a given Gauss-Markov drift as the pipeline does
    (``reruns``: ``[pairs] null_reruns``, the null from A re-runs).

    Returns a dict: ``z`` (x, y) bias error over its sigma, ``err_dph``, ``sigma_dph``, the
    drift the calibration estimated (``drift_sigma_dph``, ``drift_tau_s``, ``drift_source``).
    """
    model = dataclasses.replace(imu_grade("paper_flight"), gyro_gm_tau_s=float(tau_s),
                                gyro_gm_sigma_dph=(sigma_dph,) * 3)
    gnss = GnssModel(rate_hz=1.0, pos_noise_m=(0.05, 0.1), vel_noise_mps=(0.02, 0.03))
    sim = simulate(parse_profile(PROFILE), imu_grade=model, gnss=gnss, seed=seed)
    cfg = config_from_dict({
        "imu": {"grade": "flight"},
        "filter": {"output_rate_hz": 10.0, "smoother": True},
        "legs": {"min_duration_s": 240.0, "min_speed_mps": 20.0},
        "replay": {"reference": "smoothed", "horizon_s": 300.0},
        "pairs": {"null_reruns": reruns}})
    log = SimLog(sim.imu, sim.fix, sim.vel)
    nav = pipeline.navigate(log, cfg, record_gains=not reruns)
    imu = pipeline.imu_increments(log)
    run, _ = pipeline.calibrate_from_a(imu, nav, cfg)
    assert run.calibrated and len(run.replays) >= 2, run.reason
    honest = pipeline.null_stage(log, nav, run, cfg, n=n_null, seed=seed).calibration
    # the linear null, or A re-runs where it refuses (a leg before A's heading converged)
    assert honest.sigma_source == "linear_null" or honest.sigma_source == "null_realisations" \
        and (reruns or any("no linear null" in m for m in honest.messages))
    true_b = np.radians(np.asarray(sim.params["imu_errors"]["gyro_bias_dph"], float)) / 3600.0
    err = (honest.gyro_bias_b_radps - true_b)[:2]
    sig = honest.gyro_bias_sigma_b_radps[:2]
    # the flight's realised bias: the constant plus the drift's mean over the fitted legs
    # (the simulator's bias per IMU sample; the run's time axis starts at the first sample)
    t_imu = (np.asarray(sim.imu.time_ns) - int(sim.imu.time_ns[0])) * 1e-9
    bias = np.asarray(sim.imu_errors.gyro_bias_radps)
    parts = []
    for lid in honest.chosen.leg_ids:
        rep = honest.replays[lid]
        k0, k1 = np.searchsorted(t_imu, [rep.t0_s, rep.t0_s + rep.t_s[-1]])
        parts.append(bias[k0:k1])
    err_mean = (honest.gyro_bias_b_radps - np.concatenate(parts).mean(axis=0))[:2]
    return {"seed": seed, "z": err / sig, "err_dph": err / DEG_PER_H_RADPS,
            "z_mean": err_mean / sig, "err_mean_dph": err_mean / DEG_PER_H_RADPS,
            "sigma_dph": sig / DEG_PER_H_RADPS,
            "drift_sigma_dph": getattr(run, "drift_sigma_radps", np.nan) / DEG_PER_H_RADPS,
            "drift_tau_s": getattr(run, "drift_tau_s", np.nan),
            "drift_source": getattr(run, "drift_source", "configured")}


CASES = ((0.1, 100.0), (1.5, 300.0))
"""(sigma deg/h, tau s) of the simulated drift: a fast drift a fifth of the grade's level and a
fast one three times it (the grade configured: 0.5 deg/h, 300 s)."""
SEEDS = (0, 1, 2)


def _case(args: tuple[float, float, int]) -> dict:
    sigma_dph, tau_s, seed = args
    return drift_flight_z(seed, tau_s, sigma_dph)


@pytest.mark.slow
def test_calibration_sigmas_follow_the_flights_drift():
    # measured (these draws): error / sigma RMS 1.35, 12 of 12 within 3 sigma (largest 2.71);
    # the drift estimated at 0.05-0.10 deg/h, 100-479 s (for 0.1, 100 s) and 1.2-1.9 deg/h,
    # 479-1354 s (for 1.5, 300 s). Before (main at 5c67831: the configured 0.5 deg/h, 300 s
    # injected), see docs/calibration.md. Asserted as the issue states it (RMS 0.7-1.5,
    # >= 95 % within 3 sigma): the margin is 0.15 on the RMS and the 0.29 sigma below 3 of
    # the largest. Two worker processes share the six flights.
    jobs = [(s, t, seed) for s, t in CASES for seed in SEEDS]
    with ProcessPoolExecutor(max_workers=2, mp_context=mp.get_context("fork")) as pool:
        rows = list(pool.map(_case, jobs))
    z = np.array([r["z"] for r in rows])
    assert 0.7 <= float(np.sqrt(np.mean(z**2))) <= 1.5, z
    assert np.mean(np.abs(z) < 3.0) >= 0.95, z
