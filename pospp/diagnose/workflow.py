"""Model-discrepancy workflow: predict, compare, name, add, iterate.

Frames and units: NED (n), FRD (b), SI inside; display units only in the output rows.
Errors are computed minus true (B minus A).

Measurements: B's horizontal velocity error [dv_N, dv_E] at the samples t > 0 of every leg
(:class:`pospp.calib.replay.LegReplay`), weighted by A's sigmas (and, when the gyro angle
random walk is given, by the correlated covariance of :func:`pospp.calib.noise_model.
gyro_noise_covariance`, ``noise="gyro_rw"``), i.e. whitened by the Cholesky factor of each
leg's covariance.

Base model (what the calibration estimates, paper Eq. 17 with pospp's signs)::

    dv_h(t) = S_phi(t) [phi_N,leg, phi_E,leg, phi_D] + S_bg(t) b        (+ effects)

with per-leg tilts (B's initial tilt is A's error at that leg's start), one heading error
common to the legs and the horizontal drift b: body-frame [b_x, b_y] projected by the leg's
attitude (``"body"``), or a navigation-frame constant [eps_N, eps_E] (``"paper"``). The
sensitivities S come from the numerical transition matrices along B (``"numerical"``) or from
the paper's closed form (``"closed_form"``, :mod:`pospp.nav.closed_form`).

Steps
-----
1. Predict: fit, and predict each leg from the others (leave-one-leg-out: the common
   parameters from the other legs, the held-out leg's own tilt fitted on it).
2. Compare: residual RMS overall and per leg, held-out prediction error, and where the gap sits
   (per leg: heading, speed, start time; per third of each leg).
3. Name: every library effect (:mod:`pospp.diagnose.effects`) adds the columns of its
   signature. Parameter directions in which an effect of a large but plausible size would not
   stand 2 sigma above the current model are unobservable with these legs and dropped (one with none
   left is reported unobservable, not tested). Each remaining candidate is tested by the
   nested-model F-test on the whitened residuals::

       F = ((RSS_0 - RSS_1) / r) / (RSS_1 / (n - p_1)),      p = P(F_{r, n - p_1} > F)

   at level alpha / (number of candidates tested) (Bonferroni), together with the
   leave-one-leg-out prediction error, which must decrease (in m/s; for the vertical drift,
   which every IMU carries, in noise units: :data:`HELDOUT_WHITENED`). A lack-of-fit basis
   (per leg and channel, Legendre polynomials up to degree 4 and cosines cos(pi k t / T), 0 < k <
   ``lof_terms``) measures the whole structured gap (the polynomials keep smooth gaps in the
   span even when a correlated-noise whitening amplifies the cosines' truncation error); a
   candidate is named only when its RSS reduction beyond noise is at least
   ``min_explained_fraction`` (0.9) of the basis's: otherwise it would be a wrong effect
   soaking up part of a gap it does not explain (a wrong candidate correlated with an
   out-of-library effect typically explains 40 to 85 per cent). Two effects present at once
   each explain part of the gap: a pair of significant candidates is accepted when together
   they explain that share and leave no significant lack of fit; the one with the larger F is
   named first. The BIC difference is reported alongside.
4. Add: the named effect joins the model, and the search repeats while a candidate remains
   significant (at most ``max_steps``).
5. Close: a final lack-of-fit F-test of the last model: ``"none"`` when no structured gap
   remains at level alpha, ``"unexplained"`` when one does and no candidate explains it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pospp.calib.noise_model import NoiseModel
from pospp.calib.pairs import PairPolicy, heading_difference_rad
from pospp.calib.replay import ImuSource, LegReplay, SolutionA
from pospp.calib.segment import Leg
from pospp.calib.solve import FitOptions, fit_calibration, fit_noise_model
from pospp.diagnose import effects as fx
from pospp.diagnose._candidates import (
    family_trial,
    leg_origins,
    shape_signatures,
    shaped,
    trial,
)
from pospp.diagnose._linear import Fit, Problem, Term, f_test, rms
from pospp.diagnose._terms import (
    LOF_DEGREE,
    base_terms,
    base_x_per_leg,
    lof_term,
)
from pospp.diagnose.locate import GapLocation, horizon_worth, locate_gap
from pospp.diagnose.null_calibration import NullCalibration as _NullCalibration
from pospp.diagnose.results import CandidateTest, Diagnosis, DiagnosisStep, LegGap

BASE_FORMULATIONS = ("body", "paper")
BASE_TRANSITIONS = ("numerical", "closed_form")
CRITERION = "F_test_bonferroni_and_heldout"
LOF_CRITERION = "lack_of_fit_F"


# --------------------------------------------------------------------------------------------
# model comparison


def _phaserms(res: NDArray, n_phase: int = 3) -> NDArray:
    r = res.reshape(-1, 2)
    parts = np.array_split(np.arange(r.shape[0]), n_phase)
    return np.array([float(np.sqrt(np.mean(r[p] ** 2))) if p.size else np.nan for p in parts])


def _explained_fraction(prob: Problem, terms: list[Term], fit0: Fit, fit_lof: Fit,
                        lof: list[Term], s2_lof: float, g_lof: float,
                        null: _NullCalibration | None, terms1: list[Term], fit1: Fit) -> float:
    """Share of the structured gap (the lack-of-fit basis's RSS reduction beyond ``terms``)
    that ``terms1`` explains, both beyond what noise alone would take out.

    White expectation (no null): one residual variance ``s2_lof`` per parameter. With null
    realisations, the noise's reduction per parameter is the mean null F of the same nested
    test (``g_lof`` for the basis), in units of the noise variance of the fullest model
    ``terms1 + lof`` (an effect faster than the basis would otherwise stay in the variance).
    """
    if null is None:
        excess = fit0.rss_w - fit1.rss_w - (fit1.rank - fit0.rank) * s2_lof
        total = fit0.rss_w - fit_lof.rss_w - (fit_lof.rank - fit0.rank) * s2_lof
        return float(excess / total) if total > 0 else 0.0
    full = prob.fit(terms1 + lof)
    s2n = full.rss_w / max(prob.n - full.rank, 1)
    excess = fit0.rss_w - fit1.rss_w - (fit1.rank - fit0.rank) * s2n * \
        null.noise_factor(terms, terms1)
    total = fit0.rss_w - fit_lof.rss_w - (fit_lof.rank - fit0.rank) * s2n * g_lof
    return float(excess / total) if total > 0 else 0.0


def _pair_explaining(prob: Problem, terms: list[Term], fit0: Fit, trials: list[dict],
                     lof: list[Term], frac_of: Callable[[list[Term], Fit], float], alpha: float,
                     min_fraction: float, null: _NullCalibration | None = None) -> list[dict]:
    """Two significant candidates that together explain the structured gap, or [].

    Two real effects of similar size each explain only part of the gap; they are accepted
    together when their joint RSS reduction is at least ``min_fraction`` of the lack-of-fit
    basis's (``frac_of(terms, fit)``: the share beyond noise) and no structured gap remains
    after both (lack-of-fit F-test at ``alpha``).
    """
    cands = sorted((tr for tr in trials if tr["sig"] and tr["frac"] >= 0.25),
                   key=lambda tr: -tr["f"])[:4]
    n = prob.n
    best_pair: list[dict] = []
    best_frac = min_fraction
    for i, a in enumerate(cands):
        for b in cands[i + 1:]:
            both = prob.fit(terms + [a["term"], b["term"]])
            frac = frac_of(terms + [a["term"], b["term"]], both)
            if frac < best_frac:
                continue
            lof_fit = prob.fit(terms + [a["term"], b["term"]] + lof)
            f, p = f_test(both.rss_w, lof_fit.rss_w, lof_fit.rank - both.rank, n - lof_fit.rank)
            if null is not None:
                p = null.p_value(f, p, terms + [a["term"], b["term"]],
                                 terms + [a["term"], b["term"]] + lof)
            if p >= alpha:
                best_pair, best_frac = [a, b], frac
    return best_pair


HELDOUT_WHITENED = ("vertical_gyro_drift",)
"""Effects whose held-out prediction is compared in noise units (whitened as the fit is), the
others' in m/s (:attr:`DiagnosisOptions.heldout_whitened`'s default). In m/s the held-out rule
keeps an absent effect that soaks up correlated noise out of the names; the body z gyro bias,
present in every IMU, is compared whitened, since in m/s the late samples' Gauss-Markov drift
dominates its held-out gap (docs/decisions.md, "Held-out prediction in noise units"). The
pipeline adds ``accel_bias_change`` where A's own warm-up pass is the evidence of one."""


