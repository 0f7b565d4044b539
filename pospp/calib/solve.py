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

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from pospp.calib.design import (
    condition_numbers,
    design_matrix,
)
from pospp.calib.noise_model import (
    REFERENCE_KINDS,
    REFERENCE_LENGTHS_S,
    DriftSmoother,
    NoiseBasis,
    NoiseModel,
    accel_noise_covariance,
    gm_covariance,
    gm_noise_operator,
    gyro_noise_covariance,
    leg_noise_basis,
    leg_rows,
    reference_error_covariance,
)
from pospp.calib.reml import (
    LegNoise,
    autocorr_inflation,
    blocks_reml_nll,
    calibrate_gm,
    fit_variances,
    gls_gain,
    grid_argmin,
    lag1_autocorrelation,
    reml_nll,
    scaled_map,
    solve_scaled,
    stack_whitened,
)
from pospp.calib.replay import LegReplay

NOISE_MODELS = ("gyro_rw", "white")
GM_PRIOR_LOG_SD = float(np.log(10.0))
"""1-sigma of the grade's weak log-normal prior on the drift's sigma and tau (one decade)."""
GM_TAUS_S = tuple(float(v) for v in np.geomspace(60.0, 86400.0, 15))
"""Candidate drift correlation times of the profile REML [s] (60 s to 1 day, ratio 1.68)."""


