"""The gyro bias history of the flight: the calibration's fit and A's forward estimates, smoothed.

Frames and units: body FRD, SI (rad/s, s); run times ``t_s`` from the run's epoch.

Model of the gyro error (the calibration's noise model, :mod:`pospp.calib.solve`), per body
axis::

    e(t) = b_c + x(t) + w(t)

with b_c the turn-on constant (the least squares' fixed effect), x a first-order
Gauss-Markov drift (steady-state sigma and correlation time fitted from the flight,
``Calibration.gyro_gm_sigma_radps`` / ``gyro_gm_tau_s``) and w the white rate noise of the
angle random walk (PSD q = ARW^2). What B needs removed over a leg is e itself, so the
history estimates e as far as the data reach:

1. **The fit's own estimate** m_B(t) (:func:`fit_bias_history`): b_c plus the drift's
   conditional mean given the fit's residuals (``Calibration.drift_b_radps``); on a leg that
   took part in the fit, one value for the whole leg: b_c plus the conditional mean of the
   leg's mean drift and of the white noise's mean over the leg (:func:`fitted_leg_bias`,
   the best linear unbiased predictors of the fit's random effects):

       E[mean_L(x) | r] = mean over the leg of E[x(t) | r]
       E[mean_L(w) | r] = (q / T_L) sum_{j in L} u_j,      u = S^T C^-1 r

   (S the drift bins' map to B's velocity errors, C the fit's covariance, r its residual,
   T_L the leg's length: Cov(dv(t_i), mean_L w) = (q / T_L) int_0^t_i Phi_v,phi (-C_nb) dtau
   is the bins' columns of S summed, times q / T_L).
2. **A's forward bias estimates**, decorrelated into one measurement per GNSS update
   (:func:`pseudo_measurements`): between the output epoch before an update and the one at
   it, A's estimate moved from b- (variance P-) to b+ (P+), which a scalar update with a
   measurement z of variance R makes when

       1 / R = 1 / P+ - 1 / P-,     z = b- + (b+ - b-) P- / (P- - P+)

   (the information the update added to the bias; exact for a scalar state, the marginal of
   A's coupled one otherwise; P- adds A's bias process noise over the gap).
3. **The smoother** (:func:`smoothed_bias_history`): a Rauch-Tung-Striebel pass over a 1 s
   grid of the deviation d(t) = e(t) - m_B(t), the process the fitted drift plus the white
   noise low-passed over :data:`WHITE_TAU_S` (a Gauss-Markov component of variance
   q / (2 tau_w): the same low-frequency density q), the measurements z - m_B with variance
   ``alpha R``. ``alpha`` scales A's decorrelated noise: the decorrelation treats successive
   updates as independent, which over a leg they are not (A's error is a filtered, bounded
   one), so the scale is chosen from the flight (:func:`pospp.calib.compensate.
   choose_bias_history`): the one under which B, compensated, best matches A over the fitted
   legs. The history removed is m_B(t) + E[d(t) | z].

With no drift (sigma 0) and A's estimates left out, the history is the constant on legs not in
the fit and the constant plus the leg's white-noise mean on fitted legs; with a fast drift it
follows A's estimates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp.calib._bias_kernel import smooth_two_gm
from pospp.calib.replay import LegReplay
from pospp.calib.solve import Calibration
from pospp.nav.filter import STATUS_USED, FilterResult

WHITE_TAU_S = 10.0
"""Correlation time of the Gauss-Markov component standing for the white rate noise in the
smoother's process [s] (variance q / (2 tau): the white noise's density below 1 / (2 pi tau))."""
GRID_STEP_S = 1.0
"""Spacing of the smoothed history [s]."""
A_NOISE_SCALES = (1.0, 0.3, 0.1, 0.03)
"""Scales ``alpha`` of A's decorrelated measurement variances tried (module docstring)."""


