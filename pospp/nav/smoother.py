"""Rauch-Tung-Striebel smoother for the closed-loop error-state filter (algorithm A).

Error state (15 or 18, computed minus true; :mod:`pospp.nav.error_model`)::

    dx = [phi_n (3) rad, dv_n (3) m/s, dr_n (3) m, db_g (3) rad/s, db_a (3) m/s^2, dl_b (3) m]

db_g, db_a are the residual sensor errors left after the filter's bias estimates are removed
(measured - estimate - true), dl_b = lever estimate - true lever.

Closed-loop RTS in error-state form (Rauch, Tung & Striebel 1965; e.g. Groves 2013, Sec. 3.4.2)
---------------------------------------------------------------------------------------------
The forward filter stores, at each smoother node k (every GNSS update epoch and at least every
``node_interval``): the predicted and updated covariances P_k|k-1, P_k|k, the transition matrix
Phi_k from node k-1 to node k, and the correction dx_k it fed back into the nominal state at k
(zero when no update). With feedback the filtered error after the reset is 0, so the error of
the nominal state just before the update is the error after it plus the correction::

    e_k^- = e_k^+ + dx_k
    A_k   = P_k|k Phi_{k+1}^T P_{k+1|k}^-1
    e_k^+ = A_k e_{k+1}^-                 (e_N^+ = 0)
    P^s_k = P_k|k + A_k (P^s_{k+1} - P_{k+1|k}) A_k^T

The smoothed state at node k is the filtered nominal (after feedback) corrected by e_k^+.
Between nodes (at most ``node_interval`` apart, 1 s by default) the error is interpolated
linearly from e_k^+ (just after node k) to e_{k+1}^- (just before node k+1); over one second
the error dynamics are linear to well below the noise (Phi = I + F dt). Smoothed covariances are
interpolated the same way (an approximation documented in docs/method.md).

Memory: per node the two covariances packed (their upper triangles, n (n + 1) / 2 numbers
each: :func:`pack_symmetric`; A's P is exactly symmetric wherever a node stores it, so the
packing is exact: 35 MiB less on a 1.5 h flight's nodes) and Phi compact, its 9 rows of the
navigation errors and its diagonal ((9 + 1) n numbers, :func:`unpack_transition_into`: the
rows of the bias, scale-factor and lever-arm errors, whose F rows hold their own decay
alone, are diagonal in every product of their steps, so the form is exact: 19 MiB less);
never per IMU epoch.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pospp.nav._kernels import X_POS, X_QUAT, X_VEL, quat_from_rotvec, quat_mul, radii
from pospp.nav.error_model import I_DR, I_DV, I_PHI


def packed_size(n: int) -> int:
    """Numbers in a packed symmetric n x n matrix: its upper triangle, n (n + 1) / 2."""
    return n * (n + 1) // 2


@njit(cache=True, nogil=True)
def pack_symmetric_into(p, out):
    """The upper triangle of the symmetric n x n ``p``, row by row, into ``out``
    (n (n + 1) / 2,): the smoother nodes' covariance layout."""
    j = 0
    for a in range(p.shape[0]):
        for b in range(a, p.shape[0]):
            out[j] = p[a, b]
            j += 1


@njit(cache=True, nogil=True)
def unpack_symmetric_into(packed, p):
    """The n x n symmetric ``p`` from its packed upper triangle (:func:`pack_symmetric_into`)."""
    j = 0
    for a in range(p.shape[0]):
        for b in range(a, p.shape[0]):
            p[a, b] = packed[j]
            p[b, a] = packed[j]
            j += 1


def packed_index(n: int) -> NDArray:
    """(n, n) int: where element (a, b) of a symmetric n x n matrix sits in its packed form
    (``packed[..., packed_index(n)[s, s]]`` is a diagonal block)."""
    idx = np.empty((n, n), dtype=np.int64)
    rows, cols = np.triu_indices(n)
    idx[rows, cols] = np.arange(rows.size)
    idx[cols, rows] = idx[rows, cols]
    return idx


def pack_symmetric(p: NDArray) -> NDArray:
    """(K, n, n) -> (K, n (n + 1) / 2): the upper triangles (:func:`pack_symmetric_into`)."""
    rows, cols = np.triu_indices(p.shape[-1])
    return np.ascontiguousarray(p[..., rows, cols], dtype=float)


def unpack_symmetric(packed: NDArray, n: int) -> NDArray:
    """(K, n (n + 1) / 2) -> (K, n, n): the symmetric matrices (:func:`unpack_symmetric_into`)."""
    return packed[..., packed_index(n)]


