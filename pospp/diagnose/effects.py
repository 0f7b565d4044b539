"""Library of candidate effects and their signatures on algorithm B's velocity error.

Frames and units: NED navigation frame (n), FRD body frame (b), SI inside (rad, rad/s, m/s,
m/s^2, s, m). Errors are computed minus true (B minus A); the misalignment phi satisfies
C_nb_hat = (I - [phi x]) C_nb; sensors read true + error. Display units (deg/h, ug/h, ppm,
ms, m, arcsec/km) only in :attr:`Effect.unit` and :attr:`Effect.si_per_unit`.

Signature
---------
The signature of an effect with parameters p on a leg is the sensitivity of B's horizontal
velocity error along the leg's ACTUAL trajectory, ``S(t) = d dv_h(t) / d p`` (shape (M, 2, P)
at the leg's samples), so that an effect of size p adds ``S(t) p`` to B minus A (to first
order). Three ways, picked per effect:

* 15-state transition matrices Phi(t, t0) along B (:class:`pospp.calib.replay.LegReplay`)
  for effects that are error-state forcings. A forcing u(tau) entering the error dynamics as
  ``dx' = F dx + G(tau) u(tau)`` gives (variation of constants)::

      dx(t) = Phi(t, t0) int_t0^t Phi(tau, t0)^-1 G(tau) u(tau) dtau

  evaluated by the trapezoidal rule on the leg's sample grid
  (:func:`pospp.calib.replay.forced_response`).
* A perturbation of algorithm A (lever arm): B minus A changes by B's propagated initial error
  minus A's own error.
* Finite differences of B re-run on perturbed IMU increments (time offset): the one
  strapdown kernel, through :func:`pospp.calib.replay.replay_velocity_error`.

Effects (stable identifiers)
----------------------------
``body_fixed_gyro_bias``
    Horizontal gyro bias fixed in the body frame [b_x, b_y] (FRD). In the "paper" base model
    the drift is a navigation-frame constant common to the legs; this effect is what tells
    the two apart (its north/east projection turns with the heading). In the "body" base it is
    part of the base model.
``vertical_gyro_drift``
    Body z gyro bias b_z (FRD). On level legs it is a heading drift, seen in the horizontal
    channels only through the Earth-rate coupling of the heading error (phi_D' = -b_z; tilt
    rate w_in,N phi_D): weak on short legs.
``accel_bias_change``
    Horizontal accelerometer bias changing in-run: a first-order (warm-up) settling
    ``b(t) = b_inf + db exp(-t / T)`` with ``t`` the run time (since the run's epoch, about the
    power-up) and T = ``accel_settling_s`` (default :data:`ACCEL_SETTLING_S`); parameters
    db = [db_x, db_y] (FRD). The bias at the leg start is absorbed by the alignment
    (g phi + b = 0, docs/method.md); the change since the start is not: forcing
    ``dv' = C_nb db (exp(-t / T) - exp(-t0 / T))``. Within one leg this change is nearly a
    ramp, and a ramp is indistinguishable from a horizontal body gyro bias on level legs
    (both give dv'' + w_s^2 dv = const, with r = g b_g): only the leg-to-leg change of the
    apparent bias (legs early and late after power-up) reveals it.
``gyro_scale_factor``
    Gyro scale-factor error [s_x, s_y, s_z] (measured = (1 + s) true, per axis): forcing
    ``phi' = -C_nb diag(s) w_ib_b``. On straight level legs w_ib_b is the Earth and transport
    rate only: needs rotation inside the legs (wander, turns) to be seen.
``time_offset``
    IMU time tag minus true time, tau: the increments labelled t were sensed at t - tau.
    Only the changes of the specific force and rate reveal it (uniform legs cannot).
``lever_arm``
    Error of A's IMU-to-antenna lever arm, computed minus true, [l_x, l_y, l_z] (FRD): A's
    velocity error is -C_nb (w_nb_b x dl) and its position error -C_nb dl. Only attitude
    changes reveal it.
``earth_rate_coupling``
    The Earth-rate (Foucault) and other couplings that the paper's closed form drops: its
    signature is the difference between the numerical transition along B and the closed
    form, applied to the current estimates; the parameter is the fraction of that coupling
    present (1 when the data obey the full error model). Only a candidate when the base
    model uses the closed form.
``gravity_disturbance``
    Horizontal gravity disturbance (deflection of the vertical) varying along the track:
    ``dg_h(r) = dg_h(r0) + Gamma (r - r0)``, Gamma the symmetric horizontal gradient
    [G_NN, G_NE, G_EE] (1/s^2). The value at the leg start is absorbed like a constant
    accelerometer bias; B (normal gravity) then errs by ``dv' = -Gamma (r - r0)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp import earth, rotation
from pospp.calib.design import leg_sensitivities
from pospp.calib.replay import (
    ImuIncrements,
    ImuSource,
    LegReplay,
    SolutionA,
    forced_response,
    replay_velocity_error,
)
from pospp.effects_catalog import catalog_entry, row_named
from pospp.nav.error_model import BG, DR, DV, PHI
from pospp.threads import map_in_threads

ACCEL_SETTLING_S = 1200.0
"""Default time constant of the accelerometer-bias warm-up of ``accel_bias_change`` [s]."""


@dataclass(frozen=True)
class ReplayContext:
    """What finite-difference signatures need to re-run B (optional).

    Attributes
    ----------
    imu : ImuIncrements or ImuRates
        The flight's raw increments (or its rates).
    solution_a : SolutionA
        Algorithm A.
    replay_kwargs : dict
        Keyword arguments the replays were made with (``accel_compensation``,
        ``gyro_bias_b_radps``, ``attitude_correction_n_rad``...), except the sampling, which is
        taken from the replays.
    """

    imu: ImuSource
    solution_a: SolutionA
    replay_kwargs: dict = dataclasses.field(default_factory=dict)


@dataclass(frozen=True)
class SignatureInputs:
    """What a signature may need besides its leg (SI; every field optional).

    Attributes
    ----------
    context : ReplayContext or None
        For the signatures that re-run B (``time_offset``; ``gyro_scale_factor`` exact).
    base_x_leg : ndarray (6,) or None
        The leg's current base estimates [phi_N, phi_E, phi_D, b_x, b_y, b_z] (Earth-rate).
    accel_settling_s : float
        The warm-up's time constant [s].
    origin_n_m : ndarray (2,) or None
        The leg's start, north and east of the flight's reference point [m] (a field over
        position: ``gravity_disturbance`` shape ``field``).
    extent_m : float
        The half-size of the flown area about that point [m] (the field's length scale).
    """

    context: ReplayContext | None = None
    base_x_leg: NDArray | None = None
    accel_settling_s: float = ACCEL_SETTLING_S
    origin_n_m: NDArray | None = None
    extent_m: float = float("nan")


Signature = Callable[[LegReplay, SignatureInputs], NDArray]
"""A signature function: (leg, inputs) -> d dv_h / d p (M, 2, P), SI."""


@dataclass(frozen=True)
class Effect:
    """A candidate effect of the library: a row with its behaviour.

    Attributes
    ----------
    effect_id : str
        Stable identifier (the ``effect`` column of diagnosis.parquet).
    description : str
        Physical name.
    parameters : tuple of str
        Parameter names (frames in the name: ``_x`` body FRD, ``_n`` / ``_e`` NED).
    unit : str
        Display unit of the parameters (diagnosis.parquet ``unit``).
    si_per_unit : float
        SI value of one display unit.
    plausible_si : float
        A large but plausible size (SI) for a navigation-grade POS: the observability screen
        drops parameter directions in which an effect of this size would stand less than 2
        noise sigmas above the current model (these legs cannot reveal it).
    needs_imu : bool
        True when the signature re-runs B (needs the IMU increments and A's solution).
    signatures : tuple of (str, Signature)
        Per shape the legs test (the catalogue's :data:`pospp.effects_catalog.SHAPES`; ""
        for an effect of one form) its signature; the first is the effect's own (its
        parameters and unit).
    """

    effect_id: str
    description: str
    parameters: tuple[str, ...]
    unit: str
    si_per_unit: float
    plausible_si: float
    needs_imu: bool = False
    signatures: tuple[tuple[str, Signature], ...] = ()

    @property
    def shapes(self) -> tuple[str, ...]:
        """The shapes the legs test ("" for one form)."""
        return tuple(s for s, _ in self.signatures)


def _catalogued(effect_id: str, signatures: dict[str, Signature],
                needs_imu: bool = False) -> Effect:
    """The library entry with the name, parameters, unit, SI conversion and plausible size of
    the catalogue both workflows share (:mod:`pospp.effects_catalog`) and its signatures."""
    c = catalog_entry(effect_id)
    if isinstance(c.si_per_unit, tuple):
        raise ValueError(f"{effect_id}: a diagnosis effect has one display unit")
    return Effect(c.name, c.description, c.parameters, c.unit, c.si_per_unit, c.plausible_si,
                  needs_imu, tuple(signatures.items()))


# --------------------------------------------------------------------------------------------
# building blocks


def body_rate_nb_radps(rep: LegReplay) -> NDArray:
    """w_nb_b at the samples from B's attitude (central differences of log(C_bn C_nb')), (M, 3)."""
    c = rep.c_nb
    rel = np.swapaxes(c[:-1], 1, 2) @ c[1:]
    w_mid = rotation.rotvec_from_dcm(rel) / np.diff(rep.t_s)[:, None]
    w = np.empty((rep.t_s.size, 3))
    w[1:-1] = 0.5 * (w_mid[1:] + w_mid[:-1])
    w[0], w[-1] = w_mid[0], w_mid[-1]
    return w


def _displacement_n_m(rep: LegReplay) -> NDArray:
    """Horizontal displacement since the leg start along B's nominal velocity (M, 2) [m]."""
    return rep.v_n0_mps[None, 0:2] * rep.t_s[:, None]


