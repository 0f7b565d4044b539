"""Compiled Rauch-Tung-Striebel smoother of a scalar bias deviation on a uniform time grid.

The process is the sum of two independent first-order Gauss-Markov components (the drift and
the low-passed white rate noise of :mod:`pospp.calib.bias_smoother`), each column of the
measurements smoothed on its own::

    x_k = diag(f) x_k-1 + n_k,   n_k ~ N(0, diag(s2 (1 - f^2))),   x_0 ~ N(0, diag(s2))
    z_k = x_k[0] + x_k[1] + e_k,  e_k ~ N(0, r_k)     (r_k = inf: no measurement in cell k)

with f = exp(-dt / tau) per component. In numpy the few dozen scalar operations per step cost
their call overhead (about 0.5 s for a 1.5 h flight's 11 000 cells and 12 columns); compiled,
their arithmetic (milliseconds). The plain-numpy check is the Gaussian conditional mean of the
same model written out densely (tests/unit/test_bias_smoother.py).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def smooth_two_gm(z: NDArray, r: NDArray, f: NDArray, s2: NDArray) -> NDArray:
    """Smoothed x[0] + x[1] per cell and column, shape (N, M).

    Parameters
    ----------
    z, r : ndarray, shape (N, M)
        Measurement and its variance per grid cell and column (``r`` inf: none).
    f : ndarray, shape (2,)
        One-step decay of each component.
    s2 : ndarray, shape (2,)
        Steady-state variance of each component.
    """
    n, m = z.shape
    out = np.zeros((n, m))
    q0, q1 = s2[0] * (1.0 - f[0] * f[0]), s2[1] * (1.0 - f[1] * f[1])
    # filtered mean (2) and covariance (3: p00, p01, p11) per cell; predicted likewise
    xf = np.zeros((n, 2))
    pf = np.zeros((n, 3))
    xp = np.zeros((n, 2))
    pp = np.zeros((n, 3))
    for c in range(m):
        x0, x1 = 0.0, 0.0
        p00, p01, p11 = s2[0], 0.0, s2[1]
        for k in range(n):
            if k > 0:
                x0, x1 = f[0] * x0, f[1] * x1
                p00 = f[0] * f[0] * p00 + q0
                p01 = f[0] * f[1] * p01
                p11 = f[1] * f[1] * p11 + q1
            xp[k, 0], xp[k, 1] = x0, x1
            pp[k, 0], pp[k, 1], pp[k, 2] = p00, p01, p11
            rk = r[k, c]
            if np.isfinite(rk):
                h0, h1 = p00 + p01, p01 + p11  # P H^T
                s = h0 + h1 + rk
                nu = z[k, c] - x0 - x1
                x0 += h0 / s * nu
                x1 += h1 / s * nu
                p00 -= h0 * h0 / s
                p01 -= h0 * h1 / s
                p11 -= h1 * h1 / s
            xf[k, 0], xf[k, 1] = x0, x1
            pf[k, 0], pf[k, 1], pf[k, 2] = p00, p01, p11
        s0, s1 = xf[n - 1, 0], xf[n - 1, 1]
        out[n - 1, c] = s0 + s1
        for k in range(n - 2, -1, -1):
            # G = Pf F^T Pp^-1 (2 x 2), Pp of cell k + 1
            a, b, d = pp[k + 1, 0], pp[k + 1, 1], pp[k + 1, 2]
            det = a * d - b * b
            i00, i01, i11 = d / det, -b / det, a / det
            m00, m01 = pf[k, 0] * f[0], pf[k, 1] * f[1]
            m10, m11 = pf[k, 1] * f[0], pf[k, 2] * f[1]
            g00, g01 = m00 * i00 + m01 * i01, m00 * i01 + m01 * i11
            g10, g11 = m10 * i00 + m11 * i01, m10 * i01 + m11 * i11
            d0, d1 = s0 - xp[k + 1, 0], s1 - xp[k + 1, 1]
            s0 = xf[k, 0] + g00 * d0 + g01 * d1
            s1 = xf[k, 1] + g10 * d0 + g11 * d1
            out[k, c] = s0 + s1
    return out
