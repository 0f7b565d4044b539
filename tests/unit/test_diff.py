"""pospp diff (issue 37 item 2): what changed between two runs or two batch roots, against
tolerances; exit 0 within, 3 not, 1 on error, 2 on usage.

The runs are synthetic tables (a 100-epoch straight track, a summary); the differences are
injected in physical units and checked by an independent route (ECEF distance for position,
the known yaw offset for attitude).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import pospp
from pospp import earth
from pospp.api.diff import Tolerances, diff_paths, load_tolerances
from pospp.batch.outcome import FlightOutcome, write_rows
from pospp.cli import main
from pospp.config import ConfigError, PipelineConfig
from pospp.io import parquet_tables, run_folder
from pospp.units import ARCSEC_RAD

T0_NS = 1_717_200_000_000_000_000
META = {"input_file": "in.mcap", "input_sha256": "0" * 64, "config": {}}


def _write_run(folder: Path, *, north_m: float = 0.0, yaw_arcsec: float = 0.0,
               bias_x_dph: float = 0.94, status: str = "ok", extra: dict | None = None) -> Path:
    n = 100
    lat0 = math.radians(34.0)
    r_m, _ = earth.principal_radii_m(lat0)
    lat = np.degrees(lat0 + (np.arange(n) * 6.0 + north_m) / (float(r_m) + 900.0))
    blocks = []
    for sol in ("forward", "smoothed", "compensated"):
        blocks.append(pd.DataFrame({
            "time_ns": T0_NS + np.arange(n, dtype=np.int64) * 100_000_000, "solution": sol,
            "lat_deg": lat, "lon_deg": 108.0, "height_m": 900.0, "vn_mps": 60.0, "ve_mps": 0.0,
            "vd_mps": 0.0, "roll_deg": 1.0, "pitch_deg": 2.0,
            "yaw_deg": 20.0 + yaw_arcsec / 3600.0}))
    folder.mkdir(parents=True)
    parquet_tables.write_table(folder / "trajectory.parquet", pd.concat(blocks), "trajectory",
                               metadata=META)
    summary = {"input_file": "in.mcap", "input_sha256": "0" * 64, "status": status,
               "n_legs": 4, "n_pairs_used": 3, "gyro_bias_x_dph": bias_x_dph,
               "gyro_bias_x_sigma_dph": 0.3, "gyro_bias_y_dph": -0.55,
               "gyro_bias_y_sigma_dph": 0.3, "dv_before_mps": 2.27, "dv_after_mps": 0.167,
               "dp_before_m": 230.0, "dp_after_m": 23.8, **(extra or {})}
    parquet_tables.write_table(folder / "summary.parquet", summary, "summary", metadata=META)
    run_folder.write_marker(folder, input_file=folder.parent / "in.mcap",
                            input_sha256="0" * 64, config_json="{}", status=status)
    return folder


def _row(result, item, solution=""):
    t = result.table
    hit = t[(t["item"] == item) & (t.solution == solution)]
    assert len(hit) == 1, (item, solution, t[["item", "solution"]])
    return hit.iloc[0]


def test_a_run_against_itself_is_within_everywhere(tmp_path):
    a = _write_run(tmp_path / "a")
    result = diff_paths(a, a)
    assert result.within and result.flights(changed=True) == []
    assert result.flights(changed=False) == [""]
    assert (result.table.max_diff.fillna(0) == 0).all()
    items = set(result.table["item"])
    assert {"status", "n_legs", "gyro_bias_x_dph", "gyro_bias_x_sigma_dph", "dv_after_mps",
            "dp_before_m", "epochs", "position", "velocity", "attitude"} <= items


def test_position_and_attitude_differences_in_physical_units(tmp_path):
    a = _write_run(tmp_path / "a")
    b = _write_run(tmp_path / "b", north_m=0.02, yaw_arcsec=3.0)
    result = diff_paths(a, b)
    pos = _row(result, "position", "compensated")
    ta, tb = pospp.open_run(a).trajectory(), pospp.open_run(b).trajectory()
    ecef = [earth.llh_to_ecef_m(np.radians(t.lat_deg), np.radians(t.lon_deg), t.height_m)
            for t in (ta, tb)]
    d = np.linalg.norm(ecef[1] - ecef[0], axis=-1)  # independent: straight-line distance
    assert pos.max_diff == pytest.approx(d.max(), abs=1e-6)
    assert pos.max_diff == pytest.approx(0.02, abs=1e-4) and not pos.within
    assert pos.rms_diff == pytest.approx(np.sqrt(np.mean(d**2)), abs=1e-6)
    att = _row(result, "attitude", "smoothed")
    # roll and pitch are equal: the rotation between the two attitudes is the yaw offset
    assert att.max_diff == pytest.approx(3.0, rel=1e-6) and att.unit == "arcsec"
    assert not att.within and "max 3 arcsec" in att.note
    assert _row(result, "velocity", "forward").within
    assert _row(result, "epochs", "forward").within
    assert result.flights(changed=True) == [""] and not result.within


def test_bias_within_a_tenth_of_the_baseline_sigma(tmp_path):
    a = _write_run(tmp_path / "a")
    near = diff_paths(a, _write_run(tmp_path / "near", bias_x_dph=0.94 + 0.029))
    assert _row(near, "gyro_bias_x_dph").within
    assert _row(near, "gyro_bias_x_dph").tolerance == pytest.approx(0.03)
    far = diff_paths(a, _write_run(tmp_path / "far", bias_x_dph=0.94 + 0.031))
    row = _row(far, "gyro_bias_x_dph")
    assert not row.within and "0.94 -> 0.971 deg/h" in row.note
    loose = diff_paths(a, tmp_path / "far", Tolerances(bias_sigma_fraction=0.2))
    assert loose.within


def test_status_change_and_an_added_bias_column(tmp_path):
    """A summary column pair a later pospp adds (``<name>_dph`` with ``<name>_sigma_dph``) is
    compared like the others, read by name."""
    extra_a = {"gyro_bias_x_causal_dph": 1.0, "gyro_bias_x_causal_sigma_dph": 0.1}
    extra_b = {"gyro_bias_x_causal_dph": 1.5, "gyro_bias_x_causal_sigma_dph": 0.1}
    a = _write_run(tmp_path / "a", extra=extra_a)
    b = _write_run(tmp_path / "b", status="degraded", extra=extra_b)
    result = diff_paths(a, b)
    assert not _row(result, "status").within and _row(result, "status").text_b == "degraded"
    added = _row(result, "gyro_bias_x_causal_dph")
    assert not added.within and added.max_diff == pytest.approx(0.5)


def _root(root: Path, flights: dict[str, dict]) -> Path:
    root.mkdir()
    rows = []
    for name, kw in flights.items():
        _write_run(root / name, **kw)
        rows.append(FlightOutcome(f"/archive/{name}.mcap", "0" * 64, kw.get("status", "ok"),
                                  1.0, None, run_dir=name))
    write_rows(root, rows, PipelineConfig())
    return root


def test_two_roots_match_flights_by_folder_and_list_the_ones_in_one_only(tmp_path):
    a = _root(tmp_path / "A", {"f1": {}, "f2": {}, "old": {}})
    b = _root(tmp_path / "B", {"f1": {}, "f2": {"north_m": 0.5}, "new": {}})
    result = diff_paths(a, b)
    assert result.flights(changed=True) == ["f2", "new", "old"]
    assert result.flights(changed=False) == ["f1"]
    assert result.only_in("a") == ["old"] and result.only_in("b") == ["new"]
    assert diff_paths(a, a).within


def test_cli_exit_codes_files_and_status_line(tmp_path):
    a = _root(tmp_path / "A", {"f1": {}, "f2": {}})
    b = _root(tmp_path / "B", {"f1": {}, "f2": {"yaw_arcsec": 10.0}})
    res = CliRunner().invoke(main, ["diff", str(a), str(a)])
    assert res.exit_code == 0, res.output
    assert res.stdout.strip().splitlines()[-1] == "pospp diff: unchanged"
    out = tmp_path / "report"
    res = CliRunner().invoke(main, ["diff", str(a), str(b), "-o", str(out)])
    assert res.exit_code == 3, res.output
    lines = res.stdout.strip().splitlines()
    assert lines[-1] == "pospp diff: changed"
    assert any(line.startswith("  f2: ") and "attitude" in line for line in lines)
    table = pq.read_table(out / "diff.parquet")
    assert table.schema.metadata[b"pospp.schema_name"] == b"diff"
    assert "f2" in (out / "diff.html").read_text() and "changed" in (out / "diff.html").read_text()
    tol = tmp_path / "tol.toml"
    tol.write_text("[tolerance]\nattitude_arcsec = 20.0\n")
    res = CliRunner().invoke(main, ["diff", str(a), str(b), "--tolerances", str(tol)])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, ["diff", str(a), str(a / "f1")])  # a root and a run
    assert res.exit_code == 2 and "give two run folders or two batch roots" in res.stderr
    (tmp_path / "plain").mkdir()
    res = CliRunner().invoke(main, ["diff", str(a), str(tmp_path / "plain")])
    assert res.exit_code == 2 and "neither a pospp run folder nor a batch root" in res.stderr


def test_tolerance_file_errors_name_the_key(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text("[tolerance]\nposition_cm = 1\n")
    with pytest.raises(ConfigError, match="tolerance.position_cm"):
        load_tolerances(p)
    p.write_text("[tolerance]\nvelocity_mps = -1\n")
    with pytest.raises(ConfigError, match=r"tolerance.velocity_mps = -1: expected a number >= 0"):
        load_tolerances(p)
    p.write_text("[tolerances]\n")
    with pytest.raises(ConfigError, match="unknown key.*tolerances"):
        load_tolerances(p)
    p.write_text("[tolerance]\nposition_m = 0.05\n")
    assert load_tolerances(p) == Tolerances(position_m=0.05)
    assert load_tolerances(Path(__file__).parents[2] / "docs" / "examples" /
                           "tolerances.toml") == Tolerances()


def test_attitude_difference_is_the_rotation_angle_not_euler(tmp_path):
    """Yaw 359.9999 deg against 0.0001 deg is 0.72 arcsec, not 360 deg."""
    a = _write_run(tmp_path / "a")
    b = _write_run(tmp_path / "b")
    for folder, yaw in ((a, 359.9999), (b, 0.0001)):
        t = parquet_tables.read_table(folder / "trajectory.parquet")
        t["yaw_deg"] = yaw
        parquet_tables.write_table(folder / "trajectory.parquet", t, "trajectory", metadata=META)
    att = _row(diff_paths(a, b), "attitude", "compensated")
    assert att.max_diff == pytest.approx(0.0002 * 3600 * math.cos(0.0), rel=1e-3)
    assert att.max_diff * ARCSEC_RAD < 1e-5


def test_the_ci_workflow_commands_parse_and_its_tolerances_load(tmp_path, monkeypatch):
    """docs/examples/pospp-reprocess.yml: every ``pospp`` command line parses with the CLI's
    own options (nothing runs), in a checkout where the first step made the baseline."""
    import shlex

    import yaml

    repo = Path(__file__).parents[2]
    for name in ("sample_data", "pipelines", "docs"):
        (tmp_path / name).symlink_to(repo / name)
    (tmp_path / "out" / "baseline").mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    flow = yaml.safe_load((repo / "docs" / "examples" / "pospp-reprocess.yml").read_text())
    env = {k: v for k, v in flow["env"].items()}
    lines = [line.strip() for step in flow["jobs"]["reprocess"]["steps"]
             for line in step.get("run", "").splitlines() if "/bin/pospp " in line]
    assert len(lines) == 2 and "--baseline" in lines[1]
    for line in lines:
        for k, v in env.items():
            line = line.replace(f'"${k}"', v)
        args = shlex.split(line)[1:]
        ctx = main.make_context("pospp", list(args), resilient_parsing=False)
        with ctx:
            sub = main.get_command(ctx, args[0])
            sub.make_context(args[0], args[1:], parent=ctx)  # raises on a bad option
    assert (repo / env["TOLERANCES"]).is_file() and (repo / env["ARCHIVE"]).is_dir()
    assert (repo / env["PIPELINE"]).is_file()
