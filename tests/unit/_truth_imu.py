"""Error-free IMU increments for tests, computed independently of pospp's mechanization.

Two motions with analytically known body rates and specific force:

- stationary: w_ib_b = C_bn w_ie_n and f_b = -C_bn g_n, both constant, so the increments are
  exactly rate * dt;
- rhumb line: constant NED velocity v_n = V [cos psi, sin psi, 0] at constant height, body
  attitude following the NED frame (roll = pitch = 0, yaw = psi), so w_nb = 0 and
  w_ib_b = C_bn (w_ie_n + w_en_n), f_b = C_bn ((2 w_ie_n + w_en_n) x v_n - g_n) (the NED
  velocity equation with v_n' = 0). lat(t), lon(t) come from scipy's DOP853 on
  lat' = v_N / (R_M + h), lon' = v_E / ((R_N + h) cos lat) at rtol 1e-13, and the increments are
  the 3-node Gauss-Legendre quadrature of the rates over each interval.

Only pospp.earth (WGS-84 radii, normal gravity, rates: tested against published values) and
pospp.rotation are shared with the code under test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from pospp import earth, rotation


@dataclass(frozen=True)
class TruthImu:
    """Epoch times, increments (N intervals) and the true state at the N + 1 epochs."""

    t_s: NDArray
    dtheta_b_rad: NDArray
    dv_b_mps: NDArray
    lat_rad: NDArray
    lon_rad: NDArray
    height_m: float
    v_n_mps: NDArray  # (3,), constant
    c_nb: NDArray  # (3, 3), constant
    rpy_rad: NDArray


def stationary(lat_rad: float, height_m: float, rpy_rad, rate_hz: float, duration_s: float):
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    c_nb = rotation.dcm_from_euler(rpy_rad)
    w_b = c_nb.T @ earth.earth_rate_n_radps(lat_rad)
    f_b = -c_nb.T @ earth.gravity_n_mps2(lat_rad, height_m)
    t = np.arange(n + 1) * dt
    return TruthImu(
        t,
        np.tile(w_b * dt, (n, 1)),
        np.tile(f_b * dt, (n, 1)),
        np.full(n + 1, lat_rad),
        np.zeros(n + 1),
        height_m,
        np.zeros(3),
        c_nb,
        np.asarray(rpy_rad, dtype=float),
    )


_GL_X, _GL_W = np.polynomial.legendre.leggauss(3)


def rhumb_line(
    lat0_rad: float,
    height_m: float,
    speed_mps: float,
    heading_rad: float,
    rate_hz: float,
    duration_s: float,
) -> TruthImu:
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    t = np.arange(n + 1) * dt
    v_n = speed_mps * np.array([np.cos(heading_rad), np.sin(heading_rad), 0.0])

    def rhs(_t, y):
        r_m, r_n = earth.principal_radii_m(y[0])
        return [v_n[0] / (r_m + height_m), v_n[1] / ((r_n + height_m) * np.cos(y[0]))]

    sol = solve_ivp(
        rhs, (0.0, t[-1]), [lat0_rad, 0.0], method="DOP853", rtol=1e-13, atol=1e-16,
        dense_output=True,
    )
    rpy = np.array([0.0, 0.0, heading_rad])
    c_bn = rotation.dcm_from_euler(rpy).T

    def rates_n(lat):  # w_in_n and f_n at the latitudes `lat`
        w_ie = earth.earth_rate_n_radps(lat)
        w_en = earth.transport_rate_n_radps(lat, height_m, np.broadcast_to(v_n, lat.shape + (3,)))
        c = 2.0 * w_ie + w_en
        f_n = np.empty_like(c)  # c x v_n - g_n
        f_n[:, 0] = c[:, 1] * v_n[2] - c[:, 2] * v_n[1]
        f_n[:, 1] = c[:, 2] * v_n[0] - c[:, 0] * v_n[2]
        f_n[:, 2] = c[:, 0] * v_n[1] - c[:, 1] * v_n[0] - earth.normal_gravity_mps2(lat, height_m)
        return w_ie + w_en, f_n

    # C_bn is constant, so the body increments are C_bn times the NED-resolved integrals
    dth_n = np.zeros((n, 3))
    dv_n = np.zeros((n, 3))
    mid = t[:-1] + 0.5 * dt
    for x, w in zip(_GL_X, _GL_W, strict=True):
        w_n, f_n = rates_n(sol.sol(mid + 0.5 * dt * x)[0])
        dth_n += (0.5 * dt * w) * w_n
        dv_n += (0.5 * dt * w) * f_n
    dth = dth_n @ c_bn.T
    dvel = dv_n @ c_bn.T
    y = sol.sol(t)
    return TruthImu(t, dth, dvel, y[0], y[1], height_m, v_n, c_bn.T, rpy)


def oscillating_attitude(
    lat_rad: float,
    height_m: float,
    amp_rad: float,
    freq_hz: float,
    yaw0_rad: float,
    rate_hz: float,
    duration_s: float,
    n_sub: int = 4,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Stationary IMU whose attitude cones: roll = A sin(w t), pitch = A cos(w t), yaw fixed.

    With Euler rates (phi', theta', psi') the body rate relative to NED is (z-y-x Euler)
    w_nb_b = [phi' - psi' sin(theta), theta' cos(phi) + psi' sin(phi) cos(theta),
              -theta' sin(phi) + psi' cos(phi) cos(theta)],
    w_ib_b = w_nb_b + C_bn w_ie_n and f_b = -C_bn g_n (the IMU does not move). Increments by
    composite 3-node Gauss-Legendre, ``n_sub`` sub-intervals per IMU interval. The 90 deg phase
    between roll and pitch is classic coning, and the rotating specific force is sculling.

    Returns t_s (N+1,), dtheta_b (N, 3), dv_b (N, 3), C_nb at the epochs (N+1, 3, 3).
    """
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    t = np.arange(n + 1) * dt
    om = 2.0 * np.pi * freq_hz
    w_ie = earth.earth_rate_n_radps(lat_rad)
    g_n = earth.gravity_n_mps2(lat_rad, height_m)

    def euler(tt):
        rpy = np.stack([amp_rad * np.sin(om * tt), amp_rad * np.cos(om * tt),
                        np.full_like(tt, yaw0_rad)], axis=-1)
        rates = np.stack([amp_rad * om * np.cos(om * tt), -amp_rad * om * np.sin(om * tt),
                          np.zeros_like(tt)], axis=-1)
        return rpy, rates

    def body(tt):
        rpy, d = euler(tt)
        ph, th = rpy[:, 0], rpy[:, 1]
        w_nb = np.stack([
            d[:, 0] - d[:, 2] * np.sin(th),
            d[:, 1] * np.cos(ph) + d[:, 2] * np.sin(ph) * np.cos(th),
            -d[:, 1] * np.sin(ph) + d[:, 2] * np.cos(ph) * np.cos(th),
        ], axis=-1)
        c_bn = np.swapaxes(rotation.dcm_from_euler(rpy), -1, -2)
        return w_nb + c_bn @ w_ie, -(c_bn @ g_n)

    dth = np.zeros((n, 3))
    dv = np.zeros((n, 3))
    h = dt / n_sub
    for j in range(n_sub):
        mid = t[:-1] + (j + 0.5) * h
        for x, w in zip(_GL_X, _GL_W, strict=True):
            w_b, f_b = body(mid + 0.5 * h * x)
            dth += (0.5 * h * w) * w_b
            dv += (0.5 * h * w) * f_b
    return t, dth, dv, rotation.dcm_from_euler(euler(t)[0])


