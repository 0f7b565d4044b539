"""The stages of one flight, each a function of the results of the stages before it.

Ingestion, algorithm A (with the lever-arm re-estimation the QC stage and the diagnosis share),
the calibration stage over A (legs, B replays, pairs, least squares, B re-run), B minus A's null
realisations, and the model-discrepancy diagnosis with its A re-runs. :mod:`pospp.pipeline`
runs them in order and writes what they return; the names are importable from there too.
Nothing here touches files but through :mod:`pospp.io`'s reader.
"""

from __future__ import annotations

import itertools
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from pospp import rotation
from pospp.calib.compensate import joint_calibration
from pospp.calib.replay import ImuIncrements, SolutionA, replay_leg
from pospp.calib.solve import DriftPrior
from pospp.calib.stage import CalibrationRun, calibrate_flight
from pospp.config import PipelineConfig
from pospp.diagnose import null_model
from pospp.diagnose.alternative import (
    named_removed,
    null_note,
    removed_names,
    start_removed,
    with_vertical,
)
from pospp.diagnose.effects import ACCEL_SETTLING_S, effect_by_id
from pospp.diagnose.rerun import (
    PIPELINE_RERUN,
    REFINE_FRACTION,
    REFINE_ITERATIONS,
    first_estimates,
    gate_excess,
    refine_signatures,
    rerun_signatures,
    signature_at,
    warmed,
    warmup_fit,
)
from pospp.diagnose.workflow import HELDOUT_WHITENED, Diagnosis, diagnose_replays
from pospp.io import mcap_reader
from pospp.nav import filter as nav_filter
from pospp.nav import tuning as nav_tuning
from pospp.nav.strapdown import increments_from_rates
from pospp.threads import map_in_threads
from pospp.types import FLU_TO_FRD
from pospp.units import DEG_PER_H_RADPS, UG_MPS2


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
) -> nav_filter.FilterResult:
    """Algorithm A over the whole log; optionally with a calibrated gyro bias removed first.

    The correction is applied to the IMU samples (measured = true + bias, so the corrected rate
    is w - b_g), which is exactly what compensating the sensor means; the filter then runs
    unchanged. ``lever_arm_b_m`` and ``options`` replace the configured lever arm and the
    filter options (the QC stage's lever-arm re-estimation); ``tuning`` and
    ``estimate_scale_factors`` the configured IMU tuning and ``[filter]
    estimate_scale_factors`` (the diagnosis's scale-factor estimate).
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
    )


QC_LEVER_ARM_SIGMA_M = 2.0
"""Prior sigma of the lever-arm states in the QC stage's re-estimation [m]."""
LEVER_ARM_PASSES = 3
"""At most this many forward passes of :func:`lever_arm_estimate`, each from the last one's
estimate."""
LEVER_ARM_PASS_STEP_M = 0.1
"""Another pass when the estimate moved more than this from where its pass started [m]."""


