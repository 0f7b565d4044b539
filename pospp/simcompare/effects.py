"""Effect library of the measured-versus-simulated comparison (docs/compare_sim.md).

Each effect is a change of the simulation model (:class:`pospp.sim.sensors.ImuErrorModel`,
:class:`pospp.sim.gnss.GnssModel`) with parameters u (SI), its signature (the statistics of
:mod:`pospp.simcompare.stats` it moves, and the ones that are linear in u, used to fit u),
and how the slope d stat / d u is found:

* ``known``: the statistic is algorithm A's own estimate of the parameter (lever arm, scale
  factors, accelerometer bias trend, attitude offset), so the slope is the identity;
* ``trial``: the slope is measured by simulating once with a trial size per parameter,
  with the same random numbers as the base simulation (common random numbers);
* ``screen`` (scale factors): A's estimates choose the parameters (identity fit, at least
  2 sigma), and a trial simulation measures the slope of those only.

Variance-type effects (vibration, coloured GNSS error, bias instability) add a variance u >= 0
to the model's: the model's RMS becomes sqrt(rms_0^2 + u); their size is reported as sqrt(u)
with the upper 1-sigma distance sqrt(u + sigma_u) - sqrt(u). A fit below zero (less than the
base model) is no effect: the base model's levels are the log's own (step 0,
:mod:`pospp.simcompare.base_model`).

Names, parameter names, units and sign conventions are the shared catalogue's
(:mod:`pospp.effects_catalog`), the same as the leg-based diagnosis uses.

Effects (stable identifiers; the model change u; the reported size)
-------------------------------------------------------------------
``vibration``              accel and gyro sinusoidal vibration variance; RMS, m/s^2 and deg/s
``time_offset``            u = GNSS stamp minus true time (GnssModel.time_offset_s); reported
                           as the catalogue's IMU minus GNSS time, -u, ms. A's lever-arm
                           estimate absorbs it along the track (tau v), so the lever-arm
                           statistics are part of its signature
``lever_arm``              u = true minus configured IMU-to-antenna lever arm, body FRD;
                           reported as configured minus true, -u, m
``scale_factor``           gyro and accelerometer scale-factor errors, FRD; ppm
``mounting_misalignment``  IMU case rotated by rho (FRD) in the body: both sensor matrices
                           get C_sb = R(rho)^T exactly (v_s = C_sb v_b; to first order
                           I - [rho x]; :func:`mounting_sensor_errors`); arcsec
``coloured_gnss``          Gauss-Markov GNSS position and velocity errors (horizontal sigmas,
                           vertical 1.5 x) with one correlation time; m | s | m/s. The
                           library fits the position sigma at 60 s only;
                           :func:`coloured_tau_library` fits all three (the time on a grid)
``bias_instability``       gyro Gauss-Markov (random drift) variance added at the model's
                           correlation time; sigma, deg/h. Over a flight of minutes its
                           realization is one random bias, which A leaves in its attitude,
                           lever arm and bias trends: those statistics are one draw of it
                           (``SimEffect.ensemble``), compared with their spread between seeds
``accel_bias_ramp``        accelerometer bias ramp (ImuErrorModel.accel_bias_drift_ugph);
                           ug/h (the diagnosis's ``accel_bias_change`` is a settling step)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pospp.effects_catalog import catalog_entry
from pospp.qc.lever_time import LeverTime, lever_time_verdict
from pospp.rotation import dcm_from_rotvec
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel
from pospp.simcompare.stats import Stat
from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS, UG_MPS2

__all__ = ["BASE_DRAW", "BI_DRAW", "SimEffect", "LIBRARY", "EffectContext", "JointFit",
           "coloured_tau_library", "joint_stats", "library_by_name", "lever_time_fit"]

IMPLAUSIBLE_FACTOR = 50.0
"""A fitted effect more than this many times its catalogue's plausible size is not admissible
(:meth:`SimEffect.plausible`)."""
ACCEL_RAMP_TRIAL_MPS3 = 1e-4
"""Trial ramp of ``accel_bias_ramp`` [m/s^3] (about 37 000 ug/h): A's smoothed bias follows
only part of a ramp (its bias random walk lags), so the slope is measured, not the identity."""
SF_TRIAL = 5e-3
"""Trial scale factor of ``scale_factor`` (5000 ppm). A's scale-factor states follow only part
of a scale-factor error (a third of a 1 % gyro z error on a track of circles, a seventh of a
2 % accelerometer x error on a car track), so their slope is measured, for the scale factors
that A's estimates show (``SimEffect.screen``)."""
BI_TRIAL_DPH = 50.0
"""Trial Gauss-Markov sigma of ``bias_instability`` [deg/h]: large enough that its change of
the static Allan variance stands above the run-to-run change of the static stretch."""
SF_REFINE = 4
"""Secant iterations of the scale-factor fit on the simulated statistics."""
COLOURED_REFINE = 6
"""Secant iterations of the coloured GNSS error's variance fit: its statistics are concave in
the added variance (the innovation gate drops the largest position innovations from the NIS,
and the lag-1 correlation is bounded by 1), so a slope measured at the trial size reads a
larger error as smaller (docs/compare_sim.md)."""
COLOURED_GNSS_TAU_S = 60.0
"""Correlation time of the coloured GNSS error the library adds, before its fit [s]."""
MIN_COLOURED_TAU_S = 1.0
"""Shortest correlation time of the coloured GNSS error [s]."""
TAU_GRID_S = (10.0, 30.0, 60.0, 120.0, 300.0)
"""A grid for :func:`coloured_tau_library` [s]. None below 10 s: at 1 Hz a shorter one is
nearly white noise, which the library must not explain."""