def _heldout_lower(prob: Problem, trial: dict, ho0: list[NDArray], legs: list[int],
                   whitened: Sequence[str] = HELDOUT_WHITENED) -> bool:
    """Whether a candidate lowers the leave-one-leg-out gap over ``legs`` (m/s, or noise
    units for the effects in ``whitened``)."""
    if trial["eff"].effect_id in whitened:
        return prob.whitened_rms(trial["ho"], legs) < prob.whitened_rms(ho0, legs)
    return rms([trial["ho"][i] for i in legs]) < rms([ho0[i] for i in legs])


def informative_heldout_legs(legs: Sequence[Leg],
                             min_dheading_deg: float = PairPolicy.min_dheading_deg) -> list[int]:
    """The legs (indices into ``legs``) whose leave-one-leg-out prediction tests a candidate:
    those whose other legs hold two headings at least ``min_dheading_deg`` apart (the
    calibration's pairing rule, :class:`pospp.calib.pairs.PairPolicy`, with its
    :func:`~pospp.calib.pairs.heading_difference_rad`). From legs of one heading the base
    model's common parameters (heading error, horizontal bias) are not separable, so a
    prediction from them is an extrapolation that any added parameter can make worse: on
    flight_time_offset_200hz (legs at 20, 200, 20 deg) the 15 ms offset cut the held-out gap
    of legs 0 and 2 from 0.143 and 0.125 to 0.006-0.056 m/s, but leg 1, predicted from the
    two 20 deg legs, went from 0.31 to 0.60 m/s, and the offset (p = 2e-13) was not named
    (docs/diagnose.md). All legs when none qualifies."""
    out = []
    for i in range(len(legs)):
        others = [leg for j, leg in enumerate(legs) if j != i]
        if any(np.degrees(heading_difference_rad(a, b)) >= min_dheading_deg
               for k, a in enumerate(others) for b in others[k + 1:]):
            out.append(i)
    return out or list(range(len(legs)))


