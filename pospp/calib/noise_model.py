"""Noise covariance models of B's velocity error along a leg, for the calibration's GLS.

The covariance of B's horizontal velocity error driven by white gyro noise (angle random walk,
``K``) and white accelerometer noise, A's correlated reference error (Matern / oscillator
kernels), the first-order Gauss-Markov body drift (:func:`gm_noise_operator`,
:class:`DriftSmoother`), and the composed :class:`NoiseModel`. Frames and units as
:mod:`pospp.calib.solve` (NED n, FRD b, SI); the equations are in its module docstring
("Noise").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from pospp.calib.replay import LegReplay
from pospp.nav.error_model import DV, PHI


def gyro_noise_covariance(rep: LegReplay, rows: NDArray | None = None) -> NDArray:
    """Covariance of B's [dv_N, dv_E] at chosen samples for unit white gyro noise.

    The gyro noise w (body, PSD 1 rad^2/s per axis, i.e. ARW 1 rad/s^0.5) drives
    phi' = ... - C_nb w, so ``dv(t_i) = -int_0^t_i Phi_v,phi(t_i, tau) C_nb(tau) w dtau`` with
    Phi(t_i, tau) = Phi(t_i, t0) Phi(tau, t0)^-1 from the leg's transition matrices; the
    integrand is taken linear inside each interval of the leg's sample grid (exact for the
    last interval before t_i, where Phi_v,phi(t_i, tau) falls to 0: a left Riemann sum would
    triple the variance of each sample's newest increment, the part that whitening weighs).

    Parameters
    ----------
    rep : LegReplay
    rows : ndarray of int, optional
        Sample indices (> 0) of the rows; all samples t > 0 when None.

    Returns
    -------
    ndarray, shape (2 R, 2 R)
        Sample-major like :func:`design_matrix` [(m/s)^2 per (rad^2/s)].
    """
    return _white_forcing_covariance(rep, PHI, rows)


def accel_noise_covariance(rep: LegReplay, rows: NDArray | None = None) -> NDArray:
    """Covariance of B's [dv_N, dv_E] at chosen samples for unit white accelerometer noise.

    The accelerometer noise w_a (body, PSD 1 (m/s^2)^2/s per axis, i.e. velocity random walk
    1 m/s^1.5) drives dv' = ... + C_nb w_a, so ``dv(t_i) = int Phi_v,v(t_i, tau) C_nb w_a
    dtau``; same quadrature and layout as :func:`gyro_noise_covariance`. It also stands for
    any error that acts on B's velocity as white acceleration noise (the strapdown's own
    numerical error on vibrating data, for one).
    """
    return _white_forcing_covariance(rep, DV, rows)


def forcing_increments(rep: LegReplay, cols: slice = PHI) -> tuple[NDArray, NDArray]:
    """The state-space form of :func:`gyro_noise_covariance` (``cols`` PHI) and
    :func:`accel_noise_covariance` (DV): per sample i > 0, ``g_i = Phi_v(t_i, t0)`` (2 x 15)
    and the increment ``dS_i = S(t_i) - S(t_i-1)`` (15 x 15, symmetric, >= 0) of the forcing's
    cumulative covariance, so that ``K_ij = g_i S(min(t_i, t_j)) g_j^T``: B's velocity error
    is ``g_i s_i`` with s a random walk of increments dS_i (what the diagnosis whitens with a
    Kalman filter, :mod:`pospp.diagnose._linear`). Shapes (M - 1, 2, 15), (M - 1, 15, 15).

    dv(t_i) = g_i int_0^t_i w(tau) dn(tau) with w(tau) = Phi(tau, t0)^-1 G(tau) (15 x 3);
    w is taken linear inside each interval of the grid (exact for the last interval before
    t_i, where Phi_v,phi(t_i, tau) falls to 0: a left Riemann sum would triple the variance
    of each sample's newest increment, the part that whitening weighs):
    ``int w w^T = dt (u u^T + v v^T)``, ``u = (w_k + w_k+1) / 2``,
    ``v = (w_k+1 - w_k) / (2 sqrt 3)``.
    """
    w = np.linalg.inv(rep.phi)[:, :, cols] @ rep.c_nb  # (M, 15, 3) at the grid points
    u = 0.5 * (w[:-1] + w[1:])
    v = (w[1:] - w[:-1]) / (2.0 * np.sqrt(3.0))
    dt = np.diff(rep.t_s)[:, None, None]
    return rep.phi[1:, 3:5, :], dt * (u @ u.transpose(0, 2, 1) + v @ v.transpose(0, 2, 1))


def _white_forcing_covariance(rep: LegReplay, cols: slice, rows: NDArray | None) -> NDArray:
    # Cov(dv_i, dv_j) = g_i S(min(t_i, t_j)) g_j^T (forcing_increments): one cumulative
    # 15 x 15 sum and one (2R x 15) (15 x 2R) product, where the integrand written out per
    # row and interval cost R M products
    idx = np.arange(1, rep.t_s.size) if rows is None else np.asarray(rows)
    g_all, ds = forcing_increments(rep, cols)
    g = g_all[idx - 1]  # (R, 2, 15)
    s_k = np.zeros((rep.t_s.size, 15, 15))
    np.cumsum(ds, axis=0, out=s_k[1:])
    n = 2 * idx.size
    q = s_k[idx] @ g.transpose(0, 2, 1)  # (R, 15, 2): S(t_j) g_j^T
    a = g.reshape(n, 15) @ q.transpose(1, 0, 2).reshape(15, n)  # g_i S(t_j) g_j^T
    later = np.repeat(np.repeat(idx[None, :] <= idx[:, None], 2, axis=0), 2, axis=1)
    cov = np.where(later, a, a.T)
    return 0.5 * (cov + cov.T)  # the (i, i) blocks are symmetric only to rounding


def matern32(lag_s: NDArray, length_s: float) -> NDArray:
    """Matern-3/2 correlation ``(1 + sqrt(3) |t| / l) exp(-sqrt(3) |t| / l)`` (unit at 0)."""
    x = np.sqrt(3.0) * np.abs(np.asarray(lag_s, dtype=float)) / length_s
    return (1.0 + x) * np.exp(-x)


def dmatern52(lag_s: NDArray, length_s: float) -> NDArray:
    """Correlation of the derivative of a Matern-5/2 process, ``(1 + x - x^2) exp(-x)``.

    ``x = sqrt(5) |t| / l``; unit at 0, zero integral (its spectrum vanishes at zero
    frequency): the velocity error of a solution whose position is held by GNSS fixes cannot
    stay of one sign (its integral, the position error, is bounded).
    """
    x = np.sqrt(5.0) * np.abs(np.asarray(lag_s, dtype=float)) / length_s
    return (1.0 + x - x * x) * np.exp(-x)


def oscillator(lag_s: NDArray, length_s: float, period_s: float) -> NDArray:
    """Correlation of a damped second-order oscillator (unit at 0, smooth at 0).

    ``exp(-|t| / T) (cos(w t) + sin(w |t|) / (w T))`` with T = ``length_s`` and
    w = 2 pi / ``period_s``: the closed-loop error of a GNSS-aided INS rings at the loop's
    own frequency (A's velocity error crosses zero and swings back within a few minutes).
    """
    t = np.abs(np.asarray(lag_s, dtype=float))
    w = 2.0 * np.pi / period_s
    return np.exp(-t / length_s) * (np.cos(w * t) + np.sin(w * t) / (w * length_s))


REFERENCE_CORRELATIONS = {"matern32": matern32, "dmatern52": dmatern52}
"""Correlation families of A's velocity error (:func:`reference_error_covariance`);
``"osc<P>"`` is :func:`oscillator` with period P seconds."""


def _reference_correlation(kind: str):
    if kind.startswith("osc"):
        period = float(kind[3:])
        return lambda lag, length: oscillator(lag, length, period)
    return REFERENCE_CORRELATIONS[kind]
"""Correlation families of A's velocity error (:func:`reference_error_covariance`)."""


def reference_error_covariance(rep: LegReplay, length_s: float, rows: NDArray | None = None,
                               kind: str = "matern32") -> NDArray:
    """Covariance of A's own error in B minus A for a unit-variance coloured A error.

    A's horizontal velocity error e(t) (NED N and E independent, unit variance, Matern-3/2
    correlation r of length ``length_s``, :func:`matern32`) enters B minus A twice: B starts
    from A's state, so A's error at the leg start is propagated by B's error dynamics, and A's
    error at t is subtracted::

        d(t_i) = Phi_v,v(t_i, t0) e(t0) - e(t_i)
        Cov(d_i, d_j) = r(0) P_i P_j^T - P_i r(t_j) - r(t_i) P_j^T + r(t_i - t_j) I

    with P_i = Phi_v,v(t_i, t0) (horizontal block, from the leg's transition matrices).
    A's tilt at the leg start is a parameter of every model (not noise).

    Parameters
    ----------
    rep : LegReplay
    length_s : float
        Correlation length l of A's velocity error [s].
    rows : ndarray of int, optional
        Sample indices (> 0); all samples t > 0 when None.
    kind : {"matern32", "dmatern52"}
        Correlation family r (:data:`REFERENCE_CORRELATIONS`).

    Returns
    -------
    ndarray, shape (2 R, 2 R)
        Sample-major like :func:`design_matrix` [(m/s)^2 per (m/s)^2].
    """
    corr = _reference_correlation(kind)
    idx = np.arange(1, rep.t_s.size) if rows is None else np.asarray(rows)
    t = rep.t_s[idx]
    p = rep.phi[idx][:, 3:5, 3:5]  # (R, 2, 2)
    r0 = corr(t, length_s)  # r(t_i - t0)
    c = np.einsum("iac,jbc->iajb", p, p)
    c -= p[:, :, None, :] * r0[None, None, :, None]
    c -= np.einsum("i,jba->iajb", r0, p)
    rij = corr(t[:, None] - t[None, :], length_s)
    c += rij[:, None, :, None] * np.eye(2)[None, :, None, :]
    n = 2 * idx.size
    c = c.reshape(n, n)
    return 0.5 * (c + c.T)


@dataclass(frozen=True)
class NoiseModel:
    """Covariance model of B minus A on one leg (the residual of the base model).

    ``Cov = a diag(sigma_A^2) + q K + s_A^2 G(l) (+ sigma_gm^2 S E S^T within the leg)``:
    a white part scaled from A's reported sigmas, B's velocity error driven by the gyro angle
    random walk (K, :func:`gyro_noise_covariance`), A's own coloured velocity error entering
    at the leg start and at t (G, :func:`reference_error_covariance`), and the within-leg part
    of a first-order Gauss-Markov gyro drift (:func:`gm_noise_operator`).

    Attributes
    ----------
    white_scale : float
        a (times A's velocity variances).
    gyro_arw_radpsqrts : float
        sqrt(q), gyro angle random walk [rad/s^0.5].
    reference_sigma_mps : float
        s_A, standard deviation of A's horizontal velocity error per axis [m/s].
    reference_length_s : float
        l, its Matern-3/2 correlation length [s].
    gyro_gm_sigma_radps, gyro_gm_tau_s : float
        Gauss-Markov drift (0 and inf: none).
    """

    white_scale: float
    gyro_arw_radpsqrts: float
    reference_sigma_mps: float
    reference_length_s: float
    gyro_gm_sigma_radps: float = 0.0
    gyro_gm_tau_s: float = np.inf
    accel_vrw_mpsqrts: float = 0.0
    reference_kind: str = "matern32"

    def leg_covariance(self, rep: LegReplay, rows: NDArray | None = None) -> NDArray:
        """Covariance (2 R, 2 R) of [dv_N, dv_E] at samples ``rows`` (all t > 0 if None)."""
        idx = np.arange(1, rep.t_s.size) if rows is None else np.asarray(rows)
        sq = rep.sigma_v_n_mps[idx, 0:2].reshape(-1)
        c = self.gyro_arw_radpsqrts**2 * gyro_noise_covariance(rep, idx)
        if self.accel_vrw_mpsqrts > 0:
            c += self.accel_vrw_mpsqrts**2 * accel_noise_covariance(rep, idx)
        if self.reference_sigma_mps > 0:
            c += self.reference_sigma_mps**2 * reference_error_covariance(
                rep, self.reference_length_s, idx, self.reference_kind)
        if self.gyro_gm_sigma_radps > 0 and np.isfinite(self.gyro_gm_tau_s):
            s, tb = gm_noise_operator(rep, idx)
            c += self.gyro_gm_sigma_radps**2 * gm_covariance([(s, tb)], self.gyro_gm_tau_s)
        c[np.diag_indices_from(c)] += self.white_scale * sq**2
        return c


REFERENCE_LENGTHS_S = (20.0, 60.0, 180.0)
"""Correlation lengths (damping times) of A's error tried by :func:`fit_noise_model` [s]."""
REFERENCE_KINDS = ("matern32", "osc60", "osc120", "osc240")
"""Correlation families of A's error tried by :func:`fit_noise_model` (profile REML)."""


def leg_rows(rep: LegReplay, step_s: float) -> NDArray:
    """Sample indices of one leg's replay every ``step_s`` [s] (the leg's median sample
    interval rounded to a whole step), from index ``step`` on (index 0 is B's start)."""
    dt_s = max(float(np.median(np.diff(rep.t_s))), 1e-9)
    step = max(1, int(round(step_s / dt_s)))
    return np.arange(step, rep.t_s.size, step)


@dataclass(frozen=True)
class NoiseBasis:
    """One leg's noise model in the eigenbasis of its gyro-noise covariance (for GLS).

    With D = diag(sigma_A^2) and K' = D^-1/2 K D^-1/2 = U diag(lam) U^T,
    Cov = a D + q K = D^1/2 U diag(a + q lam) U^T D^1/2, so any (a, q) costs O(n P).

    Attributes
    ----------
    samples : ndarray of int, shape (R,)
        Sample indices (> 0) of the leg used by the GLS.
    rows : ndarray of int, shape (2 R,)
        Matching rows of the leg's block of :func:`design_matrix`.
    sq : ndarray, shape (2 R,)
        sigma_A at those rows [m/s].
    u : ndarray, shape (2 R, 2 R)
    lam : ndarray, shape (2 R,)
        Eigenvectors and eigenvalues of K' [per rad^2/s].
    """

    samples: NDArray
    rows: NDArray
    sq: NDArray
    u: NDArray
    lam: NDArray


def noise_basis(rep: LegReplay, *, noise_step_s: float = 10.0) -> NoiseBasis:
    """The :class:`NoiseBasis` of a leg, on samples every ``noise_step_s`` seconds.

    A leg shorter than ten steps is sampled every tenth of its length instead, so that every
    leg contributes rows however short it is (a 6 s leg would otherwise have none).
    """
    dt_s = max(float(np.median(np.diff(rep.t_s))), 1e-9) if rep.t_s.size > 1 else 1.0
    span_s = float(rep.t_s[-1] - rep.t_s[0]) if rep.t_s.size > 1 else 0.0
    step_s = min(noise_step_s, span_s / 10.0) if span_s > 0 else noise_step_s
    step = max(1, int(round(step_s / dt_s)))
    smp = np.arange(step, rep.t_s.size, step)
    rows = (2 * (smp - 1)[:, None] + np.arange(2)[None, :]).reshape(-1)
    sq = rep.sigma_v_n_mps[smp, 0:2].reshape(-1)
    kp = gyro_noise_covariance(rep, smp) / np.outer(sq, sq)
    lam, u = np.linalg.eigh(0.5 * (kp + kp.T))
    return NoiseBasis(smp, rows, sq, u, np.clip(lam, 0.0, None))


def leg_noise_basis(rep: LegReplay, noise_step_s: float, bases: Mapping | None = None,
                    memo: dict | None = None) -> NoiseBasis:
    """The leg's :func:`noise_basis`: ``bases[leg id]`` when there, else ``memo``'s (a fit's
    ``noise_cache``, shared by refits of the same legs: the basis reads the leg's samples,
    sigmas and transition, not B minus A), else made now (and kept in ``memo``)."""
    lid = rep.leg.leg_id
    basis = None if bases is None else bases.get(lid)
    if basis is None and memo is not None:
        basis = memo.get(("basis", lid, noise_step_s))
    if basis is None:
        basis = noise_basis(rep, noise_step_s=noise_step_s)
        if memo is not None:
            memo[("basis", lid, noise_step_s)] = basis
    return basis


DRIFT_ROWS = 512
"""Times at which :meth:`DriftSmoother.mean_b_radps` evaluates the drift at once."""


@dataclass(frozen=True)
class DriftSmoother:
    """Conditional mean of the Gauss-Markov gyro drift given a fit's residuals (BLUP).

    With the drift piecewise constant on bins j (run times ``tau_bin_s``), prior
    Cov(x(t), x_j) = sigma^2 exp(-|t - tau_j| / tau) I_3 and the GLS residual r of the fit
    (covariance C), the smoothed drift is
    ``E[x(t) | r] = sigma^2 sum_j exp(-|t - tau_j| / tau) u_j`` with ``u = S^T C^-1 r``, S
    the map from the drift bins to B's velocity errors (:func:`gm_noise_operator`).

    Attributes
    ----------
    tau_bin_s : ndarray, shape (J,)
        Run times of the drift bins of the fitted legs [s].
    u : ndarray, shape (J, 3)
        S^T C^-1 r per bin and body axis [(rad/s)^-1 ... per rad/s of drift].
    sigma2 : float
        Steady-state variance of the drift [(rad/s)^2].
    tau_s : float
        Correlation time [s].
    """

    tau_bin_s: NDArray
    u: NDArray
    sigma2: float
    tau_s: float

    def mean_b_radps(self, t_s: NDArray) -> NDArray:
        """E[x(t) | r] at run times ``t_s`` (body FRD, rad/s), shape (N, 3): the kernel
        matrix exp(-|t - tau_j| / tau) made :data:`DRIFT_ROWS` times at a time (the whole
        one is (N, J))."""
        t = np.asarray(t_s, dtype=float)
        out = np.empty((t.size, 3))
        for a in range(0, t.size, DRIFT_ROWS):
            e = np.exp(-np.abs(t[a:a + DRIFT_ROWS, None] - self.tau_bin_s[None, :])
                       / self.tau_s)
            out[a:a + DRIFT_ROWS] = self.sigma2 * (e @ self.u)
        return out

    def mean_over_b_radps(self, t_s: NDArray) -> NDArray:
        """The mean of E[x(t) | r] over the run times ``t_s`` (body FRD, rad/s), shape (3,):
        ``mean_b_radps(t_s).mean(axis=0)``, with each bin outside [t_min, t_max] factored out
        of the sum, ``exp(-(t - tau_j) / tau) = exp(-(t_min - tau_j) / tau) exp(-(t - t_min)
        / tau)`` for tau_j <= t_min (mirrored after t_max): a leg's mean reads its own bins
        at every sample, the other legs' once."""
        t = np.asarray(t_s, dtype=float)
        t0, t1, tb = float(t.min()), float(t.max()), self.tau_bin_s
        before, after = tb <= t0, tb >= t1
        inside = ~(before | after)
        w = np.empty(tb.size)
        w[before] = np.exp(-(t0 - tb[before]) / self.tau_s) * np.mean(
            np.exp(-(t - t0) / self.tau_s))
        w[after] = np.exp(-(tb[after] - t1) / self.tau_s) * np.mean(
            np.exp(-(t1 - t) / self.tau_s))
        w[inside] = np.mean(np.exp(-np.abs(t[:, None] - tb[None, inside]) / self.tau_s),
                            axis=0)
        return self.sigma2 * (w @ self.u)


def gm_noise_operator(rep: LegReplay, rows: NDArray | None = None, *, bin_s: float = 5.0
                      ) -> tuple[NDArray, NDArray]:
    """Map from a piecewise-constant body gyro drift to B's [dv_N, dv_E] at chosen samples.

    B's velocity error from a drift history x(tau) (body, rad/s) is
    ``dv(t_i) = int_0^t_i Phi_v,phi(t_i, tau) (-C_nb(tau)) x(tau) dtau`` (the time-varying
    analogue of Phi_v,bg), with Phi(t_i, tau) = Phi(t_i, t0) Phi(tau, t0)^-1 from the leg's
    transition matrices; the integral is a left Riemann sum on the leg's sample grid, and x is
    held constant over bins of ``bin_s`` seconds (fine for correlation times >> bin_s).

    Parameters
    ----------
    rep : LegReplay
    rows : ndarray of int, optional
        Sample indices (> 0); all samples t > 0 when None.
    bin_s : float
        Width of the drift bins [s].

    Returns
    -------
    s : ndarray, shape (2 R, 3 J)
        Sample-major rows like :func:`design_matrix`; columns bin-major, axis-minor
        [m/s per rad/s].
    tau_bin_s : ndarray, shape (J,)
        Run times of the bin centres [s].
    """
    idx = np.arange(1, rep.t_s.size) if rows is None else np.asarray(rows)
    g = rep.phi[idx, 3:5, :]  # (R, 2, 15)
    w = -(np.linalg.inv(rep.phi[:-1])[:, :, PHI] @ rep.c_nb[:-1])  # (M-1, 15, 3)
    dt = np.diff(rep.t_s)
    s = np.einsum("iaj,kjb->iakb", g, w, optimize=True) * dt[None, None, :, None]
    mask = idx[:, None] > np.arange(rep.t_s.size - 1)[None, :]  # tau_k < t_i
    s *= mask[:, None, :, None]
    tau_k = rep.t_s[:-1]
    b = np.floor(tau_k / bin_s).astype(int)
    nb = int(b[-1]) + 1
    sb = np.zeros((idx.size, 2, nb, 3))
    # cast: numpy's stubs take no slices in ufunc.at's index
    np.add.at(sb, cast(Any, (slice(None), slice(None), b)), s)
    # bin centre: the mean sample time of the bin (weights dt)
    centre = np.bincount(b, weights=(tau_k + 0.5 * dt) * dt, minlength=nb) / np.maximum(
        np.bincount(b, weights=dt, minlength=nb), 1e-12)
    return sb.reshape(2 * idx.size, 3 * nb), rep.t0_s + centre


def gm_covariance(ops: list[tuple[NDArray, NDArray]], tau_s: float) -> NDArray:
    """S E S^T over several legs: unit-variance drift, E = exp(-|tau_j - tau_k| / tau) I_3.

    S is block-diagonal (each leg's rows see only its own drift bins), so the blocks are
    ``G_LM = sum_axes S_L,a E_LM S_M,a^T``.
    """
    sp = [o[0].reshape(o[0].shape[0], -1, 3) for o in ops]
    edges = np.concatenate([[0], np.cumsum([o[0].shape[0] for o in ops])])
    out = np.zeros((edges[-1], edges[-1]))
    for i, (si, (_, ti)) in enumerate(zip(sp, ops, strict=True)):
        for j in range(i, len(ops)):
            e = np.exp(-np.abs(ti[:, None] - ops[j][1][None, :]) / tau_s)
            blk = sum(si[:, :, ax] @ e @ sp[j][:, :, ax].T for ax in range(3))
            out[edges[i]:edges[i + 1], edges[j]:edges[j + 1]] = blk
            out[edges[j]:edges[j + 1], edges[i]:edges[i + 1]] = blk.T
    return out