def lever_arm_estimate(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                       config: PipelineConfig) -> nav_filter.LeverArmEstimate:
    """The antenna lever arm (body FRD, m) estimated by forward passes of A with lever-arm
    states (no smoother; a second and third pass from the previous estimate while it moves
    by more than :data:`LEVER_ARM_PASS_STEP_M` and differs from the configured value by as
    much) and a :data:`QC_LEVER_ARM_SIGMA_M` prior
    sigma (the QC stage's, and the diagnosis's starting point for ``lever_arm``). The axes
    A's attitude history reveals (:func:`pospp.qc.checks.lever_arm_observable`) start from
    zero, so that the configured value does not pull them; the others start from the
    configured value, where they stay instead of floating and leaking into the revealed ones
    (all from zero, a 1.5 m down lever that one banked turn cannot reveal bent the forward
    estimate by 0.3 m at 14 sigma: 2 false alarms in 100 clean flights, docs/qc.md). Raises
    ValueError when A fails."""
    from pospp.qc.checks import lever_arm_observable

    rerun = replace(config, gnss=replace(config.gnss, estimate_lever_arm=True))
    opts = replace(config.filter_options(), smoother=False,
                   lever_arm_sigma_m=QC_LEVER_ARM_SIGMA_M)
    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    seen = lever_arm_observable(sol.rpy_rad)
    configured = np.asarray(config.gnss.lever_arm_m, dtype=float)
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
    :data:`GYRO_SF_PRIOR_PPM`, no smoother), the antenna at ``lever_b_m`` (A's own lever-arm
    estimate: measured on the power flights, seeds 1-2, a 1 m lever arm the configuration
    does not know reads 360-670 ppm of scale factor on x and y at 17-39 ppm sigma with the
    configured 0, at most 21 ppm with A's estimate; a 24 ms GNSS offset -160 to -250 ppm on
    y and z, and at most 15 ppm with the estimate, which reads the offset as 1.4 m along x).
    A 600 ppm z scale factor read 574 and 605 ppm at 24 ppm sigma (docs/diagnose.md
    "Power"). Raises ValueError when A fails."""
    tuning = replace(imu_tuning(config), gyro_sf_sigma_ppm=GYRO_SF_PRIOR_PPM)
    opts = replace(config.filter_options(), smoother=False)
    nav = navigate(log, config, lever_arm_b_m=lever_b_m, options=opts, tuning=tuning,
                   estimate_scale_factors=True)
    b = nav.forward_biases
    return np.asarray(b.gyro_sf[-1], dtype=float), np.asarray(b.gyro_sf_sigma[-1], dtype=float)


WARMUP_PRIOR_UG = 1000.0
"""Sigma of the accelerometer Gauss-Markov states in the diagnosis's warm-up pass [ug] (ten
times the effect's plausible 100 ug; the "vehicle" preset's 5 ug at 3600 s cannot follow a
warm-up: A's smoothed bias then reads 600 ug as a constant 285 ug, docs/diagnose.md)."""
WARMUP_START_UG = 200.0
"""The warm-up pass's estimate starts a Gauss-Newton signature above this norm [ug] (twice the
plausible size; the warm-up mission's null flights read at most 110 ug): :func:`_warmup_start`."""


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


def imu_increments(log: mcap_reader.FlightLog) -> ImuIncrements:
    """The log's IMU as increments on the run's time axis (t_s from the first IMU stamp)."""
    t_s, dth, dv = increments_from_rates(log.imu.time_ns, log.imu.w_ib_b_radps,
                                         log.imu.f_ib_b_mps2, epoch_ns=int(log.imu.time_ns[0]))
    return ImuIncrements(t_s, dth, dv)


def calibrate_from_a(imu: ImuIncrements, nav: nav_filter.FilterResult,
              config: PipelineConfig) -> tuple[CalibrationRun, SolutionA]:
    """Legs, B replays, pairs, least squares and B re-run (pospp.calib.stage)."""
    which = config.replay.reference if nav.smoothed is not None else "forward"
    solution_a = SolutionA(*nav_filter.solution_a_fields(nav, which=which))
    tuning = imu_tuning(config)
    gm = bool(np.isfinite(tuning.gyro_gm_tau_s) and tuning.gyro_gm_sigma_dph > 0)
    return calibrate_flight(
        imu, solution_a, legs_cfg=config.legs.thresholds(), replay_cfg=config.replay.options(),
        pairs_cfg=config.pairs.policy(), gyro_arw_dpsh=tuning.gyro_arw_dpsh,
        noise=config.pairs.noise, noise_step_s=config.pairs.noise_step_s,
        estimate_gyro_z=config.pairs.estimate_gyro_z,
        compensation=config.compensation.mode if gm or config.compensation.mode == "causal"
        else "constant",
        forward_biases=nav.forward_biases,
        # the grade's Gauss-Markov ("random") drift enters the least squares' noise model;
        # its level and correlation time are the flight's own (REML on the joint fit, tau
        # profiled), the grade's a weak prior (solve.DriftPrior; issue 16, item 3)
        gyro_gm_sigma_dph=None,
        gyro_gm_tau_s=tuning.gyro_gm_tau_s if gm else None,
        gyro_gm_prior_sigma_dph=tuning.gyro_gm_sigma_dph if gm else None,
    ), solution_a


def null_drift(calib_run: CalibrationRun, config: PipelineConfig) -> tuple[float, float, str]:
    """The gyro drift the null realisations inject: (sigma [rad/s], tau [s], source).

    The drift the flight shows (its level and tau by REML, the grade a weak prior: issue 16
    item 3; source "flight", or "grade" when the flight does not reject the grade's), so the
    calibration's and the diagnosis's sigmas follow the flight; the configured ``[imu]
    gyro_gm_sigma_dph`` / ``gyro_gm_tau_s`` (source "configured") when the calibration did not
    estimate it.
    """
    if calib_run.drift_source in ("flight", "grade"):
        return calib_run.drift_sigma_radps, calib_run.drift_tau_s, calib_run.drift_source
    si = imu_tuning(config).noise()
    return si.gyro_gm_sigma_radps, si.gyro_gm_tau_s, "configured"