# --------------------------------------------------------------------------------------------
# the workflow


@dataclass(frozen=True)
class DiagnosisOptions:
    """How :func:`diagnose_replays` models and tests (one options object).

    Attributes
    ----------
    base_formulation : {"body", "paper"}
        Body-frame horizontal gyro bias, or navigation-frame drift common to the legs.
    base_transition : {"numerical", "closed_form"}
        Sensitivities of the base model.
    effects : tuple of str, optional
        Library identifiers to consider (None: all).
    alpha : float
        Family-wise significance level of each step (Bonferroni over the candidates).
    noise : {"white", "gyro_rw", "full"}
        Residual covariance: A's sigmas only (``"white"``), or A's sigmas times a plus the
        gyro angle random walk's correlated covariance q K (``"gyro_rw"``, as
        :func:`pospp.calib.solve.fit_calibration`, which estimates a and q by REML on the base
        model). Only the shape matters to the F-tests (the scale is estimated), but a wrong
        shape (correlated residuals weighted as white) makes every test too liberal.
        ``"full"``: :class:`pospp.calib.noise_model.NoiseModel` fitted by REML on the base model
        (A's sigmas times a, the gyro ARW, an accelerometer white noise, A's own coloured
        velocity error entering at the leg start and at t, and optionally the within-leg
        part of a Gauss-Markov gyro drift).
    gyro_arw_radpsqrts : float, optional
        Gyro angle random walk [rad/s^0.5] for ``"gyro_rw"`` and ``"full"``; estimated when
        None.
    gyro_gm_taus_s : tuple of float
        ``"full"``: correlation times of a Gauss-Markov gyro drift for REML to choose from
        (none: no drift in the model).
    max_steps : int
        Most effects to add.
    lof_terms : int
        Cosines per leg and channel of the lack-of-fit basis (plus :data:`LOF_DEGREE` + 1
        polynomials).
    min_explained_fraction : float
        Least share of the structured gap a candidate (or, failing one, a pair of candidates
        leaving no structured gap) must explain to be named.
    accel_settling_s : float
        Warm-up time constant of ``accel_bias_change`` [s] (run time from the run's epoch).
    rewhiten_null : bool
        With ``noise="gyro_rw"`` and null realisations, re-estimate the whitening (REML
        variance factor) on each realisation as on the flight, so that the null statistic is
        the same function of its data as the flight's; False: the flight's whitening on every
        realisation.
    heldout_whitened : tuple of str
        Effects whose held-out prediction is compared in noise units (:data:`HELDOUT_WHITENED`).
    replay_kwargs : mapping
        Keyword arguments the replays were made with (:class:`effects.ReplayContext`).
    """

    base_formulation: str = "body"
    base_transition: str = "numerical"
    effects: tuple[str, ...] | None = None
    alpha: float = 0.01
    noise: str = "white"
    gyro_arw_radpsqrts: float | None = None
    gyro_gm_taus_s: tuple[float, ...] = ()
    max_steps: int = 4
    lof_terms: int = 8
    min_explained_fraction: float = 0.9
    accel_settling_s: float = fx.ACCEL_SETTLING_S
    rewhiten_null: bool = True
    heldout_whitened: tuple[str, ...] = HELDOUT_WHITENED
    replay_kwargs: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.base_formulation not in BASE_FORMULATIONS:
            raise ValueError(f"base_formulation: expected one of {BASE_FORMULATIONS}, "
                             f"got {self.base_formulation!r}")
        if self.base_transition not in BASE_TRANSITIONS:
            raise ValueError(f"base_transition: expected one of {BASE_TRANSITIONS}, "
                             f"got {self.base_transition!r}")
        if self.noise not in ("white", "gyro_rw", "full"):
            raise ValueError(f"noise: expected 'white', 'gyro_rw' or 'full', got {self.noise!r}")
        for e in self.effects or ():
            fx.effect_by_id(e)

    @property
    def in_base(self) -> tuple[str, ...]:
        """The library effects the base model already holds."""
        return ((("body_fixed_gyro_bias",) if self.base_formulation == "body" else ())
                + (("earth_rate_coupling",) if self.base_transition == "numerical" else ()))


