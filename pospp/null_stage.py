"""The null stage of one flight: B minus A's noise response along it, the calibration's
covariance and the diagnosis's null realisations (docs/diagnose.md, "The linear null").

A function of the results before it: A's result (its recorded gains), the calibration's legs
and B's replays, and the configuration. By default the null is linear
(:mod:`pospp.calib.linear_null`: exact draws and the least squares' exact covariance from A's
gains); with ``[pairs] null_reruns`` it is made by A re-run on noisy logs
(:mod:`pospp.diagnose.null_model`), whose machinery (the base, the summed-down log, B minus A
of a re-run) the diagnosis's re-run signatures share (:mod:`pospp.diagnosis_stage`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from pospp.calib.bias_smoother import span_means
from pospp.calib.linear_null import LinearNull, NullNoise, linear_null
from pospp.calib.null_covariance import with_covariance, with_null_covariance
from pospp.calib.replay import LegReplay, SolutionA, replay_velocity_error
from pospp.calib.segment import Leg
from pospp.calib.stage import CalibrationRun
from pospp.config import PipelineConfig
from pospp.diagnose import null_model
from pospp.diagnose.effects import ACCEL_SETTLING_S
from pospp.diagnose.linear_signatures import linear_signatures
from pospp.diagnose.rerun import gate_excess
from pospp.flight_stages import (
    imu_increments,
    imu_tuning,
    navigate,
    rerun_decimation,
    rerun_options,
    static_alignment_window,
)
from pospp.io import mcap_reader
from pospp.nav import filter as nav_filter
from pospp.nav.alignment import static_attitude_jacobian
from pospp.threads import first_kept, map_in_threads
from pospp.units import t_s_from_time_ns


def null_needs_gains(config: PipelineConfig) -> bool:
    """Whether A's pass should record its gains (``navigate(..., record_gains=)``): the null
    is wanted and linear (:func:`linear_null_model` reads them)."""
    return not config.pairs.null_reruns and config.pairs.null_realisations > 0


def null_drift(calib_run: CalibrationRun, config: PipelineConfig) -> tuple[float, float, str]:
    """The gyro drift the null realisations inject: (sigma [rad/s], tau [s], source).

    The drift the flight shows (its level and tau by REML, the grade a weak prior; source
    "flight", or "grade" when the flight does not reject the grade's), so the
    calibration's and the diagnosis's sigmas follow the flight; the configured ``[imu]
    gyro_gm_sigma_dph`` / ``gyro_gm_tau_s`` (source "configured") when the calibration did not
    estimate it.
    """
    if calib_run.drift_source in ("flight", "grade"):
        return calib_run.drift_sigma_radps, calib_run.drift_tau_s, calib_run.drift_source
    si = imu_tuning(config).noise()
    return si.gyro_gm_sigma_radps, si.gyro_gm_tau_s, "configured"


def null_white_noise(log: mcap_reader.FlightLog, config: PipelineConfig
                     ) -> tuple[float, float]:
    """The IMU white noise the null realisations add: (gyro ARW [rad/s^0.5], accelerometer
    VRW [m/s^1.5]), read from the log's samples (``[pairs] null_imu_noise`` "measured",
    :attr:`pospp.types.ImuSamples.white_noise`, read once per log) or the configured
    grade's ("grade")."""
    if config.pairs.null_imu_noise == "grade":
        si = imu_tuning(config).noise()
        return float(si.gyro_arw_radpsqrts), float(si.accel_vrw_mpspsqrts)
    return log.imu.white_noise


