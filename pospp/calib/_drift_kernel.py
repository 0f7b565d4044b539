"""Compiled loop of the drift's Kalman filter over the legs (:class:`pospp.calib.reml.DriftLegs`).

One call per evaluation of the restricted likelihood: per leg a covariance of a few dozen rows
is formed, factored (Cholesky) and used to whiten the leg's [H z] rows, then the 3-state
drift is updated. In numpy the ~20 small operations per leg cost more in call overhead than in
arithmetic (0.95 ms an evaluation on the 1.5 h flight's 10 legs, against 1.16 ms for the dense
factor of all 356 rows); compiled, they cost their arithmetic. The equations are in
:class:`pospp.calib.reml.DriftLegs`; scaled units as there.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def _cholesky_in_place(v: NDArray, n: int) -> bool:
    """Lower Cholesky factor of v[:n, :n] in its lower triangle (row by row); False when the
    matrix is not positive definite."""
    for i in range(n):
        for j in range(i + 1):
            s = v[i, j]
            for k in range(j):
                s -= v[i, k] * v[j, k]
            if i == j:
                if not s > 0.0:
                    return False
                v[i, i] = np.sqrt(s)
            else:
                v[i, j] = s / v[j, j]
    return True


@njit(cache=True, nogil=True)
def drift_filter_whiten(a: float, q: float, s2: float, hz: NDArray, off: NDArray,
                        k_flat: NDArray, g_flat: NDArray, sq_off: NDArray, m: NDArray,
                        nn: NDArray, rho: NDArray, m_j: NDArray, out: NDArray) -> float:
    """W [H z] into ``out`` (same shape as ``hz``) with W C W^T = I; returns log det C, or
    inf when a leg's innovation covariance is not positive definite.

    Legs are the row ranges ``off[l]:off[l+1]`` of ``hz`` (n_tot, p + 1), ``m`` and ``nn``
    (n_tot, 3); their K and G_LL blocks are raveled in ``k_flat`` / ``g_flat`` from
    ``sq_off[l]``; ``rho`` and ``m_j`` (L,) as in :class:`pospp.calib.reml.DriftLegs`.
    """
    ncol = hz.shape[1]
    nmax = 0
    for li in range(off.size - 1):
        nmax = max(nmax, off[li + 1] - off[li])
    v = np.empty((nmax, nmax))
    rhs = np.empty((nmax, ncol + 3))
    mu = np.zeros((3, ncol))
    p = np.eye(3)
    ma = np.empty((nmax, 3))
    sd = np.sqrt(s2)
    logdet = 0.0
    for li in range(off.size - 1):
        r0 = off[li]
        n = off[li + 1] - r0
        rl = rho[li]
        # ma = M (I - P)
        for i in range(n):
            for c in range(3):
                s = m[r0 + i, c]
                for d in range(3):
                    s -= m[r0 + i, d] * p[d, c]
                ma[i, c] = s
        base = sq_off[li]
        r2 = rl * rl
        for i in range(n):
            for j in range(i + 1):
                low = ma[i, 0] * m[r0 + j, 0] + ma[i, 1] * m[r0 + j, 1] + ma[i, 2] * m[r0 + j, 2]
                v[i, j] = q * k_flat[base + i * n + j] + s2 * (g_flat[base + i * n + j] - r2 * low)
            v[i, i] += a
        if not _cholesky_in_place(v, n):
            return np.inf
        # right-hand sides: nu = [H z] - sd rho M mu, and C_ye = sd (N - rho^2 m_J M (I - P))
        cm = r2 * m_j[li]
        for i in range(n):
            for c in range(ncol):
                s = hz[r0 + i, c]
                for d in range(3):
                    s -= sd * rl * m[r0 + i, d] * mu[d, c]
                rhs[i, c] = s
            for c in range(3):
                rhs[i, ncol + c] = sd * (nn[r0 + i, c] - cm * ma[i, c])
        for i in range(n):  # forward substitution L w = rhs (row-major inner loops)
            for k in range(i):
                lik = v[i, k]
                for c in range(ncol + 3):
                    rhs[i, c] -= lik * rhs[k, c]
            lii = v[i, i]
            logdet += 2.0 * np.log(lii)
            for c in range(ncol + 3):
                rhs[i, c] /= lii
        gam = rl * m_j[li]
        g2 = gam * gam
        new_mu = gam * mu
        new_p = g2 * p
        for d in range(3):
            new_p[d, d] += 1.0 - g2
        for i in range(n):
            for d in range(3):
                cw = rhs[i, ncol + d]
                for c in range(ncol):
                    new_mu[d, c] += cw * rhs[i, c]
                for e in range(3):
                    new_p[d, e] -= cw * rhs[i, ncol + e]
        mu = new_mu
        p = new_p
        for i in range(n):
            for c in range(ncol):
                out[r0 + i, c] = rhs[i, c]
    return logdet
