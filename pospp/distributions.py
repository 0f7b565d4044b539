"""The few distribution functions a run needs, from :mod:`scipy.special`.

Each is the function :mod:`scipy.stats` evaluates for it (scipy 1.17's ``chi2._ppf``,
``chi2._isf``, ``f._sf``, ``t._sf``; the Poisson upper quantile by the same definition as
``poisson.isf``), so the values are the same; tests/unit/test_distributions.py checks them
against scipy.stats on grids. Not scipy.stats itself: its import costs every run 0.3 s and
45 MiB for five scalar functions (docs/history/speed_rounds.md, "Speed and memory, sixth round").

And the long-run variance ratio of a correlated series (:func:`long_run_ratio`), which widens
the sigmas of estimates fitted on time-correlated residuals.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy import special


def chi2_ppf(p: float, dof: float) -> float:
    """Chi-square quantile: x with P(X <= x) = p, X ~ chi2(dof) (``2 P^-1(dof / 2, p)``,
    P the regularised lower incomplete gamma function)."""
    return float(2.0 * special.gammaincinv(dof / 2.0, p))


def chi2_isf(q: float, dof: float) -> float:
    """Chi-square upper quantile: x with P(X > x) = q."""
    return float(special.chdtri(dof, q))


def f_sf(x: float, dof1: float, dof2: float) -> float:
    """F distribution's upper tail P(X > x), X ~ F(dof1, dof2)."""
    return float(special.fdtrc(dof1, dof2, x))


def t_sf(x: float, dof: float) -> float:
    """Student t's upper tail P(X > x), X ~ t(dof)."""
    return float(special.stdtr(dof, -x))


def poisson_isf(q: float, mu: float) -> float:
    """Poisson upper quantile: the smallest integer k >= 0 with P(X > k) <= q, X ~
    Poisson(mu > 0) (``scipy.stats.poisson.isf``); from the inverse of the CDF in the rate
    and a check of its neighbours with the survival function ``pdtrc``."""
    if not 0.0 < q < 1.0 or not mu > 0.0:
        raise ValueError(f"poisson_isf: expected 0 < q < 1 and mu > 0, got q={q!r}, mu={mu!r}")
    k = max(math.ceil(float(special.pdtrik(1.0 - q, mu))) - 1, 0)
    while special.pdtrc(k, mu) > q:
        k += 1
    while k > 0 and special.pdtrc(k - 1, mu) <= q:
        k -= 1
    return float(k)