def null_noise(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
               calib_run: CalibrationRun, config: PipelineConfig, *,
               drift: tuple[float, float] | None = None,
               white_noise: tuple[float, float] | None = None,
               gnss_sigmas: tuple[np.ndarray, np.ndarray] | None = None) -> NullNoise:
    """The noise a null realisation injects: IMU white noise (:func:`null_white_noise`, or
    ``white_noise`` made before), the gyro drift of :func:`null_drift` (or ``drift``: (sigma
    [rad/s], tau [s]), :func:`pospp.diagnosis_stage.drift_under_alternative`), the configured
    accelerometer drift ``accel_gm_sigma_ug`` / ``accel_gm_tau_s``, and GNSS white noise at the
    level of the flight's GNSS minus A's solution at the antenna
    (:func:`null_model.gnss_noise_from_residuals`; ``gnss_sigmas``: made before)."""
    si = imu_tuning(config).noise()
    gm_sigma, gm_tau, _ = null_drift(calib_run, config) if drift is None else (*drift, "")
    arw, vrw = null_white_noise(log, config) if white_noise is None else white_noise
    if gnss_sigmas is None:
        gnss_sigmas = null_model.gnss_noise_from_residuals(log, _gnss_on_a(log, nav, config))
    return NullNoise(gyro_arw_radpsqrts=float(arw), accel_vrw_mpspsqrts=float(vrw),
                     gyro_gm_sigma_radps=float(gm_sigma), gyro_gm_tau_s=float(gm_tau),
                     accel_gm_sigma_mps2=float(si.accel_gm_sigma_mps2),
                     accel_gm_tau_s=float(si.accel_gm_tau_s),
                     pos_sigma_ned_m=gnss_sigmas[0], vel_sigma_ned_mps=gnss_sigmas[1])


def _gnss_on_a(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
               config: PipelineConfig) -> mcap_reader.FlightLog:
    """The log with its GNSS on A's ``[replay] reference`` solution at the antenna
    (:func:`null_model.gnss_on_solution`)."""
    which = nav_filter.reference_name(nav, config.replay.reference)
    solution = nav.smoothed if which == "smoothed" and nav.smoothed is not None else nav.forward
    return null_model.gnss_on_solution(log, solution, int(log.imu.time_ns[0]),
                                       nav.lever_arm.lever_b_m)


def linear_null_model(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                      calib_run: CalibrationRun, config: PipelineConfig,
                      noise: NullNoise) -> LinearNull:
    """B minus A's null along this flight as a linear system (:mod:`pospp.calib.linear_null`)
    on the calibration's legs and replays. A's gains are ``nav``'s (``record_gains``) when A
    used its GNSS as its model says (no more gated than it allows, no covariance reset:
    :func:`pospp.diagnose.rerun.gate_excess`); otherwise those of A re-run recording them on
    the log with its GNSS on A's solution (the "rerun" null's base, of which A gates nothing:
    the A of a flight without the effect that made it gate); A re-run on the log itself when
    ``nav`` recorded none.

    Raises ValueError (its message: why) when A fails, the legs overlap in time, or a leg
    starts before A's heading has converged (its sigma within twice its median: the gain
    replay's switch epoch, :func:`pospp.nav.filter_state.switch_epoch`): there A's error is
    not small and its response not linear (measured on the null Monte Carlo's flights that
    align in motion: A re-runs with leg-0 tilts 90-250 times the linear sigma in 4 of 40, a
    closing lack of fit at p 0.002-0.02 with the linear null where the re-runs' read 0.39;
    docs/diagnose.md, "The linear null"); the null is then made by A re-runs."""
    gains = nav.gain_replay
    if nav.resets or gate_excess(nav, config.filter_options().gate_probability):
        gains = navigate(_gnss_on_a(log, nav, config), config, options=rerun_options(config),
                         record_gains=True).gain_replay
    elif gains is None:
        gains = navigate(log, config, options=rerun_options(config),
                         record_gains=True).gain_replay
    assert gains is not None  # recorded
    t_conv = float(gains.t_s[gains.k_from])
    early = [(i, r.t0_s) for i, r in sorted(calib_run.replays.items()) if r.t0_s < t_conv]
    if early:
        raise ValueError(f"leg {early[0][0]} starts at {early[0][1]:.0f} s, before A's heading "
                         f"has converged ({t_conv:.0f} s)")
    which = nav_filter.reference_name(nav, config.replay.reference)
    sol = nav.smoothed if which == "smoothed" and nav.smoothed is not None else nav.forward
    imu = imu_increments(log)
    return linear_null(gains, sol.trajectory, imu.t_s, imu.w_ib_b_radps, imu.f_ib_b_mps2,
                       [calib_run.replays[i] for i in sorted(calib_run.replays)], noise,
                       smoothed=which == "smoothed")


