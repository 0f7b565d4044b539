"""The restricted-maximum-likelihood (REML) and generalised-least-squares pieces of the
calibration, each held once: Cholesky whitening, the REML negative log-likelihood of a
whitened system, the variance grid search, the scaled SVD solve, the per-leg and full-covariance
likelihoods, the residual autocorrelation inflation, and the Gauss-Markov drift fit with its
grade-versus-flight likelihood-ratio test.

Used by :func:`pospp.calib.solve.fit_calibration` and :func:`pospp.calib.solve.fit_noise_model`;
frames and units as there (SI).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy import linalg, optimize
from scipy.linalg import lapack

from pospp.calib._drift_kernel import drift_filter_whiten
from pospp.calib.noise_model import (
    DriftSmoother,
    NoiseBasis,
    gm_covariance,
    gm_noise_operator,
    leg_noise_basis,
)

if TYPE_CHECKING:  # for the annotation only: solve imports this module
    from pospp.calib.solve import FitOptions

GM_REJECT_DNLL = 0.5 * 5.991
"""The flight's drift replaces the grade's only when the grade's (sigma, tau) is rejected by a
likelihood-ratio test at 5 % (chi-square, 2 degrees of freedom: 2 dnll > 5.991)."""

_FD_STEP_LOG = 1e-3
"""The variance search's finite-difference step in the log-parameters [-]: the restricted
likelihood's rounding (~1e-6 on a 1.5 h flight's ten legs) over it is 1e-3 in the gradient,
and its forward-difference bias moves the optimum by half of it (0.05 % in a variance)."""


def blocks_reml_nll(params: NDArray, mats: list[tuple], hs: list[NDArray],
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
    time for the 700-row covariances of a 1.5 h flight's legs."""
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


def grid_argmin(
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
    A tall system is first reduced to the R of its QR factorisation (LAPACK dgeqrf): an
    orthogonal transform of the rows, which leaves every term unchanged (column norms,
    singular values, residual) and makes the SVD one of (p + 1) rows.
    """
    if hw.shape[0] > hw.shape[1] + 1:
        qr, _, _, info = lapack.dgeqrf(np.column_stack([hw, zw]))
        if info != 0:
            raise ValueError(f"dgeqrf: argument {-info} illegal")
        r = np.triu(qr[:hw.shape[1] + 1])
        hw, zw = r[:, :-1], r[:, -1]
    norms, u, sv, _, keep = _scaled_svd(hw)
    proj = u[:, keep].T @ zw
    rss = float(zw @ zw - proj @ proj)
    info = 2.0 * float(np.sum(np.log(sv[keep])) + np.sum(np.log(norms)))
    return 0.5 * (logdet + info + rss)


def autocorr_inflation(res: NDArray, n_series: int) -> tuple[float, float]:
    """((1 + rho) / (1 - rho), rho) from the residuals' lag-one autocorrelation."""
    r = res.reshape(n_series, -1) if res.size % n_series == 0 else res[None, :]
    num = np.sum(r[:, 1:] * r[:, :-1])
    den = np.sum(r * r)
    rho = float(np.clip(num / den, 0.0, 0.98)) if den > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho), rho


def lag1_autocorrelation(series: list[NDArray]) -> float:
    """Pooled lag-one autocorrelation of several residual series [-].

    ``rho = sum_s sum_i r_s[i] r_s[i-1] / sum_s sum_i r_s[i]^2`` (0 when every series is
    zero); each series is a 1-D array in time order (e.g. one leg's whitened N or E rows).
    """
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


def solve_scaled(hw: NDArray, zw: NDArray) -> tuple[NDArray, NDArray, bool]:
    """Least squares of a whitened system with column scaling; (x, (H^T H)^-1, deficient)."""
    norms, u, sv, vt, keep = _scaled_svd(hw)
    xs = vt[keep].T @ ((u[:, keep].T @ zw) / sv[keep])
    cov_s = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    return xs / norms, cov_s / np.outer(norms, norms), bool(not keep.all())