@dataclass(frozen=True)
class DriftPrior:
    """The IMU grade's Gauss-Markov drift as a weak prior of the flight's own estimate.

    The drift's level and correlation time are estimated from the flight (REML across the legs
    of the joint fit), penalised by ``0.5 ((ln sigma - ln sigma_g) / log_sd)^2 +
    0.5 ((ln tau - ln tau_g) / log_sd)^2`` (a log-normal prior, one decade 1-sigma by
    default), tau profiled over ``taus_s``. The flight's estimate is kept only when it
    rejects the grade's drift: when the restricted likelihood at the grade's (sigma, tau)
    (a and q re-fitted) is within :data:`pospp.calib.reml.GM_REJECT_DNLL` of the estimate's,
    the grade's drift is used (the likelihood is flat there: a drift too small, too slow or too
    close to the ARW for the legs to see).

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
    gain : ndarray, shape (P, 2 sum (M_i - 1)) or None
        The estimate as a linear map of the measurements at the fitted variances, ``x = gain
        @ z`` (z: per leg in ``leg_ids`` order, [dv_N, dv_E] at the samples t > 0, as
        :func:`pospp.calib.design.design_matrix` stacks them): the sandwich covariance's
        bread and weights (:func:`pospp.calib.stage.with_linear_null_covariance`).
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
    gain: NDArray | None = None

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
        if self.drift is None:
            return np.zeros(3)
        return self.drift.mean_over_b_radps(rep.t0_s + rep.t_s)

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
    prob = _NoiseProblem.of(legs, formulation, transition, estimate_gyro_z, noise_step_s,
                            gyro_arw_radpsqrts, with_drift=bool(gyro_gm_taus_s))
    tau0 = gyro_gm_taus_s[len(gyro_gm_taus_s) // 2] if gyro_gm_taus_s else None
    best = min((prob.fit(length, tau0, kind) for length in reference_lengths_s
                for kind in reference_kinds), key=lambda x: x[0])
    if len(gyro_gm_taus_s) > 1:
        length, kind = best[1].reference_length_s, best[1].reference_kind
        best = min([best] + [prob.fit(length, t, kind) for t in gyro_gm_taus_s if t != tau0],
                   key=lambda x: x[0])
    return best[1]


@dataclass(frozen=True)
class _NoiseProblem:
    """:func:`fit_noise_model`'s REML problem: per leg its samples (every ``noise_step_s``),
    whitened design and data, the covariances' fixed parts (I, the gyro ARW's K, the
    accelerometer's, A's sigmas) and the drift's operator (None without the drift)."""

    legs: tuple[LegReplay, ...]
    rows: list[NDArray]
    hs: list[NDArray]
    zs: list[NDArray]
    base: list[tuple[NDArray, NDArray, NDArray, NDArray]]
    ops: list[tuple[NDArray, NDArray] | None]
    q_fixed: float | None

    @classmethod
    def of(cls, legs: tuple[LegReplay, ...], formulation: str, transition: str,
           estimate_gyro_z: bool, noise_step_s: float, gyro_arw_radpsqrts: float | None,
           with_drift: bool) -> _NoiseProblem:
        h, z, _, _ = design_matrix(legs, formulation, transition=transition,
                                   estimate_gyro_z=estimate_gyro_z)
        sizes = [2 * (r.t_s.size - 1) for r in legs]
        edges = np.concatenate([[0], np.cumsum(sizes)])
        rows, hs, zs, base = [], [], [], []
        for i, rep in enumerate(legs):
            smp = leg_rows(rep, noise_step_s)
            rr = (2 * (smp - 1)[:, None] + np.arange(2)[None, :]).reshape(-1) + edges[i]
            sq = rep.sigma_v_n_mps[smp, 0:2].reshape(-1)
            rows.append(smp)
            hs.append(h[rr] / sq[:, None])
            zs.append(z[rr] / sq)
            base.append((np.eye(sq.size), gyro_noise_covariance(rep, smp) / np.outer(sq, sq),
                         accel_noise_covariance(rep, smp) / np.outer(sq, sq), sq))
        q_fixed = None if gyro_arw_radpsqrts is None else float(gyro_arw_radpsqrts) ** 2
        ops: list[tuple[NDArray, NDArray] | None] = [None] * len(legs)
        if with_drift:
            ops = []
            for rep, smp, (_, _, _, sq) in zip(legs, rows, base, strict=True):
                s_op, tb = gm_noise_operator(rep, smp)
                ops.append((s_op / sq[:, None], tb))
        return cls(legs, rows, hs, zs, base, ops, q_fixed)

    def fit(self, length: float, tau: float | None, kind: str) -> tuple[float, NoiseModel]:
        """(restricted nll, model) at A's error correlation length ``length`` [s] of
        ``kind`` and the drift's ``tau`` [s] (None: no drift): the variances by REML, a
        coarse grid, then Powell (bounded, derivative-free) and Nelder-Mead from its end (the
        likelihood is flat along components the data cannot see: one search alone stalls)."""
        q_fixed = self.q_fixed
        mats = []
        for rep, smp, (eye, k, ka, sq), op in zip(self.legs, self.rows, self.base, self.ops,
                                                  strict=True):
            g = reference_error_covariance(rep, length, smp, kind) / np.outer(sq, sq)
            m = [eye, k, ka, g]
            if tau is not None:
                assert op is not None  # a tau only with the drift's operators
                m.append(gm_covariance([op], tau))
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
            return blocks_reml_nll(unpack(theta), mats, self.hs, self.zs)

        th0, _ = grid_argmin(nll, list(zip(lo, hi, strict=True)), 3)
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


