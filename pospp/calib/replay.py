"""Algorithm B: pure-inertial replay from each leg start, and its error against algorithm A.

At the IMU epoch nearest a leg's start, B takes A's position, velocity and attitude and runs
the one strapdown kernel (:mod:`pospp.nav.strapdown`) pure-inertial to the leg end, on the raw
gyro increments (their drift is what the calibration measures) and, by default, the
accelerometer increments corrected by A's accelerometer-bias estimate (docs/method.md,
"Why the accelerometer bias drops out"). B minus A over the leg is B's navigation error when A
is the smoothed solution, whose own error is far below B's.

Outputs per leg, at ``sample_rate_hz`` (default 1 Hz): B minus A in velocity (NED, m/s) and
position (NED, m), A's velocity sigma (the weight of each sample) and the 15-state transition
matrices Phi(t, t0) from F(t) along B's actual trajectory (for the calibration's sensitivity
rows). Frames and units as in :mod:`pospp.nav.error_model`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth, rotation
from pospp.calib.segment import Leg
from pospp.nav import strapdown
from pospp.nav.error_model import transition_matrices
from pospp.threads import map_in_threads
from pospp.units import t_s_from_time_ns


@dataclass(frozen=True)
class ReplayOptions:
    """Algorithm B's settings in the calibration stage (config ``[replay]`` without its
    ``reference``: :meth:`pospp.config.ReplayConfig.options`; units in the names)."""

    accel_compensation: str = "filter"
    sample_rate_hz: float = 1.0
    sigma_floor_mps: float = 0.005
    horizon_s: float = 300.0
    transition_step: int = 10

@dataclass(frozen=True)
class ImuIncrements:
    """Raw IMU increments on a common epoch grid (body FRD).

    ``dtheta_b_rad[k]``, ``dv_b_mps[k]`` span (t_s[k], t_s[k+1]].
    """

    t_s: NDArray
    dtheta_b_rad: NDArray
    dv_b_mps: NDArray

    def window(self, k0: int, k1: int) -> ImuIncrements:
        """The increments of intervals ``k0 .. k1 - 1`` (epochs ``t_s[k0 .. k1]``): views."""
        return ImuIncrements(self.t_s[k0:k1 + 1], self.dtheta_b_rad[k0:k1],
                             self.dv_b_mps[k0:k1])


@dataclass(frozen=True)
class ImuRates:
    """A log's IMU as mean rates (the data contract, body FRD), whose increments are made per
    window: B reads a leg at a time, so the whole flight's increments (52 MiB on a 1.5 h,
    200 Hz flight, the same samples as the rates) are never held.

    ``w_ib_b_radps[k]``, ``f_ib_b_mps2[k]`` are the mean rates over (time_ns[k-1],
    time_ns[k]]; ``t_s`` [s] from the run's epoch. A window's increments are
    :func:`pospp.nav.strapdown.increments_from_rates`' over the whole log, bit for bit (the
    same products ``rate * dt``, ``dt = diff(time_ns) * 1e-9``).
    """

    t_s: NDArray
    time_ns: NDArray
    w_ib_b_radps: NDArray
    f_ib_b_mps2: NDArray

    @classmethod
    def from_rates(cls, time_ns: ArrayLike, w_ib_b_radps: ArrayLike, f_ib_b_mps2: ArrayLike,
                   *, epoch_ns: int) -> ImuRates:
        """The rates as logged (arrays not copied) and their epochs from ``epoch_ns``."""
        t_ns = np.asarray(time_ns, dtype=np.int64)
        return cls(t_s_from_time_ns(t_ns, epoch_ns), t_ns,
                   np.asarray(w_ib_b_radps, dtype=float), np.asarray(f_ib_b_mps2, dtype=float))

    def window(self, k0: int, k1: int) -> ImuIncrements:
        """The increments of intervals ``k0 .. k1 - 1`` (epochs ``t_s[k0 .. k1]``), made by
        :func:`pospp.nav.strapdown.increments_from_rates` on the window's samples."""
        sl = slice(k0, k1 + 1)
        _, dth, dv = strapdown.increments_from_rates(
            self.time_ns[sl], self.w_ib_b_radps[sl], self.f_ib_b_mps2[sl],
            epoch_ns=int(self.time_ns[k0]))
        return ImuIncrements(self.t_s[sl], dth, dv)


