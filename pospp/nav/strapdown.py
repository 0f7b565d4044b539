"""Strapdown inertial navigation: validated entry points around the compiled kernel.

Frames and units: body FRD (b), navigation NED (n); increments in rad and m/s, rates in rad/s
and m/s^2, positions geodetic (rad, rad, m above the WGS-84 ellipsoid), q_nb scalar-first.

Increment convention: ``dtheta_b_rad[k]`` and ``dv_b_mps[k]`` are the integrals of w_ib_b and
f_b over the interval (t_s[k], t_s[k+1]], so N increments advance the state over the N + 1
epochs ``t_s``. Logged IMU messages carry mean rates over the interval ending at their stamp
(data contract, design.md); :func:`increments_from_rates` converts them in one place.

The mechanization equations are listed in :mod:`pospp.nav._kernels` and docs/method.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import rotation
from pospp.nav import _kernels
from pospp.units import S_PER_NS, t_s_from_time_ns


@dataclass(frozen=True)
class NavState:
    """A navigation state at one epoch.

    Attributes
    ----------
    lat_rad, lon_rad, height_m : float
        Geodetic position of the IMU (WGS-84).
    v_n_mps : ndarray, shape (3,)
        Velocity relative to the Earth, NED [m/s].
    q_nb : ndarray, shape (4,)
        Attitude, scalar-first quaternion body FRD -> NED.
    """

    lat_rad: float
    lon_rad: float
    height_m: float
    v_n_mps: NDArray
    q_nb: NDArray

    @classmethod
    def from_euler(
        cls, lat_rad: float, lon_rad: float, height_m: float, v_n_mps: ArrayLike, rpy_rad: ArrayLike
    ) -> NavState:
        """Build a state from [roll, pitch, yaw] in rad."""
        return cls(
            float(lat_rad),
            float(lon_rad),
            float(height_m),
            np.asarray(v_n_mps, dtype=float).copy(),
            rotation.quat_from_euler(rpy_rad),
        )

    def as_vector(self) -> NDArray:
        """The kernel's state layout [lat, lon, h, vn, ve, vd, qw, qx, qy, qz]."""
        return np.concatenate(
            [[self.lat_rad, self.lon_rad, self.height_m], self.v_n_mps, self.q_nb]
        ).astype(float)


@dataclass(frozen=True)
class Trajectory:
    """Navigation solution at N epochs (time-major arrays).

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Epoch times [s] from the run's reference epoch.
    lat_rad, lon_rad, height_m : ndarray, shape (N,)
    v_n_mps : ndarray, shape (N, 3)
    q_nb : ndarray, shape (N, 4)
    """

    t_s: NDArray
    lat_rad: NDArray
    lon_rad: NDArray
    height_m: NDArray
    v_n_mps: NDArray
    q_nb: NDArray

    @classmethod
    def from_state_array(cls, t_s: NDArray, states: NDArray) -> Trajectory:
        """Wrap a (N, 10) kernel state array (columns are views of it, not copies)."""
        return cls(
            np.asarray(t_s, dtype=float),
            states[:, 0],
            states[:, 1],
            states[:, 2],
            states[:, 3:6],
            states[:, 6:10],
        )

    def __len__(self) -> int:
        return self.t_s.shape[0]

    @property
    def rpy_rad(self) -> NDArray:
        """[roll, pitch, yaw] in rad, shape (N, 3), yaw in [0, 2 pi)."""
        return rotation.euler_from_quat(self.q_nb)

    @property
    def c_nb(self) -> NDArray:
        """C_nb, shape (N, 3, 3)."""
        return rotation.dcm_from_quat(self.q_nb)

    def state(self, k: int) -> NavState:
        """The :class:`NavState` at index k."""
        return NavState(
            float(self.lat_rad[k]),
            float(self.lon_rad[k]),
            float(self.height_m[k]),
            self.v_n_mps[k].copy(),
            self.q_nb[k].copy(),
        )

    def slice(self, start: int, stop: int) -> Trajectory:
        """Epochs [start, stop) as a new trajectory."""
        s = slice(start, stop)
        return Trajectory(
            self.t_s[s], self.lat_rad[s], self.lon_rad[s], self.height_m[s], self.v_n_mps[s],
            self.q_nb[s],
        )


def _bias_array(bias: ArrayLike | None, n: int, name: str) -> NDArray:
    if bias is None:
        return np.zeros((1, 3))
    b = np.asarray(bias, dtype=float)
    if b.shape == (3,):
        return b.reshape(1, 3)
    if b.shape == (n, 3):
        return np.ascontiguousarray(b)
    raise ValueError(f"{name}: expected shape (3,) or ({n}, 3), got {b.shape}")


def check_increments(t_s: NDArray, dtheta_b_rad: NDArray, dv_b_mps: NDArray) -> NDArray:
    """Validate an increment series; return the interval lengths dt [s].

    Raises
    ------
    ValueError
        Naming the first offending sample: shape mismatch, non-finite values, or
        non-increasing time (zero or negative interval).
    """
    n = dtheta_b_rad.shape[0]
    if t_s.ndim != 1 or t_s.shape[0] != n + 1:
        raise ValueError(f"t_s: expected shape ({n + 1},) for {n} increments, got {t_s.shape}")
    for name, arr in (("dtheta_b_rad", dtheta_b_rad), ("dv_b_mps", dv_b_mps)):
        if arr.shape != (n, 3):
            raise ValueError(f"{name}: expected shape ({n}, 3), got {arr.shape}")
    # one compiled pass over the data (numpy's isfinite/diff cost ~0.1 us per epoch)
    code, k = _kernels.first_invalid_sample(
        np.ascontiguousarray(t_s, dtype=float),
        np.ascontiguousarray(dtheta_b_rad, dtype=float),
        np.ascontiguousarray(dv_b_mps, dtype=float),
    )
    if code in (1, 2):
        name, arr = (("dtheta_b_rad", dtheta_b_rad), ("dv_b_mps", dv_b_mps))[code - 1]
        raise ValueError(
            f"{name}: non-finite value in sample {k} (interval ending t = {t_s[k + 1]:.6f} s):"
            f" {arr[k].tolist()}"
        )
    if code == 3:
        raise ValueError(f"t_s: non-finite time at sample {k}")
    if code == 4:
        raise ValueError(
            f"t_s: time not increasing at sample {k}: t = {t_s[k]!r} s after "
            f"{t_s[k - 1]!r} s (interval {t_s[k] - t_s[k - 1]!r} s)"
        )
    return np.diff(t_s)


