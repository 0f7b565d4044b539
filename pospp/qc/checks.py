"""Numeric self-checks of one run: arrays in, a frozen :class:`Check` out (no I/O).

Frames and units: body FRD (b), navigation NED (n), sensor as logged (s); SI and radians
inside, the reported ``value`` / ``threshold`` in the unit named by ``Check.unit``. Times
``t_s`` are seconds from the run epoch (the first IMU stamp). The record :class:`Check` and
the run status are in :mod:`pospp.qc.check_record`.

Each check states the statistic it computes, the threshold, and (docs/qc.md) its false-alarm
level and the margins measured on clean data. A check that cannot be evaluated on the data
(no static part, no turns, ...) passes with a NaN value and says why in ``statistic``.

``severity`` is the run status a failure imposes: "partial" (a stage produced nothing),
"degraded" (the answer is suspect) or "failed" (the answer is wrong); the run status is the
worst severity among the failed checks (:func:`pospp.qc.check_record.run_status`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth
from pospp.distributions import chi2_ppf, poisson_isf
from pospp.qc.check_record import Check, skip
from pospp.qc.check_record import time_offset_ns as _toff
from pospp.qc.lever_time import LEVER_ARM_FLOOR_M, LeverTime, lever_time_verdict
from pospp.units import DEG_PER_H_RADPS

_DPH = DEG_PER_H_RADPS


# =============================================================================================
# IMU against the physics: gravity and Earth rate
# =============================================================================================
GRAVITY_DIRECTION_MAX_DEG = 45.0
"""Largest angle between the mean specific force and the body's up axis (-z FRD)."""
GRAVITY_MAGNITUDE_STATIC_MAX_MPS2 = 0.2
"""Largest | |mean f| - normal gravity | over static windows [m/s^2] (2 %)."""
GRAVITY_MAGNITUDE_DYNAMIC_MAX_MPS2 = 1.0
"""Same for the median |f| over the whole log when there is no static part [m/s^2]."""


def _axis_name(v: NDArray) -> str:
    i = int(np.argmax(np.abs(v)))
    return ("+" if v[i] > 0 else "-") + "xyz"[i]


def gravity_direction(f_b_mps2: ArrayLike, static: ArrayLike | None, c_bs: ArrayLike,
                      sensor_frame: str) -> Check:
    """Angle between the mean specific force and the body up axis (-z FRD).

    At rest or in steady (unaccelerated or coordinated) flight the specific force is the
    reaction to gravity, f_b ~ [0, 0, -g] for a level body, so the mean of f_b over the static
    windows (or the
    median over the whole log when there are none) points along -z_b within the mean attitude:
    ``angle = arccos(-f_z / |f|)``. An IMU whose axes are declared wrong gives ~180 deg (FLU
    declared FRD or back) or ~90 deg (a mounting rotation missed). The suggestion maps the
    mean back to the sensor axes as logged (f_s = C_bs^T f_b) and names the up axis.

    Parameters
    ----------
    f_b_mps2 : (N, 3) specific force, body FRD, as declared [m/s^2]
    static : (N,) bool or None
        Samples at rest (None or all False: the whole log, by component medians).
    c_bs : (3, 3) the declared sensor-to-body DCM
    sensor_frame : {"flu", "frd"} the declared axis convention
    """
    f = np.asarray(f_b_mps2, dtype=float)
    st = None if static is None else np.asarray(static, dtype=bool)
    if f.shape[0] == 0:
        return skip("gravity_direction", "ingest", "no IMU samples", "deg",
                   GRAVITY_DIRECTION_MAX_DEG)
    where = "static windows"
    if st is not None and st.any():
        fm = f[st].mean(axis=0)
    else:
        fm = np.median(f, axis=0)
        where = "whole log (median)"
    norm = float(np.linalg.norm(fm))
    angle = math.degrees(math.acos(np.clip(-fm[2] / norm, -1.0, 1.0))) if norm > 0 else 180.0
    passed = angle <= GRAVITY_DIRECTION_MAX_DEG
    suggestion = ""
    if not passed:
        f_s = np.asarray(c_bs, dtype=float).T @ fm
        up = _axis_name(f_s)  # at rest f points up: the sensor axis that points up
        if up == "+z" and sensor_frame == "frd":
            suggestion = "the IMU looks FLU, not FRD (its z axis points up): sensor_frame = 'flu'"
        elif up == "-z" and sensor_frame == "flu":
            suggestion = "the IMU looks FRD, not FLU (its z axis points down): " \
                "sensor_frame = 'frd'"
        else:
            suggestion = (f"the sensor's {up} axis points up, not the declared frame's: check "
                          f"[input] sensor_frame ('{sensor_frame}' declared) and "
                          "mounting_rpy_deg")
    return Check("gravity_direction", "ingest",
                 f"angle between the mean specific force ({where}) and body up (-z FRD)",
                 angle, GRAVITY_DIRECTION_MAX_DEG, "deg", passed, "failed", suggestion)