def scaled_map(hw: NDArray) -> NDArray:
    """The linear map (p, n) of :func:`solve_scaled`: its x is ``scaled_map(hw) @ zw``."""
    norms, u, sv, vt, keep = _scaled_svd(hw)
    return (vt[keep].T / sv[keep]) @ u[:, keep].T / norms[:, None]


def gls_gain(blocks: list[LegNoise], a: float, q: float, rows: list[NDArray], n_z: int,
              scaled: NDArray) -> NDArray:
    """The per-leg GLS's estimate as a linear map of the design's z (p, n_z): each leg's rows
    ``rows[i]`` whitened as :meth:`LegNoise.whiten` does, then ``scaled``
    (:func:`scaled_map` of the stacked whitened design)."""
    gain = np.zeros((scaled.shape[0], n_z))
    at = 0
    for r, b in zip(rows, blocks, strict=True):
        m = b.u.shape[1]
        gain[:, r] = (scaled[:, at:at + m] / np.sqrt(a + q * b.lam)) @ b.u.T / b.sq
        at += m
    return gain


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


@dataclass(frozen=True)
class DriftLegs:
    """The legs of a drift fit in time order, with the parts of C that do not depend on tau:
    the Gauss-Markov drift's restricted likelihood by a Kalman filter over the legs.

    The calibration's full covariance (:func:`calibrate_gm`, scaled units)

        C = a I + q K + s2 S E S^T,   E_jk = exp(-|tau_j - tau_k| / tau) I_3

    couples every leg to every other through the drift bins' correlation E, so factoring C costs
    the legs cubed. The drift is a first-order
    Gauss-Markov (Ornstein-Uhlenbeck) process, which is Markov: given the drift at the last bin of
    leg L - 1, leg L's bins are independent of every earlier leg. A Kalman filter over the legs
    (in time order) whose state is the unit-variance drift e at the previous leg's last bin (3
    body axes) therefore gives the same likelihood, exactly (to rounding), at a cost linear in
    the legs. With the legs' data in the regression-augmented form (the columns of [H z] filtered
    as data, de Jong's augmented Kalman filter), the filter yields W [H z] with W C W^T = I, which
    is all REML needs (its value is invariant to the choice of W).

    Per leg L with bins t_1 < ... < t_J (body axis a's columns S_a, n x J), E_L the bins'
    correlation, m = E_L[:, 0], rho = exp(-(t_1 - t_last of L-1) / tau) (1 and e ~ N(0, I) before
    the first leg), and e | past ~ N(mu, P)::

        d_L,a | past ~ N(rho m mu_a, E_L - rho^2 m m^T + rho^2 P_aa m m^T)   (axis a; P couples)
        V   = a I + q K_L + s2 (G_LL - rho^2 M (I - P) M^T),  G_LL = sum_a S_a E_L S_a^T
        nu  = [H z]_L - sqrt(s2) rho M mu,                    M = [S_a m]_a (n x 3)
        C_ye = sqrt(s2) (N - rho^2 m_J M (I - P)),            N = [S_a E_L[:, J]]_a
        mu' = rho m_J mu + C_ye^T V^-1 nu
        P'  = rho^2 m_J^2 P + (1 - rho^2 m_J^2) I - C_ye^T V^-1 C_ye

    and the rows V^-1/2 nu (V = L L^T, Cholesky) with log det C = sum 2 log diag L.

    Attributes
    ----------
    hz : ndarray, (n, p + 1)
        [H z] of the legs' rows, leg after leg, in the scaled units of the fit (rows divided
        by sigma_A).
    off : ndarray of int, (L + 1,)
        Each leg's rows ``off[l]:off[l+1]``.
    k_flat : ndarray
        Each leg's gyro-noise covariance K (n_L x n_L, same units) raveled from
        ``sq_off[l]``.
    sq_off : ndarray of int, (L + 1,)
        Where each leg's n_L^2 block starts in ``k_flat`` (and in ``DriftFilter.g_flat``).
    s_axes : tuple of ndarray, (3, n_L, J_L)
        The drift operator S per body axis (bins with no effect on the rows dropped).
    t_bin_s : tuple of ndarray, (J_L,)
        The bins' run times [s], increasing within and across legs.
    """

    hz: NDArray
    off: NDArray
    k_flat: NDArray
    sq_off: NDArray
    s_axes: tuple[NDArray, ...]
    t_bin_s: tuple[NDArray, ...]

    @classmethod
    def from_blocks(cls, hz: list[NDArray], k: list[NDArray],
                    ops: list[tuple[NDArray, NDArray]]) -> DriftLegs | None:
        """From each leg's [H z] rows, K block and (S, bin times) (:func:`gm_noise_operator`
        layout: columns bin-major, axis-minor), sorted by time. None when the legs' bins
        interleave in time (legs that overlap, where the Markov order does not hold) or a
        leg has no drift bin at all."""
        legs = []
        for h_l, k_l, (s, t) in zip(hz, k, ops, strict=True):
            sp = s.reshape(s.shape[0], -1, 3)
            used = np.any(sp != 0.0, axis=(0, 2))  # a bin no row sees does not enter C
            if not used.any():
                return None
            legs.append((h_l, k_l, np.ascontiguousarray(sp[:, used, :].transpose(2, 0, 1)),
                         np.asarray(t, dtype=float)[used]))
        legs.sort(key=lambda leg: float(leg[3][0]))
        if np.any(np.diff(np.concatenate([leg[3] for leg in legs])) < 0.0):
            return None
        sizes = np.array([leg[0].shape[0] for leg in legs])
        return cls(np.ascontiguousarray(np.vstack([leg[0] for leg in legs])),
                   np.concatenate([[0], np.cumsum(sizes)]),
                   np.concatenate([leg[1].ravel() for leg in legs]),
                   np.concatenate([[0], np.cumsum(sizes**2)]),
                   tuple(leg[2] for leg in legs), tuple(leg[3] for leg in legs))

    def at_tau(self, tau_s: float) -> DriftFilter:
        """The tau-dependent parts of the filter (:class:`DriftFilter`)."""
        g, m, nn, rho, m_j = [], [], [], [], []
        prev_s = None
        for s_ax, t in zip(self.s_axes, self.t_bin_s, strict=True):
            e = np.exp(-np.abs(t[:, None] - t[None, :]) / tau_s)
            g.append(sum(s_ax[a] @ e @ s_ax[a].T for a in range(3)).ravel())
            m.append((s_ax @ e[:, 0]).T)
            nn.append((s_ax @ e[:, -1]).T)
            rho.append(1.0 if prev_s is None else float(np.exp(-(t[0] - prev_s) / tau_s)))
            m_j.append(float(e[-1, 0]))
            prev_s = float(t[-1])
        return DriftFilter(self, np.concatenate(g), np.ascontiguousarray(np.vstack(m)),
                           np.ascontiguousarray(np.vstack(nn)), np.array(rho), np.array(m_j))


