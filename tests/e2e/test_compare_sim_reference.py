"""``compare-sim`` on the independent simulator's reference cases (issue 33's "Done when").

Each case configured as a new user would: pipelines/flight.toml (grade ``flight``) with the
lever arm of its params.json. The null cases name nothing (what differs from the grade is a
base-model level of step 0, not an effect); flight_time_offset_200hz names the time offset
(GNSS 15 ms late: -15 ms, IMU minus GNSS time) within 25 %; flight_accel_ramp_100hz names the
accelerometer family. Before issue 33 the time offset was named a lever arm (0.74 m), the nulls
carried `unexplained` IMU gaps and a negative bias-instability sigma, the ramp was not named.
Measured (docs/compare_sim.md, the reference cases' table): 12-38 s per case.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from pospp import pipeline
from pospp.compare_sim import compare_log
from pospp.config import config_from_dict

pytestmark = [pytest.mark.slow, pytest.mark.reference]

FLIGHT_TOML = Path(__file__).resolve().parents[2] / "pipelines" / "flight.toml"
NULLS = ("flight_null_200hz", "flight_survey_errors", "vehicle_bias_200hz", "vehicle_errorfree")


def _compare(reference_cases: Path, name: str):
    params = json.loads((reference_cases / f"{name}.params.json").read_text())
    raw = tomllib.loads(FLIGHT_TOML.read_text())
    raw["gnss"]["lever_arm_m"] = params["gnss"]["lever_arm_m"]
    raw["outputs"] = {"mcap": False, "report": False, "diagnose": False}
    cfg = config_from_dict(raw)
    comp, _ = compare_log(pipeline.ingest(reference_cases / f"{name}.mcap", cfg), cfg)
    return params, comp


def _significant(comp) -> list[str]:
    return [g.statistic for g in comp.final.values() if g.significant]


@pytest.mark.parametrize("name", NULLS)
def test_null_reference_cases_name_nothing(reference_cases, name):
    _, comp = _compare(reference_cases, name)
    assert comp.effects_added == (), [(s.target, s.effect, s.size) for s in comp.steps]
    assert not [s for s in comp.steps if s.effect == "unexplained"]
    assert _significant(comp) == []
    # the levels are the log's, never negative (a variance fitted as sqrt(q), q >= 0)
    assert all(b.value >= 0.0 and b.sigma >= 0.0 for b in comp.base_fit
               if b.name.startswith(("gyro_", "accel_")))


def test_time_offset_reference_case_named_within_25_percent(reference_cases):
    params, comp = _compare(reference_cases, "flight_time_offset_200hz")
    truth_ms = -1e3 * params["gnss"]["time_offset_s"]  # GNSS 15 ms late: IMU minus GNSS -15
    assert truth_ms == pytest.approx(-15.0)
    assert comp.effects_added == ("time_offset",), comp.effects_added
    step = next(s for s in comp.steps if s.effect == "time_offset")
    size = dict(zip(step.params, step.size, strict=True))["time_offset"]
    assert step.unit == "ms" and abs(size - truth_ms) <= 0.25 * abs(truth_ms), size
    assert "lever_arm" not in comp.effects_added
    assert _significant(comp) == []


def test_accel_ramp_reference_case_names_the_accelerometer(reference_cases):
    params, comp = _compare(reference_cases, "flight_accel_ramp_100hz")
    assert "accel_bias_ramp" in comp.effects_added, comp.effects_added
    step = next(s for s in comp.steps if s.effect == "accel_bias_ramp")
    ramp = dict(zip(step.params, step.size, strict=True))
    # truth 900 ug/h forward (params.json); the forward ramp is the one the flight shows
    # (measured 890 +- 71 ug/h; the lateral -400 reads 0 +- 377, below 2 sigma)
    assert np.sign(ramp["accel_ramp_x"]) == 1.0 and ramp["accel_ramp_x"] > 450.0, ramp
    assert _significant(comp) == []
