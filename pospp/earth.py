"""WGS-84 Earth model: radii, normal gravity, Earth and transport rates, llh/ECEF/NED.

Frames
------
e : ECEF (WGS-84), n : local geodetic NED (north, east, down).

Units
-----
SI and radians throughout: latitude/longitude in rad, height above the ellipsoid in m,
velocities in m/s, rates in rad/s, gravity in m/s^2.

References
----------
NIMA TR8350.2, "Department of Defense World Geodetic System 1984", 3rd ed. (2000):
constants (Table 3.1), Somigliana normal gravity (Eq. 4-1) and its second-order
height correction (Eq. 4-3). Groves, "Principles of GNSS, Inertial and Multisensor
Integrated Navigation Systems", 2nd ed. (2013), Eq. 2.105-2.106 (radii), 2.112 (llh->ECEF),
5.44 (transport rate).

All functions accept scalars or arrays (broadcast element-wise); vector results are
time-major with the component on the last axis, shape (..., 3).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

# --- WGS-84 defining and derived constants (NIMA TR8350.2, Table 3.1 / 3.3) -------------
WGS84_A_M = 6378137.0
"""Semi-major axis [m]."""
WGS84_F = 1.0 / 298.257223563
"""Flattening [-]."""
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
"""Semi-minor axis [m]."""
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""First eccentricity squared [-]."""
WGS84_GM_M3PS2 = 3.986004418e14
"""Earth's gravitational constant GM [m^3/s^2]."""
EARTH_RATE_RADPS = 7.292115e-5
"""Earth rotation rate [rad/s]."""
GAMMA_EQUATOR_MPS2 = 9.7803253359
"""Normal gravity at the equator [m/s^2]."""
GAMMA_POLE_MPS2 = 9.8321849378
"""Normal gravity at the poles [m/s^2]."""
SOMIGLIANA_K = (WGS84_B_M * GAMMA_POLE_MPS2) / (WGS84_A_M * GAMMA_EQUATOR_MPS2) - 1.0
"""Somigliana's constant k [-]."""
GRAVITY_M_RATIO = EARTH_RATE_RADPS**2 * WGS84_A_M**2 * WGS84_B_M / WGS84_GM_M3PS2
"""m = omega^2 a^2 b / GM [-] (TR8350.2 Eq. 4-3)."""


def radii_formula(lat):
    """(R_M, R_N) [m] for latitude [rad]; plain arithmetic so numba can compile it too."""
    s2 = np.sin(lat) ** 2
    w = 1.0 - WGS84_E2 * s2
    r_normal = WGS84_A_M / np.sqrt(w)
    r_meridian = WGS84_A_M * (1.0 - WGS84_E2) / (w * np.sqrt(w))
    return r_meridian, r_normal


def gravity_formula(lat, height):
    """Normal gravity [m/s^2] (Somigliana + 2nd-order height); plain arithmetic for numba."""
    s2 = np.sin(lat) ** 2
    gamma0 = GAMMA_EQUATOR_MPS2 * (1.0 + SOMIGLIANA_K * s2) / np.sqrt(1.0 - WGS84_E2 * s2)
    return gamma0 * (
        1.0
        - 2.0 / WGS84_A_M * (1.0 + WGS84_F + GRAVITY_M_RATIO - 2.0 * WGS84_F * s2) * height
        + 3.0 * height**2 / WGS84_A_M**2
    )


def radii_from_sin2(s2):
    """:func:`radii_formula` from s2 = sin^2(lat), for kernels that already hold sin(lat)."""
    w = 1.0 - WGS84_E2 * s2
    sw = np.sqrt(w)
    return WGS84_A_M * (1.0 - WGS84_E2) / (w * sw), WGS84_A_M / sw


def gravity_from_sin2(s2, height):
    """:func:`gravity_formula` from s2 = sin^2(lat), for kernels that already hold sin(lat)."""
    gamma0 = GAMMA_EQUATOR_MPS2 * (1.0 + SOMIGLIANA_K * s2) / np.sqrt(1.0 - WGS84_E2 * s2)
    return gamma0 * (
        1.0
        - 2.0 / WGS84_A_M * (1.0 + WGS84_F + GRAVITY_M_RATIO - 2.0 * WGS84_F * s2) * height
        + 3.0 * height**2 / WGS84_A_M**2
    )


