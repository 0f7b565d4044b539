"""Optional gravity disturbance field of the simulator: deflection of the vertical, anomaly
and a constant gradient about a reference point.

Frames and units: NED (n) at the IMU's position, NED at the reference point (n0); positions
geodetic WGS-84 (rad, rad, m); accelerations m/s^2, gradients 1/s^2 (1 Eotvos = 1e-9 1/s^2),
deflections rad (arcsec in the field's parameters), anomaly mGal (1 mGal = 1e-5 m/s^2).

True gravity is normal gravity plus the disturbance, g_n = [0, 0, gamma(lat, h)] + dg_n. The
disturbance is the gradient of a disturbing potential T (dg = grad T, down positive in NED),
here the harmonic quadratic about the reference point r0 (NED offsets x = r - r0 in n0)

    T(x) = T0 + c . x + 1/2 x^T Gamma x,      dg_n0(x) = c + Gamma x,

with c = [-gamma0 xi0, -gamma0 eta0, dg_D0] and the symmetric, trace-free Hessian

    Gamma = [[G_NN, G_NE, 0], [G_NE, G_EE, 0], [0, 0, -(G_NN + G_EE)]]

(symmetric: a potential's Hessian; trace-free: Laplace's equation outside the masses, so the
vertical gradient of the anomaly follows from the horizontal ones). The field is rotated from
n0 into the local NED of the IMU, dg_n = C_ne(r) C_en0 dg_n0 (over 10 km a 1.6 mrad rotation).

Sign convention (Heiskanen and Moritz 1967, "Physical Geodesy", Sec. 2-22, as quoted in
J. Geodesy, doi 10.1007/s00190-015-0844-y, Eq. 2-3): the deflection components are
xi = Phi - phi (astronomic minus geodetic latitude, north) and eta = (Lambda - lambda) cos phi
(east), the slopes of the geoid xi = -dN / dx_N, eta = -dN / dx_E with Bruns' N = T / gamma.
So the plumb line's up direction leans north by xi and east by eta, and the horizontal
gravity components are

    dg_N = -gamma xi,   dg_E = -gamma eta.

A static level IMU therefore senses f_N = -g_N = gamma xi: its x accelerometer (heading
north) reads +gamma xi. The deflection at the IMU's position is read back by
:meth:`GravityDisturbance.deflection_rad` with the local normal gravity.

In the diagnosis library's units (``gravity_disturbance``, :mod:`pospp.diagnose.effects`) the
horizontal gradient of dg is [G_NN, G_NE, G_EE] / (g0 arcsec / km) with g0 = 9.80665 m/s^2:
1 arcsec/km = 47.5 E, and G_NN = -g0 d xi / dx_N.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth
from pospp.units import ARCSEC_RAD, G0_MPS2

__all__ = ["EOTVOS_PS2", "MGAL_MPS2", "GravityDisturbance", "eotvos_from_arcsec_per_km"]

EOTVOS_PS2 = 1e-9
"""One Eotvos [1/s^2]."""
MGAL_MPS2 = 1e-5
"""One mGal [m/s^2]."""


def eotvos_from_arcsec_per_km(x: ArrayLike) -> NDArray:
    """A gradient in the diagnosis library's arcsec/km (g0 arcsec per km) in Eotvos."""
    return np.asarray(x, dtype=float) * G0_MPS2 * ARCSEC_RAD / 1000.0 / EOTVOS_PS2


