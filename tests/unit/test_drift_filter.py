"""The drift's Kalman filter over the legs (pospp.calib.reml.DriftLegs) against the covariance
written out from its definition.

``C = a I + q blockdiag(K_L) + s2 S (E x I_3) S^T`` with E_jk = exp(-|t_j - t_k| / tau) over
every drift bin of every leg, built here with numpy from random legs; the filter must whiten
it (W C W^T = I with W read off by filtering the identity) and give the restricted likelihood
``0.5 (log det C + log det H^T C^-1 H + r^T C^-1 r)`` computed by dense solves.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from pospp.calib.reml import DriftLegs

P_COLS = 4


def _legs(rng, n_legs=4, gap_s=40.0):
    """Random legs: rows n_L, bins J_L (one leg with a single bin, one with trailing bins no
    row sees), K_L positive semi-definite, S_L in the operator's layout (bin-major,
    axis-minor), bin times increasing within and across legs."""
    out, t0 = [], 100.0
    for i in range(n_legs):
        n = int(rng.integers(6, 14))
        j = 1 if i == 1 else int(rng.integers(3, 9))
        a = rng.standard_normal((n, n))
        k = a @ a.T / n
        s = rng.standard_normal((n, j, 3))
        t = t0 + 5.0 * np.arange(j) + rng.uniform(0.0, 2.0)
        if i == 2:  # two trailing bins no row sees, with a time out of order (an empty bin)
            s = np.concatenate([s, np.zeros((n, 2, 3))], axis=1)
            t = np.concatenate([t, [t[-1] + 5.0, t0 - 50.0]])
        out.append((rng.standard_normal((n, P_COLS + 1)), k, (s.reshape(n, -1), t)))
        t0 = float(t[:j].max()) + gap_s
    return out


def _dense_covariance(legs, a, q, s2, tau_s):
    k = linalg.block_diag(*[leg[1] for leg in legs])
    s = linalg.block_diag(*[leg[2][0] for leg in legs])  # (n, 3 J): bin-major, axis-minor
    t = np.concatenate([leg[2][1] for leg in legs])
    e = np.kron(np.exp(-np.abs(t[:, None] - t[None, :]) / tau_s), np.eye(3))
    return a * np.eye(k.shape[0]) + q * k + s2 * s @ e @ s.T


def _dense_reml(hz, c):
    h, z = hz[:, :-1], hz[:, -1]
    ci_h, ci_z = np.linalg.solve(c, h), np.linalg.solve(c, z)
    info = h.T @ ci_h
    x = np.linalg.solve(info, h.T @ ci_z)
    r = z - h @ x
    return 0.5 * (np.linalg.slogdet(c)[1] + np.linalg.slogdet(info)[1]
                  + r @ np.linalg.solve(c, r))


@pytest.mark.parametrize("tau_s", [30.0, 300.0, 3e4])
def test_filter_whitens_the_full_covariance(tau_s):
    rng = np.random.default_rng(3)
    legs = _legs(rng)
    a, q, s2 = 0.3, 0.7, 2.0
    c = _dense_covariance(legs, a, q, s2, tau_s)
    n = c.shape[0]
    eye_legs = np.split(np.eye(n), np.cumsum([leg[0].shape[0] for leg in legs])[:-1])
    filt = DriftLegs.from_blocks(eye_legs, [leg[1] for leg in legs],
                                 [leg[2] for leg in legs])
    assert filt is not None
    w, logdet = filt.at_tau(tau_s).whiten(a, q, s2)
    assert np.abs(w @ c @ w.T - np.eye(n)).max() < 1e-9
    assert logdet == pytest.approx(np.linalg.slogdet(c)[1], rel=1e-10)
    assert np.allclose(np.triu(w, 1), 0.0)  # in time order: a lower-triangular whitening


@pytest.mark.parametrize("tau_s", [30.0, 300.0, 3e4])
def test_filter_likelihood_equals_dense_reml_in_any_leg_order(tau_s):
    rng = np.random.default_rng(5)
    legs = _legs(rng, n_legs=5)
    a, q, s2 = 0.2, 1.3, 0.8
    ref = _dense_reml(np.vstack([leg[0] for leg in legs]),
                      _dense_covariance(legs, a, q, s2, tau_s))
    for order in ([0, 1, 2, 3, 4], [3, 0, 4, 2, 1]):
        sel = [legs[i] for i in order]
        filt = DriftLegs.from_blocks([leg[0] for leg in sel], [leg[1] for leg in sel],
                                     [leg[2] for leg in sel])
        assert filt is not None
        assert filt.at_tau(tau_s).reml_nll(a, q, s2) == pytest.approx(ref, rel=1e-10)


def test_overlapping_legs_and_a_leg_without_drift_are_refused():
    rng = np.random.default_rng(7)
    legs = _legs(rng, n_legs=3)
    hz, k = [leg[0] for leg in legs], [leg[1] for leg in legs]
    ops = [leg[2] for leg in legs]
    s, t = ops[2]
    ops_overlap = ops[:2] + [(s, t - (t[0] - ops[1][1][0]) - 1.0)]  # starts inside leg 1
    assert DriftLegs.from_blocks(hz, k, ops_overlap) is None
    assert DriftLegs.from_blocks(hz, k, ops[:2] + [(np.zeros_like(s), t)]) is None


def test_not_positive_definite_gives_the_likelihood_its_barrier():
    rng = np.random.default_rng(11)
    legs = _legs(rng, n_legs=2)
    filt = DriftLegs.from_blocks([leg[0] for leg in legs], [leg[1] for leg in legs],
                                 [leg[2] for leg in legs])
    assert filt is not None
    f = filt.at_tau(100.0)
    assert f.whiten(-5.0, 0.0, 1e-9) is None
    assert f.reml_nll(-5.0, 0.0, 1e-9) == 1e30