@dataclass(frozen=True)
class DriftFilter:
    """:class:`DriftLegs` at one tau: G_LL raveled per leg, M and N stacked (n, 3), rho and
    m_J per leg, of :class:`DriftLegs`' equations."""

    legs: DriftLegs
    g_flat: NDArray
    m: NDArray
    nn: NDArray
    rho: NDArray
    m_j: NDArray

    def whiten(self, a: float, q: float, s2: float) -> tuple[NDArray, float] | None:
        """(W [H z], log det C) with W C W^T = I (rows leg after leg in time order); None
        when a leg's innovation covariance is not positive definite."""
        lg = self.legs
        out = np.empty_like(lg.hz)
        logdet = drift_filter_whiten(a, q, s2, lg.hz, lg.off, lg.k_flat, self.g_flat,
                                     lg.sq_off, self.m, self.nn, self.rho, self.m_j, out)
        return None if not np.isfinite(logdet) else (out, float(logdet))

    def reml_nll(self, a: float, q: float, s2: float) -> float:
        """The negative restricted log-likelihood of :func:`_full_reml_nll` (constants
        dropped), 1e30 when C is not positive definite."""
        w = self.whiten(a, q, s2)
        if w is None:
            return 1e30
        return _reml_whitened(w[0][:, :-1], w[0][:, -1], w[1])


