"""Attitude helpers: quaternions, DCMs, Euler angles, rotation vectors, skew matrices.

Conventions (fixed once for all of pospp)
-----------------------------------------
- DCMs are destination-first: ``C_nb`` takes body (FRD) vectors to navigation (NED) vectors,
  ``v_n = C_nb @ v_b``.
- Quaternions are scalar-first ``[w, x, y, z]``, Hamilton product, and ``q_nb`` represents the
  same rotation as ``C_nb`` (``v_n = q_nb * v_b * conj(q_nb)``).
- Euler angles are z-y-x (yaw, then pitch, then roll) of body FRD with respect to NED:
  ``C_nb = Rz(yaw) @ Ry(pitch) @ Rx(roll)``; roll and pitch in [-pi, pi] and [-pi/2, pi/2],
  yaw clockwise from north. Arrays hold ``[roll, pitch, yaw]`` in rad on the last axis.
- Rotation vectors (axis times angle, rad) map to quaternions by the exponential map.

Arrays are time-major: (N, 3), (N, 3, 3), (N, 4). Conversions delegate to
``scipy.spatial.transform.Rotation`` (which is scalar-last internally); this module only fixes
pospp's conventions around it. The compiled strapdown kernel has its own scalar-first
quaternion arithmetic in ``pospp.nav._kernels``; tests check the two agree.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation


def _wxyz_to_xyzw(q: ArrayLike) -> NDArray:
    return np.roll(np.asarray(q, dtype=float), -1, axis=-1)


def _xyzw_to_wxyz(q: ArrayLike) -> NDArray:
    return np.roll(np.asarray(q, dtype=float), 1, axis=-1)


def skew(v: ArrayLike) -> NDArray:
    """Cross-product matrix [v x], shape (..., 3, 3), so that ``skew(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def dcm_from_euler(rpy_rad: ArrayLike) -> NDArray:
    """C_nb from [roll, pitch, yaw] (rad), shape (..., 3) -> (..., 3, 3)."""
    rpy = np.asarray(rpy_rad, dtype=float)
    return Rotation.from_euler("ZYX", rpy[..., ::-1]).as_matrix()


def euler_from_dcm(c_nb: ArrayLike) -> NDArray:
    """[roll, pitch, yaw] (rad) from C_nb; yaw wrapped to [0, 2 pi)."""
    ypr = Rotation.from_matrix(np.asarray(c_nb, dtype=float)).as_euler("ZYX")
    rpy = ypr[..., ::-1].copy()
    rpy[..., 2] = np.mod(rpy[..., 2], 2.0 * np.pi)
    return rpy


def quat_from_euler(rpy_rad: ArrayLike) -> NDArray:
    """q_nb (scalar-first) from [roll, pitch, yaw] (rad)."""
    rpy = np.asarray(rpy_rad, dtype=float)
    return _xyzw_to_wxyz(Rotation.from_euler("ZYX", rpy[..., ::-1]).as_quat())


def euler_from_quat(q_nb: ArrayLike) -> NDArray:
    """[roll, pitch, yaw] (rad) from q_nb (scalar-first); yaw wrapped to [0, 2 pi)."""
    ypr = Rotation.from_quat(_wxyz_to_xyzw(q_nb)).as_euler("ZYX")
    rpy = ypr[..., ::-1].copy()
    rpy[..., 2] = np.mod(rpy[..., 2], 2.0 * np.pi)
    return rpy


def dcm_from_quat(q_nb: ArrayLike) -> NDArray:
    """C_nb from q_nb (scalar-first), shape (..., 4) -> (..., 3, 3)."""
    return Rotation.from_quat(_wxyz_to_xyzw(q_nb)).as_matrix()


def quat_from_dcm(c_nb: ArrayLike) -> NDArray:
    """q_nb (scalar-first, w >= 0) from C_nb."""
    q = _xyzw_to_wxyz(Rotation.from_matrix(np.asarray(c_nb, dtype=float)).as_quat())
    return q * np.where(q[..., :1] < 0.0, -1.0, 1.0)


def quat_from_rotvec(rotvec_rad: ArrayLike) -> NDArray:
    """Quaternion (scalar-first) of a rotation vector (rad)."""
    return _xyzw_to_wxyz(Rotation.from_rotvec(np.asarray(rotvec_rad, dtype=float)).as_quat())


def rotvec_from_quat(q: ArrayLike) -> NDArray:
    """Rotation vector (rad) of a quaternion (scalar-first)."""
    return Rotation.from_quat(_wxyz_to_xyzw(q)).as_rotvec()


def dcm_from_rotvec(rotvec_rad: ArrayLike) -> NDArray:
    """DCM of a rotation vector (rad): exp([r x])."""
    return Rotation.from_rotvec(np.asarray(rotvec_rad, dtype=float)).as_matrix()


def rotvec_from_dcm(c: ArrayLike) -> NDArray:
    """Rotation vector (rad) of a DCM: log(C)."""
    return Rotation.from_matrix(np.asarray(c, dtype=float)).as_rotvec()


def quat_multiply(p: ArrayLike, q: ArrayLike) -> NDArray:
    """Hamilton product p * q of scalar-first quaternions, broadcast over leading axes."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conjugate(q: ArrayLike) -> NDArray:
    """Conjugate (inverse for unit quaternions) of scalar-first quaternions."""
    q = np.asarray(q, dtype=float).copy()
    q[..., 1:] *= -1.0
    return q


def attitude_error_n_rad(c_nb_computed: ArrayLike, c_nb_true: ArrayLike) -> NDArray:
    """Misalignment phi (rad, NED) of a computed attitude, pospp's error convention.

    ``C_nb_computed = (I - [phi x]) C_nb_true`` to first order, i.e. exactly
    ``C_nb_computed @ C_nb_true.T = exp(-[phi x])``: phi is the small rotation that carries the
    computed navigation frame n' back onto the true n (Titterton & Weston Eq. 12.5; Qin 2006).
    A heading error (computed minus true yaw) of dpsi gives phi_d = -dpsi; a tilt phi_n about
    north gives a computed roll too small by phi_n when level and heading north (docs/method.md).

    Returns shape (..., 3) [rad].
    """
    c_err = np.asarray(c_nb_computed, dtype=float) @ np.swapaxes(np.asarray(c_nb_true), -1, -2)
    return -rotvec_from_dcm(c_err)


def angle_between_rad(c_a: ArrayLike, c_b: ArrayLike) -> NDArray:
    """Angle (rad) of the rotation between two attitudes (never element-wise Euler)."""
    c = np.asarray(c_a, dtype=float) @ np.swapaxes(np.asarray(c_b, dtype=float), -1, -2)
    return np.linalg.norm(rotvec_from_dcm(c), axis=-1)