@dataclass(frozen=True)
class EffectContext:
    """What an effect needs beyond the models: the measured IMU's dominant high-frequency
    line [Hz] (vibration frequency when the base model has none), and the joint estimate of
    the lever arm and the GNSS time offset on the measured log (made when first asked:
    :func:`pospp.flight_stages.lever_time_estimate`; None: not available)."""

    hf_peak_hz: float = float("nan")
    lever_time: Callable[[], LeverTime | None] | None = None


@dataclass(frozen=True)
class JointFit:
    """The fit of a joint effect (``SimEffect.joint``) and what it names.

    ``u``, ``cov``: the model change (SI, ``SimEffect.apply``'s parameters) and its
    covariance; ``effect``, ``params``, ``size``, ``sigma``, ``units``: the effect named and
    its parameters in the catalogue's units and signs; ``note``: the reading in words (both
    readings where the flight cannot separate them); ``extra``: further rows (parameter,
    value, sigma, unit), e.g. the combination the flight determines."""

    u: NDArray
    cov: NDArray
    effect: str
    params: tuple[str, ...]
    size: tuple[float, ...]
    sigma: tuple[float, ...]
    units: tuple[str, ...]
    note: str
    extra: tuple[tuple[str, float, float, str], ...] = ()


Apply = Callable[[ImuErrorModel, GnssModel, NDArray, EffectContext],
                 tuple[ImuErrorModel, GnssModel]]


