"""``pospp compare-sim``: a finished run against a simulation of the same flight.

Orchestration only (docs/compare_sim.md): re-read the run's input and configuration (as
:func:`pospp.pipeline.diagnose_run`), run algorithm A, simulate the same flight with
:func:`pospp.sim.api.simulate_along` along A's smoothed trajectory with the configured IMU
grade and a GNSS model from the log (rates, stamps, gaps, reported sigmas), run A on the
simulation the same way, and hand both to the step-wise comparison of
:mod:`pospp.simcompare`. Writes sim_comparison.parquet, sim_model.toml and the report.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from pospp import earth, flight_stages, pipeline
from pospp.config import PipelineConfig
from pospp.io import mcap_reader, parquet_tables, report_files, run_folder
from pospp.io.run_lock import locked
from pospp.lever_time_stage import lever_time_estimate
from pospp.nav import filter as nav_filter
from pospp.nav.alignment import AlignmentOptions, gnss_moving_windows
from pospp.nav.solution import NavSolution
from pospp.sim.api import Kinematics, along_motion, kinematics, sensors
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel, imu_grade
from pospp.simcompare.base_model import (
    BaseFit,
    ImuParts,
    fit_base_model,
    gyrocompass_resolves,
    has_drift,
)
from pospp.simcompare.compare import Comparison, compare_flights
from pospp.simcompare.effects import BASE_DRAW, LIBRARY, EffectContext, SimEffect, joint_stats
from pospp.simcompare.ensemble import SimulateFn, masked_lines
from pospp.simcompare.stats import (
    STATIC_END_MARGIN_S,
    STATIC_SPEED_MPS,
    FlightStats,
    Stat,
    flight_stats,
    leg_stats,
    static_and_steady,
)
from pospp.simcompare.tables import comparison_columns, model_toml

__all__ = ["SIM_GRADES", "FlightTemplate", "compare_sim_run", "flight_template",
           "log_stats", "simulate_stats"]

SIM_GRADES = {"flight": "paper_flight", "vehicle": "paper_vehicle", "consumer": "mems"}
"""Filter tuning grade ([imu] grade) -> simulator grade of pospp/presets/imu.toml."""
RESIDUAL_NOISE_FACTOR = 1.5
"""The simulated GNSS white noise is at most this times the records' RMS about A's smoothed
solution (which follows part of the noise, so the factor keeps a consistent receiver's
reported sigma)."""
MIN_LEGS = 3
"""B minus A on legs is compared only on flights with at least this many legs (the
leave-one-leg-out prediction needs them)."""
SIM_SEED = 20261123
"""Seed of every simulation of one comparison (common random numbers across its steps)."""
EST_ACCEL_GM_UG = 1000.0
EST_ACCEL_GM_TAU_S = 3600.0
"""The accelerometer Gauss-Markov states of A's estimate pass (lever arm, scale factors), at
least the grade's: loose enough that its horizontal bias follows an in-run change between
the turns that reveal it (``a_accel_trend_x/y``); the vertical trend stays
A-as-configured's (docs/decisions.md "compare-sim's horizontal accelerometer trend from a
loose pass")."""
EST_SF_PRIOR_PPM = (2000.0, 5000.0)
"""Prior sigmas of the gyro and accelerometer scale-factor states of A's estimate pass [ppm],
at least the grade's (twice and five times the catalogue's plausible 1000 ppm; the diagnosis's
scale-factor pass takes 2000 ppm for the gyros): at the flight grade's 10 / 50 ppm the
states could not move, and a 500 ppm z gyro scale factor over two 180 deg turns read 0.8
+- 14 ppm."""
QUADRATURE = (1, 2)
"""Sub-intervals and Gauss-Legendre nodes per IMU interval of the comparison's kinematics
(the simulator's default is 2 x 4): on flight_time_offset_200hz's trajectory the increments
differ from the default's by at most 1e-15 rad/s and 2e-13 m/s^2 of mean rate, and take
1.9 s instead of 7.7 s."""


