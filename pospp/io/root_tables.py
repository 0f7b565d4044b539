"""The tables of a batch root (``pospp batch``, ``pospp diff``): the manifest and the diff.

Declared here, part of ``pospp.io.parquet_tables.TABLES`` (docs/formats.md renders them with
the run tables): ``manifest`` (one row per flight: its result and what the last batch did) and
``diff`` (``pospp diff``: what changed between two runs or two roots, against tolerances).
"""

from __future__ import annotations

from pospp.io.columns import BOOL, FLOAT, INT, TEXT, Column, optional

__all__ = ["DIFF_COLUMNS", "MANIFEST_COLUMNS"]

_F, _I, _S, _B = FLOAT, INT, TEXT, BOOL
_opt = optional

MANIFEST_COLUMNS: list[Column] = [
    Column("file", _S, "", "input file"),
    Column("sha256", _S, "", "SHA-256 of the input file"),
    Column("status", _S, "", "result of the run in the flight's folder, the words of "
           "pospp run: 'ok', 'degraded', 'partial' or 'failed' (null: queued, no run yet)"),
    Column("duration_s", _F, "s", "processing wall time of this batch's work on it"),
    Column("error", _S, "", "why the run failed, one line (null when it did not)"),
    _opt(Column("n_legs", _I, "", "legs found")),
    _opt(Column("dv_after_mps", _F, "m/s", "summary dv_after_mps")),
    _opt(Column("dp_after_m", _F, "m", "summary dp_after_m")),
    _opt(Column("qc_failed_checks", _S, "", "summary qc_failed_checks")),
    _opt(Column("dv_before_mps", _F, "m/s", "summary dv_before_mps")),
    *[_opt(Column(f"gyro_bias_{ax}{kind}_dph", _F, "deg/h", f"summary gyro_bias_{ax}{kind}"
                  "_dph", "b (FRD)")) for ax in "xy" for kind in ("", "_sigma")],
    _opt(Column("gap_heldout_mps", _F, "m/s", "summary gap_heldout_mps")),
    _opt(Column("not_observable", _S, "", "summary not_observable")),
    _opt(Column("action", _S, "", "what the last batch did: 'ran', 'skipped' (its folder "
                "held a finished run of this input and configuration), 'resumed' (an "
                "earlier batch queued it and stopped before it finished) or 'queued' (not "
                "reached: the batch was stopped)")),
]
"""Table ``manifest``: ``ROOT/manifest.parquet`` (pospp.batch)."""

DIFF_COLUMNS: list[Column] = [
    Column("flight", _S, "", "run folder name under the batch roots ('' for two runs)"),
    Column("item", _S, "", "what is compared: 'flight' (present in both), 'status', "
           "'n_legs', a summary column, or 'position', 'velocity', 'attitude', 'epochs' "
           "of a trajectory solution"),
    Column("solution", _S, "", "trajectory solution of the row ('' for headline rows)"),
    Column("value_a", _F, "see unit", "the value in A (NaN: not a number or absent)"),
    Column("value_b", _F, "see unit", "the value in B"),
    Column("text_a", _S, "", "the value in A as text (status, presence)"),
    Column("text_b", _S, "", "the value in B as text"),
    Column("max_diff", _F, "see unit", "largest |B - A| (trajectory: over the common "
           "epochs; position and velocity as 3-D distances, attitude as the rotation "
           "angle between the two attitudes)"),
    Column("rms_diff", _F, "see unit", "RMS of |B - A| over the common epochs (headline "
           "rows: |B - A|)"),
    Column("tolerance", _F, "see unit", "the largest |B - A| taken as unchanged"),
    Column("unit", _S, "", "unit of the values, differences and tolerance"),
    Column("within", _B, "", "whether the row is within its tolerance"),
    Column("note", _S, "", "what changed, in words (empty when within)"),
]
"""Table ``diff``: ``diff.parquet`` of ``pospp diff`` and ``pospp batch --baseline``."""