ImuSource = ImuIncrements | ImuRates
"""IMU increments held (:class:`ImuIncrements`) or made per window (:class:`ImuRates`): what
B reads, through ``t_s`` and ``window``."""


@dataclass(frozen=True)
class SolutionA:
    """Algorithm A's solution as B needs it (any epoch grid covering the legs).

    Attributes
    ----------
    trajectory : Trajectory
        Position, velocity, attitude.
    v_sigma_n_mps : ndarray, shape (N, 3)
        Velocity standard deviations, NED [m/s].
    accel_bias_b_mps2 : ndarray, shape (N, 3)
        Estimated accelerometer bias, body [m/s^2] (zeros if A has none).
    """

    trajectory: strapdown.Trajectory
    v_sigma_n_mps: NDArray
    accel_bias_b_mps2: NDArray


@dataclass(frozen=True)
class LegReplay:
    """B minus A over one leg, sampled at ``t_s`` (seconds since the leg start ``t0_s``).

    Attributes
    ----------
    leg : Leg
    t0_s : float
        Run time of B's initial epoch [s].
    t_s : ndarray, shape (M,)
        Time since the leg start [s]; ``t_s[0] == 0``.
    dv_n_mps, dr_n_m : ndarray, shape (M, 3)
        B minus A velocity and position, NED.
    sigma_v_n_mps : ndarray, shape (M, 3)
        Standard deviation of each velocity sample (A's sigma with a floor).
    phi : ndarray, shape (M, 15, 15)
        Transition matrices Phi(t0 + t_s, t0) of the 15-state error model along B.
    c_nb0 : ndarray, shape (3, 3)
        B's initial attitude.
    c_nb : ndarray, shape (M, 3, 3)
        B's attitude at the samples (the body-to-navigation projection of a body-fixed gyro
        bias and of the gyro noise).
    lat_rad, height_m : float
        B's initial latitude and height.
    v_n0_mps : ndarray, shape (3,)
        B's initial velocity.
    """

    leg: Leg
    t0_s: float
    t_s: NDArray
    dv_n_mps: NDArray
    dr_n_m: NDArray
    sigma_v_n_mps: NDArray
    phi: NDArray
    c_nb0: NDArray
    c_nb: NDArray
    lat_rad: float
    height_m: float
    v_n0_mps: NDArray


def solution_a_from_trajectory(
    trajectory: strapdown.Trajectory,
    *,
    v_sigma_n_mps: ArrayLike,
    accel_bias_b_mps2: ArrayLike | None = None,
) -> SolutionA:
    """Wrap any trajectory (a smoothed solution, a reference system, simulation truth) as A.

    Parameters
    ----------
    trajectory : Trajectory
        N epochs of position, velocity (NED) and attitude.
    v_sigma_n_mps : array_like, shape (3,) or (N, 3)
        Standard deviation of A's velocity, NED [m/s] (constant or per epoch).
    accel_bias_b_mps2 : array_like, shape (3,) or (N, 3), optional
        A's accelerometer-bias estimate, body FRD [m/s^2] (zeros when omitted).
    """
    n = len(trajectory)

    def per_epoch(a: ArrayLike | None, name: str) -> NDArray:
        arr = np.zeros(3) if a is None else np.asarray(a, dtype=float)
        if arr.shape == (3,):
            return np.tile(arr, (n, 1))
        if arr.shape != (n, 3):
            raise ValueError(f"{name}: expected shape (3,) or ({n}, 3), got {arr.shape}")
        return arr.copy()

    sig = per_epoch(v_sigma_n_mps, "v_sigma_n_mps")
    if not np.all(sig > 0):
        raise ValueError("v_sigma_n_mps: expected positive standard deviations")
    return SolutionA(trajectory, sig, per_epoch(accel_bias_b_mps2, "accel_bias_b_mps2"))


