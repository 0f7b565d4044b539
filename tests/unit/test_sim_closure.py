"""Closure: error-free simulated IMU data, integrated by pospp's strapdown, reproduces the truth.

The increments travel the real path: Simulation.imu (mean rates over the interval ending at
each stamp) -> increments_from_rates -> strapdown.integrate, from the true state at the first
IMU stamp, over the whole mission. Bounds are the brief's (0.05 m/s, 1 m, 5 arcsec); the
errors actually left are far smaller (docs/simulator.md). The unaided vertical channel
amplifies any error by about exp(t / 570 s), so the 2.3 h flight closing is a strong check of
both the increments and the kernel.
"""

from __future__ import annotations

import numpy as np
import pytest

from pospp import earth, rotation, units
from pospp.io.mcap_reader import read_flight_log
from pospp.nav.strapdown import increments_from_rates, integrate
from pospp.sim.api import simulate
from pospp.sim.imu import exact_increments
from pospp.sim.profile import parse_profile, plan_mission
from pospp.sim.trajectory import ProfileMotion

VEL_TOL_MPS = 0.05
POS_TOL_M = 1.0
ATT_TOL_ARCSEC = 5.0


def _errors(out, truth, sl):
    dp = earth.llh_difference_ned_m(out.lat_rad, out.lon_rad, out.height_m, truth.lat_rad[sl],
                                    truth.lon_rad[sl], truth.height_m[sl])
    dv = out.v_n_mps - truth.v_n_mps[sl]
    att = rotation.angle_between_rad(out.c_nb, rotation.dcm_from_quat(truth.q_nb[sl]))
    return (np.abs(dp).max(), np.abs(dv).max(), att.max() / units.ARCSEC_RAD)


def _closure(sim, window_s=None):
    t_s, dth, dv = increments_from_rates(sim.imu.time_ns, sim.imu.w_ib_b_radps,
                                         sim.imu.f_ib_b_mps2, epoch_ns=sim.start_time_ns)
    # t_s[j] is truth epoch j + 1
    n = len(t_s)
    step = n if window_s is None else int(round(window_s / (t_s[1] - t_s[0])))
    worst = np.zeros(3)
    for a in range(0, n - 1, step):
        b = min(n - 1, a + step)
        out = integrate(t_s[a : b + 1], dth[a:b], dv[a:b], sim.truth.state(a + 1),
                        previous_increments=None if a == 0 else (dth[a - 1], dv[a - 1]))
        worst = np.maximum(worst, _errors(out, sim.truth, slice(a + 1, b + 2)))
    return worst


@pytest.mark.parametrize("preset, rate", [("sample", 100.0), ("vehicle", 100.0)])
def test_whole_mission_closure(preset, rate):
    sim = simulate(preset, imu_grade="errorfree", seed=1, imu_rate_hz=rate)
    pos, vel, att = _closure(sim)
    assert pos < POS_TOL_M and vel < VEL_TOL_MPS and att < ATT_TOL_ARCSEC, (pos, vel, att)
    if preset == "vehicle":  # level road: nothing for the vertical channel to amplify
        assert pos < 0.01 and vel < 1e-4 and att < 0.01, (pos, vel, att)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["flight", "grid"])
def test_long_flight_closure_at_200_hz(preset):
    sim = simulate(preset, imu_grade="errorfree", seed=1, imu_rate_hz=200.0)
    assert sim.truth.t_s[-1] > 2 * 3600
    pos, vel, att = _closure(sim)
    assert pos < POS_TOL_M and vel < VEL_TOL_MPS and att < ATT_TOL_ARCSEC, (pos, vel, att)


def test_quadrature_has_converged():
    """2 x 4 Gauss-Legendre nodes agree with 8 x 4 to far below sensor resolution."""
    prof = parse_profile({
        "start": {"lat_deg": 45.0, "lon_deg": 7.0, "height_m": 300.0, "heading_deg": 0.0},
        "segment": [{"type": "static", "duration_s": 1.0},
                    {"type": "accelerate", "to_speed_mps": 40.0, "duration_s": 8.0},
                    {"type": "climb", "rate_mps": 5.0, "delta_m": 30.0, "blend_s": 2.0},
                    {"type": "turn", "angle_deg": 90.0, "rate_dps": 10.0, "blend_s": 1.0}]})
    m = ProfileMotion(plan_mission(prof))
    t = np.arange(0.0, 24.0, 0.01)
    a = exact_increments(m, t, n_sub=2, n_gl=4)
    b = exact_increments(m, t, n_sub=8, n_gl=4)
    assert np.abs(a[0] - b[0]).max() < 1e-14  # rad
    assert np.abs(a[1] - b[1]).max() < 1e-12  # m/s


@pytest.mark.reference
def test_static_imu_matches_the_independent_simulator(reference_cases):
    """Same place, heading and level attitude: our static IMU output equals the reference's
    (Earth rate in the body, specific force -gamma) - an outside check of frames and signs."""
    import json

    params = json.loads((reference_cases / "vehicle_errorfree.params.json").read_text())
    start = params["mission"]["start"]
    log = read_flight_log(reference_cases / "vehicle_errorfree.mcap")
    t_rel = (log.imu.time_ns - log.imu.time_ns[0]) * 1e-9
    ref_static = t_rel < 60.0
    w_ref = log.imu.w_ib_b_radps[ref_static].mean(axis=0)
    f_ref = log.imu.f_ib_b_mps2[ref_static].mean(axis=0)
    prof = parse_profile({"start": start, "options": {"turn_bank": "none"},
                          "segment": [{"type": "static", "duration_s": 60.0}]})
    sim = simulate(prof, seed=0, imu_rate_hz=200.0)
    w = sim.imu.w_ib_b_radps.mean(axis=0)
    f = sim.imu.f_ib_b_mps2.mean(axis=0)
    np.testing.assert_allclose(w, w_ref, atol=1e-12)  # rad/s (Earth rate 7.3e-5)
    np.testing.assert_allclose(f, f_ref, atol=1e-9)  # m/s^2


def test_fast_attitude_helpers_match_pospp_rotation():
    from pospp.sim.imu import dcm_nb_from_euler, quat_nb_from_euler

    rng = np.random.default_rng(0)
    rpy = rng.uniform(-np.pi, np.pi, (500, 3)) * [1.0, 0.49, 1.0]
    ref = rotation.dcm_from_euler(rpy)
    assert np.abs(dcm_nb_from_euler(rpy) - ref).max() < 1e-14
    assert np.abs(rotation.dcm_from_quat(quat_nb_from_euler(rpy)) - ref).max() < 1e-14