@dataclass(frozen=True)
class SimEffect:
    """One effect of the library (module docstring).

    Attributes
    ----------
    name : str
    params : tuple of str
        Parameter names (u, SI).
    unit : str
        Unit of the reported size; ``si_per_unit`` converts (size_si = size x si_per_unit;
        one number, or one per parameter).
    fit_stats : tuple of str
        Statistics linear in u (the fit).
    explains : tuple of str
        Every statistic the effect moves (a gap there makes it a candidate).
    trial : tuple of float or None
        Trial sizes (SI) per parameter for the slope; None: the slope is the identity.
    variance : bool or tuple of bool
        u is an added variance (size reported as a signed RMS); per parameter when a tuple.
    apply : callable(imu, gnss, u, context) -> (imu, gnss)
    screen : bool
        The fit statistics are A's own estimates of the parameters, but A follows only part
        of the true value: the identity slope picks the parameters that are significant, and
        a trial simulation measures the slope of those only.
    """

    name: str
    params: tuple[str, ...]
    unit: str
    si_per_unit: float | tuple[float, ...]
    fit_stats: tuple[str, ...]
    explains: tuple[str, ...]
    trial: tuple[float, ...] | None
    variance: bool | tuple[bool, ...]
    apply: Apply
    screen: bool = False
    fit_first: tuple[str, ...] = ()
    """Fit statistics that, when the flight has them, are used alone (the others are weaker
    readings of the same parameter: e.g. the static gyro Allan variance for
    ``bias_instability``, which is linear in the added variance)."""
    fit_censored: tuple[str, ...] = ()
    """Fit statistics that, when one of them differs significantly, are used alone: the
    others are then censored readings that are neither monotone nor smooth in u (a coloured
    GNSS error that A's gate rejects records of: the NIS and the lag-1 correlation of the
    records used, ``gnss_pos_gated``)."""
    refine: int = 0
    """Secant iterations on the simulated statistic after the trial-slope fit (0: none):
    for effects that A's statistics follow non-linearly (scale factors, whose estimates in A
    saturate: :func:`pospp.simcompare.compare._refine`)."""
    sign: float = 1.0
    """Reported size = sign x u / si_per_unit: -1 where the catalogue's sign convention is
    the opposite of the simulation model's parameter (time offset, lever arm)."""
    grid: tuple[int, tuple[float, ...]] | None = None
    """A parameter the statistics are far from linear in, and its trial values (SI): the fit
    takes the best of them (:func:`pospp.simcompare.compare._grid_fit`)."""
    fixed: tuple[int, ...] = ()
    """Parameters a grid fit leaves at 0 (reported 0 with sigma 0)."""
    offset: tuple[float, ...] | None = None
    """Added to the reported size per parameter [unit]: for a parameter that is a change
    from a fixed start (the coloured GNSS error's correlation time: 60 s + u)."""
    ensemble: tuple[str, ...] = ()
    """For a random effect whose realization over one flight is one draw of a slow process
    (the gyro random drift: over a few minutes a random constant bias, which A leaves in its
    attitude, lever arm and bias trend): the statistics that are a signed mean of that draw.
    Their expectation stays where it was, their spread between draws grows, and their
    batch-means sigmas (blocks of one flight) do not see it. A model with the effect is
    simulated with other seeds too, and these statistics' sigmas are at least their spread
    between the draws (:func:`pospp.simcompare.ensemble.ensemble_spread`). Mean-square
    statistics (NIS, Allan variance, bias wander), whose expectation the effect moves, are
    not among them."""
    trial_at_fit: bool = False
    """With ``screen``: each trial simulation at the size the identity fit reads, not at
    ``trial`` (a fixed trial can take A far from where the statistics are linear)."""
    joint: Callable[[EffectContext], JointFit | None] | None = None
    """For a group of confounded effects estimated jointly on the measured log (not from the
    statistics): the fit and what it names (:class:`JointFit`; None: nothing to add)."""

    def plausible(self, u: NDArray, cov: NDArray) -> bool:
        """Every fitted size in the first parameter's unit within ``IMPLAUSIBLE_FACTOR`` x the
        catalogue's plausible size (:attr:`pospp.effects_catalog.CatalogEffect.plausible_si`):
        a fit beyond it is no sensor's error but another model's misfit (the quadrotor's DJI
        RTK/INS "GNSS": an 8.3e6 ppm gyro scale factor, an 86 deg yaw mounting)."""
        size, _ = self.size(u, cov)
        k = np.broadcast_to(np.asarray(self.si_per_unit, dtype=float), size.shape)
        units = [x.strip() for x in self.unit.split("|")]
        same = (np.array([x == units[0] for x in units]) if len(units) == size.size
                else np.ones(size.shape, bool))
        limit = IMPLAUSIBLE_FACTOR * catalog_entry(self.name).plausible_si / k[0]
        return bool(np.all(np.abs(size[same]) <= limit))

    def size(self, u: NDArray, cov: NDArray) -> tuple[NDArray, NDArray]:
        """Reported size and 1-sigma [unit] of the fitted u (SI) and its covariance."""
        u = np.asarray(u, dtype=float)
        s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        k = np.asarray(self.si_per_unit, dtype=float)
        var = np.broadcast_to(np.asarray(self.variance, dtype=bool), u.shape)
        # an added variance is >= 0 (the candidate clips it): sqrt(u), and as its sigma the
        # upper 1-sigma distance sqrt(u + sigma_u) - sqrt(u) (never negative)
        up = np.clip(u, 0.0, None)
        r = np.sqrt(up)
        sr = np.sqrt(up + s) - r
        size = self.sign * np.where(var, r, u) / k
        if self.offset is not None:
            size = size + np.asarray(self.offset, dtype=float)
        return size, np.where(var, sr, s) / k