def linear_effect_signatures(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                             calib_run: CalibrationRun, config: PipelineConfig,
                             model: LinearNull | None = None) -> dict[str, list[np.ndarray]]:
    """The lever arm's, the GNSS time offset's and the warm-up's signatures on B minus A from
    A's own gains (:mod:`pospp.diagnose.linear_signatures`: A's derivative at the
    configuration, its gate decisions held), where that is A's response: the flight's A reset
    nothing and gated no more GNSS records than its model allows
    (:func:`pospp.diagnose.rerun.gate_excess`), and its linear system holds the legs
    (:func:`linear_null_model`). Else {} (the diagnosis re-runs A), also when A's pass
    recorded no gains. ``model``: the null stage's system (:class:`NullResult`), which the
    signatures share (they do not depend on the noise's levels); None: made here."""
    if (nav.gain_replay is None or nav.resets
            or gate_excess(nav, config.filter_options().gate_probability)):
        return {}
    if model is None:
        try:
            model = linear_null_model(log, nav, calib_run, config,
                                      null_noise(log, nav, calib_run, config))
        except ValueError:
            return {}
    which = nav_filter.reference_name(nav, config.replay.reference)
    sol = nav.smoothed if which == "smoothed" and nav.smoothed is not None else nav.forward
    window = static_alignment_window(nav, config.filter_options())
    alignment = None
    if window is not None:  # the tilt A's static alignment takes from the warm-up
        t_s = t_s_from_time_ns(log.imu.time_ns, int(log.imu.time_ns[0]))
        sel = (t_s > window[0]) & (t_s <= window[1])
        alignment = (static_attitude_jacobian(log.imu.w_ib_b_radps[sel].mean(axis=0),
                                              log.imu.f_ib_b_mps2[sel].mean(axis=0)), *window)
    return linear_signatures(model, sol.trajectory, config.gnss.lever_arm_m,
                             warmup=(ACCEL_SETTLING_S, alignment))


def with_null_sigmas(calib_run: CalibrationRun, null_dv: list[list[np.ndarray]],
                     model: LinearNull | None,
                     injected: Sequence[np.ndarray] | None = None, threads: int = 1
                     ) -> CalibrationRun:
    """The calibration with its covariance from the null: exactly from the linear null's
    ``model`` (:meth:`pospp.calib.linear_null.LinearNull.calibration_covariance`), else from
    refits on the realisations ``null_dv``
    (:func:`pospp.calib.null_covariance.with_null_covariance`). The flight's gyro bias sigma
    from refits on ``null_dv`` against their injected truths ``injected`` either way (the
    turn-on constant's without them). ``threads``: above 1, the exact covariance is made on a
    second thread beside the refits (the result does not depend on it)."""
    chosen = calib_run.chosen
    if model is None or chosen is None or chosen.gain is None:
        return with_null_covariance(calib_run, null_dv, injected or None)
    # the exact covariance (compiled, releasing the GIL) beside the refits, which then hold it
    refits, exact = map_in_threads(lambda job: job(), [
        lambda: with_null_covariance(calib_run, null_dv, injected or None),
        lambda: model.calibration_covariance(chosen)], threads)
    flight = (refits.flight_gyro_bias_sigma_b_radps if injected
              and refits.sigma_source == "null_realisations" else None)
    return with_covariance(calib_run, exact, "linear_null",
                           "calibration sigmas from the linear null of B minus A (A's gains: "
                           "the least squares' exact covariance)", flight)