@njit(cache=True, nogil=True)
def unpack_transition_into(compact, phi):
    """The n x n transition matrix ``phi`` from its compact form ``compact`` ((m + 1, n)):
    rows 0 .. m - 1 are Phi's first m rows, row m its diagonal, from which its other rows
    are read (diagonal: the states after the m navigation errors are biases, scale factors
    and lever arms, whose error dynamics are their own decay alone)."""
    m, n = compact.shape[0] - 1, compact.shape[1]
    for a in range(n):
        for b in range(n):
            phi[a, b] = compact[a, b] if a < m else (compact[m, a] if a == b else 0.0)


def compact_transition(phi: NDArray, m: int) -> NDArray:
    """(K, n, n) -> (K, m + 1, n): the compact form :func:`unpack_transition_into` reads;
    ValueError when a row at or after m is not diagonal."""
    k, n = phi.shape[0], phi.shape[-1]
    lower = phi[:, m:, :].copy()
    diag = np.einsum("kii->ki", phi)
    lower[:, np.arange(n - m), np.arange(m, n)] = 0.0
    if np.any(lower != 0.0):
        raise ValueError(f"phi: rows {m} and after are not diagonal")
    out = np.empty((k, m + 1, n))
    out[:, :m], out[:, m] = phi[:, :m], diag
    return out


@njit(cache=True, nogil=True)
def rts_backward(p_pred, p_upd, phi, dx, e_plus, e_minus, p_smooth):
    """Backward RTS pass over ``K`` nodes (see the module docstring).

    Parameters
    ----------
    p_pred, p_upd : float64[K, n (n + 1) / 2]
        Predicted and updated covariances, packed (:func:`pack_symmetric_into`).
    phi : float64[K, m + 1, n]
        Phi[k] = transition from node k-1 to node k, compact (:func:`unpack_transition_into`:
        its first m rows and its diagonal).
    dx : float64[K, n]
        Corrections fed back at each node.
    e_plus, e_minus : float64[K, n]
        Output: smoothed error just after / just before the feedback at each node.
    p_smooth : float64[K, n (n + 1) / 2]
        Output: smoothed covariance, packed (may be ``p_upd``: node k's updated covariance is
        last read before node k's smoothed one is written).
    """
    k_last = p_pred.shape[0] - 1
    n = phi.shape[2]
    pp, pu, ps_next, ph = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    e_plus[k_last, :] = 0.0
    e_minus[k_last, :] = dx[k_last]
    p_smooth[k_last] = p_upd[k_last]
    unpack_symmetric_into(p_smooth[k_last], ps_next)
    for k in range(k_last - 1, -1, -1):
        unpack_symmetric_into(p_upd[k], pu)
        unpack_symmetric_into(p_pred[k + 1], pp)
        unpack_transition_into(phi[k + 1], ph)
        b = np.dot(ph, pu)
        a_t = np.linalg.solve(pp, b)  # = P_{k+1|k}^-1 Phi P_k|k = A^T
        a = np.ascontiguousarray(a_t.T)
        e_plus[k] = np.dot(a, e_minus[k + 1])
        for i in range(e_plus.shape[1]):
            e_minus[k, i] = e_plus[k, i] + dx[k, i]
        d = ps_next - pp
        ps = pu + np.dot(np.dot(a, d), a_t)
        ps_next = 0.5 * (ps + ps.T)
        pack_symmetric_into(ps_next, p_smooth[k])


@njit(cache=True, nogil=True)
def rts_backward_states(p_pred, p_upd, phi, dx, e_plus, e_minus):
    """The backward pass's errors alone (:func:`rts_backward` without P^s): per node one
    solve with a vector, ``e_k^+ = P_k|k Phi_{k+1}^T (P_{k+1|k}^-1 e_{k+1}^-)`` (the same
    A_k e_{k+1}^-, associated the other way). Arguments as :func:`rts_backward`."""
    k_last = p_pred.shape[0] - 1
    n = phi.shape[2]
    pp, pu, ph = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    e_plus[k_last, :] = 0.0
    e_minus[k_last, :] = dx[k_last]
    for k in range(k_last - 1, -1, -1):
        unpack_symmetric_into(p_pred[k + 1], pp)
        unpack_symmetric_into(p_upd[k], pu)
        unpack_transition_into(phi[k + 1], ph)
        y = np.linalg.solve(pp, e_minus[k + 1])
        e_plus[k] = np.dot(pu, np.dot(ph.T, y))
        for i in range(e_plus.shape[1]):
            e_minus[k, i] = e_plus[k, i] + dx[k, i]


