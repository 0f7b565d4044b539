"""Least-squares calibration of misalignment and gyro drift from B-minus-A velocity errors.

For each leg, B's horizontal velocity error obeys (linear error model, 15 states)

    dv_h(t) = Phi_v,phi(t, t0) phi0 + Phi_v,bg(t, t0) b_g (+ Phi_v,ba(t, t0) b_a)

with Phi from F(t) along B's actual trajectory (``transition="numerical"``) or the paper's
closed forms (``transition="closed_form"``, ideal legs; :mod:`pospp.nav.closed_form`).
Stacking legs gives the paper's Eq. 17, ``Z = H X``, solved by weighted least squares.

Formulations (docs/method.md, "Formulations"):

``paper``
    X_p = [phi_N, phi_E, phi_D, eps_N, eps_E]: one misalignment and one *navigation-frame*
    horizontal drift common to all legs, as Liu & Fang print it (with corrected signs).
    Reported with the paper's symbols phi_x = phi_E, phi_y = phi_N, phi_z = -phi_D (ENU).
``body``
    Per-leg tilts [phi_N, phi_E] (B's initial tilt is A's error at that leg's start), one
    heading error phi_D common to the legs (its effect on 5-minute velocity errors is
    Omega cos(lat) phi_D, far below the drift's), and the gyro bias fixed in the body frame,
    [b_x, b_y] (FRD), projected into each leg by that leg's attitude through Phi_v,bg.

Sigmas are the weighted-LS covariance scaled by the a-posteriori variance factor and by the
residuals' lag-one autocorrelation (effective sample size), so they stay honest when the
1 Hz samples are correlated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp.calib.replay import LegReplay
from pospp.nav.error_model import BG, PHI

FORMULATIONS = ("paper", "body")
TRANSITIONS = ("numerical", "closed_form")


@dataclass(frozen=True)
class Calibration:
    """Result of one least-squares calibration over a set of legs.

    Attributes
    ----------
    formulation, transition : str
    leg_ids : tuple of int
    names : tuple of str
        Parameter names (SI: rad, rad/s), see :func:`parameter_names`.
    x : ndarray, shape (P,)
        Estimates.
    cov : ndarray, shape (P, P)
        Covariance (scaled, see module docstring).
    cond_raw, cond_scaled : float
        Condition number of the weighted stacked matrix in SI units, and after scaling every
        column to unit norm (unit-independent).
    residual_rms_mps : float
        RMS of the velocity residuals.
    n_samples : int
        Number of scalar velocity samples.
    variance_factor : float
        A-posteriori variance factor times the autocorrelation inflation.
    """

    formulation: str
    transition: str
    leg_ids: tuple[int, ...]
    names: tuple[str, ...]
    x: NDArray
    cov: NDArray
    cond_raw: float
    cond_scaled: float
    residual_rms_mps: float
    n_samples: int
    variance_factor: float

    @property
    def sigma(self) -> NDArray:
        return np.sqrt(np.diag(self.cov))

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def gyro_bias_b_radps(self, c_nb: NDArray | None = None) -> NDArray:
        """Body-frame gyro bias implied by the calibration [rad/s], shape (3,).

        For ``body`` it is the estimate (z = 0 unless estimated); for ``paper`` the
        navigation-frame drift [eps_N, eps_E, 0] is rotated into the body by ``c_nb``
        (the attitude of the leg it is applied to), as the paper's model implies.
        """
        if self.formulation == "body":
            b = np.zeros(3)
            for i, ax in enumerate("xyz"):
                if f"gyro_bias_{ax}" in self.names:
                    b[i] = self.value(f"gyro_bias_{ax}")
            return b
        eps_n = np.array([self.value("eps_n"), self.value("eps_e"), 0.0])
        if c_nb is None:
            raise ValueError("paper formulation: c_nb of the target leg is needed")
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
    """Parameter names of a formulation, in the order of X."""
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


def _leg_sensitivity_numerical(rep: LegReplay) -> tuple[NDArray, NDArray]:
    """(d dv_h / d phi0 (M,2,3), d dv_h / d b_g (M,2,3)) from the numerical Phi."""
    return rep.phi[:, 3:5, PHI], rep.phi[:, 3:5, BG]


def _leg_sensitivity_closed_form(rep: LegReplay) -> tuple[NDArray, NDArray]:
    """Same from the paper's closed forms (ideal leg at B's initial velocity)."""
    from pospp.nav import closed_form  # local: optional path

    rows = closed_form.velocity_error_rows(
        rep.t_s, lat_rad=rep.lat_rad, height_m=rep.height_m, v_n_mps=rep.v_n0_mps
    )  # (M, 2, 5) over [phi_N, phi_E, phi_D, eps_N, eps_E]
    d_phi = rows[:, :, 0:3]
    # nav-frame drift eps_n = C_nb b_g; the closed forms have no vertical drift column
    d_bg = rows[:, :, 3:5] @ rep.c_nb0[0:2, :]
    return d_phi, d_bg


def design_matrix(
    legs: tuple[LegReplay, ...],
    formulation: str,
    *,
    transition: str = "numerical",
    estimate_gyro_z: bool = False,
) -> tuple[NDArray, NDArray, NDArray, tuple[str, ...]]:
    """Stacked system of Eq. 17: (H (m, P), z (m,), sigma (m,), names).

    Rows are the north and east velocity errors of every sample of every leg, in leg order.
    """
    if transition not in TRANSITIONS:
        raise ValueError(f"transition: expected one of {TRANSITIONS}, got {transition!r}")
    ids = tuple(r.leg.leg_id for r in legs)
    names = parameter_names(formulation, ids, estimate_gyro_z=estimate_gyro_z)
    col = {n: i for i, n in enumerate(names)}
    h_blocks, z_blocks, s_blocks = [], [], []
    for rep in legs:
        if transition == "numerical":
            d_phi, d_bg = _leg_sensitivity_numerical(rep)
        else:
            d_phi, d_bg = _leg_sensitivity_closed_form(rep)
        m = rep.t_s.size
        h = np.zeros((m, 2, len(names)))
        if formulation == "paper":
            h[:, :, 0:3] = d_phi
            # constant navigation-frame drift: sensitivity d_bg @ C_bn0 (straight leg)
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
        h_blocks.append(h[1:].reshape(-1, len(names)))  # t = 0 rows are identically zero
        z_blocks.append(rep.dv_n_mps[1:, 0:2].reshape(-1))
        s_blocks.append(rep.sigma_v_n_mps[1:, 0:2].reshape(-1))
    return np.vstack(h_blocks), np.concatenate(z_blocks), np.concatenate(s_blocks), names


def condition_numbers(h_weighted: NDArray) -> tuple[float, float]:
    """(raw, column-scaled) 2-norm condition numbers of a stacked matrix."""
    sv = np.linalg.svd(h_weighted, compute_uv=False)
    raw = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
    norms = np.linalg.norm(h_weighted, axis=0)
    if np.any(norms == 0):
        return raw, np.inf
    sv2 = np.linalg.svd(h_weighted / norms, compute_uv=False)
    return raw, float(sv2[0] / sv2[-1]) if sv2[-1] > 0 else np.inf


def _autocorr_inflation(res: NDArray, n_series: int) -> float:
    """Variance inflation (1 + rho) / (1 - rho) from the residuals' lag-one autocorrelation."""
    r = res.reshape(n_series, -1) if res.size % n_series == 0 else res[None, :]
    num = np.sum(r[:, 1:] * r[:, :-1])
    den = np.sum(r * r)
    rho = float(np.clip(num / den, 0.0, 0.98)) if den > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho)


