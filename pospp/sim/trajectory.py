"""True motion: position, velocity, acceleration, attitude and attitude rates at any time.

Frames and units: position geodetic WGS-84 (rad, rad, m above the ellipsoid); velocity
``v_n`` and its time derivative ``a_n = dv_n/dt`` (the rate of change of the NED components,
what the strapdown velocity equation integrates) in NED [m/s], [m/s^2]; attitude [roll, pitch,
yaw] z-y-x of body FRD w.r.t. NED [rad] and their time derivatives [rad/s].

Two motions share one interface, :meth:`evaluate`, returning a :class:`MotionSample`:

- :class:`ProfileMotion`, from a :class:`pospp.sim.profile.MissionPlan`: horizontal speed s,
  heading psi and climb slope k = tan(gamma) are closed-form smooth schedules, so

      v_n = [s cos psi, s sin psi, -s k],
      roll = atan(s psi' / g) (coordinated) or 0, pitch = gamma = atan(k), yaw = psi,

  and a_n, the Euler rates follow analytically. Optional leg wander (the plan's
  ``heading_wander`` / ``speed_wander``, closed-form C2 sinusoids) adds to psi and s and their
  derivatives. Position integrates the geodetic kinematics
  lat' = v_N / (R_M + h), lon' = v_E / ((R_N + h) cos lat), h' = -v_D
  on a 0.02 s grid with 4-node Gauss-Legendre quadrature per step and Picard iteration of the
  radii, then cubic Hermite interpolation (values and exact derivatives at the grid): the
  truth is self-consistent to far below a millimetre.
- :class:`SplineMotion`, along a given trajectory (e.g. an RTK drive): quintic smoothing
  splines of the ECEF position give r_e, v_e, a_e exactly consistent with each other; then
  v_n = C_ne v_e and a_n = C_ne a_e - w_en x v_n (because dC_ne/dt = -[w_en x] C_ne).
  Heading is a smoothing spline of the track angle (speed-weighted, held through stops);
  pitch is zero (level attitude); roll is the coordinated-turn bank for aircraft, zero for cars.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import UnivariateSpline

from pospp import earth
from pospp.sim.profile import MissionPlan
from pospp.units import G0_MPS2

__all__ = ["MotionSample", "ProfileMotion", "SplineMotion", "G_BANK_MPS2"]

G_BANK_MPS2 = G0_MPS2
"""Gravity in the coordinated-turn bank law tan(roll) = v psi' / g (a definition, not physics)."""

_GL4_X, _GL4_W = np.polynomial.legendre.leggauss(4)


@dataclass(frozen=True)
class MotionSample:
    """True motion at M times (time-major arrays).

    Attributes
    ----------
    t_s : (M,)
    lat_rad, lon_rad, height_m : (M,)
    v_n_mps, a_n_mps2 : (M, 3)
        NED velocity and the time derivative of its components.
    rpy_rad, rpy_rate_radps : (M, 3)
        [roll, pitch, yaw] (z-y-x, body FRD w.r.t. NED) and their time derivatives.
    """

    t_s: NDArray
    lat_rad: NDArray
    lon_rad: NDArray
    height_m: NDArray
    v_n_mps: NDArray
    a_n_mps2: NDArray
    rpy_rad: NDArray
    rpy_rate_radps: NDArray


def _hermite(t: NDArray, grid_t0: float, step: float, y: NDArray, dy: NDArray) -> NDArray:
    """Cubic Hermite interpolation on a uniform grid (values y, derivatives dy)."""
    j = np.clip(np.floor((t - grid_t0) / step).astype(np.int64), 0, y.shape[0] - 2)
    u = (t - (grid_t0 + j * step)) / step
    h00 = (1.0 + 2.0 * u) * (1.0 - u) ** 2
    h10 = u * (1.0 - u) ** 2
    h01 = u * u * (3.0 - 2.0 * u)
    h11 = u * u * (u - 1.0)
    return h00 * y[j] + h10 * step * dy[j] + h01 * y[j + 1] + h11 * step * dy[j + 1]


def _bank(speed, speed_d1, rate, rate_d1, coordinated: bool):
    """Coordinated-turn roll and its rate: tan(roll) = s psi' / g."""
    if not coordinated:
        z = np.zeros_like(speed)
        return z, z.copy()
    x = speed * rate / G_BANK_MPS2
    dx = (speed_d1 * rate + speed * rate_d1) / G_BANK_MPS2
    return np.arctan(x), dx / (1.0 + x * x)