def diagnose_replays(
    replays: Sequence[LegReplay],
    options: DiagnosisOptions = DiagnosisOptions(),
    *,
    imu: ImuSource | None = None,
    solution_a: SolutionA | None = None,
    whitening_replays: Sequence[LegReplay] | None = None,
    noise_model: NoiseModel | None = None,
    null_dv: Sequence[Sequence[NDArray]] | None = None,
    signatures: Mapping[str, Sequence[NDArray]] | None = None,
    threads: int = 1,
) -> Diagnosis:
    """Find, with evidence, what the calibration model is missing (module docstring).

    Parameters
    ----------
    replays : sequence of LegReplay
        B minus A over each leg (at least 3 legs for held-out prediction to mean much).
    options : DiagnosisOptions
    imu, solution_a : ImuIncrements or ImuRates, SolutionA, optional
        The flight's increments and A, for effects whose signature re-runs B (``time_offset``;
        ``gyro_scale_factor`` is then exact, otherwise linearised). Without them
        ``time_offset`` is not evaluated.
    whitening_replays : sequence of LegReplay, optional
        ``"gyro_rw"``: estimate the whitening (REML variance factor of the white part, the
        random walk fixed or estimated) on these instead of ``replays``: the replays with the
        effects already named removed. A large effect left in the base model's residual is
        read as white noise, which flattens the whitening's shape (docs/decisions.md).
    noise_model : NoiseModel, optional
        ``"full"``: use this model instead of fitting one
        (:func:`pospp.calib.solve.fit_noise_model`).
    null_dv : sequence of sequences of ndarray, optional
        Null realisations of B minus A's noise (:mod:`pospp.diagnose.null_model`): R entries,
        each one (M, 2 or 3) array per leg in the order of ``replays`` (row 0 at t = 0, NED
        [m/s]). Every nested F-test (candidates, pairs, the closing lack of fit) then takes its
        p-value from these statistics' null distribution
        (:func:`pospp.diagnose.null_model.calibrated_p_value`) instead of the F distribution,
        and the criteria carry the suffix ``"_null_calibrated"``.
    signatures : mapping, optional
        Per effect id, per leg (order of ``replays``) a signature (M, 2, P) in SI parameters
        that replaces the library's (:func:`pospp.diagnose.rerun.rerun_signatures`: A re-run,
        A's own response included).
    threads : int
        Legs whose library signatures are made at once by B re-runs
        (:func:`pospp.diagnose.effects.signatures`), and null realisations re-whitened and
        refitted at once (the result does not depend on it).

    Returns
    -------
    Diagnosis
    """
    o = options
    if len(replays) < 2:
        raise ValueError(f"replays: expected at least 2 legs, got {len(replays)}")
    ids = [r.leg.leg_id for r in replays]
    if len(set(ids)) != len(ids):
        raise ValueError(f"replays: expected distinct leg ids, got {ids}")
    wanted = fx.EFFECT_IDS if o.effects is None else tuple(o.effects)
    ctx = None
    if imu is not None and solution_a is not None:
        ctx = fx.ReplayContext(imu, solution_a, dict(o.replay_kwargs))
    given = dict(signatures or {})
    for e, sg in given.items():
        fx.effect_by_id(e)
        if len(sg) != len(replays) or any(np.shape(a)[0] != r.t_s.size
                                           for a, r in zip(sg, replays, strict=True)):
            raise ValueError(f"signatures[{e!r}]: expected one (M, 2, P) array per leg")
    not_evaluated = tuple(e for e in wanted if e not in o.in_base and ctx is None
                          and e == "time_offset" and e not in given)
    pool = [fx.effect_by_id(e) for e in wanted if e not in o.in_base and e not in not_evaluated]
    prob = _problem(replays, o, whitening_replays, noise_model)
    null = _null_calibration(prob, replays, o, null_dv, threads)
    origins, extent_m = leg_origins(replays, solution_a)
    search = _Search(prob, o, null, replays, base_terms(replays, o.base_formulation,
                                                         o.base_transition),
                     lof_term(replays, o.lof_terms),
                     shape_signatures(pool, replays, given, ctx, o.accel_settling_s, threads,
                                      origins, extent_m))
    base_fit, base_ho = search.fit0, search.ho0
    steps: list[DiagnosisStep] = []
    tests: list[CandidateTest] = []
    unobservable: list[str] = []
    for step in range(1, o.max_steps + 1):
        row = search.step(step, pool, tests, unobservable)
        if row is None:
            break
        steps.append(row)
    steps.append(search.closing_row(len(steps) + 1))
    legs = tuple(
        LegGap(
            leg_id=r.leg.leg_id, start_s=float(r.t0_s), duration_s=float(r.t_s[-1]),
            heading_deg=float(np.degrees(r.leg.heading_rad)), speed_mps=float(r.leg.speed_mps),
            gap_before_mps=rms([base_fit.res_raw[i]]), gap_after_mps=rms([search.fit0.res_raw[i]]),
            heldout_gap_before_mps=rms([base_ho[i]]), heldout_gap_after_mps=rms([search.ho0[i]]),
            phase_gap_before_mps=_phaserms(base_fit.res_raw[i]),
            phase_gap_after_mps=_phaserms(search.fit0.res_raw[i]),
        )
        for i, r in enumerate(replays)
    )
    return Diagnosis(
        base_formulation=o.base_formulation, base_transition=o.base_transition, alpha=o.alpha,
        steps=tuple(steps), candidates=tuple(tests), legs=legs, in_base=o.in_base,
        unobservable=tuple(unobservable), not_evaluated=not_evaluated,
        t_s=tuple(r.t_s[1:].copy() for r in replays),
        residuals_before_n_mps=tuple(x.reshape(-1, 2) for x in base_fit.res_raw),
        residuals_after_n_mps=tuple(x.reshape(-1, 2) for x in search.fit0.res_raw),
        heldout_before_n_mps=tuple(x.reshape(-1, 2) for x in base_ho),
        heldout_after_n_mps=tuple(x.reshape(-1, 2) for x in search.ho0),
        location=search.location,
    )