def gravity_magnitude(f_b_mps2: ArrayLike, static: ArrayLike | None, lat_rad: float,
                      height_m: float, *, window_n: int = 1) -> Check:
    """| |mean f_b| - normal gravity(lat, h) | over static windows (else over the whole log).

    Catches accelerations in the wrong unit or scale that slipped past the reader's range
    checks. Threshold 0.2 m/s^2 static (a 20 mg bias, beyond any grade pospp supports), 1 m/s^2
    for a dynamic log (turns raise |f|), where the statistic is the median over consecutive
    blocks of ``window_n`` samples of |block mean of f|: a block of about 1 s averages out
    engine and propeller vibration (zero mean, tens of Hz), whose RMS would otherwise add to
    the norm of every sample (6 m/s^2 per axis on a MEMS airframe lifts the median |f| of the
    samples by several m/s^2).
    """
    f = np.asarray(f_b_mps2, dtype=float)
    if f.shape[0] == 0:
        return skip("gravity_magnitude", "ingest", "no IMU samples", "m/s^2")
    g = float(earth.normal_gravity_mps2(lat_rad, height_m))
    st = None if static is None else np.asarray(static, dtype=bool)
    if st is not None and st.any():
        mag = float(np.linalg.norm(f[st].mean(axis=0)))
        thr, where = GRAVITY_MAGNITUDE_STATIC_MAX_MPS2, "static windows"
    else:
        m = max(1, min(int(window_n), f.shape[0]))
        n = f.shape[0] // m
        blocks = f[: n * m].reshape(n, m, 3).mean(axis=1)
        mag = float(np.median(np.linalg.norm(blocks, axis=1)))
        thr, where = GRAVITY_MAGNITUDE_DYNAMIC_MAX_MPS2, f"median over {m}-sample blocks"
    dev = abs(mag - g)
    passed = dev <= thr
    sug = "" if passed else (f"|f| is {mag:.3f} m/s^2 where gravity is {g:.3f} m/s^2: check the "
                             "accelerometer unit and scale")
    return Check("gravity_magnitude", "ingest",
                 f"| |f| ({where}) - normal gravity |", dev, thr, "m/s^2", passed, "degraded",
                 sug)


EARTH_RATE_SIGMAS = 5.0
"""Threshold of the Earth-rate check in predicted sigmas (bias and ARW over the static time)."""
EARTH_RATE_MIN_STATIC_S = 60.0
EARTH_RATE_MIN_SEGMENT_S = 10.0
"""Static stretches shorter than this are left out (a lull in motion, not a vehicle at rest)."""


