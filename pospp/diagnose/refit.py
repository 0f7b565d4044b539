"""The calibration refitted with the effects the diagnosis named.

An effect the calibration's model leaves out is partly read by it: a 985 ug/h accelerometer
ramp forces B like a horizontal gyro bias of ``r / g`` (0.05 deg/h), and the calibrated gyro
bias of flight_accel_ramp_100hz moved from the true (0.4, -0.3) to (0.368, -0.350) deg/h. The
refit removes each named effect's response from B minus A (``columns @ p``,
:class:`pospp.diagnose.results.EffectResponse`) and re-runs the joint least squares unchanged
(the same pairs, formulation and noise settings:
:func:`pospp.calib.null_covariance.with_null_covariance` re-runs it the same way). Its
covariance is the calibration's (null-calibrated: the estimator is the same linear map of
the data, so the null realisations spread it the same way) plus the effects' own uncertainty
carried through the refit (delta method along the principal directions of each effect's
covariance)::

    cov_refit = cov + sum_e sum_i dx_ei dx_ei^T,
    dx_ei = x(dv - R - C_e sqrt(l_ei) u_ei) - x(dv - R)

(R the responses at the estimates, C_e an effect's columns, (l_ei, u_ei) its covariance's
largest eigenpairs). Frames and units: SI, body FRD, NED; no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pospp.calib.compensate import joint_calibration
from pospp.calib.stage import CalibrationRun, gyro_bias_sigma_b_radps
from pospp.diagnose.results import EffectResponse

DIRECTIONS = 3
"""Principal directions of each effect's covariance carried through the refit."""


@dataclass(frozen=True)
class Refit:
    """The calibration refitted with the named effects removed from B minus A.

    Attributes
    ----------
    effects : tuple of str
        The effects removed.
    run : CalibrationRun
        The calibration run with the refit chosen (its joint fit, gyro bias and sigma,
        misalignments; the compensation not yet redone).
    base_bias_b_radps, base_sigma_b_radps : ndarray (3,)
        The calibration's gyro bias and 1-sigma [rad/s], body FRD.
    bias_b_radps, sigma_b_radps : ndarray (3,)
        The refit's [rad/s] (its sigma includes the effects' uncertainty).
    effect_sigma_b_radps : ndarray (3,)
        The part of the refit's sigma the effects' uncertainty adds [rad/s] (in quadrature).
    """

    effects: tuple[str, ...]
    run: CalibrationRun
    base_bias_b_radps: NDArray
    base_sigma_b_radps: NDArray
    bias_b_radps: NDArray
    sigma_b_radps: NDArray
    effect_sigma_b_radps: NDArray

    @property
    def change_b_radps(self) -> NDArray:
        """Refit minus calibration [rad/s]."""
        return self.bias_b_radps - self.base_bias_b_radps


def _directions(resp: EffectResponse, n: int) -> list[NDArray]:
    """The effect's covariance's ``n`` largest principal directions times their sigma (SI
    parameter vectors)."""
    cov = np.asarray(resp.cov_si, dtype=float)
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    order = np.argsort(lam)[::-1][:n]
    return [np.sqrt(lam[i]) * vec[:, i] for i in order if lam[i] > 0]


def refit_calibration(run: CalibrationRun, responses: Sequence[EffectResponse],
                      directions: int = DIRECTIONS) -> Refit | None:
    """The calibration refitted with ``responses`` removed (module docstring); None without
    a calibration, without responses, or when the least squares fails or changes its
    parameters."""
    chosen = run.chosen
    if chosen is None or not responses:
        return None
    ids = sorted(run.replays)
    cache: dict = {}  # the refits share the fixed noise's eigendecomposition

    def fit(minus: list[NDArray]):
        reps = {}
        for i, m in zip(ids, minus, strict=True):
            dv = run.replays[i].dv_n_mps.copy()
            dv[:, 0:2] -= m
            reps[i] = replace(run.replays[i], dv_n_mps=dv)
        return joint_calibration(reps, run.pairs, chosen.formulation, run.fit_options,
                                 noise_cache=cache, **run.fit_bases)

    total = [np.sum([r.curves()[k] for r in responses], axis=0) for k in range(len(ids))]
    try:
        cal = fit(total)
        if cal is None or cal.names != chosen.names:
            return None
        dx = []
        for r in responses:
            for u in _directions(r, directions):
                c = fit([t + col @ u for t, col in zip(total, r.columns, strict=True)])
                if c is not None and c.names == chosen.names:
                    dx.append(c.x - cal.x)
    except (ValueError, np.linalg.LinAlgError):
        return None
    d = np.asarray(dx).reshape(-1, cal.x.size)
    refit = replace(cal, cov=chosen.cov + d.T @ d)
    first = run.replays[chosen.leg_ids[0]]
    bg = refit.gyro_bias_b_radps(first.c_nb0)
    sig = gyro_bias_sigma_b_radps(refit, first)
    extra = gyro_bias_sigma_b_radps(replace(cal, cov=d.T @ d), first)
    joint = tuple(refit if c is chosen else c for c in run.joint)
    names = tuple(r.effect for r in responses)
    new = replace(run, joint=joint, chosen=refit, gyro_bias_b_radps=bg,
                  gyro_bias_sigma_b_radps=sig,
                  misalignment_n_rad={i: refit.misalignment_n_rad(i) for i in refit.leg_ids},
                  messages=run.messages + (
                      f"calibration refitted with {', '.join(names)} removed from B minus A",))
    return Refit(names, new, run.gyro_bias_b_radps, run.gyro_bias_sigma_b_radps, bg, sig,
                 np.where(np.isfinite(extra), extra, 0.0))
