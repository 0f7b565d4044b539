"""The stages of one flight, each a function of the results of the stages before it.

Ingestion, algorithm A (with the lever-arm re-estimation the QC stage and the diagnosis share),
the calibration stage over A (legs, B replays, pairs, least squares, B re-run), and A's first
estimates the diagnosis starts from (scale factor, warm-up); B minus A's null is
:mod:`pospp.null_stage`, the diagnosis :mod:`pospp.diagnosis_stage`. :mod:`pospp.pipeline`
runs them in order and writes what they return; the names are importable from there too.
Nothing here touches files but through :mod:`pospp.io`'s reader.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pospp import rotation
from pospp.calib.bias_smoother import ForwardBiases
from pospp.calib.replay import (
    ImuRates,
    ImuSource,
    LegReplay,
    SolutionA,
    replay_legs,
)
from pospp.calib.segment import Leg, find_legs
from pospp.calib.stage import CalibrationOptions, CalibrationRun, calibrate_flight
from pospp.config import PipelineConfig
from pospp.diagnose import null_model
from pospp.diagnose.effects import ACCEL_SETTLING_S, effect_by_id
from pospp.diagnose.rerun import REFINE_FRACTION, gate_excess, warmed, warmup_fit
from pospp.io import mcap_reader
from pospp.nav import filter as nav_filter
from pospp.nav import tuning as nav_tuning
from pospp.nav.aiding import aiding_of, leg_aiding_problem
from pospp.types import FLU_TO_FRD
from pospp.units import UG_MPS2


def sensor_to_body_dcm(sensor_frame: str, mounting_rpy_deg: tuple[float, float, float]) -> Any:
    """C_bs from the logged axis convention and the extra mounting rotation.

    ``v_b = C_mount @ C_axes @ v_s``: C_axes maps the logged axes (FLU per REP-103, or FRD) to
    FRD; C_mount (roll, pitch, yaw of the sensor case in the body, z-y-x) is the residual
    mounting rotation, identity when the IMU is aligned with the body.
    """
    axes = {"flu": FLU_TO_FRD, "frd": np.eye(3)}[sensor_frame]
    return rotation.dcm_from_euler(np.radians(mounting_rpy_deg)) @ axes


def ingest(path: str | Path, config: PipelineConfig) -> mcap_reader.FlightLog:
    """Read and validate the flight log per the [input] section."""
    cfg = config.input
    return mcap_reader.read_flight_log(
        path,
        imu_topic=cfg.imu_topic,
        fix_topic=cfg.fix_topic,
        vel_topic=cfg.vel_topic,
        c_bs=sensor_to_body_dcm(cfg.sensor_frame, cfg.mounting_rpy_deg),
        max_chunk_bytes=int(cfg.max_chunk_mib * 2**20),
        events_topic=cfg.events_topic,
        window_s=(cfg.start_s, cfg.end_s),
    )


def imu_tuning(config: PipelineConfig) -> nav_tuning.ImuTuning:
    """The filter's IMU noise model: the grade preset with the [imu] overrides."""
    return config.imu.tuning()