def replay_leg(
    imu: ImuSource,
    solution_a: SolutionA,
    leg: Leg,
    *,
    gyro_bias_b_radps: NDArray | None = None,
    attitude_correction_n_rad: NDArray | None = None,
    accel_compensation: str = "filter",
    sample_rate_hz: float = 1.0,
    sigma_floor_mps: float = 0.005,
    transition_step: int = 10,
) -> LegReplay:
    """Run algorithm B over one leg and difference it with A.

    Parameters
    ----------
    imu : ImuIncrements or ImuRates
        The whole flight's raw increments (or its rates, increments made for the leg).
    solution_a : SolutionA
        Algorithm A (smoothed by default, see the pipeline config).
    leg : Leg
        The leg to replay.
    gyro_bias_b_radps : ndarray, shape (3,), optional
        Gyro bias to remove (compensation run); raw gyro when None.
    attitude_correction_n_rad : ndarray, shape (3,), optional
        Calibrated misalignment phi of B's initial attitude; the initial attitude becomes
        exp([phi x]) C_nb_A (undoing C_nb_hat = (I - [phi x]) C_nb).
    accel_compensation : {"filter", "none"}
        Remove A's accelerometer-bias estimate at the leg start ("filter"), or use the raw
        accelerometer as the paper does ("none").
    sample_rate_hz : float
        Rate of the B minus A samples [Hz].
    sigma_floor_mps : float
        Lower bound of each sample's standard deviation [m/s].
    transition_step : int
        IMU intervals per F evaluation for the numerical transition matrices.
    """
    b, x0, c_nb0, ba, (k0, k1), dv_b = _b_over_leg(imu, solution_a, leg, gyro_bias_b_radps,
                                                   attitude_correction_n_rad,
                                                   accel_compensation)
    t_imu, ref_traj = imu.t_s, solution_a.trajectory
    t0, ts, b_s, a_s = _samples(b, ref_traj, t_imu[k0], t_imu[k1], sample_rate_hz)
    dv = b_s.v_n_mps - a_s.v_n_mps
    dr = earth.llh_difference_ned_m(
        b_s.lat_rad, b_s.lon_rad, b_s.height_m, a_s.lat_rad, a_s.lon_rad, a_s.height_m
    )
    sig = np.empty((ts.size, 3))
    for c in range(3):
        sig[:, c] = np.interp(t0 + ts, ref_traj.t_s, solution_a.v_sigma_n_mps[:, c])
    sig = np.maximum(sig, sigma_floor_mps)
    # numerical transition matrices along B's actual trajectory
    dt = np.diff(b.t_s)
    f_b = (dv_b - ba * dt[:, None]) / dt[:, None]
    phi_all = transition_matrices(b, f_b, step=transition_step)
    t_phi = b.t_s[:: transition_step][: phi_all.shape[0]] - t0
    idx = np.clip(np.searchsorted(t_phi, ts - 1e-9), 0, phi_all.shape[0] - 1)
    return LegReplay(
        leg=leg,
        t0_s=t0,
        t_s=ts,
        dv_n_mps=dv,
        dr_n_m=dr,
        sigma_v_n_mps=sig,
        phi=phi_all[idx],
        c_nb0=c_nb0,
        c_nb=rotation.dcm_from_quat(b_s.q_nb),
        lat_rad=float(x0.lat_rad),
        height_m=float(x0.height_m),
        v_n0_mps=x0.v_n_mps.copy(),
    )