def calibrate(
    legs: tuple[LegReplay, ...],
    formulation: str,
    *,
    transition: str = "numerical",
    estimate_gyro_z: bool = False,
) -> Calibration:
    """Weighted least squares over all velocity-error samples of the legs (Eq. 17).

    Parameters
    ----------
    legs : tuple of LegReplay
        Two legs for a pair, or more for a joint fit.
    formulation : {"paper", "body"}
    transition : {"numerical", "closed_form"}
    estimate_gyro_z : bool
        Add the vertical body gyro bias (weakly observable on straight legs).
    """
    h, z, s, names = design_matrix(
        legs, formulation, transition=transition, estimate_gyro_z=estimate_gyro_z
    )
    hw = h / s[:, None]
    zw = z / s
    cond_raw, cond_scaled = condition_numbers(hw)
    norms = np.linalg.norm(hw, axis=0)
    norms[norms == 0] = 1.0
    hs = hw / norms
    u, sv, vt = np.linalg.svd(hs, full_matrices=False)
    keep = sv > sv[0] * 1e-12
    xs = vt[keep].T @ ((u[:, keep].T @ zw) / sv[keep])
    x = xs / norms
    cov_s = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    res_w = zw - hw @ x
    dof = max(1, zw.size - len(names))
    s0 = float(res_w @ res_w / dof)
    infl = _autocorr_inflation(res_w, 2 * len(legs))
    vf = max(s0, 1e-12) * infl
    cov = cov_s / np.outer(norms, norms) * vf
    res = z - h @ x
    return Calibration(
        formulation=formulation,
        transition=transition,
        leg_ids=tuple(r.leg.leg_id for r in legs),
        names=names,
        x=x,
        cov=cov,
        cond_raw=cond_raw,
        cond_scaled=cond_scaled,
        residual_rms_mps=float(np.sqrt(np.mean(res**2))),
        n_samples=int(z.size),
        variance_factor=vf,
    )


def predict_velocity_error(rep: LegReplay, cal: Calibration, *, transition: str = "numerical"
                           ) -> NDArray:
    """Model-predicted B velocity error (M, 2) on a leg, with the leg's own misalignment
    taken from ``cal`` when the leg was in the fit and zero otherwise."""
    if transition == "numerical":
        d_phi, d_bg = _leg_sensitivity_numerical(rep)
    else:
        d_phi, d_bg = _leg_sensitivity_closed_form(rep)
    bg = cal.gyro_bias_b_radps(rep.c_nb0)
    if rep.leg.leg_id in cal.leg_ids:
        phi = cal.misalignment_n_rad(rep.leg.leg_id)
    else:
        phi = np.zeros(3)
    return d_phi @ phi + d_bg @ bg