def integrate(
    t_s: ArrayLike,
    dtheta_b_rad: ArrayLike,
    dv_b_mps: ArrayLike,
    initial: NavState,
    *,
    gyro_bias_b_radps: ArrayLike | None = None,
    accel_bias_b_mps2: ArrayLike | None = None,
    previous_increments: tuple[ArrayLike, ArrayLike] | None = None,
) -> Trajectory:
    """Pure-inertial strapdown navigation over a series of IMU increments.

    Parameters
    ----------
    t_s : array_like, shape (N + 1,)
        Epoch times [s]; ``t_s[0]`` is the time of ``initial``.
    dtheta_b_rad, dv_b_mps : array_like, shape (N, 3)
        Angle and velocity increments over (t_s[k], t_s[k+1]], body FRD.
    initial : NavState
        State at ``t_s[0]``.
    gyro_bias_b_radps, accel_bias_b_mps2 : array_like, shape (3,) or (N, 3), optional
        Sensor biases to remove (measured = true + bias), constant or per interval.
    previous_increments : (dtheta, dv), optional
        Raw increments of the interval before ``t_s[0]``, for the coning/sculling correction of
        the first interval (B replays started mid-flight pass them; zeros otherwise).

    Returns
    -------
    Trajectory
        N + 1 epochs, the first equal to ``initial``.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    dth = np.ascontiguousarray(dtheta_b_rad, dtype=float)
    dvl = np.ascontiguousarray(dv_b_mps, dtype=float)
    dt = check_increments(t, dth, dvl)
    n = dth.shape[0]
    bg = _bias_array(gyro_bias_b_radps, n, "gyro_bias_b_radps")
    ba = _bias_array(accel_bias_b_mps2, n, "accel_bias_b_mps2")
    if previous_increments is None:
        dth_p = np.zeros(3)
        dv_p = np.zeros(3)
    else:
        dt_prev = dt[0] if n else 0.0
        dth_p = np.asarray(previous_increments[0], dtype=float) - bg[0] * dt_prev
        dv_p = np.asarray(previous_increments[1], dtype=float) - ba[0] * dt_prev
    out = np.empty((n + 1, _kernels.STATE_SIZE))
    _kernels.integrate_kernel(initial.as_vector(), dt, dth, dvl, bg, ba, dth_p, dv_p, out)
    return Trajectory.from_state_array(t, out)


def increments_from_rates(
    time_ns: ArrayLike, w_ib_b_radps: ArrayLike, f_ib_b_mps2: ArrayLike, *, epoch_ns: int
) -> tuple[NDArray, NDArray, NDArray]:
    """Mean rates over the interval ending at each stamp -> increments (data contract).

    The first sample's interval start is unknown, so it is dropped: N samples give N - 1
    increments over the epochs ``t_s = (time_ns - epoch_ns) * 1e-9`` (all N of them).

    Returns
    -------
    t_s : ndarray, shape (N,)
    dtheta_b_rad, dv_b_mps : ndarray, shape (N - 1, 3)
    """
    t_ns = np.asarray(time_ns, dtype=np.int64)
    t_s = t_s_from_time_ns(t_ns, epoch_ns)
    dt = np.diff(t_ns) * S_PER_NS
    w = np.asarray(w_ib_b_radps, dtype=float)
    f = np.asarray(f_ib_b_mps2, dtype=float)
    return t_s, w[1:] * dt[:, None], f[1:] * dt[:, None]


def interpolate_trajectory(traj: Trajectory, t_s: NDArray) -> Trajectory:
    """Trajectory at new times: linear in position and velocity, slerp-free small-step attitude.

    Attitude is interpolated by the rotation vector between the bracketing quaternions, so it
    is exact for constant-rate rotation between samples.
    """
    t_s = np.asarray(t_s, dtype=float)
    i = np.clip(np.searchsorted(traj.t_s, t_s, side="right") - 1, 0, len(traj) - 2)
    w = (t_s - traj.t_s[i]) / (traj.t_s[i + 1] - traj.t_s[i])
    w = np.clip(w, 0.0, 1.0)

    def lin(a: NDArray) -> NDArray:
        ww = w.reshape((-1,) + (1,) * (a.ndim - 1))
        return a[i] * (1 - ww) + a[i + 1] * ww

    q0, q1 = traj.q_nb[i], traj.q_nb[i + 1]
    dq = rotation.quat_multiply(rotation.quat_conjugate(q0), q1)
    rv = rotation.rotvec_from_quat(dq) * w[:, None]
    q = rotation.quat_multiply(q0, rotation.quat_from_rotvec(rv))
    return Trajectory(
        t_s, lin(traj.lat_rad), lin(traj.lon_rad), lin(traj.height_m), lin(traj.v_n_mps), q
    )
