"""Closed-form Schuler channels (paper Eq. 3-14 re-derived) against scipy.linalg.expm of one F."""

from __future__ import annotations

import numpy as np
import pytest
from _truth_imu import rhumb_line
from scipy.linalg import expm

from pospp import earth, rotation
from pospp.nav import closed_form as cf
from pospp.nav import error_model, strapdown

ROWS = [cf.DV_N, cf.DV_E, cf.DR_N, cf.DR_E]
COLS = [cf.PHI_N, cf.PHI_E, cf.PHI_D, cf.EPS_N, cf.EPS_E, cf.EPS_D]
TIMES_S = np.array([0.0, 0.5, 1.0, 7.3, 60.0, 300.0, 1266.0, 2532.0, 5064.0, 7000.0])

CASES = [  # (lat deg, height m, v_n m/s): flight legs both ways, a vehicle, static, high lat
    (40.0, 2600.0, [60.0 * np.cos(np.radians(30)), 60.0 * np.sin(np.radians(30)), 0.0]),
    (40.0, 2600.0, [-60.0 * np.cos(np.radians(30)), -60.0 * np.sin(np.radians(30)), 0.0]),
    (31.5, 50.0, [9.0 / np.sqrt(2), 9.0 / np.sqrt(2), 0.0]),
    (-12.0, 0.0, [0.0, 0.0, 0.0]),
    (70.0, 1000.0, [0.0, -80.0, 0.0]),
]


@pytest.mark.parametrize(("lat_deg", "h_m", "v"), CASES)
def test_closed_forms_equal_expm_rows_both_channels(lat_deg, h_m, v):
    kw = dict(lat_rad=np.radians(lat_deg), height_m=h_m, v_n_mps=v)
    f = cf.simplified_f_matrix(**kw)
    rows = cf.horizontal_error_rows(TIMES_S, **kw)
    ref = np.stack([expm(f * t)[np.ix_(ROWS, COLS)] for t in TIMES_S])
    # 1e-9 relative to the column's largest velocity (position) entry over the times: entries
    # cross zero, and the cross-channel entries are structurally zero
    mag = np.abs(ref).max(axis=0)
    scale = np.concatenate([np.repeat(mag[0:2].max(0, keepdims=True), 2, 0),
                            np.repeat(mag[2:4].max(0, keepdims=True), 2, 0)])[None]
    assert np.all(np.abs(rows - ref) <= 1e-9 * scale + 1e-300)
    # and entry by entry where the entry is not near a zero crossing
    big = np.abs(ref) > 1e-3 * scale
    np.testing.assert_allclose(rows[big], ref[big], rtol=1e-9)
    # velocity_error_rows is the documented (M, 2, 5) block
    np.testing.assert_array_equal(cf.velocity_error_rows(TIMES_S, **kw), rows[:, 0:2, 0:5])


def test_small_times_have_the_taylor_limits():
    # t -> 0: dv_N ~ g phi_E t, dv_E ~ -g phi_N t, dv from eps ~ g eps t^2 / 2
    lat, h = np.radians(40.0), 0.0
    g = float(earth.normal_gravity_mps2(lat, h))
    t = np.array([1e-3])
    rows = cf.velocity_error_rows(t, lat_rad=lat, height_m=h, v_n_mps=[0.0, 0.0])[0]
    np.testing.assert_allclose(rows[0, 1], g * t[0], rtol=1e-9)
    np.testing.assert_allclose(rows[1, 0], -g * t[0], rtol=1e-9)
    np.testing.assert_allclose(rows[0, 4], -g * t[0] ** 2 / 2, rtol=1e-9)
    np.testing.assert_allclose(rows[1, 3], g * t[0] ** 2 / 2, rtol=1e-9)


def test_schuler_period_is_84_minutes():
    om_n, om_e = cf.schuler_frequencies_radps(np.radians(40.0), 0.0)
    for om in (om_n, om_e):
        assert abs(2 * np.pi / om / 60.0 - 84.4) < 0.3


@pytest.mark.parametrize(("lat_deg", "h_m", "v"), CASES)
def test_simplified_f_is_the_horizontal_part_of_the_15_state_f(lat_deg, h_m, v):
    # Same signs and magnitudes as the full model for the terms it keeps (level, unaccelerated)
    lat = np.radians(lat_deg)
    g = float(earth.normal_gravity_mps2(lat, h_m))
    c_nb = np.eye(3)
    full = error_model.f_matrix(lat, h_m, v, c_nb, [0.0, 0.0, -g])
    simp = cf.simplified_f_matrix(lat_rad=lat, height_m=h_m, v_n_mps=v)
    ph, dv, bg = error_model.PHI.start, error_model.DV.start, error_model.BG.start
    full_idx = {
        cf.DV_N: dv, cf.DV_E: dv + 1, cf.PHI_N: ph, cf.PHI_E: ph + 1, cf.PHI_D: ph + 2,
        cf.EPS_N: bg, cf.EPS_E: bg + 1, cf.EPS_D: bg + 2,
    }  # with C_nb = I, b_g = eps_n
    for i, j in zip(*np.nonzero(simp[:8, :8]), strict=True):
        assert full[full_idx[i], full_idx[j]] == pytest.approx(simp[i, j], rel=1e-12), (i, j)


