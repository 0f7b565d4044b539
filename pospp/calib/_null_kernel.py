"""Compiled loops of the linear-covariance null (:mod:`pospp.calib.linear_null`): the
transition of one grid interval, the exact Gaussian draws of B minus A (forward over the grid,
then A's smoother backward over its nodes) and the adjoint pass that gives the exact
covariance of linear functionals of them.

Augmented state ``z`` (column vectors; the equations and the reasons are in
:mod:`pospp.calib.linear_null`)::

    z = [e_A (n_a), beta_g (3), beta_a (3), e_B (9: phi, dv, dr), c_B (3)]

``lay = (n_a, i_gm, i_sf, slot_g, slot_a)``: A's state count, its optional blocks
(:class:`pospp.nav.filter_state.StateLayout`, -1 absent) and the states that carry A's error
in the injected gyro / accelerometer drift (its Gauss-Markov states, else its bias states).
``inj = (1/tau_g, 1/tau_a, c_g, c_a, arw, vrw, q_g, q_a, sigma_g, sigma_a)``: the injected
drifts' inverse correlation times [1/s], their coupling into A's slot (``-1/tau - a_A``
[1/s]), the white noise densities (ARW [rad/s^0.5], VRW [m/s^1.5]), the drifts' driving
densities ``sqrt(2 sigma^2 / tau)`` and their steady-state sigmas (rad/s, m/s^2).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pospp.nav._filter_kernel import fill_extended_f

N_IN = 12
"""Continuous white inputs: gyro white (3), accelerometer white (3), the drifts' driving
noise (3 + 3)."""
N_NOISE = 2 * N_IN
"""Standard normals per grid interval: the trapezoid's two ends (:func:`interval_matrices`)."""


@njit(cache=True)
def expm4(ft, out, w1, w2):
    """``out = I + A + A^2 / 2 + A^3 / 6 + A^4 / 24`` (Horner) for ``A = ft`` (square)."""
    n = ft.shape[0]
    for a in range(n):
        for b in range(n):
            w1[a, b] = ft[a, b] / 4.0 + (1.0 if a == b else 0.0)
    for k in (3.0, 2.0, 1.0):
        np.dot(ft, w1, w2)
        for a in range(n):
            for b in range(n):
                w1[a, b] = w2[a, b] / k + (1.0 if a == b else 0.0)
    out[:, :] = w1


