"""``pospp compare-sim`` end to end: a small simulated flight with a hidden GNSS time offset
written as MCAP, ``pospp run``, then ``pospp compare-sim``: the table, the report section
and a model file that the simulator reads back."""

from __future__ import annotations

import numpy as np
import pandas as pd
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
    tab = read_table(run_dir / "sim_comparison.parquet")
    eff = tab[(tab.kind == "effect") & (tab.effect == "time_offset")]
    # ms, 25 %; the catalogue's sign: IMU minus GNSS time (GNSS 80 ms late: -80)
    assert len(eff) == 1 and abs(eff["value"].iloc[0] + 80.0) < 20.0
    assert abs(eff.z_after.iloc[0]) < abs(eff.z_before.iloc[0])
    assert "compare-sim" in (run_dir / "report.html").read_text()
    model = run_dir / "sim_model.toml"
    assert imu_grade(str(model)) == imu_grade("tactical")
    import tomllib

    gn = GnssModel.from_dict(tomllib.loads(model.read_text())["gnss"])
    assert abs(gn.time_offset_s - 0.08) < 0.02
    assert isinstance(tab, pd.DataFrame) and set(tab.step) >= {0, 1}
