"""The calibration stage: legs -> B replays -> pairs -> calibration -> compensation.

One call, :func:`calibrate_flight`, runs the double-strapdown online calibration of Liu &
Fang (2012) on a whole flight and returns a frozen :class:`CalibrationRun`. It never raises for
bad geometry (no legs, one leg, legs too short, ill-conditioned pairs): it returns what it
could and says why no calibration was produced in ``CalibrationRun.reason``.

Frames and units: NED (n), FRD (b), SI and radians; ``CalibrationRun.tables`` converts to the
output tables' units (deg, arcsec, deg/h, int64 ns) at the edge.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pospp.calib.bias_smoother import flight_bias_b_radps
from pospp.calib.compensate import (
    CAUSAL_PRIOR_SCALE,
    COMPENSATION_MODES,
    LegImprovement,
    ModeInputs,
    compensate_legs,
    joint_calibration,
)
from pospp.calib.design import FORMULATIONS
from pospp.calib.noise_model import gm_noise_operator, noise_basis
from pospp.calib.pairs import Pair, PairPolicy, evaluate_pairs
from pospp.calib.replay import (
    ImuSource,
    LegErrors,
    LegReplay,
    ReplayOptions,
    SolutionA,
    replay_legs,
)
from pospp.calib.segment import Leg, LegThresholds, find_legs
from pospp.calib.solve import Calibration, DriftPrior, FitOptions
from pospp.calib.tables import (
    Row,
    calibration_rows,
    calibration_table,
    leg_errors_table,
    legs_table,
    pairs_table,
)
from pospp.units import DEG_PER_H_RADPS
from pospp.units import DEG_PER_SQRT_H_RAD_PER_SQRT_S as _DPSH_RADPSQRTS

"""One deg/sqrt(h) in rad/sqrt(s)."""
COMPENSATIONS = tuple(COMPENSATION_MODES)
_REML_STEP_S = 20.0
"""Sample spacing of the one REML fit of the Gauss-Markov sigma [s] (the GLS uses 10 s)."""


@dataclass(frozen=True)
class CalibrationRun:
    """Everything the calibration stage produced.

    Attributes
    ----------
    legs : tuple of Leg
        Straight uniform legs found on A's trajectory.
    replays : Mapping of int to LegReplay
        B minus A per leg before compensation (legs whose replay failed are absent).
    pairs : tuple of Pair
        Every candidate pair with dH, dV, condition numbers, used, reason and, when used, one
        calibration per formulation.
    joint : tuple of Calibration
        One fit per formulation over all legs of the used pairs (empty if none).
    chosen : Calibration or None
        The joint fit of the compensation formulation (``PairsConfig.formulation``).
    replays_after : Mapping of int to LegErrors
        B re-run with ``chosen`` applied (empty if no calibration).
    improvements : tuple of LegImprovement
        B's horizontal error at the horizon (300 s or the leg end) before and after.
    gyro_bias_b_radps, gyro_bias_sigma_b_radps : ndarray, shape (3,)
        Calibrated body gyro bias to feed back into A, and its 1-sigma (zeros / inf when no
        calibration; z is not estimated unless asked).
    misalignment_n_rad : Mapping of int to ndarray, shape (3,)
        Calibrated B initial misalignment (NED) per fitted leg: A's attitude error there.
    reason : str
        "ok" or why no calibration was produced.
    messages : tuple of str
        Per-leg problems (replay failures) and notes.
    fit_options : FitOptions
        The least squares' model as the joint fit used it (the flight's drift and ARW fixed
        where REML read them): :func:`with_null_covariance` and the refits re-run that fit.
    fit_bases : Mapping
        Its precomputed per-leg noise bases and drift operators (``bases``, ``gm_ops`` of
        :func:`pospp.calib.solve.fit_calibration`).
    sigma_source : str
        Where the chosen calibration's covariance comes from: "least_squares" (the GLS's
        formal covariance), "linear_null" (its exact covariance under the linear null,
        :func:`pospp.null_stage.with_null_sigmas`) or "null_realisations" (refits on the
        realisations, :func:`with_null_covariance`).
    drift_sigma_radps, drift_tau_s : float
        The Gauss-Markov gyro drift of the noise model (steady-state sigma [rad/s] per body
        axis, correlation time [s]); 0 and inf without the drift model. The null
        realisations inject this drift (:func:`pospp.pipeline.null_realisations`).
    drift_source : str
        "flight" (sigma and tau by REML on this flight's joint fit, the grade a weak prior,
        and the flight rejects the grade's drift), "grade" (estimated the same way, but the
        flight does not reject the grade's, which is kept), "flight_sigma" (sigma by REML,
        tau given), "given" (both given) or "none".
    """

    legs: tuple[Leg, ...]
    replays: Mapping[int, LegReplay]
    pairs: tuple[Pair, ...]
    joint: tuple[Calibration, ...]
    chosen: Calibration | None
    replays_after: Mapping[int, LegErrors]
    improvements: tuple[LegImprovement, ...]
    gyro_bias_b_radps: NDArray
    gyro_bias_sigma_b_radps: NDArray
    misalignment_n_rad: Mapping[int, NDArray]
    reason: str
    messages: tuple[str, ...]
    fit_options: FitOptions = field(default_factory=FitOptions, repr=False, compare=False)
    fit_bases: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    sigma_source: str = "least_squares"
    drift_sigma_radps: float = 0.0
    drift_tau_s: float = float("inf")
    drift_source: str = "none"
    leg_refusals: Mapping[int, str] = field(default_factory=dict)
    """Legs left out before B was replayed, with why (their reference A not GNSS-aided)."""
    flight_gyro_bias_b_radps: NDArray = field(default_factory=lambda: np.zeros(3))
    """The gyro bias over this flight's fitted legs (what was used), body FRD [rad/s]: the
    legs' duration-weighted mean of the fit's estimate of each leg's mean gyro error
    (:func:`pospp.calib.bias_smoother.flight_bias_b_radps`)."""
    flight_gyro_bias_sigma_b_radps: NDArray = field(
        default_factory=lambda: np.full(3, np.inf))
    """Its 1-sigma against that flight's own bias [rad/s] (null realisations: each one's
    injected gyro error over the legs removed; least squares: the constant's sigma, an upper
    bound)."""
    compensation_source: str = ""
    """What the compensation removed: "constant", "per_leg", "causal", or for "smoothed" the
    history chosen on the fitted legs ("constant", "fit", "smoothed x<alpha>";
    :func:`pospp.calib.compensate.choose_bias_history`)."""

    @property
    def calibrated(self) -> bool:
        """True when a calibration was produced and applied."""
        return self.chosen is not None

    def joint_calibration(self, formulation: str) -> Calibration | None:
        """The joint fit of one formulation (None if absent)."""
        for c in self.joint:
            if c.formulation == formulation:
                return c
        return None

    def summary(self) -> dict[str, Any]:
        """Key figures (summary table columns): counts, RMS over legs at the horizon, the
        calibrated body gyro bias with its sigma [deg/h] (NaN: not estimated) and the chosen
        fit's parameters that are not observable, with why (``pospp.outputs.not_observable``)."""
        imp = self.improvements

        def rms(vals: list[float]) -> float:
            return float(np.sqrt(np.mean(np.square(vals)))) if vals else float("nan")

        from pospp.outputs import not_observable, velocity_gap_rms_mps

        out: dict[str, Any] = {
            "n_legs": len(self.legs),
            "n_pairs_used": sum(p.used for p in self.pairs),
            "dv_before_mps": rms([i.vel_before_mps for i in imp]),
            "dv_after_mps": rms([i.vel_after_mps for i in imp]),
            "dp_before_m": rms([i.pos_before_m for i in imp]),
            "dp_after_m": rms([i.pos_after_m for i in imp]),
            "gap_uncalibrated_mps": velocity_gap_rms_mps(
                [self.replays[i].dv_n_mps for i in sorted(self.replays)]),
        }
        if self.chosen is None:
            return out
        out["calibration_formulation"] = self.chosen.formulation
        out["calibration_sigma_source"] = self.sigma_source
        out["gyro_drift_sigma_dph"] = self.drift_sigma_radps / DEG_PER_H_RADPS
        out["gyro_drift_tau_s"] = self.drift_tau_s
        out["gyro_drift_source"] = self.drift_source
        for i, ax in enumerate("xyz"):
            for tag, b, s in (("", self.gyro_bias_b_radps, self.gyro_bias_sigma_b_radps),
                              ("_flight", self.flight_gyro_bias_b_radps,
                               self.flight_gyro_bias_sigma_b_radps)):
                known = bool(np.isfinite(s[i]))
                dph = (float(b[i]) / DEG_PER_H_RADPS, float(s[i]) / DEG_PER_H_RADPS)
                out[f"gyro_bias_{ax}{tag}_dph"] = dph[0] if known else float("nan")
                out[f"gyro_bias_{ax}{tag}_sigma_dph"] = dph[1] if known else float("nan")
        flags = [f"{name}: {why}" for name, _, s, u in calibration_rows(self.chosen)
                 if (why := not_observable(name, s, u))]
        out["not_observable"] = "; ".join(flags)
        return out

    def _flight_rows(self) -> dict[str, list[Row]]:
        """The chosen fit's rows of the flight's gyro bias (``gyro_bias_x_flight``, deg/h)."""
        if self.chosen is None:
            return {}
        b, s = self.flight_gyro_bias_b_radps, self.flight_gyro_bias_sigma_b_radps
        rows = [(f"gyro_bias_{ax}_flight", float(b[i]) / DEG_PER_H_RADPS,
                 float(s[i]) / DEG_PER_H_RADPS, "deg_per_h") for i, ax in enumerate("xyz")
                if np.isfinite(self.flight_gyro_bias_sigma_b_radps[i])]
        return {self.chosen.formulation: rows}

    def tables(self, epoch_ns: int) -> dict[str, dict[str, Any]]:
        """Column dicts of the ``legs``, ``pairs``, ``calibration`` and ``leg_errors`` tables.

        Parameters
        ----------
        epoch_ns : int
            UTC nanoseconds of t_s = 0 (the run's epoch).
        """
        return {
            "legs": {**legs_table(self.legs, epoch_ns),
                     "reason": [self.leg_refusals.get(g.leg_id, "ok") for g in self.legs]},
            "pairs": pairs_table(self.pairs),
            "calibration": calibration_table(self.pairs, self.joint, self._flight_rows()),
            "leg_errors": leg_errors_table(self.replays, self.replays_after),
        }