@dataclass(frozen=True)
class FlightTemplate:
    """What the simulation copies from the measured flight.

    Attributes
    ----------
    time_s, lat_rad, lon_rad, height_m : A's smoothed trajectory (s from ``epoch_ns``)
    epoch_ns : int
        The measured log's first IMU stamp.
    imu_dt_ns : int
        IMU interval [ns] (the median of the log's, rounded).
    imu_gaps_s : (K, 2) IMU gaps of the log (start, end) [s from epoch]
    gnss : GnssModel
        Rate, outages, the configured lever arm, the median reported sigmas (reported in the
        simulated covariances), and white noise at those sigmas, or at 1.5 x the RMS of the
        records about A's smoothed solution where that is smaller.
    has_velocity : bool
    vehicle : "car" or "aircraft"
    kinematics : pospp.sim.api.Kinematics
        The error-free simulation along the trajectory (the motion and its exact IMU
        increments, made once: every simulation of the comparison adds its sensor errors to
        it, :func:`simulate_log`).
    """

    time_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    height_m: np.ndarray
    epoch_ns: int
    imu_dt_ns: int
    imu_gaps_s: np.ndarray
    gnss: GnssModel
    has_velocity: bool
    vehicle: str
    kinematics: Kinematics

    def kinematic_imu(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The error-free simulated IMU on the measured log's time axis: stamps [s from
        ``epoch_ns``], rates [rad/s] and specific forces [m/s^2] (N, 3), body FRD."""
        k = self.kinematics
        dt = k.dt_ns * 1e-9
        t = self.time_s[0] + dt * np.arange(k.t_s.shape[0] - 1)
        return t, k.dtheta_b_rad / dt, k.dv_b_mps / dt


def _gaps(t_s: np.ndarray, factor: float) -> np.ndarray:
    d = np.diff(t_s)
    if d.size == 0:
        return np.zeros((0, 2))
    big = np.flatnonzero(d > factor * np.median(d))
    return np.stack([t_s[big], t_s[big + 1]], axis=1) if big.size else np.zeros((0, 2))


def flight_template(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                    config: PipelineConfig, *, vehicle: str | None = None) -> FlightTemplate:
    """The measured flight's trajectory (A smoothed), stamps, gaps and GNSS model."""
    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    epoch = int(log.imu.time_ns[0])
    t_imu = (log.imu.time_ns - epoch) * 1e-9
    dt_ns = int(round(float(np.median(np.diff(log.imu.time_ns)))))
    t_fix = (log.fix.time_ns - epoch) * 1e-9
    gnss_dt = float(np.median(np.diff(t_fix))) if t_fix.size > 1 else 1.0
    t_s, lat, lon, hgt = _with_static_start(log, nav, t_imu, t_fix, sol,
                                            config.filter_options().alignment)
    mission0 = float(t_s[0])
    outages = tuple((float(a - mission0 + 1e-6), float(b - mission0 - 1e-6))
                    for a, b in _gaps(t_fix, 2.5))
    pos_h, pos_v = _median_sigmas(log.fix.pos_cov_ned_m2)
    vel_h, vel_v = _median_sigmas(log.vel.vel_cov_ned_m2ps2) if len(log.vel) else (0.05, 0.1)
    # receivers often report nominal sigmas far above their noise: never simulate more noise
    # than the records show about A's smoothed solution (else A cannot even align the same way)
    rp, rv = _residual_rms(log, sol, epoch)
    k = RESIDUAL_NOISE_FACTOR
    noise_p = (min(pos_h, k * rp[0]), min(pos_v, k * rp[1]))
    noise_v = (min(vel_h, k * rv[0]), min(vel_v, k * rv[1]))
    gnss = GnssModel(rate_hz=1.0 / gnss_dt, pos_noise_m=noise_p, vel_noise_mps=noise_v,
                     reported_pos_sigma_m=(pos_h, pos_v), reported_vel_sigma_mps=(vel_h, vel_v),
                     lever_arm_b_m=config.gnss.lever_arm_m,
                     outages_s=tuple(o for o in outages if o[1] > o[0] and o[1] > 0))
    if vehicle is None:
        hspan = float(np.ptp(sol.height_m))
        vehicle = "aircraft" if hspan > 30.0 else "car"
    start = epoch + int(round(t_s[0] * 1e9)) - dt_ns
    kin = kinematics(along_motion(t_s, lat, lon, hgt, vehicle=vehicle),
                     float(t_s[-1] - t_s[0]), imu_rate_hz=1e9 / dt_ns, start_time_ns=start,
                     n_sub=QUADRATURE[0], n_gl=QUADRATURE[1])
    return FlightTemplate(t_s, lat, lon, hgt, epoch, dt_ns, _gaps(t_imu, 1.5), gnss,
                          len(log.vel) > 0, vehicle, kin)