def gravity_gradient_formula(lat, height):
    """(d gamma / d lat [m/s^2/rad], d gamma / d h [1/s^2]) of :func:`gravity_formula`.

    Exact derivatives of the Somigliana + 2nd-order height formula (TR8350.2 Eq. 4-1, 4-3);
    plain arithmetic for numba. With s2 = sin^2 lat, w = 1 - e^2 s2:
    d gamma_0 / d s2 = gamma_e [k / sqrt(w) + (1 + k s2) e^2 / (2 w^1.5)], d s2 / d lat =
    sin(2 lat).
    """
    s2 = np.sin(lat) ** 2
    w = 1.0 - WGS84_E2 * s2
    gamma0 = GAMMA_EQUATOR_MPS2 * (1.0 + SOMIGLIANA_K * s2) / np.sqrt(w)
    dgamma0_ds2 = GAMMA_EQUATOR_MPS2 * (
        SOMIGLIANA_K / np.sqrt(w) + (1.0 + SOMIGLIANA_K * s2) * WGS84_E2 / (2.0 * w * np.sqrt(w))
    )
    c1 = 2.0 / WGS84_A_M * (1.0 + WGS84_F + GRAVITY_M_RATIO - 2.0 * WGS84_F * s2)
    height_factor = 1.0 - c1 * height + 3.0 * height**2 / WGS84_A_M**2
    dfactor_ds2 = 4.0 * WGS84_F / WGS84_A_M * height
    dg_dlat = np.sin(2.0 * lat) * (dgamma0_ds2 * height_factor + gamma0 * dfactor_ds2)
    dg_dh = gamma0 * (-c1 + 6.0 * height / WGS84_A_M**2)
    return dg_dlat, dg_dh


def principal_radii_m(lat_rad: ArrayLike) -> tuple[NDArray, NDArray]:
    """Meridian (R_M, north-south) and prime-vertical (R_N, east-west) radii of curvature.

    R_M = a (1 - e^2) / (1 - e^2 sin^2 lat)^(3/2),  R_N = a / (1 - e^2 sin^2 lat)^(1/2)

    Parameters
    ----------
    lat_rad : array_like
        Geodetic latitude [rad].

    Returns
    -------
    r_meridian_m, r_normal_m : ndarray
        Radii [m], shaped like ``lat_rad``.
    """
    return radii_formula(np.asarray(lat_rad, dtype=float))


def normal_gravity_mps2(lat_rad: ArrayLike, height_m: ArrayLike) -> NDArray:
    """Magnitude of WGS-84 normal gravity at a geodetic latitude and ellipsoidal height.

    Somigliana (TR8350.2 Eq. 4-1) on the ellipsoid,
    gamma_0 = gamma_e (1 + k sin^2 lat) / sqrt(1 - e^2 sin^2 lat),
    then the second-order height expansion (Eq. 4-3),
    gamma_h = gamma_0 [1 - 2/a (1 + f + m - 2 f sin^2 lat) h + 3 h^2 / a^2].

    Normal gravity points along the ellipsoid normal (down in NED): g_n = [0, 0, gamma_h].

    Parameters
    ----------
    lat_rad : array_like
        Geodetic latitude [rad].
    height_m : array_like
        Height above the ellipsoid [m].

    Returns
    -------
    ndarray
        Normal gravity magnitude [m/s^2].
    """
    return gravity_formula(np.asarray(lat_rad, dtype=float), np.asarray(height_m, dtype=float))


def gravity_n_mps2(lat_rad: ArrayLike, height_m: ArrayLike) -> NDArray:
    """Normal gravity vector in NED [m/s^2], shape (..., 3): [0, 0, gamma]."""
    g = normal_gravity_mps2(lat_rad, height_m)
    out = np.zeros(np.shape(g) + (3,))
    out[..., 2] = g
    return out


def earth_rate_n_radps(lat_rad: ArrayLike) -> NDArray:
    """Earth rotation rate w_ie resolved in NED [rad/s], shape (..., 3).

    w_ie_n = Omega [cos lat, 0, -sin lat]
    """
    lat = np.asarray(lat_rad, dtype=float)
    out = np.zeros(lat.shape + (3,))
    out[..., 0] = EARTH_RATE_RADPS * np.cos(lat)
    out[..., 2] = -EARTH_RATE_RADPS * np.sin(lat)
    return out


def transport_rate_n_radps(lat_rad: ArrayLike, height_m: ArrayLike, v_n_mps: ArrayLike) -> NDArray:
    """Transport rate w_en (rotation of NED relative to ECEF) resolved in NED [rad/s].

    w_en_n = [v_E / (R_N + h), -v_N / (R_M + h), -v_E tan(lat) / (R_N + h)]
    (Groves Eq. 5.44).

    Parameters
    ----------
    lat_rad, height_m : array_like
        Geodetic latitude [rad] and ellipsoidal height [m], shape (...).
    v_n_mps : array_like
        Velocity relative to the Earth in NED [m/s], shape (..., 3).
    """
    lat = np.asarray(lat_rad, dtype=float)
    h = np.asarray(height_m, dtype=float)
    v = np.asarray(v_n_mps, dtype=float)
    r_m, r_n = principal_radii_m(lat)
    out = np.empty(np.broadcast_shapes(lat.shape, h.shape, v.shape[:-1]) + (3,))
    out[..., 0] = v[..., 1] / (r_n + h)
    out[..., 1] = -v[..., 0] / (r_m + h)
    out[..., 2] = -v[..., 1] * np.tan(lat) / (r_n + h)
    return out