@njit(cache=True, nogil=True)
def smoother_gains(p_pred, p_upd, phi):
    """The backward pass's gains ``A_k = P_k|k Phi_{k+1}^T P_{k+1|k}^-1`` (K, n, n), row K - 1
    zero: what a replay of the same schedule (:func:`rts_backward_gains`) applies to its own
    errors. Arguments as :func:`rts_backward` (the covariances packed)."""
    k_n, n = p_pred.shape[0], phi.shape[2]
    pp, pu, ph = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    a = np.zeros((k_n, n, n))
    for k in range(k_n - 1):
        unpack_symmetric_into(p_upd[k], pu)
        unpack_symmetric_into(p_pred[k + 1], pp)
        unpack_transition_into(phi[k + 1], ph)
        b = np.dot(ph, pu)
        a[k] = np.linalg.solve(pp, b).T  # (P^-1 Phi P_k|k)^T, as rts_backward
    return a


@njit(cache=True, nogil=True)
def rts_backward_gains(a_own, a, dx, e_plus, e_minus):
    """:func:`rts_backward_states` with given gains: ``e_k^+ = A_k e_{k+1}^-``, ``e_k^- =
    e_k^+ + dx_k``, A_k from ``a_own`` (the pass's own) for its nodes k < len(a_own), from
    ``a`` (K, n, n; :func:`smoother_gains` of another pass on the same schedule) after."""
    k_last = a.shape[0] - 1
    n_own = a_own.shape[0]
    e_plus[k_last, :] = 0.0
    e_minus[k_last, :] = dx[k_last]
    for k in range(k_last - 1, -1, -1):
        e_plus[k] = np.dot(a_own[k] if k < n_own else a[k], e_minus[k + 1])
        for i in range(e_plus.shape[1]):
            e_minus[k, i] = e_plus[k, i] + dx[k, i]


def rts_smooth(
    p_pred: NDArray, p_upd: NDArray, phi: NDArray, dx: NDArray, *,
    overwrite_p_upd: bool = False, covariance: bool = True,
) -> tuple[NDArray, NDArray, NDArray]:
    """Run the backward pass; returns (e_plus, e_minus, p_smooth), shapes (K, n), (K, n),
    (K, n (n + 1) / 2): ``p_pred``, ``p_upd`` and ``p_smooth`` packed (:func:`pack_symmetric`),
    ``phi`` (K, m + 1, n) compact (:func:`unpack_transition_into`).

    ``overwrite_p_upd``: the smoothed covariances are written over ``p_upd`` (C-contiguous
    float64) and it is returned as p_smooth: node k's updated covariance is last read by step
    k, which then writes node k's smoothed one (the same values, one array of the nodes'
    covariances fewer: 19 MiB on a 1.5 h flight). ``covariance`` False: the errors
    alone (:func:`rts_backward_states`; A's re-runs, ``FilterOptions.covariance_outputs``
    False), p_smooth with no rows.
    """
    k, n = dx.shape
    _check_nodes(k, n, p_pred, p_upd, phi)
    e_plus = np.zeros((k, n))
    e_minus = np.zeros((k, n))
    p_upd = np.ascontiguousarray(p_upd, dtype=float)
    if not covariance:
        if k:
            rts_backward_states(np.ascontiguousarray(p_pred), p_upd, np.ascontiguousarray(phi),
                                np.ascontiguousarray(dx), e_plus, e_minus)
        return e_plus, e_minus, np.empty((0, packed_size(n)))
    p_smooth = p_upd if overwrite_p_upd else np.empty((k, packed_size(n)))
    if k:
        rts_backward(
            np.ascontiguousarray(p_pred), p_upd, np.ascontiguousarray(phi),
            np.ascontiguousarray(dx), e_plus, e_minus, p_smooth,
        )
    return e_plus, e_minus, p_smooth


