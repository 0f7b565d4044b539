"""Shapes of a sensor-bias change over flight time, on one hinge basis.

Frames and units: run time t [s from the first IMU stamp]; a bias change b(t) per body axis
in SI (m/s^2 or rad/s). No I/O.

Every shape is a continuous piecewise-linear function of t with its knots at ``t_k``
(:func:`knots_s`), written on the *hinge* basis::

    R_k(t) = max(t - t_k, 0) / H,      H = 3600 s   (a slope of one unit per hour)

so that ``b(t) = sum_k a_k R_k(t)``: zero up to the first knot (A's alignment point: before it
the horizontal bias sits in A's tilt, and a constant bias is A's own state), slope changes
``a_k`` at the knots. A shape with q coefficients c is the hinge coefficients ``a = W c``
(``W`` (K, q), :meth:`TimeShape.variants`): the response of anything linear in the bias (A's
innovations, B's error) to the shape is the hinge responses times W. One response per knot
and axis serves every shape, whatever their number and their non-linear parameters (the step's
time, the settling's time constant), which are searched on a grid.

Shapes (the catalogue's names, :data:`pospp.effects_catalog.SHAPES`):

``ramp``      ``b = r (t - t_0)``; c = r [unit per hour].
``step``      ``b = s`` after the step, 0 before: resolved to one knot interval (a ramp
              across [t_j, t_j+1] of height s); c = s; its parameter the interval's middle.
``settling``  ``b = b_inf + db exp(-t / T)`` (t run time, T on :data:`SETTLING_GRID_S`): the
              piecewise-linear interpolant of ``db (exp(-t / T) - exp(-t_0 / T))`` at the
              knots; c = db.
``walk``      a free value at every knot (a random walk sampled at the knots, linearly
              between); c = a, reported as the change since t_0 at each knot's end.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp.effects_catalog import row_named

HOUR_S = 3600.0
"""The hinge basis' time unit [s]: its coefficients are slope changes per hour."""
KNOT_SPACING_S = 300.0
"""Default knot spacing [s] (the flight's span cut into pieces of at most this length)."""
MAX_KNOTS = 10
"""Most knots (each costs one A replay per axis and sensor: docs/diagnose.md)."""
MIN_KNOTS = 6
"""Fewest knots (a short flight's are closer than :data:`KNOT_SPACING_S`): with 4 on a 15 min
flight a 300 ug random walk of the accelerometer was named, and a gyro walk beside it (F
10.7); with 6, the accelerometer's alone."""
SETTLING_GRID_S = (300.0, 600.0, 1200.0, 2400.0, 4800.0)
"""Time constants the settling shape is tried at [s]."""


def knots_s(t_from_s: float, t_to_s: float, spacing_s: float = KNOT_SPACING_S,
            max_knots: int | None = None, min_knots: int | None = None) -> NDArray:
    """Knots from ``t_from_s`` (the first) splitting [t_from, t_to] into equal pieces of at
    most ``spacing_s`` (at least :data:`MIN_KNOTS`, at most :data:`MAX_KNOTS` knots) [s]."""
    if not t_to_s > t_from_s:
        raise ValueError(f"knots: the span must be positive, got {t_from_s} to {t_to_s} s")
    lo = MIN_KNOTS if min_knots is None else min_knots
    hi = MAX_KNOTS if max_knots is None else max_knots
    n = int(np.clip(np.ceil((t_to_s - t_from_s) / spacing_s), lo, hi))
    return t_from_s + (t_to_s - t_from_s) * np.arange(n) / n


def hinge_basis(t_s: NDArray, knots: NDArray) -> NDArray:
    """``R_k(t) = max(t - t_k, 0) / H`` at ``t_s`` (N,) for the K knots: (N, K) [h]."""
    return np.maximum(np.asarray(t_s, dtype=float)[:, None] - np.asarray(knots)[None, :],
                      0.0) / HOUR_S


