"""Algorithm A's error-state layout, initial covariance, process noise, and the forward pass's
arrays around the compiled kernel (docs/filter.md).

The 15 base states (:mod:`pospp.nav.error_model`: ``PHI``, ``DV``, ``DR``, ``BG``, ``BA``) are
followed by the optional blocks, in this order: Gauss-Markov gyro and accel biases (6), gyro and
accel scale factors (6), lever arm (3). Units SI and rad; variances of the NED blocks in NED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pospp import rotation
from pospp.distributions import chi2_ppf
from pospp.nav._filter_kernel import (
    FLAG_NODE,
    MEAS_KINDS,
    STATUS_BEFORE_START,
    STATUS_GATED,
    STATUS_RESET,
    STATUS_USED,
    forward_kernel,
)
from pospp.nav.alignment import AlignmentResult
from pospp.nav.error_model import BA, BG, DR, DV, I_BA, I_BG, N_NAV, N_STATES, PHI
from pospp.nav.filter_input import GnssRejection, MeasurementRecords, epoch_flags
from pospp.nav.smoother import (
    packed_size,
    rts_smooth,
    rts_smooth_replayed,
    smoother_gains,
    unpack_symmetric,
)
from pospp.nav.tuning import NoiseParameters
from pospp.units import t_s_from_time_ns

if TYPE_CHECKING:
    from pospp.nav.filter import FilterOptions

__all__ = ["ForwardArrays", "GainReplay", "Outcome", "StateLayout", "forward_pass",
           "gain_replay", "initial_covariance_and_noise", "record_outcomes",
           "smoothed_backward", "state_layout", "switch_epoch", "total_bias_map",
           "total_bias_variance"]


@dataclass(frozen=True)
class StateLayout:
    """Where the optional state blocks start (-1: absent) and the state count."""

    n: int
    i_gm: int
    i_sf: int
    i_l: int


def state_layout(gauss_markov: bool, scale_factors: bool, lever_arm: bool) -> StateLayout:
    n = N_STATES
    i_gm = i_sf = i_l = -1
    if gauss_markov:
        i_gm, n = n, n + 6
    if scale_factors:
        i_sf, n = n, n + 6
    if lever_arm:
        i_l, n = n, n + 3
    return StateLayout(n, i_gm, i_sf, i_l)


def initial_covariance_and_noise(lay: StateLayout, noise: NoiseParameters, al: AlignmentResult,
                                 lever_arm_sigma_m: float) -> tuple[NDArray, NDArray]:
    """Diagonal P0 and continuous-time noise PSD Q_c of the state layout (docs/filter.md)."""
    p0 = np.zeros(lay.n)
    q = np.zeros(lay.n)
    p0[PHI] = al.rpy_sigma_rad**2
    p0[DV] = al.vel_sigma_ned_mps**2
    p0[DR] = al.pos_sigma_ned_m**2
    q[PHI] = noise.gyro_arw_radpsqrts**2
    q[DV] = noise.accel_vrw_mpspsqrts**2
    if lay.i_gm >= 0:
        # constant part: no process noise; Gauss-Markov part: 2 sigma^2 / tau. A floor of
        # 1e-3 of the turn-on sigma keeps P invertible for the smoother when a sigma is 0.
        sg = max(noise.gyro_gm_sigma_radps, 1e-3 * noise.gyro_turn_on_sigma_radps, 1e-15)
        sa = max(noise.accel_gm_sigma_mps2, 1e-3 * noise.accel_turn_on_sigma_mps2, 1e-15)
        p0[BG] = max(noise.gyro_turn_on_sigma_radps, 1e-15) ** 2
        p0[BA] = max(noise.accel_turn_on_sigma_mps2, 1e-15) ** 2
        p0[lay.i_gm:lay.i_gm + 3] = sg**2
        p0[lay.i_gm + 3:lay.i_gm + 6] = sa**2
        q[lay.i_gm:lay.i_gm + 3] = 2.0 * sg**2 / noise.gyro_gm_tau_s
        q[lay.i_gm + 3:lay.i_gm + 6] = 2.0 * sa**2 / noise.accel_gm_tau_s
    else:
        p0[BG] = noise.gyro_bias_sigma_radps**2
        p0[BA] = noise.accel_bias_sigma_mps2**2
        q[BG] = noise.gyro_bias_psd_radps2ps
        q[BA] = noise.accel_bias_psd_mps4ps
    if lay.i_sf >= 0:
        p0[lay.i_sf:lay.i_sf + 3] = max(noise.gyro_sf_sigma, 1e-12) ** 2
        p0[lay.i_sf + 3:lay.i_sf + 6] = max(noise.accel_sf_sigma, 1e-12) ** 2
    if lay.i_l >= 0:
        p0[lay.i_l:lay.i_l + 3] = lever_arm_sigma_m**2
    return p0, q


def total_bias_map(lay: StateLayout) -> NDArray:
    """(6, n) matrix taking the error state to the total [gyro, accel] bias error."""
    tb = np.zeros((6, lay.n))
    tb[:, I_BG:I_BA + 3] = np.eye(6)
    if lay.i_gm >= 0:
        tb[:, lay.i_gm:lay.i_gm + 6] = np.eye(6)
    return tb


@dataclass(frozen=True)
class ForwardArrays:
    """The arrays the compiled forward pass filled (:mod:`pospp.nav._filter_kernel`).
    ``out_diag``, ``out_blk``, ``out_bvar`` (P at the outputs) have no rows in a pass without
    covariance outputs that records no gains (the re-runs: 20 MiB at 50 Hz on the 1.5 h
    flight, held by each realisation in flight)."""

    gate: float
    out_k: NDArray
    m_status: NDArray
    m_nis: NDArray
    m_dz: NDArray
    out_x: NDArray
    out_diag: NDArray
    out_blk: NDArray
    out_sens: NDArray
    out_bvar: NDArray
    out_lever: NDArray
    node_k: NDArray
    node_pp: NDArray
    """The nodes' predicted covariances, packed ((nodes, n (n + 1) / 2),
    :func:`pospp.nav.smoother.pack_symmetric`)."""
    node_pu: NDArray
    """Their updated covariances, packed likewise."""
    node_phi: NDArray
    """Phi from the node before, compact ((nodes, N_NAV + 1, n): its rows of the navigation
    errors and its diagonal, :func:`pospp.nav.smoother.unpack_transition_into`)."""
    node_dx: NDArray
    m_gain: NDArray
    """Each used record's Kalman gain (records, n, 3) when the pass stored them, else no
    rows."""
    m_sinv: NDArray
    """Each used record's S^-1 (records, 3, 3), likewise."""
    m_h: NDArray
    """Each used record's H (records, 3, n), likewise."""
    replayed: bool = False
    """Whether another pass's gains were replayed (:class:`GainReplay`)."""

    def without_nodes(self) -> ForwardArrays:
        """The same arrays with the smoother's nodes emptied (new empty arrays: a slice would
        keep the nodes' memory alive)."""
        def empty(a: NDArray) -> NDArray:
            return np.empty((0, *a.shape[1:]), a.dtype)

        return replace(self, node_k=empty(self.node_k), node_pp=empty(self.node_pp),
                       node_pu=empty(self.node_pu), node_phi=empty(self.node_phi),
                       node_dx=empty(self.node_dx))


