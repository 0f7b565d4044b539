"""Compensation: apply the calibrated errors to algorithm B and measure the improvement.

The calibrated gyro bias goes into the strapdown kernel (removed from every gyro increment);
the calibrated misalignment of a leg that took part in the fit corrects B's initial attitude
there. B is re-run on every leg, and B's error at ``horizon_s`` (300 s as in the paper, or
the leg end if shorter) is compared before and after.

Modes of the gyro bias removed (docs/calibration.md sections 5 and 9):

- constant: the calibrated bias b_g on every leg;
- per-leg: b_g plus the smoothed Gauss-Markov drift's mean over the leg;
- causal: a bias that changes inside the leg, built only from data up to each instant:
  algorithm A's forward (filter, not smoother) gyro-bias estimate fused with the calibrated
  bias as its prior (:func:`causal_gyro_bias_b_radps`), held over each IMU interval from the
  last A epoch at or before its start;
- smoothed: the gyro error's history estimated from the fit and A's forward estimates by a
  smoother with the fitted drift (:mod:`pospp.calib.bias_smoother`), the scale of A's noise
  chosen on the fitted legs (:func:`choose_bias_history`).

:data:`COMPENSATION_MODES` maps each mode to what it hands :func:`compensate_legs`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pospp.calib.bias_smoother import (
    A_NOISE_SCALES,
    ForwardBiases,
    constant_history,
    smoothed_bias_history,
)
from pospp.calib.bias_smoother import fit_bias_history as _fit_history
from pospp.calib.pairs import Pair
from pospp.calib.replay import (
    ImuIncrements,
    ImuSource,
    LegErrors,
    LegReplay,
    ReplayOptions,
    SolutionA,
    forced_response,
    replay_errors,
)
from pospp.calib.solve import Calibration, FitOptions, fit_calibration
from pospp.nav.error_model import DR, PHI
from pospp.threads import map_in_threads


@dataclass(frozen=True)
class LegImprovement:
    """B's horizontal error at the horizon, before and after compensation."""

    leg_id: int
    horizon_s: float
    vel_before_mps: float
    vel_after_mps: float
    pos_before_m: float
    pos_after_m: float
    in_fit: bool


def joint_calibration(
    replays: dict[int, LegReplay],
    pairs: tuple[Pair, ...],
    formulation: str,
    options: FitOptions | None = None,
    **caches: Any,
) -> Calibration | None:
    """One fit over every leg that belongs to a used pair (None if no pair is used):
    :func:`pospp.calib.solve.fit_calibration` with ``options`` and its ``caches`` (``bases``,
    ``gm_ops``, ``noise_cache``)."""
    ids = sorted({i for p in pairs if p.used for i in (p.leg_a, p.leg_b)})
    if len(ids) < 2:
        return None
    return fit_calibration(tuple(replays[i] for i in ids), formulation, options, **caches)


def horizontal_error_at(rep: LegReplay | LegErrors, horizon_s: float
                        ) -> tuple[float, float, float]:
    """(horizon actually used [s], |dv_h| [m/s], |dr_h| [m]) at min(horizon, leg end)."""
    k = int(np.searchsorted(rep.t_s, horizon_s - 1e-9))
    k = min(k, rep.t_s.size - 1)
    return (
        float(rep.t_s[k]),
        float(np.hypot(*rep.dv_n_mps[k, 0:2])),
        float(np.hypot(*rep.dr_n_m[k, 0:2])),
    )


