"""pospp.qc.checks against closed forms and seeded synthetic data (no filter runs).

Each check is fed data whose answer is known outside pospp: gravity and the Earth rate from
their WGS-84 definitions, NIS from scipy's chi-square generator, a time offset built into a
synthetic turning track, a 5 km step, and the statuses' order.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from scipy.stats import poisson

from pospp import earth
from pospp.config import PipelineConfig
from pospp.io import parquet_tables
from pospp.qc import checks as qc
from pospp.qc import time_offset
from pospp.qc.check_record import Check
from pospp.qc.stage import QualityReport, config_problems, qc_columns, worst_status
from pospp.report.summary import qc_lines
from pospp.types import FLU_TO_FRD

LAT = math.radians(34.25)
DPH = math.pi / 180.0 / 3600.0


def _static_imu(rng, n=24_000, dt=0.01, heading=0.3, gyro_bias_dph=(1.0, -1.0, 1.0)):
    """At rest, level, FRD: f = [0, 0, -g], w = C_bn w_ie_n + bias + noise."""
    g = float(earth.normal_gravity_mps2(LAT, 400.0))
    c_nb = np.array([[math.cos(heading), -math.sin(heading), 0.0],
                     [math.sin(heading), math.cos(heading), 0.0], [0.0, 0.0, 1.0]])
    w_ie_n = earth.EARTH_RATE_RADPS * np.array([math.cos(LAT), 0.0, -math.sin(LAT)])
    w = c_nb.T @ w_ie_n + np.asarray(gyro_bias_dph) * DPH
    arw = math.radians(0.01) / 60.0  # 0.01 deg/sqrt(h)
    ws = w + rng.normal(0.0, arw / math.sqrt(dt), (n, 3))
    fs = np.array([0.0, 0.0, -g]) + rng.normal(0.0, 0.01, (n, 3))
    return ws, fs, dt


def test_gravity_direction_names_an_flu_imu_declared_frd():
    rng = np.random.default_rng(1)
    _, f_frd, _ = _static_imu(rng)
    f_flu = f_frd @ FLU_TO_FRD  # FLU_TO_FRD is its own inverse: the same vector in FLU axes
    static = np.ones(len(f_frd), dtype=bool)
    good = qc.gravity_direction(f_frd, static, np.eye(3), "frd")
    assert good.passed and good.value < 0.5  # deg; the level body's 0 within noise
    # an FLU log read as FRD: f_b = f_s, up along +z
    bad = qc.gravity_direction(f_flu, static, np.eye(3), "frd")
    assert not bad.passed and bad.value > 179.0 and bad.severity == "failed"
    assert "the IMU looks FLU, not FRD" in bad.suggestion
    # an FRD log declared FLU: the reader applies FLU->FRD to FRD axes
    back = qc.gravity_direction(f_frd @ FLU_TO_FRD.T, static, FLU_TO_FRD, "flu")
    assert not back.passed and "the IMU looks FRD, not FLU" in back.suggestion
    # a 90 deg mounting error: gravity along a horizontal axis
    side = qc.gravity_direction(f_frd[:, [2, 1, 0]], None, np.eye(3), "frd")
    assert not side.passed and 89.0 < side.value < 91.0
    assert "the sensor's -x axis points up" in side.suggestion


def test_gravity_magnitude_catches_a_scale_error():
    rng = np.random.default_rng(2)
    _, f, _ = _static_imu(rng)
    static = np.ones(len(f), dtype=bool)
    ok = qc.gravity_magnitude(f, static, LAT, 400.0)
    assert ok.passed and ok.value < 0.01  # m/s^2 against 0.2
    bad = qc.gravity_magnitude(f * 1.05, static, LAT, 400.0)
    assert not bad.passed and abs(bad.value - 0.05 * 9.797) < 0.01


def test_earth_rate_at_rest_and_a_wrong_unit():
    rng = np.random.default_rng(3)
    w, f, dt = _static_imu(rng)
    static = np.ones(len(w), dtype=bool)
    kw = {"gyro_bias_sigma_radps": 1.0 * DPH, "gyro_arw_radpsqrts": math.radians(0.01) / 60.0}
    ok = qc.earth_rate(w, f, static, dt, LAT, **kw)
    # misfit bounded by the 1 deg/h biases (|b| sqrt(3) at most): well below 5 sigma (5 deg/h)
    assert ok.passed and ok.value < 1.8 and ok.threshold == pytest.approx(5.0, rel=0.01)
    bad = qc.earth_rate(w * 3.0, f, static, dt, LAT, **kw)  # a scale error of 3
    assert not bad.passed and "Earth rate" in bad.suggestion
    # a MEMS grade cannot see 15 deg/h: not applicable, passes
    mems = qc.earth_rate(w * 3.0, f, static, dt, LAT, gyro_bias_sigma_radps=20.0 * DPH,
                         gyro_arw_radpsqrts=kw["gyro_arw_radpsqrts"])
    assert mems.passed and math.isnan(mems.value) and "cannot see" in mems.statistic
    short = qc.earth_rate(w, f, static & (np.arange(len(w)) < 3000), dt, LAT, **kw)
    assert short.passed and "at rest" in short.statistic


def test_earth_rate_over_a_start_and_a_stop_at_other_headings():
    """The flight preset's 10 min start at heading 60 deg and 5 min stop at another heading:
    the vector mean of the two shrinks the horizontal Earth rate by cos(dpsi / 2) (the
    6.4 deg/h false alarm); per stretch it is the 1 deg/h biases again."""
    rng = np.random.default_rng(5)
    w1, f1, dt = _static_imu(rng, n=60_000, heading=math.radians(60.0))
    moving = np.zeros((3000, 3))  # a flight between, not at rest
    w2, f2, _ = _static_imu(rng, n=30_000, heading=math.radians(60.0 + 150.0))
    w = np.vstack([w1, moving, w2])
    f = np.vstack([f1, moving + f1[:3000], f2])
    static = np.r_[np.ones(60_000, bool), np.zeros(3000, bool), np.ones(30_000, bool)]
    kw = {"gyro_bias_sigma_radps": math.hypot(1.0, 0.5) * DPH,
          "gyro_arw_radpsqrts": math.radians(0.01) / 60.0}
    c = qc.earth_rate(w, f, static, dt, LAT, **kw)
    assert c.passed and c.value < 1.8 and "2 stretch" in c.statistic
    # the old statistic, one mean over both: |w_h| = 0.41 Omega cos L, a 7 deg/h miss
    wm = w[static].mean(axis=0)
    om_h = earth.EARTH_RATE_RADPS * math.cos(LAT) / DPH
    assert om_h - np.hypot(wm[0], wm[1]) / DPH > c.threshold
    # a 3x scale error still fails per stretch; stretches under 10 s are left out
    assert not qc.earth_rate(3.0 * w, f, static, dt, LAT, **kw).passed
    flicker = static & (np.arange(len(w)) % 500 < 400)  # 4 s stretches
    assert "stretches" in qc.earth_rate(w, f, flicker, dt, LAT, **kw).statistic


def test_gravity_magnitude_of_a_vibrating_log_without_rest():
    """6 m/s^2 RMS per axis of 50 Hz vibration (the simulator's MEMS airframe) averages out
    over 1 s blocks; the samples' median |f| is several m/s^2 above gravity."""
    rng = np.random.default_rng(6)
    _, f, dt = _static_imu(rng, n=20_000)
    t = np.arange(len(f)) * dt
    phase = rng.uniform(0.0, 2.0 * math.pi, 3)
    f = f + 6.0 * math.sqrt(2.0) * np.sin(2.0 * math.pi * 50.3 * t[:, None] + phase)
    assert not qc.gravity_magnitude(f, None, LAT, 400.0).passed  # per sample: > 1 m/s^2
    ok = qc.gravity_magnitude(f, None, LAT, 400.0, window_n=int(round(1.0 / dt)))
    assert ok.passed and ok.value < 0.1


def test_nis_band_passes_chi_square_and_fails_a_mistuned_filter():
    rng = np.random.default_rng(4)
    t = np.arange(3000.0)
    nis = rng.chisquare(3, t.shape[0])
    ok = qc.nis_band(t, nis)
    assert ok.passed and ok.value <= 0.02  # per-window false alarm 1e-3, 50 windows
    # GNSS noise 2x what the filter assumes: NIS x4
    bad = qc.nis_band(t, 4.0 * nis)
    assert not bad.passed and bad.value > 0.9 and bad.time_ns_offset is not None
    assert qc.nis_band(t[:10], nis[:10]).passed  # too few records: not applicable


def test_gnss_gate_against_the_filters_own_gate_probability():
    """gnss_gate: the count of gated records against the Poisson quantile of A's own gate
    (3300 records at 0.9999: mean 0.33). The warm-up mission's null flights gate 0-2 (pass),
    a 600 ug warm-up 33-39 with one reset (fail, timed at the first rejection); where A's
    model holds the check fails in at most 1e-3 of runs (the exact Poisson tail)."""
    assert qc.gnss_gate(3300, 0, 0.9999).passed
    ok = qc.gnss_gate(3300, 2, 0.9999, 300.0)
    assert ok.passed and ok.time_ns_offset is None and ok.threshold == 3.0
    bad = qc.gnss_gate(3300, 34, 0.9999, 212.0)
    assert not bad.passed and bad.severity == "degraded"
    assert bad.time_ns_offset == 212 * 10**9 and "34 of 3300" in bad.suggestion
    for n, p in ((3300, 0.9999), (40000, 0.9999), (500, 0.999)):
        lam, limit = n * (1.0 - p), qc.gnss_gate(n, 0, p).threshold
        # the smallest count whose Poisson upper tail is at most GATE_TAIL
        assert poisson.sf(limit, lam) <= qc.GATE_TAIL < poisson.sf(limit - 1, lam), (n, p)
    assert qc.gnss_gate(0, 0, 0.9999).passed  # nothing processed: nothing to reject


def _track(tau_s: float, *, noise_rad: float = 0.0, seed: int = 5):
    """A vehicle at 60 m/s with three 180 deg turns at 4 deg/s; the heading is the course.

    IMU at 100 Hz: w_d the exact mean yaw rate over each interval; GNSS velocity at 1 Hz,
    stamped tau_s late (the state at t - tau).
    """
    rate = math.radians(4.0)

    def heading(t):
        h = np.zeros_like(t)
        for t0 in (200.0, 500.0, 800.0):
            h += rate * np.clip(t - t0, 0.0, 45.0)
        return h

    t = np.arange(0.0, 1000.0, 0.01)
    h = heading(t)
    w_d = np.concatenate([[0.0], np.diff(h) / 0.01])
    tv = np.arange(10.0, 990.0, 1.0)
    hv = heading(tv - tau_s) + np.random.default_rng(seed).normal(0.0, noise_rad, tv.shape)
    v = 60.0 * np.column_stack([np.cos(hv), np.sin(hv), np.zeros_like(hv)])
    return t, w_d, tv, v


@pytest.mark.parametrize("tau", [0.0, 0.2, 2.0, -0.5])
def test_time_offset_from_the_turns(tau):
    est = time_offset.estimate_time_offset(*_track(tau, noise_rad=0.002))
    assert est is not None and est.explained > 0.9
    assert abs(est.offset_s - tau) < max(5.0 * est.sigma_s, 0.01), est
    check = time_offset.gnss_time_offset(est)
    assert check.passed == (abs(tau) < 0.1)
    if tau == 2.0:
        assert "GNSS lags the IMU by about 2.0 s" in check.suggestion
    if tau == -0.5:
        assert "GNSS leads the IMU by about 0.5 s" in check.suggestion


def test_time_offset_not_applicable_without_turns_or_when_flying_sideways():
    t, w_d, tv, v = _track(0.0)
    still = time_offset.estimate_time_offset(t, 0.0 * w_d, tv, v[:, [0, 0, 2]])
    assert time_offset.gnss_time_offset(still).passed
    # yaw without course change (a multirotor turning on the spot while it flies north)
    est = time_offset.estimate_time_offset(t, w_d, tv, np.tile([5.0, 0.0, 0.0], (tv.shape[0], 1)))
    chk = time_offset.gnss_time_offset(est)
    assert chk.passed and "course does not follow" in chk.statistic


def test_time_offset_grid_costs_are_one_interp_and_one_sum_per_tau_bit_for_bit():
    """The grid's squared misfits laid out record by record (np.interp then finds each query
    next to the last), summed over any subset of the records (the refit without outliers),
    are the per-tau evaluation of that subset's numbers exactly: uneven IMU stamps, records
    inside and at the ends, chunks that do not divide the grid."""
    rng = np.random.default_rng(11)
    t = np.cumsum(rng.uniform(0.004, 0.006, 20000))
    psi = np.cumsum(rng.normal(0.0, 1e-3, t.shape[0]))
    t0 = np.sort(rng.uniform(t[0] + 5.0, t[-1] - 6.0, 300))
    t1 = t0 + rng.uniform(0.5, 1.0, t0.shape[0])
    dchi = rng.normal(0.0, 0.01, t0.shape[0])
    grid = np.arange(-5.0, 5.0 + 1e-9, 0.02)
    keep = rng.uniform(size=t0.shape[0]) > 0.1
    for k in (np.ones_like(keep), keep):
        ref = np.array([np.sum((dchi[k] - (np.interp(t1[k] - g, t, psi)
                                           - np.interp(t0[k] - g, t, psi))) ** 2)
                        for g in grid])
        for chunk in (1, 64, 500, 1000):
            sq = time_offset._grid_squares(grid, t, psi, t0, t1, dchi, chunk=chunk)
            np.testing.assert_array_equal([np.sum(row[k]) for row in sq], ref)


def test_gnss_jump_of_5km_is_found_with_its_time():
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 600.0, 1.0)
    v = np.tile([60.0, 0.0, 0.0], (t.shape[0], 1))
    r = np.column_stack([60.0 * t, np.zeros_like(t), np.zeros_like(t)])
    r += rng.normal(0.0, 0.1, r.shape)
    ok = qc.gnss_jumps(t, r, t, v)
    assert ok.passed and ok.value < -4.0  # 0.5 m of noise less the 5 m allowance
    r[300:, 1] += 5000.0
    bad = qc.gnss_jumps(t, r, t, v)
    assert not bad.passed and "jumps by 5000 m between t = 299.0 s and 300.0 s" in \
        bad.suggestion
    assert bad.time_ns_offset == 300 * 10**9


