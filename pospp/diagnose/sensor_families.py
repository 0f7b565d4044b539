"""Sensor-bias changes over flight time named by family and shape from A's own innovations.

Frames and units: body FRD axes x, y; SI inside (m/s^2, rad/s, s); display units only in the
findings' ``unit``. No I/O: the innovations and their responses come from
:mod:`pospp.sensor_stage`.

Why A's innovations and not B minus A
-------------------------------------
A linear change of a horizontal accelerometer bias inside a leg, ``b_a = b0 + r t``, forces B
like a horizontal gyro bias ``r / g`` (both give ``dv'' + w_s^2 dv = const`` on a level leg:
exactly, measured, removing the true 985 ug/h ramp of flight_accel_ramp_100hz from B minus A
leaves the diagnosis's closing F unchanged at 206 and moves only the calibrated gyro bias,
docs/diagnose.md). What reveals it is the bias *level* A sees at each heading change (a
body-fixed bias flips in the navigation frame, a tilt does not), i.e. A's GNSS innovations.

The likelihood
--------------
A as configured (its own bias and drift model: "beyond the drift model") is run on the log
with its Kalman gains recorded; with those gains replayed (:class:`pospp.nav.filter.
GainReplay`) A is a fixed linear system, and its innovations are linear in a bias change
``b(t)`` added to the IMU samples. With ``b = sum_j a_j B_j(t)`` on the basis of hinges and
steps of :mod:`pospp.diagnose.shapes`, one linear pass of A's closed-loop error dynamics
(:mod:`pospp.calib.innovation_response`) gives the innovations' response ``J_j`` to every
basis function and axis; the innovations of the flight with the change removed are
``nu - J a``, and A's prediction-error likelihood (whitened by ``S^-1 = L L^T``,
``w = L^T nu``) is least squares::

    RSS(a) = sum_records | L^T (nu - J a) |^2

Each shape (``a = W c``) is fitted by least squares. The observability screen first asks
whether the family can be seen at all: a variant keeps the directions in which a plausible
coefficient stands 2 noise sigmas above the model before it (:func:`_candidate`); a family
none of whose variants keeps one is not tested. The screened fits' smallest BIC gives the
family's test: its nested F-test against the model before it, ``F = ((RSS_0 - RSS_1) / q) /
(RSS_1 / (n - k_1))``, significant at ``alpha / m`` after a Bonferroni factor for the variants
the screen kept (m: families tested at the step). The shape is then the one of smallest BIC,
``n log(RSS / n) + k log n`` (the workflow's criterion; k counts a shape's grid-searched
parameter too: a settling of T far beyond the span is a ramp), over the shapes of one
coefficient per axis (ramp, step, settling at every grid value) fitted in full and the
many-coefficient ones (the walk, the field) in their screened directions only: the screen
judges shapes at their plausible sizes, and there a walk's many knot rates reach more than a
ramp's one, so screening every shape alike named every gyro change `walk`; a few-coefficient
shape fitted in full is as well-posed as its sigmas say, while a walk's or a field's
unscreened directions read noise at implausible sizes. The family is named when the screened
test and the chosen shape's own F-test are both significant at ``alpha / m``. Families are
named in turn, the strongest F first, each later one with the earlier ones' columns in the
model (an accelerometer ramp also reads, alone, as a gyro ramp: 13.9 of F on the ramp flight,
nothing once the accelerometer's is in). Sigmas: the least squares' covariance with the
residual variance estimated.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp.calib.replay import forced_response
from pospp.diagnose._candidates import FIELD_PARAMETERS
from pospp.diagnose._linear import f_test
from pospp.diagnose.shapes import Variant, all_variants, change_at, shape_values
from pospp.distributions import f_sf, long_run_ratio
from pospp.effects_catalog import catalog_entry, row_named, shape_entry, shape_unit

AXES = ("x", "y")
"""The body axes a sensor family is fitted on (the horizontal ones the calibration's gyro
bias and B's horizontal error see)."""


@dataclass(frozen=True)
class InnovationDesign:
    """A's whitened innovations and what the fits read of their responses to each family's
    basis coefficients: the responses' Gram matrix, never the responses themselves.

    With ``J`` (n, p) every family's responses side by side, ``L^T J`` per SI basis
    coefficient (:func:`pospp.diagnose.shapes.change_basis`: a slope change of one SI unit
    per hour at knot k, a step of one SI unit at step time s; a sensor family's on body axis
    x and then y, the gravity field's per potential term), every least-squares fit of the
    workflow is a function of ``J^T J`` and ``J^T y`` (:class:`_Step`) but the flexible fit
    whose residual series gives the long-run variance ratio: that fit's columns are kept.

    Attributes
    ----------
    y : ndarray (n,)
        ``L^T nu`` over the records A used (whitened by its own ``S^-1``).
    gram : ndarray (p, p)
        ``J^T J``.
    jty : ndarray (p,)
        ``J^T y``.
    columns : mapping str -> (slice, int)
        Per family, its columns in ``J`` and its axes A (2 for a sensor family, 1 for the
        gravity field): A K columns, axis-major.
    flexible : mapping str -> ndarray (n, A q)
        Per family, the columns of its most flexible catalogue shape (:func:`flexible_variant`,
        ``J W`` per axis).
    knots : ndarray (K,)
        The hinge knots [s run time].
    t_end_s : float
        The end of the span the shapes are written over [s].
    record_t_s : ndarray (n / 3,)
        Each record's time [s run time] (the whitened innovation of a record is 3 rows of y).
    field_extent_m : float
        The half-size of the flown area the gravity field's potential is written over [m]
        (:func:`pospp.diagnose.effects.field_gradient`; NaN without the gravity family).
    time_offset_response : ndarray (n,)
        ``L^T J`` of a GNSS time offset (GNSS stamped one second earlier): what reads an
        offset left in the log (:func:`pospp.sensor_stage.innovation_design`); not a column
        of the families' fit.
    """

    y: NDArray
    gram: NDArray
    jty: NDArray
    columns: Mapping[str, tuple[slice, int]]
    flexible: Mapping[str, NDArray]
    knots: NDArray
    t_end_s: float
    record_t_s: NDArray
    field_extent_m: float = float("nan")
    time_offset_response: NDArray | None = None

    @classmethod
    def of_responses(cls, y: NDArray, responses: Mapping[str, NDArray], knots: NDArray,
                     t_end_s: float, record_t_s: NDArray, field_extent_m: float = float("nan"),
                     time_offset_response: NDArray | None = None) -> InnovationDesign:
        """The design of whole responses (per family (n, K, A), ``L^T J`` on each axis)."""
        sums = DesignSums(y, {f: r.shape[1:] for f, r in responses.items()}, knots, t_end_s,
                          field_extent_m)
        sums.add(0, np.concatenate([r.transpose(0, 2, 1).reshape(r.shape[0], -1)
                                    for r in responses.values()], axis=1))
        return sums.design(record_t_s, time_offset_response)


class DesignSums:
    """:class:`InnovationDesign` accumulated from its responses' rows a block at a time
    (:meth:`add`), so that no family's responses are held whole (a row never added reads as
    a zero response)."""

    def __init__(self, y: NDArray, shapes: Mapping[str, tuple[int, int]], knots: NDArray,
                 t_end_s: float, field_extent_m: float = float("nan")) -> None:
        """``shapes``: per family (K, A), its basis coefficients and axes, in the columns'
        order."""
        self.y, self.knots, self.t_end_s, self.extent = y, knots, t_end_s, field_extent_m
        self.columns: dict[str, tuple[slice, int]] = {}
        self.weights: dict[str, NDArray] = {}
        at = 0
        for fam, (k, n_ax) in shapes.items():
            self.columns[fam] = (slice(at, at + k * n_ax), n_ax)
            at += k * n_ax
            self.weights[fam] = flexible_variant(fam, catalog_entry(fam).shapes, knots, t_end_s,
                                                 k, field_extent_m).weights
        self.gram, self.jty = np.zeros((at, at)), np.zeros(at)
        self.flexible = {f: np.zeros((y.size, n_ax * self.weights[f].shape[1]))
                         for f, (_, n_ax) in self.columns.items()}

    def add(self, row: int, white: NDArray) -> None:
        """Rows ``row .. row + R`` of ``J`` (R, p)."""
        rows = slice(row, row + white.shape[0])
        self.gram += white.T @ white
        self.jty += white.T @ self.y[rows]
        for fam, (sl, n_ax) in self.columns.items():
            blk = white[:, sl].reshape(white.shape[0], n_ax, -1)
            self.flexible[fam][rows] = np.concatenate(
                [blk[:, a] @ self.weights[fam] for a in range(n_ax)], axis=1)

    def design(self, record_t_s: NDArray, time_offset_response: NDArray | None = None
               ) -> InnovationDesign:
        """The design once every row was added."""
        return InnovationDesign(self.y, self.gram, self.jty, self.columns, self.flexible,
                                self.knots, self.t_end_s, record_t_s, self.extent,
                                time_offset_response)


@dataclass(frozen=True)
class FamilyFinding:
    """One family named (or tested) with its chosen shape; display units in ``unit``."""

    effect: str
    shape: str
    shape_parameters: str
    parameters: tuple[str, ...]
    values: NDArray
    sigmas: NDArray
    value: float
    sigma: float
    unit: str
    statistic: float
    p_value: float
    delta_bic: float
    explained_fraction: float
    significant: bool
    basis_si: NDArray
    """(K, A): the fitted change on its basis, SI: a sensor change's basis coefficients
    (:func:`pospp.diagnose.shapes.change_basis`; K counts hinges and steps) on body x and y
    (A = 2), the gravity field's potential terms (A = 1)."""
    basis_cov_si: NDArray
    """(A K, A K): their covariance (axis-major: x's K, then y's)."""
    n_variants: int
    weights: NDArray
    """(K, q): the shape's basis coefficients per shape coefficient (its variant's)."""
    coefficients_si: NDArray
    """(A q,): the shape's fitted coefficients, SI (axis-major)."""
    coefficients_cov_si: NDArray
    """(A q, A q): their covariance."""


@dataclass(frozen=True)
class _Step:
    """The model before a step in the form its candidates are fitted in: each family's
    responses ``J_f`` (n, A K) projected off the model's columns ``X``, ``r = (I - X (X^T
    X)^+ X^T) J_f``, kept as ``r^T r`` and ``r^T y`` (made from the design's Gram matrix).

    By Frisch-Waugh-Lovell, a candidate's columns ``J M`` (``M = (I_A kron W) k``: the
    shape's weights, its kept directions) added to ``X`` fit with the coefficients
    ``c = G^-1 M^T r^T y``, ``G = M^T r^T r M``, whose block of ``(X_1^T X_1)^-1`` is
    ``G^-1``, and ``RSS_1 = RSS_0 - c^T M^T r^T y``: a candidate costs small matrices, not a
    pass over the n innovations."""

    rss: float
    k: int
    gram: Mapping[str, NDArray]
    """Per family, ``r^T r`` (A K, A K), axis-major (body x's K coefficients, then y's)."""
    rty: Mapping[str, NDArray]
    """Per family, ``r^T y`` (A K,)."""

    @classmethod
    def of(cls, design: InnovationDesign, families: Sequence[str], base: NDArray,
           rss: float, k: int) -> _Step:
        """``base`` (p, k): the model's columns as combinations of ``J``'s, ``X = J B``:
        ``r^T r = J_f^T J_f - J_f^T X (X^T X)^+ X^T J_f`` and ``r^T y`` alike, from the
        design's Gram matrix."""
        g, jty = design.gram, design.jty
        gx = g @ base
        inv = np.linalg.pinv(base.T @ gx, hermitian=True)
        xty = inv @ (base.T @ jty)
        gram, rty = {}, {}
        for fam in families:
            sl = design.columns[fam][0]
            gram[fam] = g[sl, sl] - gx[sl] @ inv @ gx[sl].T
            rty[fam] = jty[sl] - gx[sl] @ xty
        return cls(rss, k, gram, rty)


def _bic(rss: float, n: int, k: int) -> float:
    return n * np.log(rss / n) + k * np.log(n)


RATE_PLAUSIBLE_PER_H = 10.0
"""A plausible rate of change (a ramp's, a walk's slopes at its knots) is this many of the
family's plausible sizes per hour (1000 ug/h, 0.5 deg/h per hour; the catalogue's
``accel_bias_ramp`` says 1000 ug/h)."""


def _plausible(fam: str, v: Variant) -> float:
    """A large but plausible coefficient (SI) of a family's variant: its shape's own (the
    gravity field's 3 arcsec); a rate's (ramp, walk: slopes per hour)
    :data:`RATE_PLAUSIBLE_PER_H` times the family's; else the family's (a step's, a
    settling's: 100 ug, 0.05 deg/h)."""
    own = shape_entry(v.shape).plausible_si
    if np.isfinite(own):
        return own
    scale = RATE_PLAUSIBLE_PER_H if v.per_hour or v.shape == "walk" else 1.0
    return scale * float(catalog_entry(fam).plausible_si)


SCREEN_EIGENVALUE = 4.0
"""The observability screen's bar: a direction is kept when a plausible coefficient's response
along it has at least this many noise variances (2 sigmas) beyond the model before it."""
DEGENERATE = 1e-9
"""An unscreened variant keeps the directions whose eigenvalue is above this fraction of its
largest (numerically null ones dropped; weak ones kept: the F-test counts them)."""


def _candidate(design: InnovationDesign, step: _Step, fam: str, v: Variant,
               ratio: float = 1.0, screened: bool = True) -> dict | None:
    """One variant fitted on the model before ``step``: its observable directions
    (``screened``: those in which a plausible coefficient stands 2 noise sigmas above what
    the model before it fits, the workflow's screen; else every direction not numerically
    null), the nested F-test and the BIC (:class:`_Step`'s equations); None when it keeps no
    direction."""
    n_ax = design.columns[fam][1]
    w = np.kron(np.eye(n_ax), v.weights)  # (A K, A q): the shape's columns, axis-major
    lam, vec = np.linalg.eigh(w.T @ step.gram[fam] @ w * _plausible(fam, v) ** 2)
    bar = SCREEN_EIGENVALUE if screened else DEGENERATE * max(float(lam[-1]), 0.0)
    keep = vec[:, lam > bar] if lam[-1] > 0 else vec[:, :0]
    if not keep.shape[1]:
        return None
    m = w @ keep
    inv = np.linalg.pinv(m.T @ step.gram[fam] @ m)
    mty = m.T @ step.rty[fam]
    c = inv @ mty
    rss0, k0 = step.rss, step.k
    rss1, k1 = max(rss0 - float(c @ mty), 0.0), k0 + keep.shape[1]
    n = design.y.size
    f, _ = f_test(rss0, rss1, k1 - k0, n - k1)
    f = f / ratio  # the residual's correlation (long-run variance)
    p = float(f_sf(f, k1 - k0, n - k1)) if np.isfinite(f) else 1.0
    # a shape's non-linear parameter (the step's time, the settling's T: searched on a grid)
    # counts in its BIC: a settling of T well beyond the span is a ramp, and the ramp wins
    nonlinear = int(np.isfinite(v.parameter))
    return dict(v=v, c=keep @ c, inv=keep @ inv @ keep.T, rss=rss1, k=k1, f=f, p=p,
                bic=_bic(rss1, n, k1 + nonlinear), m=m)


def _finding(design: InnovationDesign, fam: str, best: dict, walk: dict, rss0: float,
             k0: int, p_adj: float, significant: bool, n_var: int) -> FamilyFinding:
    n = design.y.size
    s2 = best["rss"] / max(n - best["k"], 1)
    v: Variant = best["v"]
    entry = catalog_entry(fam)
    unit_name, unit_si = shape_unit(fam, v.shape)
    q = v.weights.shape[1]
    n_ax = design.columns[fam][1]
    c = best["c"].reshape(n_ax, q)  # axis-major
    cov = best["inv"] * s2
    # the reported values are linear in c: their covariance through the same map (a walk's
    # are its change at each knot's end; every other shape's, c)
    mp = (shape_values(v, np.eye(q), design.knots, design.t_end_s) if v.shape == "walk"
          else np.eye(q))
    m = np.kron(np.eye(n_ax), mp)
    vals = m @ best["c"] / unit_si
    cv = m @ cov @ m.T / unit_si**2
    sig = np.sqrt(np.clip(np.diag(cv), 0.0, None))
    if v.shape == "walk":  # the size: the RMS change over the knots' ends, both axes
        size = float(np.sqrt(np.mean(vals**2)))
        g = vals / (vals.size * size) if size > 0 else np.zeros_like(vals)
    else:
        size = float(np.linalg.norm(vals))
        g = vals / size if size > 0 else np.zeros_like(vals)
    size_sig = float(np.sqrt(max(g @ cv @ g, 0.0)))
    excess = rss0 - best["rss"] - (best["k"] - k0) * s2
    total = rss0 - walk["rss"] - (walk["k"] - k0) * s2
    frac = float(np.clip(excess / total, 0.0, None)) if total > 0 else float("nan")
    if v.shape == "field":
        names: tuple[str, ...] = FIELD_PARAMETERS
    else:
        names = tuple(f"{p}_{i}" if v.shape == "walk" else p
                      for p in entry.parameters for i in range(len(vals) // n_ax))
    hinge = np.stack([v.weights @ c[a] for a in range(n_ax)], axis=1)
    wcov = np.kron(np.eye(n_ax), v.weights) @ cov @ np.kron(np.eye(n_ax), v.weights).T
    return FamilyFinding(fam, v.shape, v.parameter_text, names, vals, sig, size, size_sig,
                         unit_name, best["f"], p_adj, best["bic"] - _bic(rss0, n, k0), frac,
                         significant, hinge, wcov, n_var, v.weights, best["c"], cov)


SCALE_BAND = 3.0
"""A's whitened innovations must have the variance its own S says, within this factor either
way, after every family's most flexible shape (per scalar, 1 when A's model holds): outside
it A's model does not hold where the shapes live and no family is named. Measured: 0.89-0.99
on flight_accel_ramp_100hz and the null reference flights; 0.025 on a clean MEMS flight of the
QC benchmark with 2 cm GNSS and 6 m/s^2 of vibration (S 40 times the innovations' variance,
their long-run variance ratio 10), which named an accelerometer and a gyro walk."""


def _flexible_residual(design: InnovationDesign, families: Sequence[str]
                       ) -> tuple[NDArray, int]:
    """The innovations' residual after every family's most flexible shape (the design's
    ``flexible`` columns of ``families``) and the number of its columns."""
    full = np.concatenate([design.flexible[f] for f in families], axis=1)
    c, _, _, _ = np.linalg.lstsq(full, design.y, rcond=None)
    return design.y - full @ c, full.shape[1]


def fit_sensor_families(design: InnovationDesign, families: Sequence[str],
                        shapes: Mapping[str, Sequence[str]], alpha: float
                        ) -> tuple[list[FamilyFinding], list[FamilyFinding], float, bool]:
    """Name the sensor families the innovations hold, in turn (module docstring).

    Parameters
    ----------
    design : InnovationDesign
    families : sequence of str
        Catalogue names with a response in ``design``.
    shapes : mapping
        Family -> the shapes tried (:data:`pospp.diagnose.shapes.TIME_SHAPES` names; the
        ``walk`` among them is the reference of the explained fraction).
    alpha : float
        Family-wise level of each step.

    Returns
    -------
    (named, tested, ratio, holds)
        The families named, in order, every family's chosen shape at every step, and the
        long-run variance ratio of the residual after every family's most flexible catalogue
        shape (the design's ``flexible`` columns; :func:`long_run_ratio`, over the knot
        spacing): each F is divided by it (an
        unmodelled random walk leaves a rough residual the knots cannot follow). Nothing is
        named when that residual's variance per scalar
        is outside :data:`SCALE_BAND` (A's S does not describe its innovations: ``holds``
        False).
    """
    n = design.y.size
    base = np.zeros((design.jty.size, 0))  # the model's columns, X = J B
    rss0, k0 = float(design.y @ design.y), 0
    named: list[FamilyFinding] = []
    tested: list[FamilyFinding] = []
    left = [f for f in families if f in design.columns]
    variants_of = {f: family_variants(f, shapes[f], design.knots, design.t_end_s,
                                      design.columns[f][0].stop - design.columns[f][0].start,
                                      design.field_extent_m) for f in left}
    resid, k_full = _flexible_residual(design, left)
    spacing = (design.t_end_s - float(design.knots[0])) / design.knots.size
    ratio = long_run_ratio(resid, design.record_t_s, spacing)
    scale = float(resid @ resid) / max(n - k_full, 1)
    holds = 1.0 / SCALE_BAND <= scale <= SCALE_BAND
    while left:
        trials = {}
        step = _Step.of(design, left, base, rss0, k0)
        for fam in left:
            variants = variants_of[fam]
            cands = [c for v in variants
                     if (c := _candidate(design, step, fam, v, ratio)) is not None]
            if not cands:  # these data cannot reveal the family
                continue
            screened = min(cands, key=lambda c: c["bic"])
            walk = next((c for c in cands if c["v"].shape == "walk"), screened)
            few = [c for v in variants if v.weights.shape[1] == 1 and (c := _candidate(
                design, step, fam, v, ratio, screened=False)) is not None]
            best = min([c for c in cands if c["v"].weights.shape[1] > 1] + few,
                       key=lambda c: c["bic"])
            p_adj = min(1.0, max(screened["p"] * len(cands), best["p"]))
            sig = bool(p_adj < alpha / len(left)) and holds
            trials[fam] = (best, _finding(design, fam, best, walk, rss0, k0, p_adj, sig,
                                          len(variants)))
            tested.append(trials[fam][1])
        good = [fam for fam, (_, fnd) in trials.items() if fnd.significant]
        if not good:
            break
        fam = max(good, key=lambda f: trials[f][1].statistic)
        best, fnd = trials[fam]
        named.append(fnd)
        cols = np.zeros((base.shape[0], best["m"].shape[1]))
        cols[design.columns[fam][0]] = best["m"]
        base = np.concatenate([base, cols], axis=1)
        rss0, k0 = best["rss"], best["k"]
        left.remove(fam)
    return named, tested, ratio, holds


# --------------------------------------------------------------------------------------------
# what a named change does to B minus A (the calibration's data)


def accel_response_along_b(rep, change_b: NDArray, change_b0: NDArray) -> NDArray:
    """B's horizontal velocity error (M, 2) [m/s] from an accelerometer bias change
    ``change_b`` (M, 2) [m/s^2] at the leg's samples, body x and y: B starts on A, whose tilt
    and bias estimate took up the bias at the leg start (``change_b0``), so the forcing is
    ``dv' = C_nb (b(t) - b(t0))`` (checked against flight_accel_ramp_100hz's truth: B's error
    within 0.6-3.2 mm/s RMS per leg of this, the true gyro bias and the tilts)."""
    g = np.zeros((rep.t_s.size, 15, 1))
    g[:, 3:6, 0] = np.einsum("kij,kj->ki", rep.c_nb[:, :, 0:2], change_b - change_b0)
    return forced_response(rep, g)[:, :, 0]


def gyro_response_along_b(rep, change_b: NDArray, change_b0: NDArray) -> NDArray:
    """B's horizontal velocity error (M, 2) [m/s] from a gyro bias change ``change_b`` (M, 2)
    [rad/s], body x and y: B integrates the raw rates, so the whole change forces its tilt,
    ``phi' = -C_nb b(t)`` (pospp.nav.error_model); ``change_b0`` is not used (the tilt at the
    leg start is A's)."""
    g = np.zeros((rep.t_s.size, 15, 1))
    g[:, 0:3, 0] = -np.einsum("kij,kj->ki", rep.c_nb[:, :, 0:2], change_b)
    return forced_response(rep, g)[:, :, 0]


def gravity_response_along_b(rep, field_change: NDArray, field_change0: NDArray) -> NDArray:
    """B's horizontal velocity error (M, 2) [m/s] from a gravity disturbance ``dg_h`` (M, 2)
    [m/s^2] along the leg: B (normal gravity) errs by ``dv' = -(dg_h(r) - dg_h(r0))``
    (:mod:`pospp.diagnose.effects`, the ``field`` shape)."""
    g = np.zeros((rep.t_s.size, 15, 1))
    g[:, 3:5, 0] = -(field_change - field_change0)
    return forced_response(rep, g)[:, :, 0]


@dataclass(frozen=True)
class SensorFamily:
    """A family fitted on A's innovations: what its change perturbs and what it does to B."""

    effect_id: str
    sensor: str
    """"accel" (a specific-force bias), "gyro" (a rate bias): a change over flight time on
    the hinge basis; "gravity": a deflection field over position (the potential's terms of
    :func:`pospp.diagnose.effects.field_monomials`), the specific force's ``-C_bn dg_n``."""
    response_along_b: Callable[..., NDArray]
    """(replay, change (M, 2) SI, change at the leg start (2,)) -> B's error (M, 2) [m/s]."""


SENSOR_FAMILIES: tuple[SensorFamily, ...] = (
    SensorFamily("accel_bias_change", "accel", accel_response_along_b),
    SensorFamily("gyro_bias_change", "gyro", gyro_response_along_b),
    SensorFamily("gravity_disturbance", "gravity", gravity_response_along_b),
)
"""The families fitted on A's innovations, in the order they are tested. The gravity field
competes with the sensor changes: a deflection wave along the track reads, alone, as an
accelerometer and a gyro change (docs/diagnose.md, "Power on shapes")."""


def family_variants(effect_id: str, shapes: Sequence[str], knots: NDArray, t_end_s: float,
                    n_columns: int, field_extent_m: float = float("nan")) -> list[Variant]:
    """The variants a family is fitted in: a sensor change's every shape and grid value on the
    hinge basis (:func:`pospp.diagnose.shapes.all_variants`), the gravity field's one (all
    its potential's ``n_columns`` terms, written over ``field_extent_m``)."""
    if sensor_family(effect_id).sensor == "gravity":
        return [Variant("field", np.eye(n_columns),
                        parameter_text=f"over {field_extent_m / 1000.0:.0f} km")]
    return all_variants([s for s in shapes if s not in ("gradient", "field", "deflection")],
                        knots, t_end_s)


def flexible_variant(effect_id: str, shapes: Sequence[str], knots: NDArray, t_end_s: float,
                     n_columns: int, field_extent_m: float = float("nan")) -> Variant:
    """The family's variant of the most coefficients (:func:`family_variants`' arguments):
    the fit whose residual gives the long-run variance ratio."""
    return max(family_variants(effect_id, shapes, knots, t_end_s, n_columns, field_extent_m),
               key=lambda v: v.weights.shape[1])


def sensor_family(effect_id: str) -> SensorFamily:
    """The family of a name (ValueError naming the known ones otherwise)."""
    return row_named(SENSOR_FAMILIES, "effect_id", effect_id, "sensor family")


def response_along_b(finding: FamilyFinding, knots: NDArray, replays: Sequence,
                     basis_si: NDArray | None = None) -> list[NDArray]:
    """B minus A's response (M, 2) per leg to a finding's change (its fitted basis
    coefficients, or ``basis_si`` (K + S, 2)), relative to the change's mean over the legs'
    samples (the constant part is the calibration's own bias: what it reads is then the
    bias at the legs' mean, not at the first knot)."""
    fam = sensor_family(finding.effect)
    a = finding.basis_si if basis_si is None else basis_si
    ch = [change_at(r.t0_s + r.t_s, knots, a) for r in replays]
    mean = np.mean(np.concatenate(ch), axis=0) if fam.sensor == "gyro" else 0.0
    return [fam.response_along_b(r, c - mean, c[0]) for r, c in zip(replays, ch, strict=True)]
