"""One candidate of the diagnosis at one step, in each of its shapes.

An effect with several shapes on the legs (the gravity disturbance: ``gradient``, ``field``)
is tried in each; the family's candidate is the shape of smallest BIC (the workflow's
criterion), its p-value multiplied by the number of shapes tried (Bonferroni: the shape was
chosen on the same data). Frames and units as :mod:`pospp.diagnose.workflow` (NED, SI;
display units in the effect's). No I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pospp import earth
from pospp.calib.replay import LegReplay, SolutionA
from pospp.diagnose import effects as fx
from pospp.diagnose._linear import Fit, Problem, Term, bic, f_test
from pospp.diagnose._terms import effect_estimate, effect_term
from pospp.effects_catalog import shape_entry

FIELD_PARAMETERS = tuple(f"deflection_u{i}w{j}" for i, j in fx.field_monomials())
"""The ``field`` shape's parameters: the deflection of the potential's monomial u^i w^j at
the flown area's edge (u north, w east, in units of the area's half-size)."""


def shaped(eff: fx.Effect, shape: str) -> fx.Effect:
    """``eff`` as its ``shape`` reports it: the shape's own unit, SI conversion, plausible size
    and parameters when the catalogue gives it one (the gravity ``field``), else ``eff``."""
    if not shape:
        return eff
    s = shape_entry(shape)
    if not s.unit:
        return eff
    params = FIELD_PARAMETERS if shape == "field" else eff.parameters
    return replace(eff, parameters=params, unit=s.unit, si_per_unit=s.si_per_unit,
                   plausible_si=s.plausible_si)


def leg_origins(replays: Sequence[LegReplay], solution_a: SolutionA | None
                ) -> tuple[NDArray | None, float]:
    """Each leg's start north and east of the legs' mean start [m] (A's position at B's first
    epoch; WGS-84 radii there), and the flown area's half-size about that point [m]: the
    farthest leg end, at least 1 km. (None, NaN) without A's solution."""
    if solution_a is None:
        return None, float("nan")
    tr = solution_a.trajectory
    lat = np.array([np.interp(r.t0_s, tr.t_s, tr.lat_rad) for r in replays])
    lon = np.array([np.interp(r.t0_s, tr.t_s, tr.lon_rad) for r in replays])
    lat0 = float(np.mean(lat))
    r_m, r_n = earth.principal_radii_m(lat0)
    h = float(np.mean([r.height_m for r in replays]))
    ne = np.stack([(lat - lat0) * (r_m + h), (lon - float(np.mean(lon)))
                   * (r_n + h) * np.cos(lat0)], axis=1)
    ends = [np.hypot(*(o + r.v_n0_mps[0:2] * r.t_s[-1])) for o, r in
            zip(ne, replays, strict=True)]
    reach = max(float(np.max(np.hypot(ne[:, 0], ne[:, 1]))), float(max(ends)))
    return ne, max(1000.0, reach)


def shape_signatures(pool: Sequence[fx.Effect], replays: Sequence[LegReplay],
                     given: dict, ctx: fx.ReplayContext | None, accel_settling_s: float,
                     threads: int, origins: NDArray | None, extent_m: float
                     ) -> dict[tuple[str, str], list[NDArray]]:
    """Per (effect, shape) the signature of every leg: ``given`` (A re-run) for the effect's
    first shape, else the library's; the ``field`` only with the legs' positions; not the
    Earth-rate coupling (made at each step from the current estimates)."""
    out: dict[tuple[str, str], list[NDArray]] = {}
    for e in pool:
        if e.effect_id == "earth_rate_coupling":
            continue
        for k, shape in enumerate(e.shapes):
            if k == 0 and e.effect_id in given:
                out[(e.effect_id, shape)] = [np.asarray(a, dtype=float)
                                             for a in given[e.effect_id]]
            elif shape == "field":
                if origins is not None:
                    out[(e.effect_id, shape)] = [
                        fx.signature(e.effect_id, r, shape=shape, origin_n_m=o,
                                     extent_m=extent_m) for r, o in
                        zip(replays, origins, strict=True)]
            else:
                out[(e.effect_id, shape)] = fx.signatures(
                    e.effect_id, replays, shape=shape, context=ctx,
                    accel_settling_s=accel_settling_s, threads=threads)
    return out


def trial(prob: Problem, terms: list[Term], fit0: Fit, eff: fx.Effect, sigs: list[NDArray],
          shape: str, p_value: Callable[[float, float, list[Term], list[Term]], float],
          frac_of: Callable[[list[Term], Fit], float], worth: Callable) -> dict | None:
    """One candidate in one shape: its term (observable directions), the nested F-test and
    the p-value (``p_value(f, p_nominal, terms, new_terms)``), the held-out prediction, the
    estimate, the explained fraction, the worth and the BIC change; None when the legs cannot
    reveal it."""
    term = effect_term(prob, terms, eff, sigs)
    if term is None:
        return None
    n = prob.n
    new_terms = terms + [term]
    fit1 = prob.fit(new_terms)
    r = fit1.rank - fit0.rank
    dof1 = n - fit1.rank
    f, p = f_test(fit0.rss_w, fit1.rss_w, r, dof1)
    p = p_value(f, p, terms, new_terms)
    s2 = fit1.rss_w / max(dof1, 1)
    vals, sigs_, size, size_sig = effect_estimate(term, fit1, new_terms, s2)
    return dict(eff=eff, shape=shape, term=term, fit=fit1, ho=prob.heldout(new_terms), f=f,
                p=p, r=r, vals=vals, sigs=sigs_, size=size, size_sig=size_sig,
                frac=frac_of(new_terms, fit1),
                worth=worth([a - b for a, b in zip(fit0.res_raw, fit1.res_raw, strict=True)]),
                dbic=bic(fit1.rss_w, n, fit1.rank) - bic(fit0.rss_w, n, fit0.rank))


def family_trial(trials: list[dict]) -> dict:
    """The shape of smallest BIC among an effect's ``trials`` (one per shape), its p-value
    times the number of shapes tried (at most 1)."""
    best = min(trials, key=lambda tr: tr["dbic"])
    best["p"] = min(1.0, best["p"] * len(trials))
    best["n_shapes"] = len(trials)
    return best
