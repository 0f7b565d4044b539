"""The workflow on data from pospp's mission simulator (exact IMU increments by quadrature of
the true motion, so the truth is independent of the strapdown kernel that B runs).

Mission: four 300 s survey legs on two perpendicular lines at 40 and 80 m/s (different speeds
and headings break the confounds of docs/diagnose.md), 50 Hz. A is the simulator's truth plus
3 mm/s white velocity noise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pospp.calib.replay import ImuIncrements, replay_leg, solution_a_from_trajectory
from pospp.calib.segment import Leg
from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays
from pospp.nav import strapdown
from pospp.sim.api import simulate
from pospp.sim.profile import parse_profile
from pospp.sim.sensors import ImuErrorModel

SIGMA = 0.003

PROFILE = {
    "name": "diagnose_crossing", "imu_rate_hz": 50,
    "start": {"lat_deg": 40.0, "lon_deg": 116.0, "height_m": 1000.0, "heading_deg": 0.0},
    "options": {"turn_bank": "coordinated", "blend_s": 5.0},
    "segment": [
        {"type": "accelerate", "to_speed_mps": 40.0, "duration_s": 20.0},
        {"type": "straight", "duration_s": 300.0, "kind": "survey"},
        {"type": "turn", "angle_deg": 180.0, "rate_dps": 4.0},
        {"type": "accelerate", "to_speed_mps": 80.0, "duration_s": 30.0},
        {"type": "straight", "duration_s": 300.0, "kind": "survey"},
        {"type": "turn", "angle_deg": 90.0, "rate_dps": 4.0},
        {"type": "straight", "duration_s": 300.0, "kind": "survey"},
        {"type": "turn", "angle_deg": 180.0, "rate_dps": 4.0},
        {"type": "accelerate", "to_speed_mps": 40.0, "duration_s": 30.0},
        {"type": "straight", "duration_s": 300.0, "kind": "survey"},
    ],
}


def _diagnose(errors: ImuErrorModel, seed: int, **kw):
    sim = simulate(parse_profile(PROFILE), imu_grade=errors, seed=seed)
    t_s, dth, dv = strapdown.increments_from_rates(
        sim.imu.time_ns, sim.imu.w_ib_b_radps, sim.imu.f_ib_b_mps2, epoch_ns=sim.start_time_ns)
    imu = ImuIncrements(t_s, dth, dv)
    a = solution_a_from_trajectory(sim.truth, v_sigma_n_mps=np.full(3, SIGMA))
    rng = np.random.default_rng(seed)
    reps = []
    for tl in sim.legs:
        leg = Leg(tl.leg_id, tl.start_s + 2.0, tl.end_s - 2.0, np.radians(tl.heading_deg),
                  tl.speed_mps, tl.height_m, 0.0, 0.0, 0.0, 0.0)
        r = replay_leg(imu, a, leg, sigma_floor_mps=SIGMA)
        noisy = r.dv_n_mps + rng.normal(0.0, SIGMA, r.dv_n_mps.shape)
        noisy[0] = 0.0
        reps.append(dataclasses.replace(r, dv_n_mps=noisy))
    assert len(reps) == 4
    return diagnose_replays(reps, DiagnosisOptions(**kw), imu=imu, solution_a=a)


def test_body_fixed_gyro_bias_against_paper_base():
    d = _diagnose(ImuErrorModel(gyro_bias_dph=(0.05, -0.03, 0.0)), seed=3,
                  base_formulation="paper")
    assert d.named == ("body_fixed_gyro_bias",) and d.conclusion == "none"
    s = d.steps[0]
    np.testing.assert_allclose(s.values, [0.05, -0.03], atol=0.006)
    assert s.value == pytest.approx(np.hypot(0.05, 0.03), rel=0.2)
    excess = [np.sqrt(max(g**2 - SIGMA**2, 0.0))
              for g in (s.heldout_gap_before_mps, s.heldout_gap_after_mps)]
    assert excess[1] <= 0.5 * excess[0]


@pytest.mark.slow
def test_gauss_markov_gyro_drift_is_unexplained():
    # a first-order Gauss-Markov drift (300 s) is outside the library
    d = _diagnose(ImuErrorModel(gyro_bias_dph=(0.02, -0.015, 0.0),
                                gyro_gm_sigma_dph=(0.02, 0.02, 0.0), gyro_gm_tau_s=300.0),
                  seed=3)
    assert d.named == ()
    assert d.conclusion == "unexplained"
