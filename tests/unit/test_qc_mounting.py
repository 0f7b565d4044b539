"""The mounting-yaw check (pospp.qc.mounting, issue 38 item 2) on tracks made by hand: A's
heading against the GNSS course in straight, level flight at speed; the same on the sample
flight with the mounting yaw declared wrong: tests/e2e/test_fault_injection_qc.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pospp import rotation
from pospp.qc import checks as qc
from pospp.qc.check_record import skip
from pospp.qc.mounting import heading_offset, lever_arm_naming_mounting, mounting_yaw


def _track(heading_offset_deg: float = 0.0, crab_deg: float = 0.0, *, turns: bool = True,
           sideways: bool = False):
    """Back and forth lines (heading 20 / 200 deg, 300 s each at 60 m/s) joined by 180 deg
    turns of 60 s; GNSS at 1 Hz, A at 10 Hz. A's heading is the body's plus
    ``heading_offset_deg``; the course is the heading plus the crab of a steady wind across the
    lines, ``crab_deg sin(heading - 110 deg)`` (its sign flips with the line); ``sideways``:
    the heading stays at 20 deg while the course turns (a multirotor)."""
    t = np.arange(0.0, 1440.0, 0.1)
    phase = (t % 720.0)
    head = np.where(phase < 300.0, 20.0, np.where(phase < 360.0, 20.0 + 3.0 * (phase - 300.0),
                    np.where(phase < 660.0, 200.0, 200.0 + 3.0 * (phase - 660.0))))
    if not turns:
        head = np.full_like(t, 20.0)
    course = np.radians(head + crab_deg * np.sin(np.radians(head - 110.0)))
    yaw = np.radians((np.full_like(t, 20.0) if sideways else head) + heading_offset_deg)
    q = rotation.quat_from_euler(np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw]))
    g = np.arange(0, t.size, 10)
    v = 60.0 * np.column_stack([np.cos(course[g]), np.sin(course[g]), np.zeros(g.size)])
    return t[g], v, t, q


@pytest.mark.parametrize("crab_deg", [0.0, 15.0])
def test_clean_flight_passes_with_a_crab_that_changes_sign(crab_deg):
    check = mounting_yaw(heading_offset(*_track(crab_deg=crab_deg)), (0.0, 0.0, 0.0))
    assert check.passed and check.value < 0.5, check


@pytest.mark.parametrize("offset_deg", [-90.0, 90.0, 180.0, -60.0])
def test_a_wrong_mounting_yaw_fails_and_gives_the_yaw_that_fixes_it(offset_deg):
    est = heading_offset(*_track(offset_deg, crab_deg=10.0))
    check = mounting_yaw(est, (0.0, 0.0, 30.0))
    assert not check.passed and check.severity == "failed"
    assert check.value == pytest.approx(abs(offset_deg), abs=0.5)
    fix = (30.0 + offset_deg + 180.0) % 360.0 - 180.0
    assert f"mounting_rpy_deg = [0, 0, {fix:.0f}]" in check.suggestion


def test_not_applicable_without_turns_or_when_the_course_ignores_the_heading():
    no_turn = mounting_yaw(heading_offset(*_track(90.0, turns=False)), (0, 0, 0))
    assert no_turn.passed and math.isnan(no_turn.value) and "no turn" in no_turn.statistic
    side = mounting_yaw(heading_offset(*_track(sideways=True)), (0, 0, 0))
    assert side.passed and "does not follow the heading" in side.statistic
    slow = mounting_yaw(heading_offset(*(_track()[0], 0.05 * _track()[1], *_track()[2:])),
                        (0, 0, 0))
    assert slow.passed and "fewer than" in slow.statistic


def test_a_lever_arm_rotated_by_the_mounting_names_the_mounting():
    cfg = np.array([0.3, 0.1, -1.5])
    rotated = np.array([-0.1, 0.3, -1.5])  # R_z(+90) cfg: A in a body yawed by -90 deg
    lever = qc.lever_arm(cfg, rotated, np.full(3, 0.02), observable=(True, True, False))
    mount = mounting_yaw(heading_offset(*_track(-90.0)), (0.0, 0.0, 90.0))
    named = lever_arm_naming_mounting(lever, cfg, rotated, np.full(3, 0.02),
                                      (True, True, False), mount, math.radians(-90.0))
    assert "rotated by +90 deg about body z: the IMU mounting is wrong" in named.suggestion
    # a quarter turn is named even where the heading check could not judge
    blind = skip("mounting_yaw", "navigate", "no turn", "deg")
    named = lever_arm_naming_mounting(lever, cfg, rotated, np.full(3, 0.02),
                                      (True, True, False), blind, None)
    assert "the IMU mounting is wrong, not the lever arm" in named.suggestion
    # a lever arm that is simply wrong keeps its advice
    wrong = np.array([0.9, -0.4, -1.5])
    plain = qc.lever_arm(cfg, wrong, np.full(3, 0.02), observable=(True, True, False))
    assert lever_arm_naming_mounting(plain, cfg, wrong, np.full(3, 0.02), (True, True, False),
                                     blind, None) == plain