def static_segments(static: ArrayLike) -> list[tuple[int, int]]:
    """Contiguous runs of True in a (N,) bool mask as [start, stop) sample index pairs."""
    st = np.asarray(static, dtype=bool)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], st.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def earth_rate(w_b_radps: ArrayLike, f_b_mps2: ArrayLike, static: ArrayLike | None,
               dt_s: float, lat_rad: float, *, gyro_bias_sigma_radps: float,
               gyro_arw_radpsqrts: float) -> Check:
    """Mean gyro output at rest against the Earth rate.

    At rest w_ib_b = C_bn w_ie_n with w_ie_n = Omega [cos L, 0, -sin L] (NED). Heading is not
    known here, so two components are compared: the vertical one (along the measured down
    axis d_b = -f/|f|: w . d_b = -Omega sin L) and the horizontal magnitude (Omega cos L).
    They are formed per contiguous static stretch j of at least EARTH_RATE_MIN_SEGMENT_S
    (each stretch has its own attitude: a 10 min start at one heading and a 5 min stop at
    another must not be averaged as vectors, which shrinks the horizontal part by
    cos(dpsi / 2)), and the signed misfits are averaged with the stretch durations T_j as
    weights: e_d = sum T_j (w_d,j + Omega sin L) / T, e_h = sum T_j (|w_h,j| - Omega cos L) / T.
    Statistic: max(|e_d|, |e_h|) [deg/h]. Each e is a weighted mean of bias projections of
    variance <= sigma_b^2 plus white noise of variance ARW^2 / T, so the threshold is
    EARTH_RATE_SIGMAS sqrt(sigma_b^2 + ARW^2 / T) (sigma_b the grade's turn-on and
    Gauss-Markov bias sigmas combined, T the static time used). Not applicable when less than
    EARTH_RATE_MIN_STATIC_S is at rest or the grade cannot see the Earth rate (threshold above
    half of it).
    """
    st = None if static is None else np.asarray(static, dtype=bool)
    w = np.asarray(w_b_radps, dtype=float)
    f = np.asarray(f_b_mps2, dtype=float)
    min_n = max(1, int(math.ceil(EARTH_RATE_MIN_SEGMENT_S / dt_s))) if dt_s > 0 else 1
    segs = [] if st is None else [(a, b) for a, b in static_segments(st) if b - a >= min_n]
    n_st = sum(b - a for a, b in segs)
    t_static = n_st * dt_s
    if t_static < EARTH_RATE_MIN_STATIC_S:
        return skip("earth_rate", "ingest", f"{t_static:.0f} s at rest in stretches of >= "
                   f"{EARTH_RATE_MIN_SEGMENT_S:.0f} s (< {EARTH_RATE_MIN_STATIC_S:.0f} s)",
                   "deg/h")
    sigma = math.hypot(gyro_bias_sigma_radps, gyro_arw_radpsqrts / math.sqrt(t_static))
    thr = EARTH_RATE_SIGMAS * sigma
    om = earth.EARTH_RATE_RADPS
    if thr > 0.5 * om:
        return skip("earth_rate", "ingest", f"the IMU grade cannot see it ({thr / _DPH:.1f} "
                   f"deg/h threshold, Earth rate {om / _DPH:.1f} deg/h)", "deg/h", thr / _DPH)
    wd_h = np.zeros((len(segs), 2))
    for j, (a, b) in enumerate(segs):
        wm = w[a:b].mean(axis=0)
        fm = f[a:b].mean(axis=0)
        d_b = -fm / np.linalg.norm(fm)
        wd_h[j, 0] = float(wm @ d_b)
        wd_h[j, 1] = float(np.linalg.norm(wm - wd_h[j, 0] * d_b))
    weight = np.array([b - a for a, b in segs], dtype=float) / n_st
    w_d, w_h = (float(x) for x in weight @ wd_h)
    mis = max(abs(w_d + om * math.sin(lat_rad)), abs(w_h - om * math.cos(lat_rad)))
    passed = bool(mis <= thr)
    sug = "" if passed else (
        f"at rest the gyros read {w_d / _DPH:+.1f} deg/h down and {w_h / _DPH:.1f} deg/h "
        f"horizontal where the Earth rate gives {-om * math.sin(lat_rad) / _DPH:+.1f} and "
        f"{om * math.cos(lat_rad) / _DPH:.1f}: check the gyro unit, axes and the IMU grade")
    return Check("earth_rate", "ingest",
                 f"misfit of the mean gyro output at rest ({t_static:.0f} s in {len(segs)} "
                 "stretch(es)) to the Earth rate (vertical component, horizontal magnitude)",
                 mis / _DPH, thr / _DPH, "deg/h", passed, "degraded", sug)