def _with_static_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                       t_imu: np.ndarray, t_fix: np.ndarray, sol: NavSolution,
                       options: AlignmentOptions):
    """A's smoothed trajectory (t [s], lat, lon [rad], height [m]) with the log's initial
    static period held at rest (2 Hz), so that the simulated flight has the same static start
    (``imu_avar_gyro_static``, step 0's static fits) whatever A did there.

    Where A covers the period (static alignment) and held the vehicle at rest there (no reset,
    its speed below ``STATIC_SPEED_MPS``), the template is A's solution as it is. Where A
    wandered, the rest position is A's at half ``STATIC_END_MARGIN_S`` before its end, held to
    there, and A's own solution after that; the static statistics leave the last
    ``STATIC_END_MARGIN_S`` out, so the spline's bend about the join stays out of them. Where
    A found one and started after it (motion alignment) it is prepended at the median of its
    fixes, held to the last GNSS velocity before A's start that is at rest by the alignment's
    test (:func:`pospp.nav.alignment.gnss_moving_windows`, each record alone), so that the
    simulator's spline joins the held position to A's first epoch over the start of motion
    only. Reasons: docs/decisions.md "compare-sim's A tuned to step 0's levels above the
    grade's; the static start held at rest"."""
    t, lat, lon, hgt = sol.t_s, sol.lat_rad, sol.lon_rad, sol.height_m
    end = nav.alignment.static_end_s
    if end is None:
        return t, lat, lon, hgt
    if end >= t[0] - 1.0:
        hold = end - 0.5 * STATIC_END_MARGIN_S
        at_rest = t <= hold
        if np.count_nonzero(at_rest) < 2 or not _wandered(nav, sol, hold):
            return t, lat, lon, hgt
        ts = np.arange(float(t_imu[0]) + 1e-3, hold, 0.5)
        keep = ~at_rest
        return (np.concatenate([ts, t[keep]]),
                *(np.concatenate([np.full(ts.size, float(np.interp(hold, t, x))), x[keep]])
                  for x in (lat, lon, hgt)))
    m = (t_fix >= t_imu[0]) & (t_fix <= end)
    if not m.any():
        return t, lat, lon, hgt
    end = max(end, _rest_end_s(log, end, float(t[0]) - 1.0, options))
    ts = np.arange(float(t_imu[0]) + 1e-3, end, 0.5)
    fix = log.fix
    pre = [np.full(ts.size, float(np.median(x[m])))
           for x in (fix.lat_rad, fix.lon_rad, fix.height_m)]
    return (np.concatenate([ts, t]), *(np.concatenate([p, x])
                                      for p, x in zip(pre, (lat, lon, hgt), strict=True)))


def _wandered(nav: nav_filter.FilterResult, sol: NavSolution, until_s: float
              ) -> bool:
    """Whether A left the rest before ``until_s`` [s]: a reset, or a smoothed speed of
    ``STATIC_SPEED_MPS`` or more."""
    if any(t_s < until_s for t_s, _ in nav.resets):
        return True
    m = sol.t_s <= until_s
    return bool(np.any(np.linalg.norm(sol.v_n_mps[m], axis=1) >= STATIC_SPEED_MPS))