@dataclass(frozen=True)
class GravityDisturbance:
    """A gravity disturbance field about a reference point (module docstring).

    Attributes
    ----------
    lat0_deg, lon0_deg, height0_m : float
        Reference point r0 (geodetic WGS-84).
    xi0_arcsec, eta0_arcsec : float
        Deflection of the vertical at r0, north (xi) and east (eta) [arcsec].
    anomaly0_mgal : float
        Down component of the disturbance at r0, dg_D [mGal] (positive: gravity stronger).
    gradient_eotvos : (G_NN, G_NE, G_EE)
        Horizontal Hessian of T, the gradient of [dg_N, dg_E] in n0 [E]; G_DD = -(G_NN + G_EE).
    """

    lat0_deg: float
    lon0_deg: float
    height0_m: float
    xi0_arcsec: float = 0.0
    eta0_arcsec: float = 0.0
    anomaly0_mgal: float = 0.0
    gradient_eotvos: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        vals = (self.lat0_deg, self.lon0_deg, self.height0_m, self.xi0_arcsec,
                self.eta0_arcsec, self.anomaly0_mgal, *self.gradient_eotvos)
        if len(self.gradient_eotvos) != 3 or not np.all(np.isfinite(vals)):
            raise ValueError(f"gravity disturbance: finite values and a 3-tuple gradient "
                             f"expected, got {self!r}")

    @property
    def hessian_ps2(self) -> NDArray:
        """Gamma [1/s^2], (3, 3) in n0: symmetric, trace-free."""
        g_nn, g_ne, g_ee = (float(x) * EOTVOS_PS2 for x in self.gradient_eotvos)
        return np.array([[g_nn, g_ne, 0.0], [g_ne, g_ee, 0.0], [0.0, 0.0, -(g_nn + g_ee)]])

    def _reference(self) -> tuple[float, float, float, float]:
        lat0, lon0 = np.deg2rad(self.lat0_deg), np.deg2rad(self.lon0_deg)
        gamma0 = float(earth.normal_gravity_mps2(lat0, self.height0_m))
        return float(lat0), float(lon0), float(self.height0_m), gamma0

    def disturbance_n_mps2(self, lat_rad: ArrayLike, lon_rad: ArrayLike,
                           height_m: ArrayLike) -> NDArray:
        """dg_n at geodetic positions [m/s^2], NED at each position, shape (..., 3)."""
        lat0, lon0, h0, gamma0 = self._reference()
        x_n0 = earth.llh_to_ned_m(lat_rad, lon_rad, height_m, lat0, lon0, h0)
        c = np.array([-gamma0 * self.xi0_arcsec * ARCSEC_RAD,
                      -gamma0 * self.eta0_arcsec * ARCSEC_RAD,
                      self.anomaly0_mgal * MGAL_MPS2])
        dg_n0 = c + x_n0 @ self.hessian_ps2.T
        # n0 -> e -> local n: C_nn0 = C_ne C_en0 (per position)
        c_en = earth.dcm_en(np.asarray(lat_rad, dtype=float), np.asarray(lon_rad, dtype=float))
        dg_e = dg_n0 @ earth.dcm_en(lat0, lon0).T
        return np.einsum("...ji,...j->...i", c_en, dg_e)

    def gravity_n_mps2(self, lat_rad: ArrayLike, lon_rad: ArrayLike,
                       height_m: ArrayLike) -> NDArray:
        """True gravity g_n = normal + disturbance [m/s^2], shape (..., 3)."""
        return (earth.gravity_n_mps2(lat_rad, height_m)
                + self.disturbance_n_mps2(lat_rad, lon_rad, height_m))

    def deflection_rad(self, lat_rad: ArrayLike, lon_rad: ArrayLike,
                       height_m: ArrayLike) -> tuple[NDArray, NDArray]:
        """(xi, eta) [rad] at positions: -dg_N / gamma, -dg_E / gamma (local normal gravity)."""
        dg = self.disturbance_n_mps2(lat_rad, lon_rad, height_m)
        gamma = earth.normal_gravity_mps2(lat_rad, height_m)
        return -dg[..., 0] / gamma, -dg[..., 1] / gamma

    def describe(self) -> str:
        """One line for the simulation's provenance (params.json ``gravity.model``)."""
        return (f"WGS-84 normal gravity (Somigliana, 2nd-order height term) plus a disturbance "
                f"field about ({self.lat0_deg:g} deg, {self.lon0_deg:g} deg, "
                f"{self.height0_m:g} m): deflection xi {self.xi0_arcsec:g}, eta "
                f"{self.eta0_arcsec:g} arcsec, anomaly {self.anomaly0_mgal:g} mGal, horizontal "
                f"gradient G_NN, G_NE, G_EE = {', '.join(f'{g:g}' for g in self.gradient_eotvos)}"
                f" E (G_DD = -(G_NN + G_EE)); dg_N = -gamma xi, dg_E = -gamma eta "
                f"(Heiskanen and Moritz 1967, Sec. 2-22)")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready parameters."""
        return {"lat0_deg": self.lat0_deg, "lon0_deg": self.lon0_deg,
                "height0_m": self.height0_m, "xi0_arcsec": self.xi0_arcsec,
                "eta0_arcsec": self.eta0_arcsec, "anomaly0_mgal": self.anomaly0_mgal,
                "gradient_eotvos": list(self.gradient_eotvos)}