# =============================================================================================
# GNSS against the filter
# =============================================================================================
NIS_WINDOW = 60
"""GNSS records per NIS window."""
NIS_WINDOW_PROBABILITY = 0.999
"""Chi-square quantile of the window band (per-window false-alarm level 1e-3)."""
NIS_MAX_FRACTION = 0.1
"""Largest fraction of windows above the band."""


def nis_band(t_s: ArrayLike, nis: ArrayLike, dof: int = 3) -> Check:
    """GNSS normalised innovation squared over time against its chi-square band.

    The processed GNSS records (position and velocity, gated ones included) are cut into
    windows of NIS_WINDOW; under the filter's model the window sum is chi-square with
    dof * n degrees of freedom. Statistic: fraction of windows whose mean NIS is above the
    NIS_WINDOW_PROBABILITY quantile / n (each window a 1e-3 false alarm); threshold
    NIS_MAX_FRACTION. Only the upper side: a conservative tuning (NIS below 3) is not wrong.
    """
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(nis, dtype=float)
    ok = np.isfinite(v)
    t, v = t[ok], np.minimum(v[ok], 1e12)
    n_win = v.shape[0] // NIS_WINDOW
    if n_win < 1:
        return skip("gnss_nis", "navigate", f"{v.shape[0]} GNSS updates (< {NIS_WINDOW})", "1",
                   NIS_MAX_FRACTION)
    vw = v[: n_win * NIS_WINDOW].reshape(n_win, NIS_WINDOW).mean(axis=1)
    upper = chi2_ppf(NIS_WINDOW_PROBABILITY, dof * NIS_WINDOW) / NIS_WINDOW
    bad = vw > upper
    frac = float(bad.mean())
    passed = frac <= NIS_MAX_FRACTION
    worst = int(np.argmax(vw))
    t_worst = float(t[worst * NIS_WINDOW])
    sug = "" if passed else (
        f"GNSS innovations are larger than the filter expects (mean NIS up to {vw.max():.3g} "
        f"per {NIS_WINDOW} records where {upper:.2f} is the limit, worst from t = "
        f"{t_worst:.0f} s): check the lever arm, GNSS time offset, IMU frame and GNSS "
        "covariances")
    return Check("gnss_nis", "navigate",
                 f"fraction of {NIS_WINDOW}-record windows whose mean NIS is above the "
                 f"chi-square {NIS_WINDOW_PROBABILITY} band ({upper:.2f})", frac,
                 NIS_MAX_FRACTION, "1", passed, "degraded", sug, _toff(t_worst))


GATE_TAIL = 1e-3
"""Upper-tail probability of A's gated-record count under its own model beyond which
:func:`gnss_gate` fails."""


