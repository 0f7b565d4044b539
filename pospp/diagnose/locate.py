"""Where a structured gap sits, and what a gap is worth at the horizon.

Frames and units: NED (n), SI inside: curves are per leg (M - 1, 2) [dv_N, dv_E] in m/s at the
samples t > 0 of the leg (seconds since the leg start); the diagnosis uses the horizontal
channels only (B's vertical channel is unstable and not among its measurements), so the
channel is N or E.

Practical significance (item 5): for a curve c(t) that an effect (or the unexplained gap)
adds to B's velocity error on a leg, its worth at the horizon T (the leg's last sample) is

    dv(T) = |c(T)|            [m/s],     dr(T) = | int_0^T c(t) dt |      [m]

(horizontal norms; the integral by the trapezoidal rule from c(0) = 0, since B starts on A),
reported as the RMS over the legs. The calibration's own residual (B minus A minus the base
model, the curve the calibration leaves) is measured the same way, so the two can be compared
on one scale: an effect worth 2 cm/s at the horizon beside a 30 cm/s residual is significant
but does not matter; one worth as much as the residual is the residual.

Location (item 4): the structured gap of a final model is the part of its residual that the
lack-of-fit basis fits, ``g = r(final) - r(final + lack-of-fit)`` per leg. Its energy
``sum g^2`` is split by leg, by channel (N, E), by third of the leg (early, middle, late) and
over the lack-of-fit basis functions, orthogonalised in the basis' order (Legendre
polynomials of degree 0 to 4, then cosines cos(pi k u), u = t / T): the energy shares of the
orthonormal columns add up to the gap's energy, and each is labelled by the function that
brought it in.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

PHASES = ("early", "middle", "late")
LEG_SHARE = 0.8
"""The legs named carry at least this share of the gap's energy (largest first)."""
PHASE_SHARE = 0.6
"""The parts of the leg named carry at least this share (largest first)."""
CHANNEL_SHARE = 2.0 / 3.0
"""A channel is named alone when it carries at least this share, else "N+E"."""


@dataclass(frozen=True)
class HorizonWorth:
    """What a curve is worth at the horizon, RMS over the legs (module docstring).

    Attributes
    ----------
    horizon_s : float
        Median over the legs of the last sample time [s since the leg start].
    dv_mps, dr_m : float
        RMS over the legs of |c(T)| [m/s] and |int_0^T c dt| [m].
    dv_max_mps, dr_max_m : float
        The largest over the legs.
    leg_max : int
        Leg id of the largest dr.
    """

    horizon_s: float
    dv_mps: float
    dr_m: float
    dv_max_mps: float
    dr_max_m: float
    leg_max: int


@dataclass(frozen=True)
class GapLocation:
    """Where the structured gap of the final model sits.

    Attributes
    ----------
    legs : tuple of int
        Leg ids carrying at least :data:`LEG_SHARE` of the gap's energy, largest first.
    leg_ids : tuple of int
        All legs, in the diagnosis' order; ``leg_shares`` the energy share of each.
    leg_shares : ndarray, shape (L,)
    channel : str
        "N", "E" or "N+E".
    north_share : float
        Share of the energy in the north channel.
    part : str
        "early", "middle", "late", two of them joined by "+", or "whole leg".
    phase_shares : ndarray, shape (3,)
        Energy share of the early, middle and late thirds (all legs).
    basis : str
        The lack-of-fit basis function carrying the largest share: "legendre_k" (degree k) or
        "cos_k" (cos(pi k t / T), period 2 T / k).
    basis_share : float
    worth : HorizonWorth
        Size of the gap at the horizon.
    text : str
        One sentence for messages and the report.
    """

    legs: tuple[int, ...]
    leg_ids: tuple[int, ...]
    leg_shares: NDArray
    channel: str
    north_share: float
    part: str
    phase_shares: NDArray
    basis: str
    basis_share: float
    worth: HorizonWorth
    text: str


def horizon_worth(t_s: Sequence[NDArray], curves: Sequence[NDArray],
                  leg_ids: Sequence[int]) -> HorizonWorth:
    """|c(T)| and |int_0^T c dt| per leg, RMS and largest over the legs.

    Parameters
    ----------
    t_s : per leg (M - 1,) sample times t > 0 [s since the leg start]
    curves : per leg (M - 1, 2) [m/s], NE
    leg_ids : per leg id
    """
    dv, dr = [], []
    for t, c in zip(t_s, curves, strict=True):
        c = np.asarray(c, dtype=float).reshape(-1, 2)
        if c.shape[0] == 0:
            continue
        tt = np.r_[0.0, np.asarray(t, dtype=float)]
        cc = np.vstack([np.zeros((1, 2)), c])
        integral = np.sum(0.5 * (cc[1:] + cc[:-1]) * np.diff(tt)[:, None], axis=0)
        dv.append(float(np.hypot(*c[-1])))
        dr.append(float(np.hypot(*integral)))
    if not dv:
        return HorizonWorth(float("nan"), float("nan"), float("nan"), float("nan"),
                            float("nan"), -1)
    k = int(np.argmax(dr))
    return HorizonWorth(
        horizon_s=float(np.median([t[-1] for t in t_s if np.size(t)])),
        dv_mps=float(np.sqrt(np.mean(np.square(dv)))),
        dr_m=float(np.sqrt(np.mean(np.square(dr)))),
        dv_max_mps=float(max(dv)), dr_max_m=float(max(dr)), leg_max=int(leg_ids[k]))