@njit(cache=True)
def interval_matrices(x, fm, wm, dt, lay, inv_tau_a, inj, phi_z, gam, work, work_b, g_in):
    """Phi (n_z x n_z) and Gamma (n_z x :data:`N_NOISE`) of one grid interval of ``dt`` [s]
    ending at the kernel state ``x`` (:mod:`pospp.nav._kernels` layout), with mean specific
    force ``fm`` and rate ``wm`` (body FRD) over it: ``z(t + dt) = Phi z(t) + Gamma xi``,
    xi standard normal. Phi is ``expm(F_z dt)`` to fourth order, F_z held over the interval,
    made in two blocks: A with the drifts ``[e_A, beta]`` (F_A:
    :func:`pospp.nav._filter_kernel.fill_extended_f`, A's own F, and the drifts' entry into
    its slot), and B's navigation error with the drifts (A's leading 9 x 9 block: the same F
    along the same trajectory to first order in the errors; B's accelerometer offset enters
    as A's constant accelerometer bias does). Gamma = sqrt(dt / 2) [Phi G, G] (trapezoid of
    the inputs' covariance ``int Phi G G^T Phi^T``), G the inputs' columns (module
    docstring). Scratch: ``work`` (5, n_a + 6, n_a + 6), ``work_b`` (4, 15, 15), ``g_in``
    (n_z x :data:`N_IN`)."""
    n_a, i_gm, i_sf, slot_g, slot_a = lay
    ib, jb, ny = n_a, n_a + 6, n_a + 6
    fy, ft, py = work[0], work[1], work[2]
    fa = fy[:n_a, :n_a]
    c_nb = np.empty((3, 3))
    fill_extended_f(x, fm, wm, i_gm, i_sf, inv_tau_a, c_nb, fa)
    fy[:n_a, n_a:] = 0.0
    fy[n_a:, :] = 0.0
    for k in range(3):
        fy[slot_g + k, ib + k] = inj[2]
        fy[slot_a + k, ib + 3 + k] = inj[3]
        fy[ib + k, ib + k] = -inj[0]
        fy[ib + 3 + k, ib + 3 + k] = -inj[1]
    for a in range(ny):
        for b in range(ny):
            ft[a, b] = fy[a, b] * dt
    expm4(ft, py, work[3], work[4])
    phi_z[:, :] = 0.0
    phi_z[:ny, :ny] = py
    # B: [e_B nav (9), beta (6)] with B's gyro error beta_g, accelerometer error beta_a
    fu, pu = work_b[0], work_b[1]
    fu[:, :] = 0.0
    for r in range(9):
        for c in range(9):
            fu[r, c] = fa[r, c] * dt
        for k in range(3):
            fu[r, 9 + k] = fa[r, 9 + k] * dt
            fu[r, 12 + k] = fa[r, 12 + k] * dt
    for k in range(6):
        fu[9 + k, 9 + k] = fy[ib + k, ib + k] * dt
    expm4(fu, pu, work_b[2], work_b[3])

    for r in range(9):
        for c in range(9):
            phi_z[jb + r, jb + c] = pu[r, c]
        for k in range(6):
            phi_z[jb + r, ib + k] = pu[r, 9 + k]
        for k in range(3):
            phi_z[jb + r, jb + 9 + k] = phi_z[r, 12 + k]  # c_B: as A's constant accel bias
    for k in range(3):
        phi_z[jb + 9 + k, jb + 9 + k] = 1.0
    g_in[:, :] = 0.0
    arw, vrw, qg, qa = inj[4], inj[5], inj[6], inj[7]
    for r in range(3):
        for k in range(3):
            g_in[r, k] = arw * fa[r, 9 + k]  # -C_nb ARW: A's attitude ...
            g_in[jb + r, k] = arw * fa[r, 9 + k]  # ... and B's, the same noise
            g_in[3 + r, 3 + k] = vrw * fa[3 + r, 12 + k]
            g_in[jb + 3 + r, 3 + k] = vrw * fa[3 + r, 12 + k]
    for k in range(3):
        g_in[ib + k, 6 + k] = qg
        g_in[slot_g + k, 6 + k] += qg
        g_in[ib + 3 + k, 9 + k] = qa
        g_in[slot_a + k, 9 + k] += qa
    s = math.sqrt(0.5 * dt)
    pg = np.dot(phi_z, g_in)
    for r in range(phi_z.shape[0]):
        for c in range(N_IN):
            gam[r, c] = s * pg[r, c]
            gam[r, N_IN + c] = s * g_in[r, c]


@njit(cache=True)
def initial_matrix(lay, inj, g0):
    """The start's state (A's alignment epoch): the drifts in their steady state, A's slots
    carrying them (its estimates start at the flight's): ``z_0 = G0 xi``, G0 (n_z x 6)."""
    n_a, _, _, slot_g, slot_a = lay
    g0[:, :] = 0.0
    for k in range(3):
        g0[n_a + k, k] = inj[8]
        g0[slot_g + k, k] = inj[8]
        g0[n_a + 3 + k, 3 + k] = inj[9]
        g0[slot_a + k, 3 + k] = inj[9]


@njit(cache=True)
def _ba_total(v, i_gm, out, col):
    """A's total accelerometer-bias error (constant + Gauss-Markov) of state column ``v``."""
    for k in range(3):
        out[k] = v[12 + k, col] + (v[i_gm + 3 + k, col] if i_gm >= 0 else 0.0)


@njit(cache=True)
def _nav_and_ba_total(v, i_gm, tot, out):
    """``out`` (12, R): the navigation rows (attitude, velocity, position) of state columns
    ``v`` and A's total accelerometer-bias error of each (:func:`_ba_total`); ``tot`` (3,)
    scratch."""
    for r in range(9):
        out[r] = v[r]
    for c in range(v.shape[1]):
        _ba_total(v, i_gm, tot, c)
        for k in range(3):
            out[9 + k, c] = tot[k]


@njit(cache=True)
def _normals(xi, at, rows, n_draws, rng):
    """The next ``rows`` standard normals per draw: from ``xi`` (rows consumed in order from
    ``at[0]``) when it has rows, else from the generator ``rng``."""
    if xi.shape[0] == 0:
        return rng.standard_normal((rows, n_draws))
    out = np.ascontiguousarray(xi[at[0]:at[0] + rows])
    at[0] += rows
    return out


