"""The restricted-maximum-likelihood (REML) and generalised-least-squares pieces of the
calibration, each held once: Cholesky whitening, the REML negative log-likelihood of a
whitened system, the variance grid search, the scaled SVD solve, the per-leg and full-covariance
likelihoods, the residual autocorrelation inflation, and the Gauss-Markov drift fit with its
grade-versus-flight likelihood-ratio test.

Used by :func:`pospp.calib.solve.fit_calibration` and :func:`pospp.calib.solve.fit_noise_model`.
Moved out of :mod:`pospp.calib.solve` (issue 17); frames and units as there (SI).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np
from numpy.typing import NDArray
from scipy import linalg, optimize
from scipy.linalg import lapack

from pospp.calib.noise_model import (
    DriftSmoother,
    NoiseBasis,
    _gm_covariance,
    gm_noise_operator,
    noise_basis,
)

GM_REJECT_DNLL = 0.5 * 5.991
"""The flight's drift replaces the grade's only when the grade's (sigma, tau) is rejected by a
likelihood-ratio test at 5 % (chi-square, 2 degrees of freedom: 2 dnll > 5.991)."""


def _blocks_reml_nll(params: NDArray, mats: list[tuple], hs: list[NDArray],
                     zs: list[NDArray]) -> float:
    """Negative restricted log-likelihood over independent leg blocks (constants dropped).

    Each leg's covariance is ``sum_k params[k] M_k`` (its matrices in ``mats``).
    """
    logdet = 0.0
    hw_all, zw_all = [], []
    for m, h, z in zip(mats, hs, zs, strict=True):
        w = _chol_whiten(sum(p * mk for p, mk in zip(params, m, strict=True)), h, z)
        if w is None:
            return 1e30
        hw_all.append(w[0])
        zw_all.append(w[1])
        logdet += w[2]
    hw, zw = np.vstack(hw_all), np.concatenate(zw_all)
    return _reml_whitened(hw, zw, logdet)


def _cholesky_lower(c: NDArray) -> NDArray | None:
    """L with C = L L^T (LAPACK dpotrf, upper triangle zeroed), None when C is not positive
    definite. The same factor as ``np.linalg.cholesky`` (bit for bit here), at half its
    time for the 700-row covariances of a 1.5 h flight's legs (issue 18)."""
    ll, info = lapack.dpotrf(c, lower=1, clean=1)
    if info < 0:
        raise ValueError(f"dpotrf: argument {-info} illegal")
    return ll if info == 0 else None


def _chol_whiten(c: NDArray, h: NDArray, z: NDArray) -> tuple[NDArray, NDArray, float] | None:
    """(L^-1 H, L^-1 z, log det C) with C = L L^T (Cholesky); None when C is not positive
    definite. H (n, p) and z (n,) are solved together (one triangular solve)."""
    ll = _cholesky_lower(c)
    if ll is None:
        return None
    hz = _tri_solve(ll, np.column_stack([h, z]))
    return hz[:, :-1], hz[:, -1], 2.0 * float(np.sum(np.log(np.diag(ll))))


def _grid_argmin(
    obj, bounds: list[tuple[float, float]], n: int
) -> tuple[NDArray, list[NDArray]]:
    """The best point of an n-per-axis grid over ``bounds`` (the start of the REML searches).

    Returns (best point, the grid's axes).
    """
    axes = [np.linspace(lo, hi, n) for lo, hi in bounds]
    grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    vals = [obj(th) for th in grid]
    return grid[int(np.argmin(vals))], axes


def _reml_whitened(hw: NDArray, zw: NDArray, logdet: float) -> float:
    """Negative restricted log-likelihood from the whitened system and log det Cov.

    ``0.5 (log det C + log det H^T C^-1 H + r^T C^-1 r)`` (constants dropped), with the
    information's determinant from the column-scaled SVD (rank-deficient directions dropped).
    """
    norms, u, sv, _, keep = _scaled_svd(hw)
    proj = u[:, keep].T @ zw
    rss = float(zw @ zw - proj @ proj)
    info = 2.0 * float(np.sum(np.log(sv[keep])) + np.sum(np.log(norms)))
    return 0.5 * (logdet + info + rss)


