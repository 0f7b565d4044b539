"""The diagnosis stage of one flight: the model-discrepancy workflow over a calibrated run.

:func:`diagnose_calibration` runs :func:`pospp.diagnose.workflow.diagnose_replays` on the run's
B-minus-A replays with every test calibrated on B minus A's null realisations, the first
signatures A's linear response where its gate was open (:mod:`pospp.diagnose.
linear_signatures`) and A re-runs elsewhere (:mod:`pospp.diagnose.rerun`: Gauss-Newton from
A's own estimates, secant refinements), and the drift under the alternative. No file I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from functools import cache, partial
from typing import Any

import numpy as np

from pospp.calib.compensate import (
    COMPENSATION_MODES,
    ModeChoice,
    ModeInputs,
    compensate_legs,
    joint_calibration,
)
from pospp.calib.linear_null import LinearNull
from pospp.calib.replay import ImuSource, SolutionA
from pospp.calib.solve import DriftPrior
from pospp.calib.stage import CalibrationRun
from pospp.config import PipelineConfig
from pospp.diagnose import null_model
from pospp.diagnose._candidates import leg_origins, shaped
from pospp.diagnose.alternative import (
    LIBRARY_ALTERNATIVES,
    library_fits,
    named_removed,
    null_note,
    removed_names,
    start_removed,
    with_library,
)
from pospp.diagnose.effects import ACCEL_SETTLING_S, effect_by_id, signature
from pospp.diagnose.refit import Refit, refit_calibration
from pospp.diagnose.rerun import (
    PIPELINE_RERUN,
    REFINE_FRACTION,
    REFINE_ITERATIONS,
    Jacobians,
    first_estimates,
    gate_excess,
    refine_signatures,
    rerun_signatures,
    signature_at,
    warmed,
)
from pospp.diagnose.results import Diagnosis, EffectResponse
from pospp.diagnose.workflow import HELDOUT_WHITENED, DiagnosisOptions, diagnose_replays
from pospp.flight_stages import (
    compensated,
    forward_bias_record,
    imu_tuning,
    lever_arm_and_start,
    navigate,
    rerun_decimation,
    rerun_options,
    scale_factor_start,
    warmup_start,
)
from pospp.io import mcap_reader
from pospp.nav import filter as nav_filter
from pospp.null_stage import (
    leg_epochs_ns,
    linear_effect_signatures,
    linear_null_model,
    null_drift,
    null_needs_gains,
    null_noise,
    null_realisations,
    rerun_b_minus_a,
)
from pospp.qc.check_record import Check
from pospp.qc.checks import model_fit
from pospp.qc.lever_time import LeverTime
from pospp.sensor_stage import SensorFamilies, sensor_families, with_sensor_families
from pospp.units import DEG_PER_H_RADPS
from pospp.units import G0_MPS2 as GRAVITY_MPS2

LEVER_START_SIGMAS = 3.0
"""Where A's gate is open, the lever arm's Gauss-Newton starts from A's estimate only when an
axis of it is this many of its sigmas from the configured one (else A's linear response at the
configuration, which its second-order terms do not move at that size)."""

def rerun_base(log: mcap_reader.FlightLog | None, nav: nav_filter.FilterResult | None,
               calib_run: CalibrationRun, config: PipelineConfig
               ) -> tuple[mcap_reader.FlightLog | None, CalibrationRun,
                          nav_filter.GainReplay | None]:
    """The log and calibration run the diagnosis's A re-run signatures are made against.

    The log of :func:`rerun_log` (summed down to ``[pairs] rerun_imu_rate_hz``) and the run
    with its replays' B minus A replaced by that log's own (A run on it as configured): a
    re-run's response is then B minus A at the lower rate less B minus A at the lower rate,
    the strapdown's rate-dependent error cancelling as in the null realisations
    (docs/diagnose.md, "The null at a lower IMU rate"). The log and run themselves when
    nothing is summed, A gated in excess (a step flips borderline gate decisions: the
    signatures are not smooth in it at any rate), A or B fails on the summed-down log, or B
    there is not on the flight's samples (or without a log); A and B as the null
    realisations run them (:func:`pospp.null_stage.rerun_b_minus_a`). The third element: A's
    gains on the summed-down log, which the re-runs replay (:class:`pospp.nav.filter.
    GainReplay`; a re-run whose records differ, the time offset's, runs in full); None with
    the flight's own log."""
    if log is None or nav is None:
        return log, calib_run, None
    log_r = rerun_log(log, nav, calib_run, config)
    if log_r is log:
        return log, calib_run, None
    try:
        dv, gains = rerun_b_minus_a(log_r, nav, calib_run.legs, calib_run.replays, config,
                                    record=True)
    except ValueError:
        return log, calib_run, None
    by_id = dict(zip(sorted(calib_run.replays), dv, strict=True))
    replays = {i: replace(rep, dv_n_mps=by_id[i]) for i, rep in calib_run.replays.items()}
    if any(replays[i].dv_n_mps.shape != rep.dv_n_mps.shape
           for i, rep in calib_run.replays.items()):  # B not on the flight's samples
        return log, calib_run, None
    return log_r, replace(calib_run, replays=replays), gains


def rerun_log(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
              calib_run: CalibrationRun, config: PipelineConfig) -> mcap_reader.FlightLog:
    """The log the diagnosis re-runs A on (:func:`rerun_base`): its IMU summed down to
    ``[pairs] rerun_imu_rate_hz`` keeping the legs' epochs, or the log itself where nothing
    is summed or A gated in excess."""
    factor = rerun_decimation(log, config.pairs.rerun_imu_rate_hz)
    if factor == 1 or gate_excess(nav, config.filter_options().gate_probability):
        return log
    return null_model.decimate_imu(log, factor, leg_epochs_ns(log, calib_run.legs))


def drift_under_alternative(calib_run: CalibrationRun, replays_minus_effect: list,
                            config: PipelineConfig) -> tuple[float, float] | None:
    """The flight's gyro drift re-estimated with a candidate effect in the model, or None.

    The calibration reads the drift by REML on B minus A under the base model; an effect the
    base model leaves out is then read as drift, the null realisations inject it, and the
    effect's test loses its power (docs/diagnose.md, "Power"). Here the same REML (the grade's
    drift the same weak prior, the joint fit over the same pairs) runs on
    ``replays_minus_effect`` (B minus A with the candidate's fitted response removed,
    ``LegReplay`` in leg-id order). Returns (sigma [rad/s], tau [s]) only when the flight
    rejected the grade's drift under the base model (``drift_source`` "flight") as too small
    (the flight's sigma above the grade's) and with the effect removed either no longer does
    (the grade's drift; also when the re-estimate falls below it) or reads a smaller drift
    than before, still above the grade's. None otherwise (the null stays the base model's).
    """
    tuning = imu_tuning(config)
    grade_radps = tuning.gyro_gm_sigma_dph * DEG_PER_H_RADPS
    # no excess drift for an effect to explain when the flight is quieter than the grade
    # (flight_null_200hz: 0.045 deg/h for 0.5 would otherwise get the grade's larger drift)
    if (calib_run.chosen is None or calib_run.drift_source != "flight"
            or not np.isfinite(tuning.gyro_gm_tau_s) or not grade_radps > 0
            or not calib_run.drift_sigma_radps > grade_radps):
        return None
    fit = replace(calib_run.fit_options, gyro_gm_sigma_radps=None, gyro_gm_tau_s=None,
                  gm_prior=DriftPrior(grade_radps, float(tuning.gyro_gm_tau_s)))
    reps = {r.leg.leg_id: r for r in replays_minus_effect}
    try:
        cal = joint_calibration(reps, calib_run.pairs, calib_run.chosen.formulation, fit,
                                **calib_run.fit_bases)
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


def signature_starts(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                     config: PipelineConfig,
                     lever_estimate: nav_filter.LeverArmEstimate | None
                     ) -> dict[str, np.ndarray | None]:
    """A's own first estimates the diagnosis's Gauss-Newton signatures start from (None: the
    signature at the configuration): effect id -> estimate.

    The lever arm: from A's own estimate of it (lever-arm states) when it is far enough from
    the configured value (:data:`pospp.diagnose.rerun.REFINE_FRACTION`), where A's gate and
    attitude Jacobian are those of the wrong lever arm. The gyro scale factor: A's own
    estimate (one forward pass with scale-factor states) only when it is significant. The
    warm-up: A's pass with its dynamics where it explains A's rejections
    (:func:`warmup_start`). The usual flight pays the scale-factor pass (docs/diagnose.md,
    "Power")."""
    lever_b_m, p_lever = lever_arm_and_start(log, nav, config, lever_estimate)
    gn = p_lever is not None and bool(
        np.linalg.norm(p_lever) > REFINE_FRACTION * effect_by_id("lever_arm").plausible_si)
    return {"lever_arm": p_lever if gn else None,
            "gyro_scale_factor": scale_factor_start(log, config, lever_b_m),
            "accel_bias_change": warmup_start(log, nav, config, lever_b_m)}


def _rerun_signatures_at_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                               calib_run: CalibrationRun, config: PipelineConfig,
                               starts: dict[str, np.ndarray | None],
                               navigate_a: Any, threads: int = 1,
                               rerun: tuple[Any, CalibrationRun] | None = None,
                               jacobians: Jacobians | None = None,
                               made: Mapping[str, list[np.ndarray]] | None = None
                               ) -> tuple[dict[str, list[np.ndarray]], dict[str, np.ndarray]]:
    """The diagnosis's first A re-run signatures and the estimates they were made at
    (``jacobians``: their local derivatives, added in place: :func:`signature_at`).

    The re-runs are made on ``rerun`` = (log, run) of :func:`rerun_base` (the flight's own
    when None); ``starts``: :func:`signature_starts`. An effect with a start: Gauss-Newton
    from it (the lever arm: 1 + 1 A runs and 3 replays of the second's gains; the scale
    factor: the secant along it, 1 A run; the warm-up: 1 A run and 2 replays); else at the
    configuration (the lever arm and the time offset: 1 A run each, the warm-up 2) unless
    ``made`` holds it (A's linear response: :func:`pospp.null_stage.linear_effect_signatures`);
    the gyro scale factor without a start keeps the library's signature."""
    log_r, run_r = (log, calib_run) if rerun is None else rerun
    sigs = {**(made or {}), **rerun_signatures(
        log_r, nav, run_r, config, [e for e in PIPELINE_RERUN if e != "gyro_scale_factor"
                                    and starts.get(e) is None and e not in (made or {})],
        navigate=navigate_a, threads=threads)}
    at: dict[str, np.ndarray] = {}
    for eid, p in starts.items():
        if p is None:
            continue
        try:
            sigs[eid] = signature_at(log_r, nav, run_r, config, eid, p, navigate=navigate_a,
                                     threads=threads, jacobians=jacobians)
            at[eid] = p
        except (ValueError, np.linalg.LinAlgError):  # A failed at the estimate
            if eid != "gyro_scale_factor":
                sigs.update(rerun_signatures(log_r, nav, run_r, config, (eid,),
                                             navigate=navigate_a, threads=threads))
    return sigs, at