def gnss_gate(n_records: int, n_rejected: int, gate_probability: float,
              t_first_s: float | None = None) -> Check:
    """GNSS records algorithm A's innovation gate rejected against what A's own model allows.

    ``n_records`` position and velocity records processed (after the filter start),
    ``n_rejected`` of them gated or accepted only after a covariance reset (every record
    failed the gate for ``gate_reset_s``). Under A's model each fails the chi-square gate
    with probability ``1 - gate_probability``, so the count is Poisson with mean ``lam = n (1
    - gate_probability)``. Statistic: the count; threshold: the Poisson quantile of upper
    tail :data:`GATE_TAIL` (a false alarm in 1e-3 runs where A's model holds). A run whose A
    rejects more is one where the model does not hold (an accelerometer warm-up beyond the
    grade's bias, a lever arm or GNSS time offset, GNSS faults; docs/qc.md)."""
    lam = max(int(n_records), 0) * (1.0 - gate_probability)
    limit = poisson_isf(GATE_TAIL, lam) if lam > 0 else 0.0
    passed = int(n_rejected) <= limit
    sug = "" if passed else (
        f"algorithm A rejected {n_rejected} of {n_records} GNSS records where its model allows "
        f"about {lam:.2g}{'' if t_first_s is None else f' (first at t = {t_first_s:.0f} s)'}: "
        "its IMU error model does not hold on this flight (an accelerometer warm-up or bias "
        "beyond the grade's, the lever arm, a GNSS time offset, GNSS faults); see the "
        "diagnosis and check the [imu] tuning")
    return Check("gnss_gate", "navigate",
                 f"GNSS records gated (or used after a covariance reset) of {n_records}; "
                 f"limit: Poisson quantile {1 - GATE_TAIL} of mean {lam:.3g}",
                 float(n_rejected), limit, "records", passed, "degraded", sug,
                 None if passed or t_first_s is None else _toff(t_first_s))


GNSS_JUMP_BASE_M = 30.0
"""Fixed part of the GNSS jump threshold [m]."""
GNSS_JUMP_ACCEL_MPS2 = 10.0
"""Acceleration allowed between fixes in the jump threshold [m/s^2] (adds a dt^2 / 2)."""


def gnss_jumps(fix_t_s: ArrayLike, r_n_m: ArrayLike, vel_t_s: ArrayLike, v_n_mps: ArrayLike
               ) -> Check:
    """Largest step of the GNSS track not explained by the velocity.

    For consecutive fixes k, k+1: e_k = |r_k+1 - r_k - (v(t_k) + v(t_k+1)) / 2 dt| with v the
    velocity interpolated at the fix times (GNSS velocity, or algorithm A's when the log has
    none). Statistic: max_k e_k - a dt_k^2 / 2 [m]; threshold GNSS_JUMP_BASE_M. A position
    jump of D metres gives e ~ D; the trapezoid's own error is jerk dt^3 / 12, centimetres.
    """
    t = np.asarray(fix_t_s, dtype=float)
    r = np.asarray(r_n_m, dtype=float)
    tv = np.asarray(vel_t_s, dtype=float)
    v = np.asarray(v_n_mps, dtype=float)
    if t.shape[0] < 2 or tv.shape[0] < 2:
        return skip("gnss_jumps", "ingest", "fewer than two GNSS fixes or velocities", "m",
                   GNSS_JUMP_BASE_M)
    vi = np.column_stack([np.interp(t, tv, v[:, a]) for a in range(3)])
    dt = np.diff(t)
    e = np.linalg.norm(np.diff(r, axis=0) - 0.5 * (vi[1:] + vi[:-1]) * dt[:, None], axis=1)
    e = e - 0.5 * GNSS_JUMP_ACCEL_MPS2 * dt**2
    # a step out of the track and back shows twice; name the first
    k = int(np.argmax(e))
    passed = bool(e[k] <= GNSS_JUMP_BASE_M)
    step = float(np.linalg.norm(r[k + 1] - r[k] - 0.5 * (vi[k + 1] + vi[k]) * dt[k]))
    sug = "" if passed else (
        f"the GNSS track jumps by {step:.0f} m between t = {t[k]:.1f} s and {t[k + 1]:.1f} s "
        "where the velocity does not move it: check the receiver log (fix type, datum, "
        "spliced files)")
    return Check("gnss_jumps", "ingest",
                 "largest GNSS position step not explained by the velocity, less "
                 f"{GNSS_JUMP_ACCEL_MPS2:.0f} m/s^2 dt^2/2", float(e[k]), GNSS_JUMP_BASE_M, "m",
                 passed, "degraded", sug, _toff(float(t[k + 1])))


