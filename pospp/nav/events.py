"""The imaging sensor's pose at trigger events (exterior orientation). No I/O.

Frames: n (NED), b (body FRD, the IMU's), s (the sensor: camera or lidar, its own axes).
Given the navigation solution of the IMU (:class:`pospp.nav.solution.NavSolution`), the sensor's
lever arm ``lever_b`` (sensor origin in b, from the IMU) and its boresight rotation ``C_bs``
(s -> b), at each event time t::

    C_nb(t)   slerp of the bracketing epochs (rotation vector between them, scaled)
    r_s       = r_imu(t) + C_nb lever_b                    (position, NED offset -> lat/lon/h)
    v_s       = v_imu(t) + C_nb (w_nb_b x lever_b)          (w_nb_b from the bracketing epochs)
    C_ns      = C_nb C_bs                                   (sensor attitude)
    P_r,s     = P_r + [l_n x] P_phi [l_n x]^T,  l_n = C_nb lever_b
    P_rpy,s   = E_s^-1 P_phi E_s^-T                         (E_s at the sensor's Euler angles)

Position, velocity and their covariances are interpolated linearly between the solution's
epochs (the output rate of algorithm A, 10-200 Hz: at 60 m/s the linear interpolation of a
straight path is exact and of a 3 deg/s turn within 1 mm at 10 Hz). The attitude error
phi (C_nb,computed = (I - [phi x]) C_nb,true) is the same for the sensor as for the body, since
C_bs is fixed. Events outside the solution's time span get NaN (``inside`` False).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth, rotation
from pospp.nav.error_model import rpy_covariance
from pospp.nav.smoother import interpolation_weights
from pospp.nav.solution import NavSolution
from pospp.nav.strapdown import interpolate_trajectory

__all__ = ["SensorPoses", "sensor_poses"]


@dataclass(frozen=True)
class SensorPoses:
    """The sensor's state at M event times (time-major arrays; NaN where ``inside`` is False).

    Attitude of s w.r.t. n: ``q_ns`` scalar-first, ``rpy_rad`` z-y-x [roll, pitch, yaw], yaw
    in [0, 2 pi). Sigmas are 1-sigma: position NED [m], velocity NED [m/s], Euler angles [rad]
    and the misalignment phi about N, E, D [rad].
    """

    t_s: NDArray
    inside: NDArray
    lat_rad: NDArray
    lon_rad: NDArray
    height_m: NDArray
    v_n_mps: NDArray
    q_ns: NDArray
    rpy_rad: NDArray
    pos_sigma_ned_m: NDArray
    vel_sigma_ned_mps: NDArray
    rpy_sigma_rad: NDArray
    att_sigma_ned_rad: NDArray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def sensor_poses(solution: NavSolution, t_s: ArrayLike, *, lever_b_m: ArrayLike = (0, 0, 0),
                 c_bs: ArrayLike | None = None) -> SensorPoses:
    """Interpolate ``solution`` at ``t_s`` [s, run time] and move it to the sensor.

    Parameters
    ----------
    solution : NavSolution
        The IMU's solution (at least two epochs).
    t_s : (M,) array_like
        Event times on the solution's time axis [s].
    lever_b_m : (3,) array_like
        Sensor origin in the body frame FRD, from the IMU [m].
    c_bs : (3, 3) array_like, optional
        Boresight DCM, sensor -> body (identity when None).

    Returns
    -------
    SensorPoses
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    lever = np.asarray(lever_b_m, dtype=float).reshape(3)
    c_bs = np.eye(3) if c_bs is None else np.asarray(c_bs, dtype=float)
    if len(solution) < 2:
        raise ValueError(f"sensor_poses: expected a solution of >= 2 epochs, got {len(solution)}")
    inside = (t >= solution.t_s[0]) & (t <= solution.t_s[-1])
    tc = np.clip(t, solution.t_s[0], solution.t_s[-1])
    traj = interpolate_trajectory(solution.trajectory, tc)
    i, a = interpolation_weights(solution.t_s, tc)
    nxt = np.minimum(i + 1, len(solution) - 1)

    def lin(x: NDArray) -> NDArray:
        w = a.reshape((-1,) + (1,) * (x.ndim - 1))
        return (1.0 - w) * x[i] + w * x[nxt]

    c_nb = rotation.dcm_from_quat(traj.q_nb)
    # body rate w.r.t. n between the bracketing epochs: C_nb(i)^T C_nb(i+1) = exp([w dt x])
    dt = solution.t_s[nxt] - solution.t_s[i]
    dq = rotation.quat_multiply(rotation.quat_conjugate(solution.q_nb[i]), solution.q_nb[nxt])
    w_nb_b = rotation.rotvec_from_quat(dq) / np.where(dt > 0, dt, np.inf)[:, None]
    lever_n = c_nb @ lever
    r_m, r_n = earth.principal_radii_m(traj.lat_rad)
    lat = traj.lat_rad + lever_n[:, 0] / (r_m + traj.height_m)
    lon = traj.lon_rad + lever_n[:, 1] / ((r_n + traj.height_m) * np.cos(traj.lat_rad))
    h = traj.height_m - lever_n[:, 2]
    v = traj.v_n_mps + np.einsum("kij,kj->ki", c_nb, np.cross(w_nb_b, lever))
    c_ns = c_nb @ c_bs
    q_ns = rotation.quat_from_dcm(c_ns)
    att_cov = lin(solution.att_cov_ned_rad2)
    l_x = rotation.skew(lever_n)
    pos_cov = lin(solution.pos_cov_ned_m2) + l_x @ att_cov @ np.swapaxes(l_x, 1, 2)
    vel_cov = lin(solution.vel_cov_ned_m2ps2)

    def sig(p: NDArray) -> NDArray:
        return np.sqrt(np.clip(np.diagonal(p, axis1=1, axis2=2), 0.0, None))

    rpy = rotation.euler_from_quat(q_ns)
    rpy[:, 2] = np.mod(rpy[:, 2], 2.0 * np.pi)
    out = {
        "lat_rad": lat, "lon_rad": lon, "height_m": h, "v_n_mps": v, "q_ns": q_ns,
        "rpy_rad": rpy, "pos_sigma_ned_m": sig(pos_cov), "vel_sigma_ned_mps": sig(vel_cov),
        "rpy_sigma_rad": sig(rpy_covariance(q_ns, att_cov)), "att_sigma_ned_rad": sig(att_cov),
    }
    for k, val in out.items():
        val = np.array(val, dtype=float)
        val[~inside] = np.nan
        out[k] = val
    return SensorPoses(t_s=t, inside=inside, **out)