def _null_without_warmup(log: mcap_reader.FlightLog | None, nav: nav_filter.FilterResult | None,
                         db: np.ndarray | None, calib_run: CalibrationRun,
                         config: PipelineConfig, null_dv: list | None, threads: int
                         ) -> tuple[Any, Any, list | None, str, PipelineConfig]:
    """(log, A, null realisations, note, the configuration they were made with) of the
    diagnosis's null: when A's warm-up estimate
    ``db`` (body x, y, m/s^2) explains A's rejections (:func:`warmup_start`), re-made on the
    log without it (with it, A diverged in them: 1800 ug; docs/diagnose.md "Power")."""
    if not null_dv or log is None or db is None:
        return log, nav, null_dv, "", config
    log_w = warmed(log, -db, ACCEL_SETTLING_S)
    nav_w = navigate(log_w, config, record_gains=null_needs_gains(config))
    cfg_w = config if nav is None else _flights_null_kind(log, nav, calib_run, config)
    return (log_w, nav_w, null_realisations(log_w, nav_w, calib_run, cfg_w, len(null_dv),
                                            threads=threads),
            "; made on the log with A's warm-up estimate removed", cfg_w)


def _flights_null_kind(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                       calib_run: CalibrationRun, config: PipelineConfig) -> PipelineConfig:
    """``config``, with ``[pairs] null_reruns`` set when the flight's own null is A re-runs
    (the linear null refuses the flight: :func:`pospp.null_stage.linear_null_model`): the null
    of the log without A's warm-up estimate is made as the flight's, though its A may converge
    where the flight's did not (docs/decisions.md, "The null of the log without the
    warm-up")."""
    if config.pairs.null_reruns:
        return config
    try:
        linear_null_model(log, nav, calib_run, config, null_noise(log, nav, calib_run, config))
    except ValueError:
        return replace(config, pairs=replace(config.pairs, null_reruns=True))
    return config


