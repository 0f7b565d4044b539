"""The error-free part of a simulation made once, corrupted many times (:func:`kinematics`,
:func:`sensors`; :func:`pospp.sim.api.simulate` and ``pospp compare-sim`` use both).

Frames, units, conventions as :mod:`pospp.sim.api`: IMU in body FRD, NED, SI; the sample
stamped t_k carries the mean rate and specific force over (t_{k-1}, t_k].
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pospp.sim.gnss import GnssModel, simulate_gnss
from pospp.sim.gravity import GravityDisturbance
from pospp.sim.imu import Motion, exact_increments
from pospp.sim.sensors import ImuErrorModel, RealisedImuErrors, apply_imu_errors
from pospp.types import GnssFixes, GnssVelocities, ImuSamples

__all__ = ["Kinematics", "ProgressFn", "kinematics", "sensors"]

ProgressFn = Callable[[str, float], None]
"""progress(stage, fraction): stage in {"trajectory", "imu", "errors", "gnss", "truth"}."""


def _rate_dt_ns(imu_rate_hz: float) -> int:
    if not imu_rate_hz > 0:
        raise ValueError(f"imu_rate_hz must be > 0, got {imu_rate_hz!r}")
    dt_ns = round(1e9 / imu_rate_hz)
    if abs(dt_ns - 1e9 / imu_rate_hz) > 1e-3:
        raise ValueError(f"imu_rate_hz {imu_rate_hz} does not give a whole number of "
                         "nanoseconds per interval")
    return dt_ns


@dataclass(frozen=True)
class Kinematics:
    """The error-free part of a simulation, made once and corrupted many times
    (:func:`sensors`): the motion, the IMU epochs and the exact IMU increments.

    Attributes
    ----------
    motion : object with ``evaluate(t_s) -> MotionSample`` (time from the mission start)
    t_s : (N + 1,) IMU epochs [s from the mission start], ``k dt``
    dtheta_b_rad, dv_b_mps : (N, 3) exact increments over (t_k, t_k+1], body FRD
    start_time_ns : int
        UTC stamp of the mission start (epoch 0).
    dt_ns : int
        IMU interval [ns].
    """

    motion: Motion
    t_s: np.ndarray
    dtheta_b_rad: np.ndarray
    dv_b_mps: np.ndarray
    start_time_ns: int
    dt_ns: int

    @property
    def duration_s(self) -> float:
        return (self.t_s.shape[0] - 1) * self.dt_ns * 1e-9


def kinematics(motion: Motion, duration_s: float, *, imu_rate_hz: float, start_time_ns: int,
               n_sub: int = 2, n_gl: int = 4, progress: ProgressFn | None = None,
               gravity: GravityDisturbance | None = None) -> Kinematics:
    """The exact increments of ``motion`` over [0, duration_s] at ``imu_rate_hz``
    (:func:`pospp.sim.imu.exact_increments`; ``n_sub``, ``n_gl`` its quadrature)."""
    dt_ns = _rate_dt_ns(imu_rate_hz)
    n = int(math.floor(duration_s * 1e9 / dt_ns))
    if n < 2:
        raise ValueError(f"mission of {duration_s} s is shorter than two IMU intervals")
    t_s = (np.arange(n + 1, dtype=np.int64) * dt_ns).astype(float) * 1e-9
    prog_imu = None if progress is None else (lambda f: progress("imu", f))
    dth, dv = exact_increments(motion, t_s, n_sub=n_sub, n_gl=n_gl, progress=prog_imu,
                               gravity=gravity)
    return Kinematics(motion, t_s, dth, dv, int(start_time_ns), dt_ns)


def sensors(kin: Kinematics, model: ImuErrorModel, gnss: GnssModel, seed: int,
            progress: ProgressFn | None = None
            ) -> tuple[ImuSamples, GnssFixes, GnssVelocities, RealisedImuErrors]:
    """The IMU samples (mean rates and specific forces, stamped at the interval ends) and the
    GNSS records of ``kin`` with the sensor errors of ``model`` and ``gnss``: the IMU from the
    first child of ``SeedSequence(seed)``, the GNSS from the second (so a change of the GNSS
    model leaves the IMU's draws alone, and the reverse)."""
    ss_imu, ss_gnss = np.random.SeedSequence(seed).spawn(2)
    dth_m, dv_m, realised = apply_imu_errors(kin.t_s, kin.dtheta_b_rad, kin.dv_b_mps, model,
                                             ss_imu)
    if progress is not None:
        progress("errors", 1.0)
    dt = np.diff(kin.t_s)[:, None]
    dth_m /= dt  # mean rates, in place (apply_imu_errors returns new arrays)
    dv_m /= dt
    k = np.arange(1, kin.t_s.shape[0], dtype=np.int64)
    imu = ImuSamples(np.int64(kin.start_time_ns) + k * kin.dt_ns, dth_m, dv_m, "imu_link")
    fix, vel = simulate_gnss(kin.motion, kin.duration_s, gnss,
                             start_time_ns=kin.start_time_ns, seed=ss_gnss)
    if progress is not None:
        progress("gnss", 1.0)
    return imu, fix, vel, realised