def _rest_end_s(log: mcap_reader.FlightLog, end_s: float, limit_s: float,
                options: AlignmentOptions) -> float:
    """The last GNSS velocity time [s from the first IMU stamp] in (end_s, limit_s] before
    the first record that moves (``end_s`` when the first one moves or there are none)."""
    if not len(log.vel):
        return end_s
    tv = (log.vel.time_ns - int(log.imu.time_ns[0])) * 1e-9
    m = (tv > end_s) & (tv <= limit_s)
    if not m.any():
        return end_s
    order = np.argsort(tv[m], kind="stable")
    tv = tv[m][order]
    moving = gnss_moving_windows(tv, tv, tv, log.vel.v_n_mps[m][order],
                                 log.vel.vel_cov_ned_m2ps2[m][order], options)
    n_rest = int(np.argmax(moving)) if moving.any() else tv.size
    return float(tv[n_rest - 1]) if n_rest > 0 else end_s


def _residual_rms(log: mcap_reader.FlightLog, sol: NavSolution, epoch_ns: int
                  ) -> tuple[tuple[float, float], tuple[float, float]]:
    """RMS (horizontal per axis, vertical) of the GNSS records minus A's smoothed solution,
    position [m] and velocity [m/s] (inf when there are none in A's span)."""

    def rms(x: np.ndarray) -> tuple[float, float]:
        if x.shape[0] < 3:
            return np.inf, np.inf
        return float(np.sqrt(np.mean(x[:, :2] ** 2))), float(np.sqrt(np.mean(x[:, 2] ** 2)))

    (_, dp), (_, dv) = gnss_residuals(log, sol, epoch_ns, np.zeros(3))
    return rms(dp), rms(dv)


def gnss_residuals(log: mcap_reader.FlightLog, sol: NavSolution, epoch_ns: int,
                   lever_b_m: Any) -> tuple[tuple[np.ndarray, np.ndarray],
                                            tuple[np.ndarray, np.ndarray]]:
    """The GNSS records minus A's smoothed solution in its span: (times [s from
    ``epoch_ns``], (M, 3) NED [m]) of the fixes, the antenna at ``C_nb lever_b_m`` from the
    IMU, and the same [m/s] of the velocities (the lever arm's rotation share left out)."""
    from pospp import rotation

    def at(t: np.ndarray, x: np.ndarray) -> np.ndarray:
        return np.interp(t, sol.t_s, x)

    tf = (log.fix.time_ns - epoch_ns) * 1e-9
    m = (tf >= sol.t_s[0]) & (tf <= sol.t_s[-1])
    tf = tf[m]
    lat = at(tf, sol.lat_rad)
    r_m, r_n = earth.principal_radii_m(lat)
    ant = rotation.dcm_from_quat(sol.q_nb) @ np.asarray(lever_b_m, dtype=float)
    dp = np.stack([(log.fix.lat_rad[m] - lat) * r_m - at(tf, ant[:, 0]),
                   (log.fix.lon_rad[m] - at(tf, sol.lon_rad)) * r_n * np.cos(lat)
                   - at(tf, ant[:, 1]),
                   -(log.fix.height_m[m] - at(tf, sol.height_m)) - at(tf, ant[:, 2])], axis=1)
    tv = (log.vel.time_ns - epoch_ns) * 1e-9
    mv = (tv >= sol.t_s[0]) & (tv <= sol.t_s[-1])
    tv = tv[mv]
    dv = log.vel.v_n_mps[mv] - np.stack([at(tv, sol.v_n_mps[:, i]) for i in range(3)], axis=1)
    return (tf, dp), (tv, dv)


def _median_sigmas(cov: np.ndarray) -> tuple[float, float]:
    d = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))
    return float(np.median(d[:, :2])), float(np.median(d[:, 2]))


def simulate_log(tpl: FlightTemplate, imu: ImuErrorModel, gnss: GnssModel, *,
                 seed: int = SIM_SEED) -> mcap_reader.FlightLog:
    """The flight simulated along the template: its kinematics with the sensor errors of
    ``imu`` and ``gnss`` (:func:`pospp.sim.api.sensors`), the log's IMU gaps cut out and no
    velocity topic when the log has none; the IMU's first stamp is A's first epoch."""
    ims, fix, vel, _ = sensors(tpl.kinematics, imu, gnss, seed)
    ts = (ims.time_ns - tpl.epoch_ns) * 1e-9
    keep = np.ones(ts.shape, bool)
    for a, b in tpl.imu_gaps_s:
        keep &= ~((ts > a) & (ts < b))
    if not keep.all():
        cut: dict[str, Any] = {k: v[keep] for k, v in vars(ims).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == keep.shape}
        ims = replace(ims, **cut)
    if not tpl.has_velocity:
        vel = replace(vel, **{k: v[:0] for k, v in vars(vel).items()
                              if isinstance(v, np.ndarray)})
    return mcap_reader.FlightLog(ims, fix, vel, "simulation")


