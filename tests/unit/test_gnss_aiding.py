"""Where algorithm A was GNSS-aided (pospp.nav.aiding) and the QC check on it (gnss_coverage),
on arrays made by hand (issue 38 item 1); the same on pospp runs: tests/e2e/
test_fault_injection_qc.py (the sample flight) and tests/unit/test_qc_reference.py (the
independent simulator's flight with its GNSS cut)."""

from __future__ import annotations

import numpy as np
import pytest

from pospp.calib.pairs import PairPolicy, evaluate_pairs
from pospp.calib.segment import Leg
from pospp.nav.aiding import AIDED_SIGMA_FACTOR, GNSS_GAP_MAX_S, gnss_aiding, leg_aiding_problem
from pospp.qc.coverage import gnss_coverage

T = np.arange(0.0, 1000.0, 0.1)  # A's epochs at 10 Hz [s]
SIGMA = np.tile([0.004, 0.004, 0.006], (T.size, 1))  # aided forward velocity sigma [m/s]


def _used(*holes: tuple[float, float]) -> np.ndarray:
    """GNSS records at 1 Hz, none inside the holes."""
    t = np.arange(0.5, 1000.0, 1.0)
    for a, b in holes:
        t = t[(t < a) | (t >= b)]
    return t


def test_clean_gnss_has_no_gap_and_every_leg_is_aided():
    aid = gnss_aiding(_used(), T, SIGMA)
    assert aid.gaps_s.shape == (0, 2) and aid.longest_gap_s == pytest.approx(1.0)
    assert aid.aided_vel_sigma_mps == pytest.approx(np.hypot(0.004, 0.004))
    assert leg_aiding_problem(aid, 300.0, 600.0, T, 0.2 * SIGMA) is None
    check = gnss_coverage(aid, [(0, 300.0, 600.0)])
    assert check.passed and check.value == pytest.approx(1.0) and check.unit == "s"
    # a few dropped records and a gated one are not a gap
    assert gnss_aiding(_used((100.0, 103.0)), T, SIGMA).gaps_s.shape[0] == 0


def test_gnss_lost_before_the_end_is_a_gap_over_the_legs_inside():
    aid = gnss_aiding(_used((350.0, 2000.0)), T, SIGMA)
    assert aid.gaps_s.shape == (1, 2)
    assert aid.gaps_s[0] == pytest.approx([349.5, T[-1]])
    why = leg_aiding_problem(aid, 400.0, 700.0, T, SIGMA)
    assert why is not None and "no GNSS record from t = 350 s to the end of the data" in why
    assert leg_aiding_problem(aid, 20.0, 340.0, T, SIGMA) is None  # before the loss
    check = gnss_coverage(aid, [(0, 20.0, 340.0), (1, 400.0, 700.0)], {1: why})
    assert not check.passed and check.severity == "degraded"
    assert check.value == pytest.approx(T[-1] - 349.5)
    assert "no GNSS from t = 350 s to the end of the data" in check.suggestion
    assert "leg 1 in it" in check.suggestion and "leg 1 refused by the calib" in check.suggestion
    assert check.time_ns_offset == int(round(349.5e9))


def test_a_short_gap_inside_a_leg_below_the_threshold_passes():
    aid = gnss_aiding(_used((500.0, 500.0 + GNSS_GAP_MAX_S - 2.0)), T, SIGMA)
    assert leg_aiding_problem(aid, 400.0, 700.0, T, SIGMA) is None
    assert gnss_coverage(aid, [(0, 400.0, 700.0)]).passed


def test_gnss_that_aids_nothing_shows_in_a_sigma():
    """Records present but useless (a huge covariance): no gap, A's sigma grows on the leg."""
    aid = gnss_aiding(_used(), T, SIGMA)
    grown = SIGMA.copy()
    on = (T > 450.0) & (T < 650.0)
    grown[on] *= 2.0 * AIDED_SIGMA_FACTOR
    why = leg_aiding_problem(aid, 400.0, 700.0, T, grown)
    assert why is not None and "horizontal velocity sigma reaches" in why and "10 times" in why
    check = gnss_coverage(aid, [(3, 400.0, 700.0)], {3: why})
    assert not check.passed and check.value == pytest.approx(300.0)
    assert "leg 3: reference A not GNSS-aided" in check.suggestion


def test_a_refused_leg_is_named_in_its_pairs():
    legs = tuple(Leg(i, 100.0 + 400.0 * i, 400.0 + 400.0 * i, h, 60.0, 1000.0, 0.0, 0.0,
                     0.0, 0.0) for i, h in enumerate((0.0, np.pi)))
    pairs = evaluate_pairs({}, legs, PairPolicy(), leg_reasons={1: "reference A not aided"})
    assert [p.used for p in pairs] == [False]
    assert pairs[0].reason == "leg 1: reference A not aided"
