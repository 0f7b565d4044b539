"""Pairing of legs for the double-strapdown calibration, with observability screening.

A pair stacks two legs' B-minus-A velocity errors (paper Eq. 17). Its heading difference dH
(rad, in [0, pi]), speed difference dV (m/s, leg b minus leg a) and condition numbers decide
whether it is used; every rejection keeps a plain-language reason.

Two condition numbers are reported for every pair, both of the stacked, sigma-weighted
matrix of paper Eq. 17 (the ``paper`` formulation's X_p, SI units): ``cond_raw`` as the paper
computes it, and ``cond_scaled`` after scaling each column to unit norm (independent of the
units of X). The screening itself uses the column-scaled condition number of the formulation
that will be compensated with (``PairPolicy.formulation``; ``Pair.cond_gate``), because that is
the matrix actually inverted.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pospp.calib.design import condition_numbers, design_matrix
from pospp.calib.replay import LegReplay
from pospp.calib.segment import Leg
from pospp.calib.solve import Calibration, FitOptions, fit_calibration

MODES = ("adjacent", "all")


@dataclass(frozen=True)
class PairPolicy:
    """Pairing policy (config ``[pairs]``, :class:`pospp.config.PairsConfig`).

    ``mode``: "adjacent" (each leg with the next) or "all" (every admissible pair).
    A pair is used when its heading difference is at least ``min_dheading_deg`` and the
    column-scaled condition number of the ``formulation`` matrix is at most
    ``max_cond_scaled``.
    """

    mode: str = "adjacent"
    max_cond_scaled: float = 1.0e4
    min_dheading_deg: float = 30.0
    formulation: str = "body"
    transition: str = "numerical"


@dataclass(frozen=True)
class Pair:
    """A candidate pair with its screening figures and, when used, its calibrations.

    Attributes
    ----------
    pair_id, leg_a, leg_b : int
    dheading_rad : float
        Heading change from leg a to leg b, in [0, pi] [rad].
    dspeed_mps : float
        Speed of leg b minus speed of leg a [m/s].
    cond_raw, cond_scaled : float
        Condition numbers of the paper's Eq. 17 matrix (raw SI, column-scaled).
    cond_gate : float
        Column-scaled condition number of the screening formulation's matrix.
    used : bool
    reason : str
        "ok", or why the pair was rejected.
    calibrations : tuple of Calibration
        One per formulation when used, else empty.
    """

    pair_id: int
    leg_a: int
    leg_b: int
    dheading_rad: float
    dspeed_mps: float
    cond_raw: float
    cond_scaled: float
    cond_gate: float
    used: bool
    reason: str
    calibrations: tuple[Calibration, ...]

    def calibration(self, formulation: str) -> Calibration | None:
        """This pair's calibration with one formulation (None if absent)."""
        for c in self.calibrations:
            if c.formulation == formulation:
                return c
        return None


def heading_difference_rad(a: Leg, b: Leg) -> float:
    """Absolute heading difference in [0, pi] [rad]."""
    d = (b.heading_rad - a.heading_rad + np.pi) % (2 * np.pi) - np.pi
    return float(abs(d))


def candidate_pairs(legs: tuple[Leg, ...], mode: str) -> list[tuple[Leg, Leg]]:
    """Adjacent pairs or all pairs, in time order."""
    if mode == "adjacent":
        return [(legs[i], legs[i + 1]) for i in range(len(legs) - 1)]
    if mode == "all":
        return [(legs[i], legs[j]) for i in range(len(legs)) for j in range(i + 1, len(legs))]
    raise ValueError(f"pairs.mode: expected one of {MODES}, got {mode!r}")


def _cond(reps: tuple[LegReplay, LegReplay], formulation: str, transition: str
          ) -> tuple[float, float]:
    h, _, s, _ = design_matrix(reps, formulation, transition=transition)
    return condition_numbers(h / s[:, None])


def evaluate_pairs(
    replays: dict[int, LegReplay],
    legs: tuple[Leg, ...],
    policy: PairPolicy,
    *,
    formulations: tuple[str, ...] = ("paper", "body"),
    leg_reasons: Mapping[int, str] | None = None,
    options: FitOptions | None = None,
    **caches: Any,
) -> tuple[Pair, ...]:
    """Screen every candidate pair and calibrate the usable ones with each formulation.

    Parameters
    ----------
    replays : dict of int to LegReplay
        B over each leg (legs whose replay failed are absent).
    legs : tuple of Leg
    policy : PairPolicy
    formulations : tuple of str
        Formulations to calibrate each used pair with.
    leg_reasons : Mapping of int to str, optional
        Why a leg has no replay (it was refused: its reference A not GNSS-aided), named in
        the reason of its pairs.
    options : FitOptions, optional
        The least squares' model (:func:`pospp.calib.solve.fit_calibration`), its transition
        the policy's.
    **caches
        :func:`pospp.calib.solve.fit_calibration`'s ``bases`` and ``gm_ops``.

    Returns
    -------
    tuple of Pair
        Every candidate, used or not, with its reason. Never raises for bad geometry.
    """
    out: list[Pair] = []
    fit = replace(options or FitOptions(), transition=policy.transition)
    for pid, (a, b) in enumerate(candidate_pairs(legs, policy.mode)):
        dh = heading_difference_rad(a, b)
        dv = float(b.speed_mps - a.speed_mps)
        missing = [leg.leg_id for leg in (a, b) if leg.leg_id not in replays]
        if missing:
            why = "; ".join(f"leg {i}: {leg_reasons[i]}" for i in missing
                            if leg_reasons and i in leg_reasons)
            out.append(Pair(pid, a.leg_id, b.leg_id, dh, dv, np.nan, np.nan, np.nan, False,
                            why or f"no B replay for leg(s) {missing}", ()))
            continue
        reps = (replays[a.leg_id], replays[b.leg_id])
        c_raw, c_scaled = _cond(reps, "paper", policy.transition)
        c_gate = c_scaled if policy.formulation == "paper" else _cond(
            reps, policy.formulation, policy.transition)[1]
        reason = ""
        if np.degrees(dh) < policy.min_dheading_deg:
            reason = (f"heading change {np.degrees(dh):.1f} deg below the minimum "
                      f"{policy.min_dheading_deg:g} deg")
        elif not np.isfinite(c_gate) or c_gate > policy.max_cond_scaled:
            reason = (f"ill-conditioned: {policy.formulation} cond_scaled {c_gate:.3g} > "
                      f"{policy.max_cond_scaled:g}")
        cals: tuple[Calibration, ...] = ()
        if not reason:
            try:
                cals = tuple(fit_calibration(reps, f, fit, **caches) for f in formulations)
            except (ValueError, np.linalg.LinAlgError) as exc:
                reason = f"least squares failed: {exc}"
        out.append(Pair(pid, a.leg_id, b.leg_id, dh, dv, c_raw, c_scaled, c_gate, not reason,
                        reason or "ok", cals))
    return tuple(out)