def navigate(
    log: mcap_reader.FlightLog,
    config: PipelineConfig,
    *,
    gyro_bias_correction_b_radps: Any = None,
    lever_arm_b_m: Any = None,
    options: nav_filter.FilterOptions | None = None,
    tuning: nav_tuning.ImuTuning | None = None,
    estimate_scale_factors: bool | None = None,
    record_gains: bool = False,
    replay: nav_filter.GainReplay | None = None,
) -> nav_filter.FilterResult:
    """Algorithm A over the whole log; optionally with a calibrated gyro bias removed first.

    The correction is applied to the IMU samples (measured = true + bias, so the corrected rate
    is w - b_g), which is exactly what compensating the sensor means; the filter then runs
    unchanged. ``lever_arm_b_m`` and ``options`` replace the configured lever arm and the
    filter options (the QC stage's lever-arm re-estimation); ``tuning`` and
    ``estimate_scale_factors`` the configured IMU tuning and ``[filter]
    estimate_scale_factors`` (the diagnosis's scale-factor estimate); ``record_gains`` and
    ``replay`` as :func:`pospp.nav.filter.run_integrated_navigation` (the null realisations).
    """
    imu = log.imu
    if gyro_bias_correction_b_radps is not None:
        imu = replace(imu, w_ib_b_radps=imu.w_ib_b_radps - np.asarray(
            gyro_bias_correction_b_radps, dtype=float))
    g, f = config.gnss, config.filter
    if options is None:
        options = config.filter_options()
    if lever_arm_b_m is None:
        lever_arm_b_m = g.lever_arm_m
    return nav_filter.run_integrated_navigation(
        imu,
        log.fix,
        log.vel,
        imu_tuning(config) if tuning is None else tuning,
        epoch_ns=int(log.imu.time_ns[0]),
        lever_arm_b_m=np.asarray(lever_arm_b_m, dtype=float),
        estimate_lever_arm=g.estimate_lever_arm,
        estimate_scale_factors=f.estimate_scale_factors if estimate_scale_factors is None
        else estimate_scale_factors,
        output_rate_hz=f.output_rate_hz,
        options=options,
        record_gains=record_gains,
        replay=replay,
    )


def compensated(log: mcap_reader.FlightLog, config: PipelineConfig,
                gyro_bias_b_radps: Any) -> nav_filter.NavSolution:
    """A re-run with a calibrated gyro bias (body FRD [rad/s]) removed from its samples: its
    smoothed solution (its forward one without the smoother), the run's "compensated"
    solution. P at the forward outputs is kept only where the forward solution is the one
    returned (``FilterOptions.forward_covariance``)."""
    opts = config.filter_options()
    comp = navigate(log, config, gyro_bias_correction_b_radps=gyro_bias_b_radps,
                    options=replace(opts, forward_covariance=not opts.smoother))
    return comp.smoothed if comp.smoothed is not None else comp.forward


def rerun_options(config: PipelineConfig) -> nav_filter.FilterOptions:
    """A's options for its re-runs, whose states alone are read (the null realisations, the
    diagnosis's re-run signatures and their base, the warm-up's check): the configured ones
    with ``covariance_outputs`` False (the same states to rounding, no smoothed covariance;
    a 50 Hz re-run of flight_null_200hz in 0.18 s instead of 0.22)."""
    return replace(config.filter_options(), covariance_outputs=False)


QC_LEVER_ARM_SIGMA_M = 2.0
"""Prior sigma of the lever-arm states in the QC stage's re-estimation [m]."""
LEVER_ARM_PASSES = 3
"""At most this many forward passes of :func:`lever_arm_passes`, each from the last one's
estimate."""
LEVER_ARM_PASS_STEP_M = 0.1
"""Another pass when the estimate moved more than this from where its pass started [m]."""


ESTIMATE_STEP_S = 0.5
"""Covariance step and output interval [s] of A's passes whose last estimate alone is read
(:func:`estimate_pass`): on four flights of the independent simulator and the 1.5 h flight,
the lever arm and the gyro scale factors read within 0.07 sigma of the 0.1 s step's, their
sigmas within 0.3 % (docs/decisions.md)."""


def estimate_pass(config: PipelineConfig, **option_changes: Any
                  ) -> tuple[PipelineConfig, nav_filter.FilterOptions]:
    """(config, options) of A's passes whose last estimate alone is read (the lever-arm and
    scale-factor passes): no smoother, the covariance stepped and the states output every
    :data:`ESTIMATE_STEP_S` (or the configuration's, where coarser); ``option_changes`` to
    the options."""
    opts = config.filter_options()
    step_s = max(ESTIMATE_STEP_S, opts.propagation_interval_s)
    rate_hz = min(1.0 / ESTIMATE_STEP_S, config.filter.output_rate_hz)
    return (replace(config, filter=replace(config.filter, output_rate_hz=rate_hz)),
            replace(opts, smoother=False, propagation_interval_s=step_s, **option_changes))