@dataclass(frozen=True)
class CalibrationOptions:
    """How :func:`calibrate_flight` segments, pairs, fits and compensates (one options object;
    :meth:`pospp.config.PipelineConfig` builds it for a run).

    Attributes
    ----------
    legs_cfg : LegThresholds
        Leg thresholds (``PipelineConfig.legs.thresholds()``).
    replay_cfg : ReplayOptions
        B's settings (``PipelineConfig.replay.options()``).
    pairs_cfg : PairPolicy
        Pairing policy (``PipelineConfig.pairs.policy()``).
    formulations : tuple of str
        Formulations calibrated and reported ("paper", "body"); the compensation formulation
        is added if missing.
    transition : {"numerical", "closed_form"}, optional
        Overrides ``pairs_cfg.transition``.
    noise : {"gyro_rw", "white"}
        Residual model of the least squares (:mod:`pospp.calib.solve`).
    gyro_arw_dpsh : float, optional
        Gyro angle random walk [deg/sqrt(h)] (IMU specification); estimated by REML if None.
    estimate_gyro_z : bool
        Also estimate the vertical body gyro bias (weak on straight level legs).
    gyro_gm_sigma_dph, gyro_gm_tau_s : float, optional
        First-order Gauss-Markov ("random") gyro drift of the IMU grade (steady-state sigma
        [deg/h], correlation time [s]; ``pospp.nav.tuning.tuning_preset(grade)``): added to
        the ``"gyro_rw"`` covariance, coupling the legs (:func:`pospp.calib.solve.fit_calibration`).
        Off when the tau is None; the sigma is estimated by REML when None and the tau given.
    gyro_gm_prior_sigma_dph : float, optional
        With the sigma estimated (None) and the tau given: the grade's drift sigma [deg/h];
        then the drift's sigma **and** tau are the flight's (REML profiled over candidate
        taus on the joint fit), the grade's sigma and tau a weak log-normal prior
        (:class:`pospp.calib.solve.DriftPrior`, one decade 1-sigma).
    compensation : {"constant", "per_leg", "causal", "smoothed"}
        What B is re-run with (:data:`pospp.calib.compensate.COMPENSATION_MODES`): the
        constant bias, the constant plus the smoothed drift's mean over each leg
        (``"per_leg"``, needs the Gauss-Markov model), A's forward estimate fused with the
        constant (``"causal"``), or the gyro error's history smoothed from the fit and A's
        forward estimates (``"smoothed"``, :mod:`pospp.calib.bias_smoother`; the pipeline's
        default). The constant bias is what ``gyro_bias_b_radps`` feeds back into A either way.
    causal_prior_scale : float
        ``compensation="causal"``: the calibrated prior's sigma is multiplied by this (1: the
        prior kept, > 1 weakened, ``inf``: dropped, A's forward estimate alone).
    noise_step_s : float
        Spacing of the samples of the correlated-noise least squares [s] (a leg shorter than
        ten steps is sampled every tenth of its length).
    """

    legs_cfg: LegThresholds = field(default_factory=LegThresholds)
    replay_cfg: ReplayOptions = field(default_factory=ReplayOptions)
    pairs_cfg: PairPolicy = field(default_factory=PairPolicy)
    formulations: tuple[str, ...] = FORMULATIONS
    transition: str | None = None
    noise: str = "gyro_rw"
    gyro_arw_dpsh: float | None = None
    estimate_gyro_z: bool = False
    gyro_gm_sigma_dph: float | None = None
    gyro_gm_tau_s: float | None = None
    gyro_gm_prior_sigma_dph: float | None = None
    compensation: str = "constant"
    causal_prior_scale: float = CAUSAL_PRIOR_SCALE
    noise_step_s: float = 10.0

    def __post_init__(self) -> None:
        if self.compensation not in COMPENSATIONS:
            raise ValueError(f"compensation: expected one of {COMPENSATIONS}, "
                             f"got {self.compensation!r}")
        if self.compensation == "per_leg" and not self.gm_on:
            raise ValueError("compensation='per_leg' needs the Gauss-Markov drift model "
                             "(noise='gyro_rw' and gyro_gm_tau_s given)")

    @property
    def gm_on(self) -> bool:
        """Whether the fit carries the Gauss-Markov gyro drift."""
        return self.noise == "gyro_rw" and self.gyro_gm_tau_s is not None and (
            self.gyro_gm_sigma_dph is None or self.gyro_gm_sigma_dph > 0)

    def policy(self) -> PairPolicy:
        """The pairing policy, its transition overridden by :attr:`transition` when given."""
        p = self.pairs_cfg
        return p if self.transition is None else replace(p, transition=self.transition)

    def formulations_fitted(self) -> tuple[str, ...]:
        """:attr:`formulations` and the compensation's formulation."""
        f, chosen = tuple(self.formulations), self.policy().formulation
        return f + (() if chosen in f else (chosen,))

    def fit_options(self) -> FitOptions:
        """The least squares' model before the flight is seen
        (:func:`pospp.calib.solve.fit_calibration`; SI)."""
        on = self.gm_on
        return FitOptions(
            transition=self.policy().transition, estimate_gyro_z=self.estimate_gyro_z,
            noise=self.noise, noise_step_s=self.noise_step_s,
            gyro_arw_radpsqrts=(None if self.gyro_arw_dpsh is None
                                else self.gyro_arw_dpsh * _DPSH_RADPSQRTS),
            gyro_gm_tau_s=(float(self.gyro_gm_tau_s) if on and self.gyro_gm_tau_s is not None
                           else None),
            gyro_gm_sigma_radps=(self.gyro_gm_sigma_dph * DEG_PER_H_RADPS
                                 if on and self.gyro_gm_sigma_dph is not None else None))


