"""The QC stage: every check of :mod:`pospp.qc.checks` on one run's stage results.

Takes the frozen results of ingest (``FlightLog``), algorithm A (``FilterResult``), the
calibration stage (``CalibrationRun``) and the configuration, and returns a frozen
:class:`QualityReport` (no I/O). The pipeline writes it as qc.parquet (:func:`qc_columns`)
and derives the run status from it (docs/qc.md).

Frames and units as in :mod:`pospp.qc.checks`: body FRD, NED, SI inside; t_s from the run
epoch (the first IMU stamp).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from pospp import earth, rotation
from pospp.nav.aiding import aiding_of
from pospp.nav.alignment import static_windows
from pospp.nav.filter import STATUS_GATED, STATUS_RESET, STATUS_USED
from pospp.qc import checks as qc
from pospp.qc import mounting, time_offset
from pospp.qc.check_record import STATUS_ORDER, Check, run_status, skip
from pospp.qc.coverage import gnss_coverage
from pospp.units import t_s_from_time_ns

if TYPE_CHECKING:
    from pospp.io.mcap_reader import FlightLog
    from pospp.nav.filter import FilterResult, LeverArmEstimate
    from pospp.nav.solution import NavSolution
    from pospp.qc.lever_time import LeverTime


@dataclass(frozen=True)
class QualityReport:
    """The checks of one run and the status they give."""

    checks: tuple[Check, ...]

    @property
    def status(self) -> str:
        """Worst severity among the failed checks ("ok" when all passed)."""
        return run_status(self.checks)

    @property
    def failed(self) -> tuple[Check, ...]:
        return tuple(c for c in self.checks if not c.passed)

    @property
    def failed_names(self) -> str:
        """Comma-joined names of the failed checks (summary ``qc_failed_checks``)."""
        return ",".join(c.name for c in self.failed)

    @property
    def suggestions(self) -> str:
        """'; '-joined suggestions of the failed checks (summary ``qc_suggestions``)."""
        return "; ".join(f"{c.name}: {c.suggestion}" for c in self.failed if c.suggestion)


def worst_status(*statuses: str) -> str:
    """The worst of run statuses ("ok" < "partial" < "degraded" < "failed")."""
    return STATUS_ORDER[max(STATUS_ORDER.index(s) for s in statuses)]


def config_problems(config: Any) -> list[str]:
    """Values of a :class:`pospp.config.PipelineConfig` that make no sense (key named): every
    key outside its physical range (``PipelineConfig.problems``: what the loader refuses, for
    a configuration made in Python), and a lever arm longer than 100 m."""
    out = list(config.problems())
    lever = np.asarray(config.gnss.lever_arm_m, dtype=float)
    if not np.isfinite(lever).all() or float(np.linalg.norm(lever)) > 100.0:
        out.append(f"[gnss] lever_arm_m = {list(config.gnss.lever_arm_m)} m is not an antenna "
                   "lever arm (|l| > 100 m)")
    return out


def _static_mask(t: NDArray, w: NDArray, f: NDArray, vel_t: NDArray, vel: NDArray,
                 vel_cov: NDArray) -> NDArray:
    has = len(vel_t) > 0
    ends, is_static = static_windows(t, w, f, gnss_vel_t_s=vel_t if has else None,
                                     gnss_v_n_mps=vel if has else None,
                                     gnss_vel_cov_ned_m2ps2=vel_cov if has else None)
    # windows are consecutive runs of samples, window j ending at ends[j]; samples after the
    # last whole window belong to none
    j = np.searchsorted(ends, t, side="left")
    inside = j < ends.shape[0]
    mask = np.zeros(t.shape[0], dtype=bool)
    mask[inside] = is_static[j[inside]]
    return mask


def _down_rate(t: NDArray, w: NDArray, sol: NavSolution) -> NDArray:
    """Rotation rate of the body w.r.t. NED about the down axis at the IMU epochs [rad/s].

    w_d = (C_nb w_ib_b)_D + Omega sin L (the Earth rate's down component removed; the
    transport rate, ~1 deg/h at 60 m/s, is left: it is a constant to the offset fit). C_nb
    row 3 from A's solution, interpolated to the IMU epochs.
    """
    c3 = rotation.dcm_from_quat(sol.q_nb)[:, 2, :]
    ts = np.asarray(sol.t_s, dtype=float)
    row = np.column_stack([np.interp(t, ts, c3[:, a]) for a in range(3)])
    lat = np.interp(t, ts, sol.lat_rad)
    return np.einsum("ij,ij->i", row, w) + earth.EARTH_RATE_RADPS * np.sin(lat)


def _lever_velocity(t: NDArray, w: NDArray, sol: NavSolution, vel_t: NDArray,
                    lever_b_m: Any) -> NDArray:
    """The configured lever arm's share of the antenna velocity at the GNSS velocity times,
    ``C_nb (w_ib_b x l)`` [m/s NED] (the Earth rate's share, below 1 mm/s for a few metres,
    left out): subtracted, the course is the IMU's, which turns with its yaw rate alone."""
    lever = np.asarray(lever_b_m, dtype=float)
    if vel_t.shape[0] == 0 or not np.any(lever):
        return np.zeros((vel_t.shape[0], 3))
    ts = np.asarray(sol.t_s, dtype=float)
    c = rotation.dcm_from_quat(sol.q_nb)
    c_at = np.stack([[np.interp(vel_t, ts, c[:, i, j]) for j in range(3)] for i in range(3)])
    w_at = np.stack([np.interp(vel_t, t, w[:, a]) for a in range(3)], axis=1)
    wl = np.cross(w_at, lever)
    return np.einsum("ijn,nj->ni", c_at, wl)