def replay_legs(imu: ImuSource, solution_a: SolutionA, legs: Sequence[Leg],
                options: ReplayOptions | None = None, threads: int = 1
                ) -> tuple[dict[int, LegReplay], tuple[str, ...]]:
    """B replayed over every leg (:func:`replay_leg` with ``options``' settings; defaults when
    None) on up to ``threads`` threads (B's kernels release the GIL): ({leg id: replay} in
    the legs' order, and a message for each leg whose replay failed, naming it and why)."""
    rc = options if options is not None else ReplayOptions()

    def one(leg: Leg) -> LegReplay | str:
        try:
            return replay_leg(imu, solution_a, leg, accel_compensation=rc.accel_compensation,
                              sample_rate_hz=rc.sample_rate_hz,
                              sigma_floor_mps=rc.sigma_floor_mps,
                              transition_step=int(rc.transition_step))
        except ValueError as exc:
            return f"leg {leg.leg_id}: B replay failed: {exc}"

    made = map_in_threads(one, legs, threads)
    return ({leg.leg_id: r for leg, r in zip(legs, made, strict=True)
             if isinstance(r, LegReplay)}, tuple(r for r in made if isinstance(r, str)))


def forced_response(rep: LegReplay, g: NDArray, rows: slice = slice(3, 5)) -> NDArray:
    """B's error along a leg from a forcing, ``dx(t) = Phi(t, t0) int_0^t Phi(tau, t0)^-1 G u
    dtau``, the integrand trapezoidal on the leg's samples.

    Parameters
    ----------
    rep : LegReplay
        The leg (its transition matrices Phi(t_s, t0) and samples t_s).
    g : ndarray, shape (M, 15, P)
        ``G(tau) u(tau)`` at the samples for each of P unit parameters (error-state
        derivative, 15-state layout of :mod:`pospp.nav.error_model`).
    rows : slice
        The error states returned: [dv_N, dv_E] [m/s] by default, ``DR`` for the NED position
        error [m].

    Returns
    -------
    ndarray, shape (M, R, P)
        Those rows at the samples per unit parameter; zero at t = 0.
    """
    integrand = np.linalg.solve(rep.phi, g)  # (M, 15, P)
    steps = 0.5 * (integrand[1:] + integrand[:-1]) * np.diff(rep.t_s)[:, None, None]
    cum = np.concatenate([np.zeros_like(integrand[:1]), np.cumsum(steps, axis=0)])
    return rep.phi[:, rows, :] @ cum


def replay_velocity_error(
    imu: ImuSource,
    solution_a: SolutionA,
    leg: Leg,
    *,
    gyro_bias_b_radps: NDArray | None = None,
    attitude_correction_n_rad: NDArray | None = None,
    accel_compensation: str = "filter",
    sample_rate_hz: float = 1.0,
) -> NDArray:
    """B minus A in velocity over one leg, NED [m/s], shape (M, 3): ``replay_leg(...).dv_n_mps``
    (same arguments, samples and values) without the transition matrices, which cost most of
    a replay and which the null realisations and the re-run signatures do not use
    (:func:`replay_errors`' velocity)."""
    return replay_errors(imu, solution_a, leg, gyro_bias_b_radps=gyro_bias_b_radps,
                         attitude_correction_n_rad=attitude_correction_n_rad,
                         accel_compensation=accel_compensation,
                         sample_rate_hz=sample_rate_hz).dv_n_mps


@dataclass(frozen=True)
class LegErrors:
    """B minus A over one leg without B's error model: what a compensated replay reports
    (:func:`replay_errors`)."""

    leg: Leg
    t0_s: float
    """B's start [s run time], the first IMU epoch at or after the leg's start."""
    t_s: NDArray
    """(M,) seconds since ``t0_s``."""
    dv_n_mps: NDArray
    """(M, 3) B minus A in velocity, NED [m/s]."""
    dr_n_m: NDArray
    """(M, 3) B minus A in position, NED [m]."""


