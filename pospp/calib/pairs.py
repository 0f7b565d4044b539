"""Pairing of legs for the double-strapdown calibration, with observability screening.

A pair stacks two legs' B-minus-A velocity errors (paper Eq. 17). Its heading difference dH,
speed difference dV and the condition number of the stacked matrix (raw, SI units, as the
paper; and column-scaled, unit-independent) decide whether it is used; every rejection keeps
its reason.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pospp.calib.replay import LegReplay
from pospp.calib.segment import Leg
from pospp.calib.solve import Calibration, calibrate, condition_numbers, design_matrix


@dataclass(frozen=True)
class PairPolicy:
    """Pairing policy (config ``[pairs]``).

    ``mode``: "adjacent" (each leg with the next) or "all" (every admissible pair).
    A pair is used when its column-scaled condition number is at most ``max_cond_scaled`` and
    its heading difference at least ``min_dheading_deg``.
    """

    mode: str = "adjacent"
    max_cond_scaled: float = 1.0e4
    min_dheading_deg: float = 30.0
    formulation: str = "body"
    transition: str = "numerical"


@dataclass(frozen=True)
class Pair:
    """A candidate pair with its screening figures and, when used, its calibrations."""

    pair_id: int
    leg_a: int
    leg_b: int
    dheading_rad: float
    dspeed_mps: float
    cond_raw: float
    cond_scaled: float
    used: bool
    reason: str
    calibrations: tuple[Calibration, ...]


def heading_difference_rad(a: Leg, b: Leg) -> float:
    """Absolute heading difference in [0, pi]."""
    d = (b.heading_rad - a.heading_rad + np.pi) % (2 * np.pi) - np.pi
    return float(abs(d))


def candidate_pairs(legs: tuple[Leg, ...], mode: str) -> list[tuple[Leg, Leg]]:
    """Adjacent pairs or all pairs, in time order."""
    if mode == "adjacent":
        return [(legs[i], legs[i + 1]) for i in range(len(legs) - 1)]
    if mode == "all":
        return [(legs[i], legs[j]) for i in range(len(legs)) for j in range(i + 1, len(legs))]
    raise ValueError(f"pairs.mode: expected 'adjacent' or 'all', got {mode!r}")


def evaluate_pairs(
    replays: dict[int, LegReplay],
    legs: tuple[Leg, ...],
    policy: PairPolicy,
    *,
    formulations: tuple[str, ...] = ("paper", "body"),
) -> tuple[Pair, ...]:
    """Screen every candidate pair and calibrate the usable ones with each formulation."""
    out: list[Pair] = []
    for pid, (a, b) in enumerate(candidate_pairs(legs, policy.mode)):
        dh = heading_difference_rad(a, b)
        dv = float(b.speed_mps - a.speed_mps)
        if a.leg_id not in replays or b.leg_id not in replays:
            out.append(Pair(pid, a.leg_id, b.leg_id, dh, dv, np.nan, np.nan, False,
                            "leg replay missing", ()))
            continue
        reps = (replays[a.leg_id], replays[b.leg_id])
        h, _, s, _ = design_matrix(reps, policy.formulation, transition=policy.transition)
        c_raw, c_scaled = condition_numbers(h / s[:, None])
        reason = ""
        if np.degrees(dh) < policy.min_dheading_deg:
            reason = (f"heading difference {np.degrees(dh):.1f} deg below "
                      f"{policy.min_dheading_deg:g} deg")
        elif not np.isfinite(c_scaled) or c_scaled > policy.max_cond_scaled:
            reason = f"ill-conditioned: cond_scaled {c_scaled:.3g} > {policy.max_cond_scaled:g}"
        cals: tuple[Calibration, ...] = ()
        if not reason:
            cals = tuple(
                calibrate(reps, f, transition=policy.transition) for f in formulations
            )
        out.append(Pair(pid, a.leg_id, b.leg_id, dh, dv, c_raw, c_scaled, not reason,
                        reason or "ok", cals))
    return tuple(out)