class NullResult(NamedTuple):
    """What the null stage gives (:func:`null_stage`)."""

    realisations: list[list[np.ndarray]]
    """B minus A's null realisations (:func:`null_realisations`): the diagnosis's null."""
    calibration: CalibrationRun
    """The calibration with its covariance from the null (:func:`with_null_sigmas`)."""
    model: LinearNull | None
    """B minus A's linear system along the flight (:func:`linear_null_model`), None where the
    null is A re-runs."""


def null_stage(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
               calib_run: CalibrationRun, config: PipelineConfig, *, n: int | None = None,
               seed: int = 0, threads: int = 1,
               white_noise: tuple[float, float] | None = None,
               base: NullBase | None = None) -> NullResult:
    """The null stage as a run makes it: ``n`` (``[pairs] null_realisations`` when None)
    realisations of B minus A's null along the flight and the calibration's covariance from
    the same null; ``nav`` is A as the run made it (recording its gains: :func:`navigate`
    with ``record_gains=null_needs_gains(config)``, else A is run again here to record them).
    The other arguments as :func:`null_realisations`'."""
    made: list[LinearNull | str] = []
    injected: list[np.ndarray] = []  # the re-runs' truths of the flight's gyro bias
    dv = null_realisations(log, nav, calib_run, config,
                           config.pairs.null_realisations if n is None else n, seed=seed,
                           threads=threads, white_noise=white_noise, base=base, model_out=made,
                           injected_out=injected)
    model = next((m for m in made if isinstance(m, LinearNull)), None)
    run = calib_run if model or not made else replace(
        calib_run, messages=calib_run.messages + (str(made[0]),))
    return NullResult(dv, with_null_sigmas(run, dv, model, injected, threads), model)


def null_realisations(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                      calib_run: CalibrationRun, config: PipelineConfig, n: int, *,
                      seed: int = 0, drift: tuple[float, float] | None = None,
                      threads: int = 1, white_noise: tuple[float, float] | None = None,
                      base: NullBase | None = None,
                      model_out: list[LinearNull | str] | None = None,
                      injected_out: list[np.ndarray] | None = None
                      ) -> list[list[np.ndarray]]:
    """B minus A's null realisations along this flight: ``n`` lists of (M, 3) NED arrays
    [m/s], legs in id order, each B minus A's response to one draw of :func:`null_noise`
    (``drift``, ``white_noise``: as there).

    By default (``[pairs] null_reruns`` false) exact draws of the linear null
    (:func:`linear_null_model`, appended to ``model_out`` when it is a list, else why it was
    not made; ``seed`` seeds them). With ``null_reruns``, or without a linear null (a leg
    before A's heading converged, legs that overlap),
    A re-run as configured on the log with its GNSS on A's solution at the antenna (the base,
    :func:`null_base`: made here when ``base`` is None) plus the noise drawn from ``seed``
    from A's alignment point on, B replayed on the same legs, minus the base's own B minus A
    (pospp.diagnose.null_model; docs/diagnose.md, "The null, third version"); A and B at
    ``[pairs] rerun_imu_rate_hz`` (:func:`rerun_decimation`), A with the base's gains; fewer
    than ``n`` when A fails on more than ``n`` of ``2 n`` perturbed logs; ``threads``:
    realisations made at once (the result does not depend on it). ``injected_out``: when a
    list, each realisation appends the mean over each leg (id order, the replays' span; (L,
    3), body FRD [rad/s]) of the gyro error it injected (white noise and drift): the truth its
    flight bias is measured against (:func:`pospp.calib.null_covariance.with_null_covariance`).
    """
    if not config.pairs.null_reruns:
        try:
            model: LinearNull | str = linear_null_model(log, nav, calib_run, config, null_noise(
                log, nav, calib_run, config, drift=drift, white_noise=white_noise))
        except ValueError as exc:
            model = f"the null from A re-runs: no linear null ({exc})"
        if model_out is not None:
            model_out.append(model)
        if isinstance(model, LinearNull):
            return model.draws(n, seed, injected_out=injected_out)
    b = null_base(log, nav, calib_run.legs, calib_run.replays, config) if base is None \
        else base
    noise = null_noise(log, nav, calib_run, config, drift=drift, white_noise=white_noise,
                       gnss_sigmas=(b.pos_sigma_ned_m, b.vel_sigma_ned_mps))
    rng = np.random.default_rng(seed)
    epoch_ns = int(log.imu.time_ns[0])
    spans = [(epoch_ns + round(r.t0_s * 1e9), epoch_ns + round((r.t0_s + r.t_s[-1]) * 1e9))
             for _, r in sorted(calib_run.replays.items())]

    def attempt(log_r: mcap_reader.FlightLog
                ) -> tuple[list[np.ndarray], np.ndarray | None] | None:
        try:  # A with the base's gains (nav_filter.GainReplay): first order in the noise
            dv = rerun_b_minus_a(log_r, nav, calib_run.legs, calib_run.replays, config,
                                 replay=b.gains)[0]
        except ValueError:  # a realisation whose A fails (alignment) is skipped
            return None
        return dv, (span_means(b.log.imu.time_ns, log_r.imu.w_ib_b_radps
                               - b.log.imu.w_ib_b_radps, spans) if injected_out is not None
                    else None)

    # drawn on the summed-down samples (a quarter of the flight-rate draws at 200 -> 50 Hz);
    # in this thread (drawing and scaling them in the workers held a draw per thread, +230
    # MiB on the 1.5 h flight, for no time: the generator's draws are serial)
    perturbed = (null_model.perturb_log(b.log, noise, rng, from_time_ns=b.t_align_ns)
                 for _ in range(2 * n))
    # never more logs drawn than realisations still missing: the draws, and so the
    # realisations, are those of one log at a time; the next drawn while A runs on the others
    kept = first_kept(attempt, perturbed, n, threads)
    if injected_out is not None:
        injected_out.extend(k[1] for k in kept if k[1] is not None)
    return [[d - d0 for d, d0 in zip(k[0], b.dv_n_mps, strict=True)] for k in kept]


