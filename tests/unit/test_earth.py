"""Earth model against published values and round trips (independent references)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pospp import earth


def test_normal_gravity_matches_published_values():
    # NIMA TR8350.2 Table 3.3 / Somigliana: equator and pole values on the ellipsoid.
    assert abs(earth.normal_gravity_mps2(0.0, 0.0) - 9.7803253359) < 1e-10
    assert abs(earth.normal_gravity_mps2(np.pi / 2, 0.0) - 9.8321849378) < 1e-9
    # Free-air gradient near the surface: about -3.086e-6 m/s^2 per metre at 45 deg.
    g0 = earth.normal_gravity_mps2(np.radians(45.0), 0.0)
    g1 = earth.normal_gravity_mps2(np.radians(45.0), 100.0)
    assert abs((g1 - g0) / 100.0 + 3.086e-6) < 0.01e-6


def test_radii_at_equator_and_pole():
    r_m, r_n = earth.principal_radii_m(np.array([0.0, np.pi / 2]))
    a, b = earth.WGS84_A_M, earth.WGS84_B_M
    np.testing.assert_allclose(r_n, [a, a * a / b], rtol=1e-13)
    np.testing.assert_allclose(r_m, [b * b / a, a * a / b], rtol=1e-13)


def test_ecef_of_known_point():
    # Equator / prime meridian / zero height is (a, 0, 0); north pole is (0, 0, b).
    np.testing.assert_allclose(earth.llh_to_ecef_m(0.0, 0.0, 0.0), [earth.WGS84_A_M, 0, 0])
    np.testing.assert_allclose(
        earth.llh_to_ecef_m(np.pi / 2, 0.0, 0.0), [0, 0, earth.WGS84_B_M], atol=1e-6
    )


@settings(max_examples=200, deadline=None)
@given(
    st.floats(-89.99, 89.99), st.floats(-180.0, 180.0), st.floats(-500.0, 20000.0)
)
def test_llh_ecef_round_trip(lat_deg, lon_deg, h_m):
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    lat2, lon2, h2 = earth.ecef_to_llh(earth.llh_to_ecef_m(lat, lon, h_m))
    assert abs(lat2 - lat) < 1e-11
    assert abs(np.angle(np.exp(1j * (lon2 - lon)))) < 1e-11
    assert abs(h2 - h_m) < 1e-6


@settings(max_examples=100, deadline=None)
@given(st.floats(-80.0, 80.0), st.floats(-3000.0, 3000.0), st.floats(-3000.0, 3000.0),
       st.floats(-500.0, 500.0))
def test_ned_round_trip_and_small_difference(lat_deg, dn, de, dd):
    lat0, lon0, h0 = np.radians(lat_deg), np.radians(10.0), 100.0
    lat, lon, h = earth.ned_to_llh(np.array([dn, de, dd]), lat0, lon0, h0)
    back = earth.llh_to_ned_m(lat, lon, h, lat0, lon0, h0)
    np.testing.assert_allclose(back, [dn, de, dd], atol=1e-6)
    # The linear error-model difference agrees with the exact one to curvature order. Going
    # east along the tangent plane departs from the parallel of latitude by about
    # de^2 tan(lat) / (2 R), so the curvature term grows with tan(lat) towards the poles.
    lin = earth.llh_difference_ned_m(lat, lon, h, lat0, lon0, h0)
    dist = np.sqrt(dn**2 + de**2 + dd**2)
    curvature_m = dist**2 * (1.0 + abs(np.tan(lat0))) / 6.3e6
    assert np.abs(lin - back).max() < 2e-6 * dist + 1.5 * curvature_m + 1e-6


def test_rates_point_the_right_way():
    w = earth.earth_rate_n_radps(np.radians(40.0))
    assert w[0] > 0 and w[2] < 0 and abs(np.linalg.norm(w) - earth.EARTH_RATE_RADPS) < 1e-18
    # Flying east, the NED frame turns about north (positive) and about down (negative, north
    # hemisphere); flying north, about east (negative).
    we = earth.transport_rate_n_radps(np.radians(40.0), 0.0, np.array([0.0, 100.0, 0.0]))
    assert we[0] > 0 and we[2] < 0 and abs(we[1]) == 0
    wn = earth.transport_rate_n_radps(np.radians(40.0), 0.0, np.array([100.0, 0.0, 0.0]))
    assert wn[1] < 0 and wn[0] == 0


@given(
    st.floats(min_value=-1.5, max_value=1.5),
    st.floats(min_value=-400.0, max_value=12000.0),
)
@settings(max_examples=40, deadline=None)
def test_gravity_gradient_is_the_derivative_of_normal_gravity(lat, h):
    dg_dlat, dg_dh = earth.gravity_gradient_formula(lat, h)
    e_lat, e_h = 1e-5, 1.0  # central differences: truncation ~1e-10 relative
    g = earth.normal_gravity_mps2
    num_lat = g(lat + e_lat, h) - g(lat - e_lat, h)
    num_h = g(lat, h + e_h) - g(lat, h - e_h)
    assert abs(dg_dlat - num_lat / (2 * e_lat)) < 1e-8
    assert abs(dg_dh - num_h / (2 * e_h)) < 1e-13
    # free-air gradient about -3.086e-6 /s^2 (published, 45 deg, sea level; magnitude falls
    # slowly with height); latitude gradient vanishes at equator and poles, peaks near 45 deg
    assert -3.095e-6 < dg_dh < -3.06e-6
    assert abs(dg_dlat) <= 0.052


def test_sin2_forms_equal_the_latitude_forms():
    lat = np.linspace(-1.57, 1.57, 101)
    h = np.linspace(-300.0, 9000.0, 101)
    s2 = np.sin(lat) ** 2
    np.testing.assert_allclose(earth.radii_from_sin2(s2), earth.radii_formula(lat), rtol=1e-15)
    np.testing.assert_allclose(
        earth.gravity_from_sin2(s2, h), earth.gravity_formula(lat, h), rtol=1e-15
    )
