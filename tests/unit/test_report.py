"""The report and the console summary lead with the answer (issue 15 items 1 and 2).

Checked on synthetic run tables built here with a seeded generator: every expected figure is
computed in the test from the numbers put in (closed forms), never read back from pospp.
"""

from __future__ import annotations

import re

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from pospp.batch.outcome import FlightOutcome, read_rows, write_rows
from pospp.config import PipelineConfig
from pospp.evaluate import SolutionErrors
from pospp.outputs import NOT_OBSERVABLE_SIGMA, not_observable, velocity_gap_rms_mps
from pospp.report import figures, html, svg
from pospp.report.html import render_report
from pospp.report.summary import group_messages, headline, round_to_sigma, summary_text

T0_NS = 1_717_200_000_010_000_000  # 2024-06-01 00:00:00.01 UTC


def synthetic_tables(n_legs: int = 4, seed: int = 3) -> dict[str, pd.DataFrame]:
    """Run tables shaped as docs/formats.md: body calibration with gyro_bias_x = 0.93686 +-
    0.2927 deg/h, gyro_bias_y = -0.54708 +- 0.28673, phi_z = 313 +- 1915 arcsec
    (not observable), two per-leg tilts per leg; 200 GNSS rejections differing only in
    their numbers."""
    rng = np.random.default_rng(seed)
    start = T0_NS + (300 + 400 * np.arange(n_legs)) * 1_000_000_000
    legs = pd.DataFrame({"leg_id": np.arange(n_legs), "start_ns": start,
                         "end_ns": start + 300_000_000_000, "duration_s": 300.0,
                         "heading_deg": np.where(np.arange(n_legs) % 2, 180.0, 0.0),
                         "speed_mps": 60.0, "height_m": 900.0})
    rows = [(-1, "body", "gyro_bias_x", 0.93686, 0.2927, "deg_per_h"),
            (-1, "body", "gyro_bias_y", -0.54708, 0.28673, "deg_per_h"),
            (-1, "body", "phi_z", 313.0, 1915.4, "arcsec"),
            (-1, "paper", "eps_e", 0.084, 0.14, "deg_per_h")]
    for i in range(n_legs):
        rows += [(-1, "body", f"phi_x_leg{i}", rng.normal(0, 1), 1.5, "arcsec"),
                 (-1, "body", f"phi_y_leg{i}", rng.normal(0, 1), 1.3, "arcsec")]
    for p in range(n_legs - 1):
        rows += [(p, "body", "gyro_bias_x", 0.9 + rng.normal(0, 0.3), 0.4, "deg_per_h"),
                 (p, "body", "gyro_bias_y", -0.5 + rng.normal(0, 0.3), 0.4, "deg_per_h")]
    cal = pd.DataFrame(rows, columns=["pair_id", "formulation", "parameter", "value", "sigma",
                                      "unit"]).assign(transition="numerical")
    t = np.arange(0.0, 301.0, 10.0)
    le = pd.concat([pd.DataFrame({"leg_id": i, "stage": stage, "t_s": t,
                                  "dvn_mps": k * 1e-5 * (i + 1) * t**2,
                                  "dve_mps": -k * 2e-5 * t**2, "dpn_m": k * t, "dpe_m": -k * t})
                    for i in range(n_legs) for stage, k in (("before", 1.0), ("after", 0.1))],
                   ignore_index=True)
    traj_t = T0_NS + np.arange(0, 400 * n_legs + 400, 10) * 1_000_000_000
    m = len(traj_t)
    traj = pd.DataFrame({"time_ns": traj_t, "solution": "smoothed",
                         "lat_deg": 40 + np.linspace(0, 0.1, m), "lon_deg": 8 + 0.01 *
                         np.sin(np.arange(m) / 5), "height_m": 900.0, "north_sigma_m": 0.02,
                         "east_sigma_m": 0.02, "yaw_sigma_deg": 0.01, "roll_sigma_deg": 0.001})
    diag = pd.DataFrame({"step": [1], "effect": ["unexplained"], "value": [np.nan],
                         "sigma": [np.nan], "unit": [""], "statistic": [756.0],
                         "p_value": [0.0], "significant": [True], "gap_before_mps": [0.2144],
                         "gap_after_mps": [0.2144], "heldout_gap_before_mps": [0.3926],
                         "heldout_gap_after_mps": [0.3926], "criterion": ["lack_of_fit_F"]})
    msg_t = T0_NS + np.arange(200) * 5_000_000_000
    msgs = pd.DataFrame({"severity": "warning", "stage": "navigate", "time_ns": msg_t,
                         "text": [f"GNSS position rejected: innovation {x:.2f} sigma"
                                  for x in rng.uniform(5, 50, 200)]})
    msgs = pd.concat([msgs, pd.DataFrame({"severity": ["error"], "stage": ["qc"],
                                          "time_ns": [pd.NA], "text": ["QC check x failed"]})],
                     ignore_index=True)
    msgs["time_ns"] = msgs.time_ns.astype("Int64")
    qc = pd.DataFrame({"check": ["earth_rate", "gnss_nis"], "stage": "navigate",
                       "measure": "m", "value": [1.2, 0.0], "threshold": [5.6, 0.1],
                       "unit": ["deg/h", "1"], "passed": True, "severity": "degraded",
                       "suggestion": "", "time_ns": pd.array([None, None], dtype="Int64")})
    summary = pd.DataFrame([{"input_file": "flight.mcap", "input_sha256": "ab", "status": "ok",
                             "duration_s": float(400 * n_legs + 400), "n_legs": n_legs,
                             "n_pairs_used": n_legs - 1, "dv_before_mps": 2.268,
                             "dv_after_mps": 0.2956, "dp_before_m": 230.4,
                             "dp_after_m": 44.86, "calibration_reason": "ok",
                             "calibration_formulation": "body"}])
    return {"summary": summary, "qc": qc, "legs": legs, "calibration": cal, "leg_errors": le,
            "trajectory": traj, "diagnosis": diag, "messages": msgs}


