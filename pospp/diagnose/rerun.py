"""Signatures of the GNSS-side effects by re-running algorithm A.

Frames and units: body FRD (b), NED (n), SI inside; the signatures are per leg (M, 2, P):
d [dv_N, dv_E] / d p at the replay samples, p in SI (m for the lever arm, s for the offset).

Why: an antenna lever arm the configuration gets wrong, or a GNSS time tag offset, does not
only add A's kinematic error (``-C_nb (w_nb_b x dl)``, what :mod:`pospp.diagnose.effects`
writes in closed form): A is a Kalman filter and smoother, and the mismatch of its GNSS
measurements in every turn is read as attitude, heading and bias errors, which B then carries
from each leg start. Measured on a simulated survey flight with a 1 m antenna offset
configured as 0 (tests/unit/test_diagnose_power.py): B minus A moves by 50 mm/s RMS on the
legs after the turns, the closed-form signature predicts 3 mm/s, and the workflow cannot name
the lever arm. The exact first-order signature is A's own response, obtained the way the null
realisations are (:func:`pospp.pipeline.null_realisations`): A re-run on the flight's log
with the configuration perturbed, B replayed on the same legs, minus the flight's B minus A,
divided by the perturbation (one-sided finite difference, step h = :data:`STEP_FRACTION`
times the effect's plausible size)::

    S_j(t) = ((B - A)[log, config + h e_j](t) - (B - A)[log, config](t)) / h

``lever_arm`` (dl = configured minus true, FRD): the configured lever arm plus h e_j.
``time_offset`` (IMU time tag minus GNSS time tag, tau): the GNSS fixes and velocities
stamped h earlier (the IMU then reads late by h relative to them).
``gyro_scale_factor`` (s, FRD): the IMU rates read ``(1 + h) w_j`` on axis j (A and B both
re-run: the heading error a scale factor builds up in the turns reaches B through A's state
at each leg start, which the in-leg forcing of :mod:`pospp.diagnose.effects` leaves out).
``accel_bias_change`` (db, FRD x and y): the specific force reads ``f_j + h exp(-t / T)``,
t from the first IMU stamp, T = ``accel_settling_s`` (A estimates the bias B then uses).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pospp.calib.replay import ImuRates, SolutionA, replay_velocity_error
from pospp.diagnose.effects import ACCEL_SETTLING_S, effect_by_id
from pospp.nav import filter as nav_filter
from pospp.nav.filter import FilterResult
from pospp.qc.stage import gate_check
from pospp.threads import map_in_threads

STEP_FRACTION = 1.0
"""Finite-difference step as a fraction of ``Effect.plausible_si`` (20 ms, 0.5 m, 1000 ppm,
100 ug). A's response is not linear (its chi-square gate rejects the fixes a large offset
shifts, its attitude Jacobian depends on the configured lever arm): with this step a 12 ms
GNSS offset is named 5 times in 5 and a 4 ms one reads -1.7 ms; with a tenth of it the 4 ms
offset reads -3.8 ms and the 12 ms one -0.1 ms (measured, docs/diagnose.md "Power"), hence
the secant refinement (:func:`refine_signatures`)."""
LOCAL_STEP_FRACTION = 0.2
"""Step of the local derivatives at an estimate (:func:`signature_at`), as a fraction of the
plausible size (0.1 m for the lever arm): near the effect-free state A's gate is open and its
response to the lever arm linear (5e-5 m/s, measured)."""
REFINE_FRACTION = 0.05
"""An estimate above this fraction of the plausible size gets a secant signature."""
REFINE_ITERATIONS = 8
"""Secant refinements the pipeline makes at most (each: one to four A runs per effect and one
diagnosis); it stops earlier when no estimate moves by more than :data:`REFINE_TOLERANCE` of
itself (the lever arm and the time offset within 3). The warm-up's creeps: A's response to
it is super-linear, and from the derivative at 0 a 600 ug warm-up read 148, 237, 343, 433,
488, 513, 523, 525 ug (x; seed 5 of the warm-up mission, docs/diagnose.md "Power")."""
REFINE_TOLERANCE = 0.05
RERUN_EFFECTS = ("lever_arm", "time_offset", "gyro_scale_factor", "accel_bias_change")
"""Effects whose signature :func:`rerun_signatures` makes by re-running A."""
PIPELINE_RERUN = ("lever_arm", "time_offset", "gyro_scale_factor", "accel_bias_change")
"""The ones the pipeline's diagnosis re-runs. The lever arm and the time offset always (4 A
runs, or 1 + 4 at A's lever-arm estimate); the gyro scale factor only by Gauss-Newton from A's
own scale-factor estimate, when that is significant (1 A run; otherwise the library's
signature stands and the flight pays A's 0.2 s forward pass): its re-run at the configuration
(3 A runs) read a 600 ppm z scale factor on the y axis. The warm-up always: A's
accelerometer-bias estimate lags the warm-up and its attitude and heading take up the rest,
which B carries from each leg start (measured: 61 mm/s RMS on a leg 170 s after power-up
where the in-leg forcing of :mod:`pospp.diagnose.effects` gives 25 mm/s; docs/diagnose.md
"Power"); at the configuration (2 A runs), or by Gauss-Newton from A's own pass with the
warm-up's dynamics where the warm-up explains A's gated GNSS records (:func:`gate_excess`;
``flight_stages.warmup_estimate``: 3 A runs and the pass)."""
GAUSS_NEWTON_EFFECTS = ("lever_arm", "time_offset", "gyro_scale_factor", "accel_bias_change")
"""Effects :func:`signature_at` and :func:`refine_signatures` make a signature at an estimate
for."""

Jacobians = dict[str, tuple[NDArray, list[NDArray]]]
"""The local derivatives :func:`signature_at` made: effect id -> (the estimate p they were made
at, SI (P,); per leg J (M, 2, P), d [dv_N, dv_E] / d p at the removed state)."""

Navigate = Callable[..., FilterResult]
"""A as the run configures it: ``navigate(log, lever_arm_b_m=None) -> FilterResult`` (the
pipeline's ``navigate`` with its configuration bound; the lever arm replaces the configured
one when given)."""


def _response(log_p, nav, calib_run, config, navigate: Navigate, lever_b_m=None,
              **a_options: Any) -> list[NDArray]:
    """(B - A)[log_p, lever] - (B - A)[flight] per leg (legs in id order), (M, 2) [m/s]."""
    return _response_and_gains(log_p, nav, calib_run, config, navigate, lever_b_m,
                               **a_options)[0]


def _response_and_gains(log_p, nav, calib_run, config, navigate: Navigate, lever_b_m=None,
                        **a_options: Any
                        ) -> tuple[list[NDArray], nav_filter.GainReplay | None]:
    """:func:`_response` and the re-run's recorded gains (``a_options``: ``navigate``'s
    ``record_gains`` or ``replay``; None when it recorded none)."""
    rc = config.replay
    which = nav_filter.reference_name(nav, rc.reference)
    legs = {leg.leg_id: leg for leg in calib_run.legs}
    nav_p = navigate(log_p, lever_arm_b_m=lever_b_m, **a_options)
    ref_p = SolutionA(*nav_filter.solution_a_fields(nav_p, which=which))
    gains = nav_p.gain_replay
    del nav_p  # the rest of A (its forward solution, biases: 30 MiB) is not read by B
    t0 = int(log_p.imu.time_ns[0])
    imu = ImuRates.from_rates(log_p.imu.time_ns, log_p.imu.w_ib_b_radps,
                              log_p.imu.f_ib_b_mps2, epoch_ns=t0)
    return [replay_velocity_error(imu, ref_p, legs[i], accel_compensation=rc.accel_compensation,
                                  sample_rate_hz=rc.sample_rate_hz)[:, 0:2]
            - calib_run.replays[i].dv_n_mps[:, 0:2] for i in sorted(calib_run.replays)], gains


def with_rates(log, rates):
    """The log with its IMU rates replaced (body FRD, rad/s)."""
    return replace(log, imu=replace(log.imu, w_ib_b_radps=rates))


def restamped(log, shift_s: float):
    """The log with its GNSS fixes and velocities re-stamped ``t - shift_s`` (``shift_s``:
    the GNSS stamp minus the true time the records are taken to have)."""
    d = np.int64(round(shift_s * 1e9))
    return replace(log, fix=replace(log.fix, time_ns=log.fix.time_ns - d),
                   vel=replace(log.vel, time_ns=log.vel.time_ns - d))


def warmed(log, db_b_mps2, accel_settling_s: float):
    """The log with the warm-up ``db exp(-t / T)`` added to the x and y specific force,
    ``db_b_mps2`` (2,) [m/s^2] FRD, t from the first IMU stamp [s] (a negative ``db``
    removes one)."""
    t_run_s = (log.imu.time_ns - log.imu.time_ns[0]) * 1e-9
    f = log.imu.f_ib_b_mps2.copy()
    f[:, 0:2] += np.exp(-t_run_s / accel_settling_s)[:, None] * np.asarray(db_b_mps2, float)
    return replace(log, imu=replace(log.imu, f_ib_b_mps2=f))


def rerun_signatures(log, nav, calib_run, config, effect_ids=RERUN_EFFECTS, *,
                     navigate: Navigate, accel_settling_s: float = ACCEL_SETTLING_S,
                     threads: int = 1) -> dict[str, list[NDArray]]:
    """Per effect, per leg (legs in id order) the signature (M, 2, P), SI parameters.

    Parameters
    ----------
    log : FlightLog-like (``imu``, ``fix``, ``vel``)
    nav : FilterResult
        A on the flight (only whether the smoother ran matters).
    calib_run : CalibrationRun
        The flight's legs and B-minus-A replays.
    config : PipelineConfig
    effect_ids : sequence of str
        Subset of :data:`RERUN_EFFECTS`.
    navigate : callable
        A as configured (:data:`Navigate`).
    accel_settling_s : float
        Warm-up time constant of ``accel_bias_change`` [s] (the workflow's).
    threads : int
        An effect's A re-runs made at once (:func:`pospp.threads.map_in_threads`; the
        result does not depend on it).

    Returns
    -------
    dict
        ``effect_id -> [S_leg (M, 2, P)]``; an effect whose re-run fails (A's alignment) is
        left out.
    """
    bad = [e for e in effect_ids if e not in RERUN_EFFECTS]
    if bad:
        raise ValueError(f"effect_ids: {bad} have no re-run signature; expected a subset of "
                         f"{RERUN_EFFECTS}")
    def response(run: tuple) -> list[NDArray] | Exception:  # (effect, log, lever or None)
        try:
            return _response(run[1], nav, calib_run, config, navigate, run[2])
        except (ValueError, np.linalg.LinAlgError) as exc:  # A failed: the effect is left out
            return exc

    # every effect's runs in one map: the threads stay busy across them
    steps: dict[str, float] = {}
    runs: list[tuple[str, Any, NDArray | None]] = []
    for eid in effect_ids:
        steps[eid] = h = STEP_FRACTION * effect_by_id(eid).plausible_si
        if eid == "lever_arm":
            lever0 = np.asarray(config.gnss.lever_arm_m, dtype=float)
            runs += [(eid, log, lever0 + h * e) for e in np.eye(3)]
        elif eid == "time_offset":
            runs += [(eid, restamped(log, h), None)]
        elif eid == "gyro_scale_factor":
            w = log.imu.w_ib_b_radps
            runs += [(eid, with_rates(log, w * (1.0 + h * e)), None) for e in np.eye(3)]
        else:  # accel_bias_change
            runs += [(eid, warmed(log, h * e, accel_settling_s), None) for e in np.eye(2)]
    results = map_in_threads(response, runs, threads)
    out: dict[str, list[NDArray]] = {}
    for eid, h in steps.items():
        cols = [c for run, c in zip(runs, results, strict=True) if run[0] == eid]
        if any(isinstance(c, Exception) for c in cols):
            continue
        out[eid] = [np.stack([c[k] for c in cols], axis=-1) / h
                    for k in range(len(calib_run.replays))]
    return out


def signature_at(log, nav, calib_run, config, effect_id: str, p, *, navigate: Navigate,
                 accel_settling_s: float = ACCEL_SETTLING_S, threads: int = 1,
                 jacobians: Jacobians | None = None) -> list[NDArray]:
    """Gauss-Newton signature of a re-run effect at the estimate ``p`` (SI, (P,)).

    A is re-run with the estimate removed (configured lever arm minus p; GNSS stamps moved
    back by p; the warm-up ``p exp(-t / T)`` taken off the specific force): B minus A there,
    ``r``, is the flight's effect-free curve if p is right. The direction u = p / |p| gets
    the secant ``s_u = -r / |p|`` (the response from zero to p, so that a fit reading 1 along
    it reads |p|), and the directions orthogonal to u get the local derivatives re-run *at*
    the removed state (``lever_arm``: configured - p + h e_j, h = :data:`LOCAL_STEP_FRACTION`
    of the plausible size), where A's gate and its attitude Jacobian ``[C_nb l x]`` are those
    of the effect-free flight, not of the wrong configuration (measured: at the configuration
    1 m off, the three axis responses read a 1 m offset's z part at 0.2 of its size)::

        S(p) = J(configured - p) (I - u u^T) + s_u u^T

    ``gyro_scale_factor`` (s, FRD, measured = (1 + s) true): the rates divided by (1 + p)
    remove it; p is A's own estimate (``flight_stages.scale_factor_estimate``, 15-28 ppm
    sigma per axis on the power flights), and the signature is the secant along it alone
    (one parameter, the size along A's direction; the directions orthogonal to u get zero
    columns, which the workflow's observability screen drops). Why not at the configuration:
    with 600 ppm on z in the flight, the re-run's 1000 ppm step put A at 1600 ppm, where its
    chi-square gate rejected 279 of 911 fixes and 116 velocities with 12 covariance resets
    (4 fixes at 600 ppm, 1 velocity at 0 and 200 ppm): the z column read leg 0's response at
    twice its size and the fit put the scale factor on y. At the removed state the three
    local derivatives fit the true response to 0.15 mm/s of its 56 mm/s RMS (605 ppm on z),
    but in the diagnosis their x and y columns took the grade's 0.1 deg/h z gyro bias (not in
    the base model) as 85 ppm on y and failed the held-out test more often than the secant
    alone (measured, docs/diagnose.md "Power").

    One A run (``time_offset``, ``gyro_scale_factor``: the secant alone), three
    (``accel_bias_change``: local steps h = :data:`LOCAL_STEP_FRACTION` of the plausible
    size on x and y at the removed state; A is not linear in a warm-up early in the flight:
    measured, a 600 ug warm-up moves B minus A on a leg 170 s after power-up by 61 mm/s RMS
    where the derivative at 0 predicts 38) or four (``lever_arm``); the runs of one signature
    on up to ``threads`` threads. The local steps replay the removed state's recorded gains
    (:func:`_removed_and_steps`): J is then A's derivative with its gains and gate decisions
    held, which is what "A linear at the effect-free state" means, at 0.6 of a full run's
    cost (the removed run records at 1.2; flight_time_offset_200hz, the lever arm's J on A's
    smoothed velocity: 0.04 % RMS from the full runs' finite difference). Returns
    ``[S_leg (M, 2, P)]``, legs in id order. Raises ValueError when A fails.

    ``jacobians`` (:data:`Jacobians`, updated in place): J made at an estimate within one
    local step h of p (``|p - p_J| <= h``) is taken instead of re-made, and only the removed
    state is re-run (the lever arm: 1 A run instead of 4; the warm-up: 1 instead of 3). J is
    the derivative at the effect-free state, where A's gate is open and its response linear
    (above): moving the point it is taken at by less than the finite difference's own step
    moves it by no more than the difference's truncation. The secant, which carries A's
    non-linearity, is always re-made at p.
    """
    p = np.asarray(p, dtype=float)
    size = float(np.linalg.norm(p))
    if not size > 0:
        raise ValueError(f"{effect_id}: the estimate is zero; use rerun_signatures")
    u = p / size
    h = LOCAL_STEP_FRACTION * effect_by_id(effect_id).plausible_si
    known = _jacobian_near(jacobians, effect_id, p, h)
    steps = [] if known is not None else list(h * np.eye(p.size))
    if effect_id == "lever_arm":
        lever = np.asarray(config.gnss.lever_arm_m, dtype=float) - p
        removed, cols = _removed_and_steps(
            lambda dl, **kw: _response_and_gains(log, nav, calib_run, config, navigate,
                                                 lever + dl, **kw), p.size, steps, threads)
    elif effect_id == "time_offset":
        removed = _response(restamped(log, -float(p[0])), nav, calib_run, config, navigate)
        cols = []
    elif effect_id == "gyro_scale_factor":
        removed = _response(with_rates(log, log.imu.w_ib_b_radps / (1.0 + p)), nav,
                            calib_run, config, navigate)
        cols = []  # the secant alone, along A's own estimate (see the docstring)
    elif effect_id == "accel_bias_change":
        removed, cols = _removed_and_steps(
            lambda db, **kw: _response_and_gains(warmed(log, db - p, accel_settling_s), nav,
                                                 calib_run, config, navigate, **kw),
            p.size, steps, threads)
    else:
        raise ValueError(f"{effect_id}: no Gauss-Newton signature ({GAUSS_NEWTON_EFFECTS})")
    if known is not None:
        local = known
    else:
        local = [np.stack([(c[k] - removed[k]) / h for c in cols], axis=-1) if cols
                 else np.zeros(removed[k].shape + p.shape) for k in range(len(removed))]
        if jacobians is not None and cols:
            jacobians[effect_id] = (p, local)
    return [s - np.einsum("mcp,p,q->mcq", s, u, u) + (-r / size)[:, :, None] * u
            for s, r in zip(local, removed, strict=True)]


def refine_signatures(log, nav, calib_run, config, signatures: dict[str, list[NDArray]],
                      estimates: dict[str, NDArray], at: dict[str, NDArray] | None = None,
                      *, navigate: Navigate, threads: int = 1,
                      jacobians: Jacobians | None = None
                      ) -> tuple[dict[str, list[NDArray]], dict[str, NDArray]]:
    """Gauss-Newton step: the signatures re-made at the current estimates (A is not linear).

    For each effect with an estimate p (SI, from a diagnosis with ``signatures``) larger than
    :data:`REFINE_FRACTION` of its plausible size, the signature becomes
    :func:`signature_at` p (secant along p, local derivatives at the effect-free state). A's
    chi-square gate makes its response to a GNSS-side effect change regime with the size
    (measured: a 12 ms GNSS offset is named 5 times in 5 with the 20 ms step and never with the
    2 ms one; a 4 ms offset reads -1.7 ms with the first, -3.8 ms with the second). Effects
    without an estimate, or whose estimate moved by less than :data:`REFINE_TOLERANCE` of
    itself since the signature in ``at`` was made, keep theirs. ``jacobians``: as
    :func:`signature_at`'s (updated in place). Returns the signatures and the estimates they
    were made at.
    """
    out = dict(signatures)
    at = dict(at or {})
    for eid, p in estimates.items():
        p = np.asarray(p, dtype=float)
        size = float(np.linalg.norm(p))
        if eid not in signatures or eid not in GAUSS_NEWTON_EFFECTS or \
                not size > REFINE_FRACTION * effect_by_id(eid).plausible_si:
            continue
        prev = at.get(eid)
        if prev is not None and np.linalg.norm(p - prev) <= REFINE_TOLERANCE * size:
            continue
        try:
            out[eid] = signature_at(log, nav, calib_run, config, eid, p, navigate=navigate,
                                    threads=threads, jacobians=jacobians)
        except (ValueError, np.linalg.LinAlgError):
            continue
        at[eid] = p
    return out, at


def _removed_and_steps(response: Callable[..., tuple[list[NDArray], Any]], size: int,
                       steps: list[NDArray], threads: int
                       ) -> tuple[list[NDArray], list[list[NDArray]]]:
    """B minus A's change at the removed state (``response(zeros(size))``) and at each of
    ``steps`` from it, the steps replaying the removed state's recorded gains
    (:class:`pospp.nav.filter.GainReplay`: K, S and the smoother's gains fixed, A's gate as
    there) where it recorded them, else as ``response`` runs A (its own replay)."""
    removed, gains = response(np.zeros(size), record_gains=bool(steps))
    replay = {} if gains is None else {"replay": gains}
    cols = map_in_threads(lambda d: response(d, **replay)[0], steps, threads)
    return removed, cols


def _jacobian_near(jacobians: Jacobians | None, effect_id: str, p: NDArray, h: float
                   ) -> list[NDArray] | None:
    """The local derivatives made at an estimate within ``h`` of ``p`` (SI), or None."""
    made = (jacobians or {}).get(effect_id)
    if made is None or made[0].shape != p.shape or not np.linalg.norm(p - made[0]) <= h:
        return None
    return made[1]


def first_estimates(diagnosis, alpha: float | None = None) -> dict[str, NDArray]:
    """Each re-run effect's first-step estimate, SI, where its candidate was significant, or,
    with ``alpha``, had a p-value below it before the Bonferroni correction (for
    :func:`refine_signatures`; a flight with nothing significant costs no refinement). The
    looser bar lets a candidate whose local signature is poor get its Gauss-Newton
    signature before it competes: a 12 ms GNSS offset read -12.2 ms at p = 0.013 against
    a 5-candidate Bonferroni bar of 0.01, and the lever arm it aliases into (0.75 m along x:
    v tau) was named instead (measured, docs/diagnose.md "Power")."""
    out = {}
    for c in diagnosis.candidates:
        if c.step == 1 and c.effect in RERUN_EFFECTS and np.size(c.values) and (
                c.significant or (alpha is not None and c.p_value < alpha)):
            out[c.effect] = np.asarray(c.values, dtype=float) * effect_by_id(c.effect).si_per_unit
    return out


def warmup_fit(t_s, accel_b_mps2, t_from_s: float, settling_s: float = ACCEL_SETTLING_S
               ) -> NDArray:
    """``db`` (body FRD x, y, m/s^2) of ``b(t) = b_inf + db exp(-t / T)`` fitted by least
    squares to an accelerometer-bias history ``accel_b_mps2`` (N, 3) [m/s^2] at ``t_s`` (N,)
    [s from the first IMU stamp], samples from ``t_from_s`` on (A's alignment point: before
    it the horizontal bias sits in A's tilt), T = ``settling_s`` [s]. For the history of A
    run with the warm-up's dynamics (``flight_stages.warmup_estimate``); A's own history under
    a tight bias model lags the warm-up and reads it as a constant (600 ug: b_inf 285 ug,
    db 77 ug; docs/diagnose.md, "Power")."""
    t = np.asarray(t_s, dtype=float)
    keep = t >= t_from_s
    e = np.exp(-t[keep] / settling_s)
    x = np.linalg.lstsq(np.column_stack([np.ones_like(e), e]),
                        np.asarray(accel_b_mps2, dtype=float)[keep, 0:2], rcond=None)[0]
    return np.asarray(x[1], dtype=float)


def gate_excess(nav: nav_filter.FilterResult, gate_probability: float) -> bool:
    """Whether A gated more GNSS records (position and velocity, gated or accepted after a
    covariance reset) than its own model allows (the QC check
    :func:`pospp.qc.stage.gate_check`: Poisson tail 1e-3). Where A's IMU error model does not
    hold (a 600 ug accelerometer warm-up against the "vehicle" preset's 30 ug: 33-39 of 3300
    records gated, one reset; none to 2 without it: docs/diagnose.md, "Power") A is not
    linear in the effect, and its derivative at zero is no place to start a Gauss-Newton."""
    return nav.innovations is not None and not gate_check(nav.innovations,
                                                          gate_probability).passed
