"""The diagnosis's first signatures from A's own gains: B minus A's linear response.

Frames and units: NED (n), body FRD (b), SI; signatures per leg (M, 2, P), d [dv_N, dv_E] /
d p at the replay samples, as :mod:`pospp.diagnose.rerun` makes them by re-running A.

A GNSS-side effect changes only what A's records say about the state. With A's gains held (its
Kalman gains, measurement matrices and smoother gains as the flight's pass recorded them:
:class:`pospp.calib.linear_null.LinearNull`), B minus A is linear in the records' errors ``v``
(measured minus what A's model predicts from the true state), and its response is
:meth:`LinearNull.response`. Per unit of each effect's parameter:

``lever_arm`` (the configured lever arm moved by ``dl``, body FRD [m]): A predicts the antenna
at ``r + C_nb l`` and its velocity as ``v + Cdot_nb l``; moved by ``dl`` the predictions move by
``C_nb dl`` and ``Cdot_nb dl``, so ``v_pos = -C_nb e_j``, ``v_vel = -Cdot_nb e_j``.

``time_offset`` (the GNSS records stamped ``tau`` earlier than they were taken [s], as
:func:`pospp.diagnose.rerun.restamped`): a record taken at t is read at ``t - tau``, where A
predicts the antenna's state at ``t - tau``: ``v_pos = v_ant(t)``, ``v_vel = a_ant(t)``
(``v_ant = v + Cdot_nb l``, ``a_ant`` its rate).

``Cdot_nb`` and ``a_ant`` by central differences of A's solution over +-:data:`DIFF_STEP_S`.
This is A's derivative at the configuration with its gate decisions held: exact where A's
gate is open (the flight gated no more than its model allows, no covariance reset) and the
effect small; where A gated in excess, or at a large estimate, the diagnosis re-runs A
(:mod:`pospp.diagnose.rerun`: secants through its non-linearity).

``accel_bias_change`` (the warm-up ``db exp(-t / T)`` on the x and y specific force, t from the
first IMU stamp, :func:`pospp.diagnose.rerun.warmed`): an IMU-side error A and B both read,
``u_j(t) = e_j exp(-t / T)``, and, where A aligned statically, the tilt its alignment took
from the error's mean over its window: ``phi_0 = J [0; mean u_j]`` (J
:func:`pospp.nav.alignment.static_attitude_jacobian` at the window's mean rate and specific
force).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp.calib.linear_null import LinearNull
from pospp.nav.strapdown import Trajectory, interpolate_trajectory
from pospp.rotation import dcm_from_quat

DIFF_STEP_S = 0.05
"""Half-width of the central differences of A's attitude and antenna velocity [s]."""


def _c_nb(trajectory: Trajectory, t_s: NDArray) -> NDArray:
    """A's C_nb (R, 3, 3) at ``t_s``."""
    return dcm_from_quat(interpolate_trajectory(trajectory, t_s).q_nb)


def _c_nb_rate(trajectory: Trajectory, t_s: NDArray) -> NDArray:
    """Its rate Cdot_nb (R, 3, 3) [1/s], central differences over +-:data:`DIFF_STEP_S`."""
    return (_c_nb(trajectory, t_s + DIFF_STEP_S)
            - _c_nb(trajectory, t_s - DIFF_STEP_S)) / (2.0 * DIFF_STEP_S)


def _antenna_velocity(trajectory: Trajectory, t_s: NDArray, lever_b_m: NDArray) -> NDArray:
    """The antenna's velocity (R, 3) NED [m/s] on A's solution: ``v + Cdot_nb l``."""
    return (interpolate_trajectory(trajectory, t_s).v_n_mps
            + _c_nb_rate(trajectory, t_s) @ lever_b_m)


def _lever_arm_errors(trajectory: Trajectory, t: NDArray, pos: NDArray, vel: NDArray,
                      lever_b_m: NDArray) -> NDArray:
    """Per metre of configured lever arm on each body axis (R, 3, 3): ``-C_nb``, ``-Cdot_nb``."""
    v = np.zeros((t.size, 3, 3))
    v[pos] = -_c_nb(trajectory, t[pos])
    v[vel] = -_c_nb_rate(trajectory, t[vel])
    return v


def _time_offset_errors(trajectory: Trajectory, t: NDArray, pos: NDArray, vel: NDArray,
                        lever_b_m: NDArray) -> NDArray:
    """Per second of GNSS time offset (R, 3, 1): the antenna's velocity, its acceleration."""
    v = np.zeros((t.size, 3, 1))
    v[pos, :, 0] = _antenna_velocity(trajectory, t[pos], lever_b_m)
    v[vel, :, 0] = (_antenna_velocity(trajectory, t[vel] + DIFF_STEP_S, lever_b_m)
                    - _antenna_velocity(trajectory, t[vel] - DIFF_STEP_S, lever_b_m)
                    ) / (2.0 * DIFF_STEP_S)
    return v