# --------------------------------------------------------------------------------------------
# signatures


def _sig_body_bias(rep: LegReplay, axes: slice) -> NDArray:
    return rep.phi[:, 3:5, BG][:, :, axes]


def _sig_accel_settling(rep: LegReplay, settling_s: float) -> NDArray:
    g = np.zeros((rep.t_s.size, 15, 2))
    change = np.exp(-(rep.t0_s + rep.t_s) / settling_s) - np.exp(-rep.t0_s / settling_s)
    g[:, DV, :] = rep.c_nb[:, :, 0:2] * change[:, None, None]
    return forced_response(rep, g)


def _sig_gyro_scale(rep: LegReplay) -> NDArray:
    """A gyro scale factor s_j forces B's tilt by ``phi' = -C_nb (s_j w_ib_b,j e_j)``, the
    body rate ``w_ib_b = C_bn (w_ie + w_en) + w_nb_b`` from B's attitude samples and the
    Earth and transport rates at the leg start (within 0.5 % of B re-run with the scaled
    rates on the reference flights' legs, 2.4 % on an axis whose response is small)."""
    w_ie = earth.earth_rate_n_radps(rep.lat_rad)
    w_en = earth.transport_rate_n_radps(rep.lat_rad, rep.height_m, rep.v_n0_mps)
    w_ib_b = np.einsum("kji,j->ki", rep.c_nb, w_ie + w_en) + body_rate_nb_radps(rep)
    g = np.zeros((rep.t_s.size, 15, 3))
    g[:, PHI, :] = -rep.c_nb * w_ib_b[:, None, :]
    return forced_response(rep, g)