def replay_errors(
    imu: ImuSource,
    solution_a: SolutionA,
    leg: Leg,
    *,
    gyro_bias_b_radps: NDArray | None = None,
    attitude_correction_n_rad: NDArray | None = None,
    accel_compensation: str = "filter",
    sample_rate_hz: float = 1.0,
) -> LegErrors:
    """B minus A in velocity and position over one leg: ``replay_leg(...)``'s ``t_s``,
    ``dv_n_mps`` and ``dr_n_m`` (same arguments, samples and values) without the transition
    matrices, which cost most of a replay and which a compensated replay and the smoothed
    compensation's choice (:func:`pospp.calib.compensate.history_scores_m`) do not use."""
    b, _, _, _, (k0, k1), _ = _b_over_leg(imu, solution_a, leg, gyro_bias_b_radps,
                                       attitude_correction_n_rad, accel_compensation)
    t0, ts, b_s, a_s = _samples(b, solution_a.trajectory, imu.t_s[k0], imu.t_s[k1],
                                sample_rate_hz)
    return LegErrors(leg, t0, ts, b_s.v_n_mps - a_s.v_n_mps,
                     earth.llh_difference_ned_m(b_s.lat_rad, b_s.lon_rad, b_s.height_m,
                                                a_s.lat_rad, a_s.lon_rad, a_s.height_m))


def _b_over_leg(imu: ImuSource, solution_a: SolutionA, leg: Leg,
                gyro_bias_b_radps: NDArray | None, attitude_correction_n_rad: NDArray | None,
                accel_compensation: str) -> tuple:
    """B integrated over the leg from A's state at its first IMU epoch (``replay_leg``):
    (trajectory, initial NavState, initial C_nb, accelerometer bias removed, (k0, k1), the
    leg's velocity increments ``dv_b_mps[k0:k1]``)."""
    t_imu = imu.t_s
    k0 = int(np.searchsorted(t_imu, leg.start_s))
    k1 = int(np.searchsorted(t_imu, leg.end_s, side="right")) - 1
    k0 = max(k0, 1)
    if k1 - k0 < 10:
        raise ValueError(f"leg {leg.leg_id}: fewer than 10 IMU epochs between its start and end")
    ref_traj = solution_a.trajectory
    a0 = strapdown.interpolate_trajectory(ref_traj, np.array([t_imu[k0]]))
    c_nb0 = rotation.dcm_from_quat(a0.q_nb[0])
    if attitude_correction_n_rad is not None:
        c_nb0 = rotation.dcm_from_rotvec(np.asarray(attitude_correction_n_rad)) @ c_nb0
    x0 = strapdown.NavState(
        float(a0.lat_rad[0]), float(a0.lon_rad[0]), float(a0.height_m[0]), a0.v_n_mps[0].copy(),
        rotation.quat_from_dcm(c_nb0),
    )
    if accel_compensation == "filter":
        j = min(int(np.searchsorted(ref_traj.t_s, t_imu[k0])), len(ref_traj) - 1)
        ba = solution_a.accel_bias_b_mps2[j]
    elif accel_compensation == "none":
        ba = np.zeros(3)
    else:
        raise ValueError(
            f"accel_compensation: expected 'filter' or 'none', got {accel_compensation!r}"
        )
    bg = np.zeros(3) if gyro_bias_b_radps is None else np.asarray(gyro_bias_b_radps, dtype=float)
    win = imu.window(k0 - 1, k1)  # with the interval before k0 (B's first extrapolation)
    b = strapdown.integrate(
        t_imu[k0 : k1 + 1],
        win.dtheta_b_rad[1:],
        win.dv_b_mps[1:],
        x0,
        gyro_bias_b_radps=bg,
        accel_bias_b_mps2=ba,
        previous_increments=(win.dtheta_b_rad[0], win.dv_b_mps[0]),
    )
    return b, x0, c_nb0, ba, (k0, k1), win.dv_b_mps[1:]


def _samples(b: strapdown.Trajectory, ref_traj: strapdown.Trajectory, t_start_s: float,
             t_end_s: float, sample_rate_hz: float) -> tuple:
    """B and A at every 1 / sample_rate from B's start within the leg: (t0, ts, B, A)."""
    t0 = float(t_start_s)
    ts = np.arange(0.0, t_end_s - t0 + 1e-9, 1.0 / sample_rate_hz)
    return (t0, ts, strapdown.interpolate_trajectory(b, t0 + ts),
            strapdown.interpolate_trajectory(ref_traj, t0 + ts))