@njit(cache=True)
def forward_draws(grid, lay, inv_tau_a, inj, events, records, n_draws, rng, outs, xi, z0):
    """The forward sweep of ``n_draws`` realisations (:func:`pospp.calib.linear_null.
    LinearNull.draws`): z propagated over the grid, A's updates at its nodes with fixed gains,
    B reset at each leg start.

    ``grid = (xs (G, 10), fm (G, 3), wm (G, 3), dt (G,))``: the state at each grid point and
    the interval ending there (row 0 unused). ``events = (g_node, g_leg, g_sample)`` (G,) int:
    the node, leg start and output sample at each point (-1 none). ``records = (rec_start
    (K + 1,), K (nrec, n_a, 3), H (nrec, 3, n_a), sigma (nrec, 3))``. ``outs = (dx (K, n_a,
    R), eps_s (J, 3, R), eb_s (J, 3, R), eps0 (L, 12, R))``: A's summed feedback at each node,
    A's velocity error and B's forced velocity error at each sample, A's navigation and total
    accelerometer-bias error at each leg start. ``rng``: a numpy Generator; ``xi`` (rows, R):
    the standard normals to use instead, in the order drawn (6 at the start, :data:`N_NOISE`
    per interval, one per record axis with noise; no rows: the generator's): the
    realisations are then columns of the system's matrix (tests: ``xi`` the identity).
    ``z0`` (n_z, R): a state added at the start (no rows: none).
    """
    xs, fms, wms, dts = grid
    g_node, g_leg, g_sample = events
    rec_start, rec_k, rec_h, rec_sig = records
    dx_out, eps_s, eb_s, eps0 = outs
    n_a, i_gm = lay[0], lay[1]
    nz = n_a + 18
    jb = n_a + 6
    phi_z, gam = np.empty((nz, nz)), np.empty((nz, N_NOISE))
    work, work_b = np.empty((5, n_a + 6, n_a + 6)), np.empty((4, 15, 15))
    g_in, g0 = np.empty((nz, N_IN)), np.empty((nz, 6))
    initial_matrix(lay, inj, g0)
    at = np.zeros(1, dtype=np.int64)
    z = np.dot(g0, _normals(xi, at, 6, n_draws, rng))
    if z0.shape[0] > 0:
        z += z0
    tmp = np.empty((nz, n_draws))
    tot = np.empty(3)
    for g in range(xs.shape[0]):
        if g > 0:
            interval_matrices(xs[g], fms[g], wms[g], dts[g], lay, inv_tau_a, inj, phi_z, gam,
                              work, work_b, g_in)
            np.dot(phi_z, z, tmp)
            z[:, :] = tmp + np.dot(gam, _normals(xi, at, N_NOISE, n_draws, rng))
        node = g_node[g]
        if node >= 0:
            dx = dx_out[node]
            dx[:, :] = 0.0
            for i in range(rec_start[node], rec_start[node + 1]):
                innov = np.dot(rec_h[i], z[:n_a])
                for a in range(3):
                    if rec_sig[i, a] > 0.0:
                        innov[a] -= rec_sig[i, a] * _normals(xi, at, 1, n_draws, rng)[0]
                d = np.dot(rec_k[i], innov)
                z[:n_a] -= d
                dx[:, :] += d
        leg = g_leg[g]
        if leg >= 0:  # B starts on A: its forced part from zero, its offset -beta_a(t0)
            z[jb:jb + 9] = 0.0
            for k in range(3):
                z[jb + 9 + k] = -z[n_a + 3 + k]
            _nav_and_ba_total(z, i_gm, tot, eps0[leg])
        j = g_sample[g]
        if j >= 0:
            for a in range(3):
                eps_s[j, a] = z[3 + a]
                eb_s[j, a] = z[jb + 3 + a]


