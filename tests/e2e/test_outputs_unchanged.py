"""The sample run's tables stay the same through speed work (issue 18).

Hashes of every table of the bundled sample run, recorded from main before the speed changes
(commit 3a6fca8; the diagnosis hash after the null-calibrated tests of issue 12 landed; the
calibration and summary hashes after the calibration's sigmas came from the null realisations
and the summary gained calibration_sigma_source, issue 12 item 6).
Speed work must not move a number; a change that is meant to change the results (a method
fix) regenerates the hashes on purpose, with::

    python -m pospp.cli run sample_data/sample_flight.mcap -p pipelines/sample.toml \
        -o /tmp/s --force
    python tests/e2e/test_outputs_unchanged.py /tmp/s

and pastes the printed dictionary over ``EXPECTED`` below (say why in the commit message).

What is hashed: each column's values, floats rounded to 10 significant digits (the runs are
bitwise deterministic on one machine; the rounding absorbs last-bit differences of another
CPU's libm). Left out: the summary's timing columns (``wall_time_s``, ``stage_*_s``) and its
``input_file`` (the path the run was given; in messages the path is cut to
the file name), and the report (a figure is not a table).
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_data" / "sample_flight.mcap"
SAMPLE_PIPELINE = REPO / "pipelines" / "sample.toml"
TABLES = ("trajectory", "biases", "legs", "pairs", "calibration", "leg_errors", "qc",
          "diagnosis", "diagnosis_curves", "messages", "summary")
SIGNIFICANT_DIGITS = 10


def _column_bytes(values: pd.Series) -> bytes:
    if pd.api.types.is_float_dtype(values.dtype):
        x = values.to_numpy(dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(np.isfinite(x) & (x != 0),
                             10.0 ** (SIGNIFICANT_DIGITS - 1
                                      - np.floor(np.log10(np.abs(np.where(x == 0, 1, x))))),
                             1.0)
            rounded = np.where(np.isfinite(x), np.round(x * scale) / scale, x)
        return np.array([repr(float(v)) for v in rounded]).astype("U").tobytes()
    return repr(values.tolist()).encode("utf-8")


def table_hash(path: Path, name: str) -> str:
    """sha256 over column names and values of one table (see the module docstring)."""
    table = pd.read_parquet(path)
    if name == "summary":
        table = table.drop(columns=[c for c in table.columns if c == "wall_time_s"
                                    or c == "input_file"
                                    or (c.startswith("stage_") and c.endswith("_s"))])
    if name == "messages":  # messages name the input as given: keep its file name only
        table = table.assign(text=table.text.str.replace(r"\S*/(\S+\.mcap)", r"\1",
                                                         regex=True))
    digest = hashlib.sha256()
    for column in table.columns:
        digest.update(column.encode("utf-8"))
        digest.update(_column_bytes(table[column]))
    return digest.hexdigest()[:16]


def run_hashes(run_dir: Path) -> dict[str, str]:
    return {name: table_hash(run_dir / f"{name}.parquet", name) for name in TABLES
            if (run_dir / f"{name}.parquet").is_file()}


EXPECTED: dict[str, str] = {
    "trajectory": "bd36104a84b3b48a", "biases": "e58443785ee33d51", "legs": "b1a3f06a074d2366",
    "pairs": "3834678c775431a7", "calibration": "133a3b8443c777c4",
    "leg_errors": "8fe8e16caf288234", "qc": "004a0e46fdcee046", "diagnosis": "ed2d5e16e18728ce",
    "diagnosis_curves": "b219d94fd5ea4c06", "messages": "e5cf95ab388afc70",
    "summary": "1e0b298cad3ba85c",
}


@pytest.mark.slow
def test_sample_run_tables_are_unchanged_and_timed(tmp_path):
    from pospp.config import load_config
    from pospp.pipeline import STAGES, process_flight

    seen: list[tuple[str, float]] = []
    out = tmp_path / "sample"
    outcome = process_flight(SAMPLE, load_config(SAMPLE_PIPELINE), out,
                  progress=lambda stage, fraction: seen.append((stage, fraction)))
    assert outcome.status == "ok"
    got = run_hashes(out)
    changed = sorted(k for k in EXPECTED if got.get(k) != EXPECTED[k])
    assert not changed, (f"tables changed: {changed} (if intended, regenerate: see the module "
                         f"docstring); now {got}")
    assert set(got) == set(EXPECTED)
    # the console sees every stage, the report last, before 100 %
    assert [s for s, _ in seen] == [*STAGES, "done"]
    assert [f for _, f in seen] == sorted(f for _, f in seen) and seen[-1][1] == 1.0
    # the summary's wall time is the whole run, report included: the stages tile it
    summary = pd.read_parquet(out / "summary.parquet").iloc[0]
    stages = np.array([summary[f"stage_{name}_s"] for name in STAGES])
    assert np.all(stages > 0)
    assert stages.sum() == pytest.approx(summary.wall_time_s, rel=1e-9)
    assert outcome.wall_time_s == summary.wall_time_s


def test_summary_schema_has_a_column_for_every_stage():
    from pospp.io.parquet_tables import schema
    from pospp.pipeline import STAGES

    names = [n for n in schema("summary").names if n.startswith("stage_")]
    assert names == [f"stage_{name}_s" for name in STAGES]


if __name__ == "__main__":
    print(run_hashes(Path(sys.argv[1])))