def bma_leg_stats(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                  config: PipelineConfig) -> dict[str, Stat]:
    """B minus A on the flight's legs, as the leg-based workflow sees them: the calibration's
    legs and B's replays over them (:func:`pospp.flight_stages.calibration_replays`), then
    :func:`pospp.diagnose.workflow.diagnose_replays` with its base model only (the
    pipeline's formulation, transition and gyro-random-walk weighting; no candidates), whose
    per-leg gaps give :func:`pospp.simcompare.stats.leg_stats`. Empty when the flight has
    fewer than ``MIN_LEGS`` legs B could replay."""
    from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays

    try:
        made = flight_stages.calibration_replays(pipeline.imu_increments(log), nav, config)
    except ValueError:
        return {}
    if len(made.replays) < MIN_LEGS:
        return {}
    replays = [made.replays[i] for i in sorted(made.replays)]
    d = diagnose_replays(replays, DiagnosisOptions(
        base_formulation=config.pairs.formulation, base_transition=config.pairs.transition,
        noise="gyro_rw", effects=(), max_steps=0,
        gyro_arw_radpsqrts=flight_stages.imu_tuning(config).noise().gyro_arw_radpsqrts))
    return leg_stats(np.array([g.gap_before_mps for g in d.legs]),
                     np.array([g.heldout_gap_before_mps for g in d.legs]))


def log_stats(log: mcap_reader.FlightLog, config: PipelineConfig, *, vehicle: str,
              nav: nav_filter.FilterResult | None = None, legs: bool = True
              ) -> tuple[FlightStats, nav_filter.FilterResult, nav_filter.FilterResult | None]:
    """Run A as configured (unless ``nav`` is given) and once more forward with lever-arm,
    scale-factor and loose accelerometer Gauss-Markov states (:data:`EST_ACCEL_GM_UG`), and
    return the flight's statistics (A's time axis: from the log's
    first IMU stamp), with B minus A on its legs where it has legs (``legs``; the draws of
    the ensemble spread go without: no leg statistic is a draw's), A, and that pass (None
    when it failed)."""
    if nav is None:
        nav = pipeline.navigate(log, config)
    est_cfg = replace(config, gnss=replace(config.gnss, estimate_lever_arm=True),
                      filter=replace(config.filter, estimate_scale_factors=True))
    opts = replace(config.filter_options(), smoother=False, gauss_markov_states=True)
    grade = flight_stages.imu_tuning(config)
    tuning = replace(grade, accel_gm_sigma_ug=max(EST_ACCEL_GM_UG, grade.accel_gm_sigma_ug),
                     accel_gm_tau_s=EST_ACCEL_GM_TAU_S,
                     gyro_sf_sigma_ppm=max(EST_SF_PRIOR_PPM[0], grade.gyro_sf_sigma_ppm),
                     accel_sf_sigma_ppm=max(EST_SF_PRIOR_PPM[1], grade.accel_sf_sigma_ppm))
    try:
        est = pipeline.navigate(log, est_cfg, options=opts, tuning=tuning)
    except ValueError:
        est = None
    epoch = int(log.imu.time_ns[0])
    t_imu = (log.imu.time_ns - epoch) * 1e-9
    fs = flight_stats(t_imu, log.imu.w_ib_b_radps, log.imu.f_ib_b_mps2, nav, est,
                      vehicle=vehicle, gnss_sigma=reported_sigmas(log, epoch))
    leg = bma_leg_stats(log, nav, config) if legs else {}
    return FlightStats({**fs.stats, **leg}, fs.hf_peak_hz), nav, est


