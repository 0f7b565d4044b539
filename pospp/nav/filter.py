"""Algorithm A: closed-loop error-state INS/GNSS Kalman filter and its RTS smoother.

Frames and units: body FRD (b), navigation NED (n), SI and radians; GNSS antenna (a) at the
lever arm l_b (body FRD, m) from the IMU. Error state (15, or 18 with the lever arm), computed
minus true, as in :mod:`pospp.nav.error_model` and :mod:`pospp.nav.smoother`::

    dx = [phi_n, dv_n, dr_n, db_g, db_a (, dl_b)]

Mechanization: the one strapdown kernel (:func:`pospp.nav._kernels.strapdown_step`) on the IMU
increments minus the current bias estimates. Closed loop: after every GNSS update the estimate
is fed back (position, velocity, C_nb <- (I + [phi x]) C_nb, biases accumulated, lever arm) and
the error state reset to zero.

Covariance propagation at a coarser rate than the IMU (every ``propagation_interval_s``, and at
every measurement, output and smoother node epoch): F from :func:`error_model.fill_f_matrix`
with the mean specific force over the interval T, Phi = I + F T + F^2 T^2 / 2,
Q_d = (Phi Q_c Phi^T + Q_c) T / 2 with Q_c = diag(ARW^2 I, VRW^2 I, 0, q_bg I, q_ba I (, 0)).

Measurements (predicted minus measured, = H dx + noise)::

    position:  C l + [(C l) x] phi + dr_n + C dl                                 (NED m)
               z = antenna fix relative to the nominal IMU position, moved to the IMU epoch
               by the antenna velocity when the fix time falls between IMU epochs
    velocity:  v_a = v + C (w_ib_b x l) - w_in x (C l)
               H = [[(C (w x l)) x], I, 0, -C [l x], 0 (, C [w x] - [w_in x] C)]
    ZUPT:      the velocity model with z = 0, over the detected initial static period

Each update is gated by its normalised innovation squared (NIS, 3 dof) against the chi-square
quantile ``gate_probability``; rejected measurements are reported with time and reason, as are
GNSS records refused on entry (non-finite values, covariance not positive definite or absurdly
large, duplicate times, no IMU epoch nearby). Reported covariances are floored at
``pos_sigma_floor_m`` / ``vel_sigma_floor_mps`` per axis.

Outputs are produced at ``output_rate_hz`` (IMU epochs nearest the multiples of 1 / rate in t_s;
``None`` = every IMU epoch): the forward solution with sigmas, and the smoothed one (nominal
corrected by the RTS error estimate interpolated between nodes, see :mod:`pospp.nav.smoother`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2

from pospp import rotation
from pospp.nav import _kernels, smoother
from pospp.nav.alignment import AlignmentOptions, AlignmentResult, align
from pospp.nav.error_model import fill_f_matrix
from pospp.nav.strapdown import Trajectory
from pospp.nav.tuning import ImuTuning, NoiseParameters, tuning_preset

MEAS_POSITION, MEAS_VELOCITY, MEAS_ZUPT = 0, 1, 2
MEAS_KINDS = ("position", "velocity", "zupt")
FLAG_NODE, FLAG_OUTPUT = 1, 2


# =============================================================================================
# Data classes
# =============================================================================================
@dataclass(frozen=True)
class FilterOptions:
    """Settings of algorithm A other than the IMU tuning (units in the names)."""

    propagation_interval_s: float = 0.1
    smoother_node_interval_s: float = 1.0
    pos_sigma_floor_m: float = 0.01
    vel_sigma_floor_mps: float = 0.005
    max_pos_sigma_m: float = 100.0
    max_vel_sigma_mps: float = 10.0
    gate_probability: float = 0.9999
    use_velocity: bool = True
    zupt: bool = True
    zupt_sigma_mps: float = 0.01
    zupt_interval_s: float = 1.0
    lever_arm_sigma_m: float = 0.5
    max_gnss_imu_offset_s: float = 0.05
    smoother: bool = True
    alignment: AlignmentOptions = field(default_factory=AlignmentOptions)


@dataclass(frozen=True)
class GnssRejection:
    """A GNSS (or pseudo-) measurement that was not used, and why."""

    time_ns: int
    t_s: float
    kind: str
    """"position", "velocity" or "zupt"."""
    reason: str
    value: float = math.nan
    """The offending quantity (NIS for the gate, sigma for covariance checks), else NaN."""


@dataclass(frozen=True)
class NavSolution:
    """Navigation solution with its uncertainty at N output epochs (time-major arrays).

    Attitude sigmas: ``att_sigma_ned_rad`` of the misalignment phi (NED), and
    ``rpy_sigma_rad`` of [roll, pitch, yaw] mapped by d(rpy) = -E^-1 phi, where E maps Euler
    angle rates to the NED rotation rate (z-y-x).
    """

    time_ns: NDArray
    t_s: NDArray
    lat_rad: NDArray
    lon_rad: NDArray
    height_m: NDArray
    v_n_mps: NDArray
    q_nb: NDArray
    pos_sigma_ned_m: NDArray
    vel_sigma_ned_mps: NDArray
    att_sigma_ned_rad: NDArray
    rpy_sigma_rad: NDArray
    pos_cov_ned_m2: NDArray
    vel_cov_ned_m2ps2: NDArray
    att_cov_ned_rad2: NDArray

    def __len__(self) -> int:
        return self.t_s.shape[0]

    @property
    def rpy_rad(self) -> NDArray:
        """[roll, pitch, yaw] (rad), yaw in [0, 2 pi)."""
        return rotation.euler_from_quat(self.q_nb)

    @property
    def trajectory(self) -> Trajectory:
        """The states as a :class:`pospp.nav.strapdown.Trajectory`."""
        return Trajectory(self.t_s, self.lat_rad, self.lon_rad, self.height_m, self.v_n_mps,
                          self.q_nb)


@dataclass(frozen=True)
class BiasHistory:
    """Sensor bias estimates (body FRD, measured = true + bias) with 1-sigma at output epochs."""

    t_s: NDArray
    gyro_b_radps: NDArray
    gyro_sigma_b_radps: NDArray
    accel_b_mps2: NDArray
    accel_sigma_b_mps2: NDArray


@dataclass(frozen=True)
class LeverArmEstimate:
    """Antenna lever arm (body FRD, m): the configured value or the smoothed estimate."""

    lever_b_m: NDArray
    sigma_b_m: NDArray
    estimated: bool


@dataclass(frozen=True)
class FilterResult:
    """Everything algorithm A produces.

    ``smoothed`` and ``smoothed_biases`` are None when the smoother is disabled.
    """

    forward: NavSolution
    smoothed: NavSolution | None
    forward_biases: BiasHistory
    smoothed_biases: BiasHistory | None
    rejections: tuple[GnssRejection, ...]
    lever_arm: LeverArmEstimate
    alignment: AlignmentResult
    n_updates: dict[str, int]


# =============================================================================================
# Compiled forward filter
# =============================================================================================
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
def _forward_kernel(
    t, dth, dvel, k0, x0, p0, lever0, flags, m_k, m_type, m_z, m_r, m_dt, prop_steps, q_diag,
    gate, m_status, m_nis, out_x, out_diag, out_blk, out_bias, out_lever, out_node,
    node_k, node_pp, node_pu, node_phi, node_dx,
):
    n = p0.shape[0]
    est_lever = n == 18
    n_ep = t.shape[0]
    n_meas = m_k.shape[0]
    x = x0.copy()
    xp = x0.copy()
    xn = np.empty(10)
    bg = np.zeros(3)
    ba = np.zeros(3)
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
    t_acc = 0.0
    steps = 0
    dth_p = np.zeros(3)
    dv_p = np.zeros(3)
    dth_c = np.zeros(3)
    dv_c = np.zeros(3)
    w_b = np.zeros(3)
    c_nb = np.empty((3, 3))
    h_mat = np.zeros((3, n))
    s_mat = np.empty((3, 3))
    s_inv = np.empty((3, 3))
    dz = np.empty(3)
    cl = np.empty(3)
    dx_tot = np.zeros(n)
    im = 0
    while im < n_meas and m_k[im] < k0:
        m_status[im] = 3  # before the filter start
        im += 1
    i_out = 0
    i_node = 0
    for k in range(k0, n_ep):
        if k > k0:
            j = k - 1
            dt = t[k] - t[k - 1]
            for a in range(3):
                dth_c[a] = dth[j, a] - bg[a] * dt
                dv_c[a] = dvel[j, a] - ba[a] * dt
            extrap = 0.0 if k - 1 == k0 else 0.5 * dt / (t[k - 1] - t[k - 2])
            _kernels.strapdown_step(x, xp, dth_c, dv_c, dth_p, dv_p, dt, extrap, xn)
            for a in range(10):
                xp[a] = x[a]
                x[a] = xn[a]
            for a in range(3):
                dth_p[a] = dth_c[a]
                dv_p[a] = dv_c[a]
                fsum[a] += dv_c[a]
                w_b[a] = dth_c[a] / dt
            t_acc += dt
            steps += 1
        has_meas = im < n_meas and m_k[im] == k
        flag = flags[k]
        is_node = (flag & 1) != 0 or has_meas or k == k0
        is_out = (flag & 2) != 0
        # ---- covariance propagation ------------------------------------------------------
        if steps > 0 and (steps >= prop_steps or has_meas or is_node or is_out):
            _kernels.dcm_from_quat_into(x[6:10], c_nb)
            fm = fsum / t_acc
            fill_f_matrix(x[0], x[2], x[3:6], c_nb, fm, 0.0, 0.0, f15)
            for a in range(15):
                for b in range(15):
                    ff[a, b] = f15[a, b] * t_acc
            phi = eye + ff + 0.5 * np.dot(ff, ff)
            pq = np.dot(np.dot(phi, qc), phi.T)
            p = np.dot(np.dot(phi, p), phi.T) + 0.5 * t_acc * (pq + qc)
            p = 0.5 * (p + p.T)
            phi_acc = np.dot(phi, phi_acc)
            fsum[:] = 0.0
            t_acc = 0.0
            steps = 0
        if is_node:
            node_pp[i_node] = p
        dx_tot[:] = 0.0
        # ---- measurement updates -----------------------------------------------------------
        while im < n_meas and m_k[im] == k:
            kind = m_type[im]
            _kernels.dcm_from_quat_into(x[6:10], c_nb)
            for a in range(3):
                cl[a] = c_nb[a, 0] * lever[0] + c_nb[a, 1] * lever[1] + c_nb[a, 2] * lever[2]
            lat, h = x[0], x[2]
            wie, wen = _kernels.nav_rates(lat, h, x[3], x[4])
            win = np.array([wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2]])
            wxl = np.cross(w_b, lever)
            cwl = np.dot(c_nb, wxl)
            v_ant = np.empty(3)
            wcl = np.cross(win, cl)
            for a in range(3):
                v_ant[a] = x[3 + a] + cwl[a] - wcl[a]
            h_mat[:, :] = 0.0
            if kind == 0:
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
                if est_lever:
                    for a in range(3):
                        for b in range(3):
                            h_mat[a, 15 + b] = c_nb[a, b]
            else:
                for a in range(3):
                    dz[a] = v_ant[a] - m_z[im, a]
                _skew_into(cwl, h_mat, 0, 0, 1.0)
                for a in range(3):
                    h_mat[a, 3 + a] = 1.0
                # -C [l x] for the gyro bias
                sl = np.zeros((3, 3))
                _skew_into(lever, sl, 0, 0, 1.0)
                csl = np.dot(c_nb, sl)
                for a in range(3):
                    for b in range(3):
                        h_mat[a, 9 + b] = -csl[a, b]
                if est_lever:
                    sw = np.zeros((3, 3))
                    _skew_into(w_b, sw, 0, 0, 1.0)
                    swin = np.zeros((3, 3))
                    _skew_into(win, swin, 0, 0, 1.0)
                    hl = np.dot(c_nb, sw) - np.dot(swin, c_nb)
                    for a in range(3):
                        for b in range(3):
                            h_mat[a, 15 + b] = hl[a, b]
            ph = np.dot(p, h_mat.T)  # (n, 3)
            s_full = np.dot(h_mat, ph) + m_r[im]
            for a in range(3):
                for b in range(3):
                    s_mat[a, b] = s_full[a, b]
            ok = _inv3(s_mat, s_inv)
            nis = math.inf
            if ok:
                nis = 0.0
                for a in range(3):
                    for b in range(3):
                        nis += dz[a] * s_inv[a, b] * dz[b]
            m_nis[im] = nis
            if not (nis <= gate):
                m_status[im] = 1
                im += 1
                continue
            m_status[im] = 0
            kg = np.dot(ph, s_inv)  # (n, 3)
            dxk = np.dot(kg, dz)
            ikh = eye - np.dot(kg, h_mat)
            p = np.dot(np.dot(ikh, p), ikh.T) + np.dot(np.dot(kg, m_r[im]), kg.T)
            p = 0.5 * (p + p.T)
            # ---- feedback (closed loop) ----------------------------------------------------
            x_old0, x_old1, x_old2 = x[0], x[1], x[2]
            smoother.apply_correction(x, dxk)
            xp[0] += x[0] - x_old0
            xp[1] += x[1] - x_old1
            xp[2] += x[2] - x_old2
            for a in range(3):
                xp[3 + a] -= dxk[3 + a]
                bg[a] += dxk[9 + a]
                ba[a] += dxk[12 + a]
                if est_lever:
                    lever[a] -= dxk[15 + a]
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
            for a in range(3):
                out_bias[i_out, a] = bg[a]
                out_bias[i_out, 3 + a] = ba[a]
                out_lever[i_out, a] = lever[a]
            out_node[i_out] = i_node - 1
            i_out += 1
    return i_node, i_out


# =============================================================================================
# Input handling
# =============================================================================================
def _field(obj, names: tuple[str, ...], index: int):
    if isinstance(obj, tuple | list):
        return obj[index]
    for name in names:
        if hasattr(obj, name):
            return getattr(obj, name)
    raise TypeError(f"expected an object with attribute {names[0]!r} or a tuple, got {type(obj)}")


def _noise(tuning: ImuTuning | NoiseParameters | str) -> NoiseParameters:
    if isinstance(tuning, str):
        return tuning_preset(tuning).noise()
    if isinstance(tuning, ImuTuning):
        return tuning.noise()
    if isinstance(tuning, NoiseParameters):
        return tuning
    raise TypeError(f"tuning: expected ImuTuning, NoiseParameters or a preset name, got {tuning!r}")


def _screen(
    kind: str, time_ns: NDArray, values: NDArray, cov: NDArray, floor: float, max_sigma: float,
    t_lo_s: float, t_hi_s: float, epoch_ns: int, rejections: list[GnssRejection],
) -> NDArray:
    """Entry checks of GNSS records; returns the indices kept (sorted by time), floors cov."""
    n = time_ns.shape[0]
    t_s = (time_ns - np.int64(epoch_ns)).astype(float) * 1e-9
    reason = np.full(n, "", dtype=object)
    value = np.full(n, math.nan)
    bad_val = ~np.isfinite(values).all(axis=1)
    reason[bad_val] = "non-finite value"
    bad_cov = ~np.isfinite(cov).all(axis=(1, 2)) & (reason == "")
    reason[bad_cov] = "non-finite covariance"
    fin = reason == ""
    diag = np.full((n, 3), np.nan)
    diag[fin] = np.diagonal(cov[fin], axis1=1, axis2=2)
    nonpos = fin & ~(diag > 0.0).all(axis=1)
    reason[nonpos] = "covariance not positive (zero or negative variance)"
    value[nonpos] = np.nanmin(np.where(np.isfinite(diag), diag, np.inf), axis=1)[nonpos]
    ok = reason == ""
    if ok.any():
        eig_min = np.full(n, np.inf)
        sym_cov = 0.5 * (cov[ok] + np.swapaxes(cov[ok], 1, 2))
        eig_min[ok] = np.linalg.eigvalsh(sym_cov)[:, 0]
        not_pd = ok & (eig_min <= 0.0)
        reason[not_pd] = "covariance not positive definite"
        value[not_pd] = eig_min[not_pd]
    big = (reason == "") & (np.sqrt(np.nanmax(np.where(np.isfinite(diag), diag, 0.0), axis=1))
                            > max_sigma)
    reason[big] = f"covariance too large (sigma > {max_sigma:g})"
    value[big] = np.sqrt(np.nanmax(diag[big], axis=1)) if big.any() else value[big]
    outside = (reason == "") & ((t_s < t_lo_s) | (t_s > t_hi_s))
    reason[outside] = "outside the IMU time span"
    # duplicates: the first record of a time stamp is kept, later ones are rejected
    order = np.argsort(time_ns, kind="stable")
    cand = order[reason[order] == ""]
    dup = np.zeros(n, dtype=bool)
    if cand.shape[0] > 1:
        same = np.diff(time_ns[cand]) == 0
        dup[cand[1:][same]] = True
    reason[dup] = "duplicate time"
    for i in np.flatnonzero(reason != ""):
        rejections.append(GnssRejection(int(time_ns[i]), float(t_s[i]), kind, str(reason[i]),
                                        float(value[i])))
    keep = cand[~dup[cand]]
    c = cov[keep]
    d = np.diagonal(c, axis1=1, axis2=2)
    add = np.clip(floor**2 - d, 0.0, None)
    c = c + add[:, :, None] * np.eye(3)[None]
    cov[keep] = 0.5 * (c + np.swapaxes(c, 1, 2))
    return keep


def _grid_epochs(t: NDArray, k0: int, interval_s: float | None) -> NDArray:
    """IMU epoch indices (>= k0, unique) nearest the multiples of ``interval_s`` in t_s."""
    if interval_s is None:
        return np.arange(k0, t.shape[0])
    g0 = math.ceil(t[k0] / interval_s - 1e-9)
    g1 = math.floor(t[-1] / interval_s + 1e-9)
    grid = np.arange(g0, g1 + 1) * interval_s
    k = np.clip(np.searchsorted(t, grid), 1, t.shape[0] - 1)
    k = np.where(np.abs(t[k - 1] - grid) <= np.abs(t[k] - grid), k - 1, k)
    return np.unique(np.maximum(k, k0))


def _rpy_cov(q_nb: NDArray, att_cov: NDArray) -> NDArray:
    """Covariance of [roll, pitch, yaw] errors from the phi covariance (d rpy = -E^-1 phi)."""
    rpy = rotation.euler_from_quat(q_nb)
    cz, sz = np.cos(rpy[:, 2]), np.sin(rpy[:, 2])
    cy, sy = np.cos(rpy[:, 1]), np.sin(rpy[:, 1])
    e = np.zeros((q_nb.shape[0], 3, 3))
    # columns: Rz Ry e_x (roll axis), Rz e_y (pitch axis), e_z (yaw axis), all in NED
    e[:, 0, 0] = cz * cy
    e[:, 1, 0] = sz * cy
    e[:, 2, 0] = -sy
    e[:, 0, 1] = -sz
    e[:, 1, 1] = cz
    e[:, 2, 2] = 1.0
    e_inv = np.linalg.inv(e)
    return e_inv @ att_cov @ np.swapaxes(e_inv, 1, 2)


def _solution(time_ns, t_s, states, diag, blocks) -> NavSolution:
    att_cov, vel_cov, pos_cov = blocks
    q = states[:, 6:10]
    rpy_cov = _rpy_cov(q, att_cov)
    return NavSolution(
        time_ns=time_ns, t_s=t_s, lat_rad=states[:, 0].copy(), lon_rad=states[:, 1].copy(),
        height_m=states[:, 2].copy(), v_n_mps=states[:, 3:6].copy(), q_nb=q.copy(),
        pos_sigma_ned_m=np.sqrt(diag[:, 6:9]), vel_sigma_ned_mps=np.sqrt(diag[:, 3:6]),
        att_sigma_ned_rad=np.sqrt(diag[:, 0:3]),
        rpy_sigma_rad=np.sqrt(np.clip(np.diagonal(rpy_cov, axis1=1, axis2=2), 0.0, None)),
        pos_cov_ned_m2=pos_cov, vel_cov_ned_m2ps2=vel_cov, att_cov_ned_rad2=att_cov,
    )


# =============================================================================================
# Top level
# =============================================================================================
def run_integrated_navigation(
    imu,
    gnss_fixes,
    gnss_velocities,
    tuning: ImuTuning | NoiseParameters | str,
    *,
    epoch_ns: int,
    lever_arm_b_m: ArrayLike | None = None,
    estimate_lever_arm: bool = False,
    output_rate_hz: float | None = 10.0,
    options: FilterOptions = FilterOptions(),
) -> FilterResult:
    """Forward closed-loop EKF and RTS smoother over a whole IMU/GNSS record (algorithm A).

    Parameters
    ----------
    imu : ImuSamples-like or tuple
        ``time_ns`` (N,) int64, ``w_ib_b_radps`` (N, 3), ``f_ib_b_mps2`` (N, 3): mean rate and
        specific force over the interval ending at each stamp, body FRD.
    gnss_fixes : GnssFixes-like or tuple
        ``time_ns`` (M,), ``lat_rad``, ``lon_rad``, ``height_m`` (M,), ``pos_cov_ned_m2``
        (M, 3, 3): antenna positions (WGS-84) with their NED covariance.
    gnss_velocities : GnssVelocities-like, tuple or None
        ``time_ns`` (V,), ``v_n_mps`` (V, 3), ``vel_cov_ned_m2ps2`` (V, 3, 3): antenna velocity.
    tuning : ImuTuning, NoiseParameters or preset name
    epoch_ns : int
        Reference epoch: t_s = (time_ns - epoch_ns) * 1e-9.
    lever_arm_b_m : array_like, shape (3,), optional
        Antenna position in body FRD [m] (known value, or the initial guess when estimated).
    estimate_lever_arm : bool
        Add the three lever-arm states (18-state filter).
    output_rate_hz : float or None
        Rate of the output epochs (None: every IMU epoch).
    options : FilterOptions

    Returns
    -------
    FilterResult
    """
    noise = _noise(tuning)
    imu_t_ns = np.asarray(_field(imu, ("time_ns",), 0), dtype=np.int64)
    w = np.asarray(_field(imu, ("w_ib_b_radps",), 1), dtype=float)
    f = np.asarray(_field(imu, ("f_ib_b_mps2",), 2), dtype=float)
    n_imu = imu_t_ns.shape[0]
    if n_imu < 3 or w.shape != (n_imu, 3) or f.shape != (n_imu, 3):
        raise ValueError(f"imu: expected N >= 3 stamps with (N, 3) rates, got {imu_t_ns.shape}, "
                         f"{w.shape}, {f.shape}")
    if not (np.isfinite(w).all() and np.isfinite(f).all()):
        k = int(np.argmax(~(np.isfinite(w).all(axis=1) & np.isfinite(f).all(axis=1))))
        raise ValueError(f"imu: non-finite rate in sample {k} (time_ns {imu_t_ns[k]})")
    if (np.diff(imu_t_ns) <= 0).any():
        k = int(np.argmax(np.diff(imu_t_ns) <= 0)) + 1
        raise ValueError(f"imu: time not increasing at sample {k}: {imu_t_ns[k]} after "
                         f"{imu_t_ns[k - 1]}")
    t = (imu_t_ns - np.int64(epoch_ns)).astype(float) * 1e-9
    dt = np.diff(t)
    dth = np.ascontiguousarray(w[1:] * dt[:, None])
    dvl = np.ascontiguousarray(f[1:] * dt[:, None])

    rejections: list[GnssRejection] = []
    fix_t_ns = np.asarray(_field(gnss_fixes, ("time_ns",), 0), dtype=np.int64)
    fix_val = np.column_stack([
        np.asarray(_field(gnss_fixes, ("lat_rad",), 1), dtype=float),
        np.asarray(_field(gnss_fixes, ("lon_rad",), 2), dtype=float),
        np.asarray(_field(gnss_fixes, ("height_m",), 3), dtype=float),
    ]) if fix_t_ns.shape[0] else np.zeros((0, 3))
    fix_cov = np.array(_field(gnss_fixes, ("pos_cov_ned_m2",), 4), dtype=float).reshape(-1, 3, 3)
    keep_f = _screen("position", fix_t_ns, fix_val, fix_cov, options.pos_sigma_floor_m,
                     options.max_pos_sigma_m, t[0], t[-1], epoch_ns, rejections)
    if gnss_velocities is not None and options.use_velocity:
        vel_t_ns = np.asarray(_field(gnss_velocities, ("time_ns",), 0), dtype=np.int64)
        vel_val = np.asarray(_field(gnss_velocities, ("v_n_mps",), 1), dtype=float).reshape(-1, 3)
        vel_cov = np.array(_field(gnss_velocities, ("vel_cov_ned_m2ps2",), 2),
                           dtype=float).reshape(-1, 3, 3)
        keep_v = _screen("velocity", vel_t_ns, vel_val, vel_cov, options.vel_sigma_floor_mps,
                         options.max_vel_sigma_mps, t[0], t[-1], epoch_ns, rejections)
    else:
        vel_t_ns = np.zeros(0, dtype=np.int64)
        vel_val = np.zeros((0, 3))
        vel_cov = np.zeros((0, 3, 3))
        keep_v = np.zeros(0, dtype=int)

    lever0 = np.zeros(3) if lever_arm_b_m is None else np.asarray(lever_arm_b_m, dtype=float)
    fix_ts = (fix_t_ns[keep_f] - np.int64(epoch_ns)).astype(float) * 1e-9
    vel_ts = (vel_t_ns[keep_v] - np.int64(epoch_ns)).astype(float) * 1e-9
    al = align(t, np.vstack([w[:1], w[1:]]), f, fix_ts, fix_val[keep_f], fix_cov[keep_f],
               vel_ts, vel_val[keep_v], noise, lever_arm_b_m=lever0, options=options.alignment)
    k0 = al.k_start

    # ---- measurement list ------------------------------------------------------------------
    types, times, zs, rs, src = [], [], [], [], []
    types.append(np.full(keep_f.shape[0], MEAS_POSITION))
    times.append(fix_ts)
    zs.append(fix_val[keep_f])
    rs.append(fix_cov[keep_f])
    src.append(fix_t_ns[keep_f])
    types.append(np.full(keep_v.shape[0], MEAS_VELOCITY))
    times.append(vel_ts)
    zs.append(vel_val[keep_v])
    rs.append(vel_cov[keep_v])
    src.append(vel_t_ns[keep_v])
    if options.zupt and al.method == "static" and al.static_end_s is not None:
        zt = np.arange(t[0], al.static_end_s - options.alignment.window_s,
                       options.zupt_interval_s)
        zt = zt[zt > t[0]]
        types.append(np.full(zt.shape[0], MEAS_ZUPT))
        times.append(zt)
        zs.append(np.zeros((zt.shape[0], 3)))
        rs.append(np.tile(np.eye(3) * options.zupt_sigma_mps**2, (zt.shape[0], 1, 1)))
        src.append(np.int64(epoch_ns) + np.round(zt * 1e9).astype(np.int64))
    m_type = np.concatenate(types).astype(np.int64)
    m_t = np.concatenate(times)
    m_z = np.ascontiguousarray(np.concatenate(zs))
    m_r = np.ascontiguousarray(np.concatenate(rs))
    m_src = np.concatenate(src)
    k_near = np.clip(np.searchsorted(t, m_t), 1, t.shape[0] - 1)
    k_near = np.where(np.abs(t[k_near - 1] - m_t) <= np.abs(t[k_near] - m_t), k_near - 1, k_near)
    m_dt = m_t - t[k_near]
    far = np.abs(m_dt) > options.max_gnss_imu_offset_s
    for i in np.flatnonzero(far):
        rejections.append(GnssRejection(int(m_src[i]), float(m_t[i]), MEAS_KINDS[m_type[i]],
                                        "no IMU epoch within max_gnss_imu_offset_s",
                                        float(m_dt[i])))
    order = np.lexsort((m_type, k_near))
    order = order[~far[order]]
    m_type, m_t, m_z, m_r, m_src = m_type[order], m_t[order], m_z[order], m_r[order], m_src[order]
    m_k = k_near[order].astype(np.int64)
    m_dt = np.ascontiguousarray(m_dt[order])

    # ---- epochs: outputs and smoother nodes --------------------------------------------------
    flags = np.zeros(t.shape[0], dtype=np.int64)
    out_k = _grid_epochs(t, k0, None if output_rate_hz is None else 1.0 / output_rate_hz)
    flags[out_k] |= FLAG_OUTPUT
    node_grid = _grid_epochs(t, k0, options.smoother_node_interval_s)
    flags[node_grid] |= FLAG_NODE
    flags[t.shape[0] - 1] |= FLAG_NODE
    flags[m_k[m_k >= k0]] |= FLAG_NODE
    flags[k0] |= FLAG_NODE
    n_nodes = int(np.count_nonzero(flags[k0:] & FLAG_NODE))

    # ---- initial covariance and noise ---------------------------------------------------------
    n = 18 if estimate_lever_arm else 15
    p0_diag = np.concatenate([
        al.rpy_sigma_rad**2, al.vel_sigma_ned_mps**2, al.pos_sigma_ned_m**2,
        np.full(3, noise.gyro_bias_sigma_radps**2), np.full(3, noise.accel_bias_sigma_mps2**2),
        np.full(n - 15, options.lever_arm_sigma_m**2),
    ])
    p0 = np.diag(p0_diag)
    q_diag = np.concatenate([
        np.full(3, noise.gyro_arw_radpsqrts**2), np.full(3, noise.accel_vrw_mpspsqrts**2),
        np.zeros(3), np.full(3, noise.gyro_bias_psd_radps2ps),
        np.full(3, noise.accel_bias_psd_mps4ps), np.zeros(n - 15),
    ])
    dt_med = float(np.median(dt))
    prop_steps = max(1, int(round(options.propagation_interval_s / dt_med)))
    gate = float(chi2.ppf(options.gate_probability, 3))
    x0 = np.concatenate([[al.lat_rad, al.lon_rad, al.height_m], al.v_n_mps,
                         rotation.quat_from_euler(al.rpy_rad)])

    n_meas = m_k.shape[0]
    n_out = out_k.shape[0]
    m_status = np.full(n_meas, -1, dtype=np.int64)
    m_nis = np.full(n_meas, np.nan)
    out_x = np.empty((n_out, 10))
    out_diag = np.empty((n_out, n))
    out_blk = np.empty((n_out, 3, 3, 3))
    out_bias = np.empty((n_out, 6))
    out_lever = np.empty((n_out, 3))
    out_node = np.empty(n_out, dtype=np.int64)
    node_k = np.empty(n_nodes, dtype=np.int64)
    node_pp = np.empty((n_nodes, n, n))
    node_pu = np.empty((n_nodes, n, n))
    node_phi = np.empty((n_nodes, n, n))
    node_dx = np.empty((n_nodes, n))
    used_nodes, used_out = _forward_kernel(
        t, dth, dvl, k0, x0, p0, lever0.copy(), flags, m_k, m_type, m_z, m_r, m_dt, prop_steps,
        q_diag, gate, m_status, m_nis, out_x, out_diag, out_blk, out_bias, out_lever, out_node,
        node_k, node_pp, node_pu, node_phi, node_dx,
    )
    if used_nodes != n_nodes or used_out != n_out:
        raise RuntimeError(f"filter kernel: node/output count mismatch ({used_nodes} vs "
                           f"{n_nodes}, {used_out} vs {n_out})")
    for i in np.flatnonzero(m_status == 1):
        rejections.append(GnssRejection(int(m_src[i]), float(m_t[i]), MEAS_KINDS[m_type[i]],
                                        f"innovation gate (NIS > {gate:.2f})", float(m_nis[i])))
    for i in np.flatnonzero(m_status == 3):
        rejections.append(GnssRejection(int(m_src[i]), float(m_t[i]), MEAS_KINDS[m_type[i]],
                                        "before the filter start (alignment)", math.nan))
    rejections.sort(key=lambda r: (r.time_ns, r.kind))
    n_updates = {kind: int(np.count_nonzero((m_status == 0) & (m_type == i)))
                 for i, kind in enumerate(MEAS_KINDS)}

    out_t = t[out_k]
    out_tns = imu_t_ns[out_k]
    fwd = _solution(out_tns, out_t, out_x, out_diag,
                    [out_blk[:, 0].copy(), out_blk[:, 1].copy(), out_blk[:, 2].copy()])
    fwd_bias = BiasHistory(out_t, out_bias[:, :3].copy(), np.sqrt(out_diag[:, 9:12]),
                           out_bias[:, 3:].copy(), np.sqrt(out_diag[:, 12:15]))
    lever_fwd = out_lever[-1].copy()
    lever_sig = np.sqrt(out_diag[-1, 15:18]) if estimate_lever_arm else np.zeros(3)
    smoothed = None
    sm_bias = None
    if options.smoother:
        e_plus, e_minus, p_s = smoother.rts_smooth(node_pp, node_pu, node_phi, node_dx)
        del node_pp, node_phi
        node_t = t[node_k]
        err = smoother.interpolate_errors(node_t, e_plus, e_minus, out_t)
        diag_s, blocks_s = smoother.interpolate_covariance_blocks(
            node_t, p_s, out_t, (slice(0, 3), slice(3, 6), slice(6, 9)))
        states_s = smoother.correct_states(out_x, np.ascontiguousarray(err))
        smoothed = _solution(out_tns, out_t, states_s, diag_s, blocks_s)
        sm_bias = BiasHistory(out_t, out_bias[:, :3] + err[:, 9:12], np.sqrt(diag_s[:, 9:12]),
                              out_bias[:, 3:] + err[:, 12:15], np.sqrt(diag_s[:, 12:15]))
        if estimate_lever_arm:
            lever_fwd = out_lever[0] - err[0, 15:18]
            lever_sig = np.sqrt(diag_s[0, 15:18])
    return FilterResult(
        forward=fwd, smoothed=smoothed, forward_biases=fwd_bias, smoothed_biases=sm_bias,
        rejections=tuple(rejections),
        lever_arm=LeverArmEstimate(lever_fwd, lever_sig, bool(estimate_lever_arm)),
        alignment=al, n_updates=n_updates,
    )


def enu_to_ned_covariance(cov_enu: ArrayLike) -> NDArray:
    """Rotate (..., 3, 3) ENU covariances to NED (swap E/N, negate U): T C T^T."""
    tm = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    return tm @ np.asarray(cov_enu, dtype=float) @ tm.T


__all__ = [
    "BiasHistory", "FilterOptions", "FilterResult", "GnssRejection", "LeverArmEstimate",
    "NavSolution", "enu_to_ned_covariance", "run_integrated_navigation",
]
