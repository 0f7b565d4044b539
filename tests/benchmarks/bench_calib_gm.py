"""Calibration with the Gauss-Markov gyro drift model on the sample flight (run on demand).

    python tests/benchmarks/bench_calib_gm.py

sample_data/sample_flight.mcap (paper_flight grade: constant [1, -1, 1] deg/h, Gauss-Markov
0.5 deg/h, tau 300 s; realised biases in sample_flight.bias.parquet, body FRD) through the
pipeline's ingest and algorithm A (smoothed), then the calibration stage without and with the
drift model (sigma and tau from the ``flight`` tuning preset, and sigma by REML), B re-run with
the constant bias, with the per-leg smoothed drift, and with the true per-leg mean bias
(oracle). Prints estimates, sigmas, B's error at the horizon and the stage's CPU time.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from pospp import flight_stages, pipeline
from pospp.calib.compensate import compensate_legs
from pospp.calib.replay import ReplayOptions, SolutionA
from pospp.calib.stage import calibrate_flight
from pospp.config import load_config
from pospp.nav import filter as nav_filter

ROOT = Path(__file__).resolve().parents[2]
DPH = np.pi / 180.0 / 3600.0


def rms(vals: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(vals))))


def main() -> None:
    cfg = load_config(ROOT / "pipelines" / "sample.toml")
    log = pipeline.ingest(ROOT / "sample_data" / "sample_flight.mcap", cfg)
    imu = pipeline.imu_increments(log)
    nav = pipeline.navigate(log, cfg)
    ref = SolutionA(*nav_filter.solution_a_fields(nav, which="smoothed"))
    tun = flight_stages.imu_tuning(cfg)
    epoch_ns = int(log.imu.time_ns[0])
    bias = pd.read_parquet(ROOT / "sample_data" / "sample_flight.bias.parquet")
    tb = (bias.time_ns.to_numpy() - epoch_ns) * 1e-9
    gb = bias[["gyro_bias_x_dph", "gyro_bias_y_dph", "gyro_bias_z_dph"]].to_numpy() * DPH
    base = {"legs_cfg": cfg.legs.thresholds(), "replay_cfg": cfg.replay.options(),
            "pairs_cfg": cfg.pairs.policy(),
            "gyro_arw_dpsh": tun.gyro_arw_dpsh}
    variants = {
        "no drift model": {},
        "GM sigma 0.5 deg/h, tau 300 s": {"gyro_gm_sigma_dph": tun.gyro_gm_sigma_dph,
                                          "gyro_gm_tau_s": tun.gyro_gm_tau_s},
        "GM sigma by REML, tau 300 s": {"gyro_gm_tau_s": tun.gyro_gm_tau_s},
    }
    for label, kw in variants.items():
        t0 = time.process_time()
        run = calibrate_flight(imu, ref, **base, **kw)
        cpu = time.process_time() - t0
        cal = run.chosen
        print(f"\n== {label}: stage CPU {cpu:.2f} s, legs {len(run.legs)}, pairs used "
              f"{sum(p.used for p in run.pairs)}, GM sigma {cal.gyro_gm_sigma_radps / DPH:.3f}")
        print(f"   bias x, y = {run.gyro_bias_b_radps[0] / DPH:.3f} +- "
              f"{run.gyro_bias_sigma_b_radps[0] / DPH:.3f}, {run.gyro_bias_b_radps[1] / DPH:.3f}"
              f" +- {run.gyro_bias_sigma_b_radps[1] / DPH:.3f} deg/h (constant 1, -1)")
        true_mean = {}
        for lid, rep in sorted(run.replays.items()):
            m = (tb >= rep.t0_s) & (tb <= rep.t0_s + rep.t_s[-1])
            true_mean[lid] = gb[m].mean(axis=0)
            d = cal.leg_drift_b_radps(rep)
            print(f"   leg {lid}: true mean {np.round(true_mean[lid][:2] / DPH, 3)}, "
                  f"constant + smoothed drift {np.round((run.gyro_bias_b_radps + d)[:2] / DPH, 3)}")
        rows = {"constant": run.improvements}
        opts = {"replay": ReplayOptions(horizon_s=cfg.replay.horizon_s)}
        if cal.drift is not None:
            rows["per_leg"] = compensate_legs(imu, ref, run.replays, cal, per_leg_drift=True,
                                              **opts)[1]
        rows["oracle"] = compensate_legs(imu, ref, run.replays, cal,
                                         gyro_bias_by_leg=true_mean, **opts)[1]
        before_v = rms([i.vel_before_mps for i in run.improvements])
        before_p = rms([i.pos_before_m for i in run.improvements])
        for k, imp in rows.items():
            v, p = rms([i.vel_after_mps for i in imp]), rms([i.pos_after_m for i in imp])
            print(f"   B at the horizon (RMS over legs), {k:>8}: {before_v:.3f} -> {v:.3f} m/s "
                  f"({before_v / v:.1f}x), {before_p:.1f} -> {p:.1f} m ({before_p / p:.1f}x)")


if __name__ == "__main__":
    main()