@njit(cache=True)
def smooth_draws(a_gains, dx, interp, i_gm, ehat_s, ehat0):
    """A's smoother over its nodes, backward: ``e_k^+ = A_k e_k+1^-``, ``e_k^- = e_k^+ +
    dx_k`` (``e_K-1^+ = 0``), and the estimate at each sample and leg start interpolated
    between ``e_i^+`` and ``e_i+1^-`` (``interp = (s_node (J,), s_alpha (J,), l_node (L,),
    l_alpha (L,))``): the velocity part into ``ehat_s`` (J, 3, R), the navigation and total
    accelerometer-bias part into ``ehat0`` (L, 12, R)."""
    s_node, s_alpha, l_node, l_alpha = interp
    n_k, n_a, n_r = dx.shape
    e_plus = np.zeros((n_a, n_r))
    e_next = np.zeros((n_a, n_r))  # e_k+1^-
    js, ls = s_node.shape[0] - 1, l_node.shape[0] - 1
    est = np.empty((n_a, n_r))
    tot = np.empty(3)
    for k in range(n_k - 1, -1, -1):
        if k == n_k - 1:
            e_plus[:, :] = 0.0
        else:
            np.dot(a_gains[k], e_next, e_plus)
        while js >= 0 and s_node[js] == k:
            al = s_alpha[js]
            for a in range(3):
                ehat_s[js, a] = (1.0 - al) * e_plus[3 + a] + al * e_next[3 + a]
            js -= 1
        while ls >= 0 and l_node[ls] == k:
            al = l_alpha[ls]
            est[:, :] = (1.0 - al) * e_plus + al * e_next
            _nav_and_ba_total(est, i_gm, tot, ehat0[ls])
            ls -= 1
        e_next[:, :] = e_plus + dx[k]


@njit(cache=True)
def psi_blocks(grid, lay, inv_tau_a, inj, g_leg, g_sample, leg_end, psi):
    """B's transition from its leg's start, velocity rows: ``psi[j] = Psi_dv(t_j, t0)``
    (J, 3, 12) over B's [phi, dv, dr, c] (its navigation error and accelerometer offset),
    accumulated over the grid intervals inside each leg (``leg_end`` (L,): its last grid
    point)."""
    xs, fms, wms, dts = grid
    n_a = lay[0]
    nz, jb = n_a + 18, n_a + 6
    phi_z, gam = np.empty((nz, nz)), np.empty((nz, N_NOISE))
    work, work_b = np.empty((5, n_a + 6, n_a + 6)), np.empty((4, 15, 15))
    g_in = np.empty((nz, N_IN))
    p = np.eye(12)
    leg, last = -1, -1
    for g in range(xs.shape[0]):
        if leg >= 0 and g <= last:
            interval_matrices(xs[g], fms[g], wms[g], dts[g], lay, inv_tau_a, inj, phi_z, gam,
                              work, work_b, g_in)
            p = np.dot(np.ascontiguousarray(phi_z[jb:jb + 12, jb:jb + 12]), p)
        if g_leg[g] >= 0:
            leg = g_leg[g]
            last = leg_end[leg]
            p = np.eye(12)
        j = g_sample[g]
        if j >= 0:
            psi[j] = p[3:6]


@njit(cache=True, nogil=True)
def smoother_adjoint(a_gains, sources, wj, u_a, mu_dx):
    """The adjoint of :func:`smooth_draws`, forward over the nodes: the sensitivity of the
    p functionals to each node's feedback, ``mu_dx`` (K, p, n_a), from their sources on the
    interpolated estimate: ``mu_k^- = g_k^- + mu_k-1^+ A_k-1``, ``mu_k^+ = g_k^+ + mu_k^-``,
    ``mu_dx_k = mu_k^-`` (row vectors; ``e_K-1^+`` is 0). ``sources = (node, plus, weight,
    kind, index)`` sorted by node: each adds ``weight`` times a source to ``g^+`` (plus) or
    ``g^-`` of its node, the source ``wj[index]`` (p, 3) on the velocity rows (kind 0, a
    sample) or ``-u_a[index]`` (p, n_a) on all (kind 1, a leg start)."""
    node, plus, weight, kind, index = sources
    n_k, p, n_a = mu_dx.shape
    mu_plus = np.zeros((p, n_a))
    e = 0
    for k in range(n_k):
        mu_minus = np.dot(mu_plus, a_gains[k - 1]) if k > 0 else np.zeros((p, n_a))
        g_plus = np.zeros((p, n_a))
        while e < node.shape[0] and node[e] == k:
            tgt = g_plus if plus[e] else mu_minus
            if kind[e] == 0:
                tgt[:, 3:6] += weight[e] * wj[index[e]]
            else:
                tgt -= weight[e] * u_a[index[e]]
            e += 1
        mu_dx[k] = mu_minus
        mu_plus = g_plus + mu_minus