RECORD_ERRORS = {"lever_arm": _lever_arm_errors, "time_offset": _time_offset_errors}
"""The GNSS-side effects :func:`linear_signatures` makes, each with its records' errors per
unit parameter (module docstring)."""
LINEAR_EFFECTS = tuple(RECORD_ERRORS)


def gnss_record_errors(effect_id: str, trajectory: Trajectory, record_t_s: ArrayLike,
                       record_kind: ArrayLike, lever_b_m: ArrayLike) -> NDArray:
    """Per record (its time [s] and kind: 0 position, 1 velocity, else none) the error of its
    measurement per unit of the effect's parameter, (R, 3, P) (:data:`RECORD_ERRORS`), on A's
    ``trajectory``. ``lever_b_m``: the lever arm A was configured with (body FRD [m])."""
    if effect_id not in RECORD_ERRORS:
        raise ValueError(f"{effect_id}: no linear signature (expected one of {LINEAR_EFFECTS})")
    kind = np.asarray(record_kind)
    return RECORD_ERRORS[effect_id](trajectory, np.asarray(record_t_s, dtype=float),
                                    kind == 0, kind == 1, np.asarray(lever_b_m, dtype=float))


def record_errors(model: LinearNull, trajectory: Trajectory, effect_id: str,
                  lever_b_m: ArrayLike) -> NDArray:
    """:func:`gnss_record_errors` of every record of ``model``."""
    return gnss_record_errors(effect_id, trajectory, model.record_t_s, model.record_kind,
                              lever_b_m)


def linear_signatures(model: LinearNull, trajectory: Trajectory, lever_b_m: ArrayLike,
                      effect_ids: Sequence[str] = LINEAR_EFFECTS, *,
                      warmup: tuple[float, tuple[NDArray, float, float] | None] | None = None
                      ) -> dict[str, list[NDArray]]:
    """Per effect, per leg (id order) the signature (M, 2, P) of B minus A from A's gains
    (module docstring), all effects' columns in one pass of the linear system (its
    per-interval matrices are most of a pass's time).

    ``warmup``: (T [s], alignment) adds ``accel_bias_change``, the warm-up's (M, 2, 2) per
    unit ``db`` [m/s^2] on x and y; ``alignment`` (J (3, 6), t0, t1) of A's static alignment
    over (t0, t1] [s], None where it aligned in motion."""
    errs = {e: record_errors(model, trajectory, e, lever_b_m) for e in effect_ids}
    p_rec = sum(v.shape[2] for v in errs.values())
    if warmup is None and not errs:
        return {}
    n_rec = model.records[3].shape[0]
    record_v = np.zeros((n_rec, 3, p_rec + (2 if warmup is not None else 0)))
    if errs:
        record_v[:, :, :p_rec] = np.concatenate(list(errs.values()), axis=2)
    accel = phi0 = None
    if warmup is not None:
        u, phi_w = _warmup_input(model, *warmup)
        accel = np.zeros((u.shape[0], 3, record_v.shape[2]))
        accel[:, :, p_rec:] = u
        if phi_w is not None:
            phi0 = np.zeros((3, record_v.shape[2]))
            phi0[:, p_rec:] = phi_w
    cols = model.response(record_v, accel_b_mps2=accel, phi0_n_rad=phi0)
    out, at = {}, 0
    for e, v in errs.items():
        out[e] = [np.ascontiguousarray(c[:, 0:2, at:at + v.shape[2]]) for c in cols]
        at += v.shape[2]
    if warmup is not None:
        out["accel_bias_change"] = [np.ascontiguousarray(c[:, 0:2, p_rec:]) for c in cols]
    return out


def _warmup_input(model: LinearNull, settling_s: float,
                  alignment: tuple[NDArray, float, float] | None
                  ) -> tuple[NDArray, NDArray | None]:
    """The warm-up's columns (x, y) as :meth:`LinearNull.response` takes them: the
    accelerometer error ``e_j exp(-t / T)`` at each grid point (G, 3, 2) [m/s^2 per unit],
    and the attitude error A's static alignment took from it (3, 2) [rad] (None where A
    aligned in motion)."""
    t = np.asarray(model.grid_t_s, dtype=float)
    u = np.zeros((t.size, 3, 2))
    u[:, 0, 0] = u[:, 1, 1] = np.exp(-t / settling_s)
    phi0 = None
    if alignment is not None:
        jac, t0, t1 = alignment
        mean = settling_s * (np.exp(-t0 / settling_s) - np.exp(-t1 / settling_s)) / (t1 - t0)
        phi0 = np.asarray(jac, dtype=float)[:, 3:5] * mean
    return u, phi0
