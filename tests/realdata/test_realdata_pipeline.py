"""The whole pipeline on the measured logs of ../shared/data (docs/results.md).

Each dataset is converted once per module into tmp and run with its pipelines/realdata/*.toml;
the assertions are the measured figures of docs/results.md with margins. The references are
outside the pipeline: comma's fused pose (independent of the u-blox fixes the filter uses), the
DJI RTK/INS solution (the quadrotor's GNSS input itself: checks frames and consistency, not
accuracy) and, for the SYNTHETIC tactical IMU along the KF-GINS drive, the simulator's injected
errors. The first tests (per-grade leg thresholds) need no data.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pospp import pipeline
from pospp.api.studies import evaluate_run
from pospp.config import (
    LEG_DURATION_TOLERANCE_BY_GRADE_S,
    LEG_MIN_DURATION_BY_GRADE_S,
    ConfigError,
    ImuConfig,
    LegsConfig,
    PipelineConfig,
    config_from_dict,
    load_config,
)
from pospp.convert import convert
from pospp.io.mcap_reader import read_flight_log

REPO = Path(__file__).resolve().parents[2]
PIPELINES = REPO / "pipelines" / "realdata"
ARCSEC_PER_DEG = 3600.0


# --- [legs] min_duration_s per [imu] grade (no data needed) ------------------------------------


@pytest.mark.parametrize("grade", ["flight", "vehicle", "tactical", "mems"])
def test_omitted_min_duration_takes_the_grade_default(grade):
    cfg = config_from_dict({"imu": {"grade": grade}, "legs": {"min_speed_mps": 5.0}})
    assert cfg.legs.min_duration_s == LEG_MIN_DURATION_BY_GRADE_S[grade]
    assert cfg.legs.duration_tolerance_s == LEG_DURATION_TOLERANCE_BY_GRADE_S[grade]
    assert cfg.legs.min_speed_mps == 5.0
    direct = PipelineConfig(imu=ImuConfig(grade=grade))
    assert direct.legs.min_duration_s == LEG_MIN_DURATION_BY_GRADE_S[grade]
    assert direct.legs.duration_tolerance_s == LEG_DURATION_TOLERANCE_BY_GRADE_S[grade]


def test_grade_defaults_are_the_paper_and_the_measured_values():
    # flight and vehicle keep the paper's 5 min; tactical and mems: the study's 30 s, with a
    # tolerance that keeps every accepted leg >= 20 s (two epochs of the 10 s noise grid)
    assert LEG_MIN_DURATION_BY_GRADE_S["flight"] == LEG_MIN_DURATION_BY_GRADE_S["vehicle"] == 300
    for grade in ("tactical", "mems"):
        shortest = LEG_MIN_DURATION_BY_GRADE_S[grade] - LEG_DURATION_TOLERANCE_BY_GRADE_S[grade]
        assert 20.0 <= shortest < 300.0
    assert PipelineConfig().legs.min_duration_s == 300.0  # default grade "flight"
    assert PipelineConfig().legs.duration_tolerance_s == 15.0


def test_explicit_min_duration_wins_and_round_trips():
    cfg = config_from_dict({"imu": {"grade": "mems"},
                            "legs": {"min_duration_s": 45, "duration_tolerance_s": 0}})
    assert cfg.legs.min_duration_s == 45.0 and cfg.legs.duration_tolerance_s == 0.0
    again = config_from_dict(json.loads(cfg.to_json()))
    assert again == cfg and again.to_json() == cfg.to_json()
    # a resolved default is recorded in the run's config, so a re-read config is identical
    dflt = config_from_dict({"imu": {"grade": "tactical"}})
    assert config_from_dict(json.loads(dflt.to_json())) == dflt
    assert PipelineConfig(legs=LegsConfig(min_duration_s=7.0),
                          imu=ImuConfig(grade="mems")).legs.min_duration_s == 7.0


@pytest.mark.parametrize("data, message", [
    ({"legs": {"min_duration_s": "short"}}, "legs.min_duration_s: expected a number"),
    ({"legs": {"duration_tolerance_s": [1]}}, "legs.duration_tolerance_s: expected a number"),
    ({"imu": {"grade": "navigation"}}, "imu.grade: expected one of"),
])
def test_bad_values_still_name_the_key(data, message):
    with pytest.raises(ConfigError, match=message):
        config_from_dict(data)


def test_realdata_pipelines_load():
    names = sorted(p.stem for p in PIPELINES.glob("*.toml"))
    assert names == ["ansfl_quadrotor_straightline", "ardupilot_plane_testlog2",
                     "comma2k19_example1", "kfgins_synthetic_tactical"]
    for p in PIPELINES.glob("*.toml"):
        assert load_config(p).name == p.stem


# --- measured logs -----------------------------------------------------------------------------


def _metrics(table: pd.DataFrame, solution: str) -> dict[str, float]:
    g = table[table.solution == solution]
    return dict(zip(g.metric, g.value, strict=True))


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("realdata_pipeline")


def _run(out_dir: Path, stem: str, pipe: str) -> tuple[pipeline.RunOutcome, Path]:
    cfg = load_config(PIPELINES / f"{pipe}.toml")
    run_dir = out_dir / f"run_{stem}"
    return pipeline.process_flight(out_dir / f"{stem}.mcap", cfg, run_dir), run_dir


@pytest.mark.realdata
def test_ardupilot_runs_end_to_end_and_finds_no_leg(real_data, out_dir):
    convert(real_data / "ardupilot_plane_testlog2", out_dir / "ardupilot.mcap")
    outcome, run_dir = _run(out_dir, "ardupilot", "ardupilot_plane_testlog2")
    s = outcome.summary
    # no leg (partial), and the QC finds that the GNSS model does not fit this log: NIS and
    # A's gate (208 of 3408 records gated where its model allows 3; docs/qc.md). The joint
    # lever-arm / time-offset estimate reads 57.8 ms of GNSS lead, but A's innovations on this
    # log are correlated over tens of seconds (their long-run variance ratio 140, whitened):
    # with that colour its sigma is 57 ms (4.8 ms without), and neither the offset nor the
    # 0.88 m apparent forward lever arm (+- 0.46 m) is significant (issue 33: the offset was
    # named, against AHRS_GPS_DELAY = 2's sign and the course method's 7.6 +- 8.5 ms)
    assert outcome.status == "degraded"
    assert s["qc_failed_checks"] == "gnss_nis,gnss_gate,calibration"
    qc = pd.read_parquet(run_dir / "qc.parquet").set_index("check")
    assert abs(qc.loc["gnss_time_offset", "value"] - 0.0578) < 0.25 * 0.0578
    assert qc.loc["gnss_time_offset", "threshold"] > 0.2  # 5 sigma of the colour-widened tau
    assert "apparent lever arm" in qc.loc["lever_arm", "measure"]
    assert s["n_legs"] == 0 and s["n_pairs_used"] == 0
    assert s["calibration_reason"].startswith("no calibration: no straight, level, uniform leg")
    assert 612.0 < s["duration_s"] < 614.0 and 30_600 < s["n_imu_samples"] < 30_700
    traj = pd.read_parquet(run_dir / "trajectory.parquet")
    sm = traj[traj.solution == "smoothed"]
    assert np.isfinite(sm[["lat_deg", "lon_deg", "height_m"]].to_numpy()).all()
    # A starts once the aircraft moves (272 s: a MEMS grade cannot gyrocompass) and runs on
    fix = read_flight_log(out_dir / "ardupilot.mcap").fix
    t = sm.time_ns.to_numpy()
    assert (t[0] - fix.time_ns[0]) / 1e9 < 300.0 and (fix.time_ns[-1] - t[-1]) / 1e9 < 5.0
    # A stays on its own GNSS track. Measured RMS (max) distance to the fixes: smoothed 4.2 m
    # (11.6 m), forward 9.8 m (33 m); with the converter's 0.3 m/s velocity sigma instead of
    # vel_sigma_floor_mps = 1.0 the forward pass was 31 m (174 m)
    for solution, rms_m, max_m in (("smoothed", 8.0, 25.0), ("forward", 20.0, 60.0)):
        g = traj[traj.solution == solution]
        t = g.time_ns.to_numpy()
        m = (fix.time_ns > t[0]) & (fix.time_ns < t[-1])
        lat = np.interp(fix.time_ns[m], t, np.radians(g.lat_deg.to_numpy()))
        lon = np.interp(fix.time_ns[m], t, np.radians(g.lon_deg.to_numpy()))
        d = np.hypot(lat - fix.lat_rad[m], (lon - fix.lon_rad[m]) * np.cos(lat)) * 6.371e6
        assert np.sqrt(np.mean(d**2)) < rms_m and d.max() < max_m, solution


@pytest.mark.realdata
def test_comma_against_the_fused_reference(real_data, out_dir):
    convert(real_data / "comma2k19_example1", out_dir / "comma.mcap")
    outcome, run_dir = _run(out_dir, "comma", "comma2k19_example1")
    assert outcome.summary["n_legs"] == 0  # the car accelerates from 8 to 20 m/s
    ev = evaluate_run(run_dir, out_dir / "comma.reference.parquet")
    m = _metrics(ev, "smoothed")
    # measured: 2.16 m (mostly a north offset of the u-blox fixes), 0.034 m/s, 1.0 deg heading
    assert m["horizontal_rms"] < 3.0
    assert m["vel_horizontal_rms"] < 0.08
    assert m["vd_rms"] < 0.1
    assert m["heading_rms"] < 2.0 * ARCSEC_PER_DEG
    assert m["roll_pitch_rms"] < 2.0 * ARCSEC_PER_DEG


@pytest.mark.realdata
def test_quadrotor_against_the_dji_solution(real_data, out_dir):
    convert(real_data / "ansfl_quadrotor_straightline", out_dir / "quad.mcap",
            fmt="ansfl_quadrotor_raw", unit=1, recording=2)
    outcome, run_dir = _run(out_dir, "quad", "ansfl_quadrotor_straightline")
    legs = pd.read_parquet(run_dir / "legs.parquet")
    pairs = pd.read_parquet(run_dir / "pairs.parquet")
    # two legs of >= 10 s, both nose-first at 248 deg (end of paths 1 and 2): a same-heading
    # pair, rejected; the 68 deg leg (path 4, flown backwards) lasts only 8 s
    assert len(legs) == 2 and len(pairs) == 1
    assert np.allclose(legs.heading_deg, 248.3, atol=3.0)
    assert legs.duration_s.min() >= 10.0 and legs.duration_s.max() <= 16.0
    assert not pairs.used.iloc[0] and "heading change" in pairs.reason.iloc[0]
    assert outcome.summary["calibration_reason"].startswith("no calibration: no pair passed")
    ev = evaluate_run(run_dir, out_dir / "quad.reference.parquet")
    m, f = _metrics(ev, "smoothed"), _metrics(ev, "forward")
    # measured (smoothed / forward): 0.13 / 0.11 m, 0.16 / 0.18 m/s, heading 1.06 / 1.42 deg,
    # roll-pitch 0.87 / 1.19 deg. With the converter's 0.05 m position sigma the gate locked
    # the GNSS out after each take-off (0.35 / 0.70 m): pos_sigma_floor_m = 0.2 prevents it.
    for r in (m, f):
        assert r["horizontal_rms"] < 0.3
        assert r["vel_horizontal_rms"] < 0.3
        assert r["heading_rms"] < 2.0 * ARCSEC_PER_DEG
        assert r["roll_pitch_rms"] < 2.0 * ARCSEC_PER_DEG


# --- SYNTHETIC tactical IMU along the real KF-GINS street grid ---------------------------------


@pytest.mark.realdata
@pytest.mark.slow
def test_kfgins_synthetic_tactical_recovers_the_injected_gyro_bias(real_data, out_dir):
    # the simulated IMU is defined once, in the results script
    spec = importlib.util.spec_from_file_location("_make_results", REPO / "docs" /
                                                  "_make_results.py")
    results = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(results)
    mean_bias_dph, simulate_kfgins = results.mean_bias_dph, results.simulate_kfgins

    mcap = simulate_kfgins(out_dir, "tactical")
    assert mcap == out_dir / "kfgins_tactical.mcap"
    outcome, run_dir = _run(out_dir, "kfgins_tactical", "kfgins_synthetic_tactical")
    s = outcome.summary
    assert outcome.status == "ok"
    legs = pd.read_parquet(run_dir / "legs.parquet")
    pairs = pd.read_parquet(run_dir / "pairs.parquet")
    # measured: 8 legs of 20-28 s on the grid, 22 of 28 pairs used (the rest same heading)
    assert len(legs) >= 6 and legs.duration_s.min() >= 20.0
    assert pairs.used.sum() >= 12
    assert (pairs[pairs.used].cond_scaled < 30).all()
    cal = pd.read_parquet(run_dir / "calibration.parquet")
    joint = cal[(cal.pair_id == -1) & (cal.formulation == "body")].set_index("parameter")
    truth = mean_bias_dph(out_dir, "kfgins_tactical")
    for k, ax in enumerate("xy"):
        v, sig = joint.loc[f"gyro_bias_{ax}", ["value", "sigma"]]
        assert sig < 2.0  # deg/h (measured 1.17 / 1.05 against a 10 deg/h turn-on grade)
        assert abs(v - truth[k]) < 3.0 * sig, (ax, v, sig, truth[k])
    # compensation shrinks B's error at the leg end (measured 0.139 -> 0.028 m/s)
    assert s["dv_after_mps"] < 0.5 * s["dv_before_mps"]
    assert s["dp_after_m"] < 0.5 * s["dp_before_m"]
    ev = evaluate_run(run_dir, out_dir / "kfgins_tactical.truth.parquet", skip_s=300)
    m = _metrics(ev, "smoothed")
    assert m["horizontal_rms"] < 0.05 and m["heading_rms"] < 150.0
