"""Monte Carlo of the calibration with Gauss-Markov gyro drift in the noise model (slow).

Short simulated surveys (tests/unit/_gm_mission.py: three 300 s legs with 180 deg turns,
100 Hz) with the paper's IMU grades (pospp/presets/imu.toml ``paper_flight``: constant
[1, -1, 1] deg/h + Gauss-Markov 0.5 deg/h, tau 300 s, ARW 0.01 deg/sqrt(h);
``paper_vehicle``: 0.1 + 0.05 deg/h, ARW 0.002); algorithm A is the truth. The noise model
takes the drift's sigma and tau from the tuning presets (``pospp.nav.tuning``). Checks: the
constant bias's error against its sigma (RMS of error / sigma in 0.7..1.5, within 3 sigma on
both axes in >= 95 % of the runs), and B's error at 300 s with the constant bias, with the
per-leg smoothed drift, with the true per-leg mean bias (oracle), with the smoothed drift
removed inside each leg (in-sample: it fits the very residuals it is judged on), and on the
last leg predicted from a fit of the first two. Run with ``-s`` to see the figures
(docs/calibration.md, section 9).
"""

from __future__ import annotations

import numpy as np
import pytest
from _gm_mission import run_once

pytestmark = pytest.mark.slow

DPH = np.pi / 180.0 / 3600.0
SEEDS = range(20)


@pytest.mark.parametrize("kind", ["flight", "vehicle"])
def test_gm_noise_model_sigmas_are_honest(kind, tmp_path):
    runs = [run_once(kind, seed, tmp_path) for seed in SEEDS]
    z = np.array([r.err_b_radps / r.sigma_b_radps for r in runs])  # (runs, 2)
    z_rms = float(np.sqrt(np.mean(z**2)))
    in3 = int(np.sum(np.all(np.abs(z) < 3.0, axis=1)))
    dv = {k: np.array([r.dv_mps[k] for r in runs]) for k in runs[0].dv_mps}
    dp = {k: np.array([r.dp_m[k] for r in runs]) for k in runs[0].dp_m}
    leg_d = np.sqrt(np.mean([np.mean(r.leg_drift_err_radps**2) for r in runs])) / DPH
    leg_c = np.sqrt(np.mean([np.mean(r.leg_const_err_radps**2) for r in runs])) / DPH

    def med(a):
        return float(np.median(a))

    print(f"\n{kind}: {len(runs)} runs, error/sigma RMS {z_rms:.2f}, within 3 sigma {in3}/"
          f"{len(runs)}, sigma {np.mean([r.sigma_b_radps for r in runs]) / DPH:.3f} deg/h, "
          f"max |error| {np.abs([r.err_b_radps for r in runs]).max() / DPH:.3f} deg/h")
    print(f"{kind}: per-leg bias error RMS: constant {leg_c:.3f}, constant + smoothed drift "
          f"{leg_d:.3f} deg/h")
    for k in dv:
        b = "held_before" if k.startswith("held") else "before"
        print(f"{kind}: B at 300 s (RMS over legs), median over runs, {k:>13}: "
              f"{med(dv[k]):.3f} m/s, {med(dp[k]):.1f} m; ratio {b}/{k} "
              f"{med(dv[b] / dv[k]):.1f}x / {med(dp[b] / dp[k]):.1f}x")
    print(f"{kind}: held-out leg, per-leg drift beats constant in velocity in "
          f"{int(np.sum(dv['held_per_leg'] < dv['held_constant']))}/{len(runs)} runs")
    print(f"{kind}: per-leg beats constant in velocity in "
          f"{int(np.sum(dv['per_leg'] < dv['constant']))}/{len(runs)} runs, in position in "
          f"{int(np.sum(dp['per_leg'] < dp['constant']))}/{len(runs)}")
    assert 0.7 <= z_rms <= 1.5
    assert in3 >= 0.95 * len(runs)
    assert leg_d < leg_c
    assert med(dv["per_leg"]) < med(dv["constant"]) < med(dv["before"])