@dataclass(frozen=True)
class FitOptions:
    """The least squares' model (:func:`fit_calibration`; SI).

    Attributes
    ----------
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
    gyro_gm_sigma_radps, gyro_gm_tau_s : float, optional
        First-order Gauss-Markov gyro drift (body, per axis; steady-state sigma [rad/s],
        correlation time [s]) added to the ``"gyro_rw"`` covariance:
        ``Cov = a D + q K + sigma^2 S E S^T``, E_jk = exp(-|tau_j - tau_k| / tau) between the
        drift bins of **all** legs (the drift is correlated within and across legs, so the
        legs are coupled and the GLS uses the full covariance). Off when ``gyro_gm_tau_s`` is
        None or the sigma is 0; the sigma is estimated by REML when None (with the tau given).
    gm_bin_s : float
        Width of the drift bins of :func:`gm_noise_operator` [s].
    gm_prior : DriftPrior, optional
        The grade's drift as a weak prior: with the sigma estimated (None), the drift's sigma
        and tau are both the flight's (maximum of the restricted likelihood plus the prior,
        tau profiled over the prior's candidates; ``gyro_gm_tau_s`` defaults to the prior's
        and is then only a candidate). Switches the Gauss-Markov model on by itself.
    """

    transition: str = "numerical"
    estimate_gyro_z: bool = False
    noise: str = "gyro_rw"
    gyro_arw_radpsqrts: float | None = None
    noise_step_s: float = 10.0
    gyro_gm_sigma_radps: float | None = None
    gyro_gm_tau_s: float | None = None
    gm_bin_s: float = 5.0
    gm_prior: DriftPrior | None = None

    def __post_init__(self) -> None:
        if self.noise not in NOISE_MODELS:
            raise ValueError(f"noise: expected one of {NOISE_MODELS}, got {self.noise!r}")
        if self.gyro_gm_tau_s is not None and not self.gyro_gm_tau_s > 0:
            raise ValueError(f"gyro_gm_tau_s: expected > 0 s, got {self.gyro_gm_tau_s!r}")

    @property
    def gm_tau_s(self) -> float | None:
        """The drift's correlation time [s] the fit starts from (the prior's when not given),
        None without the drift."""
        return (self.gm_prior.tau_s if self.gm_prior is not None and self.gyro_gm_tau_s is None
                else self.gyro_gm_tau_s)


def fit_calibration(
    legs: tuple[LegReplay, ...],
    formulation: str,
    options: FitOptions | None = None,
    *,
    bases: Mapping[int, NoiseBasis] | None = None,
    gm_ops: Mapping[int, tuple[NDArray, NDArray]] | None = None,
    noise_cache: dict | None = None,
) -> Calibration:
    """Calibrate from the B-minus-A velocity errors of a set of legs (paper Eq. 17).

    Parameters
    ----------
    legs : tuple of LegReplay
        Two legs for a pair, or more for a joint fit (distinct leg ids).
    formulation : {"paper", "body"}
        See the module docstring.
    options : FitOptions, optional
        The model (the defaults when None).
    bases : Mapping of leg id to NoiseBasis, optional
        Precomputed :func:`noise_basis` per leg (reused across pairs and formulations).
    gm_ops : Mapping of leg id to (S, tau_bin_s), optional
        Precomputed :func:`gm_noise_operator` per leg on its basis' samples.
    noise_cache : dict, optional
        Shared by calls with the same legs and noise where only A's scale is fitted (the ARW
        and the drift's sigma given): the eigendecomposition of the fixed part of the
        covariance, ``q K + s2 G``, made once, after which each evaluation of the restricted
        likelihood scales ``V^T [H z]`` instead of factoring the covariance (the null
        realisations' refits, :func:`pospp.calib.null_covariance.with_null_covariance`; the same
        likelihood to rounding: docs/decisions.md). It also keeps each leg's
        :func:`noise_basis` and drift operator (by leg id; neither reads B minus A, only
        the leg's samples, sigmas and transition), where ``bases`` / ``gm_ops`` lack them.

    Returns
    -------
    Calibration
    """
    o = options if options is not None else FitOptions()
    if len(legs) < 1:
        raise ValueError("legs: expected at least one leg")
    h, z, s, names = design_matrix(
        legs, formulation, transition=o.transition, estimate_gyro_z=o.estimate_gyro_z
    )
    cond_raw, cond_scaled = condition_numbers(h / s[:, None])
    sizes = [2 * (r.t_s.size - 1) for r in legs]
    edges = np.concatenate([[0], np.cumsum(sizes)])
    gm_sigma, drift, tau_profile, gm_source = 0.0, None, (), ""
    tau_s = o.gm_tau_s
    if o.noise == "white":
        x, cov, deficient, vf, arw, white, gain = _fit_white(h, z, s, edges, len(names))
    elif tau_s is not None and (o.gyro_gm_sigma_radps is None or o.gyro_gm_sigma_radps > 0):
        (x, cov, deficient, vf, arw, gm_sigma, white, drift, tau_profile,
         gm_source, gain) = calibrate_gm(legs, h, z, edges, o, float(tau_s), bases, gm_ops,
                                         noise_cache)
    else:
        x, cov, deficient, vf, arw, white, gain = _fit_gyro_rw(
            legs, h, z, edges, o, bases, noise_cache)
    res = z - h @ x
    return Calibration(
        formulation=formulation,
        transition=o.transition,
        noise=o.noise,
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
        whitened_lag1=lag1_autocorrelation([w.reshape(-1, 2)[:, c] for w in white
                                            for c in range(2)]),
        rank_deficient=deficient,
        gyro_gm_sigma_radps=gm_sigma,
        gyro_gm_tau_s=np.inf if drift is None else drift.tau_s,
        drift=drift,
        gm_tau_profile=tau_profile,
        gm_source=gm_source,
        gain=gain,
    )




