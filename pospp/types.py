"""The data contract between stages: sensor samples, reference trajectories, frame helpers.

The bottom of the house: io, sim, nav and calib import this module; it imports nothing of
pospp. io turns files into these types (and back), sim makes them from a simulated motion, nav
and the stages above consume them.

Frames and units
----------------
- b: body FRD; s: sensor as logged (FLU per REP-103 for the simulators); n: NED.
- IMU samples are in b after the mounting rotation ``C_bs`` (``w_ib_b = C_bs @ w_is_s``):
  mean angular rate [rad/s] and mean specific force [m/s^2] over the interval that ends at
  ``time_ns``.
- GNSS fixes: WGS-84 latitude/longitude [rad], height above the ellipsoid [m], position
  covariance in NED [m^2]; GNSS velocities in NED [m/s] with covariance [m^2/s^2].
- Reference trajectory (simulation truth, or a higher-grade system's solution): position,
  NED velocity and z-y-x attitude of b w.r.t. n [rad].
- Times are int64 ``time_ns`` (header stamps, UTC ns); see :mod:`pospp.units` for the one
  ns <-> s conversion.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "ENU_TO_NED",
    "FLU_TO_FRD",
    "GnssFixes",
    "GnssVelocities",
    "ImuSamples",
    "ReferenceTrajectory",
    "apply_rotation",
    "check_dcm",
    "empty_velocities",
    "rotate_covariance",
]

FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])
"""C_bs for a REP-103 FLU sensor and an FRD body: x_b = x_s, y_b = -y_s, z_b = -z_s."""
FLU_TO_FRD.setflags(write=False)

ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""T with v_ned = T @ v_enu (T is its own inverse and transpose)."""
ENU_TO_NED.setflags(write=False)


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples in the body frame (FRD) after the mounting rotation.

    Attributes
    ----------
    time_ns : (N,) int64
        End of each sampling interval (``header.stamp``) [ns].
    w_ib_b_radps : (N, 3) float64
        Mean angular rate of b w.r.t. inertial space over the interval, resolved in b [rad/s].
    f_ib_b_mps2 : (N, 3) float64
        Mean specific force over the interval, resolved in b [m/s^2] (about [0, 0, -g] level).
    frame_id : str
        ``header.frame_id`` of the sensor as logged (informational).
    """

    time_ns: np.ndarray
    w_ib_b_radps: np.ndarray
    f_ib_b_mps2: np.ndarray
    frame_id: str = ""

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])

    @cached_property
    def white_noise(self) -> tuple[float, float]:
        """The IMU's white noise density read from its own samples: (gyro ARW
        [rad/s^0.5], accelerometer VRW [m/s^1.5]), NaN with fewer than 12 samples; read once
        per samples object (the null and the sensor families' check share it).

        Second differences of the samples remove smooth motion; for white noise of per-sample
        sigma s they have variance 6 s^2. Robustly (median absolute deviation, per axis, the
        median over the three axes)::

            s = 1.4826 MAD(w_k+1 - 2 w_k + w_k-1) / sqrt(6),   ARW = s sqrt(dt)

        Vibration and quantisation above the motion's bandwidth count as noise here, so on
        real data the level reads high (a conservative null).
        """
        t = np.asarray(self.time_ns, dtype=np.int64)
        dt = float(np.median(np.diff(t))) * 1e-9 if t.size > 1 else 1.0
        out = []
        for a in (self.w_ib_b_radps, self.f_ib_b_mps2):
            d2 = np.diff(np.asarray(a, dtype=float), n=2, axis=0)
            if d2.shape[0] < 10:
                out.append(float("nan"))
                continue
            mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
            out.append(float(np.median(1.4826 * mad / np.sqrt(6.0)) * np.sqrt(dt)))
        return out[0], out[1]


@dataclass(frozen=True)
class GnssFixes:
    """GNSS antenna positions.

    Attributes
    ----------
    time_ns : (M,) int64
    lat_rad, lon_rad : (M,) float64
        Geodetic latitude and longitude (WGS-84) [rad].
    height_m : (M,) float64
        Height above the WGS-84 ellipsoid [m].
    pos_cov_ned_m2 : (M, 3, 3) float64
        Position covariance in NED [m^2].
    status : (M,) int8
        ``sensor_msgs/NavSatStatus.status`` (0 fix, 1 SBAS, 2 GBAS; -1 no-fix is dropped).
    """

    time_ns: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    height_m: np.ndarray
    pos_cov_ned_m2: np.ndarray
    status: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])


@dataclass(frozen=True)
class GnssVelocities:
    """GNSS antenna velocities.

    Attributes
    ----------
    time_ns : (K,) int64
    v_n_mps : (K, 3) float64
        Velocity in NED [m/s].
    vel_cov_ned_m2ps2 : (K, 3, 3) float64
        Velocity covariance in NED [m^2/s^2].
    """

    time_ns: np.ndarray
    v_n_mps: np.ndarray
    vel_cov_ned_m2ps2: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])


@dataclass(frozen=True)
class ReferenceTrajectory:
    """A reference trajectory (simulation truth or a higher-grade system).

    Attributes
    ----------
    time_ns : (N,) int64
    lat_rad, lon_rad, height_m : (N,) float64
        WGS-84 geodetic position of the IMU [rad, rad, m above the ellipsoid].
    v_n_mps : (N, 3) float64
        Velocity in NED [m/s].
    rpy_rad : (N, 3) float64
        [roll, pitch, yaw] of b (FRD) w.r.t. n (NED), z-y-x [rad]; yaw as stored.
    """

    time_ns: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    height_m: np.ndarray
    v_n_mps: np.ndarray
    rpy_rad: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])


def empty_velocities() -> GnssVelocities:
    """A GnssVelocities with no samples."""
    return GnssVelocities(
        np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3))
    )


def apply_rotation(c_ab: np.ndarray, v_b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``v_a = C_ab @ v_b`` for rows of ``v_b`` (N, 3).

    A signed permutation (entries in {-1, 0, 1}, e.g. FLU->FRD, ENU->NED) is applied by
    indexing and sign flips, so it is exact and invertible bit for bit (no ``0 * x`` sums that
    turn -0.0 into +0.0); any other DCM by matrix product. ``out`` (float, the shape of
    ``v_b``; may be ``v_b`` itself) receives the result instead of a new array.
    """
    c = np.asarray(c_ab, dtype=float)
    v = np.asarray(v_b, dtype=float)
    nz = c != 0.0
    if np.all(np.isin(c, (-1.0, 0.0, 1.0))) and np.all(nz.sum(axis=1) == 1):
        cols = np.argmax(nz, axis=1)
        signs = c[np.arange(3), cols]
        if np.array_equal(cols, np.arange(3)):  # diagonal (FLU->FRD): signs only
            if out is None:
                return v * signs
            if out is not v_b:
                out[...] = v
            for k in np.flatnonzero(signs < 0):  # in place (a ufunc would copy an input
                np.negative(out[..., k], out=out[..., k])  # that shares out's memory)
            return out
        return np.multiply(v[..., cols], signs, out=out)
    if out is None:
        return v @ c.T
    out[...] = v @ c.T
    return out


def rotate_covariance(c_ab: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """``P_a = C_ab P_b C_ab^T`` for (N, 3, 3) stacks.

    Exact for signed permutations (ENU/NED, FLU/FRD), signed zeros included, so that writing
    and reading a covariance round-trips bit for bit.
    """
    p_c = apply_rotation(c_ab, p_b)  # rows of P rotated: P C^T
    return np.swapaxes(apply_rotation(c_ab, np.swapaxes(p_c, -1, -2)), -1, -2)  # C (P C^T)


def check_dcm(c_bs: ArrayLike, name: str = "c_bs") -> np.ndarray:
    """Validate a DCM: shape (3, 3), orthonormal to 1e-9, determinant +1."""
    c = np.asarray(c_bs, dtype=float)
    if c.shape != (3, 3):
        raise ValueError(f"{name} must have shape (3, 3), got {c.shape}")
    err = np.abs(c @ c.T - np.eye(3)).max()
    if err > 1e-9 or np.linalg.det(c) < 0:
        raise ValueError(
            f"{name} must be a rotation (orthonormal, det +1); got |C C^T - I|max={err:.2e}, "
            f"det={np.linalg.det(c):+.6f}"
        )
    return c