def _vibration(imu: ImuErrorModel, gnss: GnssModel, u: NDArray, ctx: EffectContext):
    acc = np.sqrt(np.clip(np.square(imu.accel_vibration_rms_mps2) + u[0], 0.0, None))
    gyr = np.sqrt(np.clip(np.square(np.radians(imu.gyro_vibration_rms_dps)) + u[1], 0.0, None))
    kw: dict[str, Any] = {}
    if not imu.has_vibration():
        f = ctx.hf_peak_hz if np.isfinite(ctx.hf_peak_hz) else 50.0
        kw = {"vibration_freq_hz": float(f), "vibration_bandwidth_hz": 0.0}
    return replace(imu, accel_vibration_rms_mps2=tuple(acc),
                   gyro_vibration_rms_dps=tuple(np.degrees(gyr)), **kw), gnss


def _lever_time(imu, gnss, u, ctx):
    return imu, replace(gnss, lever_arm_b_m=tuple(np.add(gnss.lever_arm_b_m, u[:3])),
                        time_offset_s=gnss.time_offset_s + float(u[3]))


JOINT_SIGMAS = 5.0
"""A joint reading names an effect beyond this many of its sigmas (the QC checks' level)."""


def lever_time_fit(ctx: EffectContext) -> JointFit | None:
    """``lever_arm_time_offset``'s fit: the joint estimate on the measured log
    (:class:`pospp.qc.lever_time.LeverTime`) read by
    :func:`pospp.qc.lever_time.lever_time_verdict`. It names ``time_offset`` (the catalogue's
    IMU minus GNSS time, -tau, ms), ``lever_arm`` (configured minus true, m), both
    (``lever_arm_time_offset``), or, where the flight cannot separate them, the combination
    (``lever_arm_time_offset`` at the apparent lever arm, time offset 0, with the row
    ``forward_lever_arm_plus_v_time_offset``: the apparent forward lever arm, m, and the
    speed); None when the reading is "none". The model change u = [l - l_cfg, tau]."""
    lt = ctx.lever_time() if ctx.lever_time is not None else None
    if lt is None:
        return None
    v = lever_time_verdict(lt, sigmas=JOINT_SIGMAS)
    if v.kind == "none":
        return None
    cfg = lt.configured_b_m
    lev_names = tuple(f"lever_arm_{a}" for a in _XYZ)
    cov = np.zeros((4, 4))
    if v.kind == "confounded":
        dl, sl = lt.apparent_lever_b_m - cfg, lt.sigma_apparent_b_m
        cov[:3, :3] = np.diag(sl ** 2)
        extra = (("forward_lever_arm_plus_v_time_offset", float(lt.apparent_lever_b_m[0]),
                  float(sl[0]), "m"), ("speed_for_time_offset", lt.speed_mps, 0.0, "m_per_s"))
        return JointFit(np.array([*dl, 0.0]), cov, "lever_arm_time_offset", lev_names,
                        tuple(-dl), tuple(sl), ("m",) * 3, v.text, extra)
    dl, sl = lt.lever_b_m - cfg, lt.sigma_lever_b_m
    tau, st = lt.tau_s, lt.sigma_tau_s
    cov[:3, :3] = np.diag(lt.sigma_lever_given_tau_b_m ** 2) + np.outer(
        lt.dlever_dtau_mps, lt.dlever_dtau_mps) * st ** 2
    cov[:3, 3] = cov[3, :3] = lt.dlever_dtau_mps * st ** 2
    cov[3, 3] = st ** 2
    corr = tuple((f"correlation_lever_arm_{a}_time_offset", float(c), 0.0, "-")
                 for a, c in zip(_XYZ, lt.correlation, strict=True))
    if v.kind == "time_offset":
        return JointFit(np.array([*dl, tau]), cov, "time_offset", ("time_offset",),
                        (-1e3 * tau,), (1e3 * st,), ("ms",), v.text, corr)
    if v.kind == "lever_arm":
        return JointFit(np.array([*dl, tau]), cov, "lever_arm", lev_names, tuple(-dl),
                        tuple(sl), ("m",) * 3, v.text, corr)
    return JointFit(np.array([*dl, tau]), cov, "lever_arm_time_offset",
                    (*lev_names, "time_offset"), (*(-dl), -1e3 * tau), (*sl, 1e3 * st),
                    ("m", "m", "m", "ms"), v.text, corr)


