"""``pospp compare-sim`` end to end: a small simulated flight with a hidden GNSS time offset
written as MCAP, ``pospp run``, then ``pospp compare-sim``: the table, the report section
and a model file that the simulator reads back."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from pospp.cli import main
from pospp.io.parquet_tables import read_table
from pospp.io.simulation_files import write_simulation
from pospp.sim.api import simulate_along
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import imu_grade


def test_compare_sim_cli(tmp_path):
    t = np.arange(0.0, 180.01, 0.5)
    # speed swings of 0.8 m/s^2: a time offset's tau a is then told from a lever arm's tau v
    sp = np.clip(t / 10.0, 0.0, 1.0) * 12.0 + 4.0 * np.sin(2 * np.pi * t / 30.0)
    hd = (np.radians(30.0) + 0.6 * np.sin(2 * np.pi * t / 70.0)
          + np.radians(90.0) * np.clip((t - 100.0) / 10.0, 0.0, 1.0))
    lat = np.radians(30.0) + np.cumsum(sp * np.cos(hd)) * 0.5 / 6.37e6
    lon = np.radians(114.0) + np.cumsum(sp * np.sin(hd)) * 0.5 / (6.37e6 * np.cos(lat))
    sim = simulate_along(t, lat, lon, np.full(t.shape, 50.0), imu_grade="tactical",
                         gnss=GnssModel(time_offset_s=0.08), seed=4, imu_rate_hz=50.0)
    mcap = write_simulation(sim, tmp_path, "flight")["mcap"]
    pipe = tmp_path / "p.toml"
    pipe.write_text('[input]\nsensor_frame = "flu"\n[imu]\ngrade = "tactical"\n'
                    "[outputs]\nmcap = false\n")
    run_dir = tmp_path / "run"
    r = CliRunner().invoke(main, ["run", str(mcap), "-p", str(pipe), "-o", str(run_dir)])
    assert (run_dir / "summary.parquet").is_file(), r.output
    # a folder that is not a run is refused with a one-line error
    (tmp_path / "empty").mkdir()
    r = CliRunner().invoke(main, ["compare-sim", str(tmp_path / "empty")])
    assert r.exit_code != 0 and "not a pospp run folder" in r.output
    r = CliRunner().invoke(main, ["compare-sim", str(run_dir)])
    assert r.exit_code == 0, r.output
    assert "time_offset" in r.output
    # not a terminal: a line per step on stderr with the seconds since the start, no
    # transient flight counter (issue 33 item 5)
    steps = re.findall(r"^  \[ *[\d.]+ s\] (.+)$", r.stderr, flags=re.M)
    assert "simulating the trajectory (kinematics)" in steps, r.stderr
    assert len(steps) >= 4 and "simulated flight" not in r.stderr
    tab = read_table(run_dir / "sim_comparison.parquet")
    eff = tab[(tab.kind == "effect") & (tab.effect == "time_offset")]
    # ms, 25 %; the catalogue's sign: IMU minus GNSS time (GNSS 80 ms late: -80)
    assert len(eff) == 1 and abs(eff["value"].iloc[0] + 80.0) < 20.0
    assert eff["parameter"].iloc[0] == "time_offset" and eff["unit"].iloc[0] == "ms"
    assert abs(eff.z_after.iloc[0]) < abs(eff.z_before.iloc[0])
    assert "compare-sim" in (run_dir / "report.html").read_text()
    model = run_dir / "sim_model.toml"
    # the base model (step 0) is the log's: the simulated tactical IMU's own levels
    # (34 s of steady parts: 3.5 % sd of the ARW, measured on 200 white series with this
    # flight's parts: tests/unit/test_simcompare_base.py), the one simulated with
    base = tab[tab.kind == "base"].set_index("parameter")
    arw = base.loc[["gyro_arw_x", "gyro_arw_y", "gyro_arw_z"]]
    assert np.allclose(arw["prior"], 0.1) and (arw["unit"] == "deg_per_sqrt_h").all()
    assert (np.abs(arw["value"] / 0.1 - 1.0) < 0.15).all(), arw
    # simulated at the fit, or at the grade's where the fit is within 2 sigma of it
    assert imu_grade(str(model)).gyro_arw_dpsh == pytest.approx(tuple(arw["simulated_before"]))
    assert all(v in (f, 0.1) for v, f in zip(arw["simulated_before"], arw["value"], strict=True))
    import tomllib

    gn = GnssModel.from_dict(tomllib.loads(model.read_text())["gnss"])
    assert abs(gn.time_offset_s - 0.08) < 0.02
    assert isinstance(tab, pd.DataFrame) and set(tab.step) >= {0, 1}
    _signs_and_units_agree(r.output, eff.iloc[0], (run_dir / "report.html").read_text(),
                           model.read_text(), gn)


def _signs_and_units_agree(console: str, row: pd.Series, report: str, toml_text: str,
                           gnss: GnssModel) -> None:
    """Issue 33 item 4: the size printed on the console, the table's row, the report's steps
    table and sim_model.toml (its comment header, and its field through the documented
    conversion: time_offset [ms, IMU minus GNSS] = -1000 x time_offset_s [GNSS minus true])
    read back as one number with one sign and one unit."""
    value = float(row["value"])
    m = re.search(r"step \d+: \S+: time_offset time_offset ([+-][\d.]+) \+- ([\d.]+) ms",
                  console)
    assert m, console
    assert float(m.group(1)) == pytest.approx(value, rel=1e-3)
    assert float(m.group(2)) == pytest.approx(float(row["sigma"]), rel=0.05)
    cell = re.search(r">time_offset</td><td[^>]*>([-+]?[\d.]+)</td>", report)
    assert cell, "no time_offset row in the report's steps"
    assert float(cell.group(1)) == pytest.approx(value, rel=2e-3)
    head = re.search(r"# step \d+: time_offset: time_offset ([+-][\d.]+) \+- [\d.e+-]+ ms",
                     toml_text)
    assert head, toml_text[:800]
    assert float(head.group(1)) == pytest.approx(value, rel=1e-5)
    assert -1000.0 * gnss.time_offset_s == pytest.approx(value, rel=1e-9)