@pytest.fixture
def no_png(monkeypatch):
    """Figures are made but not drawn to PNG (the page text is what these tests read)."""
    def stub(fig) -> str:
        if not isinstance(fig, svg.Figure):
            plt.close(fig)
        return "<img alt='figure'/>"

    monkeypatch.setattr(html, "_img", stub)


@pytest.mark.parametrize(("value", "sigma", "expected"), [
    (0.93686, 0.2927, ("+0.94", "0.29")),
    (313.0, 1915.4, ("+300", "1900")),
    (-0.54708, 0.028673, ("-0.547", "0.029")),
    (12.5, float("nan"), ("12.5", "")),
])
def test_numbers_are_rounded_to_their_sigma(value, sigma, expected) -> None:
    assert round_to_sigma(value, sigma) == expected


def test_unobservable_is_flagged_by_its_sigma() -> None:
    assert not_observable("phi_z", 1269.0, "arcsec").startswith("sigma 1269 arcsec > 360")
    assert "Earth-rate" in not_observable("phi_z", 1269.0, "arcsec")
    assert not_observable("gyro_bias_x", 0.29, "deg_per_h") == ""
    assert not_observable("gyro_bias_z", float("inf"), "deg_per_h") != ""
    assert not_observable("phi_x_leg3", NOT_OBSERVABLE_SIGMA["arcsec"], "arcsec") == ""


def test_velocity_gap_leaves_out_the_leg_start() -> None:
    # two legs; rows after the start hold [3, 4] and [0, 0]: mean square (9 + 16) / 4
    a = np.array([[100.0, 100.0, 7.0], [3.0, 4.0, 7.0], [0.0, 0.0, 7.0]])
    assert velocity_gap_rms_mps([a]) == pytest.approx(np.sqrt(25.0 / 4.0), rel=1e-12)
    assert np.isnan(velocity_gap_rms_mps([]))


def test_headline_leads_with_the_calibrated_bias_and_both_improvements() -> None:
    tables = synthetic_tables()
    h = headline(tables)
    assert [e.name for e in h.results] == ["gyro_bias_x", "gyro_bias_y"]
    assert h.results[0].text == "+0.94 +- 0.29 deg/h"
    assert [e.name for e in h.not_observable] == ["phi_z"]
    assert len(h.per_leg) == 8
    assert (h.gap_fit_mps, h.gap_heldout_mps) == (0.2144, 0.3926)
    b = tables["leg_errors"]
    b = b[(b.stage == "before") & (b.t_s > 0)]
    expect = np.sqrt(np.mean(np.concatenate([b.dvn_mps, b.dve_mps]) ** 2))
    assert h.gap_uncalibrated_mps == pytest.approx(expect, rel=1e-12)
    assert "held out" not in h.in_sample_text and "in-sample" in h.heldout_text


def test_console_prints_the_answer_first_and_legs_only_when_verbose() -> None:
    tables = synthetic_tables()
    short = summary_text(tables)
    lines = short.splitlines()
    assert lines[1].startswith("  status: ok")
    assert "gyro_bias_x +0.94 +- 0.29 deg/h" in lines[2]
    assert "phi_z (sigma 1915 arcsec)" in lines[3] and "313" not in short
    assert "in-sample" in short and "held out" in short
    assert "phi_x_leg0" not in short and "8 per-leg misalignments" in short
    assert "phi_x_leg0" in summary_text(tables, verbose=True)
    # the 200 innovation rejections are one grouped line (issue 39 item 10)
    grouped = [line for line in lines if "GNSS position rejected" in line]
    assert len(grouped) == 1 and grouped[0].endswith(" x200")


def test_identical_messages_are_grouped_with_a_count() -> None:
    msgs = synthetic_tables()["messages"]
    g = group_messages(msgs)
    assert list(g["count"]) == [1, 200]  # the error first
    assert g.severity.iloc[0] == "error"
    assert g.first_ns.iloc[1] == T0_NS and g.last_ns.iloc[1] == T0_NS + 199 * 5_000_000_000