def _offset_and_lever(q: QcInputs, _: list[Check]) -> list[Check]:
    """The ``gnss_time_offset`` and ``lever_arm`` checks: the turns' offset (seconds measured
    again, :func:`_offset_again`) and A's lever-arm estimate, each alone; when either fails
    below ``TIME_OFFSET_MAX_S``, both from the joint estimate."""
    t, w, sol, v_t, v_n, config = q.t_s, q.log.imu.w_ib_b_radps, q.sol, q.v_t_s, q.v_n_mps, q.config
    joint, renavigate, lev = q.joint, q.renavigate, q.lever
    out: list[Check] = []
    v_imu = v_n - _lever_velocity(t, w, sol, v_t, config.gnss.lever_arm_m)
    est = time_offset.estimate_time_offset(t, _down_rate(t, w, sol), v_t, v_imu)
    if est is not None and abs(est.offset_s) >= time_offset.TIME_OFFSET_MAX_S and renavigate:
        est = _offset_again(t, w, v_t, v_n, config.gnss.lever_arm_m, est, renavigate)
    speed = np.hypot(sol.v_n_mps[:, 0], sol.v_n_mps[:, 1])
    moving = speed > time_offset.TIME_OFFSET_MIN_SPEED_MPS
    obs = qc.lever_arm_observable(sol.rpy_rad)
    mean_speed = float(speed[moving].mean()) if moving.any() else math.nan
    first = [time_offset.gnss_time_offset(est)]
    if lev is not None:
        first.append(qc.lever_arm(config.gnss.lever_arm_m, lev.lever_b_m, lev.sigma_b_m,
                                  observable=obs, mean_speed_mps=mean_speed))
    small = est is None or abs(est.offset_s) < time_offset.TIME_OFFSET_MAX_S
    need = small and joint is not None and not all(c.passed for c in first)
    lt = joint() if need and joint is not None else None
    out.append(time_offset.gnss_time_offset(est, lt) if lt is not None else first[0])
    if lev is None:
        out.append(skip("lever_arm", "navigate", "no lever-arm estimate", "m",
                        qc.LEVER_ARM_MAX_M))
    else:
        out.append(first[1] if lt is None else qc.lever_arm(
            config.gnss.lever_arm_m, lev.lever_b_m, lev.sigma_b_m, observable=obs,
            mean_speed_mps=mean_speed, joint=lt))
    toff, lev_check = out[-2], out[-1]
    if lt is None and not toff.passed and not lev_check.passed:
        # a late GNSS bends the lever-arm estimate
        out[-1] = replace(lev_check, suggestion="fix the GNSS time offset first, the lever-arm "
                          "estimate is not reliable until then; " + lev_check.suggestion)
    return out