def lof_basis(t_s: NDArray, lof_terms: int, degree: int) -> tuple[NDArray, tuple[str, ...]]:
    """The lack-of-fit basis of one leg (the workflow's), columns and labels.

    Legendre polynomials of degree 0..``degree`` in 2 u - 1, then cos(pi k u), 0 < k <
    ``lof_terms``, with u = (t - t_0) / (t_end - t_0).
    """
    t = np.asarray(t_s, dtype=float)
    u = (t - t[0]) / max(t[-1] - t[0], 1e-9)
    basis = np.hstack([np.polynomial.legendre.legvander(2.0 * u - 1.0, degree),
                       np.cos(np.pi * np.outer(u, np.arange(1, lof_terms)))])
    names = tuple(f"legendre_{k}" for k in range(degree + 1)) + tuple(
        f"cos_{k}" for k in range(1, lof_terms))
    return basis, names


def _pick(shares: NDArray, labels: Sequence, least: float) -> list:
    order = np.argsort(-shares, kind="stable")
    out, tot = [], 0.0
    for i in order:
        out.append(labels[i])
        tot += shares[i]
        if tot >= least:
            break
    return out


def locate_gap(t_s: Sequence[NDArray], gaps: Sequence[NDArray], leg_ids: Sequence[int], *,
               lof_terms: int, degree: int) -> GapLocation:
    """Split the structured gap's energy by leg, channel, third of the leg and basis function.

    Parameters
    ----------
    t_s : per leg (M - 1,) [s since the leg start]
    gaps : per leg (M - 1, 2) structured gap [m/s], NE
    leg_ids : per leg id
    lof_terms, degree : the workflow's lack-of-fit basis (:func:`lof_basis`)
    """
    g = [np.asarray(x, dtype=float).reshape(-1, 2) for x in gaps]
    leg_e = np.array([float(np.sum(x**2)) for x in g])
    total = float(leg_e.sum())
    tiny = total <= 0.0
    norm = 1.0 if tiny else total
    leg_shares = leg_e / norm
    north = float(sum(np.sum(x[:, 0] ** 2) for x in g)) / norm
    phase = np.zeros(3)
    basis_e: dict[str, float] = {}
    for t, x in zip(t_s, g, strict=True):
        for j, idx in enumerate(np.array_split(np.arange(x.shape[0]), 3)):
            phase[j] += float(np.sum(x[idx] ** 2))
        if x.shape[0] < 2:
            continue
        b, names = lof_basis(t, lof_terms, degree)
        q, r = np.linalg.qr(b)
        keep = np.abs(np.diag(r)) > 1e-9 * max(np.abs(np.diag(r)).max(), 1e-300)
        for k in np.flatnonzero(keep):
            basis_e[names[k]] = basis_e.get(names[k], 0.0) + float(np.sum((q[:, k] @ x) ** 2))
    phase /= norm
    legs = tuple(int(v) for v in _pick(leg_shares, list(leg_ids), LEG_SHARE))
    channel = "N" if north >= CHANNEL_SHARE else "E" if 1.0 - north >= CHANNEL_SHARE else "N+E"
    parts = _pick(phase, list(PHASES), PHASE_SHARE)
    part = "whole leg" if len(parts) == 3 else "+".join(p for p in PHASES if p in parts)
    if basis_e:
        bname = max(basis_e, key=lambda k: basis_e[k])
        bshare = basis_e[bname] / max(sum(basis_e.values()), 1e-300)
    else:
        bname, bshare = "", float("nan")
    worth = horizon_worth(t_s, g, leg_ids)
    text = location_text(legs, float(leg_shares[[list(leg_ids).index(v) for v in legs]].sum()),
                         channel, north, part, phase, bname, bshare, worth)
    return GapLocation(legs=legs, leg_ids=tuple(int(v) for v in leg_ids), leg_shares=leg_shares,
                       channel=channel, north_share=north, part=part, phase_shares=phase,
                       basis=bname, basis_share=float(bshare), worth=worth, text=text)


def _basis_words(name: str, horizon_s: float) -> str:
    if name.startswith("legendre_"):
        k = int(name.split("_")[1])
        words = {0: "a constant offset", 1: "a linear trend", 2: "a quadratic (bow)",
                 3: "a cubic (S-shape)", 4: "a quartic"}
        return words.get(k, f"a degree-{k} polynomial")
    if name.startswith("cos_"):
        k = int(name.split("_")[1])
        return f"an oscillation of period about {2.0 * horizon_s / k:.0f} s"
    return "no basis function"


def location_text(legs: Sequence[int], legs_share: float, channel: str, north: float,
                  part: str, phase: NDArray, basis: str, basis_share: float,
                  worth: HorizonWorth) -> str:
    """The location as one sentence (display units: mm/s, m, %)."""
    ch = {"N": f"north channel ({100 * north:.0f} %)",
          "E": f"east channel ({100 * (1 - north):.0f} %)",
          "N+E": f"both channels (north {100 * north:.0f} %)"}[channel]
    share = {p: s for p, s in zip(PHASES, phase, strict=True)}
    where = ("spread over the whole leg" if part == "whole leg" else
             f"in the {part} part of the legs ("
             + ", ".join(f"{p} {100 * share[p]:.0f} %" for p in part.split("+")) + ")")
    return (f"The unexplained gap sits on leg{'s' if len(legs) > 1 else ''} "
            f"{', '.join(str(v) for v in legs)} ({100 * legs_share:.0f} % of it), {ch}, "
            f"{where}, mostly {_basis_words(basis, worth.horizon_s)} ({basis}, "
            f"{100 * basis_share:.0f} %); at the {worth.horizon_s:.0f} s horizon it is worth "
            f"{1e3 * worth.dv_mps:.3g} mm/s and {worth.dr_m:.3g} m RMS over the legs (largest "
            f"on leg {worth.leg_max}: {1e3 * worth.dv_max_mps:.3g} mm/s, {worth.dr_max_m:.3g} m).")