def long_run_ratio(residual: NDArray, record_t_s: NDArray, window_s: float, *,
                   gauss_markov: bool = False) -> float:
    """The long-run variance of the whitened residual over its variance, the largest over the
    three components of a record (Bartlett weights over lags up to ``window_s`` of records;
    1 for white noise, at least 1 returned; ``residual`` (M, 3), ``record_t_s`` (M,) [s]).

    For a least-squares estimate b = (X^T X)^-1 X^T e, Var b = (X^T X)^-1 X^T Cov(e) X
    (X^T X)^-1 is the white-noise formula times this ratio, 1 + 2 sum_k w_k rho(k) (rho the
    residual's autocorrelation, w_k = 1 - k / (L + 1), L the window in records), where the
    regressors stay constant over the window (a heteroskedasticity-and-autocorrelation-
    consistent, Newey-West, correction; for a regressor constant over blocks of L records the
    Bartlett weights are exact: the variance of a block's sum). So it is the factor by which an
    F-test is too liberal, and the square of the factor by which a sigma is too small. The
    window is the regressors' scale: the sensor families' knot spacing (their hinges vary over
    it), the turns of the lever arm and GNSS time offset's joint estimate
    (:mod:`pospp.qc.lever_time`).

    ``gauss_markov``: rho(k) is the fitted Gauss-Markov + white noise model's, c phi^k
    (:func:`gauss_markov_phi`; c from the first lags), not the sample's: the sample's
    autocorrelations at lags near the window scatter, and the residual of a fit has lost its
    share along the regressors (the z of a slope on 120 s legs over Gauss-Markov noise of phi
    0.8-0.97 spread 0.95-1.04 with the model's, 1.14-1.17 with the sample's at phi 0.8-0.9;
    tests/unit/test_distributions.py).
    """
    r = np.asarray(residual, dtype=float).reshape(-1, 3)
    t = np.asarray(record_t_s, dtype=float)
    rate = (t.size - 1) / max(float(t[-1] - t[0]), 1e-9) if t.size > 1 else 1.0
    lags = int(min(max(1, round(window_s * rate)), r.shape[0] // 4))
    weights = 1.0 - np.arange(1, lags + 1) / (lags + 1)
    worst = 1.0
    for c in range(3):
        x = r[:, c] - r[:, c].mean()
        g0 = float(x @ x)
        if not g0 > 0:
            continue
        rho = _gauss_markov_rho(x, lags) if gauss_markov else _autocorrelation(x, lags)
        worst = max(worst, 1.0 + 2.0 * float(weights @ rho))
    return worst


PREWHITEN_MAX_PHI = 0.99
"""The largest AR coefficient :func:`gauss_markov_phi` returns (a correlation time of 100
records)."""
PREWHITEN_LAGS = 5
"""Lags of the autocorrelation :func:`gauss_markov_phi` fits phi on."""


def gauss_markov_phi(x: NDArray) -> float:
    """The AR coefficient of a Gauss-Markov error under white noise fitted to the series ``x``
    (mean removed): its autocorrelation is rho(k) = c phi^k for k >= 1 (c the Gauss-Markov
    share of the variance), so phi = sum_(k=2..K+1) rho(k) / sum_(k=1..K) rho(k) with
    K = :data:`PREWHITEN_LAGS`; 0 when rho(1) is within 2 / sqrt(M) of 0 or the sums are not
    positive (white noise), at most :data:`PREWHITEN_MAX_PHI`."""
    x = np.asarray(x, dtype=float)
    if x.size < 4 * (PREWHITEN_LAGS + 2) or not float(x @ x) > 0:
        return 0.0
    return _phi(_autocorrelation(x, PREWHITEN_LAGS + 1), x.size)


def _autocorrelation(x: NDArray, lags: int) -> NDArray:
    """The sample autocorrelation rho(1..lags) of the zero-mean series ``x`` (its sum of
    squares > 0): sum_t x_t x_(t+k) / sum_t x_t^2."""
    return np.array([float(x[k:] @ x[:-k]) for k in range(1, lags + 1)]) / float(x @ x)


def _phi(rho: NDArray, n: int) -> float:
    """:func:`gauss_markov_phi` from the first ``PREWHITEN_LAGS + 1`` autocorrelations of
    ``n`` samples."""
    low, high = float(rho[:-1].sum()), float(rho[1:].sum())
    if not (rho[0] > 2.0 / np.sqrt(n) and low > 0.0 and high > 0.0):
        return 0.0
    return min(high / low, PREWHITEN_MAX_PHI)


def _gauss_markov_rho(x: NDArray, lags: int) -> NDArray:
    """rho(1..lags) of the Gauss-Markov + white model fitted to ``x`` (zero mean, its sum of
    squares > 0): c phi^k, c = sum_(k<=K) rho(k) / sum_(k<=K) phi^k over the sample's first
    K lags; 0 for white."""
    if x.size < 4 * (PREWHITEN_LAGS + 2):
        return np.zeros(lags)
    rho = _autocorrelation(x, PREWHITEN_LAGS + 1)
    phi = _phi(rho, x.size)
    if not phi > 0.0:
        return np.zeros(lags)
    k = np.arange(1, PREWHITEN_LAGS + 1)
    c = float(rho[:PREWHITEN_LAGS].sum() / np.sum(phi ** k))
    return c * phi ** np.arange(1, lags + 1)