@njit(cache=True, nogil=True)
def filter_adjoint(grid, lay, inv_tau_a, inj, events, records, wj, u_a, mu_dx, meat):
    """The adjoint of :func:`forward_draws`, backward over the grid, accumulating the
    covariance of p linear functionals of the realisation: ``meat += (lam Gamma)(lam
    Gamma)^T`` per interval, ``(lam - mu) K R^1/2`` per record, ``lam G0`` at the start
    (lam: (p, n_z), the functionals' sensitivity to z). The sources, on the state after a
    point's updates and B's reset: each sample's weights ``wj`` (J, p, 3) on B's velocity
    error less A's, each leg start's ``u_a`` (L, p, n_a) on A's error; ``mu_dx`` (K, p,
    n_a): :func:`smoother_adjoint`'s. ``meat`` (p, p) is added to."""
    xs, fms, wms, dts = grid
    g_node, g_leg, g_sample = events
    rec_start, rec_k, rec_h, rec_sig = records
    n_a = lay[0]
    nz, jb = n_a + 18, n_a + 6
    phi_z, gam = np.empty((nz, nz)), np.empty((nz, N_NOISE))
    work, work_b = np.empty((5, n_a + 6, n_a + 6)), np.empty((4, 15, 15))
    g_in, g0 = np.empty((nz, N_IN)), np.empty((nz, 6))
    lam = np.zeros((wj.shape[1], nz))
    for g in range(xs.shape[0] - 1, -1, -1):
        j = g_sample[g]
        if j >= 0:
            lam[:, jb + 3:jb + 6] += wj[j]
            lam[:, 3:6] -= wj[j]
        if g_leg[g] >= 0:
            lam[:, :n_a] += u_a[g_leg[g]]
        if g_leg[g] >= 0:  # z_B = 0, c_B = -beta_a
            for k in range(3):
                lam[:, n_a + 3 + k] -= lam[:, jb + 9 + k]
            lam[:, jb:jb + 12] = 0.0
        node = g_node[g]
        if node >= 0:
            for i in range(rec_start[node + 1] - 1, rec_start[node] - 1, -1):
                nu = lam[:, :n_a] - mu_dx[node]
                nk = np.dot(nu, rec_k[i])
                lam[:, :n_a] -= np.dot(nk, rec_h[i])
                for a in range(3):
                    nk[:, a] *= rec_sig[i, a]
                meat += np.dot(nk, nk.T)
        if g > 0:
            interval_matrices(xs[g], fms[g], wms[g], dts[g], lay, inv_tau_a, inj, phi_z, gam,
                              work, work_b, g_in)
            lg = np.dot(lam, gam)
            meat += np.dot(lg, lg.T)
            lam = np.dot(lam, phi_z)
    initial_matrix(lay, inj, g0)
    lg = np.dot(lam, g0)
    meat += np.dot(lg, lg.T)


@njit(cache=True)
def injected_gyro_integrals(xi, off, dt, beta0, inv_tau, arw, q_g):
    """The running integral (G, 3, R) of the gyro error ``beta_g + n_g`` (body FRD [rad]) the
    standard normals ``xi`` (rows, R) inject, from the first grid point, as the forward
    sweep discretises it (:meth:`pospp.calib.linear_null.LinearNull.injected_leg_means`'
    equations); ``off`` (G,) each grid point's first normal, ``dt`` (G,) its interval [s],
    ``beta0`` (3, R) the drift at the start [rad/s], ``inv_tau`` its 1/tau [1/s] (0: a random
    walk), ``arw`` [rad/s^0.5], ``q_g`` its driving density [rad/s^1.5]."""
    n_g, n_r = dt.shape[0], xi.shape[1]
    cum = np.zeros((n_g, 3, n_r))
    beta = beta0.copy()
    for g in range(1, n_g):
        s = math.sqrt(0.5 * dt[g])
        phi = math.exp(-inv_tau * dt[g])
        c = dt[g] if inv_tau == 0.0 else (1.0 - phi) / inv_tau
        o = off[g]
        for a in range(3):
            for r in range(n_r):
                start = beta[a, r] + s * q_g * xi[o + 6 + a, r]
                cum[g, a, r] = (cum[g - 1, a, r] + c * start
                                + s * arw * (xi[o + a, r] + xi[o + N_IN + a, r]))
                beta[a, r] = phi * start + s * q_g * xi[o + N_IN + 6 + a, r]
    return cum