LEVER_ARM_MAX_M = LEVER_ARM_FLOOR_M
"""Largest difference between the configured and the estimated lever arm per axis [m] (the
practical floor; a difference must also be beyond LEVER_ARM_SIGMAS of its sigma)."""
LEVER_ARM_SIGMAS = 5.0
LEVER_ARM_MIN_YAW_SPAN_DEG = 90.0
"""The forward and right components count only when the heading turned this much."""
LEVER_ARM_MIN_TILT_SPAN_DEG = 15.0
"""The down component counts only when roll or pitch changed this much."""


def lever_arm_observable(rpy_rad: ArrayLike) -> NDArray:
    """Which lever-arm axes (FRD) the attitude history can reveal, (3,) bool.

    A lever arm shows only through attitude changes (the antenna moves around the IMU):
    x and y when the heading turned by LEVER_ARM_MIN_YAW_SPAN_DEG, z when roll or pitch
    changed by LEVER_ARM_MIN_TILT_SPAN_DEG. The filter's own sigma is too optimistic on a
    flight without such changes (a 400 s take-off and climb gave 0.8 m at 11 sigma).
    """
    rpy = np.asarray(rpy_rad, dtype=float)
    if rpy.shape[0] < 2:
        return np.zeros(3, dtype=bool)
    yaw_span = math.degrees(float(np.ptp(np.unwrap(rpy[:, 2]))))
    tilt_span = math.degrees(float(max(np.ptp(rpy[:, 0]), np.ptp(rpy[:, 1]))))
    h = yaw_span >= LEVER_ARM_MIN_YAW_SPAN_DEG
    return np.array([h, h, tilt_span >= LEVER_ARM_MIN_TILT_SPAN_DEG])