@dataclass(frozen=True)
class ForwardBiases:
    """A's forward (filter) gyro-bias record as the smoother reads it.

    Attributes
    ----------
    t_s : ndarray, shape (K,)
        A's output epochs [s].
    gyro_b_radps, gyro_sigma_b_radps : ndarray, shape (K, 3)
        A's forward gyro-bias estimate and its 1-sigma, body FRD [rad/s]
        (``FilterResult.forward_biases``).
    update_t_s : ndarray, shape (U,)
        Times of the GNSS records A used [s] (``FilterResult.innovations``, status 0).
    bias_psd_radps2ps : float
        PSD of A's gyro-bias process noise [rad^2/s^3] (``NoiseParameters.
        gyro_bias_psd_radps2ps``): the variance A adds between two outputs.
    """

    t_s: NDArray
    gyro_b_radps: NDArray
    gyro_sigma_b_radps: NDArray
    update_t_s: NDArray
    bias_psd_radps2ps: float

    @classmethod
    def of_filter(cls, result: FilterResult, bias_psd_radps2ps: float) -> ForwardBiases:
        """From A's :class:`pospp.nav.filter.FilterResult`: its forward biases and the times
        of the GNSS records it used (innovation status "used")."""
        fb, inn = result.forward_biases, result.innovations
        used = (np.zeros(0) if inn is None
                else np.unique(inn.t_s[inn.status == STATUS_USED]))
        return cls(fb.t_s, fb.gyro_b_radps, fb.gyro_sigma_b_radps, used,
                   float(bias_psd_radps2ps))


def span_means(time_ns: NDArray, values: NDArray, spans: Sequence[tuple[int, int]]) -> NDArray:
    """Mean of ``values`` (N, 3) over the samples stamped in each span (a, e] [ns], (L, 3)
    (zeros for a span without samples): a leg's mean of a rate series."""
    t = np.asarray(time_ns, dtype=np.int64)
    out = np.zeros((len(spans), 3))
    for i, (a, e) in enumerate(spans):
        k0, k1 = np.searchsorted(t, a, side="right"), np.searchsorted(t, e, side="right")
        if k1 > k0:
            out[i] = np.asarray(values[k0:k1]).mean(axis=0)
    return out


def pseudo_measurements(fwd: ForwardBiases) -> tuple[NDArray, NDArray, NDArray]:
    """A's forward estimate as independent measurements of the bias, one per output epoch at
    or after which a GNSS update came (module docstring, item 2).

    Returns
    -------
    t_s : ndarray, shape (K,)
        Output epochs of the updates [s].
    z_b_radps, var_b_radps2 : ndarray, shape (K, 3)
        Measurement and its variance per body axis (variance inf where the update added no
        information to that axis).
    """
    t = np.asarray(fwd.t_s, dtype=float)
    k = np.searchsorted(t, np.asarray(fwd.update_t_s, dtype=float) - 1e-9)
    k = np.unique(k[(k > 0) & (k < t.size)])
    b = np.asarray(fwd.gyro_b_radps, dtype=float)
    p = np.square(np.asarray(fwd.gyro_sigma_b_radps, dtype=float))
    p_minus = p[k - 1] + fwd.bias_psd_radps2ps * (t[k] - t[k - 1])[:, None]
    p_plus = p[k]
    info = np.zeros_like(p_plus)
    np.divide(1.0, p_plus, out=info, where=p_plus > 0)
    info -= 1.0 / p_minus
    good = info > 1e-9 / p_minus
    var = np.full(info.shape, np.inf)
    var[good] = 1.0 / info[good]
    gain = np.where(good, 1.0 - p_plus / p_minus, 1.0)
    z = b[k - 1] + (b[k] - b[k - 1]) / gain
    return t[k], np.where(good, z, 0.0), var


def fitted_leg_bias(cal: Calibration, rep: LegReplay) -> NDArray:
    """The fit's estimate of the mean gyro error over one leg, body FRD [rad/s], (3,).

    b_c plus the conditional mean of the drift's mean over the leg; on a leg of the fit also
    the conditional mean of the white rate noise's mean over it (module docstring, item 1).
    """
    b = cal.gyro_bias_b_radps(rep.c_nb0) + cal.leg_drift_b_radps(rep)
    d = cal.drift
    if d is None or rep.leg.leg_id not in cal.leg_ids:
        return b
    length = float(rep.t_s[-1])
    inside = (d.tau_bin_s >= rep.t0_s) & (d.tau_bin_s <= rep.t0_s + length)
    return b + cal.gyro_arw_radpsqrts**2 / length * d.u[inside].sum(axis=0)


def flight_bias_b_radps(cal: Calibration, replays: Mapping[int, LegReplay]) -> NDArray:
    """The gyro bias over the flight's fitted legs, body FRD [rad/s], (3,): the legs'
    duration-weighted mean of :func:`fitted_leg_bias` (b_c plus the estimated mean drift and
    white rate noise over the legs: what the compensation used on them)."""
    reps = [replays[i] for i in cal.leg_ids if i in replays]
    w = np.array([float(r.t_s[-1]) for r in reps])
    return (w @ np.array([fitted_leg_bias(cal, r) for r in reps])) / w.sum()


