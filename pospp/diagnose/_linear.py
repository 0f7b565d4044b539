"""Whitened stacked least squares over legs: the linear-model machinery of the workflow.

Rows are B's horizontal velocity errors [dv_N, dv_E] at the samples t > 0 of each leg
(sample-major), whitened per leg by A's sigmas, by the Cholesky factor of a full noise model,
or, for ``Sigma = a diag(sigma^2) + q K`` (K: :func:`pospp.calib.noise_model.
gyro_noise_covariance`), by a Kalman filter: K is the covariance of ``g_i s_i`` with s a
random walk (:func:`pospp.calib.noise_model.forcing_increments`), so the filter's
innovations, each normalised by its 2 x 2 covariance's Cholesky factor, are ``L^-1 y`` with
L the Cholesky factor of Sigma in the rows' order (conditioning one row at a time on the
earlier ones is what Cholesky does). Its gains depend on (a, q) only: a problem holds
(M, 15, 2) gains per leg, not an (2M)^2 factor, and the null realisations' problems (the same
legs, another a and q) make their own in milliseconds (the eigenbasis this replaced cost
0.13 s per leg and 8 MiB per leg on the 1.5 h flight). Columns come in named blocks
(:class:`Term`); fits solve the column-scaled normal equations (minimum norm on rank
deficiency). SI units.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy import linalg

from pospp.calib.noise_model import NoiseModel, forcing_increments
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
        self.sig = [r.sigma_v_n_mps[1:, 0:2].reshape(-1) for r in self.reps]
        self.chol: list[NDArray | None] = [None] * len(self.reps)
        self.kf: list[tuple[NDArray, NDArray, NDArray]] | None = None  # (g, gains, chol)
        self._forcing: list[tuple[NDArray, NDArray]] | None = None  # (g, dS) per leg
        if model is not None:
            self.chol = [linalg.cholesky(model.leg_covariance(r), lower=True)
                         for r in self.reps]
        elif arw > 0.0:
            self.kf = self._gains(white_scale, arw)
        self.zw = [self.whiten(i, z) for i, z in enumerate(self.z)]

    def _gains(self, white_scale: float, arw: float) -> list[tuple[NDArray, NDArray, NDArray]]:
        """Per leg the Kalman filter of ``white_scale diag(sigma^2) + arw^2 K`` (module
        docstring): (g, gains (M - 1, 15, 2), innovation Cholesky factors (M - 1, 3))."""
        if self._forcing is None:
            self._forcing = [forcing_increments(r) for r in self.reps]
        out = []
        for (g, ds), s, r in zip(self._forcing, self.sig, self.reps, strict=True):
            try:
                out.append((g, *_kalman_gains(g, ds, arw**2, white_scale * s**2)))
            except ValueError as exc:
                raise ValueError(f"leg {r.leg.leg_id}: {exc}") from exc
        return out

    def rewhitened(self, replays: Sequence[LegReplay], white_scale: float, arw: float
                   ) -> Problem:
        """The same design with other data and its own whitening (``replays``: the same legs
        and rows, other ``dv_n_mps``); whitened blocks are cached on the new problem."""
        if arw <= 0.0 or self.kf is None:  # white, or a full noise model: its own problem
            other = Problem(replays, white_scale, arw)
        else:
            other = copy.copy(self)
            other.reps = list(replays)
            other.kf = self._gains(white_scale, arw)
            other.z = [r.dv_n_mps[1:, 0:2].reshape(-1) for r in other.reps]
            for r, s in zip(other.reps, self.sig, strict=True):
                if not np.array_equal(r.sigma_v_n_mps[1:, 0:2].reshape(-1), s):
                    raise ValueError("rewhitened: the replays' sigmas differ from the problem's")
            other.zw = [other.whiten(i, z) for i, z in enumerate(other.z)]
        other.wcache = {}
        return other

    def with_data(self, z: Sequence[NDArray]) -> Problem:
        """The same design and whitening with other data (per leg, rows t > 0, [N, E])."""
        other = copy.copy(self)
        other.z = [np.asarray(a, dtype=float).reshape(-1) for a in z]
        other.zw = [self.whiten(i, a) for i, a in enumerate(other.z)]
        return other

    def whiten(self, i: int, a: NDArray) -> NDArray:
        """``L^-1 a`` for leg i's rows (1-D, or 2-D with columns), L its noise's square root."""
        if self.kf is not None:
            g, gains, chol = self.kf[i]
            y = _kalman_whiten(g, gains, chol, np.ascontiguousarray(
                a if a.ndim == 2 else a[:, None], dtype=float))
            return y if a.ndim == 2 else y[:, 0]
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
        """Whitened fit of ``terms`` over ``legs`` (default all). Each leg adds the normal
        equations of its own columns only: a per-leg term is zero on the other legs (the ten
        lack-of-fit terms of a 1.5 h flight's legs are 240 of its 263 columns, and their
        zeros were most of a fit's time)."""
        legs = range(len(self.reps)) if legs is None else legs
        widths = [t.blocks[0].shape[1] for t in terms]
        starts = np.cumsum([0] + widths)
        g = np.zeros((int(starts[-1]),) * 2)
        b = np.zeros(g.shape[0])
        own = {}  # leg -> (its terms, their columns, its whitened matrix)
        for i in legs:
            on = [j for j, t in enumerate(terms) if t.local_leg in (None, i)]
            cols = np.concatenate([np.zeros(0, dtype=np.int64)] + [
                np.arange(starts[j], starts[j] + widths[j]) for j in on])
            mine = [terms[j] for j in on]
            h = self.leg_matrix(mine, i) if mine else np.zeros((self.sizes[i], 0))
            g[np.ix_(cols, cols)] += h.T @ h
            b[cols] += h.T @ self.zw[i]
            own[i] = (mine, cols, h)
        x, ginv, rank = self.solve_normal(g, b)
        rss = sum(float(np.sum((self.zw[i] - h @ x[cols]) ** 2))
                  for i, (_, cols, h) in own.items())
        res_raw = [self.z[i] - np.hstack([np.zeros((self.sizes[i], 0))]
                                         + [t.blocks[i] for t in own[i][0]]) @ x[own[i][1]]
                   for i in legs]
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


@njit(cache=True, nogil=True)
def _kalman_gains(g, ds, q, r):
    """The Kalman filter of ``y_k = g_k s_k + e_k`` (2 rows per sample, Cov e_k = diag(r_2k,
    r_2k+1)), ``s_k = s_k-1 + eta_k`` (Cov q dS_k, s_0 = 0): per sample the gain
    ``P g^T S^-1`` (15, 2) and the innovation covariance's Cholesky factor (l11, l21, l22).
    Covariance update ``P - K g P``, symmetrised. Raises ValueError when an innovation
    covariance is not positive definite (as the Cholesky factor of Sigma would fail)."""
    m, n = g.shape[0], g.shape[2]
    gains = np.empty((m, n, 2))
    chol = np.empty((m, 3))
    p = np.zeros((n, n))
    gp = np.empty((2, n))
    for k in range(m):
        for a in range(n):
            for b in range(n):
                p[a, b] += q * ds[k, a, b]
        for i in range(2):
            for b in range(n):
                acc = 0.0
                for a in range(n):
                    acc += g[k, i, a] * p[a, b]
                gp[i, b] = acc
        s00, s01, s11 = r[2 * k], 0.0, r[2 * k + 1]
        for a in range(n):
            s00 += gp[0, a] * g[k, 0, a]
            s01 += gp[0, a] * g[k, 1, a]
            s11 += gp[1, a] * g[k, 1, a]
        if not (s00 > 0.0 and s11 - s01 * s01 / s00 > 0.0):
            raise ValueError("whitening: the noise covariance is not positive definite")
        l11 = math.sqrt(s00)
        l21 = s01 / l11
        chol[k, 0], chol[k, 1], chol[k, 2] = l11, l21, math.sqrt(s11 - l21 * l21)
        det = s00 * s11 - s01 * s01
        for a in range(n):
            gains[k, a, 0] = (gp[0, a] * s11 - gp[1, a] * s01) / det
            gains[k, a, 1] = (gp[1, a] * s00 - gp[0, a] * s01) / det
        for a in range(n):
            for b in range(a, n):
                v = p[a, b] - 0.5 * (gains[k, a, 0] * gp[0, b] + gains[k, a, 1] * gp[1, b]
                                     + gains[k, b, 0] * gp[0, a] + gains[k, b, 1] * gp[1, a])
                p[a, b] = v
                p[b, a] = v
    return gains, chol


@njit(cache=True, nogil=True)
def _kalman_whiten(g, gains, chol, y):
    """The filter's normalised innovations of the columns of ``y`` (2M, c):
    ``w_2k = nu_0 / l11``, ``w_2k+1 = (nu_1 - l21 w_2k) / l22`` (:func:`_kalman_gains`)."""
    m, n, c = g.shape[0], g.shape[2], y.shape[1]
    x = np.zeros((n, c))
    out = np.empty_like(y)
    for k in range(m):
        for j in range(c):
            nu0 = y[2 * k, j]
            nu1 = y[2 * k + 1, j]
            for a in range(n):
                nu0 -= g[k, 0, a] * x[a, j]
                nu1 -= g[k, 1, a] * x[a, j]
            w0 = nu0 / chol[k, 0]
            out[2 * k, j] = w0
            out[2 * k + 1, j] = (nu1 - chol[k, 1] * w0) / chol[k, 2]
            for a in range(n):
                x[a, j] += gains[k, a, 0] * nu0 + gains[k, a, 1] * nu1
    return out