@dataclass(frozen=True)
class GainReplay:
    """A pass's Kalman and smoother gains, for passes over logs that differ from its own only
    in their values (the null realisations: the same IMU and GNSS stamps, noise added).

    Such a pass (:func:`forward_pass` with ``replay``) is A as configured up to ``k_from``;
    from there it runs the strapdown and the closed-loop feedback as A does, but applies these
    gains to its own innovations (``dx = K dz``; a record this pass used is gated when
    ``dz^T S^-1 dz`` with this pass's S exceeds the gate; a second in a row of a kind ends
    the replay, and the pass runs in full) instead of propagating a covariance, and it smooths
    with these smoother gains (``e_k^+ = A_k e_{k+1}^-``; its own before ``k_from``). The
    gains depend on the trajectory and the noise model, which a difference of noise level
    moves at second order, as long as the two attitudes are close: ``k_from`` is where A's
    heading sigma has come within twice its median over the flight (:func:`switch_epoch`),
    before which a static alignment can leave a realisation's heading degrees from this
    pass's (docs/filter.md, "Gain replay").

    Attributes
    ----------
    time_ns : ndarray of int64, (N,)
        The pass's IMU stamps (the log's own array: not a copy); a replay's must be the same.
    epoch_ns : int
        Its time origin: its epochs are ``t_s`` [s from ``epoch_ns``] (made when read).
    k_start : int
        The pass's first epoch (alignment).
    meas_k, meas_kind : ndarray of int, (M,)
        Its measurement records' epochs and kinds.
    status : ndarray of int, (M,)
        What it did with each record (``STATUS_*``).
    gains : ndarray, (M, n, 3)
        The Kalman gain K of each used record.
    s_inv : ndarray, (M, 3, 3)
        Its innovation covariance's inverse S^-1 [per (m or m/s)^2].
    smoother_gains : ndarray, (K, n, n) or None
        ``A_k`` per smoother node (:func:`pospp.nav.smoother.smoother_gains`); None without
        the smoother.
    k_from : int
        The epoch from which a replay applies them.
    h : ndarray, (M, 3, n)
        The measurement matrix H of each used record (predicted minus measured = H dx).
    node_k : ndarray of int, (K,)
        The smoother nodes' epochs (every record's epoch among them).
    layout : StateLayout
        The pass's error-state layout.
    gm_inv_tau : ndarray, (2,)
        1 / tau of its gyro and accelerometer Gauss-Markov bias states [1/s].
    The last four are what :mod:`pospp.calib.linear_null` reads: the pass as a linear system
    with fixed gains.
    """

    time_ns: NDArray
    epoch_ns: int
    k_start: int
    meas_k: NDArray
    meas_kind: NDArray
    status: NDArray
    gains: NDArray
    s_inv: NDArray
    smoother_gains: NDArray | None
    k_from: int
    h: NDArray
    node_k: NDArray
    layout: StateLayout
    gm_inv_tau: NDArray

    @property
    def t_s(self) -> NDArray:
        """(N,) the pass's IMU epochs [s from ``epoch_ns``]."""
        return t_s_from_time_ns(self.time_ns, self.epoch_ns)

    def matches(self, t: NDArray, k_start: int, meas: MeasurementRecords, n: int) -> bool:
        """Whether a pass over epochs ``t`` from ``k_start`` with records ``meas`` and ``n``
        states has this pass's schedule (else it cannot use these gains)."""
        return (k_start == self.k_start and self.gains.shape[1] == n
                and np.array_equal(t, self.t_s) and np.array_equal(meas.k, self.meas_k)
                and np.array_equal(meas.kind, self.meas_kind))


