"""A new user's first hour (issue 39), item by item, on small inputs; the end-to-end walk of
the README's commands is tests/e2e/test_first_hour_walk.py.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from pospp import outputs
from pospp.cli import EXIT_CODES, main
from pospp.cli._status import StageBar, _listen_for_compilation, diagnosis_step_line
from pospp.diagnose.results import DiagnosisStep
from pospp.evaluate import TruthMismatchError, solution_errors
from pospp.flight_stages import sensor_to_body_dcm
from pospp.io import parquet_tables, run_folder
from pospp.report.summary import headline, headline_lines, message_lines

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"


# -- item 1: compare-sim's sim_model.toml is pospp's own file -------------------------------

def test_run_force_replaces_a_run_holding_compare_sims_model(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    run_folder.write_marker(run, input_file=tmp_path / "in.mcap", input_sha256="0",
                            config_json="{}", status="ok")
    (run / "sim_model.toml").write_text("[imu]\n")
    (run / "sim_comparison.parquet").write_bytes(b"x")
    assert run_folder.check_target(run, input_file=tmp_path / "in.mcap", force=True) == run
    (run / "notes.txt").write_text("the user's")
    with pytest.raises(run_folder.RunFolderError, match="notes.txt"):
        run_folder.check_target(run, input_file=tmp_path / "in.mcap", force=True)


# -- item 2: the figures script finds stale text ---------------------------------------------

def _figures_script():
    spec = importlib.util.spec_from_file_location("make_figures", DOCS / "_make_figures.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["make_figures"] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def test_every_quote_of_the_figures_script_is_in_its_doc():
    """Each pattern of docs/_make_figures.py matches its doc once (a reworded sentence would
    silently escape the check); the run-level check is tests/e2e/test_first_hour_walk.py."""
    mod = _figures_script()
    for q in mod.QUOTES:
        assert len(mod._matches(q)) == 1, (q.doc, q.keys)


def test_the_figures_check_names_a_stale_figure(tmp_path, monkeypatch):
    mod = _figures_script()
    doc = tmp_path / "README.md"
    doc.write_text("the run gives `gyro_bias_x = +0.94 +- 0.29`, `gyro_bias_y = -0.55 +- 0.29 "
                   "deg/h` here")
    monkeypatch.setattr(mod, "REPO", tmp_path)
    monkeypatch.setattr(mod, "QUOTES", (mod.Quote("README.md", mod.QUOTES[2].pattern,
                                                  ("bias_x", "bias_y")),))
    monkeypatch.setattr(mod, "PNGS", {})
    monkeypatch.setattr(mod, "sample_figures",
                        lambda run: {"bias_x": "+0.94 +- 0.32", "bias_y": "-0.55 +- 0.33"})
    bad = mod.check(tmp_path)
    assert bad == ["README.md:1: bias_x says '+0.94 +- 0.29', the run gives '+0.94 +- 0.32'",
                   "README.md:1: bias_y says '-0.55 +- 0.29', the run gives '-0.55 +- 0.33'"]
    mod.write(tmp_path)
    assert "+0.94 +- 0.32`, `gyro_bias_y = -0.55 +- 0.33 deg/h` here" in doc.read_text()
    assert mod.check(tmp_path) == []


# -- item 3: the gyro bias's frame said, the IMU's axes beside it ---------------------------

@pytest.mark.parametrize(("frame", "mount"), [("flu", (0.0, 0.0, 0.0)), ("frd", (0.0, 0.0, 0.0)),
                                              ("flu", (10.0, -5.0, 30.0))])
def test_sensor_axes_bias_is_the_body_bias_rotated_back(frame, mount):
    c_bs = sensor_to_body_dcm(frame, mount)
    b_b = np.array([0.94, -0.55, 0.2])
    s = outputs.with_sensor_axes({f"gyro_bias_{a}_dph": v for a, v in zip("xyz", b_b,
                                                                          strict=True)}
                                 | {f"gyro_bias_{a}_sigma_dph": 0.3 for a in "xyz"}, c_bs)
    b_s = np.array([s[f"gyro_bias_sensor_{a}_dph"] for a in "xyz"])
    np.testing.assert_allclose(c_bs @ b_s, b_b, atol=1e-12)  # back into the body
    if mount == (0.0, 0.0, 0.0):
        want = {"flu": [0.94, 0.55, -0.2], "frd": [0.94, -0.55, 0.2]}[frame]
        np.testing.assert_allclose(b_s, want, atol=1e-12)
        assert s["imu_axes"] == frame.upper()
        np.testing.assert_allclose([s[f"gyro_bias_sensor_{a}_sigma_dph"] for a in "xyz"], 0.3)
    else:
        assert s["imu_axes"] == "as logged"


def test_an_unestimated_body_axis_leaves_the_sensor_axes_it_feeds_unknown():
    s = outputs.with_sensor_axes({"gyro_bias_x_dph": 1.0, "gyro_bias_y_dph": 2.0,
                                  "gyro_bias_z_dph": np.nan, "gyro_bias_x_sigma_dph": 0.1,
                                  "gyro_bias_y_sigma_dph": 0.1, "gyro_bias_z_sigma_dph": np.nan},
                                 sensor_to_body_dcm("flu", (0.0, 0.0, 0.0)))
    assert s["gyro_bias_sensor_y_dph"] == -2.0 and np.isnan(s["gyro_bias_sensor_z_dph"])


def test_the_headline_names_the_body_frame_and_gives_the_imu_axes():
    summary = pd.DataFrame([outputs.with_sensor_axes(
        {"status": "ok", "calibration_formulation": "body", "gyro_bias_x_dph": 0.94,
         "gyro_bias_x_sigma_dph": 0.32, "gyro_bias_y_dph": -0.55, "gyro_bias_y_sigma_dph": 0.33,
         "gyro_bias_z_dph": np.nan, "gyro_bias_z_sigma_dph": np.nan},
        sensor_to_body_dcm("flu", (0.0, 0.0, 0.0)))])
    cal = pd.DataFrame({"pair_id": -1, "formulation": "body", "transition": "closed_form",
                        "parameter": ["gyro_bias_x", "gyro_bias_y"], "value": [0.94, -0.55],
                        "sigma": [0.32, 0.33], "unit": "deg_per_h"})
    text = "\n".join(headline_lines(headline({"summary": summary, "calibration": cal})))
    assert "body axes FRD: x forward, y right, z down" in text
    assert "IMU's axes (FLU: x forward, y left, z up): x +0.94 +- 0.32, y +0.55 +- 0.33 deg/h" \
        in text


# -- item 4: exit codes and status words -----------------------------------------------------

def test_exit_codes_follow_the_status_words():
    from pospp.cli import exit_code_for_status

    assert EXIT_CODES == {"ok": 0, "failed": 1, "usage": 2, "degraded": 3, "partial": 4,
                          "changed": 3}
    assert exit_code_for_status("ok") == 0 and exit_code_for_status("partial") == 4
    assert exit_code_for_status("ok", "partial", "degraded") == 3
    assert exit_code_for_status("degraded", "failed") == 1
    assert exit_code_for_status("ok", "changed") == 3 and exit_code_for_status("unchanged") == 0


@pytest.mark.parametrize("args", [["simulate", "--preset", "nope", "-o", "x.mcap"],
                                  ["simulate", "--preset", "sample", "--imu-grade", "nope",
                                   "-o", "x.mcap"],
                                  ["convert", ".", "--format", "nope", "-o", "x.mcap"]])
def test_unknown_choices_are_usage_errors(tmp_path, args, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 2, res.output
    err = res.stderr.strip()
    assert err.startswith("pospp: error: ") and "nope" in err and "expected one of" in err
    assert not (tmp_path / "x.mcap").exists()


def test_a_topic_the_log_does_not_have_is_a_usage_error(tmp_path):
    toml = tmp_path / "t.toml"
    toml.write_text('[input]\nimu_topic = "/nope"\n')
    res = CliRunner().invoke(main, ["run", str(REPO / "sample_data" / "sample_flight.mcap"),
                                    "-p", str(toml), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2 and "'/nope'" in res.stderr and "available topics" in res.stderr


# -- item 5: bare pospp ------------------------------------------------------------------------

def test_bare_pospp_prints_its_help_as_help():
    res = CliRunner().invoke(main, [], prog_name="pospp")
    assert res.exit_code == EXIT_CODES["usage"]
    lines = res.stdout.splitlines()
    assert lines[0].startswith("Usage: pospp") and "pospp: error" not in res.output
    assert "Commands:" in lines and any(line.strip().startswith("diff ") for line in lines)


# -- item 6: real-dataset hints ----------------------------------------------------------------

def test_an_undetected_format_says_the_flag(tmp_path):
    (tmp_path / "something.csv").write_text("a,b\n")
    res = CliRunner().invoke(main, ["convert", str(tmp_path), "-o", str(tmp_path / "x.mcap")])
    assert res.exit_code == 1 and "--format NAME" in res.stderr and "fmt=" in res.stderr


@pytest.mark.realdata
def test_the_ansfl_clip_says_which_conversion_makes_a_run(real_data, tmp_path):
    src = real_data / "ansfl_quadrotor_straightline"
    res = CliRunner().invoke(main, ["convert", str(src), "-o", str(tmp_path / "q.mcap")])
    assert res.exit_code == 0, res.output
    hints = [line for line in res.stdout.splitlines() if line.startswith("  hint: ")]
    assert "too short for a pospp run" in hints[0] and "alignment" in hints[0]
    assert "--format ansfl_quadrotor_raw --option unit=1 --option recording=2" in hints[0]
    assert "pipelines/realdata/ansfl_quadrotor_straightline.toml" in hints[1]
    assert res.stdout.strip().splitlines()[-1] == "pospp convert: ok (1 warning(s))"


# -- item 7: docs/pipelines.md -----------------------------------------------------------------

def test_pipelines_doc_is_linked_says_frames_and_grades_and_has_no_sphinx_markup():
    readme = (REPO / "README.md").read_text()
    assert "(docs/pipelines.md)" in readme
    doc = (DOCS / "pipelines.md").read_text()
    assert "`[gnss] lever_arm_m` is the antenna's position from the IMU\nin body FRD" in doc
    assert re.search(r"\| `lever_arm_m` \|.*\| Antenna position in the body frame FRD \[m\]\. \|",
                     doc)
    assert "## What each `[imu] grade` holds" in doc
    assert re.search(r"\| `\[imu\] gyro_bias_sigma_dph` \| 1 \| 0\.1 \| 10 \| 1800 \| 1800 \|", doc)
    assert not re.search(r":(class|func|meth|data|mod|attr):`", doc) and "``" not in doc


# -- item 8: evaluate refuses another flight's truth ------------------------------------------

def _track(n: int = 50, lat_deg: float = 34.0, t0_ns: int = 0):
    t = t0_ns + np.arange(n, dtype=np.int64) * 10**9
    lat = np.radians(np.full(n, lat_deg))
    lon = np.radians(108.0 + np.arange(n) * 1e-4)
    return t, lat, lon, np.full(n, 900.0), np.zeros((n, 3)), np.zeros((n, 3))


def _errors(sol, ref):
    return solution_errors(*sol, ref_time_ns=ref[0], ref_lat_rad=ref[1], ref_lon_rad=ref[2],
                           ref_height_m=ref[3], ref_v_n_mps=ref[4], ref_rpy_rad=ref[5])


def test_evaluate_refuses_a_truth_km_away_or_of_another_time():
    sol = _track()
    assert _errors(sol, _track()).pos_ned_m.max() == 0.0
    with pytest.raises(TruthMismatchError, match=r"lies 889 km from the solution"):
        _errors(sol, _track(lat_deg=42.0))  # 8 deg of latitude: 889 km
    with pytest.raises(TruthMismatchError, match="do not overlap in time"):
        _errors(sol, _track(t0_ns=10**12))
    near = _track()
    near = (near[0], near[1] + 500.0 / 6.37e6, *near[2:])  # 500 m: evaluated, not refused
    assert _errors(sol, near).pos_ned_m[:, 0].mean() == pytest.approx(-500.0, rel=0.01)


def test_evaluate_command_exit_2_naming_the_truth(tmp_path):
    t, lat, lon, h, v, rpy = _track()
    run = tmp_path / "run"
    traj = pd.DataFrame({"time_ns": t, "solution": "smoothed", "lat_deg": np.degrees(lat),
                         "lon_deg": np.degrees(lon), "height_m": h, "vn_mps": 0.0,
                         "ve_mps": 0.0, "vd_mps": 0.0, "roll_deg": 0.0, "pitch_deg": 0.0,
                         "yaw_deg": 0.0})
    parquet_tables.write_table(run / "trajectory.parquet", traj, "trajectory", metadata={})
    run_folder.write_marker(run, input_file=tmp_path / "in.mcap", input_sha256="0",
                            config_json="{}", status="ok")
    truth = tmp_path / "other.truth.parquet"
    parquet_tables.write_table(truth, traj.drop(columns="solution").assign(
        lat_deg=traj.lat_deg + 8.0), "reference", metadata={})
    res = CliRunner().invoke(main, ["evaluate", str(run), "--truth", str(truth)])
    assert res.exit_code == 2, res.output
    assert "other.truth.parquet" in res.stderr and "km from the solution" in res.stderr
    assert not (run / "evaluation.parquet").exists()


# -- item 9: diagnose says "no missing effect found" ----------------------------------------

def _step(effect: str, value: float = float("nan")) -> DiagnosisStep:
    nan = float("nan")
    return DiagnosisStep(1, effect, (), np.zeros(0), np.zeros(0), value, nan if value != value
                         else 0.1, "deg/h", nan, 0.81, "F-test", False, nan, nan, (), 0.2, 0.2,
                         0.39, 0.39)


def test_diagnosis_lines_say_what_was_found_never_nan():
    none = diagnosis_step_line(_step("none"))
    assert none.startswith("step 1: no missing effect found (lack of fit p = 0.81)")
    assert "nan" not in none.lower()
    found = diagnosis_step_line(_step("gyro_scale_factor", 120.0))
    assert "gyro_scale_factor: value +120 +- 0.1 deg/h, p = 0.81" in found
    assert "unexplained: a structured gap" in diagnosis_step_line(_step("unexplained"))


# -- item 10: routine warnings demoted, the rest grouped --------------------------------------

def test_routine_gnss_rejections_are_info_and_warnings_are_grouped():
    from pospp.nav.filter_input import GnssRejection

    rej = [GnssRejection(i, float(i), kind, "before the filter start (alignment)", np.nan)
           for i in range(86) for kind in ("position", "velocity")]
    rej += [GnssRejection(100 + i, 100.0 + i, "position", f"innovation gate (NIS > {9 + i:.2f})",
                          30.0) for i in range(3)]
    rows = outputs.rejection_messages(rej, limit=2)
    info = [r for r in rows if r["severity"] == "info"]
    assert [r["text"] for r in info] == [
        "GNSS position rejected: before the filter start (alignment): 86 records (routine)",
        "GNSS velocity rejected: before the filter start (alignment): 86 records (routine)"]
    assert info[0]["time_ns"] == 0
    warned = [r["text"] for r in rows if r["severity"] == "warning"]
    assert warned[-1] == "1 more GNSS rejections not listed" and len(warned) == 3
    rows = outputs.rejection_messages(rej)
    msgs = pd.DataFrame(rows + [{"severity": "warning", "stage": "qc", "time_ns": None,
                                 "text": "QC check x failed"}])
    lines = message_lines(msgs)
    assert lines[0] == "  messages: 0 errors, 4 warnings, 2 info (messages.parquet)"
    assert lines[1:] == ["    warning: GNSS position rejected: innovation gate (NIS > 9.00) x3"]
    for reason in outputs.ROUTINE_REJECTIONS:  # the filter still words them so
        assert reason in (REPO / "pospp" / "nav" / "filter_state.py").read_text() + (
            REPO / "pospp" / "nav" / "filter_input.py").read_text()


# -- item 11: numba's first compilation said once ---------------------------------------------

def test_the_first_numba_compilation_is_said_once(monkeypatch):
    import numba

    from pospp.cli import _status

    monkeypatch.setattr(_status, "_SAID", type(_status._SAID)())  # a fresh process's state
    said = []
    listener = _listen_for_compilation(lambda: said.append(1))
    try:
        numba.njit(lambda x: x + 1)(1)  # compiles (not cached)
        numba.njit(lambda x: x + 2)(1)
    finally:
        from numba.core import event

        event.unregister("numba:compile", listener)
    assert said == [1]
    assert _listen_for_compilation(lambda: said.append(2)) is None  # once per process
    bar = StageBar()  # not a terminal here: silent, no listener
    bar("navigate", 0.1)
    bar.compiling()
    assert bar._text() == f"navigate ({StageBar.COMPILING})"
    bar.close()


# -- item 4: a status line from every command -------------------------------------------------

TINY_PROFILE = """name = "tiny"
imu_rate_hz = 50
[start]
lat_deg = 34.0
lon_deg = 108.0
height_m = 400.0
heading_deg = 20.0
[[segment]]
type = "static"
duration_s = 20.0
[[segment]]
type = "accelerate"
to_speed_mps = 30.0
duration_s = 20.0
"""


def test_simulate_observability_and_report_end_with_a_status_line(tmp_path):
    profile = tmp_path / "tiny.toml"
    profile.write_text(TINY_PROFILE)
    res = CliRunner().invoke(main, ["simulate", "--profile", str(profile), "-o",
                                    str(tmp_path / "tiny.mcap")])
    assert res.exit_code == 0, res.output
    assert res.stdout.strip().splitlines()[-1] == f"pospp simulate: ok ({tmp_path / 'tiny.mcap'})"
    res = CliRunner().invoke(main, ["observability", "-o", str(tmp_path / "obs")])
    assert res.exit_code == 0, res.output
    assert res.stdout.strip().splitlines()[-1] == f"pospp observability: ok ({tmp_path / 'obs'})"