def _offset_again(t: NDArray, w: NDArray, v_t: NDArray, v_n: NDArray, lever_b_m: Any,
                  est: time_offset.TimeOffsetEstimate,
                  renavigate: Callable[[float], FilterResult]
                  ) -> time_offset.TimeOffsetEstimate:
    """An offset of seconds measured again: A, fed GNSS records seconds away from their
    true time, banks and pitches wrongly in the turns, and the vertical rate projected with
    that attitude biases the offset (the sample flight with its GNSS 18 s late read 18.59 +-
    0.01 s, 37 s early 36.32 +- 0.02 s). A is re-run with the GNSS re-stamped by the first
    estimate (to 0.01 s) and the rest measured within +-2 s, again from there while the rest
    exceeds :data:`OFFSET_AGAIN_DONE_S`, the lever arm's share of the
    antenna velocity (:func:`_lever_velocity`) taken at the re-stamped times (at the stamps,
    a 2 s offset read 1.91 s: the lever arm's velocity in the roll-in at the wrong time); the
    estimate is the sum, with the second's sigma (the first unchanged when that run fails).
    """
    for _ in range(OFFSET_AGAIN_RUNS):
        shift = round(est.offset_s, 2)
        try:
            nav2 = renavigate(shift)
        except ValueError:
            return est
        sol2 = nav2.smoothed if nav2.smoothed is not None else nav2.forward
        v_imu = v_n - _lever_velocity(t, w, sol2, v_t - shift, lever_b_m)
        rest = time_offset.estimate_time_offset(t, _down_rate(t, w, sol2), v_t - shift,
                                                v_imu, search_s=2.0)
        if rest is None:
            return est
        est = replace(rest, offset_s=shift + rest.offset_s)
        if abs(rest.offset_s) < OFFSET_AGAIN_DONE_S:
            break
    return est


OFFSET_AGAIN_RUNS = 3
""":func:`_offset_again` re-runs A at most this many times, each at the last estimate."""
OFFSET_AGAIN_DONE_S = 0.05
"""... until the rest it measures is below this [s] (A then ran near the right offset)."""


def _gnss_processed(rec: Any) -> NDArray:
    """The position and velocity records A processed after its start (used, gated, or used
    after a covariance reset) in the filter's ``InnovationRecord``."""
    return (rec.kind <= 1) & np.isin(rec.status, (STATUS_USED, STATUS_GATED, STATUS_RESET))


def gate_check(rec: Any, gate_probability: float) -> Check:
    """:func:`pospp.qc.checks.gnss_gate` on A's innovation record: the GNSS records it gated,
    or used only after a covariance reset, against what its gate allows (the diagnosis's
    :func:`pospp.diagnose.rerun.gate_excess` asks the same)."""
    gnss = _gnss_processed(rec)
    rejected = gnss & ((rec.status == STATUS_GATED) | (rec.status == STATUS_RESET))
    return qc.gnss_gate(int(np.count_nonzero(gnss)), int(np.count_nonzero(rejected)),
                        gate_probability,
                        float(rec.t_s[rejected][0]) if rejected.any() else None)


def _innovation_checks(rec: Any, gate_probability: float) -> list[Check]:
    """The GNSS innovations' NIS band and A's gated records (``rec``: the filter's
    ``InnovationRecord``; position and velocity records processed after the start)."""
    gnss = _gnss_processed(rec)
    return [qc.nis_band(rec.t_s[gnss], rec.nis[gnss]), gate_check(rec, gate_probability)]


