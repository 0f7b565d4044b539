"""Parquet output tables: one pyarrow schema per table, atomic writes, metadata, hashing.

Every table pospp writes is declared once in ``TABLES`` (name -> list of ``Column``): column
name, pyarrow type, unit, description, frame. The unit, frame and description go into each
field's metadata; the table name, ``SCHEMA_VERSION`` and the pospp version go into the file's
key-value metadata together with the caller's metadata (input hash, pipeline config, ...) as
JSON. docs/formats.md renders the same dict (:mod:`pospp.io.schema_docs`).

Conventions (see ``pospp`` package docstring): NED navigation frame n, FRD body frame b,
Euler z-y-x [roll, pitch, yaw] of b w.r.t. n with yaw clockwise from north, int64 ``time_ns``
(UTC nanoseconds, as stamped in the input), errors computed minus true (B minus A for legs).

Writes are atomic: a temporary file in the destination folder, fsync, ``os.replace``; a reader
never sees half a file and an interrupted run leaves the previous file intact.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pospp import __version__
from pospp.io.columns import BOOL, FLOAT, INT, TEXT, Column, optional
from pospp.io.files import atomic_path
from pospp.io.root_tables import DIFF_COLUMNS, MANIFEST_COLUMNS
from pospp.types import ReferenceTrajectory

if TYPE_CHECKING:  # pandas is loaded by pyarrow when a table is read (read_table)
    import pandas as pd

__all__ = [
    "EXTENSIBLE_TABLES",
    "SCHEMA_VERSION",
    "TABLES",
    "Column",
    "read_metadata",
    "read_reference_trajectory",
    "read_table",
    "schema",
    "write_reference_trajectory",
    "write_table",
]

SCHEMA_VERSION = "1.0"
"""Bumped on any incompatible change of a table below (renamed/retyped/removed column)."""

_RESERVED_KEYS = ("pospp_version", "schema_name", "schema_version")


_F, _I, _S, _B = FLOAT, INT, TEXT, BOOL
_NED = "n (NED)"
_ATT = "b (FRD) w.r.t. n (NED), z-y-x"
_FRD = "b (FRD)"
_SENSOR_ATT = "s (sensor, [sensor] boresight in b) w.r.t. n (NED), z-y-x"
_opt = optional


_TIME = Column("time_ns", _I, "ns", "sample time (UTC nanoseconds, as stamped in the input)")
_NAV = [
    Column("lat_deg", _F, "deg", "geodetic latitude, WGS-84", "WGS-84"),
    Column("lon_deg", _F, "deg", "geodetic longitude, WGS-84", "WGS-84"),
    Column("height_m", _F, "m", "height above the WGS-84 ellipsoid", "WGS-84"),
    Column("vn_mps", _F, "m/s", "velocity north", _NED),
    Column("ve_mps", _F, "m/s", "velocity east", _NED),
    Column("vd_mps", _F, "m/s", "velocity down", _NED),
    Column("roll_deg", _F, "deg", "roll", _ATT),
    Column("pitch_deg", _F, "deg", "pitch", _ATT),
    Column("yaw_deg", _F, "deg", "yaw (heading), clockwise from north, [0, 360)", _ATT),
]

TABLES: dict[str, list[Column]] = {
    "trajectory": [
        _TIME,
        Column("solution", _S, "", "'forward', 'smoothed' or 'compensated'"),
        *_NAV,
        *[
            _opt(Column(f"{ax}_sigma_m", _F, "m", f"1-sigma position error, {ax}", _NED))
            for ax in ("north", "east", "down")
        ],
        *[
            _opt(Column(f"v{ax}_sigma_mps", _F, "m/s", f"1-sigma velocity error, v{ax}", _NED))
            for ax in ("n", "e", "d")
        ],
        *[
            _opt(Column(f"{a}_sigma_deg", _F, "deg", f"1-sigma {a} error (from the "
                        "misalignment covariance)", _ATT))
            for a in ("roll", "pitch", "yaw")
        ],
    ],
    "legs": [
        Column("leg_id", _I, "", "leg number, 0-based in time order"),
        Column("start_ns", _I, "ns", "leg start time"),
        Column("end_ns", _I, "ns", "leg end time"),
        Column("duration_s", _F, "s", "end minus start"),
        Column("heading_deg", _F, "deg", "mean yaw over the leg, clockwise from north", _ATT),
        Column("speed_mps", _F, "m/s", "mean horizontal speed", _NED),
        Column("height_m", _F, "m", "mean ellipsoidal height", "WGS-84"),
        _opt(Column("heading_spread_deg", _F, "deg", "max minus min yaw over the leg", _ATT)),
        _opt(Column("speed_std_mps", _F, "m/s", "standard deviation of the horizontal speed")),
        _opt(Column("vertical_speed_mps", _F, "m/s", "mean vertical speed, down positive",
                    _NED)),
        _opt(Column("heading_rate_max_dps", _F, "deg/s", "max |yaw rate| over the leg")),
        _opt(Column("reason", _S, "", "'ok', or why the leg was not replayed (its reference A "
                    "not GNSS-aided: docs/qc.md, gnss_coverage)")),
    ],
    "pairs": [
        Column("pair_id", _I, "", "pair number"),
        Column("leg_a", _I, "", "leg_id of the first leg"),
        Column("leg_b", _I, "", "leg_id of the second leg"),
        Column("dheading_deg", _F, "deg", "heading change from leg a to leg b, in [0, 180]"),
        Column("dspeed_mps", _F, "m/s", "speed of leg b minus speed of leg a"),
        Column("cond_raw", _F, "1", "condition number of the stacked matrix (paper Eq. 17)"),
        Column("cond_scaled", _F, "1", "condition number after column scaling"),
        Column("used", _B, "", "whether the pair entered the calibration"),
        Column("reason", _S, "", "why the pair was used or rejected"),
    ],
    "calibration": [
        Column("pair_id", _I, "", "pair the estimate comes from (-1: all pairs combined)"),
        Column("formulation", _S, "", "'paper' (nav-frame drift) or 'body' (body-frame bias)"),
        Column("transition", _S, "", "'closed_form' or 'numerical' transition matrix"),
        Column("parameter", _S, "", "paper axes: phi_x = phi_E, phi_y = phi_N, phi_z = -phi_D "
               "(common misalignment), phi_x_leg<i> / phi_y_leg<i> (tilt at leg i's start); "
               "eps_e, eps_n (nav-frame drift); gyro_bias_x/y/z (body FRD, the turn-on "
               "constant), gyro_bias_x/y_flight (pair -1: over the flight's legs); docs/method.md"),
        Column("value", _F, "see unit", "estimate, in the row's unit"),
        Column("sigma", _F, "see unit", "1-sigma of the estimate, in the row's unit"),
        Column("unit", _S, "", "'arcsec' or 'deg_per_h'"),
    ],
    "leg_errors": [
        Column("leg_id", _I, "", "leg"),
        Column("stage", _S, "", "'before' or 'after' compensation"),
        Column("t_s", _F, "s", "time since the leg start"),
        Column("dvn_mps", _F, "m/s", "B minus A velocity error, north", _NED),
        Column("dve_mps", _F, "m/s", "B minus A velocity error, east", _NED),
        Column("dpn_m", _F, "m", "B minus A position error, north", _NED),
        Column("dpe_m", _F, "m", "B minus A position error, east", _NED),
    ],
    "summary": [
        Column("input_file", _S, "", "input MCAP path"),
        Column("input_sha256", _S, "", "SHA-256 of the input file"),
        _opt(Column("status", _S, "", "'ok' (every stage ran, every QC check passed), "
                    "'partial', 'degraded' or 'failed' (docs/qc.md)")),
        _opt(Column("duration_s", _F, "s", "IMU data span")),
        _opt(Column("n_imu_samples", _I, "", "IMU samples read")),
        _opt(Column("n_gnss_fixes", _I, "", "GNSS fixes read")),
        _opt(Column("imu_rate_hz", _F, "Hz", "nominal IMU rate")),
        _opt(Column("n_legs", _I, "", "straight uniform legs found")),
        _opt(Column("n_pairs_used", _I, "", "leg pairs used in the calibration")),
        _opt(Column("dv_before_mps", _F, "m/s", "B-minus-A horizontal velocity error at the "
                    "leg end before compensation (RMS over legs)")),
        _opt(Column("dv_after_mps", _F, "m/s", "same, after compensation")),
        _opt(Column("dp_before_m", _F, "m", "B-minus-A horizontal position error at the leg "
                    "end before compensation (RMS over legs)")),
        _opt(Column("dp_after_m", _F, "m", "same, after compensation")),
        _opt(Column("calibration_reason", _S, "", "'ok', or why no calibration was produced")),
        _opt(Column("wall_time_s", _F, "s", "processing wall time of the run "
                    "(pospp.pipeline.process_flight "
                    "from its call to the summary's last write, report included; not the "
                    "interpreter's start-up and imports)")),
        *[_opt(Column(f"stage_{name}_s", _F, "s", f"wall time of the {name} stage{extra}"))
          for name, extra in (("ingest", " (with checking the run folder and hashing the "
                                         "input)"),
                              ("navigate", " (algorithm A)"), ("calibrate", ""),
                              ("null_realisations", " (B minus A's null: the calibration's "
                                                    "sigmas, the diagnosis's realisations)"),
                              ("compensate", " (on 2+ threads: the wait for its A pass, "
                                             "made alongside the null)"),
                              ("diagnose", " (on 2+ threads: likewise its first A passes)"),
                              ("qc", " (quality checks; on 2+ threads: the wait for them)"),
                              ("write", " (tables and trajectory MCAP)"),
                              ("report", " (report.html)"))],
        _opt(Column("qc_failed_checks", _S, "", "comma-joined names of the failed QC checks "
                    "(empty: all passed; qc.parquet)")),
        _opt(Column("qc_suggestions", _S, "", "'; '-joined 'check: what the data suggest' of "
                    "the failed QC checks")),
        _opt(Column("calibration_sigma_source", _S, "", "where the calibration's sigmas come "
                    "from: 'linear_null' (the least squares' exact covariance under B minus A's "
                    "linear null), 'null_realisations' (refits on the re-run null's "
                    "realisations, [pairs] null_reruns) or 'least_squares' (its formal "
                    "covariance)")),
        _opt(Column("calibration_formulation", _S, "", "formulation of the calibration applied "
                    "('body' or 'paper')")),
        _opt(Column("gyro_drift_sigma_dph", _F, "deg/h", "Gauss-Markov gyro drift of the "
                    "calibration's noise model (the null realisations inject it when its "
                    "source is 'flight' or 'grade'): steady-state sigma per body axis (0: no "
                    "drift model)", "b (FRD)")),
        _opt(Column("gyro_drift_tau_s", _F, "s", "its correlation time (inf: no drift model)")),
        _opt(Column("gyro_drift_source", _S, "", "where the drift comes from: 'flight' (sigma "
                    "and tau by REML on this flight's legs, the [imu] grade's a weak prior; "
                    "the flight rejects the grade's drift at 5 %), 'grade' (it does not: the "
                    "grade's kept), 'flight_sigma' (sigma by REML, tau given), 'given' or "
                    "'none'")),
        *[_opt(Column(f"gyro_bias_{ax}{kind}_dph", _F, "deg/h", f"calibrated gyro bias, body "
                      f"{ax} (FRD){' 1-sigma' if kind else ''}; NaN: not estimated", "b (FRD)"))
          for ax in "xyz" for kind in ("", "_sigma")],
        *[_opt(Column(f"gyro_bias_sensor_{ax}{kind}_dph", _F, "deg/h", f"the calibrated gyro "
                      f"bias{' 1-sigma' if kind else ''} in the IMU's logged axes, {ax} (FLU for "
                      "ROS logs: x as body x, y and z negated; [input] sensor_frame, "
                      "mounting_rpy_deg); NaN: not estimated", "s (sensor, as logged)"))
          for ax in "xyz" for kind in ("", "_sigma")],
        _opt(Column("imu_axes", _S, "", "the IMU's logged axes of gyro_bias_sensor_*: 'FLU', "
                    "'FRD' or 'as logged' (another [input] mounting_rpy_deg)")),
        *[_opt(Column(f"gyro_bias_{ax}_flight{kind}_dph", _F, "deg/h", "gyro bias over the "
                      f"flight's fitted legs, body {ax} (FRD){' 1-sigma' if kind else ''}; "
                      f"gyro_bias_{ax}_dph: the turn-on constant; NaN: not estimated",
                      "b (FRD)")) for ax in "xyz" for kind in ("", "_sigma")],
        _opt(Column("refit_effects", _S, "", "';'-joined effects removed from B minus A for "
                    "the calibration's refit (the compensation, dv/dp_after use it)")),
        *[_opt(Column(f"gyro_bias_{ax}_refit{k}_dph", _F, "deg/h", f"refitted gyro bias, body "
                      f"{ax}{' 1-sigma' if k else ''}", "b (FRD)")) for ax in "xyz"
          for k in ("", "_sigma")],
        _opt(Column("not_observable", _S, "", "'; '-joined 'parameter: sigma > bound: why' of "
                    "the applied fit's parameters not observable on these legs (docs/report.md)"
                    )),
        _opt(Column("gap_uncalibrated_mps", _F, "m/s", "RMS of B minus A horizontal velocity "
                    "over every leg sample, no calibration")),
        _opt(Column("gap_fit_mps", _F, "m/s", "same minus the calibration fitted to every leg "
                    "(in-sample)")),
        _opt(Column("gap_heldout_mps", _F, "m/s", "same minus the calibration fitted without "
                    "the leg (leave-one-leg-out, held out; diagnosis)")),
    ],
    "qc": [
        Column("check", _S, "", "check name (docs/qc.md), e.g. 'gravity_direction', "
               "'gnss_time_offset'"),
        Column("stage", _S, "", "pipeline stage whose data or result is checked"),
        Column("measure", _S, "", "what value is (or why the check was not applicable)"),
        Column("value", _F, "see unit", "the statistic (NaN: not applicable)"),
        Column("threshold", _F, "see unit", "the check fails when value exceeds it"),
        Column("unit", _S, "", "unit of value and threshold"),
        Column("passed", _B, "", "whether the check passed"),
        Column("severity", _S, "", "run status a failure imposes: 'partial', 'degraded' or "
               "'failed'"),
        Column("suggestion", _S, "", "what the data suggest when it failed (may be empty)"),
        Column("time_ns", _I, "ns", "time of the worst sample (null if not timed)"),
    ],
    "diagnosis": [
        Column("step", _I, "", "step of the model-discrepancy workflow"),
        Column("effect", _S, "", "candidate effect tested"),
        Column("value", _F, "see unit", "estimated size of the effect"),
        Column("sigma", _F, "see unit", "1-sigma of the estimate"),
        Column("unit", _S, "", "unit of value and sigma"),
        Column("statistic", _F, "1", "test statistic"),
        Column("p_value", _F, "1", "p-value of the test"),
        Column("significant", _B, "", "whether the effect is significant"),
        Column("gap_before_mps", _F, "m/s", "model-data velocity gap before adding the effect"),
        Column("gap_after_mps", _F, "m/s", "model-data velocity gap after adding the effect"),
        Column("heldout_gap_before_mps", _F, "m/s", "same on held-out legs, before"),
        Column("heldout_gap_after_mps", _F, "m/s", "same on held-out legs, after"),
        _opt(Column("criterion", _S, "", "the test behind p_value (e.g. 'F-test')")),
        _opt(Column("delta_bic", _F, "1", "BIC of the model with the effect minus without")),
        _opt(Column("explained_fraction", _F, "1", "share of the structured (lack-of-fit) gap "
                    "the effect explains")),
        _opt(Column("confounded_with", _S, "", "';'-joined effects with a similar signature")),
        _opt(Column("parameters", _S, "", "';'-joined parameter names of the effect")),
        _opt(Column("parameter_values", _S, "", "';'-joined values, in the row's unit")),
        _opt(Column("parameter_sigmas", _S, "", "';'-joined 1-sigmas, in the row's unit")),
        _opt(Column("horizon_s", _F, "s", "horizon: median last sample time of the legs")),
        _opt(Column("gap_horizon_mps", _F, "m/s", "what the row is worth: B's velocity error "
                    "at the horizon that the effect (closing row: the structured gap) adds to "
                    "the model before it, RMS over the legs")),
        _opt(Column("gap_horizon_m", _F, "m", "the same integrated over the leg (position)")),
        _opt(Column("residual_horizon_mps", _F, "m/s", "the calibration's own residual at the "
                    "horizon, RMS over the legs (the scale for gap_horizon_mps)")),
        _opt(Column("residual_horizon_m", _F, "m", "the same integrated (position)")),
        _opt(Column("gap_legs", _S, "", "closing row 'unexplained': ';'-joined legs carrying "
                    "the structured gap (80 % of it, largest first)")),
        _opt(Column("gap_channel", _S, "", "closing row 'unexplained': 'N', 'E' or 'N+E'")),
        _opt(Column("gap_part", _S, "", "closing row 'unexplained': 'early', 'middle', "
                    "'late' (or two joined by '+') or 'whole leg'")),
        _opt(Column("gap_basis", _S, "", "closing row 'unexplained': the lack-of-fit basis "
                    "function carrying most of the gap ('legendre_k', 'cos_k')")),
        _opt(Column("gap_location", _S, "", "closing row 'unexplained': where the gap sits "
                    "and its size at the horizon, one sentence")),
        _opt(Column("null_model", _S, "", "what the p-values are calibrated on: the null "
                    "realisations and the gyro drift they inject, and whether they were re-made "
                    "with the drift re-estimated with a named effect removed")),
        _opt(Column("shape", _S, "", "a family's shape (effects_catalog.SHAPES; empty: one form)")),
        _opt(Column("shape_parameters", _S, "", "its own parameter, what was removed first")),
        _opt(Column("null_rebuilt", _B, "", "null re-made with the drift under the alternative")),
        _opt(Column("null_rebuilt_with", _S, "", "';'-joined effects removed for that")),
    ],
    "observability": [
        Column("formulation", _S, "", "'paper' or 'body'"),
        Column("dheading_deg", _F, "deg", "heading change between the two ideal legs"),
        Column("dspeed_mps", _F, "m/s", "speed of leg b minus speed of leg a"),
        Column("cond_raw", _F, "1", "condition number of the stacked matrix (paper Eq. 17), "
               "SI units"),
        Column("cond_scaled", _F, "1", "condition number after column scaling"),
        _opt(Column("heading_deg", _F, "deg", "heading of leg a, clockwise from north", _ATT)),
        _opt(Column("speed_mps", _F, "m/s", "speed of leg a")),
        _opt(Column("duration_s", _F, "s", "duration of each ideal leg")),
        _opt(Column("lat_deg", _F, "deg", "latitude of the ideal legs", "WGS-84")),
    ],
    "evaluation": [
        Column("solution", _S, "", "'forward', 'smoothed' or 'compensated'"),
        Column("metric", _S, "", "e.g. north_rms, horizontal_rms, vel_horizontal_rms, "
               "roll_pitch_rms, heading_rms (solution minus reference)"),
        Column("value", _F, "see unit", "the figure, in the row's unit"),
        Column("unit", _S, "", "'m', 'm/s' or 'arcsec'"),
        _opt(Column("skip_s", _F, "s", "epochs within this time of the first were left out")),
        _opt(Column("n_epochs", _I, "", "epochs compared")),
        _opt(Column("reference_file", _S, "", "reference trajectory used")),
    ],
    "diagnosis_curves": [
        Column("leg_id", _I, "", "leg"),
        Column("t_s", _F, "s", "time since the leg start"),
        Column("model", _S, "", "'before' (base model) or 'after' (with the named effects)"),
        Column("kind", _S, "", "'fit' (all legs fitted) or 'heldout' (leave-one-leg-out)"),
        Column("dvn_mps", _F, "m/s", "B minus A minus the model, north", _NED),
        Column("dve_mps", _F, "m/s", "B minus A minus the model, east", _NED),
    ],
    "messages": [
        Column("severity", _S, "", "'info', 'warning' or 'error'"),
        Column("stage", _S, "", "pipeline stage that emitted it (e.g. 'ingest')"),
        Column("time_ns", _I, "ns", "time the message refers to (null if none)"),
        Column("text", _S, "", "the message"),
        _opt(Column("topic", _S, "", "input topic concerned")),
        _opt(Column("index", _I, "", "message index within the topic (0-based, file order)")),
        _opt(Column("byte_offset", _I, "bytes", "file offset, for corrupt files")),
        _opt(Column("log_time_ns", _I, "ns", "MCAP log time of the message concerned (where "
                    "it is in the file; time_ns is its header stamp)")),
    ],
    "manifest": MANIFEST_COLUMNS,
    "diff": DIFF_COLUMNS,
    "reference": [_TIME, *_NAV],
    "events": [
        _TIME,
        Column("event_id", _I, "", "event number, 0-based in time order"),
        Column("solution", _S, "", "solution interpolated ('compensated', 'smoothed' or "
               "'forward': the best of the run)"),
        Column("inside", _B, "", "whether the event lies within the solution (else NaN)"),
        *[c._replace(description=c.description.replace("velocity", "sensor velocity"))
          for c in _NAV[:6]],
        Column("roll_deg", _F, "deg", "sensor roll", _SENSOR_ATT),
        Column("pitch_deg", _F, "deg", "sensor pitch", _SENSOR_ATT),
        Column("yaw_deg", _F, "deg", "sensor yaw, clockwise from north, [0, 360)", _SENSOR_ATT),
        *[Column(f"{ax}_sigma_m", _F, "m", f"1-sigma sensor position error, {ax} (IMU position "
                 "and attitude errors through the lever arm)", _NED)
          for ax in ("north", "east", "down")],
        *[Column(f"v{ax}_sigma_mps", _F, "m/s", f"1-sigma velocity error, v{ax}", _NED)
          for ax in ("n", "e", "d")],
        *[Column(f"{a}_sigma_deg", _F, "deg", f"1-sigma sensor {a} error", _SENSOR_ATT)
          for a in ("roll", "pitch", "yaw")],
    ],
    "biases": [
        _TIME,
        Column("solution", _S, "", "'forward' (filtered) or 'smoothed'"),
        *[Column(f"gyro_bias_{ax}_dph", _F, "deg/h", f"estimated gyro bias, {ax} (total: "
                 "constant + Gauss-Markov), measured = (1 + s) true + b", _FRD) for ax in "xyz"],
        *[Column(f"gyro_bias_{ax}_sigma_dph", _F, "deg/h", f"1-sigma of gyro_bias_{ax}", _FRD)
          for ax in "xyz"],
        *[Column(f"accel_bias_{ax}_ug", _F, "ug", f"estimated accelerometer bias, {ax} (total), "
                 "1 ug = 9.80665e-6 m/s^2", _FRD) for ax in "xyz"],
        *[Column(f"accel_bias_{ax}_sigma_ug", _F, "ug", f"1-sigma of accel_bias_{ax}", _FRD)
          for ax in "xyz"],
        *[_opt(Column(f"{s}_sf_{ax}_ppm", _F, "ppm", f"estimated {s} scale factor, {ax} "
                      "(null when not estimated)", _FRD))
          for s in ("gyro", "accel") for ax in "xyz"],
        *[_opt(Column(f"{s}_sf_{ax}_sigma_ppm", _F, "ppm", f"1-sigma of {s}_sf_{ax}", _FRD))
          for s in ("gyro", "accel") for ax in "xyz"],
    ],
    "sim_comparison": [
        Column("step", _I, "", "0: the configured model; k >= 1: after the k-th effect"),
        Column("kind", _S, "", "'base' (step 0: one row per level of the base model fitted "
               "to the log), 'statistic' (one row per statistic and step), 'effect' (one row "
               "per fitted parameter of the step's effect) or 'reading' (what else the step's "
               "reading determines: the combination of confounded effects, correlations)"),
        Column("measure", _S, "", "statistic compared (docs/compare_sim.md); on effect rows the "
               "step's target"),
        Column("effect", _S, "", "effect added at this step, 'unexplained', or '' (step 0)"),
        Column("parameter", _S, "", "effect parameter (effect rows; '' otherwise)"),
        Column("value", _F, "see unit", "fitted size of the parameter (effect rows)"),
        Column("sigma", _F, "see unit", "1-sigma of the fitted size (effect rows)"),
        Column("unit", _S, "", "unit of size and sigma (effect rows) or of the gaps"),
        Column("gap_before", _F, "see unit", "measured minus simulated before the step"),
        Column("gap_after", _F, "see unit", "measured minus simulated after the step"),
        Column("sigma_gap", _F, "see unit", "1-sigma of the gap before the step"),
        Column("z_before", _F, "1", "gap / sigma before"),
        Column("z_after", _F, "1", "gap / sigma after"),
        Column("p_before", _F, "1", "Holm-adjusted p-value before"),
        Column("significant_before", _B, "", "gap significant before (family-wise level)"),
        Column("significant_after", _B, "", "gap significant after"),
        Column("measured", _F, "see unit", "the measured flight's value"),
        Column("simulated_before", _F, "see unit", "the simulation's value before (base "
               "rows: the level simulated, the fit or, within 2 sigma of it, the prior)"),
        Column("simulated_after", _F, "see unit", "the simulation's value after"),
        Column("prior", _F, "see unit", "base rows: the grade's (or the receiver's reported) "
               "value of the fitted level; NaN otherwise"),
        Column("note", _S, "", "base rows: the fit in words; effect rows: the step's reading "
               "(both readings where the flight cannot separate confounded effects)"),
    ],
}
"""Table name -> columns. Add a table or a column here; docs/formats.md renders this dict."""

EXTENSIBLE_TABLES = frozenset({"summary", "manifest"})
"""Tables that accept extra columns (types inferred, unit from the name suffix)."""

_SUFFIX_UNITS = {"_mps2": "m/s^2", "_mps": "m/s", "_m": "m", "_s": "s", "_ns": "ns",
                 "_deg": "deg", "_rad": "rad", "_dph": "deg/h", "_ug": "ug", "_hz": "Hz",
                 "_ppm": "ppm", "_arcsec": "arcsec", "_radps": "rad/s", "_dps": "deg/s"}


def _suffix_unit(name: str) -> str:
    for suf in sorted(_SUFFIX_UNITS, key=len, reverse=True):
        if name.endswith(suf):
            return _SUFFIX_UNITS[suf]
    return ""


def _field(c: Column) -> pa.Field:
    meta = {"unit": c.unit, "frame": c.frame, "description": c.description}
    return pa.field(c.name, c.type, nullable=True, metadata=meta)


def schema(name: str) -> pa.Schema:
    """The pyarrow schema of table ``name`` (fields carry unit/frame/description metadata)."""
    if name not in TABLES:
        raise KeyError(f"unknown table {name!r}; known: {sorted(TABLES)}")
    return pa.schema([_field(c) for c in TABLES[name]])


def _columns_of(data: pd.DataFrame | Mapping[str, Any]) -> dict[str, Any]:
    if not isinstance(data, Mapping):  # a DataFrame
        return {str(c): data[c] for c in data.columns}
    cols = dict(data)
    if cols and all(np.ndim(v) == 0 for v in cols.values()):  # a dict of scalars = one row
        cols = {k: [v] for k, v in cols.items()}
    return cols


def _to_array(name: str, values: Any, typ: pa.DataType | None) -> pa.Array:
    if not isinstance(values, np.ndarray | list) and hasattr(values, "to_numpy"):  # a Series
        values = values.to_numpy(dtype=object if values.dtype == object else None)
    try:
        if typ is None:
            return pa.array(values, from_pandas=True)
        if isinstance(values, np.ndarray) and values.dtype.kind in "fc" \
                and pa.types.is_integer(typ):
            if not np.all(np.isnan(values) | (values == np.round(values))):
                raise ValueError("non-integral values")
            values = [None if np.isnan(v) else int(v) for v in values]
        return pa.array(values, type=typ, from_pandas=True)
    except (pa.ArrowInvalid, pa.ArrowTypeError, ValueError, TypeError) as exc:
        raise ValueError(f"column {name!r}: cannot convert to {typ}: {exc}") from exc


def _build(data: pd.DataFrame | Mapping[str, Any], name: str) -> pa.Table:
    cols = TABLES[name] if name in TABLES else None
    if cols is None:
        raise KeyError(f"unknown table {name!r}; known: {sorted(TABLES)}")
    given = _columns_of(data)
    names = [c.name for c in cols]
    missing = [c.name for c in cols if c.required and c.name not in given]
    if missing:
        raise ValueError(
            f"table {name!r}: missing required column(s) {missing}; expected {names}, "
            f"got {list(given)}"
        )
    extra = [k for k in given if k not in names]
    if extra and name not in EXTENSIBLE_TABLES:
        raise ValueError(f"table {name!r}: unexpected column(s) {extra}; schema has {names}")
    lengths = {k: len(v) for k, v in given.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"table {name!r}: columns differ in length: {lengths}")
    n = next(iter(lengths.values())) if lengths else 0
    if name == "summary" and n != 1:
        raise ValueError(f"table 'summary' must have exactly one row, got {n}")
    arrays, fields = [], []
    for c in cols:
        if c.name in given:
            arrays.append(_to_array(c.name, given[c.name], c.type))
        else:
            arrays.append(pa.nulls(n, type=c.type))
        fields.append(_field(c))
    for k in extra:
        arr = _to_array(k, given[k], None)
        arrays.append(arr)
        fields.append(pa.field(k, arr.type, metadata={"unit": _suffix_unit(k), "frame": "",
                                                      "description": "extra column"}))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def write_table(
    path: str | Path,
    data: pd.DataFrame | Mapping[str, Any],
    schema_name: str,
    *,
    metadata: Mapping[str, Any],
) -> Path:
    """Validate ``data`` against table ``schema_name`` and write it atomically as Parquet.

    Parameters
    ----------
    path : str or Path
        Destination file (its folder is created if needed).
    data : pandas.DataFrame or mapping of column -> array-like
        A mapping of scalars is one row. Required columns must be present (error naming them);
        optional ones absent become nulls; values are cast to the schema types (error naming
        the column on failure); extra columns are an error except in ``EXTENSIBLE_TABLES``.
    schema_name : str
        A key of ``TABLES``.
    metadata : mapping
        JSON-serialisable run metadata stored in the file, e.g. ``{"input_sha256": ...,
        "config": {...}}``. The pospp version, table name and schema version are added.

    Returns
    -------
    Path
        ``path``.
    """
    table = _build(data, schema_name)
    clash = [k for k in metadata if k in _RESERVED_KEYS]
    if clash:
        raise ValueError(f"metadata keys {clash} are reserved ({list(_RESERVED_KEYS)})")
    try:
        user = json.dumps(dict(metadata), sort_keys=True, allow_nan=True)
    except TypeError as exc:
        raise TypeError(f"metadata must be JSON-serialisable: {exc}") from exc
    kv = {
        b"pospp.version": __version__.encode(),
        b"pospp.schema_name": schema_name.encode(),
        b"pospp.schema_version": SCHEMA_VERSION.encode(),
        b"pospp.metadata": user.encode(),
    }
    table = table.replace_schema_metadata(kv)
    # dictionary encoding for the text only: on unique floats it cost the 1.5 h flight's
    # trajectory.parquet 0.24 s instead of 0.07 and 4 MB
    text = [f.name for f in table.schema if pa.types.is_string(f.type)]
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd", use_dictionary=text)
    return Path(path)


def read_table(path: str | Path) -> pd.DataFrame:
    """Read a pospp Parquet table into a DataFrame (column types as in the schema)."""
    return pq.read_table(path).to_pandas()


def read_metadata(path: str | Path) -> dict[str, Any]:
    """File metadata: ``pospp_version``, ``schema_name``, ``schema_version`` and the caller's
    metadata passed to ``write_table`` (e.g. ``input_sha256``, ``config``)."""
    kv = pq.read_schema(path).metadata or {}
    out: dict[str, Any] = json.loads(kv.get(b"pospp.metadata", b"{}"))
    out["pospp_version"] = kv.get(b"pospp.version", b"").decode() or None
    out["schema_name"] = kv.get(b"pospp.schema_name", b"").decode() or None
    out["schema_version"] = kv.get(b"pospp.schema_version", b"").decode() or None
    return out


# --------------------------------------------------------------------------- reference


def read_reference_trajectory(path: str | Path) -> ReferenceTrajectory:
    """Read a reference Parquet (columns of ``TABLES["reference"]``; others are ignored)."""
    from pospp.io.files import require_regular

    require_regular(path)  # a FIFO would block pyarrow's read forever
    names = [c.name for c in TABLES["reference"]]
    have = pq.read_schema(path).names
    missing = [n for n in names if n not in have]
    if missing:
        raise ValueError(f"{path}: reference trajectory lacks column(s) {missing}; got {have}")
    t = pq.read_table(path, columns=names)
    col = {n: t.column(n).to_numpy(zero_copy_only=False) for n in names}
    time_ns = col["time_ns"].astype(np.int64)
    bad = np.flatnonzero(np.diff(time_ns) <= 0)
    if bad.size:
        raise ValueError(f"{path}: time_ns must increase strictly; row {bad[0] + 1} does not")
    floats = {n: col[n].astype(float) for n in names[1:]}
    for n, v in floats.items():
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{path}: non-finite {n} at row {int(np.argmin(np.isfinite(v)))}")
    return ReferenceTrajectory(
        time_ns=time_ns,
        lat_rad=np.deg2rad(floats["lat_deg"]),
        lon_rad=np.deg2rad(floats["lon_deg"]),
        height_m=floats["height_m"],
        v_n_mps=np.column_stack([floats["vn_mps"], floats["ve_mps"], floats["vd_mps"]]),
        rpy_rad=np.deg2rad(
            np.column_stack([floats["roll_deg"], floats["pitch_deg"], floats["yaw_deg"]])
        ),
    )


def write_reference_trajectory(
    path: str | Path, ref: ReferenceTrajectory, *, metadata: Mapping[str, Any] | None = None
) -> Path:
    """Write a ReferenceTrajectory in the reference Parquet format (yaw wrapped to [0, 360))."""
    rpy = np.rad2deg(ref.rpy_rad)
    data = {"time_ns": ref.time_ns, "lat_deg": np.rad2deg(ref.lat_rad),
            "lon_deg": np.rad2deg(ref.lon_rad), "height_m": ref.height_m,
            "vn_mps": ref.v_n_mps[:, 0], "ve_mps": ref.v_n_mps[:, 1], "vd_mps": ref.v_n_mps[:, 2],
            "roll_deg": rpy[:, 0], "pitch_deg": rpy[:, 1], "yaw_deg": np.mod(rpy[:, 2], 360.0)}
    return write_table(path, data, "reference", metadata=dict(metadata or {}))
