"""RTS smoother of the closed-loop error-state filter against an independent batch solution.

For a linear Gaussian system the closed-loop filter's nominal state after each update is the
Kalman estimate, and the smoothed state (nominal minus the smoothed error e^+) must equal the
batch maximum-a-posteriori solution of the whole record (one big weighted least-squares
problem solved by numpy), with the posterior covariance equal to the smoothed covariance.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pospp.nav import smoother


def _system(seed, n=4, k=25, m=2):
    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, 0.3, (n, n))
    phi = np.eye(n) + 0.2 * (a - a.T) + 0.05 * a  # near-rotation, mildly unstable/stable
    lq = rng.normal(0.0, 0.1, (n, n))
    q = lq @ lq.T + 1e-3 * np.eye(n)
    h = rng.normal(0.0, 1.0, (m, n))
    r = np.diag(rng.uniform(0.05, 0.3, m))
    p0 = np.diag(rng.uniform(0.5, 2.0, n))
    m0 = rng.normal(0.0, 1.0, n)
    x = [m0 + np.linalg.cholesky(p0) @ rng.normal(size=n)]
    for _ in range(k - 1):
        x.append(phi @ x[-1] + np.linalg.cholesky(q) @ rng.normal(size=n))
    has_z = rng.uniform(size=k) < 0.7
    has_z[0] = True
    z = [h @ xi + np.linalg.cholesky(r) @ rng.normal(size=m) for xi in x]
    return dict(phi=phi, q=q, h=h, r=r, p0=p0, m0=m0, z=z, has_z=has_z, n=n, k=k)


def _closed_loop_forward(s):
    """Closed-loop filter in the pospp form: returns nominal states and the node arrays (the
    covariances symmetrised as A does, and packed as A stores them)."""
    n, k = s["n"], s["k"]
    p_pred = np.empty((k, n, n))
    p_upd = np.empty((k, n, n))
    phis = np.empty((k, n, n))
    dx = np.zeros((k, n))
    nominal = np.empty((k, n))
    x_hat, p = s["m0"].copy(), s["p0"].copy()
    for i in range(k):
        if i > 0:
            x_hat = s["phi"] @ x_hat  # nominal propagation; the error state stays zero
            p = s["phi"] @ p @ s["phi"].T + s["q"]
            p = 0.5 * (p + p.T)
        phis[i] = s["phi"] if i > 0 else np.eye(n)
        p_pred[i] = p
        if s["has_z"][i]:
            h, r = s["h"], s["r"]
            dz = h @ x_hat - s["z"][i]  # predicted minus measured
            kg = p @ h.T @ np.linalg.inv(h @ p @ h.T + r)
            dx[i] = kg @ dz
            x_hat = x_hat - dx[i]  # feedback; error state reset
            ikh = np.eye(n) - kg @ h
            p = ikh @ p @ ikh.T + kg @ r @ kg.T
            p = 0.5 * (p + p.T)
        p_upd[i] = p
        nominal[i] = x_hat
    return (nominal, smoother.pack_symmetric(p_pred), smoother.pack_symmetric(p_upd),
            smoother.compact_transition(phis, n),
            dx)


def _batch(s):
    """MAP estimate of all states and its covariance by whitened least squares."""
    n, k = s["n"], s["k"]
    rows, rhs = [], []

    def add(block_cols, mat_list, cov, y):
        w = np.linalg.inv(np.linalg.cholesky(cov))
        row = np.zeros((cov.shape[0], n * k))
        for col, mat in zip(block_cols, mat_list, strict=True):
            row[:, col * n:(col + 1) * n] = w @ mat
        rows.append(row)
        rhs.append(w @ y)

    add([0], [np.eye(n)], s["p0"], s["m0"])
    for i in range(1, k):
        add([i, i - 1], [np.eye(n), -s["phi"]], s["q"], np.zeros(n))
    for i in range(k):
        if s["has_z"][i]:
            add([i], [s["h"]], s["r"], s["z"][i])
    a = np.vstack(rows)
    b = np.concatenate(rhs)
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    cov = np.linalg.inv(a.T @ a)
    return x.reshape(k, n), cov


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_closed_loop_rts_equals_batch_map(seed):
    s = _system(seed)
    nominal, p_pred, p_upd, phis, dx = _closed_loop_forward(s)
    e_plus, e_minus, p_packed = smoother.rts_smooth(p_pred, p_upd, phis, dx)
    p_s = smoother.unpack_symmetric(p_packed, s["n"])
    x_batch, cov = _batch(s)
    np.testing.assert_allclose(nominal - e_plus, x_batch, atol=1e-9, rtol=0)
    np.testing.assert_allclose(e_minus - e_plus, dx, atol=1e-12)
    n = s["n"]
    for i in range(s["k"]):
        np.testing.assert_allclose(p_s[i], cov[i * n:(i + 1) * n, i * n:(i + 1) * n],
                                   atol=1e-9, rtol=1e-7)
    # the last node is the filtered one
    np.testing.assert_array_equal(e_plus[-1], 0.0)
    # written over the updated covariances (as A does): the same numbers, bit for bit
    p_upd_copy = np.array(p_upd, dtype=float)
    e2, _, p_s2 = smoother.rts_smooth(p_pred, p_upd_copy, phis, dx, overwrite_p_upd=True)
    assert p_s2 is p_upd_copy
    np.testing.assert_array_equal(p_s2, p_packed)
    np.testing.assert_array_equal(e2, e_plus)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_states_only_pass_equals_batch_map(seed):
    # the re-runs' smoother (no covariance): the same batch MAP errors, and rts_smooth's
    s = _system(seed)
    nominal, p_pred, p_upd, phis, dx = _closed_loop_forward(s)
    e_plus, e_minus, p_s = smoother.rts_smooth(p_pred, p_upd, phis, dx, covariance=False)
    assert p_s.shape == (0, smoother.packed_size(s["n"]))
    x_batch, _ = _batch(s)
    np.testing.assert_allclose(nominal - e_plus, x_batch, atol=1e-9, rtol=0)
    e_full, e_minus_full, _ = smoother.rts_smooth(p_pred, p_upd, phis, dx)
    np.testing.assert_allclose(e_plus, e_full, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(e_minus, e_minus_full, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("seed", [0, 1])
def test_replayed_gains_smooth_as_the_batch_map(seed):
    # a replay's smoother: its own gains over the nodes it kept, the given ones after; with
    # the pass's own gains throughout (any split) it is the batch MAP again
    s = _system(seed)
    nominal, p_pred, p_upd, phis, dx = _closed_loop_forward(s)
    gains = smoother.smoother_gains(p_pred, p_upd, phis)
    x_batch, _ = _batch(s)
    for n_own in (0, 1, 10, p_pred.shape[0]):
        e_plus, _, p_s = smoother.rts_smooth_replayed(gains, p_pred[:n_own], p_upd[:n_own],
                                                      phis[:n_own], dx)
        assert p_s.shape == (0, smoother.packed_size(s["n"]))
        np.testing.assert_allclose(nominal - e_plus, x_batch, atol=1e-9, rtol=0)
    # other gains after the split, its own before: the nodes before use its own
    bad = np.zeros_like(gains)
    e_split, _, _ = smoother.rts_smooth_replayed(bad, p_pred[:10], p_upd[:10], phis[:10], dx)
    assert not np.allclose(e_split, nominal - x_batch)
    with pytest.raises(ValueError, match="replayed pass's nodes"):
        smoother.rts_smooth_replayed(gains[1:], p_pred, p_upd, phis, dx)


@settings(max_examples=25, deadline=None)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_smoothed_covariance_below_filtered_and_symmetric(seed):
    s = _system(seed, n=5, k=15, m=2)
    _, p_pred, p_upd, phis, dx = _closed_loop_forward(s)
    _, _, p_s = smoother.rts_smooth(p_pred, p_upd, phis, dx)
    p_s = smoother.unpack_symmetric(p_s, s["n"])
    p_upd = smoother.unpack_symmetric(p_upd, s["n"])
    for i in range(s["k"]):
        np.testing.assert_allclose(p_s[i], p_s[i].T, atol=0)
        assert np.linalg.eigvalsh(p_s[i]).min() > 0.0
        assert np.linalg.eigvalsh(p_upd[i] - p_s[i]).min() > -1e-10


def test_interpolation_is_linear_between_after_and_before():
    node_t = np.array([0.0, 1.0, 3.0])
    e_plus = np.array([[0.0], [10.0], [0.0]])
    e_minus = np.array([[5.0], [2.0], [7.0]])
    got = smoother.interpolate_errors(node_t, e_plus, e_minus, np.array([0.0, 0.5, 1.0, 2.0,
                                                                         3.0, 4.0]))
    # from e+ at node i to e- at node i + 1; at a node: e+; after the last node: e+ (zero)
    np.testing.assert_allclose(got[:, 0], [0.0, 1.0, 10.0, 8.5, 0.0, 0.0])


def test_correction_round_trip():
    """apply_correction removes an error that was added with the pospp convention."""
    from pospp import rotation

    rng = np.random.default_rng(4)
    q_true = rotation.quat_from_euler([0.1, -0.2, 2.0])
    phi = rng.normal(0.0, 1e-3, 3)
    c_hat = rotation.dcm_from_rotvec(-phi) @ rotation.dcm_from_quat(q_true)  # (I - [phi x]) C
    x = np.concatenate([[0.7, 2.0, 100.0], [1.0, 2.0, 3.0], rotation.quat_from_dcm(c_hat)])
    dx = np.zeros(15)
    dx[:3] = phi
    dx[3:6] = [0.1, -0.2, 0.3]
    smoother.apply_correction(x, dx)
    np.testing.assert_allclose(x[3:6], [0.9, 2.2, 2.7])
    ang = rotation.angle_between_rad(rotation.dcm_from_quat(x[6:10]),
                                     rotation.dcm_from_quat(q_true))
    assert ang < 1e-12


def test_packed_covariances_round_trip_and_blocks():
    """A symmetric matrix packed (upper triangle, row by row) and unpacked is itself, bit for
    bit, in numpy and in the compiled kernels; packed_index picks its diagonal blocks."""
    rng = np.random.default_rng(5)
    a = rng.normal(size=(7, 6, 6))
    p = a @ a.transpose(0, 2, 1)
    p = 0.5 * (p + p.transpose(0, 2, 1))
    packed = smoother.pack_symmetric(p)
    assert packed.shape == (7, smoother.packed_size(6)) == (7, 21)
    np.testing.assert_array_equal(smoother.unpack_symmetric(packed, 6), p)
    out, back = np.empty(21), np.empty((6, 6))
    smoother.pack_symmetric_into(p[3], out)
    np.testing.assert_array_equal(out, packed[3])
    smoother.unpack_symmetric_into(out, back)
    np.testing.assert_array_equal(back, p[3])
    idx = smoother.packed_index(6)
    np.testing.assert_array_equal(packed[:, idx[2:5, 2:5]], p[:, 2:5, 2:5])
    np.testing.assert_array_equal(packed[:, np.diagonal(idx)], np.diagonal(p, axis1=1, axis2=2))


def test_packed_nodes_of_another_shape_are_refused():
    s = _system(0)
    _, p_pred, p_upd, phis, dx = _closed_loop_forward(s)
    with pytest.raises(ValueError, match="p_pred: expected shape"):
        smoother.rts_smooth(smoother.unpack_symmetric(p_pred, s["n"]), p_upd, phis, dx)


def test_replayed_gains_are_read_in_place():
    """A replayed pass reads the other pass's (K, n, n) gains where they are: what it
    allocates while smoothing is its errors ((K, n) twice) and its own gains over the nodes
    it kept, not a copy of the gains; and e_k^+ = A_k e_{k+1}^-, e_k^- = e_k^+ + dx_k, its
    own A_k (identity here: P = I, Phi = I) before its last kept node (a loop in numpy)."""
    rng = np.random.default_rng(3)
    k, n, n_own = 2000, 21, 5
    gains = rng.normal(0.0, 0.2, (k, n, n))
    dx = rng.normal(0.0, 1.0, (k, n))
    p_own = np.tile(smoother.pack_symmetric(np.eye(n)[None]), (n_own, 1))
    phi_own = smoother.compact_transition(np.tile(np.eye(n), (n_own, 1, 1)), n)
    args = (p_own, p_own.copy(), phi_own, dx)
    smoother.rts_smooth_replayed(gains[:n_own], p_own, p_own, phi_own, dx[:n_own])  # loaded
    tracemalloc.start()
    try:
        e_plus, e_minus, _ = smoother.rts_smooth_replayed(gains, *args)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < gains.nbytes / 4
    ep, em = np.zeros((k, n)), np.zeros((k, n))
    em[-1] = dx[-1]
    for j in range(k - 2, -1, -1):
        ep[j] = (np.eye(n) if j < n_own - 1 else gains[j]) @ em[j + 1]
        em[j] = ep[j] + dx[j]
    np.testing.assert_allclose(e_plus, ep, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(e_minus, em, rtol=1e-12, atol=1e-12)


def test_a_transition_is_exact_in_its_compact_form():
    """A's Phi over many steps, with every optional state (Gauss-Markov biases, scale
    factors, lever arm): the rows after the navigation errors are diagonal, so the nodes'
    compact form (its 9 navigation rows and its diagonal) gives Phi back exactly; a Phi
    whose later rows are not diagonal is refused."""
    from pospp import rotation
    from pospp.nav._filter_kernel import propagate_covariance
    from pospp.nav.error_model import N_NAV
    from pospp.nav.filter_state import state_layout

    rng = np.random.default_rng(5)
    lay = state_layout(True, True, True)
    n = lay.n
    x = np.concatenate([[0.8, 0.1, 500.0], [60.0, -20.0, 1.0],
                        rotation.quat_from_euler(np.array([0.1, -0.05, 2.0]))])
    p, phi = np.eye(n) * 1e-4, np.eye(n)
    qc, inv_tau = np.diag(rng.uniform(1e-10, 1e-6, n)), np.array([1 / 3600.0, 1 / 600.0])
    for _ in range(50):
        fm, wm = rng.normal([0.0, 0.0, -9.8], 0.5), rng.normal(0.0, 0.05, 3)
        p, phi = propagate_covariance(p, phi, x, fm, wm, 0.1, qc, lay.i_gm, lay.i_sf, inv_tau)
    assert np.count_nonzero(phi[:N_NAV, N_NAV:]) > 0  # the nav rows do read the others
    compact = smoother.compact_transition(phi[None], N_NAV)
    assert compact.shape == (1, N_NAV + 1, n) and compact.size < phi.size / 2
    back = np.empty((n, n))
    smoother.unpack_transition_into(compact[0], back)
    np.testing.assert_array_equal(back, phi)
    phi[N_NAV + 1, 0] = 1e-9
    with pytest.raises(ValueError, match="not diagonal"):
        smoother.compact_transition(phi[None], N_NAV)