def reported_sigmas(log: mcap_reader.FlightLog, epoch_ns: int
                    ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The records' reported NED sigmas: kind (0 position, 1 velocity) -> (times [s from
    ``epoch_ns``], (M, 3) sigmas [m, m/s])."""
    out = {}
    for kind, tab, cov in ((0, log.fix, log.fix.pos_cov_ned_m2),
                           (1, log.vel, log.vel.vel_cov_ned_m2ps2)):
        if len(tab):
            out[kind] = ((tab.time_ns - epoch_ns) * 1e-9,
                         np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None)))
    return out


def simulate_stats(tpl: FlightTemplate, config: PipelineConfig,
                   on_flight: Callable[[int], None] | None = None) -> SimulateFn:
    """simulate(imu, gnss, draw=0) -> statistics of A on the simulated flight (for
    compare_flights): draw 0 with ``SIM_SEED``, draw k with ``SIM_SEED + k``; each counted
    to ``on_flight(k)`` (k = 1, 2, ...)."""
    count = [0]

    def run(imu: ImuErrorModel, gnss: GnssModel, draw: int = 0) -> FlightStats:
        count[0] += 1
        if on_flight is not None:
            on_flight(count[0])
        fs = log_stats(simulate_log(tpl, imu, gnss, seed=SIM_SEED + draw), config,
                       vehicle=tpl.vehicle, legs=draw == 0)[0]
        # the joint estimate's expectation on a flight simulated with this offset and lever
        dl = np.subtract(gnss.lever_arm_b_m, config.gnss.lever_arm_m)
        own = {"lt_time_offset": Stat(float(gnss.time_offset_s), 0.0, np.inf),
               **{f"lt_lever_{a}": Stat(float(dl[i]), 0.0, np.inf) for i, a in enumerate("xyz")}}
        return FlightStats({**fs.stats, **own}, fs.hf_peak_hz)

    return run


def base_imu_model(config: PipelineConfig) -> ImuErrorModel:
    """The simulator's IMU model for the configured grade (SIM_GRADES maps the names)."""
    return imu_grade(SIM_GRADES.get(config.imu.grade, config.imu.grade))


def base_fit(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult, tpl: FlightTemplate,
             config: PipelineConfig) -> BaseFit:
    """Step 0: the base model fitted to the log (:func:`pospp.simcompare.base_model.
    fit_base_model`), the configured grade as its prior: the IMU's white noise and bias
    instability on its static (else steady) parts, against the error-free simulation's on
    the same parts; the GNSS noise from the residuals about A's
    smoothed solution (the configured lever arm)."""
    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    end = nav.alignment.static_end_s
    t_imu = (log.imu.time_ns - tpl.epoch_ns) * 1e-9
    meas = ImuParts(t_imu, log.imu.w_ib_b_radps, log.imu.f_ib_b_mps2,
                    *static_and_steady(t_imu, sol, end))
    tk, wk, fk = tpl.kinematic_imu()
    kin = ImuParts(tk, wk, fk, *static_and_steady(tk, sol, end))
    fix, vel = gnss_residuals(log, sol, tpl.epoch_ns, config.gnss.lever_arm_m)
    return fit_base_model(meas, kin, base_imu_model(config), tpl.gnss, fix=fix, vel=vel)


def tuned_to(config: PipelineConfig, fit: BaseFit | None, *, raise_only: bool = False
             ) -> PipelineConfig:
    """``config`` with A's white noise and drift (``[imu]`` gyro_arw_dpsh, accel_vrw_mpsph,
    gyro_gm_sigma_dph) at the base model's levels where they differ from the grade's (the
    largest axis): the joint estimate's passes of A (a pass tuned to the grade on an IMU three
    times noisier read a 0.54 m lever arm as 0.70 m, 2.5 sigma; tuned to its noise 0.60 m).
    ``raise_only``: only the levels fitted above the grade's (a filter given more noise than
    its IMU has stays consistent; given less, it trusts its inertial solution too long):
    :func:`compare_log`'s A where A as configured reset on the log."""
    if fit is None:
        return config
    by = {p.name: p for p in fit.parameters}
    over: dict[str, Any] = {}
    for key, name in (("gyro_arw_dpsh", "gyro_arw"), ("accel_vrw_mpsph", "accel_vrw"),
                      ("gyro_gm_sigma_dph", "gyro_gm_sigma")):
        rows = [by[n] for n in (name, f"{name}_x", f"{name}_y", f"{name}_z") if n in by
                and by[n].differs and (by[n].simulated > by[n].prior or not raise_only)]
        if rows:
            over[key] = max(r.simulated for r in rows)
    return replace(config, imu=replace(config.imu, **over)) if over else config


