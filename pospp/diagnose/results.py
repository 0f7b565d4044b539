"""Results of the model-discrepancy workflow (:func:`pospp.diagnose.workflow.diagnose_replays`).

Frozen dataclasses; display units only in the rows' ``unit``, SI elsewhere (m/s, m, s).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pospp.diagnose.locate import GapLocation


@dataclass(frozen=True)
class CandidateTest:
    """One candidate tested at one step (display units in ``unit``)."""

    step: int
    effect: str
    n_parameters: int
    value: float
    sigma: float
    unit: str
    statistic: float
    p_value: float
    delta_bic: float
    explained_fraction: float
    gap_after_mps: float
    heldout_gap_after_mps: float
    significant: bool
    gap_horizon_mps: float = float("nan")
    gap_horizon_m: float = float("nan")
    values: NDArray = field(default_factory=lambda: np.zeros(0))
    """Per-parameter estimates, display unit (the observable directions' minimum norm)."""
    shape: str = ""
    """The family's shape tested (:data:`pospp.effects_catalog.SHAPES`; empty: one form)."""


@dataclass(frozen=True)
class DiagnosisStep:
    """One row of diagnosis.parquet.

    Attributes
    ----------
    step : int
        1, 2, ...; the final row (``effect`` "none" or "unexplained") closes the list.
    effect : str
        Library identifier, "none" or "unexplained".
    parameters : tuple of str
        Parameter names of the effect.
    values, sigmas : ndarray, shape (P,)
        Estimates and 1-sigma per parameter, display unit.
    value, sigma : float
        Size of the effect (the signed value of a one-parameter effect, the norm otherwise) and
        its 1-sigma (delta method), display unit; NaN on the final row.
    unit : str
    statistic, p_value : float
        F statistic and its p-value (lack-of-fit F on the final row).
    criterion : str
    significant : bool
    delta_bic : float
        BIC(with) - BIC(without) (negative favours the effect).
    explained_fraction : float
        Share of the structured gap (lack-of-fit basis) the effect explains.
    confounded_with : tuple of str
        Other significant candidates that these legs cannot tell apart from the named one (the
        named effect adds nothing significant once one of them is in the model, nor the
        reverse): the choice between them rests on the larger F only.
    gap_before_mps, gap_after_mps : float
        RMS of B minus A minus the model (all legs, N and E) before and after the step [m/s].
    heldout_gap_before_mps, heldout_gap_after_mps : float
        The same for leave-one-leg-out predictions [m/s].
    horizon_s : float
        The horizon (median last sample time of the legs) [s since the leg start].
    gap_horizon_mps, gap_horizon_m : float
        What the row is worth (:mod:`pospp.diagnose.locate`): the part of B's velocity error
        at the horizon that the named effect causes beyond what the model before it absorbs
        (its residual minus the residual with the effect), and its integral (position), RMS
        over the legs; on the closing row the same for the structured gap (the final model's
        residual minus that with the lack-of-fit basis) [m/s, m].
    residual_horizon_mps, residual_horizon_m : float
        The calibration's own residual (B minus A minus the base model) measured the same way
        [m/s, m]: the scale the row's worth is compared against.
    shape, shape_parameters : str
        A family's shape (:data:`pospp.effects_catalog.SHAPES`: ``ramp``, ``step``, ...) and
        its non-linear parameter ("T = 1200 s"); empty for an effect of one form.
    """

    step: int
    effect: str
    parameters: tuple[str, ...]
    values: NDArray
    sigmas: NDArray
    value: float
    sigma: float
    unit: str
    statistic: float
    p_value: float
    criterion: str
    significant: bool
    delta_bic: float
    explained_fraction: float
    confounded_with: tuple[str, ...]
    gap_before_mps: float
    gap_after_mps: float
    heldout_gap_before_mps: float
    heldout_gap_after_mps: float
    horizon_s: float = float("nan")
    gap_horizon_mps: float = float("nan")
    gap_horizon_m: float = float("nan")
    residual_horizon_mps: float = float("nan")
    residual_horizon_m: float = float("nan")
    shape: str = ""
    shape_parameters: str = ""


@dataclass(frozen=True)
class LegGap:
    """Where the gap sits: one leg, base model ("before") and final model ("after") [m/s]."""

    leg_id: int
    start_s: float
    duration_s: float
    heading_deg: float
    speed_mps: float
    gap_before_mps: float
    gap_after_mps: float
    heldout_gap_before_mps: float
    heldout_gap_after_mps: float
    phase_gap_before_mps: NDArray
    phase_gap_after_mps: NDArray


@dataclass(frozen=True)
class EffectResponse:
    """What a named effect does to B minus A (the calibration's data), for its refit.

    ``columns`` per leg (legs in id order) ``(M, 2, P)``: B minus A's [dv_N, dv_E] [m/s]
    per SI parameter, at the replay samples (row 0 at t = 0); ``p_si`` (P,) the estimate and
    ``cov_si`` (P, P) its covariance: the effect's response is ``columns @ p_si``.
    """

    effect: str
    columns: tuple[NDArray, ...]
    p_si: NDArray
    cov_si: NDArray

    def curves(self) -> list[NDArray]:
        """The response at the estimate, per leg (M, 2) [m/s]."""
        return [c @ self.p_si for c in self.columns]


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes
    ----------
    base_formulation, base_transition : str
    alpha : float
    steps : tuple of DiagnosisStep
        Named effects in order, then the closing row ("none" or "unexplained").
    candidates : tuple of CandidateTest
        Every candidate tested at every step.
    legs : tuple of LegGap
    in_base : tuple of str
        Library effects already in the base model (not candidates).
    unobservable : tuple of str
        Effects these legs cannot reveal (observability screen at the first step).
    not_evaluated : tuple of str
        Effects skipped for lack of inputs (IMU increments and A's solution).
    t_s : tuple of ndarray
        Per leg, the sample times t > 0 [s since the leg start].
    residuals_before_n_mps, residuals_after_n_mps : tuple of ndarray, shape (M - 1, 2)
        Per leg, measured minus modelled [dv_N, dv_E] with the base and the final model.
    heldout_before_n_mps, heldout_after_n_mps : tuple of ndarray, shape (M - 1, 2)
        The same for the leave-one-leg-out predictions.
    location : GapLocation or None
        Where the structured gap of the final model sits (legs, channel, part of the leg,
        basis function) and its size at the horizon; None unless the closing row is
        "unexplained" (:func:`pospp.diagnose.locate.locate_gap`).
    null_model : str
        What the p-values are calibrated on, one sentence (the null realisations and the gyro
        drift they inject; whether they were re-made with the drift re-estimated with a
        named effect removed); empty when the caller did not say
        (:func:`pospp.diagnosis_stage.diagnose_calibration` does).
    null_rebuilt_with : tuple of str
        The effects whose fitted response was removed when the null realisations were
        re-made with the gyro drift estimated under the alternative
        (:func:`pospp.diagnosis_stage.drift_under_alternative`); empty when the null is the
        base model's.
    responses : tuple of EffectResponse
        What each named effect does to B minus A (:mod:`pospp.diagnose.refit`); empty when
        the caller did not make them (:func:`pospp.diagnosis_stage.diagnose_calibration`
        does).
    """

    base_formulation: str
    base_transition: str
    alpha: float
    steps: tuple[DiagnosisStep, ...]
    candidates: tuple[CandidateTest, ...]
    legs: tuple[LegGap, ...]
    in_base: tuple[str, ...]
    unobservable: tuple[str, ...]
    not_evaluated: tuple[str, ...]
    t_s: tuple[NDArray, ...] = field(repr=False)
    residuals_before_n_mps: tuple[NDArray, ...] = field(repr=False)
    residuals_after_n_mps: tuple[NDArray, ...] = field(repr=False)
    heldout_before_n_mps: tuple[NDArray, ...] = field(repr=False)
    heldout_after_n_mps: tuple[NDArray, ...] = field(repr=False)
    location: GapLocation | None = None
    null_model: str = ""
    null_rebuilt_with: tuple[str, ...] = ()
    responses: tuple[EffectResponse, ...] = field(default=(), repr=False)

    @property
    def named(self) -> tuple[str, ...]:
        """Effects named and added, in order."""
        return tuple(s.effect for s in self.steps if s.effect not in ("none", "unexplained"))

    @property
    def conclusion(self) -> str:
        """"none" or "unexplained" (the closing row)."""
        return self.steps[-1].effect

    def step_of(self, effect_id: str) -> DiagnosisStep:
        """The step that named an effect (KeyError otherwise)."""
        for s in self.steps:
            if s.effect == effect_id:
                return s
        raise KeyError(f"effect {effect_id!r} was not named; named: {self.named}")