@dataclass(frozen=True)
class DiagnosisStart:
    """The diagnosis's A re-runs that do not need the null (:func:`diagnosis_reruns`)."""

    base: Callable[[], tuple[Any, CalibrationRun, Any]]
    """The re-runs' base, made when first asked (:func:`rerun_base`): the log they are made on
    (summed down, or the flight's), the run with its replays' B minus A on it, and A as
    configured for them (with that log's gains when it has them)."""
    sigs: dict[str, list[np.ndarray]] | None
    """The first re-run signatures (None without the log and A)."""
    at: dict[str, np.ndarray]
    """The estimates the Gauss-Newton signatures were made at."""
    jacobians: Jacobians
    """Their local derivatives (:func:`pospp.diagnose.rerun.signature_at`), which the
    refinements near the same estimates take instead of re-making."""


def diagnosis_reruns(calib_run: CalibrationRun, config: PipelineConfig, *,
                     log: mcap_reader.FlightLog | None = None,
                     nav: nav_filter.FilterResult | None = None,
                     lever_estimate: nav_filter.LeverArmEstimate | None = None,
                     threads: int = 1, null_model: LinearNull | None = None) -> DiagnosisStart:
    """The diagnosis's base for its re-runs (:func:`rerun_base`) and its first re-run
    signatures (:func:`_rerun_signatures_at_start`) from A's first estimates
    (:func:`signature_starts`, its passes on the re-runs' log: the gyro scale factor is a
    low-frequency error, which the summed-down samples carry as the flight's do). Where A's
    gate was open, the lever arm's, the time offset's and the warm-up's signatures at the
    configuration are A's linear response (:func:`pospp.null_stage.linear_effect_signatures`)
    and the base is made only when a re-run needs it."""
    @cache
    def base() -> tuple[Any, CalibrationRun, Any]:
        log_r, run_r, gains = rerun_base(log, nav, calib_run, config)
        return log_r, run_r, partial(navigate, config=config, options=rerun_options(config),
                                     replay=gains)

    sigs: dict[str, list[np.ndarray]] | None = None
    at: dict[str, np.ndarray] = {}
    jacobians: Jacobians = {}
    if log is not None and nav is not None:
        # lever arm, gyro scale factor, warm-up: Gauss-Newton from A's own estimates
        starts = signature_starts(rerun_log(log, nav, calib_run, config), nav, config,
                                  lever_estimate)
        # A's gate open: A's linear response at the configuration; the lever arm's
        # Gauss-Newton only from an estimate A's own sigmas tell from the configured one
        linear = linear_effect_signatures(log, nav, calib_run, config, null_model)
        p_lever = starts.get("lever_arm")
        if p_lever is not None and linear and lever_estimate is not None and not np.any(
                np.abs(p_lever) > LEVER_START_SIGMAS * lever_estimate.sigma_b_m):
            starts = {**starts, "lever_arm": None}
        sigs = {e: s for e, s in linear.items() if starts.get(e) is None}
        if any(p is not None for p in starts.values()) or any(
                e not in sigs for e in PIPELINE_RERUN if e != "gyro_scale_factor"):
            log_r, run_r, a_run = base()
            sigs, at = _rerun_signatures_at_start(log, nav, calib_run, config, starts, a_run,
                                                  threads, (log_r, run_r), jacobians, sigs)
    return DiagnosisStart(base, sigs, at, jacobians)