def switch_epoch(fw: ForwardArrays, k_start: int) -> int:
    """The first output epoch where A's heading sigma (the forward P there) is within twice
    its median over the outputs: where a replay of this pass's gains starts
    (:class:`GainReplay`); ``k_start`` without outputs."""
    if not fw.out_k.shape[0]:
        return k_start
    heading_sigma_rad = np.sqrt(np.maximum(fw.out_diag[:, PHI.start + 2], 0.0))
    converged = heading_sigma_rad <= 2.0 * np.median(heading_sigma_rad)
    return int(fw.out_k[int(np.argmax(converged))])


def gain_replay(fw: ForwardArrays, time_ns: NDArray, epoch_ns: int, k_start: int,
                meas: MeasurementRecords, smoother_on: bool, lay: StateLayout,
                noise: NoiseParameters) -> GainReplay:
    """The :class:`GainReplay` of a pass made with ``record_gains`` over the IMU stamps
    ``time_ns`` from ``epoch_ns`` (before its smoother, which may write over the nodes' P)
    with layout ``lay`` and IMU model ``noise``."""
    return GainReplay(time_ns, int(epoch_ns), k_start, meas.k, meas.kind, fw.m_status.copy(),
                      fw.m_gain, fw.m_sinv, smoother_gains(fw.node_pp, fw.node_pu, fw.node_phi)
                      if smoother_on else None, switch_epoch(fw, k_start), fw.m_h,
                      fw.node_k.copy(), lay, _inv_tau(noise))