def _sig_lever_arm(rep: LegReplay) -> NDArray:
    w = body_rate_nb_radps(rep)
    out = np.zeros((rep.t_s.size, 2, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        dv_a = -np.einsum("kij,kj->ki", rep.c_nb, np.cross(w, e))  # A's velocity error (M, 3)
        x0 = np.zeros(15)
        x0[DV] = dv_a[0]
        x0[DR] = -rep.c_nb0 @ e
        out[:, :, j] = rep.phi[:, 3:5, :] @ x0 - dv_a[:, 0:2]
    return out


def _sig_gravity(rep: LegReplay) -> NDArray:
    d = _displacement_n_m(rep)
    g = np.zeros((rep.t_s.size, 15, 3))
    # dv' = -Gamma d, Gamma = [[G_NN, G_NE], [G_NE, G_EE]]
    g[:, 3, 0] = -d[:, 0]
    g[:, 3, 1] = -d[:, 1]
    g[:, 4, 1] = -d[:, 0]
    g[:, 4, 2] = -d[:, 1]
    return forced_response(rep, g)


FIELD_DEGREES = (2, 3, 4)
"""Degrees of the disturbing potential's monomials in the ``field`` shape (2: the gradient)."""


def field_monomials() -> list[tuple[int, int]]:
    """(i, j) of the monomials ``u^i w^j`` of the field's potential, degree by degree."""
    return [(d - j, j) for d in FIELD_DEGREES for j in range(d + 1)]


def field_gradient(u: NDArray, w: NDArray) -> NDArray:
    """d/du and d/dw of every monomial of :func:`field_monomials` at (u, w) (N,): (N, 2, P)."""
    out = []
    for i, j in field_monomials():
        du = i * u ** max(i - 1, 0) * w**j if i else np.zeros_like(u)
        dw = j * u**i * w ** max(j - 1, 0) if j else np.zeros_like(u)
        out.append(np.stack([du, dw], axis=1))
    return np.stack(out, axis=2)


def _sig_gravity_field(rep: LegReplay, origin_n_m: NDArray, extent_m: float) -> NDArray:
    """A smooth deflection field over position: the disturbing potential a polynomial of
    degree 2-4 (:data:`FIELD_DEGREES`) in u = N / L, w = E / L (L = ``extent_m``, north and
    east of the flight's reference point), ``dg_h(r) = sum_k c_k grad_u P_k(u, w)``, c_k
    [m/s^2] g0 times the deflection each monomial makes at the area's edge; B (normal
    gravity) errs by ``dv' = -(dg_h(r(t)) - dg_h(r0))`` (the leg start's value absorbed like a
    constant accelerometer bias), along the leg's nominal track ``r = r0 + v0 t``."""
    d = origin_n_m[None, :] + _displacement_n_m(rep)
    grad = field_gradient(d[:, 0] / extent_m, d[:, 1] / extent_m)
    g = np.zeros((rep.t_s.size, 15, grad.shape[2]))
    g[:, 3:5, :] = -(grad - grad[0:1])
    return forced_response(rep, g)


def _sig_earth_rate(rep: LegReplay, base_x_leg: NDArray) -> NDArray:
    """(numerical - closed form) [d_phi, d_bg] applied to the current base estimates."""
    dp_n, db_n = leg_sensitivities(rep, "numerical")
    dp_c, db_c = leg_sensitivities(rep, "closed_form")
    diff = np.concatenate([dp_n - dp_c, db_n - db_c], axis=2)  # (M, 2, 6)
    return (diff @ base_x_leg)[:, :, None]


def _rerun_dv(rep: LegReplay, ctx: ReplayContext, imu: ImuIncrements) -> NDArray:
    """B's horizontal velocity at the replay's samples after re-running on ``imu``."""
    kw = {k: v for k, v in ctx.replay_kwargs.items()
          if k in ("accel_compensation", "gyro_bias_b_radps", "attitude_correction_n_rad")}
    dv = replay_velocity_error(imu, ctx.solution_a, rep.leg,
                               sample_rate_hz=1.0 / float(rep.t_s[1] - rep.t_s[0]), **kw)
    m = min(dv.shape[0], rep.t_s.size)
    out = np.zeros((rep.t_s.size, 2))
    out[:m] = dv[:m, 0:2]
    out[m:] = out[m - 1]
    return out


def _leg_window(imu: ImuSource, rep: LegReplay) -> tuple[ImuIncrements, int]:
    """A slice of the increments around a leg (faster re-runs); (window, first index)."""
    k0 = max(int(np.searchsorted(imu.t_s, rep.leg.start_s)) - 200, 0)
    k1 = min(int(np.searchsorted(imu.t_s, rep.leg.end_s, side="right")) + 200, imu.t_s.size - 1)
    return imu.window(k0, k1), k0


def _sig_time_offset(rep: LegReplay, ctx: ReplayContext, tau_s: float = 2e-3) -> NDArray:
    win, _ = _leg_window(ctx.imu, rep)
    base = _rerun_dv(rep, ctx, win)
    # increments labelled (t_k, t_k+1] sensed over (t_k - tau, t_k+1 - tau]: cumulative sums
    # interpolated (linear in the cumulative angle / velocity = constant rate inside a sample)
    t = win.t_s
    out = []
    for arr in (win.dtheta_b_rad, win.dv_b_mps):
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(arr, axis=0)])
        shifted = np.stack([np.interp(t - tau_s, t, cum[:, c]) for c in range(3)], axis=1)
        out.append(np.diff(shifted, axis=0))
    pert = ImuIncrements(t, out[0], out[1])
    return ((_rerun_dv(rep, ctx, pert) - base) / tau_s)[:, :, None]