def calibrate_flight(
    imu: ImuSource,
    solution_a: SolutionA,
    options: CalibrationOptions | None = None,
    *,
    legs: tuple[Leg, ...] | None = None,
    forward_biases: Any = None,
    made_replays: tuple[dict[int, LegReplay], tuple[str, ...]] | None = None,
    leg_refusals: Mapping[int, str] | None = None,
    threads: int = 1,
) -> CalibrationRun:
    """Run the double-strapdown calibration on one flight (module docstring).

    Parameters
    ----------
    imu : ImuIncrements or ImuRates
        Raw IMU increments of the whole flight (body FRD, rad and m/s).
    solution_a : SolutionA
        Algorithm A (the smoothed solution by default: its errors at each leg start and along
        the leg are the smallest, and B minus A must be B's error).
    options : CalibrationOptions, optional
        How the flight is segmented, paired, fitted and compensated (the defaults when None).
    legs : tuple of Leg, optional
        Use these legs instead of segmenting A's trajectory.
    forward_biases : ForwardBiases or pospp.nav.filter.BiasHistory, optional
        A's forward (filter) gyro-bias record on the run's time axis: ``t_s`` (K,),
        ``gyro_b_radps`` and ``gyro_sigma_b_radps`` (K, 3), body FRD; ``"smoothed"`` needs a
        :class:`pospp.calib.bias_smoother.ForwardBiases` (with A's update times). Used by
        ``"causal"`` and ``"smoothed"`` only.
    made_replays : (replays, messages), optional
        :func:`pospp.calib.replay.replay_legs` of ``legs`` (given with them) with the options'
        ``replay_cfg``, already made; made here when None.
    leg_refusals : Mapping of int to str, optional
        Legs not replayed, with why (reference A not GNSS-aided): in their pairs' reasons.
    threads : int
        B's replays before and after the compensation made that many legs at once.

    Returns
    -------
    CalibrationRun
    """
    o = options if options is not None else CalibrationOptions()
    th, policy, rc = o.legs_cfg, o.policy(), o.replay_cfg
    if o.compensation in ("causal", "smoothed") and forward_biases is None:
        raise ValueError(f"compensation={o.compensation!r} needs A's forward bias record "
                         "(forward_biases=)")
    fit, bases, messages = o.fit_options(), dict[str, Any](), list[str]()
    if legs is None:
        if made_replays is not None:
            raise ValueError("calibrate_flight: made_replays given without their legs")
        t = solution_a.trajectory
        legs = find_legs(t.t_s, t.v_n_mps, t.height_m, thresholds=th)
    replays, failed = (replay_legs(imu, solution_a, legs, rc, threads) if made_replays is None
                       else made_replays)
    messages.extend(failed)
    refusals = dict(leg_refusals or {})  # in the legs table and their pairs' reasons

    def done(reason: str, pairs: tuple[Pair, ...] = (), joint: tuple[Calibration, ...] = ()
             ) -> CalibrationRun:
        return CalibrationRun(legs, replays, pairs, joint, None, {}, (), np.zeros(3),
                              np.full(3, np.inf), {}, reason, tuple(messages),
                              leg_refusals=refusals)

    if len(legs) < 2:
        return done(_too_few_legs(legs, th))
    if o.noise == "gyro_rw":  # the correlated noise's bases, made once for every fit
        bases["bases"] = {i: noise_basis(r, noise_step_s=o.noise_step_s)
                          for i, r in replays.items()}
        if o.gm_on:
            bases["gm_ops"] = {i: gm_noise_operator(r, bases["bases"][i].samples)
                               for i, r in replays.items()}
    drift_source = "none" if not o.gm_on else (
        "given" if fit.gyro_gm_sigma_radps is not None else "flight_sigma")
    if o.gm_on and fit.gyro_gm_sigma_radps is None:
        fit, drift_source = _drift_by_reml(replays, legs, o, refusals, fit, bases, messages,
                                           drift_source)
    pairs = evaluate_pairs(replays, legs, policy, formulations=o.formulations_fitted(),
                           leg_reasons=refusals, options=fit, **bases)
    if not any(p.used for p in pairs):
        why = "; ".join(f"pair {p.pair_id} (legs {p.leg_a}, {p.leg_b}): {p.reason}"
                        for p in pairs)
        return done(f"no calibration: no pair passed the screening: {why}", pairs)
    try:
        joint = tuple(c for f in o.formulations_fitted() if (c := joint_calibration(
            replays, pairs, f, fit, **bases)) is not None)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return done(f"no calibration: the joint least squares failed: {exc}", pairs)
    chosen = next(c for c in joint if c.formulation == policy.formulation)
    first = replays[chosen.leg_ids[0]]
    bg = chosen.gyro_bias_b_radps(first.c_nb0)
    sig = gyro_bias_sigma_b_radps(chosen, first)
    if chosen.formulation != "body":
        messages.append("paper formulation chosen: its nav-frame drift is rotated into the body "
                        f"with leg {first.leg.leg_id}'s attitude")
    mode = COMPENSATION_MODES[o.compensation](ModeInputs(
        imu, solution_a, replays, chosen, sig, rc, forward_biases, o.causal_prior_scale,
        threads))
    after, improvements = compensate_legs(imu, solution_a, replays, chosen, replay=rc,
                                          threads=threads, **mode.kwargs)
    mis = {i: chosen.misalignment_n_rad(i) for i in chosen.leg_ids}
    return CalibrationRun(legs, replays, pairs, joint, chosen, after, improvements, bg, sig, mis,
                          "ok", tuple(messages),
                          fit_options=fit, fit_bases=bases,
                          drift_sigma_radps=float(chosen.gyro_gm_sigma_radps),
                          drift_tau_s=float(chosen.gyro_gm_tau_s),
                          drift_source=drift_source if o.gm_on else "none",
                          leg_refusals=refusals,
                          flight_gyro_bias_b_radps=flight_bias_b_radps(chosen, replays),
                          flight_gyro_bias_sigma_b_radps=sig,
                          compensation_source=mode.source)