def rerun_decimation(log: mcap_reader.FlightLog, rate_hz: float) -> int:
    """IMU samples summed per sample of a summed-down log (the null's, the diagnosis's
    re-runs', :func:`summed_down`'s): the largest whole factor keeping the rate at or above
    ``rate_hz`` (``[pairs] rerun_imu_rate_hz``; 0: 1, the flight's rate)."""
    t = np.asarray(log.imu.time_ns, dtype=np.int64)
    if rate_hz <= 0.0 or t.size < 2:
        return 1
    flight_hz = 1e9 / float(np.median(np.diff(t)))
    return max(1, int(flight_hz / rate_hz + 1e-6))


def summed_down(log: mcap_reader.FlightLog, config: PipelineConfig) -> mcap_reader.FlightLog:
    """The log with its IMU samples summed down to ``[pairs] rerun_imu_rate_hz``
    (:func:`rerun_decimation`, :func:`pospp.diagnose.null_model.decimate_imu`: each kept
    sample the mean over the flight's samples since the last, the increments summed exactly),
    for A's passes that read only slow quantities (the lever arm, the families' bias
    changes); the log itself at or below that rate."""
    return null_model.decimate_imu(log, rerun_decimation(log, config.pairs.rerun_imu_rate_hz))


def lever_arm_seen(nav: nav_filter.FilterResult) -> np.ndarray:
    """The lever-arm axes (FRD, (3,) bool) A's attitude history reveals
    (:func:`pospp.qc.checks.lever_arm_observable` of its smoothed attitude, else its forward
    one): :func:`lever_arm_passes`'s ``seen``."""
    from pospp.qc.checks import lever_arm_observable

    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    return lever_arm_observable(sol.rpy_rad)


def lever_arm_estimate(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                       config: PipelineConfig) -> nav_filter.LeverArmEstimate:
    """The antenna lever arm (body FRD, m) A's lever-arm passes estimate for the axes A's
    attitude history reveals: :func:`lever_arm_passes` with :func:`lever_arm_seen` of
    ``nav``. Raises ValueError when A fails."""
    return lever_arm_passes(log, lever_arm_seen(nav), config)


def lever_arm_passes(log: mcap_reader.FlightLog, seen: np.ndarray,
                     config: PipelineConfig) -> nav_filter.LeverArmEstimate:
    """The antenna lever arm (body FRD, m) estimated by forward passes of A with lever-arm
    states (no smoother; a second and third pass from the previous estimate while it moves
    by more than :data:`LEVER_ARM_PASS_STEP_M` and differs from the configured value by as
    much) and a :data:`QC_LEVER_ARM_SIGMA_M` prior
    sigma (the QC stage's, and the diagnosis's starting point for ``lever_arm``), on the log
    summed down to ``[pairs] rerun_imu_rate_hz`` (:func:`summed_down`: the lever arm is read
    from the turns, which the summed increments carry as the flight's samples do) with the
    covariance stepped every :data:`ESTIMATE_STEP_S` (:func:`estimate_pass`). The axes
    A's attitude history reveals (``seen``: :func:`lever_arm_seen`) start from
    zero, so that the configured value does not pull them; the others start from the
    configured value, where they stay instead of floating and leaking into the revealed ones
    (all from zero, a 1.5 m down lever that one banked turn cannot reveal bent the forward
    estimate by 0.3 m at 14 sigma: 2 false alarms in 100 clean flights, docs/qc.md). Raises
    ValueError when A fails."""
    rerun, opts = estimate_pass(replace(config, gnss=replace(config.gnss,
                                                             estimate_lever_arm=True)),
                                lever_arm_sigma_m=QC_LEVER_ARM_SIGMA_M)
    seen = np.asarray(seen, dtype=bool)
    configured = np.asarray(config.gnss.lever_arm_m, dtype=float)
    log = summed_down(log, config)
    start = np.where(seen, 0.0, configured)
    est = navigate(log, rerun, lever_arm_b_m=start, options=opts).lever_arm
    # A is not linear in a large lever-arm error (its gate rejects the shifted fixes, its
    # attitude Jacobian is made at the wrong lever arm): a 3 m offset read 1.78 m at 5 cm
    # sigma after one pass; restarted from that estimate it read 2.95 m, then 2.99 m
    # (docs/diagnose.md, "Power"). Passes restart from the revealed axes' estimate until
    # it moves by less than LEVER_ARM_PASS_STEP_M; none when the first pass agrees with the
    # configured lever arm (A then ran near the right one: the usual flight pays one pass).
    for _ in range(LEVER_ARM_PASSES - 1):
        nxt = np.where(seen, est.lever_b_m, configured)
        if (not np.max(np.abs(nxt - start)) > LEVER_ARM_PASS_STEP_M
                or not np.max(np.abs(nxt - configured)) > LEVER_ARM_PASS_STEP_M):
            break
        start = nxt
        est = navigate(log, rerun, lever_arm_b_m=start, options=opts).lever_arm
    return est