def rts_smooth_replayed(gains: NDArray, p_pred: NDArray, p_upd: NDArray, phi: NDArray,
                        dx: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`rts_smooth` (errors alone) of a pass that replayed another's gains
    (``pospp.nav.filter_state.GainReplay``): its own gains (:func:`smoother_gains`) over the
    nodes whose P it kept (``p_pred`` etc. hold the first of them: those before the replay
    started; packed), ``gains`` (K, n, n) after. Returns (e_plus, e_minus, p_smooth with no
    rows).
    """
    k, n = dx.shape
    _check_nodes(p_pred.shape[0], n, p_pred, p_upd, phi)
    if gains.shape != (k, n, n):
        raise ValueError(f"gains: expected shape ({k}, {n}, {n}) (the replayed pass's nodes), "
                         f"got {gains.shape}")
    n_own = p_pred.shape[0]
    # its own A_k where it has the nodes' P (not node n_own - 1: A_k needs P at k + 1); the
    # replayed ones are read in place, not copied
    own = (smoother_gains(p_pred, p_upd, phi)[:n_own - 1] if n_own > 1
           else np.zeros((0, n, n)))
    e_plus, e_minus = np.zeros((k, n)), np.zeros((k, n))
    if k:
        rts_backward_gains(own, np.ascontiguousarray(gains), np.ascontiguousarray(dx), e_plus,
                           e_minus)
    return e_plus, e_minus, np.empty((0, packed_size(n)))


def _check_nodes(k: int, n: int, p_pred: NDArray, p_upd: NDArray, phi: NDArray) -> None:
    """ValueError unless the nodes' covariances are (k, n (n + 1) / 2) (packed) and Phi
    compact (k, m + 1, n) with 1 <= m <= n (:func:`unpack_transition_into`)."""
    m = phi.shape[1] - 1 if phi.ndim == 3 else -1
    for name, arr, shape in (("p_pred", p_pred, (k, packed_size(n))),
                             ("p_upd", p_upd, (k, packed_size(n))),
                             ("phi", phi, (k, min(max(m, 1), n) + 1, n))):
        if arr.shape != shape:
            raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")


def interpolation_weights(node_t_s: NDArray, t_s: NDArray) -> tuple[NDArray, NDArray]:
    """Node index i (last node at or before t) and weight alpha in [0, 1) towards node i + 1."""
    i = np.clip(np.searchsorted(node_t_s, t_s, side="right") - 1, 0, node_t_s.shape[0] - 1)
    nxt = np.minimum(i + 1, node_t_s.shape[0] - 1)
    span = node_t_s[nxt] - node_t_s[i]
    alpha = np.where(span > 0.0, (t_s - node_t_s[i]) / np.where(span > 0.0, span, 1.0), 0.0)
    return i, np.clip(alpha, 0.0, 1.0)


def interpolate_errors(
    node_t_s: NDArray, e_plus: NDArray, e_minus: NDArray, t_s: NDArray
) -> NDArray:
    """Smoothed error state at times ``t_s``: linear from e_i^+ to e_{i+1}^- (module docstring)."""
    i, a = interpolation_weights(node_t_s, t_s)
    nxt = np.minimum(i + 1, node_t_s.shape[0] - 1)
    return (1.0 - a)[:, None] * e_plus[i] + a[:, None] * e_minus[nxt]


def interpolate_covariance_blocks(
    node_t_s: NDArray, p_smooth: NDArray, t_s: NDArray, blocks: tuple[slice, ...], n: int
) -> tuple[NDArray, list[NDArray]]:
    """Diagonal (N, n) and the requested diagonal blocks of P^s (``p_smooth`` packed, (K, n (n +
    1) / 2), :func:`pack_symmetric`) interpolated to t_s, each block packed likewise (N, b (b
    + 1) / 2)."""
    i, a = interpolation_weights(node_t_s, t_s)
    nxt = np.minimum(i + 1, node_t_s.shape[0] - 1)
    idx = packed_index(n)
    diag_nodes = p_smooth[:, np.diagonal(idx)]
    diag = (1.0 - a)[:, None] * diag_nodes[i] + a[:, None] * diag_nodes[nxt]
    out = []
    for s in blocks:
        blk = p_smooth[:, idx[s, s][np.triu_indices(s.stop - s.start)]]
        out.append((1.0 - a)[:, None] * blk[i] + a[:, None] * blk[nxt])
    return diag, out


@njit(cache=True, nogil=True)
def apply_correction(x, dx):
    """Remove an estimated error ``dx`` (computed minus true) from a kernel state ``x`` in place.

    lat -= dr_N / (R_M + h), lon -= dr_E / ((R_N + h) cos lat), h += dr_D, v -= dv_n and
    q_nb <- exp(phi) * q_nb, since C_nb,true = (I + [phi x]) C_nb,computed.
    """
    lat, h = x[X_POS], x[X_POS + 2]
    r_m, r_n = radii(lat)
    x[X_POS] = lat - dx[I_DR] / (r_m + h)
    x[X_POS + 1] = x[X_POS + 1] - dx[I_DR + 1] / ((r_n + h) * math.cos(lat))
    x[X_POS + 2] = h + dx[I_DR + 2]
    for i in range(3):
        x[X_VEL + i] -= dx[I_DV + i]
    qe = quat_from_rotvec(dx[I_PHI], dx[I_PHI + 1], dx[I_PHI + 2])
    q = quat_mul(qe[0], qe[1], qe[2], qe[3], x[X_QUAT], x[X_QUAT + 1], x[X_QUAT + 2],
                 x[X_QUAT + 3])
    nrm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0.0:
        nrm = -nrm
    for i in range(4):
        x[X_QUAT + i] = q[i] / nrm


@njit(cache=True, nogil=True)
def correct_states(states, errors):
    """Apply :func:`apply_correction` row by row to (N, 10) states with (N, n) errors."""
    out = states.copy()
    for k in range(states.shape[0]):
        apply_correction(out[k], errors[k])
    return out