def test_paper_mapping_round_trip_and_signs():
    x_ned = np.array([1.0, 2.0, 3.0, 4.0, 5.0])  # phi_N, phi_E, phi_D, eps_N, eps_E
    x_paper = cf.xp_paper_from_ned(x_ned)
    np.testing.assert_array_equal(x_paper, [2.0, 1.0, -3.0, 5.0, 4.0])
    np.testing.assert_array_equal(cf.xp_ned_from_paper(x_paper), x_ned)


def test_paper_printed_sign_is_the_opposite_of_expm():
    # The paper's F, east channel (its Eq. 6, ENU, level and at rest): dV_E' = -g phi_y,
    # phi_y' = dV_E / R (+ eps_N). Its printed Eq. 13 has +omega_s R sin(omega_s t) in the
    # dV_E row, phi_y column. Compute both and pospp's closed form.
    lat = np.radians(40.0)
    g = float(earth.normal_gravity_mps2(lat, 0.0))
    r_e = float(earth.principal_radii_m(lat)[1])
    om = np.sqrt(g / r_e)
    t = np.array([300.0, 600.0, 1800.0])
    f_east = np.array([[0.0, -g], [1.0 / r_e, 0.0]])  # [dV_E, phi_y]
    from_expm = np.array([expm(f_east * ti)[0, 1] for ti in t])
    printed = +om * r_e * np.sin(om * t)
    # the printed entry is the negative of what the paper's own F gives (not a small
    # difference: both are ~2e6 m/s per rad at 600 s and their sum is 1e-9 of that)
    np.testing.assert_allclose(from_expm, -printed, rtol=1e-9)
    assert np.all(np.abs(from_expm - printed) > 1.9 * np.abs(printed))
    # pospp's closed form follows F, not the print
    rows_paper = cf.velocity_error_rows(t, lat_rad=lat, height_m=0.0, v_n_mps=[0, 0]) @ (
        cf.PAPER_FROM_NED.T
    )  # rows dv_N, dv_E; columns phi_x, phi_y, phi_z, eps_E, eps_N
    np.testing.assert_allclose(rows_paper[:, 1, 1], from_expm, rtol=1e-9)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="v_n_mps"):
        cf.velocity_error_rows([1.0], lat_rad=0.1, height_m=0.0, v_n_mps=[1.0])
    with pytest.raises(ValueError, match="lat_rad"):
        cf.velocity_error_rows([1.0], lat_rad=2.0, height_m=0.0, v_n_mps=[1.0, 0.0])
    with pytest.raises(ValueError, match="t_s"):
        cf.velocity_error_rows([np.nan], lat_rad=0.1, height_m=0.0, v_n_mps=[1.0, 0.0])


@pytest.mark.parametrize(("lat_deg", "h_m", "speed", "heading_deg"),
                         [(40.0, 1000.0, 60.0, 30.0), (40.0, 2600.0, 60.0, 210.0),
                          (31.0, 50.0, 9.0, 45.0)])
def test_closed_forms_approximate_the_full_model_on_an_ideal_leg(lat_deg, h_m, speed,
                                                                heading_deg):
    """Over 300 s the 15-state Phi along the true leg and the closed forms agree to a few %.

    What the simplified model drops (module docstring) shows mostly in the heading column:
    the Coriolis-compensating horizontal specific force (2 Omega sin L v ~ 6e-3 m/s^2 at
    60 m/s) times phi_D adds ~6 % there; tilt and drift columns agree to ~2 %.
    """
    tr = rhumb_line(np.radians(lat_deg), h_m, speed, np.radians(heading_deg), 200.0, 300.0)
    n = tr.t_s.size
    traj = strapdown.Trajectory(
        tr.t_s, tr.lat_rad, tr.lon_rad, np.full(n, h_m), np.tile(tr.v_n_mps, (n, 1)),
        np.tile(rotation.quat_from_dcm(tr.c_nb), (n, 1)),
    )
    phi = error_model.transition_matrices(traj, tr.dv_b_mps / np.diff(tr.t_s)[:, None], step=200)
    t = tr.t_s[::200]
    numerical = np.concatenate(
        [phi[:, 3:5, error_model.PHI], phi[:, 3:5, error_model.BG] @ tr.c_nb.T], axis=2
    )  # columns phi_N, phi_E, phi_D, eps_N, eps_E, eps_D (eps_n = C_nb b_g)
    closed = cf.horizontal_error_rows(t, lat_rad=tr.lat_rad[0], height_m=h_m,
                                      v_n_mps=tr.v_n_mps)[:, 0:2, :]
    rel = np.abs(numerical - closed).max(axis=(0, 1)) / np.abs(numerical).max(axis=(0, 1))
    assert np.all(rel[[0, 1, 3, 4]] < 0.03), rel  # tilts and horizontal drifts
    assert np.all(rel[[2, 5]] < 0.10), rel  # heading and vertical drift