def _tuning_text(resets: int, config: PipelineConfig, tuned: PipelineConfig) -> str:
    """What :func:`compare_log` says when it re-tunes A from ``config`` to ``tuned``."""
    levels = ", ".join(f"{k} {getattr(tuned.imu, k):.4g}" for k in
                       ("gyro_arw_dpsh", "accel_vrw_mpsph", "gyro_gm_sigma_dph")
                       if getattr(tuned.imu, k) != getattr(config.imu, k))
    return (f"A reset {resets} times as configured, on a gyro drift above the Earth rate's "
            f"horizontal part: A, the template and step 0 made again, and every simulated "
            f"flight run, with A tuned to the fitted {levels} ([imu] keys)")


def compare_log(log: mcap_reader.FlightLog, config: PipelineConfig, *,
                nav: nav_filter.FilterResult | None = None, vehicle: str | None = None,
                imu: ImuErrorModel | None = None, gnss: GnssModel | None = None,
                max_steps: int = 4, library: tuple[SimEffect, ...] = LIBRARY,
                progress: Callable[[str], None] | None = None,
                on_flight: Callable[[int], None] | None = None
                ) -> tuple[Comparison, FlightTemplate]:
    """The whole comparison for one log (numeric; no files); ``library``: the effects
    (default :data:`pospp.simcompare.effects.LIBRARY`). The base model is step 0's fit
    (:func:`base_fit`) unless ``imu`` or ``gnss`` is given (then those, the configured
    grade's or the template's for the other). ``progress(line)`` is told each step,
    ``on_flight(k)`` each simulated flight."""
    say = progress or (lambda line: None)
    if nav is None:
        nav = pipeline.navigate(log, config)
    say("simulating the trajectory (kinematics)")
    tpl = flight_template(log, nav, config, vehicle=vehicle)
    fit: BaseFit | None = None
    tuned, a_tuning = config, ""
    if imu is None and gnss is None:
        fit = base_fit(log, nav, tpl, config)
        if nav.resets and not gyrocompass_resolves(fit, nav.alignment.lat_rad):
            tuned = tuned_to(config, fit, raise_only=True)
        if tuned != config:
            # A as configured diverged on this log (it reset) on a gyro whose fitted drift
            # cannot resolve the Earth rate: A, the template and step 0 again with A tuned
            # to the fitted levels; the simulated flights run that A too
            a_tuning = _tuning_text(len(nav.resets), config, tuned)
            say(a_tuning)
            nav = pipeline.navigate(log, tuned)
            tpl = flight_template(log, nav, config, vehicle=vehicle)
            fit = base_fit(log, nav, tpl, config)
        imu, gnss = fit.imu, fit.gnss
        for prm in fit.parameters:
            if prm.differs:
                say(f"base model: {prm.text()}")
    imu = base_imu_model(config) if imu is None else imu
    gnss = tpl.gnss if gnss is None else gnss
    say("statistics of the measured flight")
    measured, _, est = log_stats(log, tuned, vehicle=tpl.vehicle, nav=nav)
    # the joint estimate of the lever arm and the GNSS time offset on the measured log (its
    # passes start from the lever arm of A's pass with lever-arm states): its offset is a
    # statistic (lt_time_offset), its reading the fit of lever_arm_time_offset
    say("joint estimate of the lever arm and the GNSS time offset")
    lt = lever_time_estimate(log, nav, tuned_to(config, fit),
                             None if est is None else est.lever_arm)
    if lt is not None:
        seen = pipeline.lever_arm_seen(nav)
        measured = FlightStats({**measured.stats, **joint_stats(lt, seen)}, measured.hf_peak_hz)
    ctx = EffectContext(hf_peak_hz=measured.hf_peak_hz, lever_time=lambda: lt)
    drift = fit is not None and has_drift(fit)
    comp = compare_flights(measured, simulate_stats(tpl, tuned, on_flight), imu, gnss,
                           max_steps=max_steps, library=library, context=ctx, progress=say,
                           base_ensemble=BASE_DRAW if drift else ())
    return replace(comp, base_fit=fit.parameters if fit else (), a_tuning=a_tuning), tpl