def causal_gyro_bias_b_radps(
    forward_b_radps: NDArray,
    forward_sigma_b_radps: NDArray,
    prior_b_radps: NDArray,
    prior_sigma_b_radps: NDArray,
) -> NDArray:
    """Fuse A's forward gyro-bias estimate with the calibrated bias, axis by axis.

    ``b = w b_fwd + (1 - w) b_prior`` with ``w = s_prior^2 / (s_prior^2 + s_fwd^2)`` (inverse
    variance weighting of two estimates treated as independent); an infinite prior sigma
    (an axis the calibration did not estimate) gives A's estimate, a zero forward sigma too.

    Parameters
    ----------
    forward_b_radps, forward_sigma_b_radps : ndarray, shape (K, 3)
        A's forward (causal) gyro-bias estimate and its 1-sigma, body FRD [rad/s]
        (:class:`pospp.nav.filter.BiasHistory` of ``FilterResult.forward_biases``).
    prior_b_radps, prior_sigma_b_radps : ndarray, shape (3,)
        The calibrated body gyro bias and the 1-sigma of the bias **now** about it [rad/s]:
        with a Gauss-Markov drift the instantaneous bias is the constant plus the drift, so
        ``hypot(sigma of the constant, drift sigma)`` (:func:`prior_sigma_b_radps`).

    Returns
    -------
    ndarray, shape (K, 3)
        The fused bias [rad/s].
    """
    bf = np.asarray(forward_b_radps, dtype=float)
    vf = np.square(np.asarray(forward_sigma_b_radps, dtype=float))
    bp = np.broadcast_to(np.asarray(prior_b_radps, dtype=float), bf.shape)
    vp = np.broadcast_to(np.square(np.asarray(prior_sigma_b_radps, dtype=float)), bf.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(np.isinf(vp) | (vf == 0.0), 1.0, vp / (vp + vf))
    return w * bf + (1.0 - w) * bp


def prior_sigma_b_radps(constant_sigma_b_radps: NDArray, cal: Calibration) -> NDArray:
    """1-sigma of the instantaneous gyro bias about the calibrated constant [rad/s], (3,).

    ``hypot(sigma of the constant, Gauss-Markov drift sigma)``: the drift's steady-state
    sigma of the calibration's noise model (0 without one) is how far the bias at any instant
    may be from the constant.
    """
    return np.hypot(np.asarray(constant_sigma_b_radps, dtype=float), cal.gyro_gm_sigma_radps)


def _bias_removed(imu: ImuSource, rep: LegReplay, t_s: NDArray, b_radps: NDArray,
                  *, hold: bool) -> ImuIncrements:
    """The IMU increments around one leg minus a time-varying gyro bias b(t) (body, rad/s).

    ``hold``: each interval gets the last value at or before its start (causal); otherwise
    the value interpolated at its middle.
    """
    t = imu.t_s
    k0 = int(np.searchsorted(t, rep.leg.start_s))
    k1 = int(np.searchsorted(t, rep.leg.end_s, side="right"))
    lo, hi = max(k0 - 2, 0), min(k1 + 2, t.size - 1)
    if hold:
        j = np.clip(np.searchsorted(t_s, t[lo:hi], side="right") - 1, 0, t_s.size - 1)
        bias = b_radps[j]
    else:
        mid = 0.5 * (t[lo:hi] + t[lo + 1:hi + 1])
        bias = np.stack([np.interp(mid, t_s, b_radps[:, c]) for c in range(3)], axis=1)
    win = imu.window(lo, hi)
    dth = win.dtheta_b_rad - bias * np.diff(t[lo:hi + 1])[:, None]
    return ImuIncrements(win.t_s, dth, win.dv_b_mps)


def _drift_removed(imu: ImuSource, rep: LegReplay, cal: Calibration) -> ImuIncrements:
    """The IMU increments around one leg with the smoothed drift removed from the gyro."""
    t = imu.t_s
    k0 = int(np.searchsorted(t, rep.leg.start_s))
    k1 = int(np.searchsorted(t, rep.leg.end_s, side="right"))
    lo, hi = max(k0 - 2, 0), min(k1 + 2, t.size - 1)
    grid = np.arange(0.5 * (t[lo] + t[lo + 1]), 0.5 * (t[hi - 1] + t[hi]) + 1.0, 1.0)
    return _bias_removed(imu, rep, grid, cal.drift_b_radps(grid), hold=False)


def compensate_legs(
    imu: ImuSource,
    solution_a: SolutionA,
    before: dict[int, LegReplay],
    cal: Calibration,
    *,
    replay: ReplayOptions | None = None,
    per_leg_drift: bool = False,
    smoothed_drift: bool = False,
    gyro_bias_by_leg: Mapping[int, NDArray] | None = None,
    gyro_bias_history: tuple[NDArray, NDArray] | None = None,
    history_hold: bool = True,
    threads: int = 1,
) -> tuple[dict[int, LegErrors], tuple[LegImprovement, ...]]:
    """Re-run B on every leg with the calibration applied (B minus A, without B's error
    model); report the improvement.

    Every leg gets the calibrated gyro bias (``paper``: the nav-frame drift rotated into the
    body by that leg's initial attitude); legs that took part in the fit also get their
    calibrated initial misalignment. Held-out legs (``in_fit`` False) measure prediction.

    Parameters
    ----------
    replay : ReplayOptions, optional
        B's settings (accelerometer compensation, transition step, sample rate, sigma floor)
        and the horizon [s] the improvement is measured at (the defaults when None).
    per_leg_drift : bool
        Add the smoothed Gauss-Markov drift's mean over each leg
        (:meth:`Calibration.leg_drift_b_radps`; zero without a Gauss-Markov noise model) to
        the constant bias: b_leg = b_g + mean over the leg of E[x_g(t) | residuals].
    smoothed_drift : bool
        Remove the smoothed Gauss-Markov drift as it changes inside each leg,
        ``b(t) = b_g + E[x_g(t) | residuals]`` (:meth:`Calibration.drift_b_radps`, evaluated
        every second and interpolated to the IMU intervals), instead of one bias per leg.
    gyro_bias_by_leg : Mapping of leg id to ndarray, shape (3,), optional
        Body gyro bias [rad/s] to remove on those legs instead of the calibration's (e.g. the
        true realised per-leg mean bias of a simulation: the oracle that measures the floor
        left by the drift's change within a leg).
    gyro_bias_history : (t_s (K,), b (K, 3)), optional
        A time-varying body gyro bias [s, rad/s] removed instead of any of the above (the
        causal mode: :func:`causal_gyro_bias_b_radps` of A's forward estimate); each IMU
        interval gets the last value at or before its start, so no later data is used.
    history_hold : bool
        False: each IMU interval gets ``gyro_bias_history`` interpolated at its middle
        instead (a smoothed history, which is not causal anyway).
    threads : int
        Legs replayed at once (B's kernels release the GIL; the same replays at any number).
    """
    replay = replay if replay is not None else ReplayOptions()

    def one(item: tuple[int, LegReplay]) -> tuple[LegErrors, LegImprovement]:
        leg_id, rep = item
        in_fit = leg_id in cal.leg_ids
        phi = cal.misalignment_n_rad(leg_id) if in_fit else None
        bg = cal.gyro_bias_b_radps(rep.c_nb0)
        if per_leg_drift:
            bg = bg + cal.leg_drift_b_radps(rep)
        if gyro_bias_by_leg is not None and leg_id in gyro_bias_by_leg:
            bg = np.asarray(gyro_bias_by_leg[leg_id], dtype=float)
        leg_imu = _drift_removed(imu, rep, cal) if smoothed_drift else imu
        if gyro_bias_history is not None:
            hist_t, hist_b = (np.asarray(a, dtype=float) for a in gyro_bias_history)
            leg_imu = _bias_removed(imu, rep, hist_t, hist_b, hold=history_hold)
            bg = np.zeros(3)
        new = replay_errors(
            leg_imu, solution_a, rep.leg, gyro_bias_b_radps=bg, attitude_correction_n_rad=phi,
            accel_compensation=replay.accel_compensation, sample_rate_hz=replay.sample_rate_hz)
        h, v0, p0 = horizontal_error_at(rep, replay.horizon_s)
        _, v1, p1 = horizontal_error_at(new, replay.horizon_s)
        return new, LegImprovement(leg_id, h, v0, v1, p0, p1, in_fit)

    made = map_in_threads(one, before.items(), threads)
    return ({leg_id: m[0] for leg_id, m in zip(before, made, strict=True)},
            tuple(m[1] for m in made))


# --------------------------------------------------------------------------- the modes


CAUSAL_PRIOR_SCALE = 3.0
"""Default factor on the calibrated prior's sigma in the causal compensation (1: kept; > 1
weakened; inf: dropped, A's forward estimate alone). Weakened three times: on held-out legs
it ties with dropping the prior (within 5 %) and beats keeping it by 10-30 % at tau <= 300 s,
while the calibration still steadies A's estimate where that is loose (docs/calibration.md
section 9)."""


@dataclass(frozen=True)
class ModeInputs:
    """What a compensation mode reads (:data:`COMPENSATION_MODES`).

    Attributes
    ----------
    imu, solution_a, replays, cal
        The flight's IMU, A, B's replays before compensation (by leg id) and the chosen fit.
    constant_sigma_b_radps : ndarray, shape (3,)
        1-sigma of the fit's constant body gyro bias [rad/s] (inf: not estimated).
    replay : ReplayOptions
        B's settings.
    forward : BiasHistory or ForwardBiases, optional
        A's forward gyro-bias record (``causal``: ``t_s``, ``gyro_b_radps``,
        ``gyro_sigma_b_radps``; ``smoothed``: a :class:`ForwardBiases`).
    causal_prior_scale : float
        ``causal``: factor on the calibrated prior's sigma.
    threads : int
        Replays made at once.
    """

    imu: ImuSource
    solution_a: SolutionA
    replays: Mapping[int, LegReplay]
    cal: Calibration
    constant_sigma_b_radps: NDArray
    replay: ReplayOptions
    forward: Any = None
    causal_prior_scale: float = CAUSAL_PRIOR_SCALE
    threads: int = 1


@dataclass(frozen=True)
class ModeChoice:
    """A mode's answer: the keyword arguments of :func:`compensate_legs` and what they remove
    (``source``: "constant", "per_leg", "causal", or the smoothed mode's choice:
    :func:`choose_bias_history`)."""

    kwargs: Mapping[str, Any]
    source: str


def history_scores_m(inputs: ModeInputs, candidates: Mapping[str, tuple[NDArray, NDArray]]
                     ) -> dict[str, float]:
    """Per candidate history (t [s], b [rad/s] body), the RMS of B minus A's horizontal
    position [m] over the samples of the fitted legs up to the horizon (B's reach), B
    compensated as :func:`compensate_legs` does it (the leg's calibrated tilt, the history
    interpolated).

    B is replayed once per leg with the calibrated constant bias ``b_g``; a history's B is that
    replay plus B's linear response to ``db = b(t) - b_g`` more bias removed from its rates:
    its rate input changes by ``-db``, so ``phi' = C_nb db`` (:mod:`pospp.nav.error_model`),
    the position rows of :func:`pospp.calib.replay.forced_response`, every candidate in one
    pass per leg. B is linear in a gyro bias of this size to far below the scores'
    differences: its attitude error is what the bias integrates, 1 deg/h over 300 s is
    0.08 deg."""
    cal, rc = inputs.cal, inputs.replay
    lids = [i for i in cal.leg_ids if i in inputs.replays]

    def base(lid: int) -> NDArray:
        rep = inputs.replays[lid]
        return replay_errors(
            inputs.imu, inputs.solution_a, rep.leg,
            gyro_bias_b_radps=cal.gyro_bias_b_radps(rep.c_nb0),
            attitude_correction_n_rad=cal.misalignment_n_rad(lid),
            accel_compensation=rc.accel_compensation, sample_rate_hz=rc.sample_rate_hz).dr_n_m

    names = list(candidates)
    sq: list[NDArray] = []  # per leg, (its samples up to the horizon, candidates)
    for lid, dr0 in zip(lids, map_in_threads(base, lids, inputs.threads), strict=True):
        rep = inputs.replays[lid]
        at = rep.t0_s + rep.t_s
        db = np.stack([np.stack([np.interp(at, t_s, b[:, c]) for c in range(3)], axis=1)
                       for t_s, b in candidates.values()], axis=2)  # (M, 3, P)
        g = np.zeros((rep.t_s.size, 15, len(names)))
        g[:, PHI, :] = rep.c_nb @ (db - cal.gyro_bias_b_radps(rep.c_nb0)[:, None])
        dr = dr0[:, :, None] + forced_response(rep, g, rows=DR)
        k = int(np.searchsorted(rep.t_s, rc.horizon_s - 1e-9))
        sq.append(np.sum(np.square(dr[1:k + 1, 0:2]), axis=1))
    rms = np.sqrt(np.mean(np.concatenate(sq), axis=0))
    return {name: float(v) for name, v in zip(names, rms, strict=True)}


def choose_bias_history(inputs: ModeInputs,
                        candidates: Mapping[str, tuple[NDArray, NDArray]],
                        off_fit: Sequence[str]) -> ModeChoice:
    """The history under which B, compensated, best matches A over the fitted legs
    (:func:`history_scores_m`, least), spliced: on the fitted legs the best of
    ``candidates``, elsewhere the best of those named in ``off_fit``.

    The candidates share one time grid. The fitted legs' B minus A is not what the smoother
    reads (A's estimates and the fit's random effects), so the score weighs what A's
    estimates add; the constant among the candidates keeps the choice from doing worse than
    it on those legs. A leg outside the fit has no random effect of its own (the fit's history
    is the constant and the predicted drift there), so it takes the best of the histories
    that read A (``off_fit``): a candidate that wins on the fitted legs by their own
    residuals says nothing about A's weight elsewhere.
    """
    scores = history_scores_m(inputs, candidates)
    best = min(scores, key=lambda n: scores[n])
    other = min(off_fit, key=lambda n: scores[n])
    t, b = candidates[other]
    if best != other:
        b = b.copy()
        for lid in inputs.cal.leg_ids:
            rep = inputs.replays[lid]
            inside = (t >= rep.t0_s - 2.0) & (t <= rep.t0_s + rep.t_s[-1] + 2.0)
            b[inside] = candidates[best][1][inside]
    source = best if best == other else f"{best} on the fitted legs, {other} elsewhere"
    return ModeChoice({"gyro_bias_history": (t, b), "history_hold": False}, source)


def _constant_mode(inputs: ModeInputs) -> ModeChoice:
    return ModeChoice({}, "constant")


def _per_leg_mode(inputs: ModeInputs) -> ModeChoice:
    return ModeChoice({"per_leg_drift": True}, "per_leg")


def _causal_mode(inputs: ModeInputs) -> ModeChoice:
    fb = inputs.forward
    if fb is None:
        raise ValueError("compensation='causal' needs A's forward bias history "
                         "(forward_biases=FilterResult.forward_biases)")
    scale = inputs.causal_prior_scale
    prior = (np.full(3, np.inf) if np.isinf(scale)
             else scale * prior_sigma_b_radps(inputs.constant_sigma_b_radps, inputs.cal))
    first = inputs.replays[inputs.cal.leg_ids[0]]
    hist = causal_gyro_bias_b_radps(fb.gyro_b_radps, fb.gyro_sigma_b_radps,
                                    inputs.cal.gyro_bias_b_radps(first.c_nb0), prior)
    return ModeChoice({"gyro_bias_history": (np.asarray(fb.t_s, dtype=float), hist)}, "causal")


def _smoothed_mode(inputs: ModeInputs) -> ModeChoice:
    fb = inputs.forward
    if not isinstance(fb, ForwardBiases):
        raise ValueError("compensation='smoothed' needs A's forward bias record "
                         "(forward_biases=pospp.calib.bias_smoother.ForwardBiases)")
    grid, made = smoothed_bias_history(inputs.cal, inputs.replays, fb, A_NOISE_SCALES)
    smoothed = {f"smoothed x{a:g}": (grid, h) for a, h in zip(A_NOISE_SCALES, made,
                                                                strict=True)}
    candidates = {"constant": (grid, constant_history(inputs.cal, inputs.replays, grid)),
                  "fit": (grid, _fit_history(inputs.cal, inputs.replays, grid)), **smoothed}
    return choose_bias_history(inputs, candidates, tuple(smoothed))


COMPENSATION_MODES: dict[str, Callable[[ModeInputs], ModeChoice]] = {
    "constant": _constant_mode,
    "per_leg": _per_leg_mode,
    "causal": _causal_mode,
    "smoothed": _smoothed_mode,
}
"""Compensation mode -> what it removes (module docstring)."""