def _fit_white(h: NDArray, z: NDArray, s: NDArray, edges: NDArray, n_par: int) -> tuple:
    """Weighted least squares with A's sigmas ``s`` (``noise="white"``), its variance factor
    inflated by the residual's autocorrelation: (x, cov, deficient, vf, arw 0, whitened
    residuals per leg, gain)."""
    hw, zw = h / s[:, None], z / s
    x, cov_s, deficient = solve_scaled(hw, zw)
    gain = scaled_map(hw) / s
    res_w = zw - hw @ x
    dof = max(1, zw.size - n_par)
    s0 = float(res_w @ res_w / dof)
    infl, _ = autocorr_inflation(res_w, 2 * (edges.size - 1))
    vf = max(s0, 1e-12) * infl
    white = [res_w[edges[i]:edges[i + 1]] / np.sqrt(vf) for i in range(edges.size - 1)]
    return x, cov_s * vf, deficient, vf, 0.0, white, gain


def _fit_gyro_rw(legs: tuple[LegReplay, ...], h: NDArray, z: NDArray, edges: NDArray,
                 o: FitOptions, bases: Mapping[int, NoiseBasis] | None,
                 noise_cache: dict | None) -> tuple:
    """GLS with ``Cov = a D + q K`` per leg (``noise="gyro_rw"``, no drift), a and q (q fixed
    when the ARW is given) by REML (:func:`pospp.calib.reml.fit_variances`: a coarse grid,
    the likelihood being flat in q where a is large, then a bounded quasi-Newton). Returns
    (x, cov, deficient, vf, arw, whitened residuals per leg, gain)."""
    blocks, rows_all = [], []
    for i, rep in enumerate(legs):
        basis = leg_noise_basis(rep, o.noise_step_s, bases, noise_cache)
        r = basis.rows + edges[i]
        rows_all.append(r)
        blocks.append(LegNoise(basis, h[r], z[r]))
    q_fixed = None if o.gyro_arw_radpsqrts is None else float(o.gyro_arw_radpsqrts) ** 2
    # no drift: its variance is not a parameter (0 here only keeps it out of theta)
    th, _ = fit_variances(lambda th: reml_nll(th, blocks, q_fixed), (q_fixed, 0.0))
    vf = float(np.exp(th[0]))
    q = q_fixed if q_fixed is not None else float(np.exp(th[1]))
    hw, zw, _ = stack_whitened(blocks, vf, q)
    x, cov, deficient = solve_scaled(hw, zw)
    gain = gls_gain(blocks, vf, q, rows_all, z.size, scaled_map(hw))
    white = []
    for r_idx, b in zip(rows_all, blocks, strict=True):  # time-ordered Cov^-1/2 r
        r = (z[r_idx] - h[r_idx] @ x) / b.sq
        white.append(b.u @ ((b.u.T @ r) / np.sqrt(vf + q * b.lam)))
    return x, cov, deficient, vf, float(np.sqrt(q)), white, gain