def _problem(replays: Sequence[LegReplay], o: DiagnosisOptions,
             whitening_replays: Sequence[LegReplay] | None,
             noise_model: NoiseModel | None) -> Problem:
    """The whitened least-squares problem of the base model's residual covariance
    (:attr:`DiagnosisOptions.noise`)."""
    model = None
    if o.noise == "white":
        white_scale, arw = 1.0, 0.0
    elif o.noise == "gyro_rw":
        cal = fit_calibration(tuple(replays if whitening_replays is None else whitening_replays),
                              "body", FitOptions(gyro_arw_radpsqrts=o.gyro_arw_radpsqrts))
        white_scale, arw = cal.variance_factor, cal.gyro_arw_radpsqrts
    else:  # "full"
        model = noise_model if noise_model is not None else fit_noise_model(
            tuple(replays), "body", gyro_arw_radpsqrts=o.gyro_arw_radpsqrts,
            gyro_gm_taus_s=tuple(o.gyro_gm_taus_s))
        white_scale, arw = model.white_scale, model.gyro_arw_radpsqrts
    return Problem(replays, white_scale, arw, model)


def _null_calibration(prob: Problem, replays: Sequence[LegReplay], o: DiagnosisOptions,
                      null_dv: Sequence[Sequence[NDArray]] | None, threads: int
                      ) -> _NullCalibration | None:
    """The tests' null distributions from the realisations ``null_dv`` (None without)."""
    if null_dv is None or len(null_dv) == 0:
        return None
    for real in null_dv:
        if len(real) != len(replays) or any(
                np.shape(d)[0] != r.t_s.size for d, r in zip(real, replays, strict=True)):
            raise ValueError("null_dv: expected one array per leg with the replays' rows")
    whitening = None
    if o.noise == "gyro_rw" and o.rewhiten_null:
        shared: dict = {}  # the realisations' legs are the flight's: bases made once

        def whitening(reps: tuple[LegReplay, ...]) -> tuple[float, float]:
            c = fit_calibration(reps, "body", FitOptions(gyro_arw_radpsqrts=o.gyro_arw_radpsqrts),
                                noise_cache=shared)
            return c.variance_factor, c.gyro_arw_radpsqrts
    return _NullCalibration(prob, null_dv, whitening, threads)


