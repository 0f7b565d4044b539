"""Signatures of the GNSS-side effects by re-running algorithm A (issue 12, item 3).

Frames and units: body FRD (b), NED (n), SI inside; the signatures are per leg (M, 2, P):
d [dv_N, dv_E] / d p at the replay samples, p in SI (m for the lever arm, s for the offset).

Why: an antenna lever arm the configuration gets wrong, or a GNSS time tag offset, does not
only add A's kinematic error (``-C_nb (w_nb_b x dl)``, what :mod:`pospp.diagnose.effects`
writes in closed form): A is a Kalman filter and smoother, and the mismatch of its GNSS
measurements in every turn is read as attitude, heading and bias errors, which B then carries
from each leg start. Measured on a simulated survey flight with a 1 m antenna offset
configured as 0 (tests/unit/test_diagnose_power.py): B minus A moves by 50 mm/s RMS on the
legs after the turns, the closed-form signature predicts 3 mm/s, and the workflow cannot name
the lever arm. The exact first-order signature is A's own response, obtained the way the null
realisations are (:func:`pospp.pipeline.null_realisations`): A re-run on the flight's log
with the configuration perturbed, B replayed on the same legs, minus the flight's B minus A,
divided by the perturbation (one-sided finite difference at the effect's plausible size)::

    S_j(t) = ((B - A)[log, config + h e_j](t) - (B - A)[log, config](t)) / h

``lever_arm`` (dl = configured minus true, FRD): the configured lever arm plus h e_j.
``time_offset`` (IMU time tag minus GNSS time tag, tau): the GNSS fixes and velocities
stamped h earlier (the IMU then reads late by h relative to them).
``gyro_scale_factor`` (s, FRD): the IMU rates read ``(1 + h) w_j`` on axis j (A and B both
re-run: the heading error a scale factor builds up in the turns reaches B through A's state
at each leg start, which the in-leg forcing of :mod:`pospp.diagnose.effects` leaves out).
``accel_bias_change`` (db, FRD x and y): the specific force reads ``f_j + h exp(-t / T)``,
t from the first IMU stamp, T = ``accel_settling_s`` (A estimates the bias B then uses).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pospp.diagnose.effects import ACCEL_SETTLING_S, effect_by_id

RERUN_EFFECTS = ("lever_arm", "time_offset", "gyro_scale_factor", "accel_bias_change")
"""Effects whose signature :func:`rerun_signatures` makes by re-running A."""
PIPELINE_RERUN = ("lever_arm", "time_offset", "gyro_scale_factor")
"""The ones the pipeline's diagnosis re-runs (7 A runs; the warm-up's re-run is left out: on
the survey flights measured, A's accelerometer-bias estimate absorbs it and the observability
screen drops it either way)."""


def rerun_signatures(log, nav, calib_run, config, effect_ids=RERUN_EFFECTS, *,
                     accel_settling_s: float = ACCEL_SETTLING_S) -> dict[str, list[NDArray]]:
    """Per effect, per leg (legs in id order) the signature (M, 2, P), SI parameters.

    Parameters
    ----------
    log : FlightLog-like (``imu``, ``fix``, ``vel``)
    nav : FilterResult
        A on the flight (only whether the smoother ran matters).
    calib_run : CalibrationRun
        The flight's legs and B-minus-A replays.
    config : PipelineConfig
    effect_ids : sequence of str
        Subset of :data:`RERUN_EFFECTS`.
    accel_settling_s : float
        Warm-up time constant of ``accel_bias_change`` [s] (the workflow's).

    Returns
    -------
    dict
        ``effect_id -> [S_leg (M, 2, P)]``; an effect whose re-run fails (A's alignment) is
        left out.
    """
    from pospp import pipeline  # the pipeline imports the workflow: import at call time
    from pospp.calib.replay import ReferenceSolution, replay_leg
    from pospp.nav import filter as nav_filter

    ids = sorted(calib_run.replays)
    legs = {leg.leg_id: leg for leg in calib_run.legs}
    rc = config.replay
    which = rc.reference if nav.smoothed is not None else "forward"
    base = [calib_run.replays[i].dv_n_mps[:, 0:2] for i in ids]
    t_run_s = (log.imu.time_ns - log.imu.time_ns[0]) * 1e-9

    def imu_log(rates=None, forces=None):
        imu_p = replace(log.imu, **({} if rates is None else {"w_ib_b_radps": rates}),
                        **({} if forces is None else {"f_ib_b_mps2": forces}))
        return replace(log, imu=imu_p)

    def response(log_p, lever_b_m=None) -> list[NDArray]:
        nav_p = pipeline.navigate(log_p, config, lever_arm_b_m=lever_b_m)
        ref_p = ReferenceSolution(*nav_filter.reference_solution(nav_p, which=which))
        imu = pipeline.imu_increments(log_p)
        return [replay_leg(imu, ref_p, legs[i], accel_compensation=rc.accel_compensation,
                           sample_rate_hz=rc.sample_rate_hz, sigma_floor_mps=rc.sigma_floor_mps,
                           transition_step=int(rc.transition_step)).dv_n_mps[:, 0:2] - b
                for i, b in zip(ids, base, strict=True)]

    out: dict[str, list[NDArray]] = {}
    for eid in effect_ids:
        h = effect_by_id(eid).plausible_si
        try:
            if eid == "lever_arm":
                lever0 = np.asarray(config.gnss.lever_arm_m, dtype=float)
                cols = [response(log, lever0 + h * e) for e in np.eye(3)]
            elif eid == "time_offset":
                dt_ns = int(round(h * 1e9))
                log_p = replace(log, fix=replace(log.fix, time_ns=log.fix.time_ns - dt_ns),
                                vel=replace(log.vel, time_ns=log.vel.time_ns - dt_ns))
                cols = [response(log_p)]
            elif eid == "gyro_scale_factor":
                w = log.imu.w_ib_b_radps
                cols = [response(imu_log(rates=w * (1.0 + h * e))) for e in np.eye(3)]
            elif eid == "accel_bias_change":
                f = log.imu.f_ib_b_mps2
                warm = np.exp(-t_run_s / accel_settling_s)[:, None]
                cols = [response(imu_log(forces=f + h * warm * e)) for e in np.eye(3)[:2]]
            else:
                raise ValueError(f"effect_ids: {eid!r} has no re-run signature; "
                                 f"expected a subset of {RERUN_EFFECTS}")
        except (ValueError, np.linalg.LinAlgError) as exc:
            if "effect_ids" in str(exc):
                raise
            continue
        out[eid] = [np.stack([c[k] for c in cols], axis=-1) / h for k in range(len(ids))]
    return out