@locked("pospp compare-sim")
def compare_sim_run(run_dir: str | Path, *, out: str | Path | None = None,
                    max_steps: int = 4, library: tuple[SimEffect, ...] = LIBRARY,
                    force: bool = False,
                    progress: Callable[[str], None] | None = None,
                    on_flight: Callable[[int], None] | None = None) -> Comparison:
    """``pospp compare-sim RUN_DIR``: write sim_comparison.parquet and sim_model.toml.

    ``out`` is the model file (default RUN_DIR/sim_model.toml; never the run's input or
    another file of a run folder, an existing one only with ``force``:
    :func:`pospp.io.run_folder.check_output_file`). The report is re-rendered. The run
    folder's lock is held throughout. ``progress(line)`` is told each step, ``on_flight(k)``
    each simulated flight (:func:`compare_log`).
    """
    run, meta, path, config = pipeline.reopen_run(run_dir)
    model_file = run_folder.check_output_file(out or run / "sim_model.toml", run=run,
                                              own_names=frozenset({"sim_model.toml"}),
                                              force=force)
    say = progress or (lambda line: None)
    say(f"reading {path.name}")
    log = pipeline.ingest(path, config)
    say("algorithm A on the log")
    try:
        comp, tpl = compare_log(log, config, max_steps=max_steps, library=library,
                                progress=say, on_flight=on_flight)
    except ValueError as exc:  # e.g. a flight too short or too slow to simulate along
        raise ValueError(f"{run}: cannot compare {path.name} with its simulation: {exc}") from exc
    out_meta = {k: meta[k] for k in ("input_file", "input_sha256", "config")}
    out_meta["vehicle"] = tpl.vehicle
    parquet_tables.write_table(run / "sim_comparison.parquet", comparison_columns(comp),
                               "sim_comparison", metadata=out_meta)
    report_files.write_text(model_file, model_toml(comp.imu_model, comp.gnss_model,
                                                   header=model_header(comp, path.name, config)))
    say("writing the report")
    pipeline.report_from_tables(run)
    return comp


def model_header(comp: Comparison, name: str, config: PipelineConfig) -> str:
    """sim_model.toml's comment header: what was fitted and named, in the tables' units and
    signs, and how the file's fields relate to them (the effect ``lever_arm`` is configured
    minus true, the file's ``lever_arm_b_m`` the true one; ``time_offset`` is IMU minus GNSS
    time, the file's ``time_offset_s`` GNSS stamp minus true time: its negative)."""
    named = ", ".join(comp.effects_added) or "none"
    lines = [f"pospp compare-sim of {name}: effects added: {named}.",
             "Simulate with: pospp simulate --model THIS_FILE.toml ... ([imu]: "
             "pospp.sim.sensors.ImuErrorModel fields, [gnss]: pospp.sim.gnss.GnssModel).",
             f"Base model fitted to the log (step 0; the grade {config.imu.grade!r} as prior):"]
    lines += [f"  {b.text()}" for b in comp.base_fit if b.fitted]
    lines += [f"  {line}" for line in masked_lines(comp.masked)]
    lines += [f"  {comp.a_tuning}"] if comp.a_tuning else []
    for s in comp.steps:
        if s.effect == "unexplained":
            continue
        vals = ", ".join(f"{p} {v:+.6g} +- {e:.2g} {u}" for p, v, e, u in
                         zip(s.params, s.size, s.sigma, s.param_units(), strict=True))
        lines.append(f"step {s.step}: {s.effect}: {vals}")
    lines.append(f"Configured lever arm {list(config.gnss.lever_arm_m)} m: the effect "
                 "lever_arm (configured minus true) = configured - lever_arm_b_m; time_offset "
                 "(IMU minus GNSS time, ms) = -1000 x time_offset_s.")
    return "\n".join(lines)