def null_realisations(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                      calib_run: CalibrationRun, config: PipelineConfig, n: int, *,
                      seed: int = 0, drift: tuple[float, float] | None = None,
                      threads: int = 1) -> list[list[np.ndarray]]:
    """B minus A's null realisations along this flight (pospp.diagnose.null_model).

    Each: the log with IMU noise (white: ``[pairs] null_imu_noise`` "measured", the
    density read from the samples, or "grade", the configured ARW / VRW; plus the
    Gauss-Markov gyro drift of :func:`null_drift`; and the configured
    accelerometer bias drift ``accel_gm_sigma_ug`` / ``accel_gm_tau_s``) and GNSS noise
    at the level of the flight's GNSS minus A (:func:`null_model.gnss_noise_from_residuals`),
    added to the base from A's alignment point on; A re-run exactly as configured, B replayed
    on the same legs (same start and end times), minus the base's own B minus A. The base is
    the flight with its GNSS replaced by A's solution at the antenna
    (:func:`pospp.diagnose.null_model.gnss_on_solution`). Returns ``n`` lists of (M, 3)
    arrays, legs in id order (fewer when A fails on more than ``n`` of ``2 n`` perturbed
    logs). ``drift``: (sigma [rad/s], tau [s]) of the gyro drift to inject instead
    (:func:`drift_under_alternative`). ``threads``: realisations made at once
    (:func:`pospp.threads.map_in_threads`); the perturbed logs are drawn in the same order
    from the same generator, so the result does not depend on it.
    """
    si = imu_tuning(config).noise()
    gm_sigma, gm_tau, _ = null_drift(calib_run, config) if drift is None else (*drift, "")
    if config.pairs.null_imu_noise == "grade":
        arw, vrw = si.gyro_arw_radpsqrts, si.accel_vrw_mpspsqrts
    else:
        arw, vrw = null_model.imu_white_noise_from_samples(
            log.imu.time_ns, log.imu.w_ib_b_radps, log.imu.f_ib_b_mps2)
    ids = sorted(calib_run.replays)
    legs = {leg.leg_id: leg for leg in calib_run.legs}
    rc = config.replay
    which = rc.reference if nav.smoothed is not None else "forward"

    def b_minus_a(log_r: mcap_reader.FlightLog) -> list[np.ndarray]:
        nav_r = navigate(log_r, config)
        ref_r = SolutionA(*nav_filter.solution_a_fields(nav_r, which=which))
        imu_r = imu_increments(log_r)
        return [replay_leg(imu_r, ref_r, legs[i],
                           accel_compensation=rc.accel_compensation,
                           sample_rate_hz=rc.sample_rate_hz, sigma_floor_mps=rc.sigma_floor_mps,
                           transition_step=int(rc.transition_step)).dv_n_mps for i in ids]

    # the base: the flight with its GNSS replaced by A's solution at the antenna
    # (null_model.gnss_on_solution: noise on top of the flight's own GNSS noise is not linear)
    solution = nav.smoothed if which == "smoothed" and nav.smoothed is not None else nav.forward
    base = null_model.gnss_on_solution(log, solution, int(log.imu.time_ns[0]),
                                       nav.lever_arm.lever_b_m)
    pos_sig, vel_sig = null_model.gnss_noise_from_residuals(log, base)
    noise = null_model.NullNoise(
        gyro_arw_radpsqrts=float(arw), accel_vrw_mpspsqrts=float(vrw),
        gyro_gm_sigma_radps=float(gm_sigma), gyro_gm_tau_s=float(gm_tau),
        accel_gm_sigma_mps2=float(si.accel_gm_sigma_mps2), accel_gm_tau_s=float(si.accel_gm_tau_s),
        pos_sigma_ned_m=pos_sig, vel_sigma_ned_mps=vel_sig)
    base_dv = b_minus_a(base)
    t_align_ns = int(log.imu.time_ns[0]) + round(nav.alignment.t_s * 1e9)
    rng = np.random.default_rng(seed)

    def attempt(log_r: mcap_reader.FlightLog) -> list[np.ndarray] | None:
        try:
            return b_minus_a(log_r)
        except ValueError:  # a realisation whose A fails (alignment) is skipped
            return None

    perturbed = (null_model.perturb_log(base, noise, rng, from_time_ns=t_align_ns)
                 for _ in range(2 * n))
    out: list[list[np.ndarray]] = []
    while len(out) < n:
        # never more logs drawn than realisations still missing: the draws, and so the
        # realisations, are those of one log at a time
        batch = list(itertools.islice(perturbed, min(max(threads, 1), n - len(out))))
        if not batch:
            break
        for dv in map_in_threads(attempt, batch, threads):
            if dv is not None:
                out.append([d - d0 for d, d0 in zip(dv, base_dv, strict=True)])
    return out