def weaving_flight(
    lat0_rad: float,
    height_m: float,
    speed_mps: float,
    heading0_rad: float,
    weave_amp_rad: float,
    weave_period_s: float,
    rate_hz: float,
    duration_s: float,
) -> TruthImu:
    """Level flight at constant speed and height whose heading weaves:
    psi(t) = psi0 + A sin(2 pi t / P), body yawing with the track (flat turns, no bank).

    v_n = V [cos psi, sin psi, 0], v_n' = V psi' [-sin psi, cos psi, 0];
    w_ib_b = C_bn (w_ie_n + w_en_n) + [0, 0, psi'];
    f_b = C_bn (v_n' + (2 w_ie_n + w_en_n) x v_n - g_n); C_nb = Rz(psi).
    lat, lon by DOP853 (rtol 1e-13), increments by 3-node Gauss-Legendre with 2 sub-intervals.
    The returned ``v_n_mps`` is the INITIAL velocity and ``c_nb`` the INITIAL attitude.
    """
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    t = np.arange(n + 1) * dt
    om = 2.0 * np.pi / weave_period_s

    def psi(tt):
        return heading0_rad + weave_amp_rad * np.sin(om * tt), weave_amp_rad * om * np.cos(om * tt)

    def rhs(tt, y):
        p, _ = psi(tt)
        r_m, r_n = earth.principal_radii_m(y[0])
        return [speed_mps * np.cos(p) / (r_m + height_m),
                speed_mps * np.sin(p) / ((r_n + height_m) * np.cos(y[0]))]

    sol = solve_ivp(rhs, (0.0, t[-1]), [lat0_rad, 0.0], method="DOP853", rtol=1e-13,
                    atol=1e-16, dense_output=True)

    def body(tt):
        lat = sol.sol(tt)[0]
        p, dp = psi(tt)
        cp, sp = np.cos(p), np.sin(p)
        v = speed_mps * np.stack([cp, sp, np.zeros_like(p)], axis=-1)
        vdot = speed_mps * dp[:, None] * np.stack([-sp, cp, np.zeros_like(p)], axis=-1)
        w_ie = earth.earth_rate_n_radps(lat)
        w_en = earth.transport_rate_n_radps(lat, height_m, v)
        f_n = vdot + np.cross(2.0 * w_ie + w_en, v) - earth.gravity_n_mps2(lat, height_m)

        def to_b(a):  # C_bn = Rz(psi)^T
            return np.stack([cp * a[:, 0] + sp * a[:, 1], -sp * a[:, 0] + cp * a[:, 1],
                             a[:, 2]], axis=-1)

        w_b = to_b(w_ie + w_en)
        w_b[:, 2] += dp
        return w_b, to_b(f_n)

    dth = np.zeros((n, 3))
    dvel = np.zeros((n, 3))
    n_sub = 2
    h = dt / n_sub
    for j in range(n_sub):
        mid = t[:-1] + (j + 0.5) * h
        for x, w in zip(_GL_X, _GL_W, strict=True):
            w_b, f_b = body(mid + 0.5 * h * x)
            dth += (0.5 * h * w) * w_b
            dvel += (0.5 * h * w) * f_b
    y = sol.sol(t)
    p0, _ = psi(np.array([0.0]))
    rpy = np.array([0.0, 0.0, p0[0]])
    v0 = speed_mps * np.array([np.cos(p0[0]), np.sin(p0[0]), 0.0])
    return TruthImu(t, dth, dvel, y[0], y[1], height_m, v0, rotation.dcm_from_euler(rpy), rpy)


def weaving_truth_state(tr: TruthImu, heading0_rad, weave_amp_rad, weave_period_s, speed_mps):
    """True v_n (N+1, 3) and C_nb (N+1, 3, 3) of :func:`weaving_flight` at its epochs."""
    p = heading0_rad + weave_amp_rad * np.sin(2.0 * np.pi / weave_period_s * tr.t_s)
    v = speed_mps * np.stack([np.cos(p), np.sin(p), np.zeros_like(p)], axis=-1)
    c = rotation.dcm_from_euler(np.stack([np.zeros_like(p), np.zeros_like(p), p], axis=-1))
    return v, c
