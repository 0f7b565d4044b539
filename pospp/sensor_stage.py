"""The sensor families of the diagnosis: A's innovations and their responses.

:func:`innovation_design` reads algorithm A as configured on the log with its gains recorded
(the run's own pass where nothing is removed from the log; else A run on the log summed down
to ``[pairs] rerun_imu_rate_hz`` with the named GNSS-side effects removed) and propagates
every column of each family (a basis function of :func:`pospp.diagnose.shapes.change_basis`
per body axis x, y and sensor; a term of the gravity field's potential) through A's
closed-loop error dynamics with those gains in one linear pass per family
(:class:`pospp.calib.innovation_response.ResponseSystem`): the innovations' linear responses
of :mod:`pospp.diagnose.sensor_families`. The same pass of the records' errors per second of
a GNSS time offset (:func:`pospp.diagnose.linear_signatures.gnss_record_errors`) gives the
offset's column, with which :func:`_without_time_offset` reads an offset left in the log and
removes it. :func:`sensor_families` names the families and :func:`with_sensor_families`
returns them as diagnosis rows with what each does to B (its worth at the horizon). Nothing
here touches files.

Cost: per design a linear pass per family and one for the offset (a 15 x m matrix over a
grid of A's records, the knots and the step times, at most 1 s apart; m = 2 (K + S), K <= 10
hinges, S <= 60 steps, or 12 field terms), and A's forward pass with its gains where the
log's own cannot serve.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pospp import earth
from pospp.calib.innovation_response import ResponseSystem
from pospp.calib.replay import SolutionA
from pospp.config import PipelineConfig
from pospp.diagnose.effects import ACCEL_SETTLING_S, field_gradient, signature
from pospp.diagnose.linear_signatures import gnss_record_errors
from pospp.diagnose.locate import horizon_worth
from pospp.diagnose.rerun import restamped, warmed, with_rates
from pospp.diagnose.results import CandidateTest, Diagnosis, DiagnosisStep, EffectResponse
from pospp.diagnose.sensor_families import (
    AXES,
    SENSOR_FAMILIES,
    DesignSums,
    FamilyFinding,
    InnovationDesign,
    fit_sensor_families,
    response_along_b,
    sensor_family,
)
from pospp.diagnose.shapes import change_basis, knots_s, step_times_s
from pospp.distributions import long_run_ratio
from pospp.effects_catalog import catalog_entry
from pospp.flight_stages import imu_tuning, navigate, static_alignment_window, summed_down
from pospp.io import mcap_reader
from pospp.nav.filter import STATUS_USED
from pospp.qc.lever_time import LeverTime
from pospp.units import t_s_from_time_ns

CRITERION = "innovation_F_bonferroni_shapes"
"""The criterion of a sensor family's row: the nested F-test on A's whitened innovations,
Bonferroni over the shape variants tried and the families tested."""
GNSS_SIDE = ("time_offset", "lever_arm", "gyro_scale_factor", "accel_bias_change")
"""Named effects removed from the log (or A's configuration) before the families are fitted:
a 15 ms GNSS offset left in reads as an accelerometer change on A's innovations
(flight_time_offset_200hz: the walk's likelihood ratio 340 on 20 parameters; removed, 1.7)."""


def _removed(log: Any, config: PipelineConfig, d: Diagnosis
             ) -> tuple[Any, np.ndarray | None, tuple[str, ...]]:
    """(log, lever arm) with the named GNSS-side effects of ``d`` taken off (the conventions of
    :func:`pospp.diagnose.rerun.signature_at`), and the effects removed."""
    lever = None
    done = []
    for e in d.named:
        if e not in GNSS_SIDE:
            continue
        p = np.asarray(d.step_of(e).values, dtype=float) * catalog_entry(e).si_per_unit
        if e == "time_offset":
            log = restamped(log, -float(p[0]))
        elif e == "lever_arm":
            lever = np.asarray(config.gnss.lever_arm_m, dtype=float) - p
        elif e == "gyro_scale_factor":
            log = with_rates(log, log.imu.w_ib_b_radps / (1.0 + p))
        elif d.step_of(e).shape in ("", "settling"):  # the legs' warm-up (its T)
            log = warmed(log, -p, ACCEL_SETTLING_S)
        done.append(e)
    return log, lever, tuple(done)


NOISE_BAND = 3.0
"""The IMU white noise read from the samples may exceed A's configured angle and velocity
random walk by at most this factor for the families to be fitted: the likelihood is A's, and
A's noise model must hold. Measured (read / configured): 0.2 ARW and 0.0 VRW on the reference
flights, 0.4-0.7 and 0.0-0.8 on the simulated grades; the simulator's MEMS at 100 Hz (6 m/s^2
of vibration) 10 and 125, where the families named accelerometer ramps of 16 000 ug that the
sensor's 60 s means do not show (they wander by 300 ug)."""


def imu_noise_holds(log: Any, config: PipelineConfig) -> bool:
    """Whether the IMU white noise read from the log's samples
    (:attr:`pospp.types.ImuSamples.white_noise`) is within
    :data:`NOISE_BAND` of A's configured ARW and VRW."""
    arw, vrw = log.imu.white_noise
    si = imu_tuning(config).noise()
    return bool(arw <= NOISE_BAND * si.gyro_arw_radpsqrts
                and vrw <= NOISE_BAND * si.accel_vrw_mpspsqrts)


def _column_input(fam: str, knots: np.ndarray, field: Any) -> Any:
    """A family's columns as :data:`pospp.calib.innovation_response.BodyInput`: a sensor
    family's basis functions (:func:`pospp.diagnose.shapes.change_basis`: hinges and steps)
    per body axis x, y (axis-major) on its sensor's rows; the gravity family's terms' specific-
    force change (``field(t, C_nb)``, (T, 3, P))."""
    sensor = sensor_family(fam).sensor

    def body_input(t_s: np.ndarray, c_nb: np.ndarray) -> np.ndarray:
        if sensor == "gravity":
            g = field(t_s, c_nb)
            return np.concatenate([np.zeros_like(g), g], axis=1)
        basis = change_basis(t_s, knots)  # (T, K + S)
        u = np.zeros((t_s.size, 6, 2, basis.shape[1]))
        row = 0 if sensor == "gyro" else 3
        for a in range(2):
            u[:, row + a, a, :] = basis
        return u.reshape(t_s.size, 6, -1)
    return body_input


def _field_input(nav_b: Any, reference: tuple[float, float], extent_m: float) -> Any:
    """``(t_s, C_nb) -> (T, 3, P)``: the specific-force change [m/s^2 per SI coefficient] of
    each term of the gravity field's potential along A's track (``nav_b``'s forward solution,
    interpolated to ``t_s``): ``-C_bn dg_n``, dg_h the term's gradient at A's position north
    and east of ``reference`` (lat, lon [rad]) in units of ``extent_m``
    (:mod:`pospp.diagnose.effects`, the ``field`` shape)."""
    sol = nav_b.forward

    def field(t_s: np.ndarray, c_nb: np.ndarray) -> np.ndarray:
        lat = np.interp(t_s, sol.t_s, sol.lat_rad)
        lon = np.interp(t_s, sol.t_s, sol.lon_rad)
        ne = north_east_m(lat, lon, *reference, 0.0)
        grad = field_gradient(ne[:, 0] / extent_m, ne[:, 1] / extent_m)  # (T, 2, P)
        return -np.einsum("kji,kjp->kip", c_nb[:, 0:2, :], grad)
    return field


def north_east_m(lat_rad: Any, lon_rad: Any, lat0_rad: float, lon0_rad: float,
                 height_m: float) -> np.ndarray:
    """North and east of (lat0, lon0) [m] (WGS-84 radii there), (N, 2)."""
    r_m, r_n = earth.principal_radii_m(lat0_rad)
    lat, lon = np.atleast_1d(lat_rad), np.atleast_1d(lon_rad)
    return np.stack([(lat - lat0_rad) * (r_m + height_m),
                     (lon - lon0_rad) * (r_n + height_m) * np.cos(lat0_rad)], axis=1)


def innovation_design(log: mcap_reader.FlightLog, config: PipelineConfig,
                      families: Sequence[str], *, lever_b_m: Any = None,
                      reference: tuple[float, float] | None = None,
                      base: Any = None, threads: int = 1) -> InnovationDesign:
    """A's whitened innovations on ``log`` and their responses to each family's coefficients
    (module docstring); the gravity family's only with ``reference`` (lat, lon [rad]: the
    field's origin, the legs' mean start), its extent the farthest point of A's track after
    its alignment (at least 1 km). ``base``: A as configured on ``log`` with its gains
    recorded (the run's own pass, :class:`pospp.nav.filter.FilterResult`); None: A is run on
    the log summed down to ``[pairs] rerun_imu_rate_hz``. ``threads``: the families' passes
    over each stretch of A's pass made at once (:meth:`pospp.calib.innovation_response.
    ResponseSystem.blocks`; the result does not depend on it). Raises ValueError when A
    fails."""
    opts = replace(config.filter_options(), smoother=False, covariance_outputs=False)
    if base is None:
        log = summed_down(log, config)
        base = navigate(log, config, options=opts, lever_arm_b_m=lever_b_m, record_gains=True)
    gains, rec = base.gain_replay, base.innovations
    if gains is None or rec is None:
        raise ValueError("A recorded no gains")
    nu0 = rec.dz_ned
    t_from = float(base.alignment.t_s)  # before it the horizontal bias is A's tilt
    used = (gains.status == STATUS_USED) & (rec.status == STATUS_USED) & \
        np.all(np.isfinite(nu0), axis=1) & (rec.t_s >= t_from)
    chol = np.linalg.cholesky(gains.s_inv[used])  # S^-1 = L L^T: L^T nu is white
    t_run = t_s_from_time_ns(log.imu.time_ns, int(log.imu.time_ns[0]))
    knots = knots_s(t_from, float(t_run[-1]))
    extent = float("nan")
    fams = [f for f in families if reference is not None or sensor_family(f).sensor != "gravity"]
    field = None
    if reference is not None and any(sensor_family(f).sensor == "gravity" for f in fams):
        sol = base.forward
        after = sol.t_s >= base.alignment.t_s
        ne = north_east_m(sol.lat_rad[after], sol.lon_rad[after], *reference, 0.0)
        extent = max(1000.0, float(np.max(np.hypot(ne[:, 0], ne[:, 1]))))
        field = _field_input(base, reference, extent)
    # where a column is not smooth (a step on a knot is one break)
    breaks = np.unique(np.round(np.concatenate([knots, step_times_s(knots)]), 6))
    system = ResponseSystem.of(gains, base.forward.trajectory, t_run, log.imu.w_ib_b_radps,
                               log.imu.f_ib_b_mps2, breaks_s=breaks)
    window = static_alignment_window(base, opts)
    rows = np.flatnonzero(used)
    white_y = np.einsum("kji,kj->ki", chol, nu0[used]).reshape(-1)
    inputs = [_column_input(f, knots, field) for f in fams]
    widths = [np.shape(u(t_run[:1], np.eye(3)[None]))[2] for u in inputs]
    sums = DesignSums(white_y, {f: (m // _family_axes(f), _family_axes(f))
                                for f, m in zip(fams, widths, strict=True)},
                      knots, float(t_run[-1]), extent)
    # the families' passes a stretch at a time, one per thread, each stretch's records
    # whitened and summed into the Gram matrix (the responses are never held whole)
    for row, dnu in system.blocks(inputs, static_window_s=window, threads=threads):
        lo, hi = np.searchsorted(rows, [row, row + dnu.shape[0]])
        white = np.einsum("kji,kjm->kim", chol[lo:hi], dnu[rows[lo:hi] - row])
        sums.add(3 * lo, white.reshape(-1, white.shape[2]))
    # a GNSS time offset changes only what the records say: A's response to its record
    # errors through the same gains (pospp.diagnose.linear_signatures)
    lever = config.gnss.lever_arm_m if lever_b_m is None else lever_b_m
    v = gnss_record_errors("time_offset", base.forward.trajectory, rec.t_s, gains.meas_kind,
                           lever)
    dnu = system.responses(_no_input, record_v=v)
    offset = np.einsum("kji,kj->ki", chol, dnu[used, :, 0]).reshape(-1)
    return sums.design(rec.t_s[used], offset)


def _family_axes(fam: str) -> int:
    """A family's axes: the gravity field's one column per term, a sensor's x and y."""
    return 1 if sensor_family(fam).sensor == "gravity" else len(AXES)


def _no_input(t_s: np.ndarray, c_nb: np.ndarray) -> np.ndarray:
    """One column that changes no IMU sample (a GNSS-side column's)."""
    return np.zeros((np.size(t_s), 6, 1))


TIME_OFFSET_FLOOR_S = 5e-3
"""A GNSS time offset A's innovations read is removed before the families are fitted when
it is beyond this and :data:`TIME_OFFSET_SIGMAS` ... (the sample flight, without an offset,
reads 1.5 +- 0.3 ms: its innovations' offset column is not a column of the families' fit,
where with an accelerometer ramp it explained what neither does alone, 297 +- 71 ug/h, p
0.005)."""
TIME_OFFSET_SIGMAS = 5.0
"""... of its sigma (the least squares', times the residual's long-run variance ratio)."""
TIME_OFFSET_WINDOW_S = 60.0
"""The window of the long-run variance ratio that widens the offset's sigma [s] (the offset's
response lives in the turns, a minute or so each)."""
TIME_OFFSET_ITERATIONS = 4
"""At most this many removals: where A gated records an offset spoils in turns its
innovations read part of the offset, and each pass on the log with the last reading removed
reads the rest (flight_time_offset_200hz reads 15.6 of its 15 ms at the first)."""


def _offset_reading(design: InnovationDesign) -> tuple[float, float, bool]:
    """(c [s], sigma [s], significant): the least-squares coefficient of the design's
    time-offset column on its innovations (the GNSS stamped c s earlier than the log's) and
    its sigma (widened by the residual's long-run variance ratio):
    :func:`_offset_significant`."""
    x = design.time_offset_response
    assert x is not None
    xtx = float(x @ x)
    c = float(x @ design.y) / xtx
    r = design.y - c * x
    ratio = long_run_ratio(r, design.record_t_s, TIME_OFFSET_WINDOW_S)
    sigma = float(np.sqrt(ratio * (r @ r) / max(r.size - 1, 1) / xtx))
    return c, sigma, _offset_significant(c, sigma)


def _offset_significant(offset_s: float, sigma_s: float) -> bool:
    """An offset [s] beyond :data:`TIME_OFFSET_FLOOR_S` and :data:`TIME_OFFSET_SIGMAS` of its
    sigma [s]."""
    return abs(offset_s) > TIME_OFFSET_FLOOR_S and abs(offset_s) > TIME_OFFSET_SIGMAS * sigma_s


def _without_time_offset(log: Any, config: PipelineConfig, families: Sequence[str],
                         lever: Any, reference: tuple[float, float] | None,
                         joint: Callable[[], LeverTime | None] | None = None,
                         base: Any = None, threads: int = 1
                         ) -> tuple[InnovationDesign, Any, float]:
    """(design, log, offset [s]): the design on ``log`` with the GNSS time offset its
    innovations read removed (GNSS stamps minus true time; 0 when none is significant,
    :data:`TIME_OFFSET_FLOOR_S`). Left in, a 15 ms offset was named as a 143-223 ug
    accelerometer step (flight_time_offset_200hz with the drift configured, where the legs
    do not name the offset); removed, nothing.

    When the innovations read one, the offset removed is the joint estimate's
    (``joint()``, :func:`pospp.lever_time_stage.lever_time_estimate`, the one the QC stage
    reads; nothing when it determines the offset and finds none beyond five of its sigmas
    and the floor). Without it, or where it cannot determine the offset, the innovations'
    own reading is removed, by at most :data:`TIME_OFFSET_ITERATIONS` passes. ``base``: A
    on ``log`` as :func:`innovation_design` takes it (the first design's; a restamped log's
    are A's passes on it). ``threads``: as :func:`innovation_design`'s."""
    def design_on(log: Any, base: Any = None) -> InnovationDesign:
        return innovation_design(log, config, families, lever_b_m=lever, reference=reference,
                                 base=base, threads=threads)

    total = 0.0
    design = design_on(log, base)
    for k in range(TIME_OFFSET_ITERATIONS):
        c, _, significant = _offset_reading(design)
        if not significant:
            break
        lt = joint() if k == 0 and joint is not None else None
        if lt is not None and np.isfinite(lt.sigma_tau_s):
            if not _offset_significant(lt.tau_s, lt.sigma_tau_s):
                break
            del design
            log = restamped(log, lt.tau_s)
            return design_on(log), log, lt.tau_s
        log = restamped(log, -c)  # the column is GNSS stamped 1 s earlier: c late
        total += c
        del design  # not held while the next one is made
        design = design_on(log)
    return design, log, -total


@dataclass(frozen=True)
class SensorFamilies:
    """The families named on A's innovations, and what B carries of each."""

    families: tuple[str, ...]
    """The families fitted (those the legs did not name)."""
    named: tuple[FamilyFinding, ...]
    tested: tuple[FamilyFinding, ...]
    knots: np.ndarray
    responses: dict[str, EffectResponse]
    """Per named family, what it does to B minus A (per shape coefficient, legs in id
    order)."""
    removed: tuple[str, ...]
    """The named GNSS-side effects taken off the log before the fit."""
    lrv_ratio: float
    """The long-run variance ratio of A's whitened innovations after every family's most
    flexible shape (:func:`pospp.distributions.long_run_ratio`), which divides
    every F."""
    holds: bool
    """Whether A's model holds for the families' likelihood: the IMU's white noise within
    :data:`NOISE_BAND` of A's and its innovations' variance what its S says there
    (:data:`pospp.diagnose.sensor_families.SCALE_BAND`); else nothing is named and the
    families are the diagnosis's ``not_evaluated``."""


def sensor_families(d: Diagnosis, replays: list, log: mcap_reader.FlightLog,
                    config: PipelineConfig, solution_a: SolutionA | None = None,
                    joint: Callable[[], LeverTime | None] | None = None,
                    nav: Any = None, threads: int = 1) -> SensorFamilies | None:
    """Fit the families on A's innovations of ``log`` with ``d``'s named GNSS-side effects
    removed; families ``d`` named on the legs are not fitted again, the gravity field only
    with A's solution (its origin: the legs' mean start). None when no family is left;
    nothing named (the families ``not_evaluated``, ``holds`` False) where A's model does not
    hold (:func:`imu_noise_holds`, the innovations' scale) or A fails on the log with the
    named effects removed. ``joint``: the joint lever-arm / time-offset estimate, made when
    first asked (:func:`_without_time_offset`; the legs' named offset, when they name one,
    is removed instead). ``nav``: the run's A on ``log`` (its gains recorded), whose
    innovations the families read where nothing is removed from the log. ``threads``: the
    families' passes made at once (:func:`innovation_design`)."""
    families = [f.effect_id for f in SENSOR_FAMILIES if f.effect_id not in d.named
                and (solution_a is not None or sensor_family(f.effect_id).sensor != "gravity")]
    if not families:
        return None
    if not imu_noise_holds(log, config):
        return SensorFamilies(tuple(families), (), (), np.zeros(0), {}, (), float("nan"),
                              False)
    log_s, lever, removed = _removed(log, config, d)
    ref = _legs_reference(replays, solution_a)
    try:
        own = nav if not removed and getattr(nav, "gain_replay", None) is not None else None
        design, log_s, offset_s = _without_time_offset(
            log_s, config, families, lever, ref,
            None if "time_offset" in removed else joint, own, threads)
    except (ValueError, np.linalg.LinAlgError):  # A failed on the log with the effects removed
        return SensorFamilies(tuple(families), (), (), np.zeros(0), {}, removed, float("nan"),
                              False)
    if offset_s:
        removed = (*removed, f"the GNSS time offset {1e3 * offset_s:+.1f} ms (GNSS stamps "
                   "minus true time)")
    named, tested, ratio, holds = fit_sensor_families(
        design, families, {f: catalog_entry(f).shapes for f in families},
        config.pairs.diagnose_alpha)
    resp = {f.effect: family_response(f, design, replays, solution_a, ref) for f in named}
    return SensorFamilies(tuple(families), tuple(named), tuple(tested), design.knots, resp,
                          removed, ratio, holds)


def _legs_reference(replays: list, solution_a: SolutionA | None
                    ) -> tuple[float, float] | None:
    """(lat, lon) [rad] of the legs' mean start on A's solution (the gravity field's origin,
    as :func:`pospp.diagnose._candidates.leg_origins` takes it), or None."""
    if solution_a is None:
        return None
    tr = solution_a.trajectory
    return (float(np.mean([np.interp(r.t0_s, tr.t_s, tr.lat_rad) for r in replays])),
            float(np.mean([np.interp(r.t0_s, tr.t_s, tr.lon_rad) for r in replays])))


def family_response(f: FamilyFinding, design: InnovationDesign, replays: list,
                    solution_a: SolutionA | None = None,
                    reference: tuple[float, float] | None = None) -> EffectResponse:
    """A named family's response on B minus A per coefficient, its fitted coefficients and
    their covariance: a sensor change's per shape coefficient (axis-major: x's q, then y's);
    the gravity field's per potential term (the legs' starts on A's solution, north and east
    of ``reference``, over the design's extent)."""
    if sensor_family(f.effect).sensor == "gravity":
        assert solution_a is not None and reference is not None
        tr = solution_a.trajectory
        columns = tuple(signature(
            "gravity_disturbance", r, shape="field", extent_m=design.field_extent_m,
            origin_n_m=north_east_m(np.interp(r.t0_s, tr.t_s, tr.lat_rad),
                                    np.interp(r.t0_s, tr.t_s, tr.lon_rad), *reference, 0.0)[0])
            for r in replays)
        return EffectResponse(f.effect, columns, f.basis_si[:, 0], f.basis_cov_si)
    cols = []
    for axis in range(2):  # axis-major, as the shape's coefficients
        for w in f.weights.T:
            basis = np.zeros((w.size, 2))
            basis[:, axis] = w
            cols.append(response_along_b(f, design.knots, replays, basis_si=basis))
    columns = tuple(np.stack([c[i] for c in cols], axis=-1) for i in range(len(replays)))
    return EffectResponse(f.effect, columns, f.coefficients_si, f.coefficients_cov_si)


def _step(f: FamilyFinding, number: int, worth: Any, closing: DiagnosisStep,
          removed: tuple[str, ...]) -> DiagnosisStep:
    note = f"fitted with {', '.join(removed)} removed" if removed else ""
    if note and f.shape_parameters:
        note = "; " + note
    return DiagnosisStep(
        step=number, effect=f.effect, parameters=f.parameters, values=f.values,
        sigmas=f.sigmas, value=f.value, sigma=f.sigma, unit=f.unit, statistic=f.statistic,
        p_value=f.p_value, criterion=CRITERION, significant=True, delta_bic=f.delta_bic,
        explained_fraction=f.explained_fraction, confounded_with=(),
        gap_before_mps=closing.gap_before_mps, gap_after_mps=closing.gap_after_mps,
        heldout_gap_before_mps=closing.heldout_gap_before_mps,
        heldout_gap_after_mps=closing.heldout_gap_after_mps,
        horizon_s=closing.horizon_s, gap_horizon_mps=worth.dv_mps, gap_horizon_m=worth.dr_m,
        residual_horizon_mps=closing.residual_horizon_mps,
        residual_horizon_m=closing.residual_horizon_m, shape=f.shape,
        shape_parameters=f.shape_parameters + note)


def with_sensor_families(d: Diagnosis, fams: SensorFamilies | None) -> Diagnosis:
    """``d`` with the named families as steps before its closing row (the closing row
    renumbered) and every family tested among its candidates."""
    if fams is None:
        return d
    closing = d.steps[-1]
    named = list(d.steps[:-1])
    t_legs = d.t_s
    ids = [g.leg_id for g in d.legs]
    for f in fams.named:
        curves = [r[1:] for r in fams.responses[f.effect].curves()]
        named.append(_step(f, len(named) + 1, horizon_worth(t_legs, curves, ids), closing,
                           fams.removed))
    left = () if fams.holds else fams.families
    tests = tuple(CandidateTest(len(d.steps[:-1]) + 1, f.effect, f.values.size, f.value,
                                f.sigma, f.unit, f.statistic, f.p_value, f.delta_bic,
                                f.explained_fraction, float("nan"), float("nan"),
                                f.significant, values=f.values, shape=f.shape)
                  for f in fams.tested)
    return replace(d, steps=(*named, replace(closing, step=len(named) + 1)),
                   candidates=d.candidates + tests,
                   not_evaluated=d.not_evaluated + left)
