"""Compiled forward pass of algorithm A (numba, ``cache=True``): one loop over the IMU epochs.

Strapdown with the one mechanization kernel (:func:`pospp.nav._kernels.strapdown_step`) on the
corrected increments, covariance propagation with the one F
(:func:`pospp.nav.error_model.fill_f_matrix`) extended by the optional state blocks,
gated GNSS/ZUPT updates with closed-loop feedback, and the storage of outputs and smoother
nodes. The models, the state layout and the meaning of every array are documented in
:mod:`pospp.nav.filter` and docs/filter.md; the public entry point is
:func:`pospp.nav.filter.run_integrated_navigation`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pospp.nav import _kernels, smoother
from pospp.nav.error_model import fill_f_matrix

MEAS_POSITION, MEAS_VELOCITY, MEAS_ZUPT = 0, 1, 2
FLAG_NODE, FLAG_OUTPUT = 1, 2


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
def forward_kernel(
    t, w_imu, f_imu, k0, x0, p0, lever0, i_gm, inv_tau, i_sf, i_l, flags, m_k, m_type, m_z,
    m_r, m_dt, prop_steps, q_diag, gate, reset_after_s, m_status, m_nis, m_dz, out_x, out_diag,
    out_blk, out_sens,
    out_bvar, out_lever, node_k, node_pp, node_pu, node_phi, node_dx,
):
    """Closed-loop forward pass over IMU epochs ``k0 .. N-1`` (module docstring).

    ``w_imu[k]``, ``f_imu[k]``: mean rates over (t[k-1], t[k]]. ``i_gm`` / ``i_sf`` / ``i_l``:
    index of the first Gauss-Markov bias / scale-factor / lever-arm state, -1 when absent;
    ``inv_tau`` = [1 / tau_gyro, 1 / tau_accel] of the Gauss-Markov states [1/s].
    ``m_status``: 0 used, 1 gated, 2 used after a covariance reset, 3 before the start.
    ``m_nis``, ``m_dz``: NIS and innovation (predicted minus measured, NED) of each record.
    Fills the output and node arrays; returns (nodes used, outputs used).
    """
    n = p0.shape[0]
    n_ep = t.shape[0]
    n_meas = m_k.shape[0]
    x = x0.copy()
    xp = x0.copy()
    xn = np.empty(10)
    # nominal sensor errors: constant gyro bias, accel bias, gyro and accel scale factors,
    # Gauss-Markov gyro and accel biases (decaying with their time constants)
    sens = np.zeros(18)
    lever = lever0.copy()
    p = p0.copy()
    eye = np.eye(n)
    phi_acc = np.eye(n)
    f15 = np.zeros((15, 15))
    ff = np.zeros((n, n))
    qc = np.zeros((n, n))
    for i in range(n):
        qc[i, i] = q_diag[i]
    fsum = np.zeros(3)
    wsum = np.zeros(3)
    t_acc = 0.0
    steps = 0
    dth_p = np.zeros(3)
    dv_p = np.zeros(3)
    dth_c = np.zeros(3)
    dv_c = np.zeros(3)
    w_b = np.zeros(3)
    fm = np.zeros(3)
    wm = np.zeros(3)
    c_nb = np.empty((3, 3))
    h_mat = np.zeros((3, n))
    s_mat = np.empty((3, 3))
    s_inv = np.empty((3, 3))
    dz = np.empty(3)
    cl = np.empty(3)
    sl = np.zeros((3, 3))
    dx_tot = np.zeros(n)
    t_ok = np.full(3, t[k0])  # last accepted record of each kind
    im = 0
    while im < n_meas and m_k[im] < k0:
        m_status[im] = 3  # before the filter start
        im += 1
    i_out = 0
    i_node = 0
    for k in range(k0, n_ep):
        if k > k0:
            dt = t[k] - t[k - 1]
            for a in range(3):
                dth_c[a] = (w_imu[k, a] - sens[a] - sens[12 + a]) * dt / (1.0 + sens[6 + a])
                dv_c[a] = (f_imu[k, a] - sens[3 + a] - sens[15 + a]) * dt / (1.0 + sens[9 + a])
            if i_gm >= 0:
                dg = math.exp(-dt * inv_tau[0])
                da = math.exp(-dt * inv_tau[1])
                for a in range(3):
                    sens[12 + a] *= dg
                    sens[15 + a] *= da
            extrap = 0.0 if k - 1 == k0 else 0.5 * dt / (t[k - 1] - t[k - 2])
            _kernels.strapdown_step(x, xp, dth_c, dv_c, dth_p, dv_p, dt, extrap, xn)
            for a in range(10):
                xp[a] = x[a]
                x[a] = xn[a]
            for a in range(3):
                dth_p[a] = dth_c[a]
                dv_p[a] = dv_c[a]
                fsum[a] += dv_c[a]
                wsum[a] += dth_c[a]
                w_b[a] = dth_c[a] / dt
            t_acc += dt
            steps += 1
        has_meas = im < n_meas and m_k[im] == k
        flag = flags[k]
        is_node = (flag & FLAG_NODE) != 0 or has_meas or k == k0
        is_out = (flag & FLAG_OUTPUT) != 0
        # ---- covariance propagation: Phi = I + F T + (F T)^2 / 2, trapezoidal Q_d ------------
        if steps > 0 and (steps >= prop_steps or has_meas or is_node or is_out):
            _kernels.dcm_from_quat_into(x[6:10], c_nb)
            for a in range(3):
                fm[a] = fsum[a] / t_acc
                wm[a] = wsum[a] / t_acc
            fill_f_matrix(x[0], x[2], x[3:6], c_nb, fm, 0.0, 0.0, f15)
            for a in range(15):
                for b in range(15):
                    ff[a, b] = f15[a, b] * t_acc
            if i_gm >= 0:
                for a in range(3):
                    for b in range(3):
                        ff[a, i_gm + b] = -c_nb[a, b] * t_acc
                        ff[3 + a, i_gm + 3 + b] = c_nb[a, b] * t_acc
                    ff[i_gm + a, i_gm + a] = -inv_tau[0] * t_acc
                    ff[i_gm + 3 + a, i_gm + 3 + a] = -inv_tau[1] * t_acc
            if i_sf >= 0:
                for a in range(3):
                    for b in range(3):
                        ff[a, i_sf + b] = -c_nb[a, b] * wm[b] * t_acc
                        ff[3 + a, i_sf + 3 + b] = c_nb[a, b] * fm[b] * t_acc
            phi = eye + ff + 0.5 * np.dot(ff, ff)
            pq = np.dot(np.dot(phi, qc), phi.T)
            p = np.dot(np.dot(phi, p), phi.T) + (0.5 * t_acc) * (pq + qc)
            p = 0.5 * (p + p.T)
            phi_acc = np.dot(phi, phi_acc)
            fsum[:] = 0.0
            wsum[:] = 0.0
            t_acc = 0.0
            steps = 0
        if is_node:
            node_pp[i_node] = p
        dx_tot[:] = 0.0
        # ---- measurement updates (predicted minus measured = H dx + noise) ---------------------
        while im < n_meas and m_k[im] == k:
            kind = m_type[im]
            _kernels.dcm_from_quat_into(x[6:10], c_nb)
            for a in range(3):
                cl[a] = c_nb[a, 0] * lever[0] + c_nb[a, 1] * lever[1] + c_nb[a, 2] * lever[2]
            lat, h = x[0], x[2]
            wie, wen = _kernels.nav_rates(lat, h, x[3], x[4])
            win = np.array([wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2]])
            cwl = np.dot(c_nb, np.cross(w_b, lever))
            wcl = np.cross(win, cl)
            v_ant = np.empty(3)
            for a in range(3):
                v_ant[a] = x[3 + a] + cwl[a] - wcl[a]
            h_mat[:, :] = 0.0
            if kind == MEAS_POSITION:
                r_m, r_n = _kernels._radii(lat)
                d0 = (m_z[im, 0] - lat) * (r_m + h)
                d1 = (m_z[im, 1] - x[1]) * (r_n + h) * math.cos(lat)
                d2 = -(m_z[im, 2] - h)
                dz[0] = cl[0] - d0 + v_ant[0] * m_dt[im]
                dz[1] = cl[1] - d1 + v_ant[1] * m_dt[im]
                dz[2] = cl[2] - d2 + v_ant[2] * m_dt[im]
                _skew_into(cl, h_mat, 0, 0, 1.0)
                for a in range(3):
                    h_mat[a, 6 + a] = 1.0
                if i_l >= 0:
                    for a in range(3):
                        for b in range(3):
                            h_mat[a, i_l + b] = c_nb[a, b]
            else:  # velocity or ZUPT (z = 0)
                for a in range(3):
                    dz[a] = v_ant[a] - m_z[im, a]
                _skew_into(cwl, h_mat, 0, 0, 1.0)
                for a in range(3):
                    h_mat[a, 3 + a] = 1.0
                _skew_into(lever, sl, 0, 0, 1.0)
                csl = np.dot(c_nb, sl)
                for a in range(3):
                    for b in range(3):
                        h_mat[a, 9 + b] = -csl[a, b]  # -C [l x] (gyro bias)
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
            ph = np.dot(p, h_mat.T)  # (n, 3)
            s_full = np.dot(h_mat, ph) + m_r[im]
            for a in range(3):
                for b in range(3):
                    s_mat[a, b] = s_full[a, b]
            nis = math.inf
            if _inv3(s_mat, s_inv):
                nis = 0.0
                for a in range(3):
                    for b in range(3):
                        nis += dz[a] * s_inv[a, b] * dz[b]
            m_nis[im] = nis
            for a in range(3):
                m_dz[im, a] = dz[a]
            status = 0
            if not (nis <= gate):
                if kind == MEAS_ZUPT or not (t[k] - t_ok[kind] > reset_after_s):
                    m_status[im] = 1
                    im += 1
                    continue
                # every GNSS record of this kind gated for reset_after_s: the filter, not GNSS,
                # has lost its way. Re-initialise the position (velocity) block from this
                # record (uncorrelated, variance dz^2 + R) and accept it ungated.
                status = 2
                blk = 6 if kind == MEAS_POSITION else 3
                for a in range(3):
                    for b in range(n):
                        p[blk + a, b] = 0.0
                        p[b, blk + a] = 0.0
                    p[blk + a, blk + a] = dz[a] * dz[a] + m_r[im, a, a]
                ph = np.dot(p, h_mat.T)
                s_full = np.dot(h_mat, ph) + m_r[im]
                for a in range(3):
                    for b in range(3):
                        s_mat[a, b] = s_full[a, b]
                if not _inv3(s_mat, s_inv):
                    m_status[im] = 1
                    im += 1
                    continue
            t_ok[kind] = t[k]
            m_status[im] = status
            kg = np.dot(ph, s_inv)  # (n, 3)
            dxk = np.dot(kg, dz)
            ikh = eye - np.dot(kg, h_mat)
            p = np.dot(np.dot(ikh, p), ikh.T) + np.dot(np.dot(kg, m_r[im]), kg.T)  # Joseph
            p = 0.5 * (p + p.T)
            # ---- closed-loop feedback, error state reset to zero ---------------------------
            x_old0, x_old1, x_old2 = x[0], x[1], x[2]
            smoother.apply_correction(x, dxk)
            xp[0] += x[0] - x_old0
            xp[1] += x[1] - x_old1
            xp[2] += x[2] - x_old2
            for a in range(3):
                xp[3 + a] -= dxk[3 + a]
                sens[a] += dxk[9 + a]
                sens[3 + a] += dxk[12 + a]
                if i_gm >= 0:
                    sens[12 + a] += dxk[i_gm + a]
                    sens[15 + a] += dxk[i_gm + 3 + a]
                if i_sf >= 0:
                    sens[6 + a] += dxk[i_sf + a]
                    sens[9 + a] += dxk[i_sf + 3 + a]
                if i_l >= 0:
                    lever[a] -= dxk[i_l + a]
            for a in range(n):
                dx_tot[a] += dxk[a]
            im += 1
        if is_node:
            node_k[i_node] = k
            node_pu[i_node] = p
            node_phi[i_node] = phi_acc
            node_dx[i_node] = dx_tot
            phi_acc = np.eye(n)
            i_node += 1
        if is_out:
            out_x[i_out] = x
            for a in range(n):
                out_diag[i_out, a] = p[a, a]
            for blk in range(3):
                for a in range(3):
                    for b in range(3):
                        out_blk[i_out, blk, a, b] = p[3 * blk + a, 3 * blk + b]
            for a in range(12):
                out_sens[i_out, a] = sens[a]
            for a in range(6):  # total bias = constant + Gauss-Markov, and its variance
                out_bvar[i_out, a] = p[9 + a, 9 + a]
                if i_gm >= 0:
                    out_sens[i_out, a] += sens[12 + a]
                    out_bvar[i_out, a] += p[i_gm + a, i_gm + a] + 2.0 * p[9 + a, i_gm + a]
            for a in range(3):
                out_lever[i_out, a] = lever[a]
            i_out += 1
    return i_node, i_out