class _Search:
    """The stepwise search's state: the model so far (``terms``, its fit ``fit0`` and
    held-out residuals ``ho0``) and what every step reads (module docstring, steps 3-5)."""

    def __init__(self, prob: Problem, o: DiagnosisOptions, null: _NullCalibration | None,
                 replays: Sequence[LegReplay], terms: list[Term], lof: list[Term],
                 fixed_sigs: dict[tuple[str, str], list[NDArray]]) -> None:
        self.prob, self.o, self.null, self.replays = prob, o, null, replays
        self.terms, self.lof, self.fixed_sigs = terms, lof, fixed_sigs
        self.fit0, self.ho0 = prob.fit(terms), prob.heldout(terms)
        self.ids = [r.leg.leg_id for r in replays]
        self.t_legs = [r.t_s[1:] for r in replays]
        self.calib_worth = self.worth(self.fit0.res_raw)
        self.ho_legs = informative_heldout_legs([r.leg for r in replays])
        self.suffix = "_null_calibrated" if null is not None else ""
        self.location: GapLocation | None = None

    def worth(self, curves: Sequence[NDArray]) -> Any:
        """What a residual curve is worth at the horizon (:func:`horizon_worth`)."""
        return horizon_worth(self.t_legs, [np.reshape(c, (-1, 2)) for c in curves], self.ids)

    def p_of(self, f: float, p: float, t0: list[Term], t1: list[Term]) -> float:
        """A nested test's p-value: the null's when calibrated, else the F distribution's."""
        return p if self.null is None else self.null.p_value(f, p, t0, t1)

    def _trials(self, pool: Sequence[fx.Effect], frac_of: Callable, step: int,
                unobservable: list[str]) -> list[dict]:
        """Every candidate not yet in the model, in its best shape (:func:`family_trial`)."""
        trials = []
        for eff in pool:
            if any(t.effect is not None and t.effect.effect_id == eff.effect_id
                   for t in self.terms):
                continue
            if eff.effect_id == "earth_rate_coupling":
                bx = base_x_per_leg(self.prob, self.terms, self.fit0, self.o.base_formulation)
                shapes = {"": [fx.signature(eff.effect_id, r, base_x_leg=b)
                               for r, b in zip(self.replays, bx, strict=True)]}
            else:
                shapes = {sh: self.fixed_sigs[(eff.effect_id, sh)] for sh in eff.shapes
                          if (eff.effect_id, sh) in self.fixed_sigs}
            tried = [tr for sh, sg in shapes.items() if (tr := trial(
                self.prob, self.terms, self.fit0, shaped(eff, sh), sg, sh, self.p_of, frac_of,
                self.worth)) is not None]
            if tried:
                trials.append(family_trial(tried))
            elif step == 1:
                unobservable.append(eff.effect_id)
        return trials

    def step(self, step: int, pool: Sequence[fx.Effect], tests: list[CandidateTest],
             unobservable: list[str]) -> DiagnosisStep | None:
        """One step: test every candidate, name the best that explains the gap and add it to
        the model (its row), or None when none does. Appends the step's candidate tests."""
        o, prob, terms = self.o, self.prob, self.terms
        gap0, hgap0 = rms(self.fit0.res_raw), rms(self.ho0)
        fit_lof = prob.fit(terms + self.lof)
        s2_lof = fit_lof.rss_w / max(prob.n - fit_lof.rank, 1)
        # "beyond noise": what noise alone would take out, from the null realisations when
        # given (their mean F: B minus A's correlated noise puts much of itself into the
        # smooth lack-of-fit basis), else white noise
        g_lof = 1.0 if self.null is None else self.null.noise_factor(terms, terms + self.lof)
        frac_of = partial(_explained_fraction, prob, terms, self.fit0, fit_lof, self.lof, s2_lof,
                          g_lof, self.null)
        trials = self._trials(pool, frac_of, step, unobservable)
        m = max(len(trials), 1)
        for tr in trials:
            tr["sig"] = bool(tr["p"] < o.alpha / m and _heldout_lower(
                prob, tr, self.ho0, self.ho_legs, o.heldout_whitened))
            tests.append(CandidateTest(
                step, tr["eff"].effect_id, tr["r"], tr["size"], tr["size_sig"], tr["eff"].unit,
                tr["f"], tr["p"], float(tr["dbic"]), tr["frac"], rms(tr["fit"].res_raw),
                rms(tr["ho"]), tr["sig"], tr["worth"].dv_mps, tr["worth"].dr_m,
                np.asarray(tr["vals"], dtype=float), tr["shape"]))
        good = [tr for tr in trials if tr["sig"] and tr["frac"] >= o.min_explained_fraction]
        if not good:
            good = _pair_explaining(prob, terms, self.fit0, trials, self.lof, frac_of, o.alpha,
                                    o.min_explained_fraction, self.null)
        if not good:
            return None
        best = max(good, key=lambda tr: tr["f"])
        eff = best["eff"]
        row = DiagnosisStep(
            step=step, effect=eff.effect_id, parameters=eff.parameters, values=best["vals"],
            sigmas=best["sigs"], value=best["size"], sigma=best["size_sig"], unit=eff.unit,
            statistic=best["f"], p_value=best["p"], criterion=CRITERION + self.suffix,
            significant=True,
            delta_bic=float(best["dbic"]), explained_fraction=best["frac"],
            confounded_with=self._confounded(best, trials), gap_before_mps=gap0,
            gap_after_mps=rms(best["fit"].res_raw),
            heldout_gap_before_mps=hgap0, heldout_gap_after_mps=rms(best["ho"]),
            horizon_s=self.calib_worth.horizon_s, gap_horizon_mps=best["worth"].dv_mps,
            gap_horizon_m=best["worth"].dr_m, residual_horizon_mps=self.calib_worth.dv_mps,
            residual_horizon_m=self.calib_worth.dr_m, shape=best["shape"],
            shape_parameters=(f"T = {o.accel_settling_s:.0f} s" if best["shape"] == "settling"
                              else ""),
        )
        self.terms = terms + [best["term"]]
        self.fit0, self.ho0 = best["fit"], best["ho"]
        return row

    def _confounded(self, best: dict, trials: list[dict]) -> tuple[str, ...]:
        """The other significant candidates, and those that explain the gap as well at the
        uncorrected level (a GNSS time offset against the lever arm it aliases into), that
        neither ``best`` nor they can be told from in a joint fit."""
        alpha, out = self.o.alpha, []
        for tr in trials:
            if tr is best or not (tr["sig"] or (tr["p"] < alpha
                                                and tr["frac"] >= self.o.min_explained_fraction)):
                continue
            both = self.prob.fit(self.terms + [tr["term"], best["term"]])
            dof = self.prob.n - both.rank
            _, p_best = f_test(tr["fit"].rss_w, both.rss_w, both.rank - tr["fit"].rank, dof)
            _, p_other = f_test(best["fit"].rss_w, both.rss_w, both.rank - best["fit"].rank, dof)
            if p_best >= alpha and p_other >= alpha:
                out.append(tr["eff"].effect_id)
        return tuple(out)

    def closing_row(self, step: int) -> DiagnosisStep:
        """The closing row: the lack-of-fit test of the final model ("none" or
        "unexplained"; :attr:`location` set where the gap sits)."""
        o, prob = self.o, self.prob
        fit_lof = prob.fit(self.terms + self.lof)
        f, p = f_test(self.fit0.rss_w, fit_lof.rss_w, fit_lof.rank - self.fit0.rank,
                      prob.n - fit_lof.rank)
        if self.null is not None:
            p = self.null.p_value(f, p, self.terms, self.terms + self.lof)
        gap, hgap = rms(self.fit0.res_raw), rms(self.ho0)
        structured = [(a - b).reshape(-1, 2)
                      for a, b in zip(self.fit0.res_raw, fit_lof.res_raw, strict=True)]
        gap_worth = self.worth(structured)
        self.location = (locate_gap(self.t_legs, structured, self.ids, lof_terms=o.lof_terms,
                                    degree=LOF_DEGREE) if p < o.alpha else None)
        cw = self.calib_worth
        return DiagnosisStep(
            step=step, effect="unexplained" if p < o.alpha else "none", parameters=(),
            values=np.zeros(0), sigmas=np.zeros(0), value=float("nan"), sigma=float("nan"),
            unit="", statistic=f, p_value=p, criterion=LOF_CRITERION + self.suffix,
            significant=bool(p < o.alpha), delta_bic=float("nan"),
            explained_fraction=float("nan"), confounded_with=(), gap_before_mps=gap,
            gap_after_mps=gap, heldout_gap_before_mps=hgap, heldout_gap_after_mps=hgap,
            horizon_s=cw.horizon_s, gap_horizon_mps=gap_worth.dv_mps,
            gap_horizon_m=gap_worth.dr_m, residual_horizon_mps=cw.dv_mps,
            residual_horizon_m=cw.dr_m,
        )