def diagnose_calibration(calib_run: CalibrationRun, imu: ImuSource, solution_a: SolutionA,
             config: PipelineConfig, *, log: mcap_reader.FlightLog | None = None,
             nav: nav_filter.FilterResult | None = None,
             null_dv: list[list[np.ndarray]] | None = None,
             null_model: LinearNull | None = None,
             lever_estimate: nav_filter.LeverArmEstimate | None = None,
             threads: int = 1,
             joint: Callable[[], LeverTime | None] | None = None) -> Diagnosis:
    """Model-discrepancy workflow on the calibrated run's B-minus-A curves (pospp.diagnose).

    Every test's null distribution is calibrated on ``null_dv`` (:func:`null_realisations`)
    when given, else on ``[pairs] null_realisations`` realisations made here when the log and
    A's result are given (seed 0: a run is reproducible). ``threads``: A re-runs made at once
    (:func:`pospp.threads.map_in_threads`; the result does not depend on it). ``null_model``:
    the null stage's linear system (:class:`pospp.null_stage.NullResult`), which the first
    signatures share (None: made here where they are A's linear response).

    With the log, the sensor families (accelerometer and gyro bias changes over flight time,
    :mod:`pospp.sensor_stage`) are then fitted on A's innovations with the named GNSS-side
    effects removed, and named as steps before the closing row. Every named effect's response
    on B minus A is in ``Diagnosis.responses`` (the calibration's refit,
    :mod:`pospp.diagnose.refit`). A GNSS time offset the families' innovations read is the
    joint lever-arm / time-offset estimate's (``joint()``, the QC stage's, made when first
    asked; None: their own reading, :func:`pospp.sensor_stage._without_time_offset`).
    """
    n_null = config.pairs.null_realisations
    if null_dv is None and n_null > 0 and log is not None and nav is not None:
        null_dv = null_realisations(log, nav, calib_run, config, n_null, threads=threads)
    replays = [calib_run.replays[i] for i in sorted(calib_run.replays)]
    d, sigs = _diagnose_legs(calib_run, imu, solution_a, config, replays, log=log, nav=nav,
                             null_dv=null_dv, lever_estimate=lever_estimate, threads=threads,
                             null_model=null_model)
    fams = (sensor_families(d, replays, log, config, solution_a, joint, nav, threads)
            if log is not None else None)
    d = with_sensor_families(d, fams)
    return replace(d, responses=named_responses(d, replays, sigs, fams, solution_a))