def llh_to_ecef_m(lat_rad: ArrayLike, lon_rad: ArrayLike, height_m: ArrayLike) -> NDArray:
    """Geodetic latitude, longitude, height -> ECEF position r_e [m], shape (..., 3)."""
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    h = np.asarray(height_m, dtype=float)
    _, r_n = principal_radii_m(lat)
    cl = np.cos(lat)
    shape = np.broadcast_shapes(lat.shape, lon.shape, h.shape)
    out = np.empty(shape + (3,))
    out[..., 0] = (r_n + h) * cl * np.cos(lon)
    out[..., 1] = (r_n + h) * cl * np.sin(lon)
    out[..., 2] = (r_n * (1.0 - WGS84_E2) + h) * np.sin(lat)
    return out


def ecef_to_llh(r_e_m: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """ECEF position -> geodetic (lat_rad, lon_rad, height_m).

    Iterative solution (fixed point on latitude); converges to < 1e-12 rad in a few
    iterations for any point above -1000 km of the ellipsoid surface.
    """
    r = np.asarray(r_e_m, dtype=float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(6):  # lat = atan2(z + e^2 R_N sin(lat), p): valid at every latitude
        _, r_n = principal_radii_m(lat)
        lat = np.arctan2(z + WGS84_E2 * r_n * np.sin(lat), p)
    sl, cl = np.sin(lat), np.cos(lat)
    h = p * cl + z * sl - WGS84_A_M * np.sqrt(1.0 - WGS84_E2 * sl**2)
    return lat, lon, h


def dcm_en(lat_rad: ArrayLike, lon_rad: ArrayLike) -> NDArray:
    """DCM from NED to ECEF, C_en, shape (..., 3, 3): r_e = C_en @ r_n."""
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    shape = np.broadcast_shapes(lat.shape, lon.shape)
    c = np.empty(shape + (3, 3))
    c[..., 0, 0] = -sl * co
    c[..., 0, 1] = -so
    c[..., 0, 2] = -cl * co
    c[..., 1, 0] = -sl * so
    c[..., 1, 1] = co
    c[..., 1, 2] = -cl * so
    c[..., 2, 0] = cl
    c[..., 2, 1] = 0.0
    c[..., 2, 2] = -sl
    return c


def llh_to_ned_m(
    lat_rad: ArrayLike,
    lon_rad: ArrayLike,
    height_m: ArrayLike,
    lat0_rad: float,
    lon0_rad: float,
    height0_m: float,
) -> NDArray:
    """Geodetic positions -> local NED coordinates [m] about an origin, shape (..., 3).

    Exact (through ECEF), not a flat-Earth approximation.
    """
    r = llh_to_ecef_m(lat_rad, lon_rad, height_m) - llh_to_ecef_m(lat0_rad, lon0_rad, height0_m)
    c_ne = dcm_en(lat0_rad, lon0_rad).T
    return r @ c_ne.T


def ned_to_llh(
    r_n_m: ArrayLike, lat0_rad: float, lon0_rad: float, height0_m: float
) -> tuple[NDArray, NDArray, NDArray]:
    """Local NED coordinates [m] about an origin -> geodetic (lat_rad, lon_rad, height_m)."""
    r_n = np.asarray(r_n_m, dtype=float)
    r_e = llh_to_ecef_m(lat0_rad, lon0_rad, height0_m) + r_n @ dcm_en(lat0_rad, lon0_rad).T
    return ecef_to_llh(r_e)


def llh_difference_ned_m(
    lat_rad: ArrayLike,
    lon_rad: ArrayLike,
    height_m: ArrayLike,
    lat_ref_rad: ArrayLike,
    lon_ref_rad: ArrayLike,
    height_ref_m: ArrayLike,
) -> NDArray:
    """Small position differences (first minus reference) in local NED [m], shape (..., 3).

    dN = dlat (R_M + h), dE = dlon (R_N + h) cos(lat), dD = -dh, evaluated at the reference;
    exact to well below a millimetre for differences under a few kilometres. This is the
    position-error definition used by the error model (computed minus true).
    """
    lat_ref = np.asarray(lat_ref_rad, dtype=float)
    h_ref = np.asarray(height_ref_m, dtype=float)
    r_m, r_n = principal_radii_m(lat_ref)
    dlat = np.asarray(lat_rad, dtype=float) - lat_ref
    dlon = np.asarray(lon_rad, dtype=float) - np.asarray(lon_ref_rad, dtype=float)
    dlon = (dlon + np.pi) % (2.0 * np.pi) - np.pi
    dh = np.asarray(height_m, dtype=float) - h_ref
    shape = np.broadcast_shapes(dlat.shape, dlon.shape, dh.shape)
    out = np.empty(shape + (3,))
    out[..., 0] = dlat * (r_m + h_ref)
    out[..., 1] = dlon * (r_n + h_ref) * np.cos(lat_ref)
    out[..., 2] = -dh
    return out
