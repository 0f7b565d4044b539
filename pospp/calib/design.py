"""The design matrix of the paired-leg least squares: each leg's sensitivities of B's
horizontal velocity error to the initial misalignment and the gyro bias, stacked per formulation
(paper Eq. 17, ``Z = H X``), and its condition numbers.

Frames and units as :mod:`pospp.calib.solve` (NED n, FRD b, SI), whose module docstring
describes the formulations and transitions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pospp.calib.replay import LegReplay
from pospp.nav.error_model import BG, PHI

FORMULATIONS = ("paper", "body")
TRANSITIONS = ("numerical", "closed_form")


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