GYRO_SF_PRIOR_PPM = 2000.0
"""Prior sigma of the gyro scale-factor states in the diagnosis's scale-factor pass [ppm]
(twice the effect's plausible size; the grades' presets, 10 ppm for "vehicle", would hold a
600 ppm scale factor at zero)."""
GYRO_SF_SIGNIFICANCE = 3.0
"""The scale-factor pass's estimate starts a Gauss-Newton signature when an axis reads more
than this many of its sigmas."""


def scale_factor_estimate(log: mcap_reader.FlightLog, config: PipelineConfig,
                          lever_b_m: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """The gyro scale factors (body FRD, measured = (1 + s) true, dimensionless) and their
    sigmas from one forward pass of A with scale-factor states (prior
    :data:`GYRO_SF_PRIOR_PPM`, :func:`estimate_pass`), the antenna at ``lever_b_m`` (A's own
    lever-arm estimate: measured on the power flights, seeds 1-2, a 1 m lever arm the configuration
    does not know reads 360-670 ppm of scale factor on x and y at 17-39 ppm sigma with the
    configured 0, at most 21 ppm with A's estimate; a 24 ms GNSS offset -160 to -250 ppm on
    y and z, and at most 15 ppm with the estimate, which reads the offset as 1.4 m along x).
    A 600 ppm z scale factor read 574 and 605 ppm at 24 ppm sigma (docs/diagnose.md
    "Power"). Raises ValueError when A fails."""
    tuning = replace(imu_tuning(config), gyro_sf_sigma_ppm=GYRO_SF_PRIOR_PPM)
    cfg, opts = estimate_pass(config)
    nav = navigate(log, cfg, lever_arm_b_m=lever_b_m, options=opts, tuning=tuning,
                   estimate_scale_factors=True)
    b = nav.forward_biases
    return np.asarray(b.gyro_sf[-1], dtype=float), np.asarray(b.gyro_sf_sigma[-1], dtype=float)


WARMUP_PRIOR_UG = 1000.0
"""Sigma of the accelerometer Gauss-Markov states in the diagnosis's warm-up pass [ug] (ten
times the effect's plausible 100 ug; the "vehicle" preset's 5 ug at 3600 s cannot follow a
warm-up: A's smoothed bias then reads 600 ug as a constant 285 ug, docs/diagnose.md)."""
WARMUP_START_UG = 200.0
"""The warm-up pass's estimate starts a Gauss-Newton signature above this norm [ug] (twice the
plausible size; the warm-up mission's null flights read at most 110 ug): :func:`warmup_start`."""


def warmup_estimate(log: mcap_reader.FlightLog, config: PipelineConfig, lever_b_m: Any = None,
                    settling_s: float = ACCEL_SETTLING_S) -> np.ndarray:
    """The accelerometer warm-up ``db`` (body FRD x, y, m/s^2) of ``b_inf + db exp(-t / T)``
    (t from the first IMU stamp, T = ``settling_s``): one pass of A, smoother on, whose
    accelerometer Gauss-Markov states have the warm-up's dynamics (``b' = -b / T``, sigma
    :data:`WARMUP_PRIOR_UG`), antenna at ``lever_b_m``, its smoothed bias fitted
    (:func:`pospp.diagnose.rerun.warmup_fit`). Warm-up mission, seeds 1-10: 600 ug read
    483-682, 1800 ug 1669-1868, none -110 to 89 ug (x). Raises ValueError when A fails."""
    tuning = replace(imu_tuning(config), accel_gm_sigma_ug=WARMUP_PRIOR_UG,
                     accel_gm_tau_s=settling_s)
    opts = replace(config.filter_options(), smoother=True, gauss_markov_states=True)
    nav = navigate(log, config, lever_arm_b_m=lever_b_m, options=opts, tuning=tuning)
    b = nav.smoothed_biases
    assert b is not None  # the smoother ran
    return warmup_fit(b.t_s, b.accel_b_mps2, nav.alignment.t_s, settling_s)


def static_alignment_window(nav: nav_filter.FilterResult, options: Any
                            ) -> tuple[float, float] | None:
    """The period (t0, t1] [s, A's time axis] whose means A's static alignment used (None:
    it aligned in motion), as :func:`pospp.nav.alignment.align` takes it (``options``: A's
    filter options)."""
    al = nav.alignment
    if al.method != "static" or al.static_end_s is None:
        return None
    return al.t_s, min(al.static_end_s, al.t_s + options.alignment.max_static_alignment_s)


def imu_increments(log: mcap_reader.FlightLog) -> ImuRates:
    """The log's IMU for B on the run's time axis (t_s from the first IMU stamp): its rates,
    whose increments are made a leg at a time (:class:`pospp.calib.replay.ImuRates`)."""
    return ImuRates.from_rates(log.imu.time_ns, log.imu.w_ib_b_radps, log.imu.f_ib_b_mps2,
                               epoch_ns=int(log.imu.time_ns[0]))


@dataclass(frozen=True)
class LegReplays:
    """A's reference solution, the legs found on it and B's replays over them
    (:func:`calibration_replays`): what the calibration's fit and the null's base share."""

    solution_a: SolutionA
    legs: tuple[Leg, ...]
    replays: dict[int, LegReplay]
    """By leg id, the legs whose replay did not fail."""
    failed: tuple[str, ...]
    """A message per leg whose replay failed or that was refused."""
    refused: dict[int, str] = field(default_factory=dict)
    """By leg id, the legs not replayed because A is not GNSS-aided over them, with why
    (:func:`pospp.nav.aiding.leg_aiding_problem`)."""


def calibration_replays(imu: ImuSource, nav: nav_filter.FilterResult, config: PipelineConfig,
                        threads: int = 1) -> LegReplays:
    """The calibration's legs (:func:`pospp.calib.segment.find_legs` on A's ``[replay]
    reference`` solution) and B's replays over them
    (:func:`pospp.calib.replay.replay_legs`, ``threads`` legs at once). A leg over which A is
    not GNSS-aided (:func:`pospp.nav.aiding.leg_aiding_problem`) is refused, not replayed:
    B minus a free-inertial A is not B's error."""
    which = nav_filter.reference_name(nav, config.replay.reference)
    solution_a = SolutionA(*nav_filter.solution_a_fields(nav, which=which))
    traj = solution_a.trajectory
    legs = tuple(find_legs(traj.t_s, traj.v_n_mps, traj.height_m,
                           thresholds=config.legs.thresholds()))
    aid = aiding_of(nav)
    refused = {g.leg_id: why for g in legs if (why := leg_aiding_problem(
        aid, g.start_s, g.end_s, traj.t_s, solution_a.v_sigma_n_mps)) is not None}
    replays, failed = replay_legs(imu, solution_a, tuple(g for g in legs
                                                         if g.leg_id not in refused),
                                  config.replay.options(), threads)
    return LegReplays(solution_a, legs, replays,
                      tuple(f"leg {i} refused: {why}" for i, why in refused.items()) + failed,
                      refused)


def calibrate_from_a(imu: ImuSource, nav: nav_filter.FilterResult,
                     config: PipelineConfig, made: LegReplays | None = None,
                     threads: int = 1) -> tuple[CalibrationRun, SolutionA]:
    """Legs, B replays, pairs, least squares and B re-run (pospp.calib.stage); ``made``: the
    legs and replays of :func:`calibration_replays`, made before (None: made here);
    ``threads``: B's replays made that many legs at once."""
    made = calibration_replays(imu, nav, config, threads) if made is None else made
    solution_a = made.solution_a
    tuning = imu_tuning(config)
    gm = bool(np.isfinite(tuning.gyro_gm_tau_s) and tuning.gyro_gm_sigma_dph > 0)
    mode = config.compensation.mode
    options = CalibrationOptions(
        legs_cfg=config.legs.thresholds(), replay_cfg=config.replay.options(),
        pairs_cfg=config.pairs.policy(), gyro_arw_dpsh=tuning.gyro_arw_dpsh,
        noise=config.pairs.noise, noise_step_s=config.pairs.noise_step_s,
        estimate_gyro_z=config.pairs.estimate_gyro_z,
        compensation=mode if gm or mode != "per_leg" else "constant",
        # the grade's Gauss-Markov ("random") drift enters the least squares' noise model;
        # its level and correlation time are the flight's own (REML on the joint fit, tau
        # profiled), the grade's a weak prior (solve.DriftPrior)
        gyro_gm_sigma_dph=None,
        gyro_gm_tau_s=tuning.gyro_gm_tau_s if gm else None,
        gyro_gm_prior_sigma_dph=tuning.gyro_gm_sigma_dph if gm else None)
    return calibrate_flight(imu, solution_a, options, legs=made.legs,
                            made_replays=(made.replays, made.failed), threads=threads,
                            leg_refusals=made.refused,
                            forward_biases=forward_bias_record(nav, tuning)), solution_a


def forward_bias_record(nav: nav_filter.FilterResult, tuning: nav_tuning.ImuTuning
                        ) -> ForwardBiases:
    """What the smoothed compensation reads of A (:meth:`ForwardBiases.of_filter`)."""
    return ForwardBiases.of_filter(nav, tuning.noise().gyro_bias_psd_radps2ps)


def lever_arm_and_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                         config: PipelineConfig,
                         est: nav_filter.LeverArmEstimate | None = None
                         ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(A's lever-arm estimate, body FRD m, configured minus it: the diagnosis's ``dl``), each
    None when A estimates the lever arm itself or the extra pass fails. ``est``: the estimate
    already made (:func:`lever_arm_estimate`); None: made here."""
    if config.gnss.estimate_lever_arm:
        return None, None
    if est is None:
        try:
            est = lever_arm_estimate(log, nav, config)
        except ValueError:
            return None, None
    return est.lever_b_m, np.asarray(config.gnss.lever_arm_m, dtype=float) - est.lever_b_m


def scale_factor_start(log: mcap_reader.FlightLog, config: PipelineConfig,
                        lever_b_m: np.ndarray | None) -> np.ndarray | None:
    """A's gyro scale-factor estimate (:func:`scale_factor_estimate`) when an axis of it is
    significant (:data:`GYRO_SF_SIGNIFICANCE`) and its norm above the refinement's bar, else
    None (also when A estimates scale factors itself, or the pass fails)."""
    if config.filter.estimate_scale_factors:
        return None
    try:
        sf, sigma = scale_factor_estimate(log, config, lever_b_m)
    except ValueError:
        return None
    if (not np.any(np.abs(sf) > GYRO_SF_SIGNIFICANCE * sigma)
            or not np.linalg.norm(sf) > REFINE_FRACTION
            * effect_by_id("gyro_scale_factor").plausible_si):
        return None
    return sf


def warmup_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                  config: PipelineConfig, lever_b_m: np.ndarray | None) -> np.ndarray | None:
    """A's warm-up estimate (:func:`warmup_estimate`) when it explains A's rejections: A as
    configured gated more GNSS records than its model allows (:func:`gate_excess`; else no
    pass), the estimate exceeds :data:`WARMUP_START_UG`, and A re-run without it gates no
    more than its model allows; else None (also when A fails). The pass alone is no evidence
    (250 ug on the power flights with nothing hidden; docs/diagnose.md, "Power")."""
    gate_p = config.filter_options().gate_probability
    if not gate_excess(nav, gate_p):
        return None
    try:
        db = warmup_estimate(log, config, lever_b_m)
        if not np.linalg.norm(db) > WARMUP_START_UG * UG_MPS2:
            return None
        explained = not gate_excess(navigate(warmed(log, -db, ACCEL_SETTLING_S), config,
                                              options=rerun_options(config)), gate_p)
    except ValueError:
        return None
    return db if explained else None
