"""The one catalogue of effect names shared by both discrepancy workflows.

The leg-based diagnosis (:mod:`pospp.diagnose.effects`: signatures on B minus A) and the
measured-versus-simulated comparison (:mod:`pospp.simcompare.effects`: changes of the
simulation model) describe an effect in different ways, but each takes the effect's name,
parameter names, display unit, SI conversion, sign convention and plausible size from here,
so that a name means one effect with one unit and one sign in diagnosis.parquet,
sim_comparison.parquet and the report.

Units: SI inside; ``unit`` is the display unit as the tables spell it (``deg_per_h``,
``ug_per_h``; the report prints ``_per_`` as ``/``); the SI value of a display value x is
``x * si_per_unit`` (one number, or one per parameter). Frames: body FRD (``_x/_y/_z``),
NED (``_n/_e``).

Sign conventions (the same in both workflows)
---------------------------------------------
``time_offset``  the IMU's time tag minus the GNSS (reference) time of the same instant:
                 positive when the GNSS records are stamped early against the IMU, negative
                 when they are stamped late.
``lever_arm``    the configured (computed) IMU-to-antenna lever arm minus the true one.
Scale factors    measured = (1 + s) true.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS, G0_MPS2, UG_MPS2

__all__ = ["CatalogEffect", "CATALOG", "catalog_entry", "CatalogShape", "SHAPES", "shape_entry",
           "shape_unit", "row_named"]

_XYZ = ("x", "y", "z")


@dataclass(frozen=True)
class CatalogEffect:
    """One named effect: what the name means in every table.

    Attributes
    ----------
    name : str
        Stable identifier (the ``effect`` column of diagnosis.parquet and
        sim_comparison.parquet).
    description : str
        Physical name, with its sign convention.
    parameters : tuple of str
        Parameter names (frame in the suffix).
    unit : str
        Display unit (table spelling); ``" | "`` between the units of parameters that differ.
    si_per_unit : float or tuple of float
        SI value of one display unit (one per parameter when they differ).
    plausible_si : float
        A large but plausible size for a navigation- or survey-grade POS (SI of the first
        parameter's unit).
    shapes : tuple of str
        A family's shapes (:data:`SHAPES`), the one its parameters and unit describe first;
        empty for an effect of one form.
    """

    name: str
    description: str
    parameters: tuple[str, ...]
    unit: str
    si_per_unit: float | tuple[float, ...]
    plausible_si: float
    shapes: tuple[str, ...] = ()


CATALOG: tuple[CatalogEffect, ...] = (
    # both workflows
    CatalogEffect("time_offset", "IMU-GNSS time offset (IMU time tag minus GNSS time)",
                  ("time_offset",), "ms", 1e-3, 20e-3),
    CatalogEffect("lever_arm", "GNSS antenna lever-arm error (configured minus true)",
                  tuple(f"lever_arm_{a}" for a in _XYZ), "m", 1.0, 0.5),
    # the two above estimated jointly (pospp.qc.lever_time): named so when the flight shows
    # both, or cannot tell them apart (forward lever arm + v x time offset)
    CatalogEffect("lever_arm_time_offset",
                  "GNSS antenna lever-arm error and IMU-GNSS time offset, estimated jointly "
                  "(confounded along the track: forward lever arm + v x time offset)",
                  (*(f"lever_arm_{a}" for a in _XYZ), "time_offset"), "m | ms",
                  (1.0, 1.0, 1.0, 1e-3), 0.5),
    # the leg-based diagnosis
    CatalogEffect("body_fixed_gyro_bias",
                  "horizontal gyro bias fixed in the body frame (vs nav frame)",
                  ("gyro_bias_x", "gyro_bias_y"), "deg_per_h", DEG_PER_H_RADPS,
                  0.05 * DEG_PER_H_RADPS),
    CatalogEffect("vertical_gyro_drift", "vertical (body z) gyro drift", ("gyro_bias_z",),
                  "deg_per_h", DEG_PER_H_RADPS, 0.5 * DEG_PER_H_RADPS),
    CatalogEffect("accel_bias_change",
                  "horizontal accelerometer bias changing in-run (warm-up settling, step, "
                  "ramp, random walk)",
                  ("accel_bias_change_x", "accel_bias_change_y"), "ug", UG_MPS2,
                  100.0 * UG_MPS2, ("settling", "step", "ramp", "walk")),
    CatalogEffect("gyro_bias_change",
                  "horizontal gyro bias changing in-run beyond the drift model (step, ramp, "
                  "settling, random walk)",
                  ("gyro_bias_change_x", "gyro_bias_change_y"), "deg_per_h", DEG_PER_H_RADPS,
                  0.05 * DEG_PER_H_RADPS, ("step", "ramp", "settling", "walk")),
    CatalogEffect("gyro_scale_factor", "gyro scale-factor error",
                  tuple(f"gyro_sf_{a}" for a in _XYZ), "ppm", 1e-6, 1000e-6),
    CatalogEffect("earth_rate_coupling",
                  "Earth-rate (Foucault) coupling dropped by the closed form",
                  ("earth_rate_fraction",), "fraction", 1.0, 1.0),
    CatalogEffect("gravity_disturbance",
                  "gravity disturbance (deflection of the vertical) over position: its "
                  "gradient, or a smooth field along the track",
                  ("gravity_gradient_nn", "gravity_gradient_ne", "gravity_gradient_ee"),
                  "arcsec_per_km", G0_MPS2 * ARCSEC_RAD / 1000.0,
                  1.0 * G0_MPS2 * ARCSEC_RAD / 1000.0, ("gradient", "field", "deflection")),
    # the measured-versus-simulated comparison
    CatalogEffect("vibration", "IMU vibration (sinusoidal), RMS per axis",
                  ("accel_vibration_rms", "gyro_vibration_rms"), "m_per_s2 | deg_per_s",
                  (1.0, DEG_PER_H_RADPS * 3600.0), 1.0),
    CatalogEffect("scale_factor", "gyro and accelerometer scale-factor errors",
                  (*(f"gyro_sf_{a}" for a in _XYZ), *(f"accel_sf_{a}" for a in _XYZ)), "ppm",
                  1e-6, 1000e-6),
    CatalogEffect("mounting_misalignment", "IMU case rotated in the body (FRD rotation vector)",
                  tuple(f"rho_{a}" for a in _XYZ), "arcsec", ARCSEC_RAD, 3600.0 * ARCSEC_RAD),
    CatalogEffect("coloured_gnss",
                  "Gauss-Markov GNSS position and velocity errors (horizontal sigmas, vertical "
                  "1.5 x; one correlation time)",
                  ("pos_gm_sigma_h", "gm_tau", "vel_gm_sigma_h"), "m | s | m_per_s",
                  (1.0, 1.0, 1.0), 0.5),
    CatalogEffect("bias_instability", "gyro Gauss-Markov drift (random drift), sigma",
                  ("gyro_gm_sigma",), "deg_per_h", DEG_PER_H_RADPS, 10.0 * DEG_PER_H_RADPS),
    CatalogEffect("accel_bias_ramp", "accelerometer bias changing in-run, linearly (ramp)",
                  tuple(f"accel_ramp_{a}" for a in _XYZ), "ug_per_h", UG_MPS2 / 3600.0,
                  1000.0 * UG_MPS2 / 3600.0),
)
"""Every effect name of both libraries, once."""


@dataclass(frozen=True)
class CatalogShape:
    """One shape an effect family takes (the ``shape`` column of diagnosis.parquet).

    Attributes
    ----------
    name : str
    description : str
    per_hour : bool
        Its parameters are rates: the family's unit per hour (``ug_per_h``).
    unit : str
        Its own display unit when not the family's (empty: the family's), with
        ``si_per_unit`` the SI value of one and ``plausible_si`` a large but plausible size of
        each of its parameters (SI; the observability screen's).
    """

    name: str
    description: str
    per_hour: bool = False
    unit: str = ""
    si_per_unit: float = 1.0
    plausible_si: float = float("nan")


SHAPES: tuple[CatalogShape, ...] = (
    # sensor-bias changes over flight time (pospp.diagnose.shapes)
    CatalogShape("settling", "first-order settling b_inf + db exp(-t / T), T fitted on a grid"),
    CatalogShape("step", "a step between two knots of the flight time"),
    CatalogShape("ramp", "a linear change over the flight (rate)", per_hour=True),
    CatalogShape("walk", "a random walk: a free value at every knot, linear between"),
    # the gravity disturbance over position (pospp.diagnose.effects)
    CatalogShape("gradient", "a constant horizontal gradient of the deflection"),
    CatalogShape("field", "a smooth field along the track: the disturbing potential a "
                 "polynomial of degree 2-4 over the flown area; parameters: the deflection each "
                 "term makes at the area's edge, size their norm", unit="arcsec",
                 si_per_unit=G0_MPS2 * ARCSEC_RAD, plausible_si=3.0 * G0_MPS2 * ARCSEC_RAD),
    CatalogShape("deflection", "a constant deflection of the vertical (absorbed like a "
                 "constant accelerometer bias: not observable on legs)", unit="arcsec",
                 si_per_unit=G0_MPS2 * ARCSEC_RAD, plausible_si=10.0 * G0_MPS2 * ARCSEC_RAD),
)
"""Every shape name a family's row may carry, once."""


def row_named(rows: Sequence[Any], key: str, name: str, what: str) -> Any:
    """The row of a registry whose attribute ``key`` is ``name`` (ValueError saying ``what``
    and naming the known ones otherwise)."""
    for r in rows:
        if getattr(r, key) == name:
            return r
    raise ValueError(f"{what}: expected one of {tuple(getattr(r, key) for r in rows)}, "
                     f"got {name!r}")


def shape_entry(name: str) -> CatalogShape:
    """The shape of a name (ValueError naming the known ones otherwise)."""
    return row_named(SHAPES, "name", name, "shape")


def shape_unit(effect: str, shape: str) -> tuple[str, float]:
    """(display unit, SI per unit) of a family's parameters in one of its shapes (the rate
    of a ``ramp`` per hour of the family's unit; a shape with its own unit, that one)."""
    e, s = catalog_entry(effect), shape_entry(shape)
    if shape not in e.shapes:
        raise ValueError(f"{effect}: expected a shape of {e.shapes}, got {shape!r}")
    if s.unit:
        return s.unit, s.si_per_unit
    si = e.si_per_unit if isinstance(e.si_per_unit, float) else e.si_per_unit[0]
    return (e.unit + "_per_h" if s.per_hour else e.unit), si


def catalog_entry(name: str) -> CatalogEffect:
    """The catalogue entry of a name (ValueError naming the known ones otherwise)."""
    return row_named(CATALOG, "name", name, "effect")
