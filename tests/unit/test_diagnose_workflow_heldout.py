"""Which legs' leave-one-leg-out predictions test a candidate (pospp.diagnose.workflow)."""

from __future__ import annotations

import numpy as np

from pospp.calib.segment import Leg
from pospp.diagnose.workflow import informative_heldout_legs


def _legs(headings_deg: list[float]) -> list[Leg]:
    return [Leg(i, 100.0 * i, 100.0 * i + 90.0, float(np.radians(h)), 60.0, 1000.0, 0.0, 0.0,
                0.0, 0.0) for i, h in enumerate(headings_deg)]


def test_a_leg_predicted_from_legs_of_one_heading_is_not_informative():
    # legs at 20, 200, 20 deg (flight_time_offset_200hz): leg 1's others are both at 20 deg,
    # an extrapolation; legs 0 and 2 are predicted from a reversal pair
    assert informative_heldout_legs(_legs([20.0, 200.0, 20.0])) == [0, 2]
    # the Monte Carlo's legs (30, 210, 300 deg): every leg's others hold two headings
    assert informative_heldout_legs(_legs([30.0, 210.0, 300.0])) == [0, 1, 2]
    # across north: 355 and 5 deg are 10 deg apart, not 350
    assert informative_heldout_legs(_legs([355.0, 5.0, 90.0])) == [0, 1]
    # no leg qualifies (all one heading): every leg, as before
    assert informative_heldout_legs(_legs([20.0, 21.0, 19.0])) == [0, 1, 2]
    # 30 deg is the calibration's pairing bar (calib.pairs.PairPolicy.min_dheading_deg)
    assert informative_heldout_legs(_legs([0.0, 29.0, 0.0, 29.0])) == [0, 1, 2, 3]
    assert informative_heldout_legs(_legs([0.0, 10.0, 10.0]), 5.0) == [1, 2]
