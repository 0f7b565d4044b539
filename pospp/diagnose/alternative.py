"""B minus A with named effects' fitted responses removed: the data under the alternative.

The pipeline's diagnosis (:func:`pospp.diagnosis_stage.diagnose_calibration`) re-estimates the
null's gyro drift and the whitening on the replays with the effects it named (or its leading
significant candidate) removed, so that an effect the base model leaves out is not read as
noise (docs/diagnose.md, "Power"). Replays are :class:`pospp.calib.replay.LegReplay` in leg-id
order; signatures SI, per leg (M, 2, P); diagnosis values in display units. No I/O.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from pospp.diagnose.effects import effect_by_id, signature
from pospp.diagnose.results import Diagnosis
from pospp.units import DEG_PER_H_RADPS

LIBRARY_ALTERNATIVES = ("vertical_gyro_drift", "gravity_disturbance")
"""Library effects (signatures along B, no A re-run) whose fitted response is removed for the
null's drift under the alternative: the base model's REML reads each as excess gyro drift (a
z bias beyond the grade's: 0.21 deg/h for 0.4 deg/h on 180 s legs, against 0.05 configured;
a 2 arcsec/km gravity gradient on the crossing mission: 0.07-0.10 deg/h), and the null
realisations then hide it."""
SIGNIFICANT_ALTERNATIVES = ("gravity_disturbance",)
"""Of :data:`LIBRARY_ALTERNATIVES`, those whose first-step candidate also counts when it is
significant where the explained fraction reads 0 (:func:`library_fits`). Not the vertical
drift: a body z bias is in every IMU, and removing its significant candidate on the 12 ms
GNSS offset's seed 2 (tests/unit/test_diagnose_power.py) re-estimated the drift at 0.125
deg/h, 6435 s, where with the offset alone removed it fell back to the grade's."""
LIBRARY_ALT_EXPLAINED = 0.9
"""Share of the structured gap a first-step candidate of :data:`LIBRARY_ALTERNATIVES` must
explain for the null's drift to be re-estimated with it removed
(:func:`pospp.diagnosis_stage.drift_under_alternative`; the workflow's
``min_explained_fraction``)."""


def library_fits(d: Diagnosis, *, candidate: bool) -> dict[str, np.ndarray]:
    """Effect -> values (display units) of the :data:`LIBRARY_ALTERNATIVES` named or, with
    ``candidate``, whose first-step candidate explains at least :data:`LIBRARY_ALT_EXPLAINED`
    of the structured gap, or (:data:`SIGNIFICANT_ALTERNATIVES`) is significant where no
    structured gap stands beyond the null's noise (explained fraction 0: the drift the flight
    showed has taken the gap in; a 9 arcsec/km gravity gradient read as 0.25 deg/h of drift);
    the named value when named."""
    fits = {}
    for eid in LIBRARY_ALTERNATIVES:
        first = [c for c in d.candidates if c.step == 1 and c.effect == eid
                 and (c.explained_fraction >= LIBRARY_ALT_EXPLAINED
                      or (eid in SIGNIFICANT_ALTERNATIVES and c.significant
                          and not c.explained_fraction > 0.0))]
        # the effect's own shape only (the gravity gradient's, not the field's: its
        # signature along B needs the legs' positions, which this removal does not have)
        own = effect_by_id(eid).shapes[0]
        if eid in d.named and d.step_of(eid).shape in ("", own):
            fits[eid] = np.asarray(d.step_of(eid).values, dtype=float)
        elif candidate and first and first[0].shape in ("", own):
            fits[eid] = np.asarray(first[0].values, dtype=float)
    return fits


def with_library(replays: list, removed: list | None, d: Diagnosis, *, candidate: bool
                 ) -> list | None:
    """``removed`` (the replays minus the named re-run effects' response, or None) minus the
    fitted response ``S p`` (library signature along B, SI) of :func:`library_fits`; else
    ``removed`` unchanged."""
    fits = library_fits(d, candidate=candidate)
    if not fits:
        return removed
    reps = removed if removed is not None else replays
    p_si = {e: v * effect_by_id(e).si_per_unit for e, v in fits.items()}
    return _minus(reps, [sum(signature(e, r) @ p for e, p in p_si.items()) for r in reps])


def removed_fits(d: Diagnosis, sigs: dict[str, list[np.ndarray]]) -> dict[str, Any]:
    """The re-run effects named (effect -> values, display units), or, when none was, the
    first step's significant re-run candidate with the largest F; empty when neither."""
    fits = {e: d.step_of(e).values for e in d.named if e in sigs}
    if not fits:
        first = [c for c in d.candidates if c.step == 1 and c.significant and c.effect in sigs]
        if first:
            best = max(first, key=lambda c: c.statistic)
            fits = {best.effect: best.values}
    return fits


def removed_names(d: Diagnosis, sigs: dict[str, list[np.ndarray]], library: list[str]
                  ) -> list[str]:
    """The effects whose response was removed for the drift under the alternative
    (``library``: those of :func:`library_fits`)."""
    return [*removed_fits(d, sigs), *library]


def named_removed(replays: list, d: Diagnosis, sigs: dict[str, list[np.ndarray]]
                  ) -> list | None:
    """The replays minus the fitted response (``S p``, SI) of :func:`removed_fits`: the
    replays to estimate the whitening on (the noise estimated under the model tested). None
    when no re-run effect was named or significant."""
    fits = removed_fits(d, sigs)
    if not fits:
        return None
    p_si = {e: np.asarray(v, dtype=float) * effect_by_id(e).si_per_unit for e, v in fits.items()}
    return _minus(replays, [sum(sigs[e][k] @ p for e, p in p_si.items())
                            for k in range(len(replays))])


def start_removed(replays: list, sigs: dict[str, list[np.ndarray]],
                  at: dict[str, np.ndarray], effect_id: str) -> list | None:
    """The replays minus ``effect_id``'s response at its first estimate ``at[effect_id]``
    (SI; the signature made there: ``S p`` is the secant's whole response), or None when it
    has none. The whitening of the first diagnosis when A's own estimate of the warm-up
    started its signature: a 1800 ug warm-up left in B minus A is read as white noise by the
    REML of the whitening, and the observability screen, in those noise units, then drops
    the warm-up (measured, docs/diagnose.md "Power")."""
    if effect_id not in at or effect_id not in sigs:
        return None
    return _minus(replays, [s @ at[effect_id] for s in sigs[effect_id]])


def _minus(replays: list, responses: list) -> list:
    """Each replay with ``response`` ((M, 2) [m/s], N and E) taken off its B minus A."""
    out = []
    for r, resp in zip(replays, responses, strict=True):
        dv = r.dv_n_mps.copy()
        dv[:, 0:2] -= resp
        out.append(replace(r, dv_n_mps=dv))
    return out


def null_note(null_dv: list | None, sigma_radps: float, tau_s: float, source: str, *,
               base: tuple[float, float, str] | None = None) -> str:
    """One sentence: the null the diagnosis's p-values are calibrated on; ``base``: the
    drift (sigma [rad/s], tau [s], source) of the base model's null when this one was re-made
    under the alternative."""
    if not null_dv:
        return "no null realisations: nominal F distributions"
    text = (f"{len(null_dv)} null realisations, gyro drift {sigma_radps / DEG_PER_H_RADPS:.3g} "
            f"deg/h, tau {tau_s:.0f} s ({source})")
    if base is not None:
        text += (f"; re-made: under the base model the flight's drift read "
                 f"{base[0] / DEG_PER_H_RADPS:.3g} deg/h, tau {base[1]:.0f} s, which the "
                 "effect explains")
    return text
