"""Fault injection through the whole pipeline: every "silent wrong answer" of issue 13 must end
non-ok with the failing QC check named (and what the data suggest, where it can be estimated).

Each case cuts the first 720 s of the bundled sample flight (240 s static, take-off, climb,
survey line 1, a 180 deg turn at 4 deg/s and the start of line 2; the simulator's truth:
lever arm [0.3, 0.1, -1.5] m FRD, no GNSS time offset), damages it in one way, writes it as
MCAP and runs ``pospp.pipeline.process_flight`` on it. The window has one leg and so no
calibration: the clean window is "partial" with ``calibration`` as its only failed check,
which is what the faults are compared against. The clean full sample staying "ok" is asserted by
tests/e2e/test_pipeline.py (slow) and the reference cases below.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pospp import pipeline
from pospp.config import load_config
from pospp.io import parquet_tables
from pospp.io.mcap_reader import read_flight_log
from pospp.io.mcap_writer import write_flight_log
from pospp.report.summary import summary_text

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_data" / "sample_flight.mcap"
SAMPLE_PIPELINE = REPO / "pipelines" / "sample.toml"
WINDOW_S = 720.0


def _config(**sections):
    cfg = load_config(SAMPLE_PIPELINE)
    cfg = replace(cfg, outputs=replace(cfg.outputs, mcap=False, report=False, diagnose=False))
    for name, values in sections.items():
        cfg = replace(cfg, **{name: replace(getattr(cfg, name), **values)})
    return cfg


@pytest.fixture(scope="module")
def window():
    log = read_flight_log(SAMPLE)
    t0 = int(log.imu.time_ns[0])

    def keep(obj):
        m = obj.time_ns < t0 + int(WINDOW_S * 1e9)
        return replace(obj, **{k: v[m] for k, v in vars(obj).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == m.shape})

    return keep(log.imu), keep(log.fix), keep(log.vel)


def _run(tmp_path: Path, imu, fix, vel, config=None, name="case"):
    path = tmp_path / f"{name}.mcap"
    write_flight_log(path, imu, fix, vel)
    out = pipeline.process_flight(path, config or _config(), tmp_path / f"run_{name}")
    qc = parquet_tables.read_table(out.out_dir / "qc.parquet")
    return out, qc


def _failed(qc) -> dict[str, str]:
    bad = qc[~qc.passed]
    return dict(zip(bad.check, bad.suggestion, strict=True))


def test_clean_window_fails_only_the_calibration_check(window, tmp_path):
    out, qc = _run(tmp_path, *window, name="clean")
    assert out.status == "partial"
    assert _failed(qc).keys() == {"calibration"}, qc.to_string()
    assert out.summary["qc_failed_checks"] == "calibration"
    # margins on clean data (docs/qc.md): each statistic well inside its threshold
    row = qc.set_index("check")
    assert row.loc["gravity_direction", "value"] < 1.0  # deg, threshold 45
    assert row.loc["gnss_time_offset", "value"] < 0.03  # s, threshold 0.1
    assert row.loc["lever_arm", "value"] == 0.0  # no axis beyond 5 sigma and 0.2 m
    assert row.loc["gnss_jumps", "value"] < 0.0  # m, threshold 30


def test_flu_log_declared_frd_fails_and_says_flu(window, tmp_path):
    out, qc = _run(tmp_path, *window, config=_config(input={"sensor_frame": "frd"}),
                   name="frd")
    assert out.status == "failed"
    failed = _failed(qc)
    assert "gravity_direction" in failed
    assert "the IMU looks FLU, not FRD" in failed["gravity_direction"]
    text = summary_text({"summary": parquet_tables.read_table(
        out.out_dir / "summary.parquet"), "qc": qc})
    assert "the IMU looks FLU, not FRD" in text and "status: failed" in text


@pytest.mark.parametrize("late_s, said", [(2.0, "GNSS lags the IMU by about 2.0 s"),
                                          (0.2, "GNSS lags the IMU by about 0.2 s")])
def test_late_gnss_stamps_are_estimated(window, tmp_path, late_s, said):
    imu, fix, vel = window
    dt = np.int64(round(late_s * 1e9))
    out, qc = _run(tmp_path, imu, replace(fix, time_ns=fix.time_ns + dt),
                   replace(vel, time_ns=vel.time_ns + dt), name=f"late{late_s}")
    assert out.status == "degraded"
    failed = _failed(qc)
    assert said in failed["gnss_time_offset"], failed
    assert "gnss_time_offset" in out.summary["qc_failed_checks"].split(",")
    assert said in out.summary["qc_suggestions"]


@pytest.mark.parametrize(("late_s", "said"), [
    (0.03, "GNSS lags the IMU by 2"), (18.0, "18 s, the GPS time - UTC difference")])
def test_late_gnss_is_named_with_its_size(window, tmp_path, late_s, said):
    """Issue 38 item 3 and issue 33: 30 ms late is the time offset with its size (the
    window's take-off roll separates it from a forward lever arm: jointly, 29.0 +- 0.9 ms; the
    lever-arm check passes at that offset), not half of it as a lever-arm remark (the
    lever-arm pass alone read about 1.8 m, "lags by 0.030 s", and at 50 ms "0.034 s");
    18 s late is found (the search stopped at 5 s) and named as the GPS-UTC leap seconds."""
    imu, fix, vel = window
    dt = np.int64(round(late_s * 1e9))
    out, qc = _run(tmp_path, imu, replace(fix, time_ns=fix.time_ns + dt),
                   replace(vel, time_ns=vel.time_ns + dt), name=f"late{late_s}")
    assert out.status == "degraded"
    row = qc.set_index("check").loc["gnss_time_offset"]
    assert not row.passed and abs(row.value - late_s) < 0.25 * late_s
    assert said in row.suggestion, row.suggestion
    if late_s < 0.1:
        assert "time_offset, IMU minus GNSS time, -" in row.suggestion
        assert qc.set_index("check").loc["lever_arm", "passed"]


def test_5km_step_in_the_gnss_track_fails(window, tmp_path):
    imu, fix, vel = window
    t = (fix.time_ns - imu.time_ns[0]) * 1e-9
    lat = fix.lat_rad + np.where(t > 500.0, 5000.0 / 6.37e6, 0.0)
    out, qc = _run(tmp_path, imu, replace(fix, lat_rad=lat), vel, name="jump")
    assert out.status == "degraded"
    failed = _failed(qc)
    assert "jumps by 49" in failed["gnss_jumps"] or "jumps by 50" in failed["gnss_jumps"]
    assert "at t = 500" in failed["gnss_jumps"] or "t = 500.0 s" in failed["gnss_jumps"]


@pytest.mark.parametrize("lever", [(0.0, 0.0, 0.0), (-0.3, -0.1, 1.5)])
def test_wrong_lever_arm_is_estimated(window, tmp_path, lever):
    out, qc = _run(tmp_path, *window, config=_config(gnss={"lever_arm_m": lever}),
                   name=f"lever{lever[2]}")
    assert out.status == "degraded"
    failed = _failed(qc)
    assert "the data suggest a lever arm of [" in failed["lever_arm"]
    est = json.loads(failed["lever_arm"].split("lever arm of ")[1].split(" m")[0])
    # the simulator's antenna is at [0.3, 0.1, -1.5] m
    assert np.allclose(est, [0.3, 0.1, -1.5], atol=0.3), est


def test_truncated_log_is_not_ok(window, tmp_path):
    path = tmp_path / "full.mcap"
    write_flight_log(path, *window)
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.8)])
    out = pipeline.process_flight(cut, _config(), tmp_path / "run_cut")
    qc = parquet_tables.read_table(out.out_dir / "qc.parquet")
    assert out.status != "ok"
    assert "data_complete" in _failed(qc)


def test_non_positive_horizon_fails(window, tmp_path):
    out, qc = _run(tmp_path, *window, config=_config(replay={"horizon_s": -300.0}),
                   name="horizon")
    assert out.status == "failed"
    assert "replay.horizon_s: expected a value >= 1, <= 86400, got -300.0" in _failed(qc)["config"]


def test_window_longer_than_the_data_is_not_ok(window, tmp_path):
    out, qc = _run(tmp_path, *window, config=_config(input={"start_s": 0.0, "end_s": 900.0}),
                   name="window")
    assert out.status == "degraded"
    assert "of the 900.0 s configured window" in _failed(qc)["data_complete"]


def test_gnss_lost_over_the_leg_is_not_ok_and_the_leg_is_refused(window, tmp_path):
    """GNSS stopping 400 s in (the window's leg starts at 338 s): every check passed, the
    trajectory drifted free-inertial and the calibration used the leg (issue 38 item 1)."""
    imu, fix, vel = window

    def before(obj):
        m = obj.time_ns < imu.time_ns[0] + 400 * 10**9
        return replace(obj, **{k: v[m] for k, v in vars(obj).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == m.shape})

    out, qc = _run(tmp_path, imu, before(fix), before(vel), name="gnss_lost")
    assert out.status == "degraded"
    sug = _failed(qc)["gnss_coverage"]
    assert "no GNSS from t = 400 s to the end of the data (320 s, 44 % of the flight" in sug
    assert "leg 0 in it" in sug and "leg 0 refused by the calibration" in sug
    legs = parquet_tables.read_table(out.out_dir / "legs.parquet")
    assert legs.reason.iloc[0].startswith("reference A not GNSS-aided: no GNSS record "
                                          "from t = 400 s to the end of the data")


@pytest.mark.parametrize("lever", [None, (-0.10, 0.30, -1.52)], ids=["configured", "advised"])
def test_wrong_mounting_yaw_is_named_not_the_lever_arm(window, tmp_path, lever):
    """``mounting_rpy_deg = [0, 0, 90]`` on the sample: "degraded" with the advice to rotate the
    lever arm by 90 deg, and following it gave "ok" with an 89 deg heading error (issue 38
    item 2). A's heading is compared with the GNSS course; the lever-arm suggestion names the
    mounting."""
    cfg = _config(input={"mounting_rpy_deg": (0.0, 0.0, 90.0)},
                  **({} if lever is None else {"gnss": {"lever_arm_m": lever}}))
    out, qc = _run(tmp_path, *window, config=cfg, name=f"yaw90_{lever is None}")
    assert out.status == "failed"
    failed = _failed(qc)
    assert "A's heading is -90.0 deg off the GNSS course" in failed["mounting_yaw"]
    assert "mounting_rpy_deg = [0, 0, 0]" in failed["mounting_yaw"]
    if lever is None:
        assert "is the configured lever arm rotated by +90 deg about body z: the IMU mounting " \
            "is wrong, not the lever arm" in failed["lever_arm"]
        assert "set [gnss] lever_arm_m" not in failed["lever_arm"]