def _diagnose_legs(calib_run: CalibrationRun, imu: ImuSource, solution_a: SolutionA,
                   config: PipelineConfig, replays: list, *,
                   log: mcap_reader.FlightLog | None, nav: nav_filter.FilterResult | None,
                   null_dv: list[list[np.ndarray]] | None,
                   lever_estimate: nav_filter.LeverArmEstimate | None, threads: int,
                   null_model: LinearNull | None = None
                   ) -> tuple[Diagnosis, dict[str, list[np.ndarray]] | None]:
    """:func:`diagnose_calibration` on the legs (B minus A): the diagnosis and the A re-run
    signatures it named its re-run effects with (None without the log)."""
    start = diagnosis_reruns(calib_run, config, log=log, nav=nav,
                             lever_estimate=lever_estimate, threads=threads,
                             null_model=null_model)
    sigs, at, jacobians = start.sigs, dict(start.at), dict(start.jacobians)
    null_log, null_nav, null_dv, warm_note, null_cfg = _null_without_warmup(
        log, nav, at.get("accel_bias_change"), calib_run, config, null_dv, threads)
    # B's residuals carry the gyro angle random walk, correlated along each leg: weighting them
    # as white noise would make every F-test too liberal
    arw_radpsqrts = imu_tuning(config).noise().gyro_arw_radpsqrts
    def diagnose_with(signatures, whitening_replays=None):
        opts = DiagnosisOptions(
            replay_kwargs={"accel_compensation": config.replay.accel_compensation},
            base_formulation=config.pairs.formulation, base_transition=config.pairs.transition,
            noise="gyro_rw", gyro_arw_radpsqrts=arw_radpsqrts,
            alpha=config.pairs.diagnose_alpha, heldout_whitened=ho_white)
        return diagnose_replays(replays, opts, imu=imu, solution_a=solution_a, null_dv=null_dv,
                                signatures=signatures, whitening_replays=whitening_replays,
                                threads=threads)

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
        estimates = first_estimates(d, config.pairs.diagnose_alpha)
        if not estimates:
            break
        log_r, run_r, a_run = start.base()
        refined, at = refine_signatures(log_r, nav, run_r, config, sigs, estimates, at,
                                        navigate=a_run, threads=threads, jacobians=jacobians)
        if all(refined[k] is sigs[k] for k in sigs):
            break
        d, sigs = diagnose_with(refined, white), refined
    removed = named_removed(replays, d, sigs) if sigs else None
    # the drift under the alternative: when the effect (re-run effects named; a vertical
    # drift or a gravity gradient, diagnose.alternative.with_library) explains the excess
    # drift the flight showed, the null realisations inject the drift the flight shows with
    # it removed
    alt = with_library(replays, removed, d, candidate=True) if sigs else None
    if alt is None:
        return replace(d, null_model=note), sigs
    drift = (drift_under_alternative(calib_run, alt, config)
             if null_dv and log is not None and nav is not None else None)
    rebuilt: tuple[str, ...] = ()
    if drift is not None:
        assert null_log is not None and null_nav is not None and sigs is not None and null_dv
        null_dv = null_realisations(null_log, null_nav, calib_run, null_cfg, len(null_dv),
                                    drift=drift, threads=threads)
        d, d_base = diagnose_with(sigs, white), d
        if removed is None and not set(LIBRARY_ALTERNATIVES) & set(d.named):
            return replace(d_base, null_model=note), sigs  # the library effect: not borne out
        rebuilt = tuple(removed_names(d_base, sigs, list(library_fits(d_base, candidate=True))))
        note = null_note(null_dv, *drift, f"re-estimated with {' + '.join(rebuilt)} removed",
                         base=null_drift(calib_run, config)) + warm_note
        removed = named_removed(replays, d, sigs)
    removed = with_library(replays, removed, d, candidate=False)  # whitened under it too
    if removed is None:
        return replace(d, null_model=note, null_rebuilt_with=rebuilt), sigs
    # the whitening under the model named: a pass whose whitening drops an effect it was
    # estimated under is not self-consistent, and the first stands (measured: a 3 m lever arm)
    d2 = diagnose_with(sigs, removed)
    return replace(d2 if set(d.named) <= set(d2.named) else d, null_model=note,
                   null_rebuilt_with=rebuilt), sigs