@dataclass(frozen=True)
class QcInputs:
    """What the checks read: a run's stage results and the series derived from them once.

    Times from the run epoch (the first IMU stamp) [s]; IMU in body FRD (rad/s, m/s^2); GNSS
    velocities ``v_n_mps`` at ``v_t_s`` in NED (the track's own differences at its midpoints
    when the log has no velocity topic); ``r_n_m`` the fixes in NED about the first one;
    ``static`` the IMU samples at rest; ``lat0_rad``, ``h0_m`` the first fix's (A's alignment's
    without one); ``dt_s`` the median IMU interval."""

    log: FlightLog
    nav: FilterResult
    calib_run: Any
    config: Any
    c_bs: NDArray
    lever_estimate: LeverArmEstimate | None
    joint: Callable[[], LeverTime | None] | None
    renavigate: Callable[[float], FilterResult] | None
    t_s: NDArray
    fix_t_s: NDArray
    vel_t_s: NDArray
    static: NDArray
    lat0_rad: float
    h0_m: float
    dt_s: float
    sol: NavSolution
    r_n_m: NDArray
    v_t_s: NDArray
    v_n_mps: NDArray

    @property
    def lever(self) -> LeverArmEstimate | None:
        """A's lever-arm estimate the checks use: the re-run's, else A's own when it
        estimated one, else None."""
        if self.lever_estimate is not None:
            return self.lever_estimate
        return self.nav.lever_arm if self.nav.lever_arm.estimated else None


def qc_inputs(log: FlightLog, nav: FilterResult, calib_run: Any, config: Any, *,
              c_bs: NDArray, lever_estimate: LeverArmEstimate | None = None,
              joint: Callable[[], LeverTime | None] | None = None,
              renavigate: Callable[[float], FilterResult] | None = None) -> QcInputs:
    """:class:`QcInputs` of a run (arguments as :func:`quality_checks`)."""
    imu = log.imu
    epoch_ns = int(imu.time_ns[0])
    t = t_s_from_time_ns(imu.time_ns, epoch_ns)
    vel_t = t_s_from_time_ns(log.vel.time_ns, epoch_ns)
    fix_t = t_s_from_time_ns(log.fix.time_ns, epoch_ns)
    static = _static_mask(t, imu.w_ib_b_radps, imu.f_ib_b_mps2, vel_t, log.vel.v_n_mps,
                          log.vel.vel_cov_ned_m2ps2)
    lat0 = float(log.fix.lat_rad[0]) if len(log.fix.time_ns) else nav.alignment.lat_rad
    h0 = float(log.fix.height_m[0]) if len(log.fix.time_ns) else nav.alignment.height_m
    dt = float(np.median(np.diff(t))) if t.shape[0] > 1 else 0.0
    r_n = earth.llh_to_ned_m(log.fix.lat_rad, log.fix.lon_rad, log.fix.height_m,
                             lat0, float(log.fix.lon_rad[0]) if len(fix_t) else 0.0, h0)
    if len(vel_t) >= 2:
        v_t, v_n = vel_t, log.vel.v_n_mps
    elif len(fix_t) >= 3:  # no velocity topic: the track's own differences, at the midpoints
        v_t = 0.5 * (fix_t[1:] + fix_t[:-1])
        v_n = np.diff(r_n, axis=0) / np.diff(fix_t)[:, None]
    else:
        v_t, v_n = np.zeros(0), np.zeros((0, 3))
    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    return QcInputs(log, nav, calib_run, config, c_bs, lever_estimate, joint, renavigate, t,
                    fix_t, vel_t, static, lat0, h0, dt, sol, r_n, v_t, v_n)


def _config_sanity(q: QcInputs, _: list[Check]) -> list[Check]:
    return [qc.config_sanity(config_problems(q.config))]