def test_report_has_no_raw_ns_no_nan_and_readable_units(no_png) -> None:
    page = render_report(synthetic_tables(n_legs=12))
    text = re.sub(r"<[^>]+>", " ", re.sub(r"src=\"data:[^\"]+\"", "", page))
    assert not re.search(r"\d{19}", text), "19-digit ns times in the report"
    assert not re.search(r"\bnan\b|\bNaN\b|<NA>", text)
    assert "deg_per_h" not in text and "deg/h" in text
    assert "+0.94 \u00b1 0.29 deg/h" in text and "not observable" in text
    assert "00:05:00.01" in text  # leg 0 starts 300 s after 00:00:00.01 UTC
    assert text.index("The answer") < text.index("Quality checks") < text.index("Legs")
    assert "200" in text and "GNSS position rejected" in text


def test_thirty_legs_get_thirty_distinct_colours() -> None:
    assert len(set(figures.leg_colors(30))) == 30


def test_evaluation_figure_respects_skip_s() -> None:
    t = np.arange(0, 100) * 1_000_000_000
    pos = np.zeros((100, 3))
    pos[:10, 0] = 1000.0  # an alignment spike in the first 10 s
    e = SolutionErrors(t, pos, np.zeros((100, 3)), np.zeros((100, 3)))
    fig = figures.evaluation_errors({"smoothed": e}, skip_s=10.0)
    x, y = fig.axes[0].lines[0].get_data()
    assert x.min() >= 10.0 and y.max() == 0.0
    fig.clf()


def test_manifest_keeps_the_headline_columns(tmp_path) -> None:
    rows = [FlightOutcome("a.mcap", "ab", "ok", 1.0, None, 4, 0.3, 45.0, "a",
                          "", 2.27, 0.937, 0.293, -0.547, 0.287, 0.39, "phi_z: why"),
            FlightOutcome("b.mcap", "cd", "failed", 1.0, "boom", run_dir="b")]
    write_rows(tmp_path, rows, PipelineConfig())
    back = read_rows(tmp_path)
    assert back["a.mcap"].gyro_bias_x_dph == 0.937 and back["a.mcap"].not_observable == \
        "phi_z: why"
    assert back["b.mcap"].gyro_bias_x_dph is None


def test_sensor_errors_read_the_biases_table(no_png) -> None:
    """A's bias estimates (the ``biases`` table) are drawn beside the calibrated value."""
    t = T0_NS + np.arange(0, 1000, 10) * 1_000_000_000
    b = pd.DataFrame({"time_ns": np.r_[t, t], "solution": ["forward"] * 100 + ["smoothed"] * 100,
                      "gyro_bias_x_dph": np.r_[np.zeros(100), np.linspace(0.5, 1.0, 100)],
                      "gyro_bias_x_sigma_dph": 0.1, "gyro_bias_y_dph": -0.5,
                      "gyro_bias_y_sigma_dph": 0.1, "gyro_bias_z_dph": 0.0,
                      "gyro_bias_z_sigma_dph": 0.1, "accel_bias_x_ug": 5.0,
                      "accel_bias_y_ug": -5.0, "accel_bias_z_ug": 5.0,
                      "accel_bias_x_sigma_ug": 1.0})
    fig = figures.sensor_errors(b, {"gyro_bias_x": (0.94, 0.29)})
    gyro, accel = fig.axes
    x, y = gyro.lines[0].get_data()
    assert np.allclose(y, np.linspace(0.5, 1.0, 100)) and x[-1] == pytest.approx(990.0)  # smoothed
    assert any(np.allclose(ln.get_ydata(), 0.94) for ln in gyro.lines)  # the calibration
    assert accel.get_ylabel() == "accel bias (ug)"
    assert np.allclose(accel.lines[0].get_ydata(), 5.0)
    fig.clf()
    tables = synthetic_tables()
    page = render_report({**tables, "biases": b})
    assert "is not in this run" not in page and "is not in this run" in render_report(tables)


def test_sim_comparison_steps_print_units_as_a_reader_writes_them() -> None:
    """compare-sim's effect rows carry table units ("deg_per_h"); the report prints "deg/h"."""
    stat = {"kind": "statistic", "effect": "", "parameter": "", "value": np.nan,
            "sigma": np.nan, "unit": "", "measured": 1.0, "simulated_before": 0.5,
            "gap_before": 0.5, "gap_after": 0.0, "sigma_gap": 0.1, "z_before": 5.0,
            "z_after": 0.0, "p_before": 1e-6, "significant_before": True}
    rows = [dict(stat, step=0, measure="a_gyro_bias_wander"),
            dict(stat, step=1, measure="a_gyro_bias_wander"),
            dict(stat, kind="effect", step=1, measure="a_gyro_bias_wander",
                 effect="bias_instability", parameter="gyro_gm_sigma", value=100.0,
                 sigma=8.0, unit="deg_per_h")]
    text = "".join(html.sim_comparison_section(pd.DataFrame(rows)))
    assert "deg/h" in text and "deg_per_h" not in text