def _too_few_legs(legs: tuple[Leg, ...], th: LegThresholds) -> str:
    """Why no calibration was made from fewer than two legs."""
    if legs:
        return (f"no calibration: only one leg (leg {legs[0].leg_id}) was found; a pair "
                "needs two legs with different headings")
    return ("no calibration: no straight, level, uniform leg of at least "
            f"{th.min_duration_s - th.duration_tolerance_s:g} s was found "
            f"(heading rate < {th.max_heading_rate_dps:g} deg/s, speed std < "
            f"{th.max_speed_std_mps:g} m/s, |v_D| < {th.max_vertical_speed_mps:g} m/s)")


def _drift_by_reml(replays: dict[int, LegReplay], legs: tuple[Leg, ...],
                   o: CalibrationOptions, refusals: Mapping[int, str], fit: FitOptions,
                   bases: Mapping[str, Any], messages: list[str], drift_source: str
                   ) -> tuple[FitOptions, str]:
    """The Gauss-Markov drift's sigma (and, with the grade's prior, its tau) by REML once, on
    the joint fit of the compensation formulation over the legs of the usable pairs (rows
    every :data:`_REML_STEP_S`), fixed in the model for the pairs and the other formulations
    to reuse (with the ARW when it was not given; a pair alone has too few legs to estimate
    it); its message appended. Returns the model and the drift's source ("flight", "grade"
    or ``drift_source``)."""
    policy = o.policy()
    assert o.gyro_gm_tau_s is not None  # gm_on needs it
    prior = (DriftPrior(o.gyro_gm_prior_sigma_dph * DEG_PER_H_RADPS, float(o.gyro_gm_tau_s))
             if o.gyro_gm_prior_sigma_dph else None)
    screened = evaluate_pairs(replays, legs, policy, formulations=(), leg_reasons=refusals,
                              options=fit, **bases)
    coarse = {i: noise_basis(r, noise_step_s=_REML_STEP_S) for i, r in replays.items()}
    first_fit = joint_calibration(
        replays, screened, policy.formulation,
        replace(fit, noise_step_s=_REML_STEP_S, gm_prior=prior), bases=coarse,
        gm_ops={i: gm_noise_operator(r, coarse[i].samples) for i, r in replays.items()})
    if first_fit is None:
        return fit, drift_source
    fit = replace(fit, gyro_gm_sigma_radps=first_fit.gyro_gm_sigma_radps,
                  gyro_arw_radpsqrts=(first_fit.gyro_arw_radpsqrts
                                      if fit.gyro_arw_radpsqrts is None
                                      else fit.gyro_arw_radpsqrts))
    sigma_dph = first_fit.gyro_gm_sigma_radps / DEG_PER_H_RADPS
    if prior is None:
        messages.append("Gauss-Markov gyro drift sigma by REML on the joint "
                        f"{policy.formulation} fit: {sigma_dph:.3f} deg/h")
        return fit, drift_source
    messages.append(
        f"Gauss-Markov gyro drift by REML on the joint {policy.formulation} fit (grade "
        f"{o.gyro_gm_prior_sigma_dph:g} deg/h, {float(o.gyro_gm_tau_s):g} s as a weak prior): "
        f"{sigma_dph:.3f} deg/h, {first_fit.gyro_gm_tau_s:.0f} s ("
        + ("the flight rejects the grade's drift" if first_fit.gm_source == "flight"
           else "the flight does not reject the grade's drift: kept") + ")")
    return replace(fit, gyro_gm_tau_s=first_fit.gyro_gm_tau_s), first_fit.gm_source


def gyro_bias_sigma_b_radps(chosen: Calibration, first: LegReplay) -> NDArray:
    """1-sigma of the calibrated body gyro bias (inf for an axis not estimated) [rad/s].

    Parameters
    ----------
    chosen : Calibration
        The fit; ``body`` formulation: the sigmas of its ``gyro_bias_{x,y,z}`` (FRD b).
    first : LegReplay
        The fit's first leg; ``paper`` formulation: its navigation-frame drift covariance
        (eps_N, eps_E) rotated into the body with this leg's initial attitude,
        ``sqrt(diag(C_bn[:, :2] cov C_bn[:, :2]^T))``.

    Returns
    -------
    (3,) float
        sigma of (b_x, b_y, b_z) [rad/s].
    """
    if chosen.formulation == "body":
        sig = np.full(3, np.inf)
        for i, ax in enumerate("xyz"):
            if f"gyro_bias_{ax}" in chosen.names:
                sig[i] = chosen.sigma_of(f"gyro_bias_{ax}")
        return sig
    c_bn = first.c_nb0.T[:, 0:2]
    return np.sqrt(np.diag(c_bn @ chosen.cov[3:5, 3:5] @ c_bn.T))
