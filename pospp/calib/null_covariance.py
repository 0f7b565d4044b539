"""The chosen calibration's covariance from B minus A's null (the null stage's): exactly from
the linear null's system, or by re-running the least squares on each null realisation
(:func:`with_null_covariance`); the turn-on constant's and the flight's gyro bias sigmas
follow (:func:`with_covariance`).

Frames and units: body FRD (b), NED (n), SI; covariances in the fit's parameters' units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pospp.calib.bias_smoother import flight_bias_b_radps
from pospp.calib.compensate import joint_calibration
from pospp.calib.stage import CalibrationRun, gyro_bias_sigma_b_radps

MIN_NULL_REALISATIONS = 3
"""Fewest null realisations :func:`with_null_covariance` turns into a covariance."""


def with_null_covariance(run: CalibrationRun, null_dv: Sequence[Sequence[NDArray]],
                         injected: Sequence[NDArray] | None = None) -> CalibrationRun:
    """The chosen calibration's covariance from B minus A's null realisations.

    Each realisation ``d_r`` (one (M, 3) array per leg in id order, the replays' rows:
    :func:`pospp.pipeline.null_realisations`) is B minus A's response to one draw of the
    flight's noise: IMU white noise, the configured Gauss-Markov drift, GNSS noise, through
    A's own gains and the legs' coupling through A's errors at the leg starts. The joint least
    squares is re-run, unchanged (same pairs, formulation and noise settings), on the flight's
    B minus A plus ``d_r``; the covariance of the estimate is the mean outer product of the
    parameter changes::

        dx_r = x(dv + d_r) - x(dv),   cov = (1 / R) sum_r dx_r dx_r^T

    (a parametric bootstrap by perturbation: the estimator's own spread under the flight's
    noise, where the GLS's formal covariance is only as honest as its noise model; the mean
    of dx is zero by construction of the perturbation, so no degree of freedom is spent on
    it). The chosen calibration (and its entry in ``joint``) gets this covariance; the
    turn-on constant's sigma follows.

    ``injected``: per realisation, the mean over each leg (id order) of the gyro error it
    injected ((L, 3); ``null_realisations(..., injected_out=)``). The flight's gyro bias is
    then measured against that truth, ``df_r = f(dv + d_r) - f(dv) - (injected mean over the
    fitted legs)`` with f :func:`pospp.calib.bias_smoother.flight_bias_b_radps`, and its
    sigma is the RMS of df_r. With fewer than :data:`MIN_NULL_REALISATIONS` usable
    realisations, or no calibration, the run is returned unchanged.

    The compensation already applied is not redone (it reads the fit, not its sigma).
    """
    chosen = run.chosen
    if chosen is None or len(null_dv) < MIN_NULL_REALISATIONS:
        return run
    ids = sorted(run.replays)
    cache: dict = {}  # the realisations share the fixed noise's eigendecomposition
    fitted = [ids.index(i) for i in chosen.leg_ids]
    length = np.array([run.replays[i].t_s[-1] for i in chosen.leg_ids])
    f0 = flight_bias_b_radps(chosen, run.replays)
    dx, df = [], []
    for r, real in enumerate(null_dv):
        reps = {i: replace(run.replays[i], dv_n_mps=run.replays[i].dv_n_mps + np.asarray(d))
                for i, d in zip(ids, real, strict=True)}
        cal = joint_calibration(reps, run.pairs, chosen.formulation, run.fit_options,
                                noise_cache=cache, **run.fit_bases)
        if cal is not None and cal.names == chosen.names:
            dx.append(cal.x - chosen.x)
            if injected is not None:
                truth = length @ np.asarray(injected[r])[fitted] / length.sum()
                df.append(flight_bias_b_radps(cal, reps) - f0 - truth)
    if len(dx) < MIN_NULL_REALISATIONS:
        return run
    d = np.asarray(dx)
    flight_sig = (np.sqrt(np.mean(np.square(df), axis=0)) if injected is not None
                  and len(df) == len(dx) else None)
    return with_covariance(run, d.T @ d / d.shape[0], "null_realisations",
                           f"calibration sigmas from {d.shape[0]} null realisations of B minus "
                           "A (the least squares re-run on each)", flight_sig)


def with_covariance(run: CalibrationRun, cov: NDArray, source: str, note: str,
                    flight_sigma_b_radps: NDArray | None = None) -> CalibrationRun:
    """``run`` with the chosen calibration's covariance (and its entry in ``joint``'s) ``cov``,
    the turn-on constant's gyro bias sigma following, ``sigma_source`` ``source`` and the
    message ``note``. The flight's gyro bias sigma (``flight_gyro_bias_sigma_b_radps``):
    ``flight_sigma_b_radps`` [rad/s] on the axes the fit estimates, else the constant's (no
    injected truth to measure the flight's bias against: the linear null; larger than the
    flight's own, docs/calibration.md)."""
    chosen = run.chosen
    assert chosen is not None  # a covariance is only given to a calibration
    honest = replace(chosen, cov=cov)
    joint = tuple(honest if c is chosen else c for c in run.joint)
    sig = gyro_bias_sigma_b_radps(honest, run.replays[chosen.leg_ids[0]])
    flight_sig = sig if flight_sigma_b_radps is None else np.where(
        np.isfinite(sig), flight_sigma_b_radps, np.inf)
    return replace(run, joint=joint, chosen=honest, gyro_bias_sigma_b_radps=sig,
                   flight_gyro_bias_sigma_b_radps=flight_sig, sigma_source=source,
                   messages=run.messages + (note,))
