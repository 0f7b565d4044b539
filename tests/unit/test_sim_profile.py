"""Mission profiles and smooth schedules: closed forms checked against numerical calculus."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from pospp.sim.profile import load_profile, parse_profile, plan_mission, preset_names
from pospp.sim.ramps import RampSchedule
from pospp.sim.trajectory import ProfileMotion

START = {"lat_deg": 34.0, "lon_deg": 108.0, "height_m": 100.0, "heading_deg": 10.0}


def _profile(*segments, turn_bank="coordinated"):
    return parse_profile({"name": "t", "start": START, "options": {"turn_bank": turn_bank},
                          "segment": list(segments)})


def test_ramp_derivatives_and_integral_against_numerical_calculus():
    s = RampSchedule.build(1.0, [(2.0, 3.0, 4.0), (7.0, 1.5, -2.5), (10.0, 2.0, 0.7)])
    t = np.linspace(0.0, 14.0, 2801)
    x, x1, x2 = s.evaluate(t)
    h = 1e-5
    xp, x1p, _ = s.evaluate(t + h)
    xm, x1m, _ = s.evaluate(t - h)
    np.testing.assert_allclose(x1, (xp - xm) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(x2, (x1p - x1m) / (2 * h), atol=3e-4)  # O(h) at the joins
    for tt in (0.5, 3.3, 6.0, 8.1, 11.0, 14.0):
        knots = [p for p in (2.0, 5.0, 7.0, 8.5, 10.0, 12.0) if p < tt]
        ref, _ = quad(lambda u: s.evaluate(np.array(u))[0], 0.0, tt, points=knots or None,
                      epsabs=1e-13, epsrel=1e-13, limit=200)
        assert s.integral(np.array(tt)) == pytest.approx(ref, abs=1e-10)
    # C2 joins: value, slope and curvature continuous at every ramp end
    for te in (2.0, 5.0, 7.0, 8.5, 10.0, 12.0):
        a = [v.item() for v in s.evaluate(np.array(te - 1e-9))]
        b = [v.item() for v in s.evaluate(np.array(te + 1e-9))]
        np.testing.assert_allclose(a, b, atol=1e-6)


def test_overlapping_ramps_are_rejected():
    with pytest.raises(ValueError, match="overlap"):
        RampSchedule.build(0.0, [(0.0, 2.0, 1.0), (1.0, 1.0, 1.0)])


def test_turn_climb_and_leg_geometry_match_the_request():
    prof = _profile(
        {"type": "static", "duration_s": 5.0},
        {"type": "accelerate", "to_speed_mps": 50.0, "duration_s": 20.0},
        {"type": "climb", "rate_mps": 5.0, "delta_m": 300.0, "blend_s": 6.0},
        {"type": "straight", "length_m": 6000.0},
        {"type": "turn", "angle_deg": -135.0, "rate_dps": 3.0},
        {"type": "straight", "duration_s": 30.0},
    )
    plan = plan_mission(prof)
    m = ProfileMotion(plan)
    seg = plan.segments
    end = m.evaluate(np.array([seg[2].end_s, seg[4].end_s]))
    assert end.height_m[0] == pytest.approx(400.0, abs=1e-6)  # climb reached its target
    assert math.degrees(end.rpy_rad[1, 2]) == pytest.approx(10.0 - 135.0, abs=1e-9)
    assert seg[4].end_s - seg[4].start_s == pytest.approx(135.0 / 3.0 + 5.0)
    leg = plan.legs[0]
    assert leg.duration_s == pytest.approx(120.0) and leg.height_m == pytest.approx(400.0)
    # during the straight leg the motion is level, straight, constant speed
    mid = m.evaluate(np.linspace(leg.start_s, leg.end_s, 50))
    np.testing.assert_allclose(np.hypot(mid.v_n_mps[:, 0], mid.v_n_mps[:, 1]), 50.0, atol=1e-9)
    np.testing.assert_allclose(mid.v_n_mps[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(mid.rpy_rad[:, :2], 0.0, atol=1e-12)
    # distance flown along the leg (geodesic, via NED) equals the requested length
    from pospp.earth import llh_to_ned_m

    ned = llh_to_ned_m(mid.lat_rad[-1], mid.lon_rad[-1], mid.height_m[-1],
                       mid.lat_rad[0], mid.lon_rad[0], mid.height_m[0])
    assert np.hypot(ned[0], ned[1]) == pytest.approx(6000.0, abs=0.05)


def test_coordinated_bank_and_position_derivative_consistency():
    prof = _profile(
        {"type": "static", "duration_s": 2.0},
        {"type": "accelerate", "to_speed_mps": 60.0, "duration_s": 30.0},
        {"type": "turn", "angle_deg": 180.0, "rate_dps": 3.0},
    )
    m = ProfileMotion(plan_mission(prof))
    t = np.linspace(33.0, 90.0, 400)
    s = m.evaluate(t)
    turn_rate = s.rpy_rate_radps[:, 2]
    np.testing.assert_allclose(np.tan(s.rpy_rad[:, 0]), 60.0 * turn_rate / 9.80665, atol=1e-12)
    # the integrated position's derivative equals the closed-form velocity (truth consistency)
    h = 1e-3
    p1 = m.position(t + h)
    p0 = m.position(t - h)
    from pospp.earth import principal_radii_m

    r_m, r_n = principal_radii_m(s.lat_rad)
    vn = (p1[0] - p0[0]) / (2 * h) * (r_m + s.height_m)
    ve = (p1[1] - p0[1]) / (2 * h) * (r_n + s.height_m) * np.cos(s.lat_rad)
    np.testing.assert_allclose(vn, s.v_n_mps[:, 0], atol=1e-5)
    np.testing.assert_allclose(ve, s.v_n_mps[:, 1], atol=1e-5)


@pytest.mark.parametrize("name", ["flight", "vehicle", "grid", "sample"])
def test_presets_load_and_meet_the_brief(name):
    assert name in preset_names()
    plan = plan_mission(load_profile(name))
    survey = [lg for lg in plan.legs if lg.kind == "survey"]
    assert len(survey) >= 3
    headings = np.degrees([lg.heading_rad for lg in survey]) % 360.0
    assert any(abs((b - a) % 360.0 - 180.0) < 1e-9 for a, b in zip(headings, headings[1:],
                                                                  strict=False))
    if name == "flight":
        assert plan.segments[0].type == "static" and plan.segments[0].end_s == 600.0
        s_time = sum(lg.duration_s for lg in survey) + sum(
            s.end_s - s.start_s for s in plan.segments if "survey:" in s.label)
        assert 1.4 * 3600 < s_time < 1.7 * 3600
        assert all(300.0 <= lg.duration_s <= 420.0 for lg in survey)
        assert max(s.height_end_m for s in plan.segments) == pytest.approx(2600.0)
    if name == "vehicle":
        assert all(lg.duration_s >= 300.0 and lg.speed_mps == 9.0 for lg in survey)
        assert all(lg.speed_mps * lg.duration_s == pytest.approx(2700.0) for lg in survey)
    if name == "grid":
        assert {round(h) % 180 for h in headings} == {0, 90}
    if name == "sample":
        assert 20 * 60 <= plan.duration_s <= 28 * 60
        assert any(abs(((b - a) % 360.0) - 90.0) < 1e-9 for a, b in zip(
            headings, headings[1:], strict=False))


def test_bad_profiles_fail_with_the_facts():
    with pytest.raises(ValueError, match="unknown"):
        _profile({"type": "static", "duration_s": 1.0, "speed": 3})
    with pytest.raises(ValueError, match="type must be one of"):
        _profile({"type": "hover", "duration_s": 1.0})
    with pytest.raises(ValueError, match="speed > 0"):
        plan_mission(_profile({"type": "straight", "duration_s": 10.0}))
    with pytest.raises(ValueError, match="unknown mission preset"):
        load_profile("no_such_preset")


def test_profile_from_a_toml_file_and_progress_reports(tmp_path):
    from pospp.sim.api import simulate

    path = tmp_path / "mine.toml"
    path.write_text(
        'name = "mine"\nimu_rate_hz = 20\n'
        "[start]\nlat_deg = 10.0\nlon_deg = 20.0\nheight_m = 5.0\nheading_deg = 270.0\n"
        '[options]\nturn_bank = "none"\n'
        '[[segment]]\ntype = "static"\nduration_s = 3.0\n'
        '[[segment]]\ntype = "accelerate"\nto_speed_mps = 5.0\nduration_s = 4.0\n'
        '[[segment]]\ntype = "straight"\nlength_m = 50.0\nkind = "survey"\n'
    )
    prof = load_profile(path)
    assert prof.name == "mine" and prof.turn_bank == "none" and prof.imu_rate_hz == 20.0
    seen = []
    sim = simulate(path, seed=0, progress=lambda stage, f: seen.append((stage, f)))
    assert len(sim.imu) == 17 * 20 and sim.legs[0].length_m == pytest.approx(50.0)
    stages = [s for s, _ in seen]
    assert {"trajectory", "imu", "errors", "gnss", "truth"} <= set(stages)
    assert all(0.0 <= f <= 1.0 for _, f in seen) and seen[-1] == ("truth", 1.0)
    with pytest.raises(FileNotFoundError):
        load_profile(tmp_path / "missing.toml")