def named_responses(d: Diagnosis, replays: list, sigs: dict[str, list[np.ndarray]] | None,
                    fams: SensorFamilies | None, solution_a: SolutionA | None = None
                    ) -> tuple[EffectResponse, ...]:
    """What each effect ``d`` named does to B minus A (legs in id order): a sensor family's
    along B per shape coefficient (:func:`pospp.sensor_stage.family_response`), a re-run
    effect's A re-run signature (``sigs``), a library effect's signature along B; the
    estimate and its covariance (the legs' effects: their sigmas, independent). An effect
    whose signature cannot be made here is left out (the refit then says which it used)."""
    out = []
    origins, extent = leg_origins(replays, solution_a)
    for e in d.named:
        if fams is not None and e in fams.responses:
            out.append(fams.responses[e])
            continue
        step = d.step_of(e)
        eff = shaped(effect_by_id(e), step.shape)
        p = np.asarray(step.values, dtype=float) * eff.si_per_unit
        try:
            cols = sigs[e] if sigs and e in sigs else [
                signature(e, r, shape=step.shape or None,
                          origin_n_m=None if origins is None else origins[k], extent_m=extent)
                for k, r in enumerate(replays)]
        except ValueError:  # a signature that needs what is not here (the Earth-rate's)
            continue
        if any(np.shape(c)[2] != p.size for c in cols):
            continue
        out.append(EffectResponse(e, tuple(np.asarray(c, float) for c in cols), p,
                                  np.diag((np.asarray(step.sigmas, dtype=float)
                                           * eff.si_per_unit) ** 2)))
    return tuple(out)


