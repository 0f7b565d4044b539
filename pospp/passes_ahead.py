"""A's passes of one flight that need neither the null realisations nor each other's stage,
and the QC checks, made ahead on a second lane (issue 18).

With more than one thread, :mod:`pospp.pipeline` gives a run a second lane (one worker
thread) and puts on it, in this order: A's lever-arm pass and the diagnosis's scale-factor
start (:func:`passes_on_log`: they need the log and the lever-arm axes A will reveal, guessed
from the GNSS track, so they run alongside A; made again by :func:`passes_on_a` when A's
attitude reveals other axes), the diagnosis's other signature starts (:func:`passes_on_a`:
they need A only, so they run alongside the calibration), then
the compensated A and the diagnosis's first re-runs (:func:`passes_ahead`: they need the
calibration, not the null, so they run alongside the null realisations), then the QC checks
(:func:`checks_ahead`: they need the calibration with its null covariance and the lever-arm
estimate, not the diagnosis, so they run alongside the diagnosis's tests). The pipeline puts
two more there itself: the null's base (:func:`pospp.null_stage.null_base`, which needs
the legs and B's replays, not the fit, so it runs alongside the fit) and the trajectory MCAP's
messages (:func:`pospp.io.trajectory_mcap.trajectory_messages`, alongside the diagnosis; the
metadata record with the run's status is written at the end). Measured before
the lane: a run on two threads kept 1.2 cores busy. Each is a
:class:`pospp.threads.Later`: with no lane it is made where its stage uses it, as a plain
call there would be (and not at all when no stage does), so a run on one thread does the
same work in the same order as before. The values do not depend on the lane: none of the
passes reads the null (the compensation's gyro bias and the re-runs' legs and replays are
the calibration's, which the null covariance leaves as they are), and the tables of a run on
one and on two threads are the same (tests/e2e).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from pospp.calib.stage import CalibrationRun
from pospp.config import PipelineConfig
from pospp.diagnosis_stage import diagnosis_reruns, scale_factor_start, signature_starts
from pospp.flight_stages import lever_arm_passes, lever_arm_seen, navigate, sensor_to_body_dcm
from pospp.io import mcap_reader
from pospp.lever_time_stage import qc_passes
from pospp.nav import filter as nav_filter
from pospp.qc.checks import lever_arm_observable_from_track
from pospp.qc.stage import quality_checks
from pospp.threads import Later, SharedWork
from pospp.units import t_s_from_time_ns


@dataclass(frozen=True)
class Ahead:
    """A's passes and the QC checks made ahead, each a :class:`pospp.threads.Later` (None: not
    made)."""

    lever: Later
    """:func:`lever_re_estimate`."""
    starts: Later | None
    """:func:`pospp.diagnosis_stage.signature_starts` (None: no diagnosis)."""
    compensated: Later | None = None
    """A with the calibrated gyro bias removed (None: no calibration or no re-run)."""
    diagnosis: Later | None = None
    """:func:`pospp.diagnosis_stage.diagnosis_reruns` (None: no calibration or diagnosis)."""
    checks: Later | None = None
    """:func:`pospp.qc.stage.quality_checks` on the final calibration (:func:`checks_ahead`)."""


@dataclass(frozen=True)
class Guess:
    """A's lever-arm pass and the diagnosis's scale-factor start, started before A
    (:func:`passes_on_log`) for the lever-arm axes a rough attitude from the GNSS track
    reveals."""

    seen: np.ndarray
    """The guessed axes (FRD, (3,) bool):
    :func:`pospp.qc.checks.lever_arm_observable_from_track`."""
    lever: Later
    """:func:`lever_re_estimate` for ``seen``."""
    scale_factor: Later | None
    """:func:`pospp.diagnosis_stage.scale_factor_start` at that estimate (None: no diagnosis)."""


def lever_re_estimate(log: mcap_reader.FlightLog, seen: np.ndarray, config: PipelineConfig
                      ) -> tuple[nav_filter.LeverArmEstimate | None, str | None]:
    """(A's lever-arm estimate, None) by :func:`pospp.flight_stages.lever_arm_passes` for
    the revealed axes ``seen`` (:func:`pospp.flight_stages.lever_arm_seen`), or (None, why it
    failed); (None, None) when A estimates the lever arm itself."""
    if config.gnss.estimate_lever_arm:
        return None, None
    try:
        return lever_arm_passes(log, seen, config), None
    except ValueError as exc:
        return None, str(exc)


def passes_on_log(log: mcap_reader.FlightLog, config: PipelineConfig,
                  lane: ThreadPoolExecutor | None) -> Guess | None:
    """A's lever-arm pass and the diagnosis's scale-factor start, on ``lane`` from now on,
    alongside A: they need the log and the lever-arm axes A's attitude will reveal, which are
    guessed here from the GNSS velocity track
    (:func:`pospp.qc.checks.lever_arm_observable_from_track`). :func:`passes_on_a` keeps
    them when A's attitude reveals the same axes and makes them again when it does not, so
    the values are those of A's axes either way (measured on the 1.5 h flight: the second
    core was idle through A's 1.4 s). None: no lane, or no GNSS velocity to guess from."""
    if lane is None or len(log.vel) < 2:
        return None
    t_s = t_s_from_time_ns(log.vel.time_ns, int(log.vel.time_ns[0]))
    seen = lever_arm_observable_from_track(t_s, log.vel.v_n_mps)
    lever = Later(lane, lever_re_estimate, log, seen, config)
    sf = (Later(lane, lambda: scale_factor_start(log, config, lever.result()[0]))
          if config.outputs.diagnose else None)
    return Guess(seen, lever, sf)


def passes_on_a(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                config: PipelineConfig, lane: ThreadPoolExecutor | None,
                guess: Guess | None = None) -> Ahead:
    """A's lever-arm pass and the diagnosis's signature starts (the scale-factor pass), on
    ``lane`` from now on, alongside the calibration (None: each where its stage uses it);
    ``guess``'s passes (:func:`passes_on_log`) when it guessed the axes A's attitude reveals
    (else they are cancelled, or let run out and dropped)."""
    seen = lever_arm_seen(nav)
    if guess is not None and np.array_equal(guess.seen, seen):
        lever, sf = guess.lever, guess.scale_factor
    else:
        if guess is not None:
            for later in (guess.scale_factor, guess.lever):
                if later is not None:
                    later.cancel()
        lever, sf = Later(lane, lever_re_estimate, log, seen, config), None
    starts = (Later(lane, lambda: signature_starts(log, nav, config, lever.result()[0], sf))
              if config.outputs.diagnose else None)
    return Ahead(lever, starts)


def passes_ahead(ahead: Ahead, log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                 calib_run: CalibrationRun, config: PipelineConfig,
                 lane: ThreadPoolExecutor | None, threads: int) -> Ahead:
    """``ahead`` with the compensated A and the diagnosis's first re-runs, on ``lane`` after
    the passes already there, alongside the null realisations (None: each where its stage
    uses it). On the lane the re-runs are made one at a time (the null's ``threads``
    workers hold the cores then; measured on the 1.5 h flight, two at a time: no faster, 200
    MiB more), and the main thread joins them when it has nothing left but to wait for them
    (:class:`pospp.threads.SharedWork`: it waited 0.9 s for the last ones); without a lane,
    ``threads`` at a time as in the diagnosis stage."""
    if not calib_run.calibrated:
        return ahead
    comp = (Later(lane, navigate, log, config,
                  gyro_bias_correction_b_radps=calib_run.gyro_bias_b_radps)
            if config.compensation.rerun_filter else None)
    starts = ahead.starts
    shared = SharedWork()  # on the lane: the re-runs one at a time, the main thread joins
    diag = None if starts is None else Later(lane, lambda: diagnosis_reruns(
        calib_run, config, log=log, nav=nav, lever_estimate=ahead.lever.result()[0],
        threads=shared if lane is not None else threads, starts=starts.result()),
        helped=shared)
    return replace(ahead, compensated=comp, diagnosis=diag)


def checks_ahead(ahead: Ahead, log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                 calib_run: CalibrationRun | None, config: PipelineConfig,
                 lane: ThreadPoolExecutor | None) -> Ahead:
    """``ahead`` with the QC stage's checks (:func:`pospp.qc.stage.quality_checks`, pure: the
    stage notes their failures), on ``lane`` after the passes already there, alongside the
    diagnosis's tests; ``calib_run``: the calibration as the run reports it (its null
    covariance in). They need A's lever-arm estimate, not the diagnosis."""
    cin = config.input
    return replace(ahead, checks=Later(
        lane, lambda: quality_checks(log, nav, calib_run, config,
                                     lever_estimate=ahead.lever.result()[0],
                                     c_bs=sensor_to_body_dcm(cin.sensor_frame,
                                                             cin.mounting_rpy_deg),
                                     **qc_passes(log, nav, config,
                                                 ahead.lever.result()[0]))))
