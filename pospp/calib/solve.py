"""Least-squares calibration of misalignment and gyro drift from B-minus-A velocity errors.

Frames and units: NED navigation frame n, FRD body frame b, SI (rad, rad/s, m/s). Errors are
computed minus true (B minus A); the misalignment phi satisfies C_nb_hat = (I - [phi x]) C_nb;
the gyro reads true + bias.

For each leg, B's horizontal velocity error obeys the linear error model (15 states,
:mod:`pospp.nav.error_model`)::

    dv_h(t) = Phi_v,phi(t, t0) phi0 + Phi_v,bg(t, t0) b_g        (+ A's error, + noise)

with Phi from F(t) along B's actual trajectory (``transition="numerical"``) or the closed forms
of an ideal leg (``transition="closed_form"``: paper Eq. 10 and 13 with the signs of its own
F, :mod:`pospp.nav.closed_form`). Stacking the samples of two legs gives the paper's Eq. 17,
``Z = H X``, solved by (generalised) least squares.

Formulations (docs/calibration.md, "Formulations")
-------------------------------------------------
``paper``
    X = [phi_N, phi_E, phi_D, eps_N, eps_E]: one misalignment and one *navigation-frame*
    horizontal drift common to both legs, as Liu & Fang print it (signs corrected). The
    paper's X_p = [phi_x, phi_y, phi_z, eps_E, eps_N] (ENU) is
    ``pospp.nav.closed_form.PAPER_FROM_NED @ X``.
``body``
    Per-leg tilts [phi_N, phi_E] (B's initial tilt is A's error at that leg's start, and it
    also absorbs the accelerometer bias, whose Schuler response is identical), one heading
    error phi_D common to the legs, and the gyro bias fixed in the body frame [b_x, b_y]
    (FRD, optionally b_z), projected into each leg by that leg's attitude through
    Phi_v,bg(t) = int Phi_v,phi(t, tau) (-C_nb(tau)) dtau.

Noise (``noise=``)
------------------
``"gyro_rw"`` (default)
    Generalised least squares with, per leg, Cov(dv) = a diag(sigma_A^2) + q K, where K is
    the covariance of B's velocity error driven by unit white gyro noise (angle random walk,
    isotropic in the body frame), K = int Phi_v,phi(t_i, tau) C_nb C_nb^T Phi_v,phi(t_j, tau)^T
    dtau, computed from the same transition matrices. The random walk makes the residuals
    strongly correlated in time; ignoring it gives sigmas ten times too small. a and q are
    estimated by restricted maximum likelihood (REML) unless q is given from the IMU
    specification (``gyro_arw_radpsqrts``).
    With ``gyro_gm_tau_s`` (and optionally ``gyro_gm_sigma_radps``), a first-order
    Gauss-Markov body drift x_g is added: Cov += sigma_gm^2 S E S^T, where S maps the drift
    (piecewise constant on bins) to B's velocity errors through the same transition matrices,
    ``dv(t) = int Phi_v,phi(t, tau) (-C_nb) x_g(tau) dtau``, and
    E_jk = exp(-|tau_j - tau_k| / tau_gm) between bins of any two legs (run times): the legs
    are coupled and the GLS uses the full covariance. The fit then also carries the drift's
    conditional mean (:class:`DriftSmoother`).
``"white"``
    Weighted least squares with A's sigmas, the covariance scaled by the a-posteriori variance
    factor and by (1 + rho) / (1 - rho) from the residuals' lag-one autocorrelation rho.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray
from scipy import linalg, optimize

from pospp.calib.replay import LegReplay
from pospp.nav.error_model import BG, DV, PHI

FORMULATIONS = ("paper", "body")
TRANSITIONS = ("numerical", "closed_form")
NOISE_MODELS = ("gyro_rw", "white")
GM_PRIOR_LOG_SD = float(np.log(10.0))
"""1-sigma of the grade's weak log-normal prior on the drift's sigma and tau (one decade)."""
GM_TAUS_S = tuple(float(v) for v in np.geomspace(60.0, 86400.0, 15))
GM_REJECT_DNLL = 0.5 * 5.991
"""The flight's drift replaces the grade's only when the grade's (sigma, tau) is rejected by a
likelihood-ratio test at 5 % (chi-square, 2 degrees of freedom: 2 dnll > 5.991)."""
"""Candidate drift correlation times of the profile REML [s] (60 s to 1 day, ratio 1.68)."""


@dataclass(frozen=True)
class DriftPrior:
    """The IMU grade's Gauss-Markov drift as a weak prior of the flight's own estimate.

    The drift's level and correlation time are estimated from the flight (REML across the legs
    of the joint fit), penalised by ``0.5 ((ln sigma - ln sigma_g) / log_sd)^2 +
    0.5 ((ln tau - ln tau_g) / log_sd)^2`` (a log-normal prior, one decade 1-sigma by
    default), tau profiled over ``taus_s``. The flight's estimate is kept only when it
    rejects the grade's drift: when the restricted likelihood at the grade's (sigma, tau)
    (a and q re-fitted) is within :data:`GM_REJECT_DNLL` of the estimate's, the grade's drift
    is used (the likelihood is flat there: a drift too small, too slow or too close to the
    ARW for the legs to see).

    Attributes
    ----------
    sigma_radps : float
        The grade's steady-state drift sigma [rad/s] (body, per axis).
    tau_s : float
        The grade's correlation time [s].
    taus_s : tuple of float
        Candidate correlation times [s] (the grade's is added).
    log_sd : float
        1-sigma of the prior on ln sigma and on ln tau.
    """

    sigma_radps: float
    tau_s: float
    taus_s: tuple[float, ...] = GM_TAUS_S
    log_sd: float = GM_PRIOR_LOG_SD

    def candidates_s(self) -> tuple[float, ...]:
        """Sorted candidate taus with the grade's [s]."""
        return tuple(sorted(set(self.taus_s) | {float(self.tau_s)}))

    def penalty(self, sigma2_radps2: float, tau_s: float) -> float:
        """Negative log prior (constants dropped) of a drift variance and correlation time."""
        ls = 0.5 * np.log(max(sigma2_radps2, 1e-300)) - np.log(self.sigma_radps)
        lt = np.log(tau_s) - np.log(self.tau_s)
        return 0.5 * float(ls**2 + lt**2) / self.log_sd**2


@dataclass(frozen=True)
class Calibration:
    """Result of one least-squares calibration over a set of legs.

    Attributes
    ----------
    formulation, transition, noise : str
    leg_ids : tuple of int
    names : tuple of str
        Parameter names (SI: rad, rad/s), see :func:`parameter_names`.
    x : ndarray, shape (P,)
        Estimates.
    cov : ndarray, shape (P, P)
        Covariance of the estimates.
    cond_raw, cond_scaled : float
        Condition number of the stacked weighted matrix in SI units (as the paper), and after
        scaling every column to unit norm (unit-independent).
    residuals_n_mps : tuple of ndarray, shape (M_i - 1, 2)
        Per leg, measured minus modelled [dv_N, dv_E] at the samples t > 0.
    residual_rms_mps : float
        RMS of all residuals.
    n_samples : int
        Number of scalar velocity samples.
    variance_factor : float
        ``"white"``: a-posteriori factor times the autocorrelation inflation; ``"gyro_rw"``: a,
        the estimated scale of A's velocity variances.
    gyro_arw_radpsqrts : float
        Angle random walk of the noise model [rad/s^0.5] (0 for ``"white"``).
    whitened_rms, whitened_lag1 : float
        RMS and lag-one autocorrelation of the whitened residuals (about 1 and 0 when the
        noise model fits).
    rank_deficient : bool
        True when directions of X were unobservable and left at zero (pseudo-inverse).
    gyro_gm_sigma_radps, gyro_gm_tau_s : float
        Gauss-Markov gyro drift of the noise model (steady-state sigma [rad/s], correlation
        time [s]); 0 and inf when the model has none.
    drift : DriftSmoother or None
        Conditional mean of the Gauss-Markov drift given this fit's residuals (None without
        a Gauss-Markov component), see :meth:`drift_b_radps`.
    gm_tau_profile : tuple of (float, float)
        (tau [s], negative restricted log-likelihood plus the grade's prior) per candidate
        correlation time when the drift was estimated with a :class:`DriftPrior` (else empty).
    gm_source : str
        With a :class:`DriftPrior`: "flight" (the estimate rejects the grade's drift) or
        "grade" (it does not: the grade's sigma and tau are used); else "".
    """

    formulation: str
    transition: str
    noise: str
    leg_ids: tuple[int, ...]
    names: tuple[str, ...]
    x: NDArray
    cov: NDArray
    cond_raw: float
    cond_scaled: float
    residuals_n_mps: tuple[NDArray, ...]
    residual_rms_mps: float
    n_samples: int
    variance_factor: float
    gyro_arw_radpsqrts: float
    whitened_rms: float
    whitened_lag1: float
    rank_deficient: bool
    gyro_gm_sigma_radps: float = 0.0
    gyro_gm_tau_s: float = np.inf
    drift: DriftSmoother | None = None
    gm_tau_profile: tuple[tuple[float, float], ...] = ()
    gm_source: str = ""

    def drift_b_radps(self, t_s: NDArray) -> NDArray:
        """Smoothed Gauss-Markov drift (body FRD, rad/s) at run times ``t_s``, shape (N, 3).

        Zeros when the noise model has no Gauss-Markov component.
        """
        t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
        if self.drift is None:
            return np.zeros((t_s.size, 3))
        return self.drift.mean_b_radps(t_s)

    def leg_drift_b_radps(self, rep: LegReplay) -> NDArray:
        """Mean smoothed drift over one leg's samples (body FRD, rad/s), shape (3,).

        Works for any leg, in the fit or not (a held-out leg gets the prediction from the
        drift's correlation with the fitted legs).
        """
        return self.drift_b_radps(rep.t0_s + rep.t_s).mean(axis=0)

    @property
    def sigma(self) -> NDArray:
        """1-sigma of each estimate (SI)."""
        return np.sqrt(np.diag(self.cov))

    def value(self, name: str) -> float:
        """Estimate of one parameter (SI)."""
        return float(self.x[self.names.index(name)])

    def sigma_of(self, name: str) -> float:
        """1-sigma of one parameter (SI)."""
        i = self.names.index(name)
        return float(np.sqrt(self.cov[i, i]))

    def gyro_bias_b_radps(self, c_nb: NDArray | None = None) -> NDArray:
        """Body-frame gyro bias implied by the calibration [rad/s], shape (3,).

        For ``body`` it is the estimate (z = 0 unless estimated); for ``paper`` the
        navigation-frame drift [eps_N, eps_E, 0] is rotated into the body by ``c_nb`` (the
        attitude of the leg it is applied to), as the paper's model implies.
        """
        if self.formulation == "body":
            b = np.zeros(3)
            for i, ax in enumerate("xyz"):
                if f"gyro_bias_{ax}" in self.names:
                    b[i] = self.value(f"gyro_bias_{ax}")
            return b
        if c_nb is None:
            raise ValueError("paper formulation: the attitude c_nb of the target leg is needed")
        eps_n = np.array([self.value("eps_n"), self.value("eps_e"), 0.0])
        return np.asarray(c_nb).T @ eps_n

    def misalignment_n_rad(self, leg_id: int) -> NDArray:
        """B's initial misalignment phi (NED, rad) at a leg of this calibration."""
        if self.formulation == "paper":
            return np.array([self.value("phi_n"), self.value("phi_e"), self.value("phi_d")])
        return np.array(
            [self.value(f"phi_n_leg{leg_id}"), self.value(f"phi_e_leg{leg_id}"),
             self.value("phi_d")]
        )


def parameter_names(formulation: str, leg_ids: tuple[int, ...], *, estimate_gyro_z: bool = False
                    ) -> tuple[str, ...]:
    """Parameter names of a formulation, in the order of X (NED / FRD, SI)."""
    if formulation == "paper":
        return ("phi_n", "phi_e", "phi_d", "eps_n", "eps_e")
    if formulation == "body":
        names: list[str] = []
        for i in leg_ids:
            names += [f"phi_n_leg{i}", f"phi_e_leg{i}"]
        names += ["phi_d", "gyro_bias_x", "gyro_bias_y"]
        if estimate_gyro_z:
            names.append("gyro_bias_z")
        return tuple(names)
    raise ValueError(f"formulation: expected one of {FORMULATIONS}, got {formulation!r}")


def leg_sensitivities(rep: LegReplay, transition: str) -> tuple[NDArray, NDArray]:
    """(d dv_h / d phi0, d dv_h / d b_g), each (M, 2, 3), at the leg's samples.

    ``numerical``: blocks of the 15-state Phi along B's trajectory. ``closed_form``: paper
    Eq. 10/13 (pospp signs) at B's initial latitude, height and velocity; the body bias enters
    through the leg's initial attitude, eps_n = C_nb0 b_g (no vertical drift column).
    """
    if transition == "numerical":
        return rep.phi[:, 3:5, PHI], rep.phi[:, 3:5, BG]
    if transition == "closed_form":
        from pospp.nav import closed_form

        rows = closed_form.velocity_error_rows(
            rep.t_s, lat_rad=rep.lat_rad, height_m=rep.height_m, v_n_mps=rep.v_n0_mps
        )  # (M, 2, 5) over [phi_N, phi_E, phi_D, eps_N, eps_E]
        return rows[:, :, 0:3], rows[:, :, 3:5] @ rep.c_nb0[0:2, :]
    raise ValueError(f"transition: expected one of {TRANSITIONS}, got {transition!r}")


def _leg_design(rep: LegReplay, formulation: str, names: tuple[str, ...], transition: str,
                estimate_gyro_z: bool) -> NDArray:
    """Rows (M - 1, 2, P) of one leg (the t = 0 rows are identically zero and dropped)."""
    d_phi, d_bg = leg_sensitivities(rep, transition)
    col = {n: i for i, n in enumerate(names)}
    h = np.zeros((rep.t_s.size, 2, len(names)))
    if formulation == "paper":
        h[:, :, 0:3] = d_phi
        # constant navigation-frame drift: b_g = C_bn0 eps_n on a straight leg
        d_eps = d_bg @ rep.c_nb0.T
        h[:, :, 3] = d_eps[:, :, 0]
        h[:, :, 4] = d_eps[:, :, 1]
    else:
        i = rep.leg.leg_id
        h[:, :, col[f"phi_n_leg{i}"]] = d_phi[:, :, 0]
        h[:, :, col[f"phi_e_leg{i}"]] = d_phi[:, :, 1]
        h[:, :, col["phi_d"]] = d_phi[:, :, 2]
        h[:, :, col["gyro_bias_x"]] = d_bg[:, :, 0]
        h[:, :, col["gyro_bias_y"]] = d_bg[:, :, 1]
        if estimate_gyro_z:
            h[:, :, col["gyro_bias_z"]] = d_bg[:, :, 2]
    return h[1:]


def design_matrix(
    legs: tuple[LegReplay, ...],
    formulation: str,
    *,
    transition: str = "numerical",
    estimate_gyro_z: bool = False,
) -> tuple[NDArray, NDArray, NDArray, tuple[str, ...]]:
    """Stacked system of Eq. 17: (H (m, P), z (m,), sigma (m,), names).

    Rows are [dv_N, dv_E] of every sample t > 0 of every leg, sample-major, in leg order.
    """
    if transition not in TRANSITIONS:
        raise ValueError(f"transition: expected one of {TRANSITIONS}, got {transition!r}")
    ids = tuple(r.leg.leg_id for r in legs)
    if len(set(ids)) != len(ids):
        raise ValueError(f"legs: expected distinct leg ids, got {ids}")
    names = parameter_names(formulation, ids, estimate_gyro_z=estimate_gyro_z)
    h = [_leg_design(r, formulation, names, transition, estimate_gyro_z).reshape(-1, len(names))
         for r in legs]
    z = [r.dv_n_mps[1:, 0:2].reshape(-1) for r in legs]
    s = [r.sigma_v_n_mps[1:, 0:2].reshape(-1) for r in legs]
    return np.vstack(h), np.concatenate(z), np.concatenate(s), names


def condition_numbers(h_weighted: NDArray) -> tuple[float, float]:
    """(raw, column-scaled) 2-norm condition numbers of a stacked matrix."""
    sv = np.linalg.svd(h_weighted, compute_uv=False)
    raw = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
    norms = np.linalg.norm(h_weighted, axis=0)
    if np.any(norms == 0):
        return raw, np.inf
    sv2 = np.linalg.svd(h_weighted / norms, compute_uv=False)
    return raw, float(sv2[0] / sv2[-1]) if sv2[-1] > 0 else np.inf


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


def _white_forcing_covariance(rep: LegReplay, cols: slice, rows: NDArray | None) -> NDArray:
    idx = np.arange(1, rep.t_s.size) if rows is None else np.asarray(rows)
    g = rep.phi[idx, 3:5, :]  # (R, 2, 15)
    w = np.linalg.inv(rep.phi)[:, :, cols] @ rep.c_nb  # (M, 15, 3) at the grid points
    f = np.einsum("iaj,kjb->iakb", g, w, optimize=True)  # integrand at tau_k
    sdt = np.sqrt(np.diff(rep.t_s))[None, None, :, None]
    mask = (idx[:, None] > np.arange(rep.t_s.size - 1)[None, :])[:, None, :, None]
    # integrand linear inside each interval (exact for its last one, where it falls to 0):
    # int f f^T = u u^T + v v^T with u = (f_k + f_k+1) / 2, v = (f_k+1 - f_k) / (2 sqrt 3)
    u = 0.5 * (f[:, :, :-1] + f[:, :, 1:]) * sdt * mask
    v = (f[:, :, 1:] - f[:, :, :-1]) * (sdt / (2.0 * np.sqrt(3.0))) * mask
    n = 2 * idx.size
    u = u.reshape(n, -1)
    v = v.reshape(n, -1)
    return u @ u.T + v @ v.T


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
            c += self.gyro_gm_sigma_radps**2 * _gm_covariance([(s, tb)], self.gyro_gm_tau_s)
        c[np.diag_indices_from(c)] += self.white_scale * sq**2
        return c


REFERENCE_LENGTHS_S = (20.0, 60.0, 180.0)
"""Correlation lengths (damping times) of A's error tried by :func:`fit_noise_model` [s]."""
REFERENCE_KINDS = ("matern32", "osc60", "osc120", "osc240")
"""Correlation families of A's error tried by :func:`fit_noise_model` (profile REML)."""


def _leg_rows(rep: LegReplay, step_s: float) -> NDArray:
    dt_s = max(float(np.median(np.diff(rep.t_s))), 1e-9)
    step = max(1, int(round(step_s / dt_s)))
    return np.arange(step, rep.t_s.size, step)


def _blocks_reml_nll(params: NDArray, mats: list[tuple], hs: list[NDArray],
                     zs: list[NDArray]) -> float:
    """Negative restricted log-likelihood over independent leg blocks (constants dropped).

    Each leg's covariance is ``sum_k params[k] M_k`` (its matrices in ``mats``).
    """
    logdet = 0.0
    hw_all, zw_all = [], []
    for m, h, z in zip(mats, hs, zs, strict=True):
        w = _chol_whiten(sum(p * mk for p, mk in zip(params, m, strict=True)), h, z)
        if w is None:
            return 1e30
        hw_all.append(w[0])
        zw_all.append(w[1])
        logdet += w[2]
    hw, zw = np.vstack(hw_all), np.concatenate(zw_all)
    return _reml_whitened(hw, zw, logdet)


def _chol_whiten(c: NDArray, h: NDArray, z: NDArray) -> tuple[NDArray, NDArray, float] | None:
    """(L^-1 H, L^-1 z, log det C) with C = L L^T (Cholesky); None when C is not positive
    definite."""
    try:
        ll = np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        return None
    return _tri_solve(ll, h), _tri_solve(ll, z), 2.0 * float(np.sum(np.log(np.diag(ll))))


def _grid_argmin(
    obj, bounds: list[tuple[float, float]], n: int
) -> tuple[NDArray, list[NDArray]]:
    """The best point of an n-per-axis grid over ``bounds`` (the start of the REML searches).

    Returns (best point, the grid's axes).
    """
    axes = [np.linspace(lo, hi, n) for lo, hi in bounds]
    grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    vals = [obj(th) for th in grid]
    return grid[int(np.argmin(vals))], axes


def _reml_whitened(hw: NDArray, zw: NDArray, logdet: float) -> float:
    """Negative restricted log-likelihood from the whitened system and log det Cov.

    ``0.5 (log det C + log det H^T C^-1 H + r^T C^-1 r)`` (constants dropped), with the
    information's determinant from the column-scaled SVD (rank-deficient directions dropped).
    """
    norms, u, sv, _, keep = _scaled_svd(hw)
    proj = u[:, keep].T @ zw
    rss = float(zw @ zw - proj @ proj)
    info = 2.0 * float(np.sum(np.log(sv[keep])) + np.sum(np.log(norms)))
    return 0.5 * (logdet + info + rss)


def fit_noise_model(
    legs: tuple[LegReplay, ...],
    formulation: str = "body",
    *,
    transition: str = "numerical",
    estimate_gyro_z: bool = False,
    noise_step_s: float = 3.0,
    gyro_arw_radpsqrts: float | None = None,
    reference_lengths_s: tuple[float, ...] = REFERENCE_LENGTHS_S,
    reference_kinds: tuple[str, ...] = REFERENCE_KINDS,
    gyro_gm_taus_s: tuple[float, ...] = (),
) -> NoiseModel:
    """Fit :class:`NoiseModel` by restricted maximum likelihood on the base model's residual.

    The base model of ``formulation`` is the fixed effect. The variances a, q (unless
    ``gyro_arw_radpsqrts`` is given), s_A^2 and, when ``gyro_gm_taus_s`` is not empty, the
    Gauss-Markov drift's sigma^2 are estimated by REML (a coarse grid, then Nelder-Mead on
    their logs) for each correlation length l of A's error in ``reference_lengths_s``; the l
    with the largest restricted likelihood is kept (profile REML), then, with that l, each
    drift correlation time of ``gyro_gm_taus_s`` (the grade's value and its neighbours: the
    grade serves as the candidates, the flight's data choose). The legs are independent
    blocks: A's errors at legs separated by turns of more than a few l are uncorrelated
    (r(5 l) < 1e-3), and only the drift's within-leg part is modelled. Samples every
    ``noise_step_s`` seconds (shorter than the smallest l).
    """
    h, z, _, _ = design_matrix(legs, formulation, transition=transition,
                               estimate_gyro_z=estimate_gyro_z)
    sizes = [2 * (r.t_s.size - 1) for r in legs]
    edges = np.concatenate([[0], np.cumsum(sizes)])
    rows, hs, zs, base = [], [], [], []
    for i, rep in enumerate(legs):
        smp = _leg_rows(rep, noise_step_s)
        rr = (2 * (smp - 1)[:, None] + np.arange(2)[None, :]).reshape(-1) + edges[i]
        sq = rep.sigma_v_n_mps[smp, 0:2].reshape(-1)
        rows.append(smp)
        hs.append(h[rr] / sq[:, None])
        zs.append(z[rr] / sq)
        base.append((np.eye(sq.size), gyro_noise_covariance(rep, smp) / np.outer(sq, sq),
                     accel_noise_covariance(rep, smp) / np.outer(sq, sq), sq))
    q_fixed = None if gyro_arw_radpsqrts is None else float(gyro_arw_radpsqrts) ** 2
    ops: list[tuple[NDArray, NDArray] | None] = [None] * len(legs)
    if gyro_gm_taus_s:
        ops = []
        for rep, smp, (_, _, _, sq) in zip(legs, rows, base, strict=True):
            s_op, tb = gm_noise_operator(rep, smp)
            ops.append((s_op / sq[:, None], tb))

    def fit(length: float, tau: float | None, kind: str) -> tuple[float, NoiseModel]:
        mats = []
        for rep, smp, (eye, k, ka, sq), op in zip(legs, rows, base, ops, strict=True):
            g = reference_error_covariance(rep, length, smp, kind) / np.outer(sq, sq)
            m = [eye, k, ka, g]
            if tau is not None:
                assert op is not None  # a tau only when gyro_gm_taus_s built the operators
                m.append(_gm_covariance([op], tau))
            mats.append(tuple(m))
        free_q = q_fixed is None
        lo = [np.log(1e-8)] + ([np.log(1e-22)] if free_q else []) + [np.log(1e-16)] * 2
        hi = [np.log(1e4)] + ([np.log(1e-6)] if free_q else []) + [np.log(1e-4), np.log(1e-2)]
        if tau is not None:
            lo.append(np.log(1e-20))
            hi.append(np.log(1e-8))

        def unpack(theta: NDArray) -> NDArray:
            v = np.exp(theta)
            q = v[1] if free_q else q_fixed
            j = 2 if free_q else 1
            out = [v[0], q, v[j], v[j + 1]]
            if tau is not None:
                out.append(v[j + 2])
            return np.array(out)

        def nll(theta: NDArray) -> float:
            return _blocks_reml_nll(unpack(theta), mats, hs, zs)

        th0, _ = _grid_argmin(nll, list(zip(lo, hi, strict=True)), 3)
        # Powell (bounded, derivative-free), then Nelder-Mead from its end: the likelihood is
        # flat along components that the data cannot see, and one search alone stalls there
        opt = optimize.minimize(nll, th0, method="Powell", bounds=list(zip(lo, hi, strict=True)),
                                options={"xtol": 1e-3, "ftol": 1e-6, "maxfev": 3000})
        opt = optimize.minimize(nll, np.clip(opt.x, lo, hi), method="Nelder-Mead",
                                options={"xatol": 1e-3, "fatol": 1e-4, "maxiter": 800})
        th = np.clip(opt.x, lo, hi)
        v = unpack(th)
        model = NoiseModel(float(v[0]), float(np.sqrt(v[1])), float(np.sqrt(v[3])),
                           float(length), float(np.sqrt(v[4])) if tau is not None else 0.0,
                           float(tau) if tau is not None else np.inf,
                           accel_vrw_mpsqrts=float(np.sqrt(v[2])), reference_kind=kind)
        return nll(th), model

    tau0 = gyro_gm_taus_s[len(gyro_gm_taus_s) // 2] if gyro_gm_taus_s else None
    best = min((fit(length, tau0, kind) for length in reference_lengths_s
                for kind in reference_kinds), key=lambda x: x[0])
    if len(gyro_gm_taus_s) > 1:
        length, kind = best[1].reference_length_s, best[1].reference_kind
        best = min([best] + [fit(length, t, kind) for t in gyro_gm_taus_s if t != tau0],
                   key=lambda x: x[0])
    return best[1]


def _autocorr_inflation(res: NDArray, n_series: int) -> tuple[float, float]:
    """((1 + rho) / (1 - rho), rho) from the residuals' lag-one autocorrelation."""
    r = res.reshape(n_series, -1) if res.size % n_series == 0 else res[None, :]
    num = np.sum(r[:, 1:] * r[:, :-1])
    den = np.sum(r * r)
    rho = float(np.clip(num / den, 0.0, 0.98)) if den > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho), rho


def _lag1(series: list[NDArray]) -> float:
    num = sum(float(np.sum(r[1:] * r[:-1])) for r in series)
    den = sum(float(np.sum(r * r)) for r in series)
    return num / den if den > 0 else 0.0


def _scaled_svd(hw: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Column norms of a whitened design and the SVD of it scaled to unit columns:
    (norms, U, s, V^T, kept), singular values below 1e-10 of the largest not kept (the
    one rank rule of the GLS and of REML's information determinant)."""
    norms = np.linalg.norm(hw, axis=0)
    norms[norms == 0] = 1.0
    u, sv, vt = np.linalg.svd(hw / norms, full_matrices=False)
    return norms, u, sv, vt, sv > sv[0] * 1e-10


def _solve_scaled(hw: NDArray, zw: NDArray) -> tuple[NDArray, NDArray, bool]:
    """Least squares of a whitened system with column scaling; (x, (H^T H)^-1, deficient)."""
    norms, u, sv, vt, keep = _scaled_svd(hw)
    xs = vt[keep].T @ ((u[:, keep].T @ zw) / sv[keep])
    cov_s = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    return xs / norms, cov_s / np.outer(norms, norms), bool(not keep.all())


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
        """E[x(t) | r] at run times ``t_s`` (body FRD, rad/s), shape (N, 3)."""
        e = np.exp(-np.abs(np.asarray(t_s, dtype=float)[:, None] - self.tau_bin_s[None, :])
                   / self.tau_s)
        return self.sigma2 * (e @ self.u)


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


def _gm_covariance(ops: list[tuple[NDArray, NDArray]], tau_s: float) -> NDArray:
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


def _full_reml_nll(theta: NDArray, parts: tuple, fixed: tuple[float | None, float | None]
                   ) -> float:
    """Negative restricted log-likelihood with the full (legs coupled) covariance.

    In D^-1/2-scaled units, C = a I + q K + s2 G; theta holds log a and the logs of the free
    ones of (q, s2).
    """
    hs, zs, k, gm = parts
    w = _chol_whiten(_full_cov(theta, k, gm, fixed), hs, zs)
    return 1e30 if w is None else _reml_whitened(*w)


def _full_params(theta: NDArray, fixed: tuple[float | None, float | None]
                 ) -> tuple[float, float, float]:
    a = float(np.exp(theta[0]))
    j = 1
    vals = []
    for f in fixed:
        if f is None:
            vals.append(float(np.exp(theta[j])))
            j += 1
        else:
            vals.append(float(f))
    return a, vals[0], vals[1]


def _full_cov(theta: NDArray, k: NDArray, gm: NDArray,
              fixed: tuple[float | None, float | None]) -> NDArray:
    a, q, s2 = _full_params(theta, fixed)
    c = q * k + s2 * gm
    c[np.diag_indices_from(c)] += a
    return c


def _tri_solve(ll: NDArray, b: NDArray) -> NDArray:
    return linalg.solve_triangular(ll, b, lower=True, check_finite=False)


class _LegNoise:
    """Projected H and z of one leg in its :class:`NoiseBasis`."""

    def __init__(self, basis: NoiseBasis, h: NDArray, z: NDArray):
        self.lam, self.u, self.sq = basis.lam, basis.u, basis.sq
        self.h = basis.u.T @ (h / basis.sq[:, None])
        self.z = basis.u.T @ (z / basis.sq)
        self.logdet_d = 2.0 * float(np.sum(np.log(basis.sq)))

    def whiten(self, a: float, q: float) -> tuple[NDArray, NDArray, float]:
        v = a + q * self.lam
        w = 1.0 / np.sqrt(v)
        return self.h * w[:, None], self.z * w, float(np.sum(np.log(v))) + self.logdet_d


def _gls(blocks: list[_LegNoise], a: float, q: float) -> tuple[NDArray, NDArray, float]:
    parts = [b.whiten(a, q) for b in blocks]
    return (np.vstack([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            sum(p[2] for p in parts))


def _reml_nll(theta: NDArray, blocks: list[_LegNoise], q_fixed: float | None) -> float:
    """Negative restricted log-likelihood (constants dropped) of log a (and log q)."""
    a = float(np.exp(theta[0]))
    q = q_fixed if q_fixed is not None else float(np.exp(theta[1]))
    hw, zw, logdet = _gls(blocks, a, q)
    return _reml_whitened(hw, zw, logdet)


def fit_calibration(
    legs: tuple[LegReplay, ...],
    formulation: str,
    *,
    transition: str = "numerical",
    estimate_gyro_z: bool = False,
    noise: str = "gyro_rw",
    gyro_arw_radpsqrts: float | None = None,
    noise_step_s: float = 10.0,
    bases: Mapping[int, NoiseBasis] | None = None,
    gyro_gm_sigma_radps: float | None = None,
    gyro_gm_tau_s: float | None = None,
    gm_bin_s: float = 5.0,
    gm_ops: Mapping[int, tuple[NDArray, NDArray]] | None = None,
    gm_prior: DriftPrior | None = None,
) -> Calibration:
    """Calibrate from the B-minus-A velocity errors of a set of legs (paper Eq. 17).

    Parameters
    ----------
    legs : tuple of LegReplay
        Two legs for a pair, or more for a joint fit (distinct leg ids).
    formulation : {"paper", "body"}
        See the module docstring.
    transition : {"numerical", "closed_form"}
        Sensitivity rows from Phi along B, or the ideal-leg closed forms.
    estimate_gyro_z : bool
        Add the vertical body gyro bias (weakly observable on straight level legs).
    noise : {"gyro_rw", "white"}
        Residual model, see the module docstring.
    gyro_arw_radpsqrts : float, optional
        Gyro angle random walk [rad/s^0.5] for ``"gyro_rw"``; estimated (REML) when None.
    noise_step_s : float
        Spacing of the samples entering the ``"gyro_rw"`` GLS [s] (the estimate uses every
        ``noise_step_s``-th second; the condition numbers and residuals use all samples).
    bases : Mapping of leg id to NoiseBasis, optional
        Precomputed :func:`noise_basis` per leg (reused across pairs and formulations).
    gyro_gm_sigma_radps, gyro_gm_tau_s : float, optional
        First-order Gauss-Markov gyro drift (body, per axis; steady-state sigma [rad/s],
        correlation time [s]) added to the ``"gyro_rw"`` covariance:
        ``Cov = a D + q K + sigma^2 S E S^T``, E_jk = exp(-|tau_j - tau_k| / tau) between the
        drift bins of **all** legs (the drift is correlated within and across legs, so the
        legs are coupled and the GLS uses the full covariance). Off when ``gyro_gm_tau_s`` is
        None or the sigma is 0; the sigma is estimated by REML when None (with the tau given).
    gm_bin_s : float
        Width of the drift bins of :func:`gm_noise_operator` [s].
    gm_ops : Mapping of leg id to (S, tau_bin_s), optional
        Precomputed :func:`gm_noise_operator` per leg on its basis' samples.
    gm_prior : DriftPrior, optional
        The grade's drift as a weak prior: with the sigma estimated (None), the drift's sigma
        and tau are both the flight's (maximum of the restricted likelihood plus the prior,
        tau profiled over the prior's candidates; ``gyro_gm_tau_s`` defaults to the prior's
        and is then only a candidate). Switches the Gauss-Markov model on by itself.

    Returns
    -------
    Calibration
    """
    if noise not in NOISE_MODELS:
        raise ValueError(f"noise: expected one of {NOISE_MODELS}, got {noise!r}")
    if gyro_gm_tau_s is not None and not gyro_gm_tau_s > 0:
        raise ValueError(f"gyro_gm_tau_s: expected > 0 s, got {gyro_gm_tau_s!r}")
    if len(legs) < 1:
        raise ValueError("legs: expected at least one leg")
    h, z, s, names = design_matrix(
        legs, formulation, transition=transition, estimate_gyro_z=estimate_gyro_z
    )
    cond_raw, cond_scaled = condition_numbers(h / s[:, None])
    sizes = [2 * (r.t_s.size - 1) for r in legs]
    edges = np.concatenate([[0], np.cumsum(sizes)])
    gm_sigma, drift, tau_profile, gm_source = 0.0, None, (), ""
    if gm_prior is not None and gyro_gm_tau_s is None:
        gyro_gm_tau_s = gm_prior.tau_s
    if noise == "white":
        hw, zw = h / s[:, None], z / s
        x, cov_s, deficient = _solve_scaled(hw, zw)
        res_w = zw - hw @ x
        dof = max(1, zw.size - len(names))
        s0 = float(res_w @ res_w / dof)
        infl, _ = _autocorr_inflation(res_w, 2 * len(legs))
        vf = max(s0, 1e-12) * infl
        cov = cov_s * vf
        arw = 0.0
        white = [res_w[edges[i]:edges[i + 1]] / np.sqrt(vf) for i in range(len(legs))]
    elif gyro_gm_tau_s is not None and (gyro_gm_sigma_radps is None
                                        or gyro_gm_sigma_radps > 0):
        (x, cov, deficient, vf, arw, gm_sigma, white, drift, tau_profile,
         gm_source) = _calibrate_gm(
            legs, h, z, edges, noise_step_s, bases, gm_ops, gyro_arw_radpsqrts,
            gyro_gm_sigma_radps, float(gyro_gm_tau_s), gm_bin_s, gm_prior)
    else:
        blocks, rows_all = [], []
        for i, rep in enumerate(legs):
            basis = None if bases is None else bases.get(rep.leg.leg_id)
            if basis is None:
                basis = noise_basis(rep, noise_step_s=noise_step_s)
            r = basis.rows + edges[i]
            rows_all.append(r)
            blocks.append(_LegNoise(basis, h[r], z[r]))
        if gyro_arw_radpsqrts is None:
            bounds = [(np.log(1e-6), np.log(1e4)), (np.log(1e-22), np.log(1e-6))]
            q_fixed = None
        else:
            bounds = [(np.log(1e-6), np.log(1e4))]
            q_fixed = float(gyro_arw_radpsqrts) ** 2
        # coarse grid (the likelihood is flat in q where a is large), then Nelder-Mead
        theta0, _ = _grid_argmin(lambda th: _reml_nll(th, blocks, q_fixed), bounds, 11)
        opt = optimize.minimize(_reml_nll, theta0, args=(blocks, q_fixed), method="Nelder-Mead",
                                options={"xatol": 1e-3, "fatol": 1e-4, "maxiter": 400})
        th = np.clip(opt.x, [b[0] for b in bounds], [b[1] for b in bounds])
        vf = float(np.exp(th[0]))
        q = q_fixed if q_fixed is not None else float(np.exp(th[1]))
        hw, zw, _ = _gls(blocks, vf, q)
        x, cov, deficient = _solve_scaled(hw, zw)
        arw = float(np.sqrt(q))
        white = []
        for r_idx, b in zip(rows_all, blocks, strict=True):  # time-ordered Cov^-1/2 r
            r = (z[r_idx] - h[r_idx] @ x) / b.sq
            white.append(b.u @ ((b.u.T @ r) / np.sqrt(vf + q * b.lam)))
    res = z - h @ x
    return Calibration(
        formulation=formulation,
        transition=transition,
        noise=noise,
        leg_ids=tuple(r.leg.leg_id for r in legs),
        names=names,
        x=x,
        cov=cov,
        cond_raw=cond_raw,
        cond_scaled=cond_scaled,
        residuals_n_mps=tuple(res[edges[i]:edges[i + 1]].reshape(-1, 2)
                              for i in range(len(legs))),
        residual_rms_mps=float(np.sqrt(np.mean(res**2))),
        n_samples=int(z.size),
        variance_factor=vf,
        gyro_arw_radpsqrts=arw,
        whitened_rms=float(np.sqrt(np.mean(np.concatenate(white) ** 2))),
        whitened_lag1=_lag1([w.reshape(-1, 2)[:, c] for w in white for c in range(2)]),
        rank_deficient=deficient,
        gyro_gm_sigma_radps=gm_sigma,
        gyro_gm_tau_s=np.inf if drift is None else drift.tau_s,
        drift=drift,
        gm_tau_profile=tau_profile,
        gm_source=gm_source,
    )


def _calibrate_gm(legs, h, z, edges, noise_step_s, bases, gm_ops, arw_given, sigma_given,
                  tau_s, bin_s, prior=None):
    """GLS + REML with the Gauss-Markov drift (full covariance over all legs).

    With ``prior`` (:class:`DriftPrior`) and the sigma estimated, tau is profiled over the
    prior's candidates and the grade's weak prior is added to the restricted likelihood
    (maximum a posteriori); the returned profile holds (tau, penalised nll) per candidate.
    """
    rows, sqs, kb, ops = [], [], [], []
    for i, rep in enumerate(legs):
        lid = rep.leg.leg_id
        basis = None if bases is None else bases.get(lid)
        if basis is None:
            basis = noise_basis(rep, noise_step_s=noise_step_s)
        op = None if gm_ops is None else gm_ops.get(lid)
        if op is None:
            op = gm_noise_operator(rep, basis.samples, bin_s=bin_s)
        rows.append(basis.rows + edges[i])
        sqs.append(basis.sq)
        kb.append((basis.u * basis.lam) @ basis.u.T)
        ops.append((op[0] / basis.sq[:, None], op[1]))
    r_all = np.concatenate(rows)
    sq = np.concatenate(sqs)
    hs, zs = h[r_all] / sq[:, None], z[r_all] / sq
    k = linalg.block_diag(*kb)
    q_fixed = None if arw_given is None else float(arw_given) ** 2
    s2_fixed = None if sigma_given is None else float(sigma_given) ** 2
    fixed = (q_fixed, s2_fixed)
    use_prior = prior is not None and s2_fixed is None
    taus = prior.candidates_s() if use_prior else (float(tau_s),)
    profile = []
    for tau in taus:
        parts = (hs, zs, k, _gm_covariance(ops, tau))
        pen = ((lambda th, tau=tau: prior.penalty(_full_params(th, fixed)[2], tau))
               if use_prior else None)
        th, val = _fit_variances(parts, fixed, pen)
        profile.append((float(tau), val, th, parts))
    tau_best, _, th, parts = min(profile, key=lambda p: p[1])
    source = ""
    if use_prior:
        source = "flight"
        nll_best = _full_reml_nll(th, parts, fixed)
        g_fixed = (q_fixed, float(prior.sigma_radps) ** 2)
        g_parts = (hs, zs, k, _gm_covariance(ops, float(prior.tau_s)))
        g_th, g_nll = _fit_variances(g_parts, g_fixed)
        if g_nll - nll_best < GM_REJECT_DNLL:  # the flight does not reject the grade
            source, tau_best, parts, fixed = "grade", float(prior.tau_s), g_parts, g_fixed
            th = g_th
    gm = parts[3]
    a, q, s2 = _full_params(th, fixed)
    ll = np.linalg.cholesky(_full_cov(th, k, gm, fixed))
    x, cov, deficient = _solve_scaled(_tri_solve(ll, hs), _tri_solve(ll, zs))
    r = zs - hs @ x
    wr = _tri_solve(ll, r)  # innovations: time-ordered within each leg
    cuts = np.cumsum([rr.size for rr in rows])[:-1]
    white = np.split(wr, cuts)
    alpha = np.split(linalg.cho_solve((ll, True), r), cuts)
    u = np.vstack([(o[0].T @ al).reshape(-1, 3) for o, al in zip(ops, alpha, strict=True)])
    drift = DriftSmoother(np.concatenate([o[1] for o in ops]), u, s2, tau_best)
    tau_profile = tuple((t, v) for t, v, _, _ in profile) if use_prior else ()
    return (x, cov, deficient, a, float(np.sqrt(q)), float(np.sqrt(s2)), white, drift,
            tau_profile, source)


def _fit_variances(parts: tuple, fixed: tuple[float | None, float | None], penalty=None
                   ) -> tuple[NDArray, float]:
    """REML (plus an optional penalty of theta) of a and the free ones of (q, s2).

    A coarse grid (each evaluation is a Cholesky of the full covariance), then bounded Brent
    (only a free) or Nelder-Mead. Returns (theta, objective at theta).
    """
    bounds = [(np.log(1e-6), np.log(1e4))]
    if fixed[0] is None:
        bounds.append((np.log(1e-22), np.log(1e-6)))
    if fixed[1] is None:
        bounds.append((np.log(1e-17), np.log(1e-8)))

    def obj(th: NDArray) -> float:
        v = _full_reml_nll(th, parts, fixed)
        return v if penalty is None else v + penalty(th)

    best, axes = _grid_argmin(obj, bounds, 9 if len(bounds) == 1 else 6)
    if len(bounds) == 1:  # only A's scale: bounded Brent around the best grid point
        step = axes[0][1] - axes[0][0]
        opt = optimize.minimize_scalar(
            lambda v: obj(np.array([v])), method="bounded",
            bounds=(best[0] - step, best[0] + step), options={"xatol": 1e-3})
        th = np.clip(np.array([opt.x]), bounds[0][0], bounds[0][1])
    else:
        opt = optimize.minimize(obj, best, method="Nelder-Mead",
                                options={"xatol": 1e-2, "fatol": 1e-3, "maxiter": 300})
        th = np.clip(opt.x, [b[0] for b in bounds], [b[1] for b in bounds])
    return th, obj(th)


def predict_velocity_error(rep: LegReplay, cal: Calibration, *, transition: str = "numerical"
                           ) -> NDArray:
    """Model-predicted B velocity error [dv_N, dv_E] (M, 2) on a leg [m/s].

    The gyro bias comes from ``cal``; the leg's own misalignment too when the leg was in the
    fit, zero otherwise (a held-out leg's tilt is not known to the calibration).
    """
    d_phi, d_bg = leg_sensitivities(rep, transition)
    bg = cal.gyro_bias_b_radps(rep.c_nb0)
    phi = cal.misalignment_n_rad(rep.leg.leg_id) if rep.leg.leg_id in cal.leg_ids else np.zeros(3)
    return d_phi @ phi + d_bg @ bg
