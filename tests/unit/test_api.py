"""pospp.api (issue 37 item 1): open_run's typed access to every documented table, its refusals,
the lazy ``import pospp``, and open_archive over a manifest.

Every table of ``pospp.io.parquet_tables.TABLES`` (the schemas docs/formats.md renders) is
written with values of each column's type, read back through :func:`pospp.open_run` (or
``open_archive`` for the manifest) and written again: the Arrow schema and the values
round-trip exactly. tests/e2e/test_first_hour_walk.py does the same on a real sample run.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import pospp
from pospp.api import SchemaError, TableNotInRun
from pospp.io import parquet_tables, run_folder
from pospp.io.manifest import ManifestError

RUN_TABLES = [n for n in parquet_tables.TABLES if n not in ("manifest", "diff")]
META = {"input_file": "in.mcap", "input_sha256": "0" * 64, "config": {"name": "test"}}


def _column_values(col: parquet_tables.Column, n: int) -> list:
    t = col.type
    last_null = n > 1 and not col.name.endswith(("_id", "time_ns"))  # a null in the others
    if pa.types.is_floating(t):
        return [0.5 + i for i in range(n)][: n - last_null] + [None] * last_null
    if pa.types.is_integer(t):
        return [10 * i for i in range(n)][: n - last_null] + [None] * last_null
    if pa.types.is_boolean(t):
        return [i % 2 == 0 for i in range(n)]
    return [f"{col.name}-{i}" for i in range(n)]


def _table(name: str) -> dict[str, list]:
    n = 1 if name == "summary" else 3
    data = {c.name: _column_values(c, n) for c in parquet_tables.TABLES[name]}
    if name == "trajectory":
        data["solution"] = ["compensated", "smoothed", "compensated"]
        data["time_ns"] = [30, 20, 10]
    if name == "summary":
        data["status"] = ["degraded"]
    return data


def _run(folder: Path, names=RUN_TABLES) -> Path:
    folder.mkdir()
    for name in names:
        parquet_tables.write_table(folder / f"{name}.parquet", _table(name), name, metadata=META)
    run_folder.write_marker(folder, input_file=folder.parent / "in.mcap", input_sha256="0" * 64,
                            config_json="{}", status="degraded")
    return folder


@pytest.fixture(scope="module")
def every_table_run(tmp_path_factory) -> Path:
    return _run(tmp_path_factory.mktemp("api") / "run")


@pytest.mark.parametrize("name", RUN_TABLES)
def test_every_table_round_trips_its_documented_schema(every_table_run, tmp_path, name):
    run = pospp.open_run(every_table_run)
    df = run.table(name)
    assert list(df.columns) == [c.name for c in parquet_tables.TABLES[name]]
    back = parquet_tables.write_table(tmp_path / f"{name}.parquet", df, name, metadata=META)
    original = pq.read_table(every_table_run / f"{name}.parquet")
    again = pq.read_table(back)
    assert again.schema.equals(original.schema, check_metadata=False)
    assert again.equals(original)
    assert again.schema == parquet_tables.schema(name)  # the documented types, as rendered


def test_typed_access(every_table_run):
    run = pospp.open_run(every_table_run)
    assert run.status == "degraded" and repr(run).endswith(": degraded>")
    s = run.summary
    assert s["status"] == "degraded" and s.units["dv_after_mps"] == "m/s"
    assert s.frames["gyro_bias_x_dph"] == "b (FRD)" and s.units["gyro_bias_x_dph"] == "deg/h"
    assert s.text("dv_after_mps") == "0.5 m/s" and s["n_legs"] == 0
    legs = run.legs
    assert legs.duration_s.isna().iloc[-1]  # a null float is NaN in a frame
    comp = run.trajectory()
    assert list(comp.solution) == ["compensated", "compensated"]
    assert comp.time_ns.is_monotonic_increasing
    assert list(run.trajectory("best").solution) == ["compensated"] * 2
    assert len(run.trajectory(None)) == 3
    with pytest.raises(TableNotInRun, match="no 'forward' solution.*compensated, smoothed"):
        run.trajectory("forward")
    for prop in ("legs", "pairs", "calibration", "leg_errors", "qc", "diagnosis", "events",
                 "biases", "messages", "evaluation"):
        assert list(getattr(run, prop).columns)[:2] == \
            [c.name for c in parquet_tables.TABLES[prop]][:2]
    assert run.columns("legs").set_index("column").unit["duration_s"] == "s"
    mine = run.legs
    mine.loc[0, "leg_id"] = 99  # a fresh frame each time: the run's copy is not changed
    assert run.legs.leg_id.iloc[0] == 0


def test_a_missing_table_says_why_and_the_folder_must_be_a_run(tmp_path):
    run = pospp.open_run(_run(tmp_path / "run", ["summary", "trajectory"]))
    assert not run.has("events") and run.tables() == ["trajectory", "summary"]
    with pytest.raises(TableNotInRun, match="no events.parquet .no trigger events"):
        _ = run.events
    with pytest.raises(TableNotInRun, match="pospp evaluate"):
        _ = run.evaluation
    with pytest.raises(KeyError, match="no table 'legz'"):
        run.table("legz")
    (tmp_path / "plain").mkdir()
    with pytest.raises(run_folder.RunFolderError) as err:
        pospp.open_run(tmp_path / "plain")
    assert "not a pospp run folder" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(FileNotFoundError):
        pospp.open_run(tmp_path / "absent")


def test_read_by_name_added_columns_kept_older_optional_columns_filled(tmp_path):
    run_dir = _run(tmp_path / "run", ["summary"])
    legs = _table("legs")
    for c in parquet_tables.TABLES["legs"]:
        if not c.required:
            legs.pop(c.name)  # an older run: no optional column
    legs = pa.table(legs).append_column("leg_quality_new", pa.array([1.0, 2.0, 3.0]))
    pq.write_table(legs, run_dir / "legs.parquet")  # a later pospp's extra column
    df = pospp.open_run(run_dir).legs
    assert df.heading_spread_deg.isna().all() and df.leg_quality_new.tolist() == [1, 2, 3]
    bad = pa.table({**_table("legs"), "duration_s": ["300", "300", "300"]})
    pq.write_table(bad, run_dir / "legs.parquet")
    with pytest.raises(SchemaError, match=r"legs.parquet: column 'duration_s' is string, "
                                          r"documented as double"):
        _ = pospp.open_run(run_dir).legs


def test_plots_are_matplotlib_figures_and_save(every_table_run, tmp_path):
    from matplotlib.figure import Figure

    run = pospp.open_run(every_table_run)
    fig = run.plot.leg_errors("position")
    assert isinstance(fig, Figure) and fig.axes
    fig.savefig(tmp_path / "le.png")
    assert (tmp_path / "le.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="quantity"):
        run.plot.leg_errors("speed")


def test_import_pospp_is_light():
    """``import pospp`` loads neither numpy nor pandas; the API loads on first use."""
    code = ("import sys, pospp; assert 'pandas' not in sys.modules and 'numpy' not in "
            "sys.modules; pospp.open_run; assert 'pandas' in sys.modules; print(pospp.__all__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "open_run" in out and "open_archive" in out and "diff_paths" in out
    assert "process_flight" in out and "load_config" in out
    from pospp.pipeline import process_flight
    assert pospp.process_flight is process_flight
    assert set(pospp.__all__) == {*pospp._HOME, "__version__"}
    assert all(callable(getattr(pospp, name)) for name in pospp.__all__ if name != "__version__")
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        pospp.nope  # noqa: B018


def test_open_archive_over_a_manifest_never_trusts_its_folder_names(tmp_path):
    from pospp.batch.outcome import FlightOutcome, write_rows
    from pospp.config import PipelineConfig

    root = tmp_path / "root"
    _run(root / "a", ["summary", "trajectory"]) if root.mkdir() is None else None
    rows = [FlightOutcome("/x/a.mcap", "s", "degraded", 1.0, None, run_dir="a"),
            FlightOutcome("/x/b.mcap", "s", "failed", 1.0, "boom", run_dir="../victim"),
            FlightOutcome("/x/c.mcap", "s", "ok", 1.0, None, run_dir="/abs/c")]
    write_rows(root, rows, PipelineConfig())
    archive = pospp.open_archive(root)
    assert archive.flights == ["a"] and archive.manifest.run_dir.isna().sum() == 2
    assert archive.run("a").status == "degraded" and archive.run("/x/a.mcap").path == root / "a"
    with pytest.raises(KeyError, match="no flight '/x/b.mcap'"):
        archive.run("/x/b.mcap")
    assert list(archive.summaries().index) == ["a"]
    assert "1 degraded" in repr(archive)
    pq.write_table(pa.table({"file": ["x"]}), root / "manifest.parquet")  # another tool's
    with pytest.raises(ManifestError, match="not a pospp manifest"):
        pospp.open_archive(root)
    (root / "manifest.parquet").unlink()
    with pytest.raises(FileNotFoundError, match="no manifest.parquet"):
        pospp.open_archive(root)


def test_summary_dict_of_a_real_row_has_python_values(every_table_run):
    s = pospp.open_run(every_table_run).summary
    assert all(v is None or isinstance(v, str | int | float | bool) for v in s.values())
    assert isinstance(s, dict) and pd.notna(s["duration_s"]) and np.isfinite(s["duration_s"])
    assert isinstance(s["n_legs"], int)