def interpolant_weights(values: NDArray, knots: NDArray, t_end_s: float) -> NDArray:
    """Hinge coefficients (K,) of the piecewise-linear function through ``values`` (K + 1,)
    at the knots and ``t_end_s``, minus its value at the first knot (slope changes per
    hour)."""
    nodes = np.append(np.asarray(knots, dtype=float), float(t_end_s))
    slopes = np.diff(np.asarray(values, dtype=float)) / np.diff(nodes) * HOUR_S
    return np.diff(np.concatenate([[0.0], slopes]))


@dataclass(frozen=True)
class Variant:
    """One shape at one value of its non-linear parameter: ``a = weights @ c``."""

    shape: str
    weights: NDArray
    """(K, q): hinge coefficients per unit shape coefficient."""
    parameter: float = float("nan")
    """The non-linear parameter (the step's time, the settling's T) [s]; NaN if none."""
    parameter_text: str = ""
    """It for the tables ("T = 1200 s", "step at 1530 +- 150 s")."""
    per_hour: bool = False
    """Whether c is a rate per hour (the display unit gains ``_per_h``)."""


@dataclass(frozen=True)
class TimeShape:
    """A shape: its name and how it is written on the hinge basis."""

    name: str
    variants: Callable[[NDArray, float], list[Variant]]
    """(knots, t_end_s) -> the shape at every grid value of its parameter."""


def _ramp(knots: NDArray, t_end_s: float) -> list[Variant]:
    w = np.zeros((knots.size, 1))
    w[0, 0] = 1.0
    return [Variant("ramp", w, per_hour=True)]


def _steps(knots: NDArray, t_end_s: float) -> list[Variant]:
    nodes = np.append(knots, t_end_s)
    out = []
    for j in range(1, knots.size):
        w = np.zeros((knots.size, 1))
        w[j, 0] = HOUR_S / (nodes[j + 1] - nodes[j])
        if j + 1 < knots.size:
            w[j + 1, 0] = -w[j, 0]
        mid, half = 0.5 * (nodes[j] + nodes[j + 1]), 0.5 * (nodes[j + 1] - nodes[j])
        out.append(Variant("step", w, mid, f"step at {mid:.0f} +- {half:.0f} s"))
    return out


def _settlings(knots: NDArray, t_end_s: float) -> list[Variant]:
    nodes = np.append(knots, t_end_s)
    out = []
    for tau in SETTLING_GRID_S:
        v = np.exp(-nodes / tau)
        w = interpolant_weights(v - v[0], knots, t_end_s)[:, None]
        out.append(Variant("settling", w, tau, f"T = {tau:.0f} s"))
    return out


def _walk(knots: NDArray, t_end_s: float) -> list[Variant]:
    return [Variant("walk", np.eye(knots.size), parameter_text=f"{knots.size} knots")]


TIME_SHAPES: tuple[TimeShape, ...] = (
    TimeShape("settling", _settlings), TimeShape("step", _steps), TimeShape("ramp", _ramp),
    TimeShape("walk", _walk),
)
"""The shapes of a sensor-bias change (the catalogue's ``shapes`` of the sensor families)."""


def time_shape(name: str) -> TimeShape:
    """The shape of a name (ValueError naming the known ones otherwise)."""
    return row_named(TIME_SHAPES, "name", name, "shape")


def shape_values(variant: Variant, c: NDArray, knots: NDArray, t_end_s: float) -> NDArray:
    """The reported parameters of a fitted shape (per axis, SI or SI per hour): c itself, or
    for the walk the change since the first knot at each knot's end (K,)."""
    c = np.asarray(c, dtype=float)
    if variant.shape != "walk":
        return c
    ends = np.append(knots[1:], t_end_s)
    return hinge_basis(ends, knots) @ c


def change_at(t_s: NDArray, knots: NDArray, a: NDArray) -> NDArray:
    """The bias change ``sum_k a_k R_k(t)`` at ``t_s`` for hinge coefficients ``a`` (K, P)
    (P axes): (N, P), the unit of ``a`` times an hour."""
    return hinge_basis(t_s, knots) @ np.asarray(a, dtype=float)


def all_variants(names: Sequence[str], knots: NDArray, t_end_s: float) -> list[Variant]:
    """Every grid variant of the named shapes."""
    return [v for n in names for v in time_shape(n).variants(knots, t_end_s)]