def _inv_tau(noise: NoiseParameters) -> NDArray:
    """[1 / tau_gyro, 1 / tau_accel] of the Gauss-Markov bias states [1/s]."""
    return np.array([1.0 / noise.gyro_gm_tau_s, 1.0 / noise.accel_gm_tau_s])


def forward_pass(t: NDArray, w: NDArray, f: NDArray, al: AlignmentResult,
                  noise: NoiseParameters, lay: StateLayout, lever0: NDArray,
                  meas: MeasurementRecords, output_rate_hz: float | None,
                  options: FilterOptions, *, record_gains: bool = False,
                  replay: GainReplay | None = None) -> ForwardArrays:
    """Initial state and covariance, the output arrays, and the compiled forward pass.

    ``record_gains``: store each used record's K, S^-1 and H (``m_gain``, ``m_sinv``, ``m_h``).
    ``replay``: apply another pass's gains from its ``k_from`` (:class:`GainReplay`, whose
    ``matches`` the caller has checked), keeping node P and Phi only before it; when the
    replay ends (two records of a kind gated in a row), the pass in full."""
    k0 = al.k_start
    flags, out_k = epoch_flags(t, k0, meas.k, output_rate_hz, options.smoother_node_interval_s)
    n_nodes = int(np.count_nonzero(flags[k0:] & FLAG_NODE))
    n_kept = n_nodes if options.smoother else 0  # without the smoother no node is stored
    p0_diag, q_diag = initial_covariance_and_noise(lay, noise, al,
                                                    options.lever_arm_sigma_m)
    n, n_meas, n_out = lay.n, meas.k.shape[0], out_k.shape[0]
    prop_steps = max(1, int(round(options.propagation_interval_s / float(np.median(np.diff(t))))))
    gate = chi2_ppf(options.gate_probability, 3)
    x0 = np.concatenate([[al.lat_rad, al.lon_rad, al.height_m], al.v_n_mps,
                         rotation.quat_from_euler(al.rpy_rad)])
    inv_tau = _inv_tau(noise)
    n_cov = n_kept if replay is None or not n_kept else int(np.count_nonzero(
        flags[k0:max(k0, replay.k_from)] & FLAG_NODE))  # a replay's own nodes: before it
    status = np.full(n_meas, -1, dtype=np.int64) if replay is None else replay.status.copy()
    m_rec = n_meas if record_gains and replay is None else 0
    # P at the outputs: for the solutions' sigmas, and a recording pass's switch_epoch
    n_pout = n_out if (options.covariance_outputs and options.forward_covariance) or m_rec else 0
    fw = ForwardArrays(
        gate=gate, out_k=out_k, m_status=status,
        m_nis=np.full(n_meas, np.nan), m_dz=np.full((n_meas, 3), np.nan),
        out_x=np.empty((n_out, 10)), out_diag=np.empty((n_pout, n)),
        out_blk=np.empty((n_pout, 3, 3, 3)), out_sens=np.empty((n_out, 12)),
        out_bvar=np.empty((n_pout, 6)), out_lever=np.empty((n_out, 3)),
        node_k=np.empty(n_kept, dtype=np.int64), node_pp=np.empty((n_cov, packed_size(n))),
        node_pu=np.empty((n_cov, packed_size(n))), node_phi=np.empty((n_cov, N_NAV + 1, n)),
        node_dx=np.empty((n_kept, n)), m_gain=np.empty((m_rec, n, 3)),
        m_sinv=np.empty((m_rec, 3, 3)), m_h=np.empty((m_rec, 3, n)),
        replayed=replay is not None,
    )
    gains = (fw.m_gain, fw.m_sinv, fw.m_h) if replay is None else (replay.gains, replay.s_inv,
                                                                    fw.m_h)
    used_nodes, used_out = forward_kernel(
        t, w, f, k0, x0, np.diag(p0_diag), lever0.copy(), (lay.i_gm, lay.i_sf, lay.i_l),
        inv_tau, flags, (meas.k, meas.kind, meas.z, meas.r, meas.dt_s),
        (fw.m_status, fw.m_nis, fw.m_dz), prop_steps, q_diag, gate, options.gate_reset_s,
        (fw.out_x, fw.out_diag, fw.out_blk, fw.out_sens, fw.out_bvar, fw.out_lever),
        (fw.node_k, fw.node_pp, fw.node_pu, fw.node_phi, fw.node_dx), gains,
        -1 if replay is None else max(int(replay.k_from), k0),
    )
    if replay is not None and used_nodes < 0:  # the replay ended: A in full
        return forward_pass(t, w, f, al, noise, lay, lever0, meas, output_rate_hz, options)
    if used_nodes != n_nodes or used_out != n_out:
        raise RuntimeError(f"filter kernel: node/output count mismatch ({used_nodes} vs "
                           f"{n_nodes}, {used_out} vs {n_out})")
    return fw


