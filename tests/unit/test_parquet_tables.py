"""Parquet output tables: schemas with units, file metadata, atomic and deterministic writes."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import pospp
from pospp.io import parquet_tables as pt
from pospp.io.errors import IngestIssue
from pospp.io.files import sha256_file
from pospp.io.schema_docs import render_all_schemas_markdown
from pospp.outputs import issue_message, messages_table
from pospp.types import ReferenceTrajectory

REPO = Path(__file__).resolve().parents[2]

# The columns design.md and the issue notes promise, per table (at least these).
PROMISED = {
    "trajectory": ["time_ns", "solution", "lat_deg", "lon_deg", "height_m", "vn_mps", "ve_mps",
                   "vd_mps", "roll_deg", "pitch_deg", "yaw_deg", "north_sigma_m",
                   "east_sigma_m", "down_sigma_m", "vn_sigma_mps", "ve_sigma_mps",
                   "vd_sigma_mps", "roll_sigma_deg", "pitch_sigma_deg", "yaw_sigma_deg"],
    "legs": ["leg_id", "start_ns", "end_ns", "duration_s", "heading_deg", "speed_mps",
             "height_m"],
    "pairs": ["pair_id", "leg_a", "leg_b", "dheading_deg", "dspeed_mps", "cond_raw",
              "cond_scaled", "used", "reason"],
    "calibration": ["pair_id", "formulation", "parameter", "value", "sigma", "unit"],
    "leg_errors": ["leg_id", "stage", "t_s", "dvn_mps", "dve_mps", "dpn_m", "dpe_m"],
    "summary": ["input_file", "input_sha256"],
    "messages": ["severity", "stage", "time_ns", "text", "topic", "index", "byte_offset"],
    "manifest": ["file", "sha256", "status", "duration_s", "error"],
    "diagnosis": ["step", "effect", "value", "sigma", "unit", "statistic", "p_value",
                  "significant", "gap_before_mps", "gap_after_mps", "heldout_gap_before_mps",
                  "heldout_gap_after_mps"],
    "observability": ["formulation", "dheading_deg", "dspeed_mps", "cond_raw", "cond_scaled"],
    "evaluation": ["solution", "metric", "value", "unit"],
    "reference": ["time_ns", "lat_deg", "lon_deg", "height_m", "vn_mps", "ve_mps", "vd_mps",
                  "roll_deg", "pitch_deg", "yaw_deg"],
}
# Column names that carry no physical unit (identifiers, labels, counts, dimensionless).
UNITLESS = {"solution", "leg_id", "pair_id", "leg_a", "leg_b", "used", "reason", "formulation",
            "transition", "parameter", "unit", "stage", "input_file", "input_sha256", "status",
            "step", "effect", "statistic", "p_value", "significant", "severity", "text",
            "topic", "index", "file", "sha256", "error", "metric", "cond_raw", "cond_scaled",
            "reference_file", "byte_offset", "criterion", "delta_bic", "explained_fraction",
            "confounded_with", "parameters", "parameter_values", "parameter_sigmas", "model",
            "kind", "calibration_reason",
            "check", "measure", "passed", "suggestion", "qc_failed_checks", "qc_suggestions",
            "calibration_formulation", "calibration_sigma_source", "not_observable",
            "event_id", "inside"}
# Long-form tables: 'value' / 'sigma' carry the unit named in the row's 'unit' column.
ROW_UNIT = {"value", "sigma", "threshold"}
# sim_comparison (compare-sim): gaps in the row's unit, tests unitless
ROW_UNIT |= {"gap_before", "gap_after", "sigma_gap", "measured", "simulated_before",
             "simulated_after", "prior"}
UNITLESS |= {"note"}  # sim_comparison: the step's reading in words (issue 33)
UNITLESS |= {"z_before", "z_after", "p_before", "significant_before", "significant_after"}
# diagnosis: where an unexplained gap sits (issue 12, item 4)
UNITLESS |= {"gap_legs", "gap_channel", "gap_part", "gap_basis", "gap_location"}
# summary: where the calibration's gyro drift comes from (issue 16 item 3)
UNITLESS |= {"gyro_drift_source"}
# diagnosis: the null its p-values are calibrated on (issue 12)
UNITLESS |= {"null_model"}
# manifest: what a batch did; summary: the IMU's axes of the sensor-frame bias (issues 37, 39)
UNITLESS |= {"action", "imu_axes"}
# diff (pospp diff, issue 37): the row's unit column names the unit of its numbers
UNITLESS |= {"flight", "item", "text_a", "text_b", "within", "note"}
ROW_UNIT |= {"value_a", "value_b", "max_diff", "rms_diff", "tolerance"}
# diagnosis: a family's shape, the null re-made under the alternative; summary: the refit's
# effects (issue 34)
UNITLESS |= {"shape", "shape_parameters", "null_rebuilt", "null_rebuilt_with", "refit_effects"}


@pytest.mark.parametrize("name", sorted(PROMISED))
def test_every_promised_table_and_column_exists(name: str) -> None:
    names = pt.schema(name).names
    missing = [c for c in PROMISED[name] if c not in names]
    assert not missing, f"{name}: missing {missing}"


@pytest.mark.parametrize("name", sorted(pt.TABLES))
def test_units_in_names_and_field_metadata(name: str) -> None:
    for field in pt.schema(name):
        meta = {k.decode(): v.decode() for k, v in field.metadata.items()}
        assert set(meta) == {"unit", "frame", "description"}
        assert meta["description"]
        if field.name in ROW_UNIT:
            assert "unit" in pt.schema(name).names and meta["unit"] == "see unit"
        elif field.name in UNITLESS or field.name.startswith("n_"):
            assert meta["unit"] in ("", "1", "bytes"), field.name
        else:  # a physical quantity: the suffix names the unit and the metadata agrees
            assert meta["unit"] == pt._suffix_unit(field.name) != "", (name, field.name)


def test_no_column_is_defined_twice_with_different_meaning() -> None:
    seen: dict[str, tuple] = {}
    for cols in pt.TABLES.values():
        for c in cols:
            key = (c.type, c.unit)
            if c.name in seen and c.name not in ROW_UNIT:
                assert seen[c.name] == key, c.name
            seen[c.name] = key


def _legs(n: int = 4) -> dict:
    rng = np.random.default_rng(2)
    start = 1_717_200_000_000_000_000 + np.arange(n, dtype=np.int64) * 400 * 10**9
    return {
        "leg_id": np.arange(n),
        "start_ns": start,
        "end_ns": start + 300 * 10**9,
        "duration_s": np.full(n, 300.0),
        "heading_deg": rng.uniform(0, 360, n),
        "speed_mps": rng.uniform(55, 65, n),
        "height_m": np.full(n, 2600.0),
    }


META = {"input_sha256": "ab" * 32, "config": {"imu": {"topic": "/imu/data"}, "alpha": 0.5}}


def test_write_read_with_metadata(tmp_path: Path) -> None:
    p = pt.write_table(tmp_path / "legs.parquet", _legs(), "legs", metadata=META)
    df = pt.read_table(p)
    assert list(df.columns) == pt.schema("legs").names
    np.testing.assert_array_equal(df.start_ns.to_numpy(), _legs()["start_ns"])
    assert df.heading_spread_deg.isna().all()  # optional column absent -> nulls
    meta = pt.read_metadata(p)
    assert meta["pospp_version"] == pospp.__version__
    assert meta["schema_name"] == "legs" and meta["schema_version"] == pt.SCHEMA_VERSION
    assert meta["input_sha256"] == META["input_sha256"] and meta["config"] == META["config"]
    field = pq.read_schema(p).field("heading_deg")
    assert field.metadata[b"unit"] == b"deg" and b"FRD" in field.metadata[b"frame"]


def test_sha256_file_matches_hashlib_known_value(tmp_path: Path) -> None:
    p = tmp_path / "abc"
    p.write_bytes(b"abc")
    # FIPS 180-2 test vector for "abc"
    assert sha256_file(p, chunk_bytes=2) == (
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad")


def test_deterministic_bytes(tmp_path: Path) -> None:
    a = pt.write_table(tmp_path / "a.parquet", _legs(), "legs", metadata=META)
    b = pt.write_table(tmp_path / "b.parquet", pd.DataFrame(_legs()), "legs",
                       metadata=dict(reversed(list(META.items()))))
    assert a.read_bytes() == b.read_bytes()


def test_crash_mid_write_leaves_previous_file(tmp_path: Path, monkeypatch) -> None:
    target = pt.write_table(tmp_path / "legs.parquet", _legs(2), "legs", metadata=META)
    before = target.read_bytes()
    real = pq.write_table

    def half_then_crash(table, where, **kw):
        real(table.slice(0, 1), where, **kw)  # something is on disk under the temporary name
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(pq, "write_table", half_then_crash)
    with pytest.raises(OSError, match="simulated"):
        pt.write_table(target, _legs(4), "legs", metadata=META)
    assert target.read_bytes() == before
    assert [q.name for q in tmp_path.iterdir()] == ["legs.parquet"]  # no temporary left
    with pytest.raises(OSError, match="simulated"):
        pt.write_table(tmp_path / "new.parquet", _legs(4), "legs", metadata=META)
    assert not (tmp_path / "new.parquet").exists()


def test_validation_messages(tmp_path: Path) -> None:
    legs = _legs()
    del legs["speed_mps"]
    with pytest.raises(ValueError, match=r"missing required column\(s\) \['speed_mps'\]"):
        pt.write_table(tmp_path / "x.parquet", legs, "legs", metadata={})
    with pytest.raises(ValueError, match=r"unexpected column\(s\) \['speed_kph'\]"):
        pt.write_table(tmp_path / "x.parquet", {**_legs(), "speed_kph": np.zeros(4)}, "legs",
                       metadata={})
    with pytest.raises(ValueError, match="column 'leg_id'"):
        pt.write_table(tmp_path / "x.parquet", {**_legs(), "leg_id": np.full(4, 0.5)}, "legs",
                       metadata={})
    with pytest.raises(ValueError, match="reserved"):
        pt.write_table(tmp_path / "x.parquet", _legs(), "legs", metadata={"pospp_version": 1})
    with pytest.raises(KeyError, match="unknown table"):
        pt.schema("legz")
    assert not list(tmp_path.iterdir())


def test_summary_is_one_row_and_extensible(tmp_path: Path) -> None:
    row = {"input_file": "f.mcap", "input_sha256": "0" * 64, "dv_after_mps": 0.04,
           "gyro_bias_x_dph": 0.49}
    p = pt.write_table(tmp_path / "summary.parquet", row, "summary", metadata={})
    s = pq.read_schema(p)
    assert s.field("gyro_bias_x_dph").metadata[b"unit"] == b"deg/h"
    assert pt.read_table(p).gyro_bias_x_dph.iloc[0] == 0.49
    with pytest.raises(ValueError, match="exactly one row"):
        pt.write_table(tmp_path / "s2.parquet", {k: [v, v] for k, v in row.items()}, "summary",
                       metadata={})


def test_ingest_issues_become_messages(tmp_path: Path) -> None:
    issues = [
        IngestIssue("warning", "f.mcap", "/imu/data", 1000, 17, "IMU gap", log_time_ns=17),
        IngestIssue("error", "f.mcap", None, None, None, "truncated", byte_offset=4096),
    ]
    rows = [issue_message(i) for i in issues]
    p = pt.write_table(tmp_path / "messages.parquet", messages_table(rows), "messages",
                       metadata={})
    df = pt.read_table(p)
    assert df.severity.tolist() == ["warning", "error"]
    assert df["index"].iloc[0] == 1000 and pd.isna(df["index"].iloc[1])
    assert df.byte_offset.iloc[1] == 4096 and df.text.iloc[0] == "f.mcap: IMU gap"
    assert df.log_time_ns.iloc[0] == 17
    assert pq.read_schema(p).field("index").type == pa.int64()


def test_reference_trajectory_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    n = 50
    ref = ReferenceTrajectory(
        time_ns=1_717_200_000_000_000_000 + np.arange(n, dtype=np.int64) * 10**8,
        lat_rad=np.deg2rad(40 + rng.normal(0, 1e-3, n)),
        lon_rad=np.deg2rad(116 + rng.normal(0, 1e-3, n)),
        height_m=rng.uniform(0, 3000, n),
        v_n_mps=rng.normal(0, 30, (n, 3)),
        rpy_rad=np.column_stack([rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(0, 2 * np.pi, n)]),
    )
    p = pt.write_reference_trajectory(tmp_path / "ref.parquet", ref)
    back = pt.read_reference_trajectory(p)
    np.testing.assert_array_equal(back.time_ns, ref.time_ns)
    np.testing.assert_allclose(back.lat_rad, ref.lat_rad, rtol=1e-15)
    np.testing.assert_array_equal(back.v_n_mps, ref.v_n_mps)
    np.testing.assert_allclose(back.rpy_rad, ref.rpy_rad, rtol=1e-14)


def test_reference_trajectory_reads_simulator_truth(reference_cases: Path) -> None:
    ref = pt.read_reference_trajectory(reference_cases / "vehicle_errorfree.truth.parquet")
    assert len(ref) == 12001 and np.all(np.diff(ref.time_ns) == 10**8)
    assert np.rad2deg(ref.rpy_rad[0, 2]) == pytest.approx(45.0)


def _formats_md() -> str:
    return (REPO / "docs" / "formats.md").read_text()


def test_docs_formats_md_holds_the_rendered_schemas() -> None:
    """docs/formats.md embeds render_all_schemas_markdown() verbatim between markers."""
    text = _formats_md()
    m = re.search(r"<!-- schemas:begin -->\n(.*)<!-- schemas:end -->", text, re.S)
    assert m, "markers <!-- schemas:begin --> / <!-- schemas:end --> missing in docs/formats.md"
    assert m.group(1) == render_all_schemas_markdown(), (
        "docs/formats.md is out of date: paste pospp.io.parquet_tables."
        "render_all_schemas_markdown() between the markers")