def _settling(rep: LegReplay, x: SignatureInputs) -> NDArray:
    return _sig_accel_settling(rep, x.accel_settling_s)


def _scale(rep: LegReplay, x: SignatureInputs) -> NDArray:
    return _sig_gyro_scale(rep)


def _offset(rep: LegReplay, x: SignatureInputs) -> NDArray:
    if x.context is None:
        raise ValueError("time_offset: the IMU increments and A's solution are needed")
    return _sig_time_offset(rep, x.context)


def _earth(rep: LegReplay, x: SignatureInputs) -> NDArray:
    if x.base_x_leg is None:
        raise ValueError("earth_rate_coupling: the current base estimates are needed")
    return _sig_earth_rate(rep, np.asarray(x.base_x_leg, dtype=float))


def _field(rep: LegReplay, x: SignatureInputs) -> NDArray:
    if x.origin_n_m is None or not x.extent_m > 0:
        raise ValueError("gravity_disturbance field: the legs' positions are needed")
    return _sig_gravity_field(rep, np.asarray(x.origin_n_m, dtype=float), float(x.extent_m))


LIBRARY: tuple[Effect, ...] = (
    _catalogued("body_fixed_gyro_bias", {"": lambda r, x: _sig_body_bias(r, slice(0, 2))}),
    _catalogued("vertical_gyro_drift", {"": lambda r, x: _sig_body_bias(r, slice(2, 3))}),
    _catalogued("accel_bias_change", {"settling": _settling}),
    _catalogued("gyro_scale_factor", {"": _scale}),
    _catalogued("time_offset", {"": _offset}, needs_imu=True),
    _catalogued("lever_arm", {"": lambda r, x: _sig_lever_arm(r)}),
    _catalogued("earth_rate_coupling", {"": _earth}),
    _catalogued("gravity_disturbance", {"gradient": lambda r, x: _sig_gravity(r),
                                        "field": _field}),
)
"""The candidate effects on the legs, in the order they are tested, each with its signature
per shape (adding an effect: a catalogue row, a row here with its function, its test in
tests/unit/test_diagnose_effects.py and its line in docs/diagnose.md). The sensor families
fitted on A's innovations are :data:`pospp.diagnose.sensor_families.SENSOR_FAMILIES`."""