def _data_complete(q: QcInputs, _: list[Check]) -> list[Check]:
    errors = [i for i in q.log.issues if i.severity == "error"]
    cin = q.config.input
    window = None if cin.end_s is None else cin.end_s - (cin.start_s or 0.0)
    return [qc.data_complete(bool(q.log.complete), len(errors),
                             errors[0].message if errors else "",
                             float(q.t_s[-1] - q.t_s[0]) if q.t_s.shape[0] else 0.0, window)]


def _gravity(q: QcInputs, _: list[Check]) -> list[Check]:
    f = q.log.imu.f_ib_b_mps2
    return [qc.gravity_direction(f, q.static, q.c_bs, q.config.input.sensor_frame),
            qc.gravity_magnitude(f, q.static, q.lat0_rad, q.h0_m,
                                 window_n=int(round(1.0 / q.dt_s)) if q.dt_s > 0 else 1)]


def _earth_rate(q: QcInputs, _: list[Check]) -> list[Check]:
    noise = q.config.imu.tuning().noise()
    sb = math.hypot(noise.gyro_turn_on_sigma_radps, noise.gyro_gm_sigma_radps) \
        or noise.gyro_bias_sigma_radps
    return [qc.earth_rate(q.log.imu.w_ib_b_radps, q.log.imu.f_ib_b_mps2, q.static, q.dt_s,
                          q.lat0_rad, gyro_bias_sigma_radps=sb,
                          gyro_arw_radpsqrts=noise.gyro_arw_radpsqrts)]


def _gnss_jumps(q: QcInputs, _: list[Check]) -> list[Check]:
    vel = (q.vel_t_s, q.log.vel.v_n_mps) if len(q.vel_t_s) >= 2 else \
        (q.nav.forward.t_s, q.nav.forward.v_n_mps)
    return [qc.gnss_jumps(q.fix_t_s, q.r_n_m, *vel)]


def _innovations(q: QcInputs, _: list[Check]) -> list[Check]:
    rec = getattr(q.nav, "innovations", None)
    return [] if rec is None else _innovation_checks(
        rec, q.config.filter_options().gate_probability)


def _mounting_yaw(q: QcInputs, so_far: list[Check]) -> list[Check]:
    """``mounting_yaw`` (A's heading against the GNSS course); the ``lever_arm`` check again,
    naming the mounting when its estimate is the configured lever arm rotated."""
    head = mounting.heading_offset(q.v_t_s, q.v_n_mps, q.sol.t_s, q.sol.q_nb)
    mount = mounting.mounting_yaw(head, q.config.input.mounting_rpy_deg)
    lev = q.lever
    if lev is None:
        return [mount]
    lever_check = next(c for c in so_far if c.name == "lever_arm")
    return [mounting.lever_arm_naming_mounting(
        lever_check, q.config.gnss.lever_arm_m, lev.lever_b_m, lev.sigma_b_m,
        qc.lever_arm_observable(q.sol.rpy_rad), mount,
        None if head is None else head.offset_rad), mount]


def _coverage(q: QcInputs, _: list[Check]) -> list[Check]:
    run = q.calib_run
    legs = [] if run is None else [(g.leg_id, g.start_s, g.end_s) for g in run.legs]
    return [gnss_coverage(aiding_of(q.nav), legs, getattr(run, "leg_refusals", None))]


def _calibration(q: QcInputs, _: list[Check]) -> list[Check]:
    run = q.calib_run
    if run is None:
        return []
    s = run.summary()
    return [qc.calibration_quality(run.calibrated, run.reason, int(s["n_pairs_used"])),
            qc.compensation_gain(float(s["dv_before_mps"]), float(s["dv_after_mps"]))]