def lever_arm(configured_b_m: ArrayLike, estimated_b_m: ArrayLike, sigma_b_m: ArrayLike,
              *, observable: ArrayLike = (True, True, True),
              mean_speed_mps: float = math.nan, joint: LeverTime | None = None) -> Check:
    """Configured antenna lever arm against the one the data estimate (A with lever states).

    Statistic: max over axes of |l_cfg - l_est| where that difference is also beyond
    LEVER_ARM_SIGMAS of the estimate's sigma and the axis is ``observable``
    (:func:`lever_arm_observable`; an axis the flight cannot reveal does not count) [m];
    threshold LEVER_ARM_MAX_M, the practical floor. A GNSS time offset tau moves the antenna
    along the track by -v tau, which the lever-arm states read as a forward lever arm.
    ``joint`` (:func:`pospp.qc.lever_time.lever_time_joint`), when made, separates the two
    where the flight's speed changes allow: the statistic is then taken on the lever arm at
    the joint offset with its sigma including the offset's uncertainty, and the suggestion
    is the joint reading's (:func:`pospp.qc.lever_time.lever_time_verdict`: the lever arm,
    the offset, both, or, where the flight cannot tell them apart, the combination it
    determines with both readings); where it reads neither, the statistic is taken on its
    apparent lever arm with its sigma (widened by the records' level and colour). Without
    it, when the forward axis dominates, the suggestion names the equivalent offset
    -dl_x / v as well.
    """
    cfg = np.asarray(configured_b_m, dtype=float)
    est = np.asarray(estimated_b_m, dtype=float)
    sig = np.asarray(sigma_b_m, dtype=float)
    obs = np.asarray(observable, dtype=bool)
    if not np.isfinite(est).all():
        return skip("lever_arm", "navigate", "no lever-arm estimate", "m", LEVER_ARM_MAX_M)
    if not obs.any():
        return skip("lever_arm", "navigate", "no turn and no tilt change to reveal it", "m",
                   LEVER_ARM_MAX_M)
    verdict = lever_time_verdict(joint, sigmas=LEVER_ARM_SIGMAS) if joint else None
    at = ""
    if joint is not None and verdict is not None and verdict.kind in (
            "time_offset", "lever_arm", "both"):
        est, sig = joint.lever_b_m, joint.sigma_lever_b_m
        at = f" at the joint GNSS time offset {1e3 * joint.tau_s:+.1f} ms"
    elif joint is not None and verdict is not None and verdict.kind == "none":
        # the joint estimate sees no lever arm: its apparent one with its sigmas (those of
        # the records' level and colour, which A's single pass does not have)
        est, sig = joint.apparent_lever_b_m, joint.sigma_apparent_b_m
        at = " (the joint estimate's apparent lever arm)"
    d = np.abs(cfg - est)
    seen = (d > LEVER_ARM_SIGMAS * sig) & obs
    value = float(np.max(np.where(seen, d, 0.0)))
    passed = value <= LEVER_ARM_MAX_M
    fmt = ", ".join(f"{x:.2f}" for x in est)
    sug = "" if passed else (
        f"the data suggest a lever arm of [{fmt}] m (body FRD, sigma "
        f"{', '.join(f'{s:.2f}' for s in sig)}) where [{', '.join(f'{x:.2f}' for x in cfg)}] "
        "m is configured: set [gnss] lever_arm_m")
    dx = est[0] - cfg[0]
    if verdict is not None and verdict.kind in ("lever_arm", "both", "confounded"):
        sug = "" if passed else verdict.text
    elif not passed and int(np.argmax(np.where(seen, d, 0.0))) == 0 and mean_speed_mps > 1.0:
        sug += (f" (or, if the forward lever is right, GNSS {'lags' if dx < 0 else 'leads'} "
                f"the IMU by about {abs(dx) / mean_speed_mps:.3f} s)")
    return Check("lever_arm", "navigate",
                 "largest |configured - estimated| antenna lever arm component (beyond "
                 f"{LEVER_ARM_SIGMAS:.0f} sigma; axes seen: "
                 f"{''.join(a for a, o in zip('xyz', obs, strict=True) if o)}){at}", value,
                 LEVER_ARM_MAX_M, "m", passed, "degraded", sug)


# =============================================================================================
# Data completeness, calibration, configuration
# =============================================================================================
def data_complete(complete: bool, n_error_issues: int, first_error: str, duration_s: float,
                  window_s: float | None) -> Check:
    """The log was read to its end with no error, and covers the configured window.

    Statistic: the number of problems (incomplete read, error-severity ingest issues, the data
    ending more than 1 s before the configured [input] window); threshold 0.
    """
    problems = []
    if not complete:
        problems.append("the log was not read to its end (truncated or corrupt)")
    if n_error_issues:
        problems.append(f"{n_error_issues} ingest error(s), first: {first_error}")
    if window_s is not None and duration_s < window_s - 1.0:
        problems.append(f"the data span {duration_s:.1f} s of the {window_s:.1f} s configured "
                        "window")
    passed = not problems
    return Check("data_complete", "ingest",
                 "problems with the completeness of the read log", float(len(problems)), 0.0,
                 "1", passed, "degraded", "; ".join(problems))


def calibration_quality(calibrated: bool, reason: str, n_pairs_used: int) -> Check:
    """A calibration was produced from at least one admissible pair (else the run is partial).

    The suggestion is the calibration stage's reason without its "no calibration: " prefix:
    every place that shows it already names the check ("calibration (partial) 0 < 1: only one
    leg ..."), and the reason itself is shown beside "calibration: none" in the report.
    """
    why = reason.strip()
    while why.lower().startswith("no calibration:"):
        why = why[len("no calibration:"):].strip()
    return Check("calibration", "calibrate", "leg pairs used in the calibration",
                 float(n_pairs_used), 1.0, "1", bool(calibrated), "partial",
                 "" if calibrated else why or "no calibration was produced")


