"""The few distribution functions a run needs, from :mod:`scipy.special`.

Each is the function :mod:`scipy.stats` evaluates for it (scipy 1.17's ``chi2._ppf``,
``chi2._isf``, ``f._sf``, ``t._sf``; the Poisson upper quantile by the same definition as
``poisson.isf``), so the values are the same; tests/unit/test_distributions.py checks them
against scipy.stats on grids. Why not scipy.stats itself: importing it costs every run
0.3 s and 45 MiB of resident memory (``python -X importtime -c "import pospp.pipeline"``;
docs/history/speed_rounds.md, "Speed and memory, sixth round"), for five scalar functions.
"""

from __future__ import annotations

import math

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