def _scale(imu, gnss, u, ctx):
    return replace(imu, gyro_sf_ppm=tuple(np.add(imu.gyro_sf_ppm, u[:3] * 1e6)),
                   accel_sf_ppm=tuple(np.add(imu.accel_sf_ppm, u[3:] * 1e6))), gnss


def mounting_sensor_errors(rho_rad: NDArray) -> tuple[NDArray, NDArray]:
    """(scale factors [ppm] (3,), misalignments [xy, xz, yx, yz, zx, zy] [arcsec] (6,)) whose
    sensor matrix I + diag(sf) + off-diagonals is C_sb = R(rho)^T exactly (IMU case rotated by
    rho in the body, FRD; v_s = C_sb v_b). To first order the off-diagonals are -[rho x] and
    the scale factors 0; the second order, cos(rho) - 1 on the diagonal, is kept
    (docs/decisions.md "A mounting misalignment simulated as the exact rotation")."""
    c_sb = dcm_from_rotvec(np.asarray(rho_rad, dtype=float)).T
    sf_ppm = (np.diag(c_sb) - 1.0) * 1e6
    off = np.array([c_sb[0, 1], c_sb[0, 2], c_sb[1, 0], c_sb[1, 2], c_sb[2, 0], c_sb[2, 1]])
    return sf_ppm, off / ARCSEC_RAD


def _mounting(imu, gnss, u, ctx):
    sf, m = mounting_sensor_errors(u)
    return replace(imu, gyro_misalign_arcsec=tuple(np.add(imu.gyro_misalign_arcsec, m)),
                   accel_misalign_arcsec=tuple(np.add(imu.accel_misalign_arcsec, m)),
                   gyro_sf_ppm=tuple(np.add(imu.gyro_sf_ppm, sf)),
                   accel_sf_ppm=tuple(np.add(imu.accel_sf_ppm, sf))), gnss


def _coloured(imu, gnss, u, ctx):
    """u = [added horizontal variance (m^2), correlation time minus COLOURED_GNSS_TAU_S (s)]
    of the position error, and [added horizontal variance (m^2/s^2)] of the velocity error
    at the same correlation time."""
    h = float(np.sqrt(max(gnss.pos_gm_sigma_m[0] ** 2 + float(u[0]), 0.0)))
    hv = float(np.sqrt(max(gnss.vel_gm_sigma_mps[0] ** 2 + float(u[2]), 0.0)))
    tau = max(COLOURED_GNSS_TAU_S + float(u[1]), MIN_COLOURED_TAU_S)
    return imu, replace(gnss, pos_gm_sigma_m=(h, 1.5 * h), pos_gm_tau_s=tau,
                        vel_gm_sigma_mps=(hv, 1.5 * hv), vel_gm_tau_s=tau)


def _instability(imu, gnss, u, ctx):
    s = np.radians(np.asarray(imu.gyro_gm_sigma_dph)) / 3600.0
    s = np.sqrt(np.clip(s ** 2 + float(u[0]), 0.0, None))
    return replace(imu, gyro_gm_sigma_dph=tuple(s / DEG_PER_H_RADPS)), gnss


def _accel_change(imu, gnss, u, ctx):
    r = np.asarray(u) * 3600.0 / UG_MPS2
    return replace(imu, accel_bias_drift_ugph=tuple(np.add(imu.accel_bias_drift_ugph, r))), gnss