COMPENSATION_MARGIN_MPS = 0.01
"""Compensation may leave B's velocity error at most this much above the uncompensated one."""


def compensation_gain(dv_before_mps: float, dv_after_mps: float) -> Check:
    """B's RMS velocity error at the horizon after compensation against before.

    Statistic: dv_after - dv_before [m/s]; threshold COMPENSATION_MARGIN_MPS. A calibration
    that makes B worse is wrong (wrong signs, frames or a model that does not fit).
    """
    if not (math.isfinite(dv_before_mps) and math.isfinite(dv_after_mps)):
        return skip("compensation", "compensate", "no compensation", "m/s",
                   COMPENSATION_MARGIN_MPS)
    d = dv_after_mps - dv_before_mps
    passed = d <= COMPENSATION_MARGIN_MPS
    sug = "" if passed else (f"compensation made B worse ({dv_before_mps:.3g} -> "
                             f"{dv_after_mps:.3g} m/s): do not use the calibration")
    return Check("compensation", "compensate",
                 "B's horizontal velocity error at the horizon, after minus before (RMS over "
                 "legs)", d, COMPENSATION_MARGIN_MPS, "m/s", passed, "degraded", sug)


def config_sanity(problems: list[str]) -> Check:
    """Configuration values that make no sense but were not refused (threshold 0)."""
    return Check("config", "config", "configuration values out of their meaningful range",
                 float(len(problems)), 0.0, "1", not problems, "failed", "; ".join(problems))


MODEL_FIT_SIGMAS = 2.0
"""A finding fails ``model_fit`` when it could move the calibrated gyro bias beyond this many
of its 1-sigma (out of its 95 % interval): the refit with the named effects, or the bias an
unexplained gap stands for (docs/decisions.md "`model_fit` fails on what could move the
calibration out of its 95 % interval")."""


def model_fit(named: list[str], refit_shift_sigmas: float, gap_p_value: float, alpha: float,
              gap_bias_bound_radps: float, bias_sigma_radps: float,
              named_texts: list[str], gap_text: str = "") -> Check:
    """The calibration's model explains B minus A: no effect the diagnosis named
    outside it and no unexplained gap could move the calibrated gyro bias out of its 95 %
    interval.

    Statistic: the findings, counted: the effects the diagnosis named that the calibration
    does not model (``named``), when the calibration refitted with them removed moves the
    horizontal gyro bias by more than :data:`MODEL_FIT_SIGMAS` of its 1-sigma on an axis
    (``refit_shift_sigmas``; NaN, no refit: they count), plus one for a significant
    unexplained gap (the closing row's p below ``alpha``) standing for more than that: the
    horizontal gyro bias a structured gap of ``dv(T)`` at the horizon T stands for on a level
    leg (T well below the Schuler period) is ``b = 2 dv(T) / (g T^2)``
    (``gap_bias_bound_radps``). Threshold 0. ``named_texts`` (the named effects and the
    refit) and ``gap_text`` (the gap): the suggestion, each when it counts. Severity
    "degraded": the calibration may be biased; the refit (which the compensation uses) says
    by how much.
    """
    moved = bool(named) and not refit_shift_sigmas <= MODEL_FIT_SIGMAS
    gap = (math.isfinite(gap_p_value) and gap_p_value < alpha
           and gap_bias_bound_radps > MODEL_FIT_SIGMAS * bias_sigma_radps)
    n = (len(named) if moved else 0) + int(gap)
    return Check("model_fit", "diagnose",
                 "effects named outside the calibration's model whose refit moves the gyro "
                 "bias beyond 2 sigma, plus an unexplained gap (p < alpha) that could",
                 float(n), 0.0, "1", n == 0, "degraded",
                 "; ".join([*(named_texts if moved else []),
                            *([gap_text] if gap and gap_text else [])]))
