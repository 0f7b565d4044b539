"""Algorithm A's error-state layout, initial covariance, process noise, and the forward pass's
arrays around the compiled kernel (docs/filter.md).

The 15 base states (:mod:`pospp.nav.error_model`: ``PHI``, ``DV``, ``DR``, ``BG``, ``BA``) are
followed by the optional blocks, in this order: Gauss-Markov gyro and accel biases (6), gyro and
accel scale factors (6), lever arm (3). Units SI and rad; variances of the NED blocks in NED.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pospp import rotation
from pospp.distributions import chi2_ppf
from pospp.nav._filter_kernel import FLAG_NODE, forward_kernel
from pospp.nav.alignment import AlignmentResult
from pospp.nav.error_model import BA, BG, DR, DV, I_BA, I_BG, N_STATES, PHI
from pospp.nav.filter_input import MeasurementRecords, epoch_flags
from pospp.nav.tuning import NoiseParameters

if TYPE_CHECKING:
    from pospp.nav.filter import FilterOptions

__all__ = ["ForwardArrays", "StateLayout", "forward_pass", "initial_covariance_and_noise",
           "state_layout", "total_bias_map"]


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
    """The arrays the compiled forward pass filled (:mod:`pospp.nav._filter_kernel`)."""

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
    node_pu: NDArray
    node_phi: NDArray
    node_dx: NDArray

    def without_nodes(self) -> ForwardArrays:
        """The same arrays with the smoother's nodes emptied (new empty arrays: a slice would
        keep the nodes' memory alive)."""
        def empty(a: NDArray) -> NDArray:
            return np.empty((0, *a.shape[1:]), a.dtype)

        return replace(self, node_k=empty(self.node_k), node_pp=empty(self.node_pp),
                       node_pu=empty(self.node_pu), node_phi=empty(self.node_phi),
                       node_dx=empty(self.node_dx))


def forward_pass(t: NDArray, w: NDArray, f: NDArray, al: AlignmentResult,
                  noise: NoiseParameters, lay: StateLayout, lever0: NDArray,
                  meas: MeasurementRecords, output_rate_hz: float | None,
                  options: FilterOptions) -> ForwardArrays:
    """Initial state and covariance, the output arrays, and the compiled forward pass."""
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
    inv_tau = np.array([1.0 / noise.gyro_gm_tau_s, 1.0 / noise.accel_gm_tau_s])
    fw = ForwardArrays(
        gate=gate, out_k=out_k, m_status=np.full(n_meas, -1, dtype=np.int64),
        m_nis=np.full(n_meas, np.nan), m_dz=np.full((n_meas, 3), np.nan),
        out_x=np.empty((n_out, 10)), out_diag=np.empty((n_out, n)),
        out_blk=np.empty((n_out, 3, 3, 3)), out_sens=np.empty((n_out, 12)),
        out_bvar=np.empty((n_out, 6)), out_lever=np.empty((n_out, 3)),
        node_k=np.empty(n_kept, dtype=np.int64), node_pp=np.empty((n_kept, n, n)),
        node_pu=np.empty((n_kept, n, n)), node_phi=np.empty((n_kept, n, n)),
        node_dx=np.empty((n_kept, n)),
    )
    used_nodes, used_out = forward_kernel(
        t, w, f, k0, x0, np.diag(p0_diag), lever0.copy(), (lay.i_gm, lay.i_sf, lay.i_l),
        inv_tau, flags, (meas.k, meas.kind, meas.z, meas.r, meas.dt_s),
        (fw.m_status, fw.m_nis, fw.m_dz), prop_steps, q_diag, gate, options.gate_reset_s,
        (fw.out_x, fw.out_diag, fw.out_blk, fw.out_sens, fw.out_bvar, fw.out_lever),
        (fw.node_k, fw.node_pp, fw.node_pu, fw.node_phi, fw.node_dx),
    )
    if used_nodes != n_nodes or used_out != n_out:
        raise RuntimeError(f"filter kernel: node/output count mismatch ({used_nodes} vs "
                           f"{n_nodes}, {used_out} vs {n_out})")
    return fw