def drift_under_alternative(calib_run: CalibrationRun, replays_minus_effect: list,
                            config: PipelineConfig) -> tuple[float, float] | None:
    """The flight's gyro drift re-estimated with a candidate effect in the model, or None.

    The calibration reads the drift by REML on B minus A under the base model (issue 16 item
    3); an effect the base model leaves out (a 12 ms GNSS offset: 0.28 deg/h at 100 s against
    the grade's 0.05) is then read as drift, the null realisations inject it, and the
    effect's test loses its power (docs/diagnose.md, "Power"). Here the same REML (the grade's
    drift the same weak prior, the joint fit over the same pairs) runs on
    ``replays_minus_effect`` (B minus A with the candidate's fitted response removed,
    ``LegReplay`` in leg-id order). Returns (sigma [rad/s], tau [s]) only when the flight
    rejected the grade's drift under the base model (``drift_source`` "flight") as too small
    (the flight's sigma above the grade's) and with the effect removed either no longer does
    (the grade's drift; also when the re-estimate falls below it) or reads a smaller drift
    than before, still above the grade's (that one: three 600 s legs read 0.071 deg/h of
    drift for the grade's 0.05 with nothing hidden, 0.44 with a 1.1 deg/h vertical drift).
    None otherwise (the null stays the base model's).
    """
    tuning = imu_tuning(config)
    grade_radps = tuning.gyro_gm_sigma_dph * DEG_PER_H_RADPS
    # no excess drift for an effect to explain when the flight is quieter than the grade
    # (flight_null_200hz: 0.045 deg/h for 0.5 would otherwise get the grade's larger drift)
    if (calib_run.chosen is None or calib_run.drift_source != "flight"
            or not np.isfinite(tuning.gyro_gm_tau_s) or not grade_radps > 0
            or not calib_run.drift_sigma_radps > grade_radps):
        return None
    kw = dict(calib_run.solve_kwargs)
    transition = kw.pop("transition", calib_run.chosen.transition)
    kw.update(gyro_gm_sigma_radps=None, gyro_gm_tau_s=None,
              gm_prior=DriftPrior(grade_radps, float(tuning.gyro_gm_tau_s)))
    reps = {r.leg.leg_id: r for r in replays_minus_effect}
    try:
        cal = joint_calibration(reps, calib_run.pairs, calib_run.chosen.formulation,
                                transition=transition, **kw)
    except (ValueError, np.linalg.LinAlgError):
        return None
    if cal is None:
        return None
    if cal.gm_source == "grade":
        return float(cal.gyro_gm_sigma_radps), float(cal.gyro_gm_tau_s)
    if cal.gm_source == "flight" and cal.gyro_gm_sigma_radps <= grade_radps:
        return grade_radps, float(tuning.gyro_gm_tau_s)  # not below the grade's
    if cal.gm_source == "flight" and cal.gyro_gm_sigma_radps < calib_run.drift_sigma_radps:
        # less excess drift with the effect removed, still above the grade's (600 s legs)
        return float(cal.gyro_gm_sigma_radps), float(cal.gyro_gm_tau_s)
    return None


def _lever_arm_and_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
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


