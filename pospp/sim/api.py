"""Top-level simulator: mission profile (or a given trajectory) -> IMU, GNSS, truth, params.

Frames, units, conventions: as :mod:`pospp` (IMU in body FRD, NED, SI inside; errors computed
minus true; sensors read true + error). IMU samples follow the data contract: the sample
stamped t_k carries the MEAN rate and specific force over (t_{k-1}, t_k], i.e. exact
increment / dt (:mod:`pospp.sim.imu`). The truth is the IMU's state at every IMU epoch,
including the mission start t_0 (one epoch before the first IMU stamp).

Entry points: :func:`simulate` (mission profile), :func:`simulate_along` (smooth motion along a
given lat/lon/height series), :func:`load_profile`, :func:`imu_grade`. Files are written by
:func:`pospp.io.simulation_files.write_simulation`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from pospp import __version__, rotation
from pospp.nav.strapdown import Trajectory
from pospp.sim.gnss import GnssModel
from pospp.sim.gravity import GravityDisturbance
from pospp.sim.imu import Motion, quat_nb_from_euler
from pospp.sim.kinematics import Kinematics, ProgressFn, kinematics, sensors
from pospp.sim.profile import MissionProfile, load_profile, plan_mission
from pospp.sim.sensors import ImuErrorModel, RealisedImuErrors, imu_grade
from pospp.sim.trajectory import MotionSample, ProfileMotion, SplineMotion
from pospp.types import GnssFixes, GnssVelocities, ImuSamples, ReferenceTrajectory
from pospp.units import DEG_PER_H_RADPS, UG_MPS2, time_ns_from_t_s

__all__ = [
    "DEFAULT_START_TIME_NS",
    "GnssModel",
    "GravityDisturbance",
    "ImuErrorModel",
    "Kinematics",
    "Simulation",
    "TrueLeg",
    "along_motion",
    "gnss_model_from_params",
    "imu_error_model_from_params",
    "imu_grade",
    "load_profile",
    "kinematics",
    "sensors",
    "simulate",
    "simulate_along",
]

DEFAULT_START_TIME_NS = 1_717_200_000_000_000_000
"""2024-06-01T00:00:00 UTC, the default mission start (same epoch as the reference cases)."""


CONVENTIONS = {
    "nav_frame": "NED (local geodetic, WGS-84)",
    "body_frame": "FRD (x forward, y right, z down); per-axis parameters are on these axes "
                  "unless the key says _flu",
    "imu_message_frame": "FLU (REP-103) in the MCAP: x_flu = x_frd, y_flu = -y_frd, "
                         "z_flu = -z_frd",
    "imu_message": "header.stamp = end of the IMU interval; angular_velocity = delta_theta/dt, "
                   "linear_acceleration = delta_v/dt; delta_theta = int w_ib_b dt, delta_v = "
                   "int f_b dt (body axes at the integrand time, no coning/sculling)",
    "attitude": "z-y-x Euler angles of body FRD w.r.t. NED; yaw clockwise from north, "
                "[0, 360) deg in truth.parquet",
    "truth": "state of the IMU (not the antenna)",
    "gnss": "antenna position (lat/lon deg, ellipsoidal height m) and ENU velocity in the "
            "MCAP; the fix stamped t is the antenna state at true time t - time_offset_s",
    "gravity": "WGS-84 normal gravity (Somigliana, 2nd-order height term), no deflection",
    "errors": "sensors read true + error; navigation errors are computed minus true",
    "misalignment_order": "[xy, xz, yx, yz, zx, zy]: M_ij = sensitivity of axis i to input "
                          "about/along axis j (small angles)",
    "random_drift": "gyro 'random drift' = first-order Gauss-Markov sigma (gyro_gm_sigma_dph), "
                    "correlation time gyro_gm_tau_s",
}


@dataclass(frozen=True)
class TrueLeg:
    """A true straight, level, constant-velocity leg of the mission (``start_s``/``end_s`` from
    the mission start, ``start_ns``/``end_ns`` UTC stamps). With leg wander (profile.py) the
    heading and speed wander about the nominal ``heading_deg``/``speed_mps`` by the wander
    amplitudes, and ``length_m`` is the nominal speed x duration."""

    leg_id: int
    kind: str
    label: str
    start_s: float
    end_s: float
    start_ns: int
    end_ns: int
    duration_s: float
    heading_deg: float
    speed_mps: float
    height_m: float
    length_m: float
    start_lat_deg: float
    start_lon_deg: float
    end_lat_deg: float
    end_lon_deg: float
    heading_wander_deg: float = 0.0
    heading_wander_period_s: float = 0.0
    speed_wander_mps: float = 0.0
    speed_wander_period_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """All fields; the wander fields only when that wander is on (heading, speed and
        length are then the leg's nominal values)."""
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        for k in ("heading_wander", "speed_wander"):
            amp = f"{k}_deg" if k == "heading_wander" else f"{k}_mps"
            if not d[amp]:
                del d[amp], d[f"{k}_period_s"]
        return d


@dataclass(frozen=True)
class Simulation:
    """One simulated data set.

    Attributes
    ----------
    name : str
    imu : ImuSamples
        Body FRD mean rates / specific forces, stamps ``start_time_ns + k dt``, k = 1..N.
    fix : GnssFixes
    vel : GnssVelocities
    truth : pospp.nav.strapdown.Trajectory
        True IMU state at the N + 1 epochs ``t_s = k dt`` (k = 0..N) from ``start_time_ns``.
    start_time_ns : int
    legs : tuple of TrueLeg
    imu_errors : RealisedImuErrors
        Realised biases per IMU interval and the scale-factor/misalignment matrices.
    params : dict
        JSON-ready record of everything injected (layout mirrors the reference cases).
    """

    name: str
    imu: ImuSamples
    fix: GnssFixes
    vel: GnssVelocities
    truth: Trajectory
    start_time_ns: int
    legs: tuple[TrueLeg, ...]
    imu_errors: RealisedImuErrors
    params: dict[str, Any]

    @property
    def truth_time_ns(self) -> np.ndarray:
        """Stamps of the truth epochs [ns]."""
        return time_ns_from_t_s(self.truth.t_s, self.start_time_ns)

    def truth_reference(self, rate_hz: float = 10.0) -> ReferenceTrajectory:
        """The truth decimated to ``rate_hz`` (which must divide the IMU rate)."""
        dt_ns = int(self.params["time"]["imu_dt_ns"])
        step_ns = round(1e9 / rate_hz)
        if step_ns % dt_ns:
            raise ValueError(f"truth rate {rate_hz} Hz must divide the IMU rate "
                             f"({1e9 / dt_ns} Hz)")
        idx = np.arange(0, len(self.truth), step_ns // dt_ns)
        tr = self.truth
        return ReferenceTrajectory(
            self.truth_time_ns[idx], tr.lat_rad[idx], tr.lon_rad[idx], tr.height_m[idx],
            tr.v_n_mps[idx], rotation.euler_from_quat(tr.q_nb[idx]),
        )

    def trigger_stamps_ns(self, rate_hz: float, *, offset_s: float = 0.123456789
                          ) -> np.ndarray:
        """Trigger stamps [ns] of a sensor firing at ``rate_hz`` over the IMU span.

        ``t_k = first IMU stamp + offset_s + k / rate_hz`` up to the last IMU stamp; the
        default offset puts the triggers off the IMU and GNSS grids, so a consumer must
        interpolate.
        """
        if not rate_hz > 0:
            raise ValueError(f"rate_hz: expected a value > 0, got {rate_hz!r}")
        first, last = int(self.imu.time_ns[0]), int(self.imu.time_ns[-1])
        k = np.arange(int(np.floor((last - first - offset_s * 1e9) * rate_hz * 1e-9)) + 1)
        return first + np.round((offset_s + k / rate_hz) * 1e9).astype(np.int64)

    def realised_bias(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The realised IMU biases (constant + ramp + Gauss-Markov, white noise excluded) at
        the truth epochs of ``rate_hz``: the bias of the IMU interval ending at each epoch.

        Returns
        -------
        time_ns : (M,) int64
        gyro_bias_b_radps, accel_bias_b_mps2 : (M, 3) float64
            Body FRD [rad/s], [m/s^2].
        """
        dt_ns = int(self.params["time"]["imu_dt_ns"])
        step = round(1e9 / rate_hz) // dt_ns
        j = np.arange(0, len(self.truth), step)
        k = np.maximum(j - 1, 0)  # interval ending at epoch j
        return (self.truth_time_ns[j], self.imu_errors.gyro_bias_radps[k],
                self.imu_errors.accel_bias_mps2[k])


def imu_error_model_from_params(params: dict[str, Any]) -> ImuErrorModel:
    """The injected :class:`ImuErrorModel` of a params dict (``config.imu_errors``; read by
    ``pospp.io.simulation_files.read_params``)."""
    d = params["config"]["imu_errors"]
    known = ImuErrorModel.__dataclass_fields__
    return ImuErrorModel.from_dict({k: v for k, v in d.items() if k in known})


def gnss_model_from_params(params: dict[str, Any]) -> GnssModel:
    """The :class:`GnssModel` of a params dict written by pospp (``config.gnss``)."""
    d = dict(params["config"]["gnss"])
    d["outages_s"] = tuple(tuple(x) for x in d.get("outages_s", ()))
    return GnssModel.from_dict(d)


def _resolve_grade(g: str | ImuErrorModel) -> tuple[str, ImuErrorModel]:
    if isinstance(g, ImuErrorModel):
        return "custom", g
    return str(g), imu_grade(str(g))


def _truth(motion: Motion, t_s: np.ndarray, progress: ProgressFn | None) -> Trajectory:
    """The true IMU state at the epochs ``t_s``, in blocks of 200 000 epochs."""
    n1 = t_s.shape[0]
    lat, lon, hgt = np.empty(n1), np.empty(n1), np.empty(n1)
    v_n, q_nb = np.empty((n1, 3)), np.empty((n1, 4))
    for a in range(0, n1, 200_000):
        s = slice(a, a + 200_000)
        m = motion.evaluate(t_s[s])
        lat[s], lon[s], hgt[s], v_n[s] = m.lat_rad, m.lon_rad, m.height_m, m.v_n_mps
        q_nb[s] = quat_nb_from_euler(m.rpy_rad)
        if progress is not None:
            progress("truth", min(1.0, (a + 200_000) / n1))
    return Trajectory(t_s, lat, lon, hgt, v_n, q_nb)


def _params(*, grade_name: str, model: ImuErrorModel, realised: RealisedImuErrors,
            gnss: GnssModel, n_fix: int, seed: int, imu_rate_hz: float, start_time_ns: int,
            dt_ns: int, n: int, n_sub: int, n_gl: int, extra_params: dict[str, Any],
            legs: tuple[TrueLeg, ...], timings: dict[str, float],
            gravity: GravityDisturbance | None = None) -> dict[str, Any]:
    """The JSON-ready record of everything injected (layout mirrors the reference cases)."""
    g = model.as_dict()
    flu = np.array([1.0, -1.0, -1.0])
    imu_err = dict(g)
    imu_err.update({
        "grade": grade_name,
        "gyro_bias_flu_dph": list(np.asarray(model.gyro_bias_dph) * flu),
        "accel_bias_flu_ug": list(np.asarray(model.accel_bias_ug) * flu),
        "gyro_matrix_frd": realised.gyro_matrix.tolist(),
        "accel_matrix_frd": realised.accel_matrix.tolist(),
        "realised_gyro_bias_at_start_dph": list(
            realised.gyro_bias_radps[0] / DEG_PER_H_RADPS),
        "realised_accel_bias_at_start_ug": list(realised.accel_bias_mps2[0] / UG_MPS2),
    })
    gn = gnss.as_dict()
    conventions = CONVENTIONS if gravity is None else {**CONVENTIONS,
                                                        "gravity": gravity.describe()}
    grav: dict[str, Any] = {"model": "WGS-84 normal gravity, TR8350.2 Eq. 4-1 and 4-3 "
                                     "(pospp.earth.normal_gravity_mps2)"}
    if gravity is not None:
        grav = {"model": gravity.describe(), "disturbance": gravity.as_dict()}
    gn.update({"lever_arm_flu_m": list(np.asarray(gnss.lever_arm_b_m) * flu),
               "n_epochs": n_fix,
               "reported_pos_sigma_m": [max(x, 1e-3) for x in gnss.pos_noise_m],
               "reported_vel_sigma_mps": [max(x, 1e-3) for x in gnss.vel_noise_mps]})
    return {
        "generator": {"name": "pospp.sim", "version": __version__},
        "config": {"imu_grade": grade_name, "imu_rate_hz": imu_rate_hz, "seed": seed,
                   "imu_errors": g, "gnss": gnss.as_dict(), "start_time_ns": start_time_ns,
                   "n_sub": n_sub, "n_gl": n_gl, **extra_params.get("config", {}),
                   **({} if gravity is None else {"gravity": gravity.as_dict()})},
        "seed": seed,
        "time": {
            "start_time_ns": start_time_ns, "imu_rate_hz": imu_rate_hz, "imu_dt_ns": dt_ns,
            "n_imu_messages": n, "duration_s": n * dt_ns * 1e-9,
            "end_time_ns": start_time_ns + n * dt_ns,
            "first_imu_stamp_ns": start_time_ns + dt_ns,
        },
        "conventions": conventions,
        **{k: v for k, v in extra_params.items() if k != "config"},
        "legs": [lg.as_dict() for lg in legs],
        "imu_errors": imu_err,
        "gnss": gn,
        "gravity": grav,
        "numerics": {
            "quadrature": f"composite Gauss-Legendre, {n_sub} sub-intervals x {n_gl} nodes "
                          "per IMU interval",
            "timings_s": timings,
        },
    }


def _generate(
    name: str,
    motion: Motion,
    duration_s: float,
    *,
    grade_name: str,
    model: ImuErrorModel,
    gnss: GnssModel,
    seed: int,
    imu_rate_hz: float,
    start_time_ns: int,
    progress: ProgressFn | None,
    n_sub: int,
    n_gl: int,
    extra_params: dict[str, Any],
    legs_fn: Callable[[Trajectory], tuple[TrueLeg, ...]],
    gravity: GravityDisturbance | None = None,
) -> Simulation:
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def tick(key: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[key] = now - clock
        clock = now

    kin = kinematics(motion, duration_s, imu_rate_hz=imu_rate_hz, start_time_ns=start_time_ns,
                     n_sub=n_sub, n_gl=n_gl, progress=progress, gravity=gravity)
    tick("increments_s")
    imu, fix, vel, realised = sensors(kin, model, gnss, seed, progress)
    tick("imu_errors_s")
    truth = _truth(motion, kin.t_s, progress)
    tick("truth_s")
    legs = legs_fn(truth)
    n = kin.t_s.shape[0] - 1
    params = _params(grade_name=grade_name, model=model, realised=realised, gnss=gnss,
                     n_fix=len(fix), seed=seed, imu_rate_hz=imu_rate_hz,
                     start_time_ns=start_time_ns, dt_ns=kin.dt_ns, n=n, n_sub=n_sub,
                     n_gl=n_gl, extra_params=extra_params, legs=legs, timings=timings,
                     gravity=gravity)
    return Simulation(name, imu, fix, vel, truth, int(start_time_ns), legs, realised, params)


def simulate(
    profile: MissionProfile | str | Path,
    *,
    imu_grade: str | ImuErrorModel = "errorfree",
    gnss: GnssModel | None = None,
    seed: int = 0,
    imu_rate_hz: float | None = None,
    progress: ProgressFn | None = None,
    start_time_ns: int = DEFAULT_START_TIME_NS,
    duration_s: float | None = None,
    n_sub: int = 2,
    n_gl: int = 4,
    gravity: GravityDisturbance | None = None,
) -> Simulation:
    """Simulate a mission: exact IMU increments + IMU errors, GNSS, truth and parameters.

    Parameters
    ----------
    profile : MissionProfile, preset name or TOML path
    imu_grade : str or ImuErrorModel
        A grade of ``pospp/presets/imu.toml`` (``errorfree``, ``paper_vehicle``,
        ``paper_flight``) or explicit parameters.
    gnss : GnssModel, optional
        Default ``GnssModel()`` (1 Hz, 0.05/0.1 m, 0.02/0.03 m/s, no lever arm).
    seed : int
        Seeds everything (IMU and GNSS streams are spawned from it): same seed, same bits.
    imu_rate_hz : float, optional
        Default: the profile's ``imu_rate_hz``, else 200.
    progress : callable(stage, fraction), optional
    start_time_ns : int
        UTC stamp of the mission start (the truth's first epoch).
    duration_s : float, optional
        Truncate the mission (default: the whole plan).
    n_sub, n_gl : int
        Quadrature: sub-intervals and Gauss-Legendre nodes per IMU interval.
    gravity : GravityDisturbance, optional
        A gravity disturbance field (deflection, anomaly, gradient; :mod:`pospp.sim.gravity`)
        in the true specific force; default WGS-84 normal gravity only. Recorded in
        ``params["gravity"]`` and ``params["conventions"]["gravity"]``.

    Returns
    -------
    Simulation
    """
    prof = profile if isinstance(profile, MissionProfile) else load_profile(profile)
    grade_name, model = _resolve_grade(imu_grade)
    gnss = gnss if gnss is not None else GnssModel()
    rate = float(imu_rate_hz or prof.imu_rate_hz or 200.0)
    t0 = time.perf_counter()
    plan = plan_mission(prof)
    motion = ProfileMotion(plan)
    if progress is not None:
        progress("trajectory", 1.0)
    t_traj = time.perf_counter() - t0
    dur = plan.duration_s if duration_s is None else min(float(duration_s), plan.duration_s)

    def legs_fn(truth: Trajectory) -> tuple[TrueLeg, ...]:
        out = []
        for lg in plan.legs:
            if lg.end_s > truth.t_s[-1] + 1e-9:
                continue
            lat, lon = np.rad2deg(motion.position(np.array([lg.start_s, lg.end_s]))[:2])
            out.append(TrueLeg(
                lg.leg_id, lg.kind, lg.label, lg.start_s, lg.end_s,
                start_time_ns + round(lg.start_s * 1e9),
                start_time_ns + round(lg.end_s * 1e9), lg.duration_s,
                round(math.degrees(lg.heading_rad) % 360.0, 9) % 360.0, lg.speed_mps,
                lg.height_m,
                lg.speed_mps * lg.duration_s, start_lat_deg=float(lat[0]),
                start_lon_deg=float(lon[0]), end_lat_deg=float(lat[1]),
                end_lon_deg=float(lon[1]),
                heading_wander_deg=round(math.degrees(lg.heading_wander_rad), 12),
                heading_wander_period_s=lg.heading_wander_period_s,
                speed_wander_mps=lg.speed_wander_mps,
                speed_wander_period_s=lg.speed_wander_period_s,
            ))
        return tuple(out)

    segs = []
    for s in plan.segments:
        d = s.as_dict()
        d["start_ns"] = start_time_ns + round(s.start_s * 1e9)
        d["end_ns"] = start_time_ns + round(s.end_s * 1e9)
        segs.append(d)
    extra = {
        "config": {"preset": prof.name, "mission": prof.as_dict()},
        "mission": {"preset": prof.name, "turn_bank": prof.turn_bank,
                    "duration_s": plan.duration_s,
                    "start": {"lat_deg": prof.lat_deg, "lon_deg": prof.lon_deg,
                              "height_m": prof.height_m, "heading_deg": prof.heading_deg},
                    "truncated_at_s": None if duration_s is None else dur},
        "segments": segs,
    }
    sim = _generate(prof.name, motion, dur, grade_name=grade_name, model=model, gnss=gnss,
                    seed=seed, imu_rate_hz=rate, start_time_ns=start_time_ns,
                    progress=progress, n_sub=n_sub, n_gl=n_gl, extra_params=extra,
                    legs_fn=legs_fn, gravity=gravity)
    sim.params["numerics"]["timings_s"]["trajectory_s"] = t_traj
    sim.params["numerics"]["position"] = (
        "Gauss-Legendre 4 nodes per 0.02 s step, Picard on the radii, cubic Hermite between")
    return sim


class _ShiftedMotion:
    def __init__(self, motion: SplineMotion, t0: float) -> None:
        self.motion = motion
        self.t0 = t0

    def evaluate(self, t_s: ArrayLike) -> MotionSample:
        m = self.motion.evaluate(np.asarray(t_s, dtype=float) + self.t0)
        return type(m)(np.asarray(t_s, dtype=float), *(getattr(m, f) for f in (
            "lat_rad", "lon_rad", "height_m", "v_n_mps", "a_n_mps2", "rpy_rad",
            "rpy_rate_radps")))


def along_motion(time_s: ArrayLike, lat_rad: ArrayLike, lon_rad: ArrayLike,
                 height_m: ArrayLike, *, vehicle: str = "car", position_sigma_m: float = 0.02,
                 heading_sigma_rad: float = 0.01, heading_min_speed_mps: float = 1.0
                 ) -> Motion:
    """The smooth motion :func:`simulate_along` follows (its parameters), with time from
    ``time_s[0]``: :class:`pospp.sim.trajectory.SplineMotion` shifted to start at 0."""
    t = np.asarray(time_s, dtype=float)
    sm = SplineMotion(t, lat_rad, lon_rad, height_m, vehicle=vehicle,
                      position_sigma_m=position_sigma_m, heading_sigma_rad=heading_sigma_rad,
                      heading_min_speed_mps=heading_min_speed_mps)
    return _ShiftedMotion(sm, float(t[0]))


def simulate_along(
    time_s: ArrayLike,
    lat_rad: ArrayLike,
    lon_rad: ArrayLike,
    height_m: ArrayLike,
    *,
    vehicle: str = "car",
    imu_grade: str | ImuErrorModel = "errorfree",
    gnss: GnssModel | None = None,
    seed: int = 0,
    imu_rate_hz: float = 200.0,
    progress: ProgressFn | None = None,
    start_time_ns: int = DEFAULT_START_TIME_NS,
    position_sigma_m: float = 0.02,
    heading_sigma_rad: float = 0.01,
    heading_min_speed_mps: float = 1.0,
    n_sub: int = 2,
    n_gl: int = 4,
    name: str = "along",
    gravity: GravityDisturbance | None = None,
) -> Simulation:
    """Simulate along a given trajectory (e.g. an RTK drive), exact increments included.

    The true motion is :class:`pospp.sim.trajectory.SplineMotion`: quintic smoothing splines
    of the ECEF position (RMS residual about ``position_sigma_m``), heading a smoothing spline
    of the track angle, zero pitch, zero roll (``vehicle="car"``) or coordinated-turn bank
    (``"aircraft"``). The mission starts at ``time_s[0]`` (stamped ``start_time_ns``) and ends
    at ``time_s[-1]``. No true legs are reported (segment the truth if needed).

    Parameters
    ----------
    time_s : (N,) [s], strictly increasing
    lat_rad, lon_rad, height_m : (N,) geodetic (WGS-84)
    vehicle : {"car", "aircraft"}
    position_sigma_m, heading_sigma_rad : float
        Smoothing: RMS residual of the position / heading fits, none above 4 x this.
    heading_min_speed_mps : float
        Below this speed the heading is held (the track angle of a stopped vehicle is noise).
    Other parameters (``gravity`` too) as :func:`simulate`.
    """
    t = np.asarray(time_s, dtype=float)
    grade_name, model = _resolve_grade(imu_grade)
    gnss = gnss if gnss is not None else GnssModel()
    t0 = time.perf_counter()
    motion = along_motion(t, lat_rad, lon_rad, height_m, vehicle=vehicle,
                          position_sigma_m=position_sigma_m,
                          heading_sigma_rad=heading_sigma_rad,
                          heading_min_speed_mps=heading_min_speed_mps)
    if progress is not None:
        progress("trajectory", 1.0)
    t_traj = time.perf_counter() - t0
    extra = {
        "config": {"along": {"n_points": int(t.size), "vehicle": vehicle,
                             "position_sigma_m": position_sigma_m,
                             "heading_sigma_rad": heading_sigma_rad,
                             "heading_min_speed_mps": heading_min_speed_mps,
                             "input_t0_s": float(t[0])}},
        "mission": {"preset": None, "turn_bank": "coordinated" if vehicle == "aircraft"
                    else "none", "duration_s": float(t[-1] - t[0])},
        "segments": [],
    }
    sim = _generate(name, motion, float(t[-1] - t[0]), grade_name=grade_name, model=model,
                    gnss=gnss, seed=seed, imu_rate_hz=imu_rate_hz,
                    start_time_ns=start_time_ns, progress=progress, n_sub=n_sub, n_gl=n_gl,
                    extra_params=extra, legs_fn=lambda truth: (), gravity=gravity)
    sim.params["numerics"]["timings_s"]["trajectory_s"] = t_traj
    sim.params["numerics"]["position"] = "quintic smoothing splines of ECEF position"
    return sim
