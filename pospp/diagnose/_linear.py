"""Whitened stacked least squares over legs: the linear-model machinery of the workflow.

Rows are B's horizontal velocity errors [dv_N, dv_E] at the samples t > 0 of each leg
(sample-major), whitened per leg by A's sigmas or by the Cholesky factor of
``a diag(sigma^2) + q K`` (K: :func:`pospp.calib.noise_model.gyro_noise_covariance`).
Problems re-whitened with other variances (the null realisations: the same legs, another
``a``, ``q``) share one eigenbasis per leg instead: with ``S = diag(sigma)`` and
``S^-1 K S^-1 = U diag(lam) U^T``, ``a S^2 + q K = S U diag(a + q lam) U^T S``, so
``W = diag(a + q lam)^-1/2 U^T S^-1`` whitens it (``W Sigma W^T = I``). Whitened residual
sums of squares (``r^T Sigma^-1 r``) do not depend on which square root whitens, so the fits
are those of the Cholesky factor to rounding; one basis per leg is held instead of a
factor per leg per realisation (420 MiB on the 1.5 h flight's 20 null problems).
Columns come in named blocks (:class:`Term`); fits solve the column-scaled normal equations
(minimum norm on rank deficiency). SI units.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import linalg

from pospp.calib.noise_model import NoiseModel, gyro_noise_covariance
from pospp.calib.replay import LegReplay
from pospp.diagnose.effects import Effect
from pospp.distributions import f_sf


@dataclass
class Term:
    """A block of columns: raw per-leg blocks (rows t > 0, sample-major [N, E])."""

    name: str
    blocks: list[NDArray]  # per leg (2 (M - 1), k)
    local_leg: int | None = None  # index of the leg for per-leg (nuisance) terms
    basis: NDArray | None = None  # (P, k): parameters (SI) = basis @ coefficients
    effect: Effect | None = None
    wblocks: list[NDArray] | None = None

    def __post_init__(self) -> None:
        if self.local_leg is not None and any(
                np.any(b) for j, b in enumerate(self.blocks) if j != self.local_leg):
            raise ValueError(f"term {self.name}: a per-leg term is zero on the other legs")


@dataclass
class Fit:
    """A whitened least-squares fit: x, (H_w^T H_w)^+, whitened RSS, rank, raw residuals."""

    x: NDArray
    cov_unscaled: NDArray  # (H_w^T H_w)^+
    rss_w: float
    rank: int
    res_raw: list[NDArray]


class Problem:
    """Whitened stacked least squares over legs."""

    def __init__(self, replays: Sequence[LegReplay], white_scale: float, arw: float,
                 model: NoiseModel | None = None):
        self.reps = list(replays)
        self.wcache: dict[int, tuple[Term, list[NDArray]]] | None = None
        self.z = [r.dv_n_mps[1:, 0:2].reshape(-1) for r in self.reps]
        self.sizes = [z.size for z in self.z]
        self.n = int(sum(self.sizes))
        self.chol: list[NDArray | None] = []
        self.sig: list[NDArray] = []
        self.eig: list[tuple[NDArray, NDArray]] | None = None  # (U, 1 / sqrt(a + q lam))
        self._basis: list[tuple[NDArray, NDArray]] | None = None  # (U, lam) per leg
        for r in self.reps:
            s = r.sigma_v_n_mps[1:, 0:2].reshape(-1)
            self.sig.append(s)
            if model is not None:
                self.chol.append(linalg.cholesky(model.leg_covariance(r), lower=True))
            elif arw > 0.0:
                cov = arw**2 * gyro_noise_covariance(r)
                cov[np.diag_indices_from(cov)] += white_scale * s**2
                self.chol.append(linalg.cholesky(cov, lower=True))
            else:
                self.chol.append(None)
        self.zw = [self.whiten(i, z) for i, z in enumerate(self.z)]

    def rewhitened(self, replays: Sequence[LegReplay], white_scale: float, arw: float
                   ) -> Problem:
        """The same design with other data and its own whitening (``replays``: the same legs
        and rows, other ``dv_n_mps``); whitened blocks are cached on the new problem."""
        if arw <= 0.0:
            other = Problem(replays, white_scale, arw)
        else:
            other = copy.copy(self)
            other.reps = list(replays)
            other.chol = [None] * len(other.reps)
            other.eig = [(u, 1.0 / np.sqrt(white_scale + arw**2 * lam))
                         for u, lam in self.eigenbasis()]
            other.z = [r.dv_n_mps[1:, 0:2].reshape(-1) for r in other.reps]
            for r, s in zip(other.reps, self.sig, strict=True):
                if not np.array_equal(r.sigma_v_n_mps[1:, 0:2].reshape(-1), s):
                    raise ValueError("rewhitened: the replays' sigmas differ from the problem's")
            other.zw = [other.whiten(i, z) for i, z in enumerate(other.z)]
        other.wcache = {}
        return other

    def eigenbasis(self) -> list[tuple[NDArray, NDArray]]:
        """Per leg (U, lam): ``S^-1 K S^-1 = U diag(lam) U^T`` (module docstring), lam >= 0."""
        if self._basis is None:
            self._basis = []
            for r, s in zip(self.reps, self.sig, strict=True):
                lam, u = linalg.eigh(gyro_noise_covariance(r) / np.outer(s, s),
                                     check_finite=False)
                self._basis.append((u, np.clip(lam, 0.0, None)))
        return self._basis

    def with_data(self, z: Sequence[NDArray]) -> Problem:
        """The same design and whitening with other data (per leg, rows t > 0, [N, E])."""
        other = copy.copy(self)
        other.z = [np.asarray(a, dtype=float).reshape(-1) for a in z]
        other.zw = [self.whiten(i, a) for i, a in enumerate(other.z)]
        return other

    def whiten(self, i: int, a: NDArray) -> NDArray:
        if self.eig is not None:
            u, w = self.eig[i]
            y = u.T @ (a / (self.sig[i] if a.ndim == 1 else self.sig[i][:, None]))
            return y * (w if a.ndim == 1 else w[:, None])
        c = self.chol[i]
        if c is None:
            return a / (self.sig[i] if a.ndim == 1 else self.sig[i][:, None])
        return linalg.solve_triangular(c, a, lower=True, check_finite=False)

    def whitened_rms(self, res: Sequence[NDArray], legs: Sequence[int]) -> float:
        """RMS of the legs' raw residuals ``res[i]`` (flattened (2 (M - 1),)) whitened by
        their leg's noise model, over ``legs`` (dimensionless: noise sigmas)."""
        return rms([self.whiten(i, np.ravel(res[i])) for i in legs])

    def wblocks(self, term: Term) -> list[NDArray]:
        """Whitened blocks of a term (cached on the term, or on a re-whitened problem).

        A per-leg term's blocks on the other legs are zero, and so whitened: they are the
        term's own (shared, not copied; the ten lack-of-fit terms of a 1.5 h flight's ten
        null problems held 120 MiB of whitened zeros)."""
        def whitened() -> list[NDArray]:
            return [self.whiten(i, b) if term.local_leg in (None, i) else b
                    for i, b in enumerate(term.blocks)]

        if self.wcache is not None:
            # the entry holds the term: a freed term's id could be reused by a new one
            if id(term) not in self.wcache:
                self.wcache[id(term)] = (term, whitened())
            return self.wcache[id(term)][1]
        if term.wblocks is None:
            term.wblocks = whitened()
        return term.wblocks

    def leg_matrix(self, terms: Sequence[Term], i: int) -> NDArray:
        return np.hstack([self.wblocks(t)[i] for t in terms])

    @staticmethod
    def solve_normal(g: NDArray, b: NDArray) -> tuple[NDArray, NDArray, int]:
        """Minimum-norm solution of the column-scaled normal equations; (x, G^+, rank)."""
        d = np.sqrt(np.diag(g))
        d[d == 0] = 1.0
        lam, v = np.linalg.eigh(g / np.outer(d, d))
        keep = lam > lam[-1] * 1e-13 if lam.size else np.zeros(0, bool)
        ginv = (v[:, keep] / lam[keep]) @ v[:, keep].T
        ginv = ginv / np.outer(d, d)
        return ginv @ b, ginv, int(keep.sum())

    def fit(self, terms: Sequence[Term], legs: Sequence[int] | None = None) -> Fit:
        legs = range(len(self.reps)) if legs is None else legs
        hws = {i: self.leg_matrix(terms, i) for i in legs}
        g = sum(h.T @ h for h in hws.values())
        b = sum(hws[i].T @ self.zw[i] for i in legs)
        x, ginv, rank = self.solve_normal(g, b)
        rss = sum(float(np.sum((self.zw[i] - hws[i] @ x) ** 2)) for i in legs)
        res_raw = [self.z[i] - np.hstack([t.blocks[i] for t in terms]) @ x for i in legs]
        return Fit(x, ginv, rss, rank, res_raw)

    def heldout(self, terms: Sequence[Term]) -> list[NDArray]:
        """Leave-one-leg-out raw residuals per leg (held-out leg's own tilt fitted on it)."""
        out = []
        nl = len(self.reps)
        for i in range(nl):
            others = [j for j in range(nl) if j != i]
            common = [t for t in terms if t.local_leg is None]
            local_o = [t for t in terms if t.local_leg in others]
            local_i = [t for t in terms if t.local_leg == i]
            x = self.fit(common + local_o, others).x
            k = sum(t.blocks[i].shape[1] for t in common)
            r = self.z[i] - np.hstack([t.blocks[i] for t in common]) @ x[:k]
            if local_i:
                hl = np.hstack([t.blocks[i] for t in local_i])
                hlw = self.whiten(i, hl)
                xl, _, _ = self.solve_normal(hlw.T @ hlw, hlw.T @ self.whiten(i, r))
                r = r - hl @ xl
            out.append(r)
        return out


def rms(res: Sequence[NDArray]) -> float:
    a = np.concatenate([np.ravel(r) for r in res])
    return float(np.sqrt(np.mean(a**2))) if a.size else float("nan")


def f_test(rss0: float, rss1: float, r: int, dof1: int) -> tuple[float, float]:
    if r <= 0 or dof1 <= 0 or rss1 <= 0:
        return float("nan"), 1.0
    f = max(rss0 - rss1, 0.0) / r / (rss1 / dof1)
    return float(f), f_sf(f, r, dof1)


def bic(rss_w: float, n: int, k: int) -> float:
    return n * np.log(rss_w / n) + k * np.log(n)
