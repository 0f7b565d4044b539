"""Leg segmentation against the independent simulator's true legs (reference cases)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pospp.calib.segment import LegThresholds, find_legs


def _truth(ref, name):
    tr = pd.read_parquet(ref / f"{name}.truth.parquet")
    params = json.loads((ref / f"{name}.params.json").read_text())
    t_s = (tr.time_ns.to_numpy() - tr.time_ns.iloc[0]) * 1e-9
    v = tr[["vn_mps", "ve_mps", "vd_mps"]].to_numpy()
    return t_s, v, tr.height_m.to_numpy(), params


@pytest.mark.parametrize("name", ["flight_survey_errors", "vehicle_errorfree"])
def test_found_legs_match_true_legs(reference_cases, name):
    t_s, v, h, params = _truth(reference_cases, name)
    legs = find_legs(t_s, v, h, thresholds=LegThresholds())
    true_legs = [leg for leg in params["legs"] if leg["duration_s"] >= 300.0 - 1e-6]
    assert len(legs) == len(true_legs), (legs, true_legs)
    for found, true in zip(legs, true_legs, strict=True):
        assert abs(found.start_s - true["start_s"]) < 8.0
        assert abs(found.end_s - true["end_s"]) < 8.0
        dh = (np.degrees(found.heading_rad) - true["heading_deg"] + 180) % 360 - 180
        assert abs(dh) < 0.2
        assert abs(found.speed_mps - true["speed_mps"]) < 0.05
        assert abs(found.height_m - true["height_m"]) < 1.0


def test_short_legs_and_no_motion_give_no_legs():
    t = np.arange(0.0, 2000.0, 0.1)
    # stationary: nothing
    assert find_legs(t, np.zeros((t.size, 3)), np.zeros(t.size)) == ()
    # a circle: heading rate 1 deg/s everywhere, never straight
    c = np.radians(t)
    v = np.stack([10 * np.cos(c), 10 * np.sin(c), 0 * c], axis=1)
    assert find_legs(t, v, np.zeros(t.size)) == ()
    # straight for 200 s only
    v = np.zeros((t.size, 3))
    v[(t > 100) & (t < 300), 0] = 20.0
    assert find_legs(t, v, np.zeros(t.size)) == ()
    legs = find_legs(t, v, np.zeros(t.size), thresholds=LegThresholds(min_duration_s=120.0))
    assert len(legs) == 1 and abs(legs[0].duration_s - 200.0) < 15.0