@dataclass(frozen=True)
class NullBase:
    """What the null realisations perturb and subtract (:func:`null_base`): none of it
    depends on the calibration's fit (its drift sets the noise only)."""

    log: mcap_reader.FlightLog
    """The flight with its GNSS on A's solution at the antenna, IMU summed down (or not)."""
    dv_n_mps: list[np.ndarray]
    """B minus A on ``log`` per leg with a replay, in id order (M, 3) [m/s]."""
    gains: nav_filter.GainReplay | None
    """A's gains on ``log``, which the realisations' A re-uses."""
    pos_sigma_ned_m: np.ndarray
    """The GNSS position noise the realisations add (NED) [m]."""
    vel_sigma_ned_mps: np.ndarray
    """The GNSS velocity noise the realisations add (NED) [m/s]."""
    t_align_ns: int
    """The noise is added from A's alignment point on [ns, log stamps]."""


def null_base(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult, legs: Sequence[Leg],
              replays: Mapping[int, LegReplay], config: PipelineConfig) -> NullBase:
    """The base of :func:`null_realisations` on ``legs`` and their B ``replays`` (before the
    fit: a run on two threads makes it while it calibrates): the flight with its GNSS replaced
    by A's solution at the antenna (:func:`pospp.diagnose.null_model.gnss_on_solution`; noise
    on top of the flight's own GNSS noise is not linear), the IMU summed down to ``[pairs]
    rerun_imu_rate_hz`` (the flight's rate when A fails on the summed-down base), A re-run on
    it recording its gains and B replayed on the legs. Raises ValueError when A fails on it
    at the flight's rate."""
    base = _gnss_on_a(log, nav, config)
    pos_sig, vel_sig = null_model.gnss_noise_from_residuals(log, base)
    factor = rerun_decimation(log, config.pairs.rerun_imu_rate_hz)
    t_align_ns = int(log.imu.time_ns[0]) + round(nav.alignment.t_s * 1e9)
    leg_ns = null_sample_stamps_ns(log, legs, t_align_ns)
    base_r = null_model.decimate_imu(base, factor, leg_ns)
    try:
        base_dv, gains = rerun_b_minus_a(base_r, nav, legs, replays, config, record=True)
        if any(d.shape != replays[i].dv_n_mps.shape
               for d, i in zip(base_dv, sorted(replays), strict=True)):
            raise ValueError("B on the summed-down base is not on the flight's samples")
    except ValueError:  # A fails on the summed-down base (its alignment): the flight's rate
        if factor == 1:
            raise
        base_r = base
        base_dv, gains = rerun_b_minus_a(base_r, nav, legs, replays, config, record=True)
    return NullBase(base_r, base_dv, gains, pos_sig, vel_sig, t_align_ns)