def constant_history(cal: Calibration, replays: Mapping[int, LegReplay], t_s: NDArray
                     ) -> NDArray:
    """The constant b_c at run times ``t_s``, (N, 3) [rad/s] (``paper``: rotated into the body
    with each leg's attitude inside it, the first fitted leg's elsewhere)."""
    t = np.asarray(t_s, dtype=float)
    out = np.tile(cal.gyro_bias_b_radps(replays[cal.leg_ids[0]].c_nb0), (t.size, 1))
    if cal.formulation != "body":
        for rep in replays.values():
            out[(t >= rep.t0_s) & (t <= rep.t0_s + rep.t_s[-1])] = cal.gyro_bias_b_radps(
                rep.c_nb0)
    return out


def fit_bias_history(cal: Calibration, replays: Mapping[int, LegReplay], t_s: NDArray
                     ) -> NDArray:
    """m_B(t): the fit's estimate of the gyro error at run times ``t_s``, (N, 3) [rad/s].

    b_c plus the drift's conditional mean, and inside each leg of the fit that leg's
    :func:`fitted_leg_bias` (one value; the shape inside comes from A's estimates). The
    constant of ``paper`` is rotated into the body with the first fitted leg's attitude
    outside the legs, each leg's own inside.
    """
    t = np.asarray(t_s, dtype=float)
    first = replays[cal.leg_ids[0]]
    out = cal.gyro_bias_b_radps(first.c_nb0) + cal.drift_b_radps(t)
    for lid, rep in replays.items():
        inside = (t >= rep.t0_s) & (t <= rep.t0_s + rep.t_s[-1])
        if lid in cal.leg_ids:
            out[inside] = fitted_leg_bias(cal, rep)
        elif cal.formulation != "body":
            out[inside] += cal.gyro_bias_b_radps(rep.c_nb0) - cal.gyro_bias_b_radps(first.c_nb0)
    return out


def _on_grid(t_grid: NDArray, t_meas: NDArray, z: NDArray, var: NDArray
             ) -> tuple[NDArray, NDArray]:
    """Measurements combined per grid cell (inverse-variance), (N, 3) each; var inf: none."""
    step = t_grid[1] - t_grid[0] if t_grid.size > 1 else 1.0
    cell = np.clip(np.rint((t_meas - t_grid[0]) / step).astype(int), 0, t_grid.size - 1)
    w = np.where(np.isfinite(var), 1.0 / np.where(np.isfinite(var), var, 1.0), 0.0)
    wsum = np.zeros((t_grid.size, z.shape[1]))
    zsum = np.zeros_like(wsum)
    np.add.at(wsum, cell, w)
    np.add.at(zsum, cell, w * z)
    has = wsum > 0
    return (np.where(has, zsum / np.where(has, wsum, 1.0), 0.0),
            np.where(has, 1.0 / np.where(has, wsum, 1.0), np.inf))


def smoothed_bias_history(cal: Calibration, replays: Mapping[int, LegReplay],
                          fwd: ForwardBiases, alphas: tuple[float, ...] = A_NOISE_SCALES
                          ) -> tuple[NDArray, list[NDArray]]:
    """The smoothed gyro-bias history for each scale of A's noise (module docstring).

    Returns
    -------
    t_s : ndarray, shape (N,)
        The 1 s grid over A's outputs [s].
    histories : list of ndarray, shape (N, 3)
        m_B(t) + E[d(t) | A's measurements], one per ``alphas`` [rad/s].
    """
    t0, t1 = float(fwd.t_s[0]), float(fwd.t_s[-1])
    grid = np.arange(t0, t1 + 0.5 * GRID_STEP_S, GRID_STEP_S)
    m_b = fit_bias_history(cal, replays, grid)
    t_m, z, var = pseudo_measurements(fwd)
    zc, vc = _on_grid(grid, t_m, z, var)
    dz = zc - m_b
    sigma, tau = float(cal.gyro_gm_sigma_radps), float(cal.gyro_gm_tau_s)
    q = float(cal.gyro_arw_radpsqrts) ** 2
    f = np.exp(-GRID_STEP_S / np.array([tau if np.isfinite(tau) and tau > 0 else np.inf,
                                        WHITE_TAU_S]))
    s2 = np.array([sigma**2, q / (2.0 * WHITE_TAU_S)])
    s2 = np.maximum(s2, 1e-30)  # a component of zero variance: kept invertible, inert
    cols_z = np.concatenate([dz] * len(alphas), axis=1)
    cols_r = np.concatenate([vc * a for a in alphas], axis=1)
    sm = smooth_two_gm(np.ascontiguousarray(cols_z), np.ascontiguousarray(cols_r), f, s2)
    return grid, [m_b + sm[:, 3 * i:3 * i + 3] for i in range(len(alphas))]
