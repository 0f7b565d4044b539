"""Design terms of the diagnosis regression (:mod:`pospp.diagnose.workflow`).

Frames and units: NED (n), FRD (b), SI inside. Every term holds, per leg, the rows t > 0 of
B's horizontal velocity error [dv_N, dv_E] (sample-major, 2 (M - 1) rows) per parameter:

- the base model (paper Eq. 17 with pospp's signs): per-leg tilts [phi_N, phi_E], the common
  heading error phi_D and the horizontal gyro drift, body-frame [b_x, b_y] (``"body"``) or a
  navigation-frame constant [eps_N, eps_E] (``"paper"``);
- the lack-of-fit basis: per leg and channel, Legendre polynomials up to :data:`LOF_DEGREE`
  and cosines (:func:`pospp.diagnose.locate.lof_basis`);
- a library effect's observable directions, in units of its plausible size, and the effect's
  estimate back in its display unit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pospp.calib.design import leg_sensitivities
from pospp.calib.replay import LegReplay
from pospp.diagnose import effects as fx
from pospp.diagnose._linear import Fit, Problem, Term
from pospp.diagnose.locate import lof_basis

LOF_DEGREE = 4
"""Legendre degree of the polynomial part of the lack-of-fit basis."""


def _rows(sig: NDArray) -> NDArray:
    """(M, 2, k) sensitivity -> rows t > 0, sample-major (2 (M - 1), k)."""
    return sig[1:].reshape(-1, sig.shape[2])


def base_terms(reps: Sequence[LegReplay], formulation: str, transition: str) -> list[Term]:
    nl = len(reps)
    sens = [leg_sensitivities(r, transition) for r in reps]
    terms = []
    for i in range(nl):
        blocks = [np.zeros((2 * (r.t_s.size - 1), 2)) for r in reps]
        blocks[i] = _rows(sens[i][0][:, :, 0:2])
        terms.append(Term(f"tilt_leg{reps[i].leg.leg_id}", blocks, local_leg=i))
    terms.append(Term("phi_d", [_rows(s[0][:, :, 2:3]) for s in sens]))
    if formulation == "body":
        terms.append(Term("gyro_bias_xy", [_rows(s[1][:, :, 0:2]) for s in sens]))
    else:
        terms.append(Term("eps_ne", [_rows((s[1] @ r.c_nb0.T)[:, :, 0:2])
                                      for s, r in zip(sens, reps, strict=True)]))
    return terms


def lof_term(reps: Sequence[LegReplay], k: int) -> list[Term]:
    terms = []
    for i, r in enumerate(reps):
        t = r.t_s[1:]
        basis, _ = lof_basis(t, k, LOF_DEGREE)
        w = basis.shape[1]
        blk = np.zeros((t.size, 2, 2 * w))
        blk[:, 0, :w] = basis
        blk[:, 1, w:] = basis
        blocks = [np.zeros((2 * (q.t_s.size - 1), 2 * w)) for q in reps]
        blocks[i] = blk.reshape(-1, 2 * w)
        terms.append(Term(f"lof_leg{r.leg.leg_id}", blocks, local_leg=i))
    return terms


def base_x_per_leg(prob: Problem, terms: list[Term], fit: Fit, formulation: str
                    ) -> list[NDArray]:
    """Current [phi_N, phi_E, phi_D, b_x, b_y, b_z] (SI) of every leg."""
    vals: dict[str, NDArray] = {}
    k = 0
    for t in terms:
        w = t.blocks[0].shape[1]
        vals[t.name] = fit.x[k:k + w]
        k += w
    out = []
    for r in prob.reps:
        v = np.zeros(6)
        v[0:2] = vals[f"tilt_leg{r.leg.leg_id}"]
        v[2] = vals["phi_d"][0]
        if formulation == "body":
            v[3:5] = vals["gyro_bias_xy"]
        else:
            v[3:6] = r.c_nb0.T @ np.array([*vals["eps_ne"], 0.0])
        for t in terms:
            if t.effect is not None and t.effect.effect_id == "body_fixed_gyro_bias":
                v[3:5] += t.basis @ vals[t.name]
            if t.effect is not None and t.effect.effect_id == "vertical_gyro_drift":
                v[5] += (t.basis @ vals[t.name])[0]
        out.append(v)
    return out


def effect_term(prob: Problem, terms: list[Term], eff: fx.Effect, sigs: list[NDArray]
                 ) -> Term | None:
    """The effect's observable directions (in units of its plausible size), or None."""
    raw = [_rows(s) * eff.plausible_si for s in sigs]
    if not all(np.all(np.isfinite(r)) for r in raw):
        return None
    probe = Term(eff.effect_id, raw)
    h = prob.leg_matrix(terms, 0)
    ew = prob.wblocks(probe)[0]
    g, c, e = h.T @ h, h.T @ ew, ew.T @ ew
    for i in range(1, len(prob.reps)):
        h = prob.leg_matrix(terms, i)
        ew = prob.wblocks(probe)[i]
        g, c, e = g + h.T @ h, c + h.T @ ew, e + ew.T @ ew
    _, ginv, _ = prob.solve_normal(g, np.zeros(g.shape[0]))
    lam, vecs = np.linalg.eigh(e - c.T @ ginv @ c)  # Gram of the part the model cannot fit
    keep = lam >= 4.0  # singular value >= 2: a plausible effect stands 2 sigma out
    if not keep.any():
        return None
    vt = vecs.T
    v = vt[keep].T  # (P, r)
    return Term(eff.effect_id, [b @ v for b in raw], basis=v * eff.plausible_si, effect=eff)


def effect_estimate(term: Term, fit: Fit, terms: list[Term], s2: float
                     ) -> tuple[NDArray, NDArray, float, float]:
    """(values, sigmas, size, size sigma) in the effect's display unit."""
    k = 0
    for t in terms:
        w = t.blocks[0].shape[1]
        if t is term:
            break
        k += w
    w = term.blocks[0].shape[1]
    c = fit.x[k:k + w]
    cc = fit.cov_unscaled[k:k + w, k:k + w] * s2
    assert term.effect is not None and term.basis is not None  # an effect's term
    unit = term.effect.si_per_unit
    p = term.basis @ c / unit
    cp = term.basis @ cc @ term.basis.T / unit**2
    sig = np.sqrt(np.clip(np.diag(cp), 0.0, None))
    if p.size == 1:
        return p, sig, float(p[0]), float(sig[0])
    size = float(np.linalg.norm(p))
    g = p / size if size > 0 else np.zeros_like(p)
    return p, sig, size, float(np.sqrt(max(g @ cp @ g, 0.0)))