QC_CHECKS: tuple[tuple[tuple[str, ...], Callable[[QcInputs, list[Check]], list[Check]]], ...] = (
    (("config",), _config_sanity),
    (("data_complete",), _data_complete),
    (("gravity_direction", "gravity_magnitude"), _gravity),
    (("earth_rate",), _earth_rate),
    (("gnss_jumps",), _gnss_jumps),
    (("gnss_nis", "gnss_gate"), _innovations),
    (("gnss_time_offset", "lever_arm"), _offset_and_lever),
    (("lever_arm", "mounting_yaw"), _mounting_yaw),
    (("gnss_coverage",), _coverage),
    (("calibration", "compensation"), _calibration),
)
"""The QC stage's checks in report order: (the names of the checks a row may make, its
function). A row's function takes the inputs and the checks made so far and returns its
checks (a check that does not apply is left out: no innovations, no calibration); one named
like an earlier check replaces it in place (the mounting row re-reads the lever arm). A new check
is a function of :mod:`pospp.qc.checks` (or its own module), a row here, its test and its
entry in docs/qc.md; checks of later stages (the diagnosis's ``model_fit``) are appended by
the pipeline."""


def quality_checks(log: FlightLog, nav: FilterResult, calib_run: Any, config: Any, *,
                   c_bs: NDArray, lever_estimate: LeverArmEstimate | None = None,
                   joint: Callable[[], LeverTime | None] | None = None,
                   renavigate: Callable[[float], FilterResult] | None = None
                   ) -> QualityReport:
    """Run every check of :data:`QC_CHECKS` on a run's results.

    Parameters
    ----------
    log : pospp.io.mcap_reader.FlightLog
        As processed (after the [input] window).
    nav : pospp.nav.filter.FilterResult
        Algorithm A on the log.
    calib_run : pospp.calib.stage.CalibrationRun or None
    config : pospp.config.PipelineConfig
    c_bs : (3, 3) array
        The declared sensor-to-body DCM the log was read with (axes and mounting).
    lever_estimate : pospp.nav.filter.LeverArmEstimate, optional
        The lever arm estimated by a re-run of A with lever-arm states (None: not re-run; the
        check then uses ``nav.lever_arm`` when A estimated it, else is not applicable).
    joint : callable() -> LeverTime or None, optional
        Makes the joint estimate of the lever arm and the GNSS time offset
        (:func:`pospp.flight_stages.lever_time_estimate`); called only when the time-offset
        or the lever-arm check fails on its own estimate (an offset below
        ``TIME_OFFSET_MAX_S``), and then both checks take its reading.
    renavigate : callable(shift_s) -> FilterResult, optional
        A on the log with its GNSS re-stamped ``t - shift_s``
        (:func:`pospp.diagnose.rerun.restamped`): an offset of seconds found by the turns is
        measured again on A's attitude with the GNSS re-stamped by it (:func:`_offset_again`).
    """
    q = qc_inputs(log, nav, calib_run, config, c_bs=c_bs, lever_estimate=lever_estimate,
                  joint=joint, renavigate=renavigate)
    out: list[Check] = []
    for _, make in QC_CHECKS:
        for check in make(q, out):
            at = next((i for i, c in enumerate(out) if c.name == check.name), None)
            if at is None:
                out.append(check)
            else:
                out[at] = check
    return QualityReport(tuple(out))


def qc_columns(report: QualityReport, epoch_ns: int) -> dict[str, list[Any]]:
    """qc.parquet columns (schema ``qc`` in pospp.io.parquet_tables)."""
    cs = report.checks
    return {
        "check": [c.name for c in cs],
        "stage": [c.stage for c in cs],
        "measure": [c.statistic for c in cs],
        "value": [float(c.value) for c in cs],
        "threshold": [float(c.threshold) for c in cs],
        "unit": [c.unit for c in cs],
        "passed": [bool(c.passed) for c in cs],
        "severity": [c.severity for c in cs],
        "suggestion": [c.suggestion for c in cs],
        "time_ns": [None if c.time_ns_offset is None else int(epoch_ns) + c.time_ns_offset
                    for c in cs],
    }
