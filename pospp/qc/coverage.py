"""QC check of the GNSS coverage of algorithm A: arrays in, a frozen
:class:`pospp.qc.check_record.Check` out (no I/O).

A check that the other checks cannot replace: with GNSS lost, a NIS band and a gate count
have no records to judge and the lever-arm and time-offset checks no turns, while B minus A
is no longer B's error (docs/qc.md). This check measures where A was GNSS-aided
(:mod:`pospp.nav.aiding`): the gaps between the GNSS records A received, where they fall
against the legs, and A's velocity sigma along each leg. Times ``t_s`` from the run epoch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from pospp.nav.aiding import GNSS_GAP_MAX_S, GnssAiding
from pospp.qc.check_record import Check
from pospp.units import NS_PER_S

__all__ = ["gnss_coverage"]

_LISTED = 3
"""Gaps named in the suggestion (then a count)."""


def _legs_in(gap: tuple[float, float], legs: Sequence[tuple[int, float, float]]) -> list[int]:
    return [i for i, a, b in legs if b > gap[0] and a < gap[1]]


def _legs_text(ids: Sequence[int]) -> str:
    """"leg 2" or "legs 0, 1, 3"."""
    return ("leg " if len(ids) == 1 else "legs ") + ", ".join(map(str, ids))


def gnss_coverage(aiding: GnssAiding, legs: Sequence[tuple[int, float, float]] = (),
                  refused: Mapping[int, str] | None = None) -> Check:
    """The longest stretch of A's span without GNSS aiding against :data:`GNSS_GAP_MAX_S`.

    Statistic [s]: the longest of (a) the gaps between the GNSS position and velocity records
    A received (the span's ends count), and (b) the legs the calibration refused because A's
    velocity sigma on them says A was not aided (GNSS records present that aid nothing: a
    huge covariance, or gated). Fails (degraded) above the threshold. The suggestion names
    the gaps (time, length, share of the span), the legs inside them, and the legs refused.

    Parameters
    ----------
    aiding : pospp.nav.aiding.GnssAiding
    legs : sequence of (leg_id, start_s, end_s)
        The calibration's legs (empty: no calibration ran; the gaps alone are judged).
    refused : Mapping of int to str
        The legs the calibration refused, with why.
    """
    refused = dict(refused or {})
    by_id = {i: (a, b) for i, a, b in legs}
    sigma_only = {i: why for i, why in refused.items()
                  if i in by_id and not aiding.gaps_in(*by_id[i]).shape[0]}
    value = max([aiding.longest_gap_s] + [by_id[i][1] - by_id[i][0] for i in sigma_only])
    passed = value <= GNSS_GAP_MAX_S
    span = aiding.span_s[1] - aiding.span_s[0]
    parts = []
    for a, b in aiding.gaps_s[:_LISTED]:
        inside = _legs_in((a, b), legs)
        end = "the end of the data" if b >= aiding.span_s[1] else f"t = {b:.0f} s"
        parts.append(f"no GNSS from t = {a:.0f} s to {end} ({b - a:.0f} s, "
                     f"{100 * (b - a) / max(span, 1e-9):.0f} % of the flight"
                     + (f"; {_legs_text(inside)} in it" if inside else "") + ")")
    if aiding.gaps_s.shape[0] > _LISTED:
        parts.append(f"and {aiding.gaps_s.shape[0] - _LISTED} more gaps")
    parts += [f"leg {i}: {why}" for i, why in sorted(sigma_only.items())]
    sug = "" if passed else (
        "; ".join(parts) + ": algorithm A ran free-inertial there (the trajectory is not "
        "GNSS-controlled)" + (f"; {_legs_text(sorted(refused))} refused by the calibration"
                              if refused else "")
        + "; check the receiver log and the [input] window")
    at = float(aiding.gaps_s[0, 0]) if aiding.gaps_s.shape[0] else (
        by_id[min(sigma_only)][0] if sigma_only else aiding.longest_at_s)
    return Check("gnss_coverage", "navigate",
                 "longest stretch of A's span without GNSS aiding (no GNSS record, or a "
                 "leg where A's velocity sigma says it was not aided)", value, GNSS_GAP_MAX_S,
                 "s", passed, "degraded", sug, None if passed else int(round(at * NS_PER_S)))