def rerun_b_minus_a(log_r: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                    legs: Sequence[Leg], replays: Mapping[int, LegReplay],
                    config: PipelineConfig, record: bool = False,
                    replay: nav_filter.GainReplay | None = None
                    ) -> tuple[list[np.ndarray], nav_filter.GainReplay | None]:
    """A re-run on ``log_r`` as the null realisations and the diagnosis's re-run base run it
    (``record``: recording its gains; ``replay``: with those gains), then B minus it on the
    legs with a replay, in id order: (M, 3) NED velocity errors [m/s], and the gains recorded
    (else None). Raises ValueError when A or B fails on ``log_r``."""
    which = nav_filter.reference_name(nav, config.replay.reference)
    nav_r = navigate(log_r, config, options=rerun_options(config), record_gains=record,
                     replay=replay)
    ref_r = SolutionA(*nav_filter.solution_a_fields(nav_r, which=which))
    gains = nav_r.gain_replay
    del nav_r  # the rest of A (its forward solution, biases: 30 MiB) is not read by B
    imu_r = imu_increments(log_r)
    by_id = {leg.leg_id: leg for leg in legs}
    rc = config.replay
    return [replay_velocity_error(imu_r, ref_r, by_id[i],
                                  accel_compensation=rc.accel_compensation,
                                  sample_rate_hz=rc.sample_rate_hz)
            for i in sorted(replays)], gains


def leg_epochs_ns(log: mcap_reader.FlightLog, legs: Sequence[Leg]) -> np.ndarray:
    """The IMU stamps [ns] a decimated log keeps so that B runs over each leg as on the
    flight: the epoch before B's first (its previous increments), B's first and its last
    (:func:`pospp.calib.replay.replay_velocity_error`: the first epoch at or after the leg's
    start, at least the second, and the last at or before its end)."""
    t_ns = np.asarray(log.imu.time_ns, dtype=np.int64)
    t_s = t_s_from_time_ns(t_ns, int(t_ns[0]))  # imu_increments' axis
    out: list[int] = []
    for leg in legs:
        k0 = max(int(np.searchsorted(t_s, leg.start_s)), 1)
        k1 = int(np.searchsorted(t_s, leg.end_s, side="right")) - 1
        out += [k0 - 1, k0, max(k1, k0)]
    return t_ns[np.clip(out, 0, t_ns.size - 1)] if out else np.zeros(0, np.int64)


def null_sample_stamps_ns(log: mcap_reader.FlightLog, legs: Sequence[Leg],
                          from_time_ns: int) -> np.ndarray:
    """The IMU stamps [ns] the null's summed-down log keeps: the legs' (:func:`leg_epochs_ns`)
    and the last one before ``from_time_ns`` (where the noise starts: a summed sample then
    holds flight samples all before it or all at or after it, as the flight-rate noise
    :func:`pospp.diagnose.null_model.perturb_log` adds to them)."""
    t_ns = np.asarray(log.imu.time_ns, dtype=np.int64)
    before = int(np.searchsorted(t_ns, int(from_time_ns))) - 1
    extra = t_ns[before:before + 1] if before >= 0 else np.zeros(0, np.int64)
    return np.concatenate([leg_epochs_ns(log, legs), extra])