class ProfileMotion:
    """Closed-form smooth motion of a mission plan (see module docstring).

    Parameters
    ----------
    plan : MissionPlan
    grid_step_s : float
        Position integration step [s] (Gauss-Legendre 4 nodes per step).
    """

    def __init__(self, plan: MissionPlan, *, grid_step_s: float = 0.02) -> None:
        self.plan = plan
        self.coordinated = plan.profile.turn_bank == "coordinated"
        self.lat0_rad = np.deg2rad(plan.profile.lat_deg)
        self.lon0_rad = np.deg2rad(plan.profile.lon_deg)
        self.height0_m = plan.profile.height_m
        self.duration_s = plan.duration_s
        self._step = float(grid_step_s)
        self._integrate_position()

    # -- velocity and attitude (closed form) ------------------------------------------------
    def _kinematics(self, t: NDArray):
        s, s1, _ = self.plan.speed.evaluate(t)
        r, r1, _ = self.plan.heading_rate.evaluate(t)
        psi = self.plan.heading0_rad + self.plan.heading_rate.integral(t)
        if self.plan.speed_wander is not None:  # leg speed wander (profile.py)
            w, w1, _ = self.plan.speed_wander.evaluate(t)
            s, s1 = s + w, s1 + w1
        if self.plan.heading_wander is not None:  # leg heading wander: psi += x, r += x'
            w, w1, w2 = self.plan.heading_wander.evaluate(t)
            psi, r, r1 = psi + w, r + w1, r1 + w2
        k, k1, _ = self.plan.slope.evaluate(t)
        cp, sp = np.cos(psi), np.sin(psi)
        v = np.stack([s * cp, s * sp, -s * k], axis=-1)
        a = np.stack([s1 * cp - s * r * sp, s1 * sp + s * r * cp, -(s1 * k + s * k1)], axis=-1)
        roll, roll1 = _bank(s, s1, r, r1, self.coordinated)
        rpy = np.stack([roll, np.arctan(k), psi], axis=-1)
        rpy1 = np.stack([roll1, k1 / (1.0 + k * k), r], axis=-1)
        return v, a, rpy, rpy1

    def velocity_n_mps(self, t_s: ArrayLike) -> NDArray:
        """True NED velocity [m/s] at ``t_s``, shape (..., 3)."""
        return self._kinematics(np.asarray(t_s, dtype=float))[0]

    # -- position ---------------------------------------------------------------------------
    def _integrate_position(self) -> None:
        h = self._step
        n = int(np.ceil(self.duration_s / h)) + 2
        t_grid = np.arange(n + 1) * h
        tn = t_grid[:-1, None] + 0.5 * h * (1.0 + _GL4_X)[None, :]  # (n, 4) nodes
        w = 0.5 * h * _GL4_W
        v = self.velocity_n_mps(tn)
        height = self.height0_m + np.concatenate([[0.0], np.cumsum(-(v[..., 2] @ w))])
        # node heights: height at the step start plus the exact partial integral is not
        # needed; the radii depend on h only through R + h (1e-10 relative per metre).
        u = 0.5 * (1.0 + _GL4_X)[None, :]
        hn = height[:-1, None] * (1.0 - u) + height[1:, None] * u
        lat = np.full(n + 1, self.lat0_rad)
        lon = np.full(n + 1, self.lon0_rad)
        for _ in range(3):  # Picard on the latitude-dependent radii
            latn = lat[:-1, None] * (1.0 - u) + lat[1:, None] * u
            r_m, r_n = earth.principal_radii_m(latn)
            dlat = (v[..., 0] / (r_m + hn)) @ w
            dlon = (v[..., 1] / ((r_n + hn) * np.cos(latn))) @ w
            lat = self.lat0_rad + np.concatenate([[0.0], np.cumsum(dlat)])
            lon = self.lon0_rad + np.concatenate([[0.0], np.cumsum(dlon)])
        vg = self.velocity_n_mps(t_grid)
        r_m, r_n = earth.principal_radii_m(lat)
        self._grid = (lat, lon, height)
        self._grid_d = (
            vg[:, 0] / (r_m + height),
            vg[:, 1] / ((r_n + height) * np.cos(lat)),
            -vg[:, 2],
        )

    def position(self, t_s: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        """(lat_rad, lon_rad, height_m) at ``t_s``."""
        t = np.asarray(t_s, dtype=float)
        lat, lon, h = (_hermite(t, 0.0, self._step, y, dy)
                       for y, dy in zip(self._grid, self._grid_d, strict=True))
        return lat, lon, h

    def evaluate(self, t_s: ArrayLike) -> MotionSample:
        """Full :class:`MotionSample` at times ``t_s`` [s from the mission start], shape (M,)."""
        t = np.asarray(t_s, dtype=float)
        v, a, rpy, rpy1 = self._kinematics(t)
        lat, lon, h = self.position(t)
        return MotionSample(t, lat, lon, h, v, a, rpy, rpy1)


def _fit_quintic(t: NDArray, y: NDArray, sigma: float | NDArray) -> UnivariateSpline:
    """Quintic smoothing spline with RMS residual about ``sigma`` (per sample if an array) and
    no residual above 4 sigma (FITPACK places few knots where a tight turn needs many: the
    smoothing budget is quartered until the worst residual fits, at most 6 times)."""
    w = np.broadcast_to(1.0 / np.asarray(sigma, dtype=float), t.shape)
    s = float(t.size)
    for _ in range(6):
        sp = UnivariateSpline(t, y, w=w, k=5, s=s)
        if (np.abs(sp(t) - y) * w).max() <= 4.0:
            break
        s *= 0.25
    return sp


HELD_HEADING_WEIGHT = 1e4
"""Weight of a held heading sample (below ``heading_min_speed_mps``) in the heading spline,
against 1 for a moving one (:class:`SplineMotion`)."""


class SplineMotion:
    """Smooth true motion along a given trajectory (module docstring).

    Parameters
    ----------
    time_s : (N,) strictly increasing [s]
    lat_rad, lon_rad, height_m : (N,)
        Geodetic positions (e.g. an RTK solution).
    vehicle : {"car", "aircraft"}
        Zero roll for cars; coordinated-turn bank for aircraft.
    position_sigma_m : float
        Expected position noise; the smoothing splines fit to RMS residual about this, with
        no residual above 4 x this (the smoothing is tightened until so).
    heading_min_speed_mps : float
        Below this speed the track angle is not trusted (heading held, low weight).
    """

    def __init__(
        self,
        time_s: ArrayLike,
        lat_rad: ArrayLike,
        lon_rad: ArrayLike,
        height_m: ArrayLike,
        *,
        vehicle: str = "car",
        position_sigma_m: float = 0.02,
        heading_sigma_rad: float = 0.01,
        heading_min_speed_mps: float = 1.0,
    ) -> None:
        t = np.asarray(time_s, dtype=float)
        if t.ndim != 1 or t.size < 10 or (np.diff(t) <= 0).any():
            raise ValueError(f"time_s: need >= 10 strictly increasing samples, got {t.shape}")
        if vehicle not in ("car", "aircraft"):
            raise ValueError(f"vehicle must be 'car' or 'aircraft', got {vehicle!r}")
        self.coordinated = vehicle == "aircraft"
        self.t0_s = float(t[0])
        self.duration_s = float(t[-1] - t[0])
        r_e = earth.llh_to_ecef_m(lat_rad, lon_rad, height_m)
        self._r0 = r_e[0].copy()
        n = t.size
        self._pos = [_fit_quintic(t, r_e[:, k] - self._r0[k], position_sigma_m)
                     for k in range(3)]
        self._vel = [sp.derivative(1) for sp in self._pos]
        self._acc = [sp.derivative(2) for sp in self._pos]
        # heading: smoothing spline of the unwrapped track angle, speed-weighted
        smp = self._geometry(t)
        vh = np.hypot(smp[1][:, 0], smp[1][:, 1])
        track = np.arctan2(smp[1][:, 1], smp[1][:, 0])
        good = vh >= heading_min_speed_mps
        if not good.any():
            raise ValueError("the trajectory never moves faster than heading_min_speed_mps")
        idx = np.where(good, np.arange(n), -1)
        idx = np.maximum.accumulate(idx)
        idx[idx < 0] = np.argmax(good)
        track = np.unwrap(track[idx])
        # held values (slow samples) are held: HELD_HEADING_WEIGHT times the weight of a
        # moving sample (at weight 1 the spline may leave a held heading by the moving
        # samples' sigma, and a 10 min static start then turned 0.21 deg at up to 8.8 deg/h,
        # at 100 0.004 deg at 0.5 deg/h: a gyro signal of a vehicle at rest, above a
        # navigation-grade gyro's noise); the track of slow moving samples less so
        wts = np.where(good, np.clip(vh / (3.0 * heading_min_speed_mps), 0.3, 1.0),
                       HELD_HEADING_WEIGHT)
        self._psi = _fit_quintic(t, track, heading_sigma_rad / wts)
        self._psi1 = self._psi.derivative(1)
        self._psi2 = self._psi.derivative(2)

    def _geometry(self, t: NDArray):
        r = np.stack([sp(t) for sp in self._pos], axis=-1) + self._r0
        v_e = np.stack([sp(t) for sp in self._vel], axis=-1)
        a_e = np.stack([sp(t) for sp in self._acc], axis=-1)
        lat, lon, h = earth.ecef_to_llh(r)
        c_ne = np.swapaxes(earth.dcm_en(lat, lon), -1, -2)
        v_n = np.einsum("nij,nj->ni", c_ne, v_e)
        w_en = earth.transport_rate_n_radps(lat, h, v_n)
        a_n = np.einsum("nij,nj->ni", c_ne, a_e) - np.cross(w_en, v_n)
        return (lat, lon, h), v_n, a_n

    def evaluate(self, t_s: ArrayLike) -> MotionSample:
        """:class:`MotionSample` at ``t_s`` (the input's time scale)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        (lat, lon, h), v, a = self._geometry(t)
        psi, psi1, psi2 = self._psi(t), self._psi1(t), self._psi2(t)
        sp = np.hypot(v[:, 0], v[:, 1])
        sp1 = (v[:, 0] * a[:, 0] + v[:, 1] * a[:, 1]) / np.maximum(sp, 1e-6)
        roll, roll1 = _bank(sp, sp1, psi1, psi2, self.coordinated)
        zero = np.zeros_like(t)
        rpy = np.stack([roll, zero, psi], axis=-1)
        rpy1 = np.stack([roll1, zero, psi1], axis=-1)
        return MotionSample(t, lat, lon, h, v, a, rpy, rpy1)
