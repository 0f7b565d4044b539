"""Algorithm A: closed-loop error-state INS/GNSS Kalman filter and its RTS smoother.

Frames and units: body FRD (b), navigation NED (n), SI and radians; GNSS antenna (a) at the
lever arm l_b (body FRD, m) from the IMU. Errors are computed minus true (pospp conventions).
Error state (docs/filter.md), 15 base states and optional blocks, in this order::

    dx = [phi_n, dv_n, dr_n, db_g, db_a (, db_g,gm, db_a,gm) (, ds_g, ds_a) (, dl_b)]

phi_n misalignment (C_nb_hat = (I - [phi x]) C_nb), dv_n, dr_n (NED m) as in
:mod:`pospp.nav.error_model`; db_g, db_a the residual constant body-frame biases, db_*,gm their
first-order Gauss-Markov parts (default on), ds_g, ds_a the residual scale factors left in the
corrected sensor outputs (w_hat - w = db_g + db_g,gm + diag(w) ds_g); dl_b = lever estimate -
true lever.

The compiled forward pass lives in :mod:`pospp.nav._filter_kernel`, the backward pass in
:mod:`pospp.nav.smoother`, the input checks in :mod:`pospp.nav.filter_input`.

Mechanization: the one strapdown kernel (:func:`pospp.nav._kernels.strapdown_step`) on the
corrected increments dtheta_hat = (dtheta - (b_g + b_g,gm) dt) / (1 + s_g), dv_hat likewise;
the nominal Gauss-Markov biases decay as exp(-dt / tau). Closed loop: after every accepted
update the estimate is fed back (position, velocity, C_nb <- (I + [phi x]) C_nb, biases and
scale factors accumulated, lever arm) and the error state reset to zero.

Covariance propagation at a coarser rate than the IMU (every ``propagation_interval_s``, and at
every measurement, output and smoother node epoch): F from :func:`error_model.fill_f_matrix`
(the one F) with the mean specific force over the interval T, extended by the optional columns
phi' += -C_nb (db_g,gm + diag(w_b) ds_g), dv' += C_nb (db_a,gm + diag(f_b) ds_a) and
db_*,gm' = -db_*,gm / tau; Phi = I + F T + F^2 T^2 / 2, Q_d = (Phi Q_c Phi^T + Q_c) T / 2 with
Q_c = diag(ARW^2 I, VRW^2 I, 0, 0, 0, 2 sigma_gm^2 / tau I, 0...) (or random-walk biases,
``FilterOptions.gauss_markov_states=False``).

Measurements (predicted minus measured = H dx + noise; Groves 2013 Sec. 14.2)::

    position:  r_a = r + C l (+ v_a dt_meas)                                      (NED m)
               H = [[(C l) x], 0, I, 0, 0 (, 0, 0) (, 0, 0) (, C)]
    velocity:  v_a = v + C (w_ib_b x l) - w_in x (C l)
               H = [[(C (w x l)) x], I, 0, -C [l x], 0 (, -C [l x], 0)
                    (, -C [l x] diag(w), 0) (, C [w x] - [w_in x] C)]
    ZUPT:      the velocity model with z = 0, over the detected initial static period

Each update is gated by its normalised innovation squared (NIS, 3 dof) against the chi-square
quantile ``gate_probability``; rejected measurements are reported with time, kind and NIS, as
are GNSS records refused on entry (non-finite values, covariance not positive definite or
absurdly large, duplicate times, outside the IMU span). After ``gate_reset_s`` of gated GNSS
positions (velocities) the position (velocity) block of P is reset from the next record
(reported in ``FilterResult.resets``). Reported covariances are used as given, floored at
``pos_sigma_floor_m`` / ``vel_sigma_floor_mps`` per axis.

Outputs at ``output_rate_hz`` (IMU epochs nearest the multiples of 1 / rate in t_s; ``None``:
every IMU epoch): the forward solution with sigmas, and the smoothed one (nominal corrected by
the RTS error estimate interpolated between the smoother nodes, :mod:`pospp.nav.smoother`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp.nav import filter_input, smoother
from pospp.nav._filter_kernel import STATUS_GATED, STATUS_RESET, STATUS_USED
from pospp.nav.alignment import AlignmentOptions, AlignmentResult, align
from pospp.nav.error_model import DR, DV, PHI
from pospp.nav.filter_input import GnssRejection, MeasurementRecords
from pospp.nav.filter_state import (
    ForwardArrays,
    GainReplay,
    StateLayout,
    forward_pass,
    gain_replay,
    record_outcomes,
    smoothed_backward,
    state_layout,
    total_bias_map,
    total_bias_variance,
)
from pospp.nav.solution import NavSolution
from pospp.nav.strapdown import Trajectory
from pospp.nav.tuning import ImuTuning, NoiseParameters, tuning_preset
from pospp.types import GnssFixes, GnssVelocities, ImuSamples


# =============================================================================================
# Data classes
# =============================================================================================
@dataclass(frozen=True)
class FilterOptions:
    """Settings of algorithm A other than the IMU tuning (units in the names).

    Attributes
    ----------
    propagation_interval_s : float
        Covariance propagation step (also at every measurement, output and node epoch).
    smoother_node_interval_s : float
        Longest spacing of the smoother nodes (every GNSS epoch is a node as well).
    pos_sigma_floor_m, vel_sigma_floor_mps : float
        Floors of the reported GNSS standard deviations per axis.
    max_pos_sigma_m, max_vel_sigma_mps : float
        GNSS records reporting a larger sigma are refused ("covariance too large").
    gate_probability : float
        Chi-square (3 dof) quantile of the innovation gate.
    gate_reset_s : float
        When every GNSS position (velocity) record has failed the gate for longer than this,
        the next one resets the position (velocity) block of the covariance and is used
        (recorded in ``FilterResult.resets``); ``inf`` never resets.
    use_velocity, zupt : bool
        Use the GNSS velocities; zero-velocity updates over the initial static period.
    zupt_sigma_mps, zupt_interval_s : float
    lever_arm_sigma_m : float
        Initial sigma of the lever-arm states (when estimated).
    max_gnss_imu_offset_s : float
        A GNSS record further than this from every IMU epoch is refused.
    max_imu_gap_intervals, max_imu_gap_s : float
        An IMU interval longer than this many median intervals is a gap: bridged by holding
        the rate of the sample after it, and reported in ``FilterResult.imu_gaps``; a gap
        longer than ``max_imu_gap_s`` raises ValueError.
    gauss_markov_states : bool
        Carry the biases as constant plus first-order Gauss-Markov (six more states); False:
        one random-walk state per axis (:mod:`pospp.nav.tuning`, "Bias model").
    smoother : bool
        Run the RTS smoother.
    covariance_outputs : bool
        Form the solutions' covariances. False (A's re-runs in the diagnosis and the null
        realisations, which read only the states and biases): the smoother runs on the errors
        alone (:func:`pospp.nav.smoother.rts_smooth`, ``covariance=False``) and every sigma
        and covariance of the solutions and biases is NaN; the states are those of a run with
        True, to rounding (the forward pass is the same).
    forward_covariance : bool
        Keep P at the forward pass's outputs (the forward solution's and biases' sigmas).
        False (a pass whose smoothed solution alone is read: the compensation's): those
        sigmas are NaN, the smoothed solution is the same, and P's (N, n) and (N, 3, 3, 3)
        output arrays are not made.
    alignment : AlignmentOptions
    """

    propagation_interval_s: float = 0.1
    smoother_node_interval_s: float = 1.0
    pos_sigma_floor_m: float = 0.01
    vel_sigma_floor_mps: float = 0.005
    max_pos_sigma_m: float = 100.0
    max_vel_sigma_mps: float = 10.0
    gate_probability: float = 0.9999
    gate_reset_s: float = 30.0
    use_velocity: bool = True
    zupt: bool = True
    zupt_sigma_mps: float = 0.01
    zupt_interval_s: float = 1.0
    lever_arm_sigma_m: float = 0.5
    max_gnss_imu_offset_s: float = 0.05
    max_imu_gap_intervals: float = 5.0
    max_imu_gap_s: float = 0.5
    gauss_markov_states: bool = True
    smoother: bool = True
    covariance_outputs: bool = True
    forward_covariance: bool = True
    alignment: AlignmentOptions = field(default_factory=AlignmentOptions)

    def __post_init__(self) -> None:
        positive = ("propagation_interval_s", "smoother_node_interval_s", "max_pos_sigma_m",
                    "max_vel_sigma_mps", "zupt_sigma_mps", "zupt_interval_s",
                    "lever_arm_sigma_m", "max_gnss_imu_offset_s", "max_imu_gap_intervals",
                    "max_imu_gap_s", "gate_reset_s")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value > 0.0):
                raise ValueError(f"FilterOptions.{name}: expected a number > 0, got {value!r}")
        for name in ("pos_sigma_floor_m", "vel_sigma_floor_mps"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f"FilterOptions.{name}: expected a finite number >= 0, "
                                 f"got {value!r}")
        if not 0.0 < self.gate_probability < 1.0:
            raise ValueError("FilterOptions.gate_probability: expected 0 < p < 1, got "
                             f"{self.gate_probability!r}")


@dataclass(frozen=True)
class BiasHistory:
    """Sensor error estimates (body FRD, measured = (1 + s) true + b) with 1-sigma.

    Scale factors are dimensionless (1e-6 = 1 ppm); zeros with zero sigma when not estimated
    (then read-only arrays that take no memory).
    """

    t_s: NDArray
    gyro_b_radps: NDArray
    gyro_sigma_b_radps: NDArray
    accel_b_mps2: NDArray
    accel_sigma_b_mps2: NDArray
    gyro_sf: NDArray
    gyro_sf_sigma: NDArray
    accel_sf: NDArray
    accel_sf_sigma: NDArray


@dataclass(frozen=True)
class LeverArmEstimate:
    """Antenna lever arm (body FRD, m): the configured value or the (smoothed) estimate."""

    lever_b_m: NDArray
    sigma_b_m: NDArray
    estimated: bool


@dataclass(frozen=True)
class InnovationRecord:
    """Every GNSS/ZUPT record the forward pass processed, in processing order (M,).

    ``t_s`` record time; ``kind`` index into ``MEAS_KINDS``; ``status`` 0 used, 1 gated,
    2 used after a covariance reset, 3 before the filter start (``nis``, ``dz_ned`` NaN);
    ``nis`` normalised innovation squared (3 dof); ``dz_ned`` innovation, predicted minus
    measured (NED m for positions, m/s for velocities and ZUPTs), before the update.
    """

    t_s: NDArray
    kind: NDArray
    status: NDArray
    nis: NDArray
    dz_ned: NDArray


@dataclass(frozen=True)
class FilterResult:
    """Everything algorithm A produces.

    ``smoothed`` and ``smoothed_biases`` are None when the smoother is disabled.
    ``rejections`` lists every GNSS/ZUPT record not used (entry checks and the innovation gate),
    sorted by time; ``n_updates`` counts the accepted updates per kind.
    """

    forward: NavSolution
    smoothed: NavSolution | None
    forward_biases: BiasHistory
    smoothed_biases: BiasHistory | None
    rejections: tuple[GnssRejection, ...]
    lever_arm: LeverArmEstimate
    alignment: AlignmentResult
    n_updates: dict[str, int]
    gate_nis: float
    """The innovation gate threshold (chi-square, 3 dof)."""
    resets: tuple[tuple[float, str], ...] = ()
    """(t_s, kind) of the GNSS records accepted by a covariance reset (gate_reset_s)."""
    imu_gaps: tuple[tuple[float, float], ...] = ()
    """(t_s at the end, duration_s) of the IMU gaps bridged (FilterOptions.max_imu_gap_*)."""
    innovations: InnovationRecord | None = None
    """NIS and innovation of every processed GNSS/ZUPT record (pospp.qc reads them)."""
    gain_replay: GainReplay | None = None
    """The pass's gains when asked for (``record_gains``), for replays on noisier logs."""


def _nan(shape: tuple[int, ...]) -> NDArray:
    """A read-only array of NaN that takes no memory (a broadcast scalar): the sigmas of a
    run with ``covariance_outputs`` False."""
    return np.broadcast_to(np.float64(np.nan), shape)


def _zeros(shape: tuple[int, ...]) -> NDArray:
    """A read-only array of zeros that takes no memory (a broadcast scalar): the scale
    factors and their sigmas of a pass that does not estimate them."""
    return np.broadcast_to(np.float64(0.0), shape)


def _solution(time_ns, t_s, states, blocks) -> NavSolution:
    """The states with P's [phi, dv, dr] blocks, packed ((N, 6) each); ``blocks`` None: NaN
    (``covariance_outputs`` False)."""
    if blocks is None:
        blocks = [_nan((states.shape[0], 6))] * 3
    att_cov, vel_cov, pos_cov = blocks
    return NavSolution(
        time_ns=time_ns, t_s=t_s, lat_rad=states[:, 0].copy(), lon_rad=states[:, 1].copy(),
        height_m=states[:, 2].copy(), v_n_mps=states[:, 3:6].copy(), q_nb=states[:, 6:10].copy(),
        pos_cov_packed_ned_m2=pos_cov, vel_cov_packed_ned_m2ps2=vel_cov,
        att_cov_packed_ned_rad2=att_cov,
    )


def _noise(tuning: ImuTuning | str) -> NoiseParameters:
    if isinstance(tuning, str):
        return tuning_preset(tuning).noise()
    if isinstance(tuning, ImuTuning):
        return tuning.noise()
    raise TypeError(f"tuning: expected ImuTuning or a preset name, got {tuning!r}")


# =============================================================================================
# Top level
# =============================================================================================
def run_integrated_navigation(
    imu: ImuSamples,
    gnss_fixes: GnssFixes,
    gnss_velocities: GnssVelocities | None,
    tuning: ImuTuning | str,
    *,
    epoch_ns: int | None = None,
    lever_arm_b_m: ArrayLike | None = None,
    estimate_lever_arm: bool = False,
    estimate_scale_factors: bool = False,
    output_rate_hz: float | None = 10.0,
    options: FilterOptions = FilterOptions(),
    record_gains: bool = False,
    replay: GainReplay | None = None,
) -> FilterResult:
    """Forward closed-loop EKF and RTS smoother over a whole IMU/GNSS record (algorithm A).

    Parameters
    ----------
    imu : pospp.types.ImuSamples
        ``time_ns`` (N,) int64, ``w_ib_b_radps`` (N, 3), ``f_ib_b_mps2`` (N, 3): mean rate and
        specific force over the interval ending at each stamp, body FRD.
    gnss_fixes : pospp.types.GnssFixes
        ``time_ns`` (M,), ``lat_rad``, ``lon_rad``, ``height_m`` (M,), ``pos_cov_ned_m2``
        (M, 3, 3): antenna positions (WGS-84) with their NED covariance.
    gnss_velocities : pospp.types.GnssVelocities or None
        ``time_ns`` (V,), ``v_n_mps`` (V, 3), ``vel_cov_ned_m2ps2`` (V, 3, 3): antenna velocity.
    tuning : ImuTuning or preset name
        IMU noise model (:mod:`pospp.nav.tuning`).
    epoch_ns : int, optional
        Reference epoch: t_s = (time_ns - epoch_ns) * 1e-9 (default: the first IMU stamp).
    lever_arm_b_m : array_like, shape (3,), optional
        Antenna position in body FRD [m] (known value, or the initial guess when estimated).
    estimate_lever_arm : bool
        Add three lever-arm states.
    estimate_scale_factors : bool
        Add six scale-factor states (gyro, accelerometer).
    output_rate_hz : float or None
        Rate of the output epochs (None: every IMU epoch).
    options : FilterOptions
    record_gains : bool
        Keep the pass's Kalman and smoother gains (``FilterResult.gain_replay``).
    replay : GainReplay, optional
        Apply another pass's gains from its ``k_from`` on instead of propagating a covariance
        (states only; a log whose stamps, alignment or records differ from that pass's runs
        in full instead).

    Returns
    -------
    FilterResult

    Raises
    ------
    ValueError
        IMU samples that break the contract (non-finite, not increasing, gaps), no usable GNSS,
        or no possible alignment; the message names the time and what is wrong.
    """
    noise = _noise(tuning)
    imu_t_ns = np.asarray(imu.time_ns, dtype=np.int64)
    w = np.ascontiguousarray(imu.w_ib_b_radps, dtype=float)
    f = np.ascontiguousarray(imu.f_ib_b_mps2, dtype=float)
    if epoch_ns is None:
        epoch_ns = int(imu_t_ns[0]) if imu_t_ns.shape[0] else 0
    t, imu_gaps = filter_input.imu_epochs(imu_t_ns, w, f, epoch_ns,
                                          options.max_imu_gap_intervals, options.max_imu_gap_s)
    lever0 = np.zeros(3) if lever_arm_b_m is None else np.asarray(lever_arm_b_m, dtype=float)
    if lever0.shape != (3,) or not np.isfinite(lever0).all():
        raise ValueError(f"lever_arm_b_m: expected 3 finite numbers, got {lever_arm_b_m!r}")
    rejections: list[GnssRejection] = []
    al, meas = _align_and_measurements(t, w, f, gnss_fixes, gnss_velocities, epoch_ns, noise,
                                       lever0, options, rejections)
    lay = state_layout(options.gauss_markov_states, estimate_scale_factors, estimate_lever_arm)
    if replay is not None and (not replay.matches(t, al.k_start, meas, lay.n)
                               or options.smoother != (replay.smoother_gains is not None)):
        replay = None
    fw = forward_pass(t, w, f, al, noise, lay, lever0, meas, output_rate_hz, options,
                      record_gains=record_gains, replay=replay)
    replay = replay if fw.replayed else None  # a replay that ended ran in full
    outcome = record_outcomes(meas, fw, rejections)
    out_tns = imu_t_ns[fw.out_k]
    # before the smoother, which may write over the nodes' P
    gains = gain_replay(fw, imu_t_ns, epoch_ns, al.k_start, meas, options.smoother, lay,
                        noise) if record_gains and replay is None else None
    errors = None
    if options.smoother:
        node_t = t[fw.node_k]
        back = smoothed_backward(fw, options.covariance_outputs and replay is None, replay)
        # the nodes' predicted P and Phi are freed before the interpolation (the smoothed P
        # is written over the updated P's memory): 55 MiB less at a 1.5 h flight's peak
        fw = fw.without_nodes()
        errors = _smoothed_errors(t[fw.out_k], node_t, lay, *back)
        del back
    else:
        fw = fw.without_nodes()
    smoothed = sm_bias = lever_s = None
    if errors is not None:
        smoothed, sm_bias, lever_s = _smoothed(t, fw, lay, out_tns, *errors)
    fwd, fwd_bias, lever = _forward_results(t, fw, lay, out_tns, options.covariance_outputs
                                            and options.forward_covariance)
    lever = lever if lever_s is None else lever_s
    return FilterResult(
        forward=fwd, smoothed=smoothed, forward_biases=fwd_bias, smoothed_biases=sm_bias,
        rejections=outcome.rejections, lever_arm=LeverArmEstimate(*lever, lay.i_l >= 0),
        alignment=al, n_updates=outcome.n_updates, gate_nis=fw.gate, resets=outcome.resets,
        imu_gaps=imu_gaps,
        innovations=InnovationRecord(meas.t_s.copy(), meas.kind.copy(), fw.m_status.copy(),
                                     fw.m_nis, fw.m_dz), gain_replay=gains,
    )


def _forward_results(t: NDArray, fw: ForwardArrays, lay: StateLayout, out_tns: NDArray,
                     with_cov: bool = True
                     ) -> tuple[NavSolution, BiasHistory, tuple[NDArray, NDArray]]:
    """The forward solution, its biases, and the lever arm (last epoch) with its sigma
    (``with_cov`` False: every sigma NaN, ``FilterOptions.covariance_outputs``)."""
    out_t = t[fw.out_k]
    n_out = fw.out_x.shape[0]  # (without covariance outputs P's arrays may have no rows)
    diag = fw.out_diag if with_cov else _nan((n_out, fw.out_diag.shape[1]))
    bvar = fw.out_bvar if with_cov else _nan((n_out, 6))
    blocks = [smoother.pack_symmetric(fw.out_blk[:, j]) for j in range(3)] if with_cov else None
    fwd = _solution(out_tns, out_t, fw.out_x, blocks)
    fwd_bias = _bias_history(out_t, fw.out_sens, bvar, diag, lay.i_sf)
    lever_sig = np.sqrt(diag[-1, lay.i_l:lay.i_l + 3]) if lay.i_l >= 0 else np.zeros(3)
    return fwd, fwd_bias, (fw.out_lever[-1].copy(), lever_sig)


def _align_and_measurements(
    t: NDArray, w: NDArray, f: NDArray, fixes: GnssFixes, vels: GnssVelocities | None,
    epoch_ns: int, noise: NoiseParameters, lever0: NDArray, options: FilterOptions,
    rejections: list[GnssRejection],
) -> tuple[AlignmentResult, MeasurementRecords]:
    """Screen the GNSS records, align, and list the measurements (ZUPTs over a static start)."""
    gnss = filter_input.screened_gnss(fixes, vels, t, epoch_ns, options, rejections)
    al = align(t, w, f, gnss.fix_t_s, gnss.fix_llh, gnss.fix_cov, gnss.vel_t_s, gnss.vel_n,
               noise, lever_arm_b_m=lever0, options=options.alignment,
               vel_cov_ned_m2ps2=gnss.vel_cov)
    zupt_t_s = None
    if options.zupt and al.method == "static" and al.static_end_s is not None:
        zupt_t_s = np.arange(t[0], al.static_end_s - options.alignment.window_s,
                             options.zupt_interval_s)
        zupt_t_s = zupt_t_s[zupt_t_s > t[0]]
    meas = filter_input.measurement_records(gnss, zupt_t_s, options.zupt_sigma_mps, t,
                                            epoch_ns, options.max_gnss_imu_offset_s,
                                            rejections)
    return al, meas


def _smoothed_errors(out_t: NDArray, node_t: NDArray, lay: StateLayout, e_plus: NDArray,
                     e_minus: NDArray, p_s: NDArray | None
                     ) -> tuple[NDArray, NDArray, list[NDArray] | None, NDArray]:
    """The smoothed errors and covariance (None: none) of
    :func:`pospp.nav.filter_state.smoothed_backward` at the nodes' times ``node_t``,
    interpolated to the outputs' ``out_t``: (error (N, n), diagonal of P^s (N, n), its [phi,
    dv, dr] blocks, total bias variance (N, 6)); without P^s the errors alone, the rest NaN."""
    if p_s is not None:
        diag_s, blocks_s = smoother.interpolate_covariance_blocks(node_t, p_s, out_t,
                                                                  (PHI, DV, DR), lay.n)
        bvar_nodes = total_bias_variance(p_s, lay)
        i, a = smoother.interpolation_weights(node_t, out_t)
        nxt = np.minimum(i + 1, node_t.shape[0] - 1)
        bvar_s = (1.0 - a)[:, None] * bvar_nodes[i] + a[:, None] * bvar_nodes[nxt]
    else:
        diag_s = _nan((out_t.shape[0], lay.n))
        blocks_s, bvar_s = None, _nan((out_t.shape[0], 6))
    return smoother.interpolate_errors(node_t, e_plus, e_minus, out_t), diag_s, blocks_s, bvar_s


def _smoothed(t: NDArray, fw: ForwardArrays, lay: StateLayout, out_tns: NDArray,
              err: NDArray, diag_s: NDArray, blocks_s: list[NDArray] | None, bvar_s: NDArray
              ) -> tuple[NavSolution, BiasHistory, tuple[NDArray, NDArray] | None]:
    """The smoothed solution, biases and (when estimated) lever arm with its sigma, from the
    forward outputs and :func:`_smoothed_errors` (``blocks_s`` None: every sigma NaN)."""
    out_t = t[fw.out_k]
    states_s = smoother.correct_states(fw.out_x, np.ascontiguousarray(err))
    smoothed = _solution(out_tns, out_t, states_s, blocks_s)
    # total bias error (constant + Gauss-Markov) and its smoothed variance
    sens_s = fw.out_sens.copy()
    sens_s[:, :6] += err @ total_bias_map(lay).T
    if lay.i_sf >= 0:
        sens_s[:, 6:] += err[:, lay.i_sf:lay.i_sf + 6]
    sm_bias = _bias_history(out_t, sens_s, bvar_s, diag_s, lay.i_sf)
    lever = None
    if lay.i_l >= 0:
        lever = (fw.out_lever[0] - err[0, lay.i_l:lay.i_l + 3],
                 np.sqrt(diag_s[0, lay.i_l:lay.i_l + 3]))
    return smoothed, sm_bias, lever


def _bias_history(t_s: NDArray, sens: NDArray, bias_var: NDArray, diag: NDArray, i_sf: int
                  ) -> BiasHistory:
    bsig = np.sqrt(np.clip(bias_var, 0.0, None))
    if i_sf >= 0:
        sf_sig = np.sqrt(np.clip(diag[:, i_sf:i_sf + 6], 0.0, None))
        sf = [sens[:, 6:9].copy(), sf_sig[:, 0:3].copy(), sens[:, 9:12].copy(),
              sf_sig[:, 3:6].copy()]
    else:  # not estimated: zero (the kernel leaves them there), one zero, not one per epoch
        sf = [_zeros((t_s.shape[0], 3))] * 4
    return BiasHistory(
        t_s=t_s, gyro_b_radps=sens[:, 0:3].copy(), gyro_sigma_b_radps=bsig[:, 0:3].copy(),
        accel_b_mps2=sens[:, 3:6].copy(), accel_sigma_b_mps2=bsig[:, 3:6].copy(),
        gyro_sf=sf[0], gyro_sf_sigma=sf[1], accel_sf=sf[2], accel_sf_sigma=sf[3],
    )


def reference_name(result: FilterResult, preferred: str) -> str:
    """The solution of ``result`` B is referenced to (``[replay] reference``): ``preferred``
    ("smoothed" or "forward"), "forward" when the smoother did not run."""
    return preferred if result.smoothed is not None else "forward"


def solution_a_fields(
    result: FilterResult, *, which: str = "smoothed"
) -> tuple[Trajectory, NDArray, NDArray]:
    """What algorithm B needs from A, in the field order of ``pospp.calib.replay.
    SolutionA``: ``SolutionA(*solution_a_fields(result))``.

    Parameters
    ----------
    result : FilterResult
    which : {"smoothed", "forward"}

    Returns
    -------
    trajectory : Trajectory
        A's position, velocity and attitude at its output epochs.
    v_sigma_n_mps : ndarray, shape (N, 3)
        Velocity standard deviations, NED [m/s].
    accel_bias_b_mps2 : ndarray, shape (N, 3)
        Estimated accelerometer bias, body FRD [m/s^2].
    """
    if which not in ("smoothed", "forward"):
        raise ValueError(f"which: expected 'smoothed' or 'forward', got {which!r}")
    sol, bias = result.forward, result.forward_biases
    if which == "smoothed":
        if result.smoothed is None or result.smoothed_biases is None:
            raise ValueError("which='smoothed' but the smoother was disabled (options.smoother)")
        sol, bias = result.smoothed, result.smoothed_biases
    return sol.trajectory, sol.vel_sigma_ned_mps, bias.accel_b_mps2


__all__ = [
    "STATUS_GATED", "STATUS_RESET", "STATUS_USED",
    "BiasHistory", "FilterOptions", "FilterResult", "GainReplay", "GnssRejection",
    "InnovationRecord", "LeverArmEstimate", "reference_name", "solution_a_fields",
    "run_integrated_navigation",
]