@dataclass(frozen=True)
class Outcome:
    """What became of A's measurement records (:func:`record_outcomes`)."""

    rejections: tuple[GnssRejection, ...]
    n_updates: dict[str, int]
    resets: tuple[tuple[float, str], ...]


def record_outcomes(meas: MeasurementRecords, fw: ForwardArrays,
                     rejections: list[GnssRejection]) -> Outcome:
    """Rejections (entry checks, gate, before the start) sorted by time; updates per kind;
    covariance resets."""
    st, kind = fw.m_status, meas.kind
    for i in np.flatnonzero(st == STATUS_GATED):
        rejections.append(GnssRejection(int(meas.time_ns[i]), float(meas.t_s[i]),
                                        MEAS_KINDS[kind[i]],
                                        f"innovation gate (NIS > {fw.gate:.2f})",
                                        float(fw.m_nis[i])))
    for i in np.flatnonzero(st == STATUS_BEFORE_START):
        rejections.append(GnssRejection(int(meas.time_ns[i]), float(meas.t_s[i]),
                                        MEAS_KINDS[kind[i]],
                                        "before the filter start (alignment)", math.nan))
    rejections.sort(key=lambda r: (r.time_ns, r.kind))
    n_updates = {name: int(np.count_nonzero((st == STATUS_USED) & (kind == i)))
                 for i, name in enumerate(MEAS_KINDS)}
    for j, name in enumerate(MEAS_KINDS[:2]):
        n_updates[f"{name}_reset"] = int(np.count_nonzero((st == STATUS_RESET) & (kind == j)))
    resets = tuple((float(meas.t_s[i]), MEAS_KINDS[kind[i]])
                   for i in np.flatnonzero(st == STATUS_RESET))
    return Outcome(tuple(rejections), n_updates, resets)


def smoothed_backward(fw: ForwardArrays, with_cov: bool, replay: GainReplay | None
                      ) -> tuple[NDArray, NDArray, NDArray | None]:
    """RTS smoother's backward pass over the nodes: (e_plus, e_minus, P^s packed or None);
    P^s is written over the nodes' updated P (``with_cov`` False: the errors alone, by
    ``replay``'s smoother gains when it has them). What reads the nodes' P and Phi: the
    caller frees them after it (:meth:`ForwardArrays.without_nodes`)."""
    if with_cov:
        return rts_smooth(fw.node_pp, fw.node_pu, fw.node_phi, fw.node_dx,
                          overwrite_p_upd=True)
    if replay is None or replay.smoother_gains is None:
        e_plus, e_minus, _ = rts_smooth(fw.node_pp, fw.node_pu, fw.node_phi, fw.node_dx,
                                        covariance=False)
    else:
        e_plus, e_minus, _ = rts_smooth_replayed(replay.smoother_gains, fw.node_pp,
                                                 fw.node_pu, fw.node_phi, fw.node_dx)
    return e_plus, e_minus, None


def total_bias_variance(p_packed: NDArray, lay: StateLayout, chunk: int = 2048) -> NDArray:
    """diag(T P T^T) per node (K, 6): the total [gyro, accel] bias variance
    (:func:`total_bias_map` T) of packed covariances (K, n (n + 1) / 2), unpacked ``chunk``
    nodes at a time (the same sums as over the whole (K, n, n) array)."""
    tb = total_bias_map(lay)
    out = np.empty((p_packed.shape[0], 6))
    for c in range(0, p_packed.shape[0], chunk):
        full = unpack_symmetric(p_packed[c:c + chunk], lay.n)
        out[c:c + chunk] = np.einsum("ij,kjl,il->ki", tb, full, tb)
    return out