_XYZ = ("x", "y", "z")
_LEGS = ("legs_bma_ms", "legs_bma_heldout_ms")
BI_DRAW = ("att_offset_roll", "att_offset_pitch", "att_offset_yaw",
            *(f"a_lever_{a}" for a in _XYZ), *(f"a_{k}_trend_{a}" for k in ("gyro", "accel")
                                              for a in _XYZ),
            *(f"a_{k}_sf_{a}" for k in ("gyro", "accel") for a in _XYZ))
"""The statistics that are a signed mean of one draw of the gyro random drift
(``SimEffect.ensemble``): A's attitude offsets, lever-arm estimate, gyro and accelerometer
bias trends (the drift's tilt error leaks into A's accelerometer bias) and its estimate
pass's scale factors (the drift's change over a turn moves A's gyro bias there as a scale
factor would, and the heading error it leaves rotates the velocity error into the
accelerometer scale factors)."""
BASE_DRAW = (*BI_DRAW, "gnss_pos_gated")
"""The statistics that are one draw of a gyro drift already in the base model (step 0's level,
:func:`pospp.simcompare.compare.compare_flights`' ``base_ensemble``): those of ``BI_DRAW`` and
the share of position records A's gate rejects, which is decided by whether this draw's drift
carries A's error past the gate. The drift's level is fixed there, so no effect can explain a
gap by widening it; a ``bias_instability`` candidate, whose level is fitted, floors
``BI_DRAW`` only (its expectation of the share moves with the level)."""
COLOURED_DRAW = (*BI_DRAW, "lt_time_offset", *(f"lt_lever_{a}" for a in _XYZ))
"""The statistics that are a signed mean of one draw of a coloured GNSS error: A's estimates
that take up the slowly wandering position error (attitude offsets, lever arm, bias trends,
the estimate pass's scale factors) and the joint lever-arm / time-offset estimate's."""
_IMU_SPECTRUM = tuple(f"imu_band_{s}_{b}" for s in ("accel", "gyro") for b in ("lo", "hi"))


def _norm(kind: str) -> tuple[str, ...]:
    return tuple(f"gnss_{kind}_norm_{a}" for a in "ned")

def _effect(name: str, fit_stats: tuple[str, ...], explains: tuple[str, ...],
            trial: tuple[float, ...] | None, variance: bool | tuple[bool, ...], apply: Apply,
            **kw) -> SimEffect:
    """A library effect whose name, parameters, unit and SI conversion are the shared
    catalogue's (:mod:`pospp.effects_catalog`)."""
    c = catalog_entry(name)
    return SimEffect(c.name, c.parameters, c.unit, c.si_per_unit, fit_stats, explains, trial,
                     variance, apply, **kw)


