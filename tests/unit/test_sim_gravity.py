"""The simulator's gravity disturbance field (pospp.sim.gravity): a potential's gradient, the
geodetic sign convention, and what a static and a moving IMU sense."""

from __future__ import annotations

import numpy as np
import pytest

from pospp import earth
from pospp.nav.strapdown import increments_from_rates, integrate
from pospp.sim.api import simulate
from pospp.sim.gravity import EOTVOS_PS2, GravityDisturbance, eotvos_from_arcsec_per_km
from pospp.sim.profile import parse_profile
from pospp.units import ARCSEC_RAD, G0_MPS2

LAT0, LON0, H0 = 40.0, 116.0, 1000.0
FIELD = GravityDisturbance(LAT0, LON0, H0, xi0_arcsec=5.0, eta0_arcsec=-3.0, anomaly0_mgal=20.0,
                           gradient_eotvos=(30.0, -20.0, 50.0))


def _field_e(r_e: np.ndarray) -> np.ndarray:
    """The disturbance in ECEF [m/s^2] at ECEF positions (N, 3)."""
    lat, lon, h = earth.ecef_to_llh(r_e)
    dg_n = FIELD.disturbance_n_mps2(lat, lon, h)
    return np.einsum("nij,nj->ni", earth.dcm_en(lat, lon), dg_n)