def _autocorr_inflation(res: NDArray, n_series: int) -> tuple[float, float]:
    """((1 + rho) / (1 - rho), rho) from the residuals' lag-one autocorrelation."""
    r = res.reshape(n_series, -1) if res.size % n_series == 0 else res[None, :]
    num = np.sum(r[:, 1:] * r[:, :-1])
    den = np.sum(r * r)
    rho = float(np.clip(num / den, 0.0, 0.98)) if den > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho), rho


def _lag1(series: list[NDArray]) -> float:
    num = sum(float(np.sum(r[1:] * r[:-1])) for r in series)
    den = sum(float(np.sum(r * r)) for r in series)
    return num / den if den > 0 else 0.0


def _scaled_svd(hw: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Column norms of a whitened design and the SVD of it scaled to unit columns:
    (norms, U, s, V^T, kept), singular values below 1e-10 of the largest not kept (the
    one rank rule of the GLS and of REML's information determinant)."""
    norms = np.linalg.norm(hw, axis=0)
    norms[norms == 0] = 1.0
    u, sv, vt = np.linalg.svd(hw / norms, full_matrices=False)
    return norms, u, sv, vt, sv > sv[0] * 1e-10


def _solve_scaled(hw: NDArray, zw: NDArray) -> tuple[NDArray, NDArray, bool]:
    """Least squares of a whitened system with column scaling; (x, (H^T H)^-1, deficient)."""
    norms, u, sv, vt, keep = _scaled_svd(hw)
    xs = vt[keep].T @ ((u[:, keep].T @ zw) / sv[keep])
    cov_s = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    return xs / norms, cov_s / np.outer(norms, norms), bool(not keep.all())


def _full_reml_nll(theta: NDArray, parts: tuple, fixed: tuple[float | None, float | None]
                   ) -> float:
    """Negative restricted log-likelihood with the full (legs coupled) covariance.

    In D^-1/2-scaled units, C = a I + q K + s2 G; theta holds log a and the logs of the free
    ones of (q, s2).
    """
    hs, zs, k, gm = parts
    w = _chol_whiten(_full_cov(theta, k, gm, fixed), hs, zs)
    return 1e30 if w is None else _reml_whitened(*w)


def _eig_reml_nll(theta: NDArray, lam: NDArray, vhz: NDArray) -> float:
    """:func:`_full_reml_nll` with only a free, from the fixed part's eigendecomposition
    ``q K + s2 G = V diag(lam) V^T`` and ``vhz = V^T [H z]``: ``C = V diag(lam + a) V^T``."""
    d = lam + float(np.exp(theta[0]))
    if not np.all(d > 0.0):
        return 1e30
    w = vhz / np.sqrt(d)[:, None]
    return _reml_whitened(w[:, :-1], w[:, -1], float(np.sum(np.log(d))))


def _full_params(theta: NDArray, fixed: tuple[float | None, float | None]
                 ) -> tuple[float, float, float]:
    a = float(np.exp(theta[0]))
    j = 1
    vals = []
    for f in fixed:
        if f is None:
            vals.append(float(np.exp(theta[j])))
            j += 1
        else:
            vals.append(float(f))
    return a, vals[0], vals[1]


def _full_cov(theta: NDArray, k: NDArray, gm: NDArray,
              fixed: tuple[float | None, float | None]) -> NDArray:
    a, q, s2 = _full_params(theta, fixed)
    c = q * k + s2 * gm
    c[np.diag_indices_from(c)] += a
    return c


def _tri_solve(ll: NDArray, b: NDArray) -> NDArray:
    return linalg.solve_triangular(ll, b, lower=True, check_finite=False)


class _LegNoise:
    """Projected H and z of one leg in its :class:`NoiseBasis`."""

    def __init__(self, basis: NoiseBasis, h: NDArray, z: NDArray):
        self.lam, self.u, self.sq = basis.lam, basis.u, basis.sq
        self.h = basis.u.T @ (h / basis.sq[:, None])
        self.z = basis.u.T @ (z / basis.sq)
        self.logdet_d = 2.0 * float(np.sum(np.log(basis.sq)))

    def whiten(self, a: float, q: float) -> tuple[NDArray, NDArray, float]:
        v = a + q * self.lam
        w = 1.0 / np.sqrt(v)
        return self.h * w[:, None], self.z * w, float(np.sum(np.log(v))) + self.logdet_d


def _gls(blocks: list[_LegNoise], a: float, q: float) -> tuple[NDArray, NDArray, float]:
    parts = [b.whiten(a, q) for b in blocks]
    return (np.vstack([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            sum(p[2] for p in parts))


def _reml_nll(theta: NDArray, blocks: list[_LegNoise], q_fixed: float | None) -> float:
    """Negative restricted log-likelihood (constants dropped) of log a (and log q)."""
    a = float(np.exp(theta[0]))
    q = q_fixed if q_fixed is not None else float(np.exp(theta[1]))
    hw, zw, logdet = _gls(blocks, a, q)
    return _reml_whitened(hw, zw, logdet)


def _calibrate_gm(legs, h, z, edges, noise_step_s, bases, gm_ops, arw_given, sigma_given,
                  tau_s, bin_s, prior=None, noise_cache=None):
    """GLS + REML with the Gauss-Markov drift (full covariance over all legs).

    With ``prior`` (:class:`DriftPrior`) and the sigma estimated, tau is profiled over the
    prior's candidates and the grade's weak prior is added to the restricted likelihood
    (maximum a posteriori); the returned profile holds (tau, penalised nll) per candidate.
    ``noise_cache``: see :func:`pospp.calib.solve.fit_calibration`.
    """
    rows, sqs, kb, ops = [], [], [], []
    for i, rep in enumerate(legs):
        lid = rep.leg.leg_id
        basis = None if bases is None else bases.get(lid)
        if basis is None:
            basis = noise_basis(rep, noise_step_s=noise_step_s)
        op = None if gm_ops is None else gm_ops.get(lid)
        if op is None:
            op = gm_noise_operator(rep, basis.samples, bin_s=bin_s)
        rows.append(basis.rows + edges[i])
        sqs.append(basis.sq)
        kb.append((basis.u * basis.lam) @ basis.u.T)
        ops.append((op[0] / basis.sq[:, None], op[1]))
    r_all = np.concatenate(rows)
    sq = np.concatenate(sqs)
    hs, zs = h[r_all] / sq[:, None], z[r_all] / sq
    k = linalg.block_diag(*kb)
    q_fixed = None if arw_given is None else float(arw_given) ** 2
    s2_fixed = None if sigma_given is None else float(sigma_given) ** 2
    fixed = (q_fixed, s2_fixed)
    use_prior = prior is not None and s2_fixed is None
    taus = prior.candidates_s() if use_prior else (float(tau_s),)
    profile = []
    for tau in taus:
        parts = (hs, zs, k, _gm_covariance(ops, tau))
        pen = ((lambda th, tau=tau: prior.penalty(_full_params(th, fixed)[2], tau))
               if use_prior else None)
        eig = None
        if noise_cache is not None and None not in fixed:  # only A's scale is fitted
            key = (tuple(rep.leg.leg_id for rep in legs), noise_step_s, bin_s, float(tau),
                   fixed, hs.shape)
            if key not in noise_cache:
                noise_cache[key] = linalg.eigh(_full_cov(np.array([-np.inf]), k, parts[3],
                                                         fixed), check_finite=False)
            eig = noise_cache[key]
        th, val = _fit_variances(parts, fixed, pen, eig)
        profile.append((float(tau), val, th, parts))
    tau_best, _, th, parts = min(profile, key=lambda p: p[1])
    source = ""
    if use_prior:
        source = "flight"
        nll_best = _full_reml_nll(th, parts, fixed)
        g_fixed = (q_fixed, float(prior.sigma_radps) ** 2)
        g_parts = (hs, zs, k, _gm_covariance(ops, float(prior.tau_s)))
        g_th, g_nll = _fit_variances(g_parts, g_fixed)
        if g_nll - nll_best < GM_REJECT_DNLL:  # the flight does not reject the grade
            source, tau_best, parts, fixed = "grade", float(prior.tau_s), g_parts, g_fixed
            th = g_th
    gm = parts[3]
    a, q, s2 = _full_params(th, fixed)
    ll = _cholesky_lower(_full_cov(th, k, gm, fixed))
    if ll is None:
        raise np.linalg.LinAlgError("the drift fit's covariance is not positive definite")
    x, cov, deficient = _solve_scaled(_tri_solve(ll, hs), _tri_solve(ll, zs))
    r = zs - hs @ x
    wr = _tri_solve(ll, r)  # innovations: time-ordered within each leg
    cuts = np.cumsum([rr.size for rr in rows])[:-1]
    white = np.split(wr, cuts)
    alpha = np.split(linalg.cho_solve((ll, True), r), cuts)
    u = np.vstack([(o[0].T @ al).reshape(-1, 3) for o, al in zip(ops, alpha, strict=True)])
    drift = DriftSmoother(np.concatenate([o[1] for o in ops]), u, s2, tau_best)
    tau_profile = tuple((t, v) for t, v, _, _ in profile) if use_prior else ()
    return (x, cov, deficient, a, float(np.sqrt(q)), float(np.sqrt(s2)), white, drift,
            tau_profile, source)


def _fit_variances(parts: tuple, fixed: tuple[float | None, float | None], penalty=None,
                   eig: tuple[NDArray, NDArray] | None = None) -> tuple[NDArray, float]:
    """REML (plus an optional penalty of theta) of a and the free ones of (q, s2).

    A coarse grid (each evaluation is a Cholesky of the full covariance), then bounded Brent
    (only a free) or Nelder-Mead. Returns (theta, objective at theta). ``eig``: (lam, V) of
    the fixed part ``q K + s2 G`` when only a is free: ``C = V diag(lam + a) V^T``, so each
    evaluation scales ``V^T [H z]`` instead of factoring C (the same likelihood to rounding).
    """
    bounds = [(np.log(1e-6), np.log(1e4))]
    if fixed[0] is None:
        bounds.append((np.log(1e-22), np.log(1e-6)))
    if fixed[1] is None:
        bounds.append((np.log(1e-17), np.log(1e-8)))
    nll: Callable[[NDArray], float] = partial(_full_reml_nll, parts=parts, fixed=fixed)
    if eig is not None:
        nll = partial(_eig_reml_nll, lam=eig[0],
                      vhz=eig[1].T @ np.column_stack([parts[0], parts[1]]))

    def obj(th: NDArray) -> float:
        v = nll(th)
        return v if penalty is None else v + penalty(th)

    best, axes = _grid_argmin(obj, bounds, 9 if len(bounds) == 1 else 6)
    if len(bounds) == 1:  # only A's scale: bounded Brent around the best grid point
        step = axes[0][1] - axes[0][0]
        opt = optimize.minimize_scalar(
            lambda v: obj(np.array([v])), method="bounded",
            bounds=(best[0] - step, best[0] + step), options={"xatol": 1e-3})
        th = np.clip(np.array([opt.x]), bounds[0][0], bounds[0][1])
    else:
        opt = optimize.minimize(obj, best, method="Nelder-Mead",
                                options={"xatol": 1e-2, "fatol": 1e-3, "maxiter": 300})
        th = np.clip(opt.x, [b[0] for b in bounds], [b[1] for b in bounds])
    return th, obj(th)