def _scale_factor_start(log: mcap_reader.FlightLog, config: PipelineConfig,
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


def _warmup_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
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
        explained = not gate_excess(navigate(warmed(log, -db, ACCEL_SETTLING_S), config), gate_p)
    except ValueError:
        return None
    return db if explained else None


def _rerun_signatures_at_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                               calib_run: CalibrationRun, config: PipelineConfig,
                               lever_estimate: nav_filter.LeverArmEstimate | None,
                               navigate_a: Any, threads: int = 1
                               ) -> tuple[dict[str, list[np.ndarray]], dict[str, np.ndarray]]:
    """The diagnosis's first A re-run signatures and the estimates they were made at.

    The lever arm: Gauss-Newton from A's own estimate of it (lever-arm states; 1 + 4 A runs)
    instead of at the configured value, where A's gate and attitude Jacobian are those of the
    wrong lever arm. The time offset: at the configuration (1 A run). The gyro scale factor:
    Gauss-Newton from A's own estimate (one forward pass with scale-factor states) only when
    that is significant (the secant along it: 1 A run); else the library's signature. The
    warm-up: Gauss-Newton from A's pass with its dynamics where it explains A's rejections
    (:func:`_warmup_start`: 3 A runs), else at the configuration (2 A runs). The usual flight
    pays the scale-factor pass (docs/diagnose.md, "Power")."""
    lever_b_m, p_lever = _lever_arm_and_start(log, nav, config, lever_estimate)
    gn = p_lever is not None and bool(
        np.linalg.norm(p_lever) > REFINE_FRACTION * effect_by_id("lever_arm").plausible_si)
    starts = {"lever_arm": p_lever if gn else None,
              "gyro_scale_factor": _scale_factor_start(log, config, lever_b_m),
              "accel_bias_change": _warmup_start(log, nav, config, lever_b_m)}
    sigs = rerun_signatures(log, nav, calib_run, config,
                            [e for e in PIPELINE_RERUN if e != "gyro_scale_factor"
                             and starts.get(e) is None], navigate=navigate_a,
                            threads=threads)
    at: dict[str, np.ndarray] = {}
    for eid, p in starts.items():
        if p is None:
            continue
        try:
            sigs[eid] = signature_at(log, nav, calib_run, config, eid, p, navigate=navigate_a,
                                     threads=threads)
            at[eid] = p
        except (ValueError, np.linalg.LinAlgError):  # A failed at the estimate
            if eid != "gyro_scale_factor":
                sigs.update(rerun_signatures(log, nav, calib_run, config, (eid,),
                                             navigate=navigate_a, threads=threads))
    return sigs, at


def _null_without_warmup(log: mcap_reader.FlightLog | None, nav: nav_filter.FilterResult | None,
                         db: np.ndarray | None, calib_run: CalibrationRun,
                         config: PipelineConfig, null_dv: list | None, threads: int
                         ) -> tuple[Any, Any, list | None, str]:
    """(log, A, null realisations, note) of the diagnosis's null: when A's warm-up estimate
    ``db`` (body x, y, m/s^2) explains A's rejections (:func:`_warmup_start`), re-made on the
    log without it (with it, A diverged in them: 1800 ug; docs/diagnose.md "Power")."""
    if not null_dv or log is None or db is None:
        return log, nav, null_dv, ""
    log_w = warmed(log, -db, ACCEL_SETTLING_S)
    nav_w = navigate(log_w, config)
    return (log_w, nav_w, null_realisations(log_w, nav_w, calib_run, config, len(null_dv),
                                            threads=threads),
            "; made on the log with A's warm-up estimate removed")