def refit_stage(calib_run: CalibrationRun, diagnosis: Diagnosis | None, imu: ImuSource,
                solution_a: SolutionA, config: PipelineConfig, threads: int = 1,
                nav: nav_filter.FilterResult | None = None) -> Refit | None:
    """The calibration refitted with the effects the diagnosis named
    (:func:`pospp.diagnose.refit.refit_calibration`) and B re-run with it on every leg (the
    compensation's replays and improvements, as the calibration stage makes them, in
    ``[compensation] mode`` with the refit's fit; the modes reading A's forward bias
    estimates need ``nav``, else the refit's constant): what the run compensates with when an
    effect outside the calibration's model was named. None when nothing was named or the
    refit fails."""
    if diagnosis is None or not diagnosis.responses or not calib_run.calibrated:
        return None
    refit = refit_calibration(calib_run, diagnosis.responses)
    if refit is None or refit.run.chosen is None:
        return None
    rc = config.replay
    replays = dict(calib_run.replays)
    mode = ModeChoice({}, "constant")
    if nav is not None and calib_run.compensation_source != "constant":
        tuning = imu_tuning(config)
        gm = bool(np.isfinite(tuning.gyro_gm_tau_s) and tuning.gyro_gm_sigma_dph > 0)
        name = str(config.compensation.mode)
        mode = COMPENSATION_MODES[name if gm or name != "per_leg" else "constant"](ModeInputs(
            imu, solution_a, replays, refit.run.chosen, refit.sigma_b_radps, rc.options(),
            forward_bias_record(nav, tuning), threads=threads))
    after, improvements = compensate_legs(imu, solution_a, replays, refit.run.chosen,
                                          replay=rc.options(), threads=threads, **mode.kwargs)
    return replace(refit, run=replace(refit.run, replays_after=after, improvements=improvements,
                                      compensation_source=mode.source))


def _bias_text(b_radps: np.ndarray, sigma_radps: np.ndarray | None = None) -> str:
    """'(0.391 +- 0.023, -0.299 +- 0.017) deg/h' of the x and y body gyro bias."""
    b = np.asarray(b_radps)[:2] / DEG_PER_H_RADPS
    if sigma_radps is None:
        return "(" + ", ".join(f"{v:+.3g}" for v in b) + ") deg/h"
    s = np.asarray(sigma_radps)[:2] / DEG_PER_H_RADPS
    return "(" + ", ".join(f"{v:.3g} +- {e:.2g}" for v, e in zip(b, s, strict=True)) + ") deg/h"


def refit_shift_sigmas(refit: Refit) -> float:
    """The refit's largest change of the horizontal gyro bias, in the calibration's sigmas
    (an axis of infinite sigma counts 0)."""
    r = np.abs(refit.change_b_radps[:2]) / refit.base_sigma_b_radps[:2]
    return float(np.max(np.where(np.isfinite(r), r, 0.0)))