class LegNoise:
    """Projected H and z of one leg in its :class:`NoiseBasis`.

    With ``K = U diag(lam) U^T`` in units scaled by ``sq`` (D^-1/2), the leg's covariance
    ``a I + q K`` is diagonal in U: ``h = U^T D^-1/2 H`` (m, p), ``z = U^T D^-1/2 z`` (m,),
    ``logdet_d = log det D``.
    """

    def __init__(self, basis: NoiseBasis, h: NDArray, z: NDArray):
        self.lam, self.u, self.sq = basis.lam, basis.u, basis.sq
        self.h = basis.u.T @ (h / basis.sq[:, None])
        self.z = basis.u.T @ (z / basis.sq)
        self.logdet_d = 2.0 * float(np.sum(np.log(basis.sq)))

    def whiten(self, a: float, q: float) -> tuple[NDArray, NDArray, float]:
        """(h, z divided by sqrt(a + q lam), log det of the leg's unscaled covariance)."""
        v = a + q * self.lam
        w = 1.0 / np.sqrt(v)
        return self.h * w[:, None], self.z * w, float(np.sum(np.log(v))) + self.logdet_d


def stack_whitened(blocks: list[LegNoise], a: float, q: float
                   ) -> tuple[NDArray, NDArray, float]:
    """The legs' whitened designs stacked for the per-leg GLS.

    Each leg's covariance is ``a I + q K`` in its :class:`NoiseBasis` (``a`` A's variance
    scale [-], ``q`` the gyro angle-random-walk PSD [rad^2/s]); returns (H_w (n, p), z_w (n,),
    log det Cov) with H_w, z_w the blocks of :meth:`LegNoise.whiten` one under the other.
    """
    parts = [b.whiten(a, q) for b in blocks]
    return (np.vstack([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            sum(p[2] for p in parts))


def reml_nll(theta: NDArray, blocks: list[LegNoise], q_fixed: float | None) -> float:
    """Negative restricted log-likelihood (constants dropped) of log a (and log q)."""
    a = float(np.exp(theta[0]))
    q = q_fixed if q_fixed is not None else float(np.exp(theta[1]))
    hw, zw, logdet = stack_whitened(blocks, a, q)
    return _reml_whitened(hw, zw, logdet)


def _kept(memo: dict, key: tuple, make: Callable[[], Any]) -> Any:
    """``memo[key]``, made by ``make()`` and kept there the first time (a fit's noise cache:
    what its refits of the same legs share)."""
    if key not in memo:
        memo[key] = make()
    return memo[key]


def calibrate_gm(legs, h, z, edges, options: FitOptions, tau_s: float, bases=None,
                 gm_ops=None, noise_cache=None):
    """GLS + REML with the Gauss-Markov drift (full covariance over all legs): the model of
    ``options`` (:class:`pospp.calib.solve.FitOptions`), the drift's correlation time ``tau_s``
    [s] (the start of its profile with a prior).

    With ``prior`` (:class:`DriftPrior`) and the sigma estimated, tau is profiled over the
    prior's candidates and the grade's weak prior is added to the restricted likelihood
    (maximum a posteriori); the returned profile holds (tau, penalised nll) per candidate.
    ``noise_cache``: see :func:`pospp.calib.solve.fit_calibration`. The likelihood is
    evaluated by the Kalman filter over the legs (:class:`DriftLegs`, linear in the legs);
    the chosen model's GLS factors the full covariance once.
    """
    noise_step_s, bin_s, prior = options.noise_step_s, options.gm_bin_s, options.gm_prior
    arw_given, sigma_given = options.gyro_arw_radpsqrts, options.gyro_gm_sigma_radps
    rows, sqs, kb, ops = [], [], [], []
    memo = {} if noise_cache is None else noise_cache  # the refits share the legs' grids
    for i, rep in enumerate(legs):
        lid = rep.leg.leg_id
        basis = leg_noise_basis(rep, noise_step_s, bases, memo)
        op = None if gm_ops is None else gm_ops.get(lid)
        if op is None:
            op = _kept(memo, ("gm_op", lid, noise_step_s, bin_s),
                       partial(gm_noise_operator, rep, basis.samples, bin_s=bin_s))
        rows.append(basis.rows + edges[i])
        sqs.append(basis.sq)
        kb.append((basis.u * basis.lam) @ basis.u.T)
        ops.append((op[0] / basis.sq[:, None], op[1]))
    r_all = np.concatenate(rows)
    sq = np.concatenate(sqs)
    hs, zs = h[r_all] / sq[:, None], z[r_all] / sq
    k = linalg.block_diag(*kb)
    cuts = np.cumsum([rr.size for rr in rows])[:-1]
    dlegs = DriftLegs.from_blocks(np.split(np.column_stack([hs, zs]), cuts), kb, ops)
    q_fixed = None if arw_given is None else float(arw_given) ** 2
    s2_fixed = None if sigma_given is None else float(sigma_given) ** 2
    fixed = (q_fixed, s2_fixed)
    grade = prior if s2_fixed is None else None  # the prior acts with the sigma estimated

    leg_ids = tuple(rep.leg.leg_id for rep in legs)

    def gm_cov(tau: float) -> NDArray:  # S E S^T, kept in the refits' memo (not in B - A)
        return _kept(memo, ("gm_cov", leg_ids, noise_step_s, bin_s, float(tau)),
                     partial(gm_covariance, ops, tau))

    def likelihood(tau: float, fixed: tuple) -> Callable[[NDArray], float]:
        if noise_cache is not None and None not in fixed:  # only A's scale is fitted
            lam, v = _kept(noise_cache, (leg_ids, noise_step_s, bin_s, float(tau), fixed,
                                         hs.shape),
                           lambda: linalg.eigh(_full_cov(np.array([-np.inf]), k, gm_cov(tau),
                                                         fixed), check_finite=False))
            return partial(_eig_reml_nll, lam=lam, vhz=v.T @ np.column_stack([hs, zs]))
        if dlegs is None:  # legs that overlap in time: the full covariance
            return partial(_full_reml_nll, parts=(hs, zs, k, gm_cov(tau)), fixed=fixed)
        filt = dlegs.at_tau(tau)
        return lambda th: filt.reml_nll(*_full_params(th, fixed))

    taus = grade.candidates_s() if grade is not None else (float(tau_s),)
    profile = _tau_profile(likelihood, taus, fixed, grade)
    tau_best, _, th, nll = min(profile, key=lambda p: p[1])
    source = ""
    if grade is not None:
        source = "flight"
        g_fixed = (q_fixed, float(grade.sigma_radps) ** 2)
        g_th, g_nll = fit_variances(likelihood(float(grade.tau_s), g_fixed), g_fixed)
        if g_nll - nll(th) < GM_REJECT_DNLL:  # the flight does not reject the grade
            source, tau_best, fixed, th = "grade", float(grade.tau_s), g_fixed, g_th
    a, q, s2 = _full_params(th, fixed)
    ll = _cholesky_lower(_full_cov(th, k, gm_cov(tau_best), fixed))
    if ll is None:
        raise np.linalg.LinAlgError("the drift fit's covariance is not positive definite")
    hw = _tri_solve(ll, hs)
    x, cov, deficient = solve_scaled(hw, _tri_solve(ll, zs))
    gain = np.zeros((x.size, z.size))  # x = gain z: L^-T maps the whitened rows' weights back
    gain[:, r_all] = linalg.solve_triangular(ll, scaled_map(hw).T, lower=True, trans="T",
                                             check_finite=False).T / sq
    r = zs - hs @ x
    wr = _tri_solve(ll, r)  # innovations: time-ordered within each leg
    white = np.split(wr, cuts)
    alpha = np.split(linalg.cho_solve((ll, True), r), cuts)
    u = np.vstack([(o[0].T @ al).reshape(-1, 3) for o, al in zip(ops, alpha, strict=True)])
    drift = DriftSmoother(np.concatenate([o[1] for o in ops]), u, s2, tau_best)
    tau_profile = tuple((t, v) for t, v, _, _ in profile) if grade is not None else ()
    return (x, cov, deficient, a, float(np.sqrt(q)), float(np.sqrt(s2)), white, drift,
            tau_profile, source, gain)


def _tau_profile(likelihood: Callable[[float, tuple], Callable[[NDArray], float]],
                 taus: tuple[float, ...], fixed: tuple[float | None, float | None],
                 grade: Any) -> list[tuple[float, float, NDArray, Callable[[NDArray], float]]]:
    """(tau [s], objective, theta, nll of theta) per candidate tau: the variances by
    :func:`fit_variances` of ``likelihood(tau, fixed)`` plus the grade's prior
    (:class:`pospp.calib.solve.DriftPrior`, None: no prior). The first candidate is searched
    from the grid, each next from the previous one's optimum (the profile over tau is
    smooth), and the lowest once more from the grid, the lower of its two optima kept."""
    def penalty(tau: float) -> Callable[[NDArray], float] | None:
        return None if grade is None else partial(_drift_penalty, grade=grade, tau_s=tau,
                                                  fixed=fixed)

    profile: list[tuple[float, float, NDArray, Callable[[NDArray], float]]] = []
    for tau in taus:
        nll = likelihood(tau, fixed)
        th, val = fit_variances(nll, fixed, penalty(tau), profile[-1][2] if profile else None)
        profile.append((float(tau), val, th, nll))
    i_best = min(range(len(profile)), key=lambda i: profile[i][1])
    if len(profile) > 1:
        tau, val, _, nll = profile[i_best]
        th, val_grid = fit_variances(nll, fixed, penalty(tau))
        if val_grid < val:
            profile[i_best] = (tau, val_grid, th, nll)
    return profile


def _drift_penalty(th: NDArray, grade: Any, tau_s: float,
                   fixed: tuple[float | None, float | None]) -> float:
    """The grade's prior (:meth:`pospp.calib.solve.DriftPrior.penalty`) of theta's drift
    variance at the correlation time ``tau_s`` [s]."""
    return float(grade.penalty(_full_params(th, fixed)[2], tau_s))


def variance_bounds(fixed: tuple[float | None, float | None]) -> list[tuple[float, float]]:
    """The box of the variance search in theta: log a in [log 1e-6, log 1e4] (A's variance
    scale [-]), then for each free one of (q, s2) (None in ``fixed``) log q in
    [log 1e-22, log 1e-6] (ARW PSD [rad^2/s]) and log s2 in [log 1e-17, log 1e-8] (drift
    variance [rad^2/s^2])."""
    bounds = [(np.log(1e-6), np.log(1e4))]
    if fixed[0] is None:
        bounds.append((np.log(1e-22), np.log(1e-6)))
    if fixed[1] is None:
        bounds.append((np.log(1e-17), np.log(1e-8)))
    return bounds


def fit_variances(nll: Callable[[NDArray], float], fixed: tuple[float | None, float | None],
                   penalty=None, start: NDArray | None = None) -> tuple[NDArray, float]:
    """REML (plus an optional penalty of theta) of log a and the logs of the free ones of
    (q, s2) (None in ``fixed``), the negative restricted likelihood ``nll`` of theta given.

    From ``start`` (a nearby optimum: the previous tau candidate's) or else the best point
    of a coarse grid over the bounds, a bounded quasi-Newton search (L-BFGS-B) on the
    log-parameters with forward-difference gradients (step :data:`_FD_STEP_LOG`); it stops
    when the projected gradient is under 1e-3 or a step lowers the objective by under 1e-8
    of its value, and holds at its bound a variance the data drive to zero. Returns (theta,
    objective at theta).
    """
    bounds = variance_bounds(fixed)

    def obj(th: NDArray) -> float:
        v = nll(th)
        return v if penalty is None else v + penalty(th)

    if start is None:
        start, _ = grid_argmin(obj, bounds, 9 if len(bounds) == 1 else 6)
    opt = optimize.minimize(obj, np.asarray(start, dtype=float), method="L-BFGS-B",
                            bounds=bounds, options={"ftol": 1e-8, "gtol": 1e-3,
                                                    "maxiter": 100, "eps": _FD_STEP_LOG})
    return np.clip(opt.x, [b[0] for b in bounds], [b[1] for b in bounds]), float(opt.fun)
