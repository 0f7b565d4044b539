"""Exact IMU increments from a true motion: Gauss-Legendre quadrature of w_ib_b and f_b.

Frames and units: body FRD (b), NED (n); rates rad/s, specific force m/s^2, increments rad
and m/s; times s from the mission start.

For each IMU interval (t_k, t_{k+1}] the increments are

    dtheta_b = integral w_ib_b(t) dt,   w_ib_b = w_nb_b + C_bn (w_ie_n + w_en_n)
    dv_b     = integral f_b(t) dt,      f_b    = C_bn [a_n + (2 w_ie_n + w_en_n) x v_n - g_n]

(body axes at the integrand time, no rotation or sculling compensation: what a real IMU
outputs; the strapdown kernel applies coning and sculling). ``a_n`` is dv_n/dt, g_n the
WGS-84 normal gravity [0, 0, gamma(lat, h)] (:mod:`pospp.earth`) or, with a
:class:`pospp.sim.gravity.GravityDisturbance`, normal gravity plus its disturbance dg_n
(deflection, anomaly, gradient: the true plumb line the IMU senses), w_ie and w_en the Earth and
transport rates (Groves Eq. 2.123, 5.44), and with z-y-x Euler angles (roll phi, pitch theta,
yaw psi)

    w_nb_b = [phi' - psi' sin theta,
              theta' cos phi + psi' sin phi cos theta,
              -theta' sin phi + psi' cos phi cos theta].

The quadrature is composite Gauss-Legendre (``n_sub`` sub-intervals x ``n_gl`` nodes); the
integrands are analytic between the C2 joins of the profile, so the default 2 x 4 nodes leaves
errors far below the strapdown kernel's own (closure tests in tests/unit/test_sim_closure.py).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth
from pospp.sim.gravity import GravityDisturbance
from pospp.sim.trajectory import MotionSample

__all__ = ["body_rates", "dcm_nb_from_euler", "exact_increments", "quat_nb_from_euler"]


class Motion(Protocol):
    def evaluate(self, t_s: ArrayLike) -> MotionSample: ...


def dcm_nb_from_euler(rpy_rad: NDArray) -> NDArray:
    """C_nb = Rz(yaw) Ry(pitch) Rx(roll), shape (..., 3, 3) (same as pospp.rotation, faster)."""
    cr, sr = np.cos(rpy_rad[..., 0]), np.sin(rpy_rad[..., 0])
    cp, sp = np.cos(rpy_rad[..., 1]), np.sin(rpy_rad[..., 1])
    cy, sy = np.cos(rpy_rad[..., 2]), np.sin(rpy_rad[..., 2])
    c = np.empty(rpy_rad.shape[:-1] + (3, 3))
    c[..., 0, 0] = cp * cy
    c[..., 0, 1] = -cr * sy + sr * sp * cy
    c[..., 0, 2] = sr * sy + cr * sp * cy
    c[..., 1, 0] = cp * sy
    c[..., 1, 1] = cr * cy + sr * sp * sy
    c[..., 1, 2] = -sr * cy + cr * sp * sy
    c[..., 2, 0] = -sp
    c[..., 2, 1] = sr * cp
    c[..., 2, 2] = cr * cp
    return c


def quat_nb_from_euler(rpy_rad: NDArray) -> NDArray:
    """q_nb (scalar-first, w >= 0) of [roll, pitch, yaw]: q = q_z(yaw) q_y(pitch) q_x(roll).

    Same rotation as ``pospp.rotation.quat_from_euler``, closed form (several times faster).
    """
    hr, hp, hy = 0.5 * rpy_rad[..., 0], 0.5 * rpy_rad[..., 1], 0.5 * rpy_rad[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    q = np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )
    return q * np.where(q[..., :1] < 0.0, -1.0, 1.0)


def body_rates(m: MotionSample, gravity: GravityDisturbance | None = None
               ) -> tuple[NDArray, NDArray]:
    """True w_ib_b [rad/s] and f_ib_b [m/s^2] of a motion sample, each shape (M, 3);
    ``gravity``: the disturbance added to normal gravity (None: normal gravity only)."""
    c_nb = dcm_nb_from_euler(m.rpy_rad)
    roll, pitch = m.rpy_rad[:, 0], m.rpy_rad[:, 1]
    d = m.rpy_rate_radps
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    w_nb_b = np.stack(
        [
            d[:, 0] - d[:, 2] * sp,
            d[:, 1] * cr + d[:, 2] * sr * cp,
            -d[:, 1] * sr + d[:, 2] * cr * cp,
        ],
        axis=-1,
    )
    w_ie = earth.earth_rate_n_radps(m.lat_rad)
    w_en = earth.transport_rate_n_radps(m.lat_rad, m.height_m, m.v_n_mps)
    if gravity is None:
        g_n = earth.gravity_n_mps2(m.lat_rad, m.height_m)
    else:
        g_n = gravity.gravity_n_mps2(m.lat_rad, m.lon_rad, m.height_m)
    f_n = m.a_n_mps2 + np.cross(2.0 * w_ie + w_en, m.v_n_mps) - g_n
    # C_bn x = C_nb^T x
    w_ib_b = w_nb_b + np.einsum("nji,nj->ni", c_nb, w_ie + w_en)
    f_b = np.einsum("nji,nj->ni", c_nb, f_n)
    return w_ib_b, f_b


def exact_increments(
    motion: Motion,
    t_s: ArrayLike,
    *,
    n_sub: int = 2,
    n_gl: int = 4,
    chunk_intervals: int = 20_000,
    progress: Callable[[float], None] | None = None,
    gravity: GravityDisturbance | None = None,
) -> tuple[NDArray, NDArray]:
    """Increments over the intervals (t_s[k], t_s[k+1]] by composite Gauss-Legendre.

    Parameters
    ----------
    motion : object with ``evaluate(t_s) -> MotionSample``
    t_s : (N + 1,) increasing epochs [s]
    n_sub, n_gl : int
        Sub-intervals per IMU interval and Gauss-Legendre nodes per sub-interval.
    chunk_intervals : int
        Intervals evaluated at once (bounds memory: about 1.5 kB per node).
    progress : callable, optional
        Called with the fraction done (0..1) after each chunk.
    gravity : GravityDisturbance, optional
        Gravity disturbance field (default: WGS-84 normal gravity only).

    Returns
    -------
    dtheta_b_rad, dv_b_mps : (N, 3)
    """
    t = np.asarray(t_s, dtype=float)
    n = t.size - 1
    x, w = np.polynomial.legendre.leggauss(n_gl)
    # node offsets and weights as fractions of the interval
    frac = ((np.arange(n_sub)[:, None] + 0.5 * (1.0 + x)[None, :]) / n_sub).ravel()
    wfrac = np.tile(0.5 * w / n_sub, n_sub)
    dth = np.empty((n, 3))
    dv = np.empty((n, 3))
    for a in range(0, n, chunk_intervals):
        b = min(n, a + chunk_intervals)
        dt = np.diff(t[a : b + 1])
        tn = (t[a:b, None] + dt[:, None] * frac[None, :]).ravel()
        w_ib, f_b = body_rates(motion.evaluate(tn), gravity)
        k = len(frac)
        wdt = (dt[:, None] * wfrac[None, :])[..., None]
        dth[a:b] = (w_ib.reshape(b - a, k, 3) * wdt).sum(axis=1)
        dv[a:b] = (f_b.reshape(b - a, k, 3) * wdt).sum(axis=1)
        if progress is not None:
            progress(b / n)
    return dth, dv