def test_lever_arm_check_and_its_time_offset_reading():
    sig = np.full(3, 0.02)
    assert qc.lever_arm([0.3, 0.1, -1.5], [0.31, 0.09, -1.48], sig).passed
    bad = qc.lever_arm([0.0, 0.0, 0.0], [0.3, 0.1, -1.5], sig)
    assert not bad.passed and bad.value == pytest.approx(1.5)
    assert "the data suggest a lever arm of [0.30, 0.10, -1.50] m" in bad.suggestion
    # an unobservable axis (sigma 1 m) does not count
    assert qc.lever_arm([0.0, 0.0, 0.0], [0.0, 0.0, -1.5], [0.02, 0.02, 1.0]).passed
    # GNSS 15 ms late at 60 m/s looks like the antenna 0.9 m behind
    along = qc.lever_arm([0.0, 0.0, 0.0], [-0.9, 0.0, 0.0], sig, mean_speed_mps=60.0)
    assert "GNSS lags the IMU by about 0.015 s" in along.suggestion


def test_lever_arm_counts_only_the_axes_the_attitude_reveals():
    n = 600
    level = np.zeros((n, 3))
    assert not qc.lever_arm_observable(level).any()
    chk = qc.lever_arm([0.0, 0.0, 0.0], [0.0, 0.0, -0.7], np.full(3, 0.05),
                       observable=qc.lever_arm_observable(level))
    assert chk.passed and "no turn" in chk.statistic
    turn = level.copy()
    turn[:, 2] = np.linspace(0.0, math.pi, n)  # a 180 deg turn, wings level
    assert qc.lever_arm_observable(turn).tolist() == [True, True, False]
    turn[n // 3: 2 * n // 3, 0] = math.radians(23.0)  # banked at 4 deg/s and 60 m/s
    assert qc.lever_arm_observable(turn).all()


def test_completeness_calibration_compensation_and_config():
    assert qc.data_complete(True, 0, "", 100.0, None).passed
    cut = qc.data_complete(False, 1, "truncated at byte 8931240", 1316.0, None)
    assert not cut.passed and cut.value == 2.0 and "8931240" in cut.suggestion
    short = qc.data_complete(True, 0, "", 1316.0, 1634.0)
    assert not short.passed and "1316.0 s of the 1634.0 s" in short.suggestion
    nocal = qc.calibration_quality(False, "no calibration: no pair passed", 0)
    assert not nocal.passed and nocal.severity == "partial"
    # the check's name already says calibration: the reason is not prefixed twice (issue 13)
    assert nocal.suggestion == "no pair passed"
    twice = qc.calibration_quality(False, "no calibration: no calibration: only one leg", 0)
    assert twice.suggestion == "only one leg"
    assert "no calibration" not in QualityReport((twice,)).suggestions
    assert not qc.compensation_gain(0.1, 0.5).passed and qc.compensation_gain(2.3, 0.3).passed
    cfg = PipelineConfig()
    assert config_problems(cfg) == []
    bad = replace(cfg, replay=replace(cfg.replay, horizon_s=-300.0),
                  filter=replace(cfg.filter, output_rate_hz=0.0))
    problems = config_problems(bad)
    assert "replay.horizon_s: expected a value >= 1, <= 86400, got -300.0" in problems
    assert any("output_rate_hz" in p for p in problems)
    assert qc.config_sanity(problems).severity == "failed"


def test_status_table_and_console_lines(tmp_path):
    a = Check("a", "ingest", "s", 1.0, 2.0, "m", True, "failed")
    b = Check("b", "navigate", "s", 3.0, 2.0, "m", False, "degraded", "do this")
    c = Check("c", "calibrate", "s", 0.0, 1.0, "1", False, "partial")
    rep = QualityReport((a, b, c))
    assert rep.status == "degraded" and rep.failed_names == "b,c"
    assert rep.suggestions == "b: do this"
    assert QualityReport((a,)).status == "ok"
    assert worst_status("partial", "ok") == "partial"
    assert worst_status("ok", "failed", "degraded") == "failed"
    path = tmp_path / "qc.parquet"
    parquet_tables.write_table(path, qc_columns(rep, 10**18), "qc", metadata={})
    back = parquet_tables.read_table(path)
    assert list(back.check) == ["a", "b", "c"] and back.passed.tolist() == [True, False, False]
    assert back.time_ns.isna().all()
    lines = qc_lines(back)
    assert "quality checks FAILED: b, c" in lines[0] and "do this" in lines[1]
    assert qc_lines(pd.DataFrame(qc_columns(QualityReport((a,)), 0)))[0].endswith("all 1 passed")


def test_report_opens_with_the_quality_checks():
    from pospp.report.html import render_report

    bad = Check("gnss_time_offset", "navigate", "s", 2.0, 0.1, "s", False, "degraded",
                   "GNSS lags the IMU by about 2.0 s")
    good = Check("gravity_direction", "ingest", "s", 0.1, 45.0, "deg", True, "failed")
    page = render_report({"summary": pd.DataFrame({"input_file": ["x.mcap"],
                                                   "status": ["degraded"]}),
                          "qc": pd.DataFrame(qc_columns(QualityReport((good, bad)), 0))})
    # the report leads with the answer: the verdict box or the QC section comes first, and the
    # failed check with its suggestion stands before any other section
    heads = [m.start() for m in re.finditer("<h2>", page)]
    assert page[heads[0]:].startswith(("<h2>The answer", "<h2>Quality checks"))
    later = [h for h in heads if not page[h:].startswith(("<h2>The answer", "<h2>Quality"))]
    assert page.index("GNSS lags the IMU") < (later[0] if later else len(page))
    assert "GNSS lags the IMU by about 2.0 s" in page and "failed: gnss_time_offset" in page


def test_model_fit_counts_unmodelled_effects_and_a_gap_that_could_bias_the_calibration():
    # issue 34: a named effect the calibration does not model fails the check when its refit
    # moves the gyro bias beyond MODEL_FIT_SIGMAS (or there is no refit); so does a
    # significant unexplained gap standing for more than that
    nan, sigma, bar = math.nan, 1e-7, qc.MODEL_FIT_SIGMAS
    ok = qc.model_fit([], nan, nan, 0.05, nan, sigma, [])
    assert ok.name == "model_fit" and ok.passed and ok.value == 0 and ok.suggestion == ""
    named = qc.model_fit(["accel_bias_change"], 1.1 * bar, nan, 0.05, nan, sigma,
                         ["the ramp; refit"])
    assert not named.passed and named.value == 1 and named.severity == "degraded"
    assert named.suggestion == "the ramp; refit"
    assert qc.model_fit(["accel_bias_change"], 0.9 * bar, nan, 0.05, nan, sigma, ["r"]).passed
    assert not qc.model_fit(["lever_arm"], nan, nan, 0.05, nan, sigma, ["r"]).passed  # no refit
    gap = qc.model_fit([], nan, 0.001, 0.05, 1.1 * bar * sigma, sigma, [], "the gap")
    assert not gap.passed and gap.value == 1 and gap.suggestion == "the gap"
    assert qc.model_fit([], nan, 0.001, 0.05, 0.9 * bar * sigma, sigma, [], "gap").passed
    assert qc.model_fit([], nan, 0.2, 0.05, 1.1 * bar * sigma, sigma, [], "gap").passed
    both = qc.model_fit(["lever_arm", "time_offset"], 3 * bar, 0.001, 0.05, 3 * bar * sigma,
                        sigma, ["a"], "b")
    assert both.value == 3 and both.suggestion == "a; b"


def test_the_registry_names_every_check_in_the_docs():
    """QC_CHECKS' rows name their checks; each is in docs/qc.md's table of checks."""
    import re
    from pathlib import Path

    from pospp.qc.stage import QC_CHECKS

    repo = Path(__file__).resolve().parents[2]
    names = {n for row, _ in QC_CHECKS for n in row}
    documented = set(re.findall(r"^\| `([a-z_]+)` \|", (repo / "docs" / "qc.md").read_text(),
                                re.M))
    assert names <= documented, names - documented