LIBRARY: tuple[SimEffect, ...] = (
    _effect("vibration", ("imu_hf_accel_var", "imu_hf_gyro_var", *_IMU_SPECTRUM),
            ("imu_hf_accel_var", "imu_hf_gyro_var", *_IMU_SPECTRUM, "imu_avar_accel_1s",
             "imu_avar_gyro_1s"),
            (0.25, np.radians(0.5) ** 2), True, _vibration),
    # the lever arm and the GNSS time offset, jointly (pospp.qc.lever_time): u = true minus
    # configured lever arm (3), GNSS stamp minus true time; named by the joint reading
    _effect("lever_arm_time_offset", (),
            ("lt_time_offset", *(f"lt_lever_{a}" for a in _XYZ), "gnss_vel_dot_accel",
             *(f"a_lever_{a}" for a in _XYZ),
             "att_offset_pitch",
             "gnss_pos_nis", "gnss_vel_nis", *_norm("pos"), *_norm("vel"),
             "gnss_vel_lb_n", "gnss_vel_lb_e", "gnss_vel_lowband", *_LEGS), None, False,
            _lever_time, joint=lever_time_fit),
    _effect("scale_factor",
            (*(f"a_gyro_sf_{a}" for a in _XYZ), *(f"a_accel_sf_{a}" for a in _XYZ)),
            (*(f"a_gyro_sf_{a}" for a in _XYZ), *(f"a_accel_sf_{a}" for a in _XYZ),
             "gnss_vel_nis", "gnss_vel_norm_n", "gnss_vel_norm_e", *_LEGS),
            (SF_TRIAL,) * 6, False, _scale, screen=True, refine=SF_REFINE),
    _effect("mounting_misalignment", ("att_offset_roll", "att_offset_pitch", "att_offset_yaw"),
            ("att_offset_roll", "att_offset_pitch", "att_offset_yaw", *_LEGS), None, False,
            _mounting),
    # the position error at 60 s (the velocity's and the time fixed; coloured_tau_library
    # fits all three)
    _effect("coloured_gnss", ("gnss_pos_lag1", "gnss_pos_nis", "gnss_pos_gated"),
            ("gnss_pos_lag1", "gnss_pos_nis", "gnss_pos_gated", *_norm("pos"),
             *(f"gnss_pos_lb_{a}" for a in "ned"), "gnss_pos_lowband"),
            (0.04, 0.0, 0.0025), (True, False, True), _coloured,
            grid=(1, (0.0,)), fixed=(2,), offset=(0.0, COLOURED_GNSS_TAU_S, 0.0),
            refine=COLOURED_REFINE, fit_censored=("gnss_pos_gated",), ensemble=COLOURED_DRAW),
    _effect("bias_instability", ("imu_avar_gyro_static", "a_gyro_bias_wander",
                                 "imu_avar_gyro_10s", *_LEGS),
            ("imu_avar_gyro_static", "a_gyro_bias_wander", "imu_avar_gyro_10s",
             "gnss_vel_nis", *_norm("vel"), *BI_DRAW, *_LEGS),
            ((BI_TRIAL_DPH * DEG_PER_H_RADPS) ** 2,), True, _instability,
            fit_first=("imu_avar_gyro_static",), ensemble=BI_DRAW),
    _effect("accel_bias_ramp", tuple(f"a_accel_trend_{a}" for a in _XYZ),
            (*(f"a_accel_trend_{a}" for a in _XYZ), "a_accel_bias_wander", *_LEGS),
            (ACCEL_RAMP_TRIAL_MPS3,) * 3, False, _accel_change, screen=True,
            trial_at_fit=True),
)
"""The library, in a fixed order."""


def coloured_tau_library(taus_s: tuple[float, ...] = TAU_GRID_S) -> tuple[SimEffect, ...]:
    """The library with the coloured GNSS error's correlation time chosen from ``taus_s``
    [s] and its velocity error fitted too, on the position and velocity innovations'
    whiteness and NIS (the statistics are far from linear in tau: at each value the two
    variances are fitted and re-simulated, and the best is kept). Not the default (its
    reading of the hidden-error flight: docs/compare_sim.md)."""
    grid = (1, tuple(float(t) - COLOURED_GNSS_TAU_S for t in taus_s))
    fit = ("gnss_pos_lag1", "gnss_pos_nis", "gnss_pos_gated", "gnss_vel_lag1", "gnss_vel_nis")
    vel = ("gnss_vel_lag1", "gnss_vel_nis", *_norm("vel"),
           *(f"gnss_vel_lb_{a}" for a in "ned"), "gnss_vel_lowband")
    return tuple(replace(e, grid=grid, fixed=(), fit_stats=fit, explains=(*e.explains, *vel))
                 if e.name == "coloured_gnss" else e for e in LIBRARY)


def library_by_name() -> dict[str, SimEffect]:
    return {e.name: e for e in LIBRARY}


def joint_stats(lt: LeverTime, seen: np.ndarray) -> dict[str, Stat]:
    """The joint estimate's statistics on the measured flight (:mod:`pospp.simcompare.stats`:
    ``lt_time_offset`` where the offset is determined, ``lt_lever_*`` on the axes ``seen``):
    the offset, and the lever arm minus the configured one at it (the apparent one where the
    offset is not determined), with their sigmas."""
    out = {}
    if np.isfinite(lt.sigma_tau_s):
        out["lt_time_offset"] = Stat(lt.tau_s, lt.sigma_tau_s, np.inf)
        lev, sig = lt.lever_b_m, lt.sigma_lever_b_m
    else:
        lev, sig = lt.apparent_lever_b_m, lt.sigma_apparent_b_m
    for i, a in enumerate("xyz"):
        if seen[i]:
            out[f"lt_lever_{a}"] = Stat(float(lev[i] - lt.configured_b_m[i]), float(sig[i]),
                                        np.inf)
    return out