@pytest.mark.parametrize("offset_n_m", [(0.0, 0.0, 0.0), (8000.0, -5000.0, -300.0)])
def test_field_is_the_gradient_of_a_harmonic_potential(offset_n_m):
    """The Jacobian of dg (ECEF, central differences of 1 m) is symmetric (curl-free: the
    gradient of a potential) and trace-free (Laplace), and its horizontal block in the
    reference's NED is the gradient put in, at the reference and 9.4 km away."""
    lat0, lon0 = np.deg2rad(LAT0), np.deg2rad(LON0)
    c_en0 = earth.dcm_en(lat0, lon0)
    r0 = earth.llh_to_ecef_m(lat0, lon0, H0) + c_en0 @ np.asarray(offset_n_m)
    step = 1.0
    jac = np.empty((3, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = step
        jac[:, j] = (_field_e((r0 + e)[None])[0] - _field_e((r0 - e)[None])[0]) / (2 * step)
    scale = 50.0 * EOTVOS_PS2
    np.testing.assert_allclose(jac, jac.T, atol=1e-4 * scale)
    assert abs(np.trace(jac)) < 1e-4 * scale
    jac_n0 = c_en0.T @ jac @ c_en0
    np.testing.assert_allclose(jac_n0[:2, :2] / EOTVOS_PS2, [[30.0, -20.0], [-20.0, 50.0]],
                               atol=5e-3)
    np.testing.assert_allclose(jac_n0[2, 2] / EOTVOS_PS2, -80.0, atol=5e-3)


def test_deflection_sign_and_value_at_the_reference():
    """dg_N = -gamma xi, dg_E = -gamma eta (Heiskanen and Moritz, Sec. 2-22): read back."""
    lat0, lon0 = np.deg2rad(LAT0), np.deg2rad(LON0)
    dg = FIELD.disturbance_n_mps2(lat0, lon0, H0)
    gamma = float(earth.normal_gravity_mps2(lat0, H0))
    np.testing.assert_allclose(dg, [-gamma * 5.0 * ARCSEC_RAD, gamma * 3.0 * ARCSEC_RAD, 20e-5],
                               rtol=1e-12)
    xi, eta = FIELD.deflection_rad(lat0, lon0, H0)
    np.testing.assert_allclose([xi / ARCSEC_RAD, eta / ARCSEC_RAD], [5.0, -3.0], rtol=1e-12)


def test_unit_conversion():
    """1 arcsec/km of the diagnosis library (g0 arcsec / km) is 47.5 Eotvos."""
    assert eotvos_from_arcsec_per_km(1.0) == pytest.approx(G0_MPS2 * ARCSEC_RAD / 1e3 / 1e-9)
    assert eotvos_from_arcsec_per_km(1.0) == pytest.approx(47.54, abs=0.01)


def _static(lat_deg: float, lon_deg: float, gravity: GravityDisturbance | None):
    prof = {"name": "static", "imu_rate_hz": 50,
            "start": {"lat_deg": lat_deg, "lon_deg": lon_deg, "height_m": H0,
                      "heading_deg": 0.0},
            "segment": [{"type": "static", "duration_s": 4.0}]}
    return simulate(parse_profile(prof), imu_grade="errorfree", seed=0, gravity=gravity)


def test_static_imu_senses_the_tilt_put_in():
    """A static, level IMU heading north senses f = -g: its x and y accelerometers read
    gamma xi and gamma eta. At the reference it reads xi0, eta0; with a gradient alone, 6 km
    north and 4 km east it reads the closed form [xi, eta] = -C_nn0 Gamma_h x / gamma0 (x the
    NED offset in the reference's frame n0, C_nn0 = C_ne C_en0 the turn of the local axes:
    mostly the meridian convergence, 0.5 mrad over 4 km east, 1 mas of the 2.7 arcsec here)
    to 0.05 mas. Without the field it reads zero tilt."""
    lat0, lon0 = np.deg2rad(LAT0), np.deg2rad(LON0)
    r_m, r_n = earth.principal_radii_m(lat0)
    d_n, d_e = 6000.0, 4000.0
    lat1 = LAT0 + np.rad2deg(d_n / (r_m + H0))
    lon1 = LON0 + np.rad2deg(d_e / ((r_n + H0) * np.cos(lat0)))

    def tilt(sim):
        f = sim.imu.f_ib_b_mps2.mean(axis=0)
        return np.array([f[0], f[1]]) / -f[2]  # xi, eta [rad] (level, body x = north)

    # (FIELD's 20 mGal anomaly lengthens f_z by 2e-5 of it)
    np.testing.assert_allclose(tilt(_static(LAT0, LON0, FIELD)) / ARCSEC_RAD, [5.0, -3.0],
                               rtol=3e-5)
    gradient_only = GravityDisturbance(LAT0, LON0, H0, gradient_eotvos=FIELD.gradient_eotvos)
    x = earth.llh_to_ned_m(np.deg2rad(lat1), np.deg2rad(lon1), H0, lat0, lon0, H0)
    gamma0 = float(earth.normal_gravity_mps2(lat0, H0))
    c_nn0 = earth.dcm_en(np.deg2rad(lat1), np.deg2rad(lon1)).T @ earth.dcm_en(lat0, lon0)
    expected = -(c_nn0 @ FIELD.hessian_ps2 @ x)[:2] / gamma0
    assert np.all(np.abs(expected / ARCSEC_RAD) > 0.3)  # a change the test can see
    np.testing.assert_allclose(tilt(_static(lat1, lon1, gradient_only)) / ARCSEC_RAD,
                               expected / ARCSEC_RAD, atol=5e-5)
    np.testing.assert_allclose(tilt(_static(LAT0, LON0, None)), 0.0, atol=1e-12)


def test_provenance_says_what_gravity_was_used():
    """Off: params say normal gravity, no deflection. On: the field and its parameters."""
    off = _static(LAT0, LON0, None).params
    assert off["conventions"]["gravity"].endswith("no deflection")
    assert "disturbance" not in off["gravity"] and "gravity" not in off["config"]
    on = _static(LAT0, LON0, FIELD).params
    assert "disturbance field" in on["conventions"]["gravity"]
    assert on["gravity"]["disturbance"]["gradient_eotvos"] == [30.0, -20.0, 50.0]
    assert on["config"]["gravity"] == FIELD.as_dict()


def test_free_inertial_velocity_error_on_a_northward_leg():
    """Strapdown with normal gravity (pospp's kernel) on a 60 m/s northward leg, from the true
    state at the leg start, minus the same without the field: the north velocity error is
    -int dg_N dt = -G_NN int x_N dt (no deflection at the reference; Schuler below 0.3 % in
    120 s): the sign B's `gravity_disturbance` signature carries (dv' = -Gamma (r - r0))."""
    field = GravityDisturbance(LAT0, LON0, H0, gradient_eotvos=(50.0, 0.0, 0.0))
    prof = {"name": "north", "imu_rate_hz": 50,
            "start": {"lat_deg": LAT0, "lon_deg": LON0, "height_m": H0, "heading_deg": 0.0},
            "segment": [{"type": "accelerate", "to_speed_mps": 60.0, "duration_s": 10.0},
                        {"type": "straight", "duration_s": 120.0}]}
    v_n = []
    for grav in (field, None):
        sim = simulate(parse_profile(prof), imu_grade="errorfree", seed=0, gravity=grav)
        t_s, dth, dv = increments_from_rates(sim.imu.time_ns, sim.imu.w_ib_b_radps,
                                             sim.imu.f_ib_b_mps2, epoch_ns=sim.start_time_ns)
        a = 500  # truth epoch 501: 10.02 s, on the straight
        out = integrate(t_s[a:], dth[a:], dv[a:], sim.truth.state(a + 1),
                        previous_increments=(dth[a - 1], dv[a - 1]))
        v_n.append(out.v_n_mps[:, 0])
    tr = sim.truth
    x_n = earth.llh_to_ned_m(tr.lat_rad, tr.lon_rad, tr.height_m, np.deg2rad(LAT0),
                             np.deg2rad(LON0), H0)[a + 1:, 0]
    t = tr.t_s[a + 1:]
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (x_n[1:] + x_n[:-1]) * np.diff(t))])
    expected = -50.0 * EOTVOS_PS2 * integral
    assert expected[-1] < -0.02
    np.testing.assert_allclose(v_n[0] - v_n[1], expected, atol=3e-3 * abs(expected[-1]))