def model_fit_check(diagnosis: Diagnosis, refit: Refit | None, calib_run: CalibrationRun,
                    config: PipelineConfig) -> Check:
    """The QC check ``model_fit`` of a diagnosed run (:func:`pospp.qc.checks.model_fit`): the
    effects named outside the calibration's model with the refit's change of the gyro bias,
    and the unexplained gap with the gyro bias it could stand for."""
    named = [s for s in diagnosis.steps if s.effect in diagnosis.named]
    texts = []
    for s in named:
        shape = f"{s.shape}, " if s.shape else ""
        texts.append(f"{s.effect} ({shape}{s.value:.3g} +- {s.sigma:.2g} "
                     f"{s.unit.replace('_per_', '/')}) is not in the calibration's model")
    if refit is not None:
        texts.append(f"refitted with {', '.join(refit.effects)} removed, the gyro bias moves by "
                     f"{_bias_text(refit.change_b_radps)} "
                     f"({refit_shift_sigmas(refit):.2g} sigma) from "
                     f"{_bias_text(refit.base_bias_b_radps, refit.base_sigma_b_radps)} to "
                     f"{_bias_text(refit.bias_b_radps, refit.sigma_b_radps)}, which the "
                     "compensation uses")
    last = diagnosis.steps[-1]
    sigma = calib_run.gyro_bias_sigma_b_radps[:2]
    sigma_max = float(np.max(sigma)) if np.all(np.isfinite(sigma)) else float("inf")
    t = last.horizon_s
    bound = (2.0 * last.gap_horizon_mps / (GRAVITY_MPS2 * t**2)
             if last.effect == "unexplained" and t > 0 else float("nan"))
    gap_text = (f"an unexplained gap (p = {last.p_value:.2g}) worth "
                f"{1e3 * last.gap_horizon_mps:.3g} mm/s at the {t:.0f} s horizon: the calibrated "
                f"gyro bias may be biased by up to {bound / DEG_PER_H_RADPS:.2g} deg/h (the bias "
                f"that would make it), {bound / sigma_max:.2g} times its 1-sigma")
    shift = float("nan") if refit is None else refit_shift_sigmas(refit)
    return model_fit([s.effect for s in named], shift,
                     last.p_value if last.effect == "unexplained" else float("nan"),
                     diagnosis.alpha, bound, sigma_max, texts, gap_text)


@dataclass(frozen=True)
class RefitOutcome:
    """What the run takes from the refit (:func:`refit_and_check`)."""

    refit: Refit | None
    solutions: dict[str, Any]
    """``{"compensated": A re-run with the refit's gyro bias}`` when it was made, else {}."""
    checks: tuple[Check, ...]
    """``(model_fit,)`` when a diagnosis ran, else ()."""

    def tables(self, epoch_ns: int) -> dict[str, Any]:
        """The refit's ``leg_errors`` table (B after the compensation with it), or {}."""
        if self.refit is None:
            return {}
        return {"leg_errors": self.refit.run.tables(epoch_ns)["leg_errors"]}


def refit_and_check(log: mcap_reader.FlightLog, calib_run: CalibrationRun,
                    diagnosis: Diagnosis | None, imu: ImuSource, solution_a: SolutionA,
                    config: PipelineConfig, threads: int = 1, *, compensate: bool = True,
                    nav: nav_filter.FilterResult | None = None) -> RefitOutcome:
    """The run's refit stage after its diagnosis: the calibration refitted with the named
    effects (:func:`refit_stage`), A re-run with the refit's gyro bias removed when
    ``compensate`` (the compensated solution then uses the refit), and the ``model_fit``
    check (:func:`model_fit_check`); ``nav``: A's result, for the legs' compensation in the
    configured mode (:func:`refit_stage`)."""
    if diagnosis is None:
        return RefitOutcome(None, {}, ())
    refit = refit_stage(calib_run, diagnosis, imu, solution_a, config, threads, nav)
    sols: dict[str, Any] = {}
    if refit is not None and compensate:
        sols["compensated"] = compensated(log, config, refit.bias_b_radps)
    return RefitOutcome(refit, sols, (model_fit_check(diagnosis, refit, calib_run, config),))
