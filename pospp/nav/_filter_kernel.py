"""Compiled forward pass of algorithm A (numba, ``cache=True``): one loop over the IMU epochs.

Strapdown with the one mechanization kernel (:func:`pospp.nav._kernels.strapdown_step`) on the
corrected increments, covariance propagation with the one F
(:func:`pospp.nav.error_model.fill_f_matrix`) extended by the optional state blocks,
gated GNSS/ZUPT updates with closed-loop feedback, and the storage of outputs and smoother
nodes. The models, the state layout and the meaning of every array are documented in
:mod:`pospp.nav.filter` and docs/filter.md; the public entry point is
:func:`pospp.nav.filter.run_integrated_navigation`.

The loop (:func:`forward_kernel`) calls one compiled helper per job, each tested alone against
numpy (tests/unit/test_filter_kernel.py):

- :func:`correct_increments`, :func:`decay_gauss_markov`: the sensor-error model;
- :func:`propagate_covariance` (in place: :func:`propagate_covariance_into`):
  Phi = I + F T + (F T)^2 / 2, P <- Phi P Phi^T + Q_d;
- :func:`measurement_model`: innovation dz (predicted minus measured) and H;
- :func:`innovation_covariance`: S = H P H^T + R and its inverse (the one place S is made);
- :func:`reset_block`: the covariance reset after ``gate_reset_s`` of gated records;
- :func:`kalman_update`: K = P H^T S^-1, dx = K dz, Joseph form;
- :func:`feedback`: closed-loop correction of the nominal state and sensor errors;
- :func:`store_output`, :func:`store_node`: the output and smoother-node arrays.

Error-state blocks are named once in :mod:`pospp.nav.error_model` (``I_PHI`` ... ``I_BA``), the
nominal state in :mod:`pospp.nav._kernels` (``X_POS``, ``X_VEL``, ``X_QUAT``), the nominal
sensor errors below (``SENS_*``), the record status codes below (``STATUS_*``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pospp.nav import _kernels, smoother
from pospp.nav._kernels import STATE_SIZE, X_POS, X_QUAT, X_VEL
from pospp.nav.error_model import I_BA, I_BG, I_DR, I_DV, I_PHI, N_STATES, fill_f_matrix

MEAS_POSITION, MEAS_VELOCITY, MEAS_ZUPT = 0, 1, 2
"""Kinds of measurement record (index into ``MEAS_KINDS``)."""
MEAS_KINDS = ("position", "velocity", "zupt")
FLAG_NODE, FLAG_OUTPUT = 1, 2
"""Bits of the per-epoch flags: smoother node, output epoch."""
STATUS_USED, STATUS_GATED, STATUS_RESET, STATUS_BEFORE_START = 0, 1, 2, 3
"""Status of each measurement record: used; refused by the innovation gate; used after a
covariance reset (``gate_reset_s``); before the filter start (alignment)."""
SENS_BG, SENS_BA, SENS_SG, SENS_SA, SENS_GM_G, SENS_GM_A = 0, 3, 6, 9, 12, 15
"""Offsets in the nominal sensor-error vector (float64[18]): constant gyro and accel bias,
gyro and accel scale factor, Gauss-Markov gyro and accel bias."""
N_SENS = 18


@njit(cache=True)
def _skew_into(v, out, r0, c0, sign):
    out[r0 + 0, c0 + 1] = -sign * v[2]
    out[r0 + 0, c0 + 2] = sign * v[1]
    out[r0 + 1, c0 + 0] = sign * v[2]
    out[r0 + 1, c0 + 2] = -sign * v[0]
    out[r0 + 2, c0 + 0] = -sign * v[1]
    out[r0 + 2, c0 + 1] = sign * v[0]


@njit(cache=True)
def _inv3(s, out):
    a, b, c = s[0, 0], s[0, 1], s[0, 2]
    d, e, f = s[1, 0], s[1, 1], s[1, 2]
    g, h, i = s[2, 0], s[2, 1], s[2, 2]
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if not (abs(det) > 0.0):
        return False
    out[0, 0] = (e * i - f * h) / det
    out[0, 1] = (c * h - b * i) / det
    out[0, 2] = (b * f - c * e) / det
    out[1, 0] = (f * g - d * i) / det
    out[1, 1] = (a * i - c * g) / det
    out[1, 2] = (c * d - a * f) / det
    out[2, 0] = (d * h - e * g) / det
    out[2, 1] = (b * g - a * h) / det
    out[2, 2] = (a * e - b * d) / det
    return True


@njit(cache=True)
def correct_increments(w_b, f_b, sens, dt, dth_c, dv_c):
    """Sensor-error-corrected increments over ``dt`` [s] into ``dth_c`` [rad], ``dv_c`` [m/s].

    ``dtheta = (w - b_g - b_g,gm) dt / (1 + s_g)``, ``dv = (f - b_a - b_a,gm) dt / (1 + s_a)``.
    """
    for a in range(3):
        dth_c[a] = (w_b[a] - sens[SENS_BG + a] - sens[SENS_GM_G + a]) * dt \
            / (1.0 + sens[SENS_SG + a])
        dv_c[a] = (f_b[a] - sens[SENS_BA + a] - sens[SENS_GM_A + a]) * dt \
            / (1.0 + sens[SENS_SA + a])


@njit(cache=True)
def decay_gauss_markov(sens, dt, inv_tau):
    """Nominal Gauss-Markov biases decay over ``dt``: ``b <- b exp(-dt / tau)``."""
    dg = math.exp(-dt * inv_tau[0])
    da = math.exp(-dt * inv_tau[1])
    for a in range(3):
        sens[SENS_GM_G + a] *= dg
        sens[SENS_GM_A + a] *= da


@njit(cache=True)
def propagate_covariance(p, phi_acc, x, fm, wm, t_acc, qc, i_gm, i_sf, inv_tau):
    """One covariance step over ``t_acc`` [s] with mean specific force ``fm`` and rate ``wm``.

    ``Phi = I + F T + (F T)^2 / 2`` with F the 15-state ``fill_f_matrix`` extended by the
    optional columns (``phi' += -C_nb (b_g,gm + diag(w) s_g)``, ``dv' += C_nb (b_a,gm +
    diag(f) s_a)``, ``b_gm' = -b_gm / tau``); ``P <- Phi P Phi^T + (Phi Q_c Phi^T + Q_c) T / 2``
    (symmetrised). Returns the new P and ``Phi @ phi_acc`` (new arrays; the forward pass
    uses :func:`propagate_covariance_into`).
    """
    n = p.shape[0]
    p_new, phi_new = p.copy(), phi_acc.copy()
    propagate_covariance_into(p_new, phi_new, x, fm, wm, t_acc, qc, i_gm, i_sf, inv_tau,
                              np.empty((5, n, n)))
    return p_new, phi_new


@njit(cache=True)
def fill_extended_f(x, fm, wm, i_gm, i_sf, inv_tau, c_nb, f_out):
    """A's continuous-time error dynamics F (n x n, zeroed here) at the kernel state ``x`` with
    mean specific force ``fm`` and rate ``wm`` (body FRD): the 15-state
    :func:`pospp.nav.error_model.fill_f_matrix` (biases constant there) extended by the
    optional columns ``phi' += -C_nb (b_g,gm + diag(w) s_g)``, ``dv' += C_nb (b_a,gm +
    diag(f) s_a)``, ``b_gm' = -b_gm / tau`` (the lever-arm states have none). ``c_nb`` receives
    the attitude DCM. The one F of A's covariance steps and of :mod:`pospp.calib.linear_null`.
    """
    n = f_out.shape[0]
    _kernels.dcm_from_quat_into(x[X_QUAT:X_QUAT + 4], c_nb)
    for a in range(n):
        for b in range(n):
            f_out[a, b] = 0.0
    fill_f_matrix(x[X_POS], x[X_POS + 2], x[X_VEL:X_VEL + 3], c_nb, fm, 0.0, 0.0,
                  f_out[:N_STATES, :N_STATES])
    if i_gm >= 0:
        for a in range(3):
            for b in range(3):
                f_out[I_PHI + a, i_gm + b] = -c_nb[a, b]
                f_out[I_DV + a, i_gm + 3 + b] = c_nb[a, b]
            f_out[i_gm + a, i_gm + a] = -inv_tau[0]
            f_out[i_gm + 3 + a, i_gm + 3 + a] = -inv_tau[1]
    if i_sf >= 0:
        for a in range(3):
            for b in range(3):
                f_out[I_PHI + a, i_sf + b] = -c_nb[a, b] * wm[b]
                f_out[I_DV + a, i_sf + 3 + b] = c_nb[a, b] * fm[b]


@njit(cache=True)
def propagate_covariance_into(p, phi_acc, x, fm, wm, t_acc, qc, i_gm, i_sf, inv_tau, work):
    """:func:`propagate_covariance` in place: ``p`` and ``phi_acc`` are overwritten (``phi_acc``
    of shape (0, 0): not accumulated, as when the pass keeps no smoother nodes).

    ``work``: float64[5, n, n] scratch, reused across steps (the step allocates nothing n x n:
    the allocations and the separate ``Phi Q_c Phi^T`` product were half of
    the step's time). ``Phi P Phi^T + (Phi Q_c Phi^T + Q_c) T / 2`` is computed as the one
    product ``Phi (P + Q_c T / 2) Phi^T + Q_c T / 2``.
    """
    n = p.shape[0]
    ff, ff2, phi, m, m2 = work[0], work[1], work[2], work[3], work[4]
    c_nb = np.empty((3, 3))
    fill_extended_f(x, fm, wm, i_gm, i_sf, inv_tau, c_nb, m)  # m is free until the product
    for a in range(n):
        for b in range(n):
            ff[a, b] = m[a, b] * t_acc
    np.dot(ff, ff, ff2)
    for a in range(n):
        for b in range(n):
            phi[a, b] = ff[a, b] + 0.5 * ff2[a, b] + (1.0 if a == b else 0.0)
    half_t = 0.5 * t_acc
    for a in range(n):
        for b in range(n):
            m2[a, b] = p[a, b] + half_t * qc[a, b]
    np.dot(phi, m2, m)
    np.dot(m, phi.T, m2)
    for a in range(n):
        for b in range(a, n):
            v = 0.5 * (m2[a, b] + m2[b, a]) + half_t * qc[a, b]
            p[a, b] = v
            p[b, a] = v
    if phi_acc.shape[0]:  # empty: no smoother nodes kept, the product is not needed
        np.dot(phi, phi_acc, m)
        phi_acc[:, :] = m


@njit(cache=True)
def measurement_model(kind, x, lever, w_b, a_n, z, dt_meas, i_gm, i_sf, i_l, h_mat, dz):
    """Innovation ``dz`` (predicted minus measured) and ``H`` (zeroed here) of one record.

    The record is ``dt_meas`` after its epoch: it is predicted there, a position with the
    antenna's velocity ``v_a``, a velocity with the mean acceleration ``a_n`` over the epoch's
    last interval (NED m/s^2).
    Position: ``dz = r + C l + v_a dt_meas - z`` (NED m), ``H = [[(C l) x], 0, I, 0, 0 ...
    (, C)]``. Velocity: ``dz = v + C (w x l) - w_in x (C l) + a_n dt_meas - z``; ZUPT
    (z = 0): the same without ``a_n dt_meas``; ``H =
    [[(C (w x l)) x], I, 0, -C [l x], 0 (, -C [l x], 0) (, -C [l x] diag(w), 0) (, C [w x] -
    [w_in x] C)]`` (module docstring of :mod:`pospp.nav.filter`).
    """
    c_nb = np.empty((3, 3))
    _kernels.dcm_from_quat_into(x[X_QUAT:X_QUAT + 4], c_nb)
    cl = np.empty(3)
    for a in range(3):
        cl[a] = c_nb[a, 0] * lever[0] + c_nb[a, 1] * lever[1] + c_nb[a, 2] * lever[2]
    lat, h = x[X_POS], x[X_POS + 2]
    wie, wen = _kernels.nav_rates(lat, h, x[X_VEL], x[X_VEL + 1])
    win = np.array([wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2]])
    cwl = np.dot(c_nb, np.cross(w_b, lever))
    wcl = np.cross(win, cl)
    v_ant = np.empty(3)
    for a in range(3):
        v_ant[a] = x[X_VEL + a] + cwl[a] - wcl[a]
    h_mat[:, :] = 0.0
    if kind == MEAS_POSITION:
        r_m, r_n = _kernels.radii(lat)
        d0 = (z[0] - lat) * (r_m + h)
        d1 = (z[1] - x[X_POS + 1]) * (r_n + h) * math.cos(lat)
        d2 = -(z[2] - h)
        dz[0] = cl[0] - d0 + v_ant[0] * dt_meas
        dz[1] = cl[1] - d1 + v_ant[1] * dt_meas
        dz[2] = cl[2] - d2 + v_ant[2] * dt_meas
        _skew_into(cl, h_mat, 0, I_PHI, 1.0)
        for a in range(3):
            h_mat[a, I_DR + a] = 1.0
        if i_l >= 0:
            for a in range(3):
                for b in range(3):
                    h_mat[a, i_l + b] = c_nb[a, b]
        return
    ahead = dt_meas if kind == MEAS_VELOCITY else 0.0
    for a in range(3):
        dz[a] = v_ant[a] + a_n[a] * ahead - z[a]
    _skew_into(cwl, h_mat, 0, I_PHI, 1.0)
    for a in range(3):
        h_mat[a, I_DV + a] = 1.0
    sl = np.zeros((3, 3))
    _skew_into(lever, sl, 0, 0, 1.0)
    csl = np.dot(c_nb, sl)
    for a in range(3):
        for b in range(3):
            h_mat[a, I_BG + b] = -csl[a, b]  # -C [l x] (gyro bias)
            if i_gm >= 0:
                h_mat[a, i_gm + b] = -csl[a, b]
            if i_sf >= 0:
                h_mat[a, i_sf + b] = -csl[a, b] * w_b[b]  # -C [l x] diag(w)
    if i_l >= 0:
        sw = np.zeros((3, 3))
        _skew_into(w_b, sw, 0, 0, 1.0)
        swin = np.zeros((3, 3))
        _skew_into(win, swin, 0, 0, 1.0)
        hl = np.dot(c_nb, sw) - np.dot(swin, c_nb)
        for a in range(3):
            for b in range(3):
                h_mat[a, i_l + b] = hl[a, b]


@njit(cache=True)
def innovation_covariance(p, h_mat, r, s_inv):
    """``S = H P H^T + R`` inverted into ``s_inv``; returns ``(P H^T, invertible)``."""
    ph = np.dot(p, h_mat.T)  # (n, 3)
    s_full = np.dot(h_mat, ph) + r
    s_mat = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            s_mat[a, b] = s_full[a, b]
    return ph, _inv3(s_mat, s_inv)


@njit(cache=True)
def normalised_innovation(dz, s_inv):
    """NIS ``dz^T S^-1 dz`` (3 dof)."""
    nis = 0.0
    for a in range(3):
        for b in range(3):
            nis += dz[a] * s_inv[a, b] * dz[b]
    return nis


@njit(cache=True)
def reset_block(p, blk, dz, r):
    """Re-initialise the 3-state block at ``blk`` from one record: uncorrelated with the rest,
    variance ``dz^2 + R`` per axis (after ``gate_reset_s`` of gated records)."""
    n = p.shape[0]
    for a in range(3):
        for b in range(n):
            p[blk + a, b] = 0.0
            p[b, blk + a] = 0.0
        p[blk + a, blk + a] = dz[a] * dz[a] + r[a, a]


@njit(cache=True)
def kalman_update(p, ph, s_inv, h_mat, dz, r):
    """``K = P H^T S^-1``, ``dx = K dz``, Joseph form ``P = (I - K H) P (I - K H)^T + K R K^T``
    (symmetrised). Returns ``(P, dx)``."""
    n = p.shape[0]
    kg = np.dot(ph, s_inv)  # (n, 3)
    dxk = np.dot(kg, dz)
    ikh = np.eye(n) - np.dot(kg, h_mat)
    p_new = np.dot(np.dot(ikh, p), ikh.T) + np.dot(np.dot(kg, r), kg.T)  # Joseph
    return 0.5 * (p_new + p_new.T), dxk


@njit(cache=True)
def feedback(x, xp, sens, lever, dxk, i_gm, i_sf, i_l):
    """Closed-loop feedback of an update ``dxk`` (error state reset to zero afterwards).

    Nominal state corrected (:func:`pospp.nav.smoother.apply_correction`); the previous epoch
    ``xp`` (used by the next strapdown step's extrapolation) moved by the same position and
    velocity correction; sensor errors accumulated; lever arm ``l <- l - dl``.
    """
    x_old0, x_old1, x_old2 = x[X_POS], x[X_POS + 1], x[X_POS + 2]
    smoother.apply_correction(x, dxk)
    xp[X_POS] += x[X_POS] - x_old0
    xp[X_POS + 1] += x[X_POS + 1] - x_old1
    xp[X_POS + 2] += x[X_POS + 2] - x_old2
    for a in range(3):
        xp[X_VEL + a] -= dxk[I_DV + a]
        sens[SENS_BG + a] += dxk[I_BG + a]
        sens[SENS_BA + a] += dxk[I_BA + a]
        if i_gm >= 0:
            sens[SENS_GM_G + a] += dxk[i_gm + a]
            sens[SENS_GM_A + a] += dxk[i_gm + 3 + a]
        if i_sf >= 0:
            sens[SENS_SG + a] += dxk[i_sf + a]
            sens[SENS_SA + a] += dxk[i_sf + 3 + a]
        if i_l >= 0:
            lever[a] -= dxk[i_l + a]


@njit(cache=True)
def store_output(i_out, x, p, sens, lever, i_gm, outs):
    """Row ``i_out`` of the outputs ``(x, diag P, [phi, dv, dr] blocks, sensor errors, total
    bias variance, lever)``; the total bias is constant + Gauss-Markov. P's outputs (diag,
    blocks, bias variance) without rows are not stored (a run without covariance outputs)."""
    out_x, out_diag, out_blk, out_sens, out_bvar, out_lever = outs
    n = p.shape[0]
    keep_p = out_diag.shape[0] > 0
    out_x[i_out] = x
    if keep_p:
        for a in range(n):
            out_diag[i_out, a] = p[a, a]
        for ib, blk in enumerate((I_PHI, I_DV, I_DR)):
            for a in range(3):
                for b in range(3):
                    out_blk[i_out, ib, a, b] = p[blk + a, blk + b]
    for a in range(SENS_GM_G):
        out_sens[i_out, a] = sens[a]
    for a in range(6):  # total bias = constant + Gauss-Markov, and its variance
        if i_gm >= 0:
            out_sens[i_out, SENS_BG + a] += sens[SENS_GM_G + a]
        if keep_p:
            out_bvar[i_out, a] = p[I_BG + a, I_BG + a]
            if i_gm >= 0:
                out_bvar[i_out, a] += p[i_gm + a, i_gm + a] + 2.0 * p[I_BG + a, i_gm + a]
    for a in range(3):
        out_lever[i_out, a] = lever[a]


@njit(cache=True)
def store_node(i_node, k, p_upd, phi_acc, dx_tot, nodes):
    """Smoother node ``i_node`` at epoch ``k``: updated P, Phi since the last node, the summed
    feedback of the epoch (the predicted P was stored before the updates)."""
    node_k, node_pp, node_pu, node_phi, node_dx = nodes
    node_k[i_node] = k
    smoother.pack_symmetric_into(p_upd, node_pu[i_node])  # P is exactly symmetric here
    m = node_phi.shape[1] - 1  # Phi compact: its first m rows and its diagonal
    node_phi[i_node, :m] = phi_acc[:m]
    for a in range(phi_acc.shape[0]):
        node_phi[i_node, m, a] = phi_acc[a, a]
    node_dx[i_node] = dx_tot


@njit(cache=True)
def _update_epoch(k, im, t, x, xp, p, sens, lever, w_b, meas, meas_out, gate, reset_after_s,
                  t_ok, i_gm, i_sf, i_l, dx_tot, gains, replay, record, n_gated):
    """All measurement records of epoch ``k`` from index ``im``: model, gate (or reset),
    update, feedback. Returns the new P and the index after the epoch's records. The mean
    acceleration over the epoch's last interval, ``(v_k - v_k-1) / (t_k - t_k-1)`` (the
    strapdown's increment), predicts a velocity record off its epoch
    (:func:`measurement_model`).

    ``gains = (K, S^-1, H)``, (records, n, 3), (records, 3, 3) and (records, 3, n).
    ``record``: each used record's K, S^-1 and H are stored in them. ``replay``: they are
    read instead (another pass's, :class:`pospp.nav.filter_state.GainReplay`; H is not), with
    that pass's record status in ``m_status``: a record it used is gated here when ``dz^T
    S^-1 dz`` exceeds the gate with its S, else ``dx = K dz``; a record it reset with is
    used; no covariance is touched. A second record of a kind gated in a row (``n_gated``
    counts them per kind) ends the replay:
    the index returned is -1 (the full filter's covariance would have grown over the gap and
    its gains with it, and it would reset after ``reset_after_s``: no longer this pass's).
    """
    m_k, m_type, m_z, m_r, m_dt = meas
    if not (im < m_k.shape[0] and m_k[im] == k):  # most epochs: nothing to allocate
        return p, im
    m_status, m_nis, m_dz = meas_out
    k_gain, k_sinv, k_h = gains
    n = p.shape[0]
    h_mat = np.zeros((3, n))
    dz = np.empty(3)
    s_inv = np.empty((3, 3))
    a_n = np.zeros(3)
    if k > 0:
        for a in range(3):
            a_n[a] = (x[X_VEL + a] - xp[X_VEL + a]) / (t[k] - t[k - 1])
    while im < m_k.shape[0] and m_k[im] == k:
        kind = m_type[im]
        measurement_model(kind, x, lever, w_b, a_n, m_z[im], m_dt[im], i_gm, i_sf, i_l, h_mat,
                          dz)
        if replay:
            for a in range(3):
                m_dz[im, a] = dz[a]
            st = m_status[im]
            if st == STATUS_USED or st == STATUS_RESET:
                nis = normalised_innovation(dz, k_sinv[im])
                m_nis[im] = nis
                if st == STATUS_USED and not (nis <= gate):
                    m_status[im] = STATUS_GATED
                    n_gated[kind] += 1
                    if n_gated[kind] > 1:
                        return p, -1
                else:
                    n_gated[kind] = 0
                    dxk = np.dot(k_gain[im], dz)
                    feedback(x, xp, sens, lever, dxk, i_gm, i_sf, i_l)
                    for a in range(n):
                        dx_tot[a] += dxk[a]
            im += 1
            continue
        ph, ok = innovation_covariance(p, h_mat, m_r[im], s_inv)
        nis = normalised_innovation(dz, s_inv) if ok else math.inf
        m_nis[im] = nis
        for a in range(3):
            m_dz[im, a] = dz[a]
        status = STATUS_USED
        if not (nis <= gate):
            if kind == MEAS_ZUPT or not (t[k] - t_ok[kind] > reset_after_s):
                m_status[im] = STATUS_GATED
                im += 1
                continue
            # every GNSS record of this kind gated for reset_after_s: the filter, not GNSS,
            # has lost its way. Re-initialise the position (velocity) block from this record
            # and accept it ungated.
            status = STATUS_RESET
            reset_block(p, I_DR if kind == MEAS_POSITION else I_DV, dz, m_r[im])
            ph, ok = innovation_covariance(p, h_mat, m_r[im], s_inv)
            if not ok:
                m_status[im] = STATUS_GATED
                im += 1
                continue
        t_ok[kind] = t[k]
        m_status[im] = status
        if record:
            k_gain[im] = np.dot(ph, s_inv)  # kalman_update's K, the same product
            k_sinv[im] = s_inv
            k_h[im] = h_mat
        p, dxk = kalman_update(p, ph, s_inv, h_mat, dz, m_r[im])
        feedback(x, xp, sens, lever, dxk, i_gm, i_sf, i_l)
        for a in range(n):
            dx_tot[a] += dxk[a]
        im += 1
    return p, im


@njit(cache=True, nogil=True)
def forward_kernel(t, w_imu, f_imu, k0, x0, p0, lever0, layout, inv_tau, flags, meas,
                   meas_out, prop_steps, q_diag, gate, reset_after_s, outs, nodes, gains,
                   replay_from):
    """Closed-loop forward pass over IMU epochs ``k0 .. N-1`` (module docstring).

    ``w_imu[k]``, ``f_imu[k]``: mean rates over (t[k-1], t[k]]. ``layout = (i_gm, i_sf,
    i_l)``: index of the first Gauss-Markov bias / scale-factor / lever-arm state, -1 when
    absent; ``inv_tau`` = [1 / tau_gyro, 1 / tau_accel] of the Gauss-Markov states [1/s].
    ``meas = (m_k, m_type, m_z, m_r, m_dt)`` the records sorted by epoch; ``meas_out =
    (m_status, m_nis, m_dz)``: ``STATUS_*`` code, NIS and innovation (predicted minus measured,
    NED) of each record. ``outs`` / ``nodes``: see :func:`store_output` / :func:`store_node`.
    Without the smoother ``nodes`` has no rows: node epochs are counted (they still force a
    covariance step, so the schedule is the smoothed run's), nothing is stored and Phi is
    not accumulated. ``gains``: see :func:`_update_epoch`; stored when they have rows and
    ``replay_from`` is -1, replayed from epoch ``replay_from`` on otherwise: from there no
    covariance is propagated, and the nodes keep only their epoch and summed feedback (their
    P and Phi are kept for the node rows the P arrays have: the nodes before the replay).
    Fills the output and node arrays; returns (nodes used, outputs used), (-1, -1) when a
    replay ended.
    """
    i_gm, i_sf, i_l = layout
    m_k = meas[0]
    m_status = meas_out[0]
    n = p0.shape[0]
    x, xp, xn = x0.copy(), x0.copy(), np.empty(STATE_SIZE)
    sens = np.zeros(N_SENS)
    lever = lever0.copy()
    p = p0.copy()
    keep_nodes = nodes[0].shape[0] > 0  # no smoother: nodes counted, not stored
    n_cov = nodes[1].shape[0]  # nodes whose P and Phi are kept (a replay's: before it)
    record = gains[0].shape[0] > 0 and replay_from < 0
    phi_acc = np.eye(n) if n_cov > 0 else np.empty((0, 0))
    qc = np.diag(q_diag)
    work = np.empty((5, n, n))
    fsum, wsum = np.zeros(3), np.zeros(3)
    dth_p, dv_p, dth_c, dv_c, w_b = (np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3),
                                     np.zeros(3))
    dx_tot = np.zeros(n)
    t_ok = np.full(3, t[k0])  # last accepted record of each kind
    n_gated = np.zeros(3, dtype=np.int64)  # a replay's records gated in a row, per kind
    t_acc, steps, im, i_out, i_node = 0.0, 0, 0, 0, 0
    while im < m_k.shape[0] and m_k[im] < k0:
        m_status[im] = STATUS_BEFORE_START
        im += 1
    for k in range(k0, t.shape[0]):
        if k > k0:
            dt = t[k] - t[k - 1]
            correct_increments(w_imu[k], f_imu[k], sens, dt, dth_c, dv_c)
            if i_gm >= 0:
                decay_gauss_markov(sens, dt, inv_tau)
            extrap = 0.0 if k - 1 == k0 else 0.5 * dt / (t[k - 1] - t[k - 2])
            _kernels.strapdown_step(x, xp, dth_c, dv_c, dth_p, dv_p, dt, extrap, xn)
            xp[:] = x
            x[:] = xn
            for a in range(3):
                dth_p[a], dv_p[a] = dth_c[a], dv_c[a]
                fsum[a] += dv_c[a]
                wsum[a] += dth_c[a]
                w_b[a] = dth_c[a] / dt
            t_acc += dt
            steps += 1
        has_meas = im < m_k.shape[0] and m_k[im] == k
        is_node = (flags[k] & FLAG_NODE) != 0 or has_meas or k == k0
        is_out = (flags[k] & FLAG_OUTPUT) != 0
        replay = replay_from >= 0 and k >= replay_from
        if steps > 0 and (steps >= prop_steps or has_meas or is_node or is_out):
            if not replay:
                propagate_covariance_into(p, phi_acc, x, fsum / t_acc, wsum / t_acc, t_acc,
                                          qc, i_gm, i_sf, inv_tau, work)
            fsum[:] = 0.0
            wsum[:] = 0.0
            t_acc, steps = 0.0, 0
        keep_cov = keep_nodes and i_node < n_cov
        if is_node and keep_cov:
            smoother.pack_symmetric_into(p, nodes[1][i_node])  # predicted P (symmetric)
        dx_tot[:] = 0.0
        if has_meas:  # the call alone, with its 22 arguments, was a third of an epoch's time
            p, im = _update_epoch(k, im, t, x, xp, p, sens, lever, w_b, meas, meas_out, gate,
                                  reset_after_s, t_ok, i_gm, i_sf, i_l, dx_tot, gains, replay,
                                  record, n_gated)
            if im < 0:  # the replay ended (_update_epoch): the caller runs the pass in full
                return -1, -1
        if is_node:
            if keep_cov:
                store_node(i_node, k, p, phi_acc, dx_tot, nodes)
                phi_acc = np.eye(n)
            elif keep_nodes:
                nodes[0][i_node] = k
                nodes[4][i_node] = dx_tot
            i_node += 1
        if is_out:
            store_output(i_out, x, p, sens, lever, i_gm, outs)
            i_out += 1
    return i_node, i_out