def diagnose_calibration(calib_run: CalibrationRun, imu: ImuIncrements, solution_a: SolutionA,
             config: PipelineConfig, *, log: mcap_reader.FlightLog | None = None,
             nav: nav_filter.FilterResult | None = None,
             null_dv: list[list[np.ndarray]] | None = None,
             lever_estimate: nav_filter.LeverArmEstimate | None = None,
             threads: int = 1) -> Diagnosis:
    """Model-discrepancy workflow on the calibrated run's B-minus-A curves (pospp.diagnose).

    Every test's null distribution is calibrated on ``null_dv`` (:func:`null_realisations`)
    when given, else on ``[pairs] null_realisations`` realisations made here when the log and
    A's result are given (seed 0: a run is reproducible). ``threads``: A re-runs made at once
    (:func:`pospp.threads.map_in_threads`; the result does not depend on it).
    """
    n_null = config.pairs.null_realisations
    if null_dv is None and n_null > 0 and log is not None and nav is not None:
        null_dv = null_realisations(log, nav, calib_run, config, n_null, threads=threads)
    replays = [calib_run.replays[i] for i in sorted(calib_run.replays)]
    # PIPELINE_RERUN: A's own response to them, by re-running A (issue 12)
    a_as_configured = partial(navigate, config=config)

    sigs: dict[str, list[np.ndarray]] | None = None
    at: dict[str, np.ndarray] = {}
    if log is not None and nav is not None:
        # lever arm, gyro scale factor, warm-up: Gauss-Newton from A's own estimates
        sigs, at = _rerun_signatures_at_start(log, nav, calib_run, config, lever_estimate,
                                              a_as_configured, threads)
    null_log, null_nav, null_dv, warm_note = _null_without_warmup(
        log, nav, at.get("accel_bias_change"), calib_run, config, null_dv, threads)
    # B's residuals carry the gyro angle random walk, correlated along each leg: weighting them
    # as white noise would make every F-test too liberal
    arw_radpsqrts = imu_tuning(config).noise().gyro_arw_radpsqrts
    def diagnose_with(signatures, whitening_replays=None):
        return diagnose_replays(
            replays, imu=imu, solution_a=solution_a,
            replay_kwargs={"accel_compensation": config.replay.accel_compensation},
            base_formulation=config.pairs.formulation, base_transition=config.pairs.transition,
            noise="gyro_rw", gyro_arw_radpsqrts=arw_radpsqrts, null_dv=null_dv,
            alpha=config.pairs.diagnose_alpha, signatures=signatures,
            whitening_replays=whitening_replays, heldout_whitened=ho_white)

    note = null_note(null_dv, *null_drift(calib_run, config)) + warm_note

    # A's warm-up pass started its signature: the whitening under it while it is named, its
    # held-out in noise units as the vertical drift's (the pass: evidence it is present)
    white = start_removed(replays, sigs, at, "accel_bias_change") if sigs else None
    ho_white = (*HELDOUT_WHITENED, *(("accel_bias_change",) if white is not None else ()))
    d = diagnose_with(sigs, white)
    if white is not None and "accel_bias_change" not in d.named:
        white, d = None, diagnose_with(sigs)
    for _ in range(REFINE_ITERATIONS if sigs else 0):
        assert sigs is not None  # the loop runs only with signatures
        # A is not linear in a GNSS-side effect: secants through the current estimates
        refined, at = refine_signatures(log, nav, calib_run, config, sigs,
                                        first_estimates(d, config.pairs.diagnose_alpha), at,
                                        navigate=a_as_configured, threads=threads)
        if all(refined[k] is sigs[k] for k in sigs):
            break
        d, sigs = diagnose_with(refined, white), refined
    removed = named_removed(replays, d, sigs) if sigs else None
    # the drift under the alternative: when the effect (re-run effects named; a vertical
    # drift, diagnose.alternative.with_vertical) explains the excess drift the flight
    # showed, the null realisations inject the drift the flight shows with it removed
    alt = with_vertical(replays, removed, d, candidate=True) if sigs else None
    if alt is None:
        return replace(d, null_model=note)
    drift = (drift_under_alternative(calib_run, alt, config)
             if null_dv and log is not None and nav is not None else None)
    if drift is not None:
        assert null_log is not None and null_nav is not None and sigs is not None and null_dv
        null_dv = null_realisations(null_log, null_nav, calib_run, config, len(null_dv),
                                    drift=drift, threads=threads)
        d, d_base = diagnose_with(sigs, white), d
        if removed is None and "vertical_gyro_drift" not in d.named:
            return replace(d_base, null_model=note)  # the vertical drift is not borne out
        gone = " + ".join(removed_names(d_base, sigs, alt is not removed))
        note = null_note(null_dv, *drift, f"re-estimated with {gone} removed",
                         base=null_drift(calib_run, config)) + warm_note
        removed = named_removed(replays, d, sigs)
    removed = with_vertical(replays, removed, d, candidate=False)  # whitened under it too
    if removed is None:
        return replace(d, null_model=note)
    # the whitening under the model named: a pass whose whitening drops an effect it was
    # estimated under is not self-consistent, and the first stands (measured: a 3 m lever arm)
    d2 = diagnose_with(sigs, removed)
    return replace(d2 if set(d.named) <= set(d2.named) else d, null_model=note)
