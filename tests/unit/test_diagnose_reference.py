"""The workflow on the independent simulator's flight_survey_errors case (outside check).

A is the simulator's truth (10 Hz, interpolated), so B minus A is B's own error: the injected
body-frame gyro bias [0.5, -0.4, 0.2] deg/h, the accelerometer bias (absorbed by the per-leg
tilts, A being true) and the gyro angle random walk 0.002 deg/sqrt(h) (the ``gyro_rw`` noise
model). Against the "paper" base (navigation-frame drift common to the legs) the workflow
must name the body-fixed gyro bias, from data it did not generate.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from pospp import rotation
from pospp.calib.replay import ImuIncrements, replay_leg, solution_a_from_trajectory
from pospp.calib.segment import Leg
from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays
from pospp.io.mcap_reader import read_flight_log
from pospp.io.parquet_tables import read_reference_trajectory
from pospp.nav import strapdown

NAME = "flight_survey_errors"


@pytest.mark.slow
@pytest.mark.reference
def test_paper_base_names_body_fixed_gyro_bias(reference_cases):
    log = read_flight_log(reference_cases / f"{NAME}.mcap")
    params = json.loads((reference_cases / f"{NAME}.params.json").read_text())
    tr = read_reference_trajectory(reference_cases / f"{NAME}.truth.parquet")
    epoch = int(tr.time_ns[0])
    t_s, dth, dv = strapdown.increments_from_rates(
        log.imu.time_ns, log.imu.w_ib_b_radps, log.imu.f_ib_b_mps2, epoch_ns=epoch)
    traj = strapdown.Trajectory((tr.time_ns - epoch) * 1e-9, tr.lat_rad, tr.lon_rad,
                                tr.height_m, tr.v_n_mps, rotation.quat_from_euler(tr.rpy_rad))
    a = solution_a_from_trajectory(traj, v_sigma_n_mps=np.full(3, 0.001))
    imu = ImuIncrements(t_s, dth, dv)
    legs = [Leg(p["leg_id"], (p["start_ns"] - epoch) * 1e-9 + 3.0,
                (p["end_ns"] - epoch) * 1e-9 - 3.0, np.radians(p["heading_deg"]),
                p["speed_mps"], p["height_m"], 0.0, 0.0, 0.0, 0.0)
            for p in params["legs"] if p["duration_s"] >= 150.0]
    assert len(legs) == 4  # transit at 90 deg and three survey lines at 20 / 200 deg
    reps = [replay_leg(imu, a, leg, sigma_floor_mps=0.001) for leg in legs]
    arw = np.radians(params["imu_errors"]["gyro_arw_dpsh"][0]) / 60.0
    d = diagnose_replays(reps, DiagnosisOptions(
        base_formulation="paper", noise="gyro_rw", gyro_arw_radpsqrts=arw,
        effects=("body_fixed_gyro_bias", "vertical_gyro_drift", "accel_bias_change",
                 "gravity_disturbance")), imu=imu, solution_a=a)
    assert d.named[:1] == ("body_fixed_gyro_bias",)
    s = d.steps[0]
    assert s.p_value < 1e-10 and s.explained_fraction > 0.9
    # the paper model misses ~0.45 m/s RMS; with the body-fixed bias the gap is the ARW's
    assert s.gap_before_mps > 0.3 and s.gap_after_mps < 0.015
    assert s.heldout_gap_after_mps < 0.1 * s.heldout_gap_before_mps
    # equal speeds: the along-track (x) bias is confounded with the heading error through the
    # transport rate (docs/diagnose.md), so only the size in the observable direction is
    # checked: its cross-track part, about -0.4 deg/h on every leg
    assert s.values[1] == pytest.approx(-0.4, abs=0.1)
