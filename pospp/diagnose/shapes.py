"""Shapes of a sensor-bias change over flight time, on one basis of hinges and steps.

Frames and units: run time t [s from the first IMU stamp]; a bias change b(t) per body axis
in SI (m/s^2 or rad/s). No I/O.

A change is written on a basis of K *hinges* at the knots ``t_k`` (:func:`knots_s`) and S
*steps* at the step times ``tau_s`` (:func:`step_times_s`, every :data:`STEP_SPACING_S`
between the first knot and the span's end)::

    R_k(t) = max(t - t_k, 0) / H,      H = 3600 s   (a slope of one unit per hour)
    U_s(t) = 1 if t >= tau_s else 0

so that ``b(t) = sum_k a_k R_k(t) + sum_s a_K+s U_s(t)`` (:func:`change_basis`): zero up to
the first knot (A's alignment point: before it the horizontal bias sits in A's tilt, and a
constant bias is A's own state). A shape with q coefficients c is the basis coefficients
``a = W c`` (``W`` (K + S, q), :meth:`TimeShape.variants`): the response of anything linear
in the bias (A's innovations, B's error) to the shape is the basis responses times W. One
response per basis function and axis serves every shape, whatever their number and their
non-linear parameters (the step's time, the settling's time constant), which are searched on
a grid.

Shapes (the catalogue's names, :data:`pospp.effects_catalog.SHAPES`):

``ramp``      ``b = r (t - t_0)``; c = r [unit per hour].
``step``      ``b = s`` from the step time on, 0 before, the time on the step grid
              (resolved to :data:`STEP_SPACING_S`); c = s; its parameter the step time.
``settling``  ``b = b_inf + db exp(-t / T)`` (t run time, T on :data:`SETTLING_GRID_S`): the
              piecewise-linear interpolant of ``db (exp(-t / T) - exp(-t_0 / T))`` at the
              knots; c = db.
``walk``      a free value at every knot (a random walk sampled at the knots, linearly
              between: the hinges alone); c = a, reported as the change since t_0 at each
              knot's end.
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
"""Most knots (each adds a column per axis and sensor to the linear pass of
:mod:`pospp.calib.innovation_response`, and a coefficient to the walk)."""
MIN_KNOTS = 6
"""Fewest knots (a short flight's are closer than :data:`KNOT_SPACING_S`): with 4 on a 15 min
flight a 300 ug random walk of the accelerometer was named, and a gyro walk beside it (F
10.7); with 6, the accelerometer's alone."""
STEP_SPACING_S = 60.0
"""Spacing of the step grid [s]: a step's time is resolved to it (A's innovations see an
accelerometer step of 300 ug sharper than a knot interval: as a ramp across one 150 s
interval it fitted 208 of RSS worse than the walk, and was named `walk`)."""
MAX_STEPS = 90
"""Most step times (the grid is widened beyond :data:`STEP_SPACING_S` on a long span)."""
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


def span_end_s(knots: NDArray) -> float:
    """The end of the span the knots split [s] (they are equally spaced, :func:`knots_s`)."""
    k = np.asarray(knots, dtype=float)
    return float(2.0 * k[-1] - k[-2])


def step_times_s(knots: NDArray) -> NDArray:
    """The step grid [s]: every :data:`STEP_SPACING_S` (at most :data:`MAX_STEPS` times)
    strictly inside the knots' span, the first a spacing after the first knot."""
    t0, t1 = float(knots[0]), span_end_s(knots)
    n = int(min(MAX_STEPS, max(1, np.ceil((t1 - t0) / STEP_SPACING_S) - 1)))
    return t0 + (t1 - t0) * np.arange(1, n + 1) / (n + 1)


def change_basis(t_s: NDArray, knots: NDArray) -> NDArray:
    """The hinges and the steps at ``t_s`` (N,): (N, K + S), the hinges [h] first."""
    t = np.asarray(t_s, dtype=float)
    steps = (t[:, None] >= step_times_s(knots)[None, :]).astype(float)
    return np.concatenate([hinge_basis(t, knots), steps], axis=1)


def basis_size(knots: NDArray) -> int:
    """K + S: the number of basis functions per axis."""
    return int(np.asarray(knots).size + step_times_s(knots).size)


def interpolant_weights(values: NDArray, knots: NDArray, t_end_s: float) -> NDArray:
    """Hinge coefficients (K,) of the piecewise-linear function through ``values`` (K + 1,)
    at the knots and ``t_end_s``, minus its value at the first knot (slope changes per
    hour)."""
    nodes = np.append(np.asarray(knots, dtype=float), float(t_end_s))
    slopes = np.diff(np.asarray(values, dtype=float)) / np.diff(nodes) * HOUR_S
    return np.diff(np.concatenate([[0.0], slopes]))


def _on_hinges(w: NDArray, knots: NDArray) -> NDArray:
    """Basis weights (K + S, q) of hinge weights (K, q): the steps' rows zero."""
    return np.concatenate([w, np.zeros((step_times_s(knots).size, w.shape[1]))], axis=0)


@dataclass(frozen=True)
class Variant:
    """One shape at one value of its non-linear parameter: ``a = weights @ c``."""

    shape: str
    weights: NDArray
    """(K + S, q): basis coefficients (:func:`change_basis`) per unit shape coefficient."""
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
    return [Variant("ramp", _on_hinges(w, knots), per_hour=True)]


def _steps(knots: NDArray, t_end_s: float) -> list[Variant]:
    taus = step_times_s(knots)
    half = 0.5 * (taus[1] - taus[0]) if taus.size > 1 else 0.5 * (t_end_s - knots[0])
    out = []
    for j, tau in enumerate(taus):
        w = np.zeros((knots.size + taus.size, 1))
        w[knots.size + j, 0] = 1.0
        out.append(Variant("step", w, float(tau), f"step at {tau:.0f} +- {half:.0f} s"))
    return out


def _settlings(knots: NDArray, t_end_s: float) -> list[Variant]:
    nodes = np.append(knots, t_end_s)
    out = []
    for tau in SETTLING_GRID_S:
        v = np.exp(-nodes / tau)
        w = interpolant_weights(v - v[0], knots, t_end_s)[:, None]
        out.append(Variant("settling", _on_hinges(w, knots), tau, f"T = {tau:.0f} s"))
    return out


def _walk(knots: NDArray, t_end_s: float) -> list[Variant]:
    return [Variant("walk", _on_hinges(np.eye(knots.size), knots),
                    parameter_text=f"{knots.size} knots")]


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
    return change_basis(ends, knots) @ (variant.weights @ c)


def change_at(t_s: NDArray, knots: NDArray, a: NDArray) -> NDArray:
    """The bias change ``sum_j a_j B_j(t)`` at ``t_s`` for basis coefficients ``a`` (K + S,
    P) (P axes; :func:`change_basis`): (N, P), in the unit of a step's coefficient."""
    return change_basis(t_s, knots) @ np.asarray(a, dtype=float)


def all_variants(names: Sequence[str], knots: NDArray, t_end_s: float) -> list[Variant]:
    """Every grid variant of the named shapes."""
    return [v for n in names for v in time_shape(n).variants(knots, t_end_s)]