EFFECT_IDS: tuple[str, ...] = tuple(e.effect_id for e in LIBRARY)


def effect_by_id(effect_id: str) -> Effect:
    """The library entry of an identifier (ValueError naming the known ones otherwise)."""
    return row_named(LIBRARY, "effect_id", effect_id, "effect")


def signature(effect_id: str, rep: LegReplay, *, shape: str | None = None,
              context: ReplayContext | None = None, base_x_leg: NDArray | None = None,
              accel_settling_s: float = ACCEL_SETTLING_S, origin_n_m: NDArray | None = None,
              extent_m: float = float("nan")) -> NDArray:
    """Signature of one library effect on one leg, ``d dv_h / d p`` (M, 2, P), SI.

    Parameters
    ----------
    effect_id : str
        A library identifier (:data:`EFFECT_IDS`).
    rep : LegReplay
        The leg.
    shape : str, optional
        One of the effect's shapes (:attr:`Effect.shapes`; default its first).
    context, base_x_leg, accel_settling_s, origin_n_m, extent_m
        :class:`SignatureInputs` (``time_offset`` needs the context, ``earth_rate_coupling``
        the base estimates, the gravity ``field`` the legs' positions).
    """
    eff = effect_by_id(effect_id)
    table = dict(eff.signatures)
    key = eff.shapes[0] if shape is None else shape
    if key not in table:
        raise ValueError(f"{effect_id}: expected a shape of {eff.shapes}, got {shape!r}")
    return table[key](rep, SignatureInputs(context, base_x_leg, accel_settling_s, origin_n_m,
                                           extent_m))


def signatures(effect_id: str, replays: Sequence[LegReplay], *, threads: int = 1,
               **kwargs) -> list[NDArray]:
    """:func:`signature` of every leg, ``threads`` legs at once
    (:func:`pospp.threads.map_in_threads`: B's re-runs release the GIL; the result does not
    depend on it)."""
    return map_in_threads(lambda r: signature(effect_id, r, **kwargs), replays, threads)
