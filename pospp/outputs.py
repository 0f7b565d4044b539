"""Stage results -> output table columns (docs/formats.md schemas). No I/O, no printing.

The pipeline turns its frozen stage results into the documented tables here, in one place, so
the column names and units of ``pospp.io.parquet_tables.TABLES`` meet the numeric results
once. Angles leave the numeric core in radians and arrive here; degrees, deg/h and arcsec are
made only here (design.md: units at the edges).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp.units import DEG_PER_H_RADPS, NS_PER_S, UG_MPS2, time_ns_from_t_s

if TYPE_CHECKING:
    import pandas as pd

    from pospp.io.errors import IngestIssue
    from pospp.io.mcap_reader import FlightLog
    from pospp.nav.events import SensorPoses
    from pospp.nav.filter import BiasHistory
    from pospp.nav.filter_input import GnssRejection
    from pospp.nav.solution import NavSolution


def trajectory_table(solutions: Mapping[str, NavSolution], epoch_ns: int
                     ) -> dict[str, NDArray]:
    """trajectory.parquet's columns: one block of rows per solution ("forward", "smoothed",
    ...), each a :class:`pospp.nav.solution.NavSolution` (NED, rad, SI). Written into one
    array per column, a solution at a time (not a table per solution joined after)."""
    sizes = [len(sol.t_s) for sol in solutions.values()]
    cols: dict[str, NDArray] = {"solution": np.repeat(np.array(list(solutions), dtype=object),
                                                      sizes)}
    at = 0
    for sol, n in zip(solutions.values(), sizes, strict=True):
        for name, values in _trajectory_columns(sol, epoch_ns).items():
            if name not in cols:
                cols[name] = np.empty(sum(sizes), dtype=np.asarray(values).dtype)
            cols[name][at:at + n] = values
        at += n
    return cols


def _trajectory_columns(sol: NavSolution, epoch_ns: int) -> dict[str, NDArray]:
    rpy = np.degrees(sol.rpy_rad)
    rpy_sig = np.degrees(sol.rpy_sigma_rad)
    return {
        "time_ns": time_ns_from_t_s(sol.t_s, epoch_ns),
        "lat_deg": np.degrees(sol.lat_rad),
        "lon_deg": np.degrees(sol.lon_rad),
        "height_m": sol.height_m,
        "vn_mps": sol.v_n_mps[:, 0],
        "ve_mps": sol.v_n_mps[:, 1],
        "vd_mps": sol.v_n_mps[:, 2],
        "roll_deg": rpy[:, 0],
        "pitch_deg": rpy[:, 1],
        "yaw_deg": np.mod(rpy[:, 2], 360.0),
        "north_sigma_m": sol.pos_sigma_ned_m[:, 0],
        "east_sigma_m": sol.pos_sigma_ned_m[:, 1],
        "down_sigma_m": sol.pos_sigma_ned_m[:, 2],
        "vn_sigma_mps": sol.vel_sigma_ned_mps[:, 0],
        "ve_sigma_mps": sol.vel_sigma_ned_mps[:, 1],
        "vd_sigma_mps": sol.vel_sigma_ned_mps[:, 2],
        "roll_sigma_deg": rpy_sig[:, 0],
        "pitch_sigma_deg": rpy_sig[:, 1],
        "yaw_sigma_deg": rpy_sig[:, 2],
    }


def bias_table(histories: Mapping[str, BiasHistory | None], epoch_ns: int, *, rate_hz: float = 1.0
               ) -> pd.DataFrame:
    """biases.parquet: algorithm A's estimated sensor errors over time, one block per solution.

    Each history is a :class:`pospp.nav.filter.BiasHistory` (body FRD, rad/s, m/s^2,
    dimensionless scale factors, measured = (1 + s) true + b). Biases in deg/h and ug, scale
    factors in ppm; the scale-factor columns are null when A did not estimate them (all
    sigmas zero). Thinned to about ``rate_hz`` (every k-th epoch; the estimates change over
    minutes).
    """
    import pandas as pd  # imported where a table is made: the stages before run without it

    blocks = []
    for name, hist in histories.items():
        if hist is None:
            continue
        step = 1
        if len(hist.t_s) > 1:
            step = max(1, int(round(1.0 / (rate_hz * float(np.median(np.diff(hist.t_s)))))))
        h = type(hist)(**{k: v[::step] for k, v in vars(hist).items()})
        cols: dict[str, Any] = {"time_ns": time_ns_from_t_s(h.t_s, epoch_ns), "solution": name}
        gyro_dph = h.gyro_b_radps / DEG_PER_H_RADPS
        gyro_sig_dph = h.gyro_sigma_b_radps / DEG_PER_H_RADPS
        for k, ax in enumerate("xyz"):
            cols[f"gyro_bias_{ax}_dph"] = gyro_dph[:, k]
            cols[f"gyro_bias_{ax}_sigma_dph"] = gyro_sig_dph[:, k]
            cols[f"accel_bias_{ax}_ug"] = h.accel_b_mps2[:, k] / UG_MPS2
            cols[f"accel_bias_{ax}_sigma_ug"] = h.accel_sigma_b_mps2[:, k] / UG_MPS2
        for sensor, sf, sig in (("gyro", h.gyro_sf, h.gyro_sf_sigma),
                                ("accel", h.accel_sf, h.accel_sf_sigma)):
            if np.any(np.asarray(sig) > 0.0):
                for k, ax in enumerate("xyz"):
                    cols[f"{sensor}_sf_{ax}_ppm"] = sf[:, k] * 1e6
                    cols[f"{sensor}_sf_{ax}_sigma_ppm"] = sig[:, k] * 1e6
        blocks.append(pd.DataFrame(cols))
    return pd.concat(blocks, ignore_index=True)


def event_poses_table(events_ns: ArrayLike, solution: Any, name: str, epoch_ns: int,
                      sensor: Any, note: Any) -> pd.DataFrame:
    """events.parquet: the ``[sensor]``'s pose (its lever arm and boresight, config section
    ``sensor``) at every trigger event ``events_ns`` on a solution (:class:`pospp.nav.filter.
    NavSolution` ``name``, run epoch ``epoch_ns``) (pospp.nav.events); ``note(text)`` says how
    many events fall outside the solution's time span."""
    from pospp import rotation
    from pospp.nav import events as sensor_events
    from pospp.units import t_s_from_time_ns

    poses = sensor_events.sensor_poses(
        solution, t_s_from_time_ns(np.asarray(events_ns), epoch_ns),
        lever_b_m=sensor.lever_arm_m,
        c_bs=rotation.dcm_from_euler(np.radians(sensor.boresight_rpy_deg)))
    n_out = int(np.count_nonzero(~poses.inside))
    if n_out:
        note(f"{n_out} of {len(poses)} trigger event(s) outside the solution's time span: NaN "
             "in events.parquet")
    return events_table(poses, events_ns, name)


def events_table(poses: SensorPoses, events_ns: ArrayLike, solution: str) -> pd.DataFrame:
    """events.parquet: the sensor's pose at every trigger event.

    ``poses`` is a :class:`pospp.nav.events.SensorPoses` at the stamps ``events_ns``.
    """
    import pandas as pd

    rpy = np.degrees(poses.rpy_rad)
    rpy_sig = np.degrees(poses.rpy_sigma_rad)
    cols: dict[str, Any] = {
        "time_ns": np.asarray(events_ns, dtype=np.int64),
        "event_id": np.arange(len(poses), dtype=np.int64),
        "solution": solution,
        "inside": np.asarray(poses.inside, dtype=bool),
        "lat_deg": np.degrees(poses.lat_rad), "lon_deg": np.degrees(poses.lon_rad),
        "height_m": poses.height_m,
    }
    for k, ax in enumerate("ned"):
        cols[f"v{ax}_mps"] = poses.v_n_mps[:, k]
    cols.update({"roll_deg": rpy[:, 0], "pitch_deg": rpy[:, 1], "yaw_deg": rpy[:, 2]})
    for k, ax in enumerate(("north", "east", "down")):
        cols[f"{ax}_sigma_m"] = poses.pos_sigma_ned_m[:, k]
    for k, ax in enumerate("ned"):
        cols[f"v{ax}_sigma_mps"] = poses.vel_sigma_ned_mps[:, k]
    for k, a in enumerate(("roll", "pitch", "yaw")):
        cols[f"{a}_sigma_deg"] = rpy_sig[:, k]
    return pd.DataFrame(cols)


def with_sensor_axes(summary: Mapping[str, Any], c_bs: ArrayLike) -> dict[str, Any]:
    """``summary`` with the calibrated body gyro bias also in the IMU's logged axes.

    The bias is estimated in the body frame b (FRD); the log's IMU axes s (FLU for ROS, or
    as configured) differ by ``C_bs`` (sensor to body, ``[input] sensor_frame`` and
    ``mounting_rpy_deg``): ``b_s = C_bs^T b_b`` (for FLU: x the same, y and z negated). The
    sigmas map as ``sigma_s_i = sqrt(sum_j C_bs[j, i]^2 sigma_b_j^2)`` (exact for a signed
    permutation such as FLU; the body sigmas' correlations are not in the summary). Columns
    ``gyro_bias_sensor_{x,y,z}_dph`` and ``..._sigma_dph``, and ``imu_axes`` naming those axes
    ("FLU", "FRD", or "as logged" for another mounting); absent when no body bias is.
    """
    out = dict(summary)
    if not all(f"gyro_bias_{ax}_dph" in out for ax in "xyz"):
        return out
    c = np.asarray(c_bs, dtype=float)
    out["imu_axes"] = ("FLU" if np.allclose(c, np.diag([1.0, -1.0, -1.0]), atol=1e-12) else
                       "FRD" if np.allclose(c, np.eye(3), atol=1e-12) else "as logged")
    b = np.array([out[f"gyro_bias_{ax}_dph"] for ax in "xyz"], dtype=float)
    s2 = np.array([out[f"gyro_bias_{ax}_sigma_dph"] for ax in "xyz"], dtype=float) ** 2
    known = np.isfinite(b)
    b_s = c.T @ np.where(known, b, 0.0)
    s_s = np.sqrt((c.T ** 2) @ np.where(known, s2, 0.0))
    for i, ax in enumerate("xyz"):  # an axis fed by an unestimated body axis is unknown too
        fed = np.abs(c[:, i]) > 1e-12
        ok = bool(np.all(known[fed]))
        out[f"gyro_bias_sensor_{ax}_dph"] = float(b_s[i]) if ok else float("nan")
        out[f"gyro_bias_sensor_{ax}_sigma_dph"] = float(s_s[i]) if ok else float("nan")
    return out


def issue_message(issue: IngestIssue) -> dict[str, Any]:
    """One :class:`pospp.io.errors.IngestIssue` -> a messages row."""
    return {
        "severity": issue.severity,
        "stage": "ingest",
        "time_ns": issue.time_ns,
        "text": (f"{issue.file}: " if issue.file else "") + issue.message,
        "topic": issue.topic,
        "index": issue.index,
        "byte_offset": issue.byte_offset,
        "log_time_ns": issue.log_time_ns,
    }


ROUTINE_REJECTIONS = frozenset({"before the filter start (alignment)",
                                "outside the IMU time span"})
"""Reasons (``GnssRejection.reason``) for which every flight leaves GNSS records out: the
records logged while A aligns, or before the IMU starts and after it stops. They say nothing
about the data's quality (172 of the 176 warnings of the comma2k19 run were these): one "info"
row per kind and reason with the count, not a warning per record."""


def rejection_messages(rejections: Iterable[GnssRejection], *, limit: int = 200
                       ) -> list[dict[str, Any]]:
    """GNSS measurements algorithm A did not use -> messages rows: a warning per rejection
    (at most ``limit``, then one row counting the rest, so a flight with a bad receiver does
    not flood the table), and for the routine ones (:data:`ROUTINE_REJECTIONS`) one info row
    per kind and reason, at the first one's time, with their count."""
    rows: list[dict[str, Any]] = []
    routine: dict[tuple[str, str], list[GnssRejection]] = {}
    other = []
    for r in rejections:
        if r.reason in ROUTINE_REJECTIONS:
            routine.setdefault((r.kind, r.reason), []).append(r)
        else:
            other.append(r)
    for (kind, reason), group in routine.items():
        rows.append({"severity": "info", "stage": "navigate", "time_ns": int(group[0].time_ns),
                     "text": f"GNSS {kind} rejected: {reason}: {len(group)} records "
                             "(routine)"})
    for r in other[:limit]:
        rows.append({"severity": "warning", "stage": "navigate", "time_ns": int(r.time_ns),
                     "text": f"GNSS {r.kind} rejected: {r.reason}"})
    if len(other) > limit:
        rows.append({"severity": "warning", "stage": "navigate", "time_ns": None,
                     "text": f"{len(other) - limit} more GNSS rejections not listed"})
    return rows


def filter_event_messages(resets: Iterable[tuple[float, str]],
                          imu_gaps: Iterable[tuple[float, float]],
                          epoch_ns: int) -> list[dict[str, Any]]:
    """Algorithm A's covariance resets and bridged IMU gaps -> messages rows."""
    rows = []
    for t_s, kind in resets:
        rows.append({"severity": "warning", "stage": "navigate",
                     "time_ns": int(time_ns_from_t_s(t_s, epoch_ns)),
                     "text": f"{kind} covariance reset after a run of gated GNSS records"})
    for t_s, gap_s in imu_gaps:
        rows.append({"severity": "warning", "stage": "navigate",
                     "time_ns": int(time_ns_from_t_s(t_s, epoch_ns)),
                     "text": f"IMU gap of {gap_s:.3f} s bridged"})
    return rows


def messages_table(messages: list[dict[str, Any]]) -> pd.DataFrame:
    """messages.parquet from rows (optional columns may be absent in a row)."""
    import pandas as pd

    cols = ["severity", "stage", "time_ns", "text", "topic", "index", "byte_offset",
            "log_time_ns"]
    df = pd.DataFrame(messages, columns=cols)
    for c in ("time_ns", "index", "byte_offset", "log_time_ns"):
        df[c] = df[c].astype("Int64")
    return df


def log_summary(log: FlightLog) -> dict[str, Any]:
    """Summary columns describing the input."""
    t = log.imu.time_ns
    dt = np.diff(t)
    return {
        "duration_s": float((t[-1] - t[0]) / NS_PER_S),
        "n_imu_samples": int(len(log.imu)),
        "n_gnss_fixes": int(len(log.fix)),
        "imu_rate_hz": float(NS_PER_S / np.median(dt)) if dt.size else float("nan"),
    }


# --------------------------------------------------------------------------- headline figures

NOT_OBSERVABLE_SIGMA = {"arcsec": 360.0, "deg_per_h": 10.0}
"""1-sigma above which a calibrated parameter is reported as not observable, by its unit.

360 arcsec (0.1 deg) is the coarse-alignment level: a misalignment known no better than
that says nothing about algorithm A's attitude error. 10 deg/h is above the bias of every
gyro pospp targets but consumer MEMS: a drift known no better than that cannot be fed back.
"""

_WHY_NOT_OBSERVABLE = {
    "phi_z": "heading misalignment: on straight, level, unaccelerated legs it enters B's "
             "horizontal error only through the Earth-rate coupling, which is weak",
    "gyro_bias_z": "vertical gyro drift: on level legs it reaches B's horizontal error only "
                   "through the small tilts",
}


def not_observable(parameter: str, sigma: float, unit: str) -> str:
    """Why a calibrated parameter is not observable ("" when it is).

    A parameter is not observable when its 1-sigma exceeds :data:`NOT_OBSERVABLE_SIGMA` for
    its unit, or is not finite; the value is then flagged, never reported as a result.
    """
    bound = NOT_OBSERVABLE_SIGMA.get(unit, np.inf)
    if np.isfinite(sigma) and sigma <= bound:
        return ""
    base = parameter.partition("_leg")[0]
    why = _WHY_NOT_OBSERVABLE.get(base, "these legs do not determine it")
    unit_txt = unit.replace("_per_", "/")
    return f"sigma {sigma:.4g} {unit_txt} > {bound:g} {unit_txt}: {why}"


def velocity_gap_rms_mps(dv_n_mps: Iterable[ArrayLike]) -> float:
    """RMS of B minus A horizontal velocity over every sample after each leg's start [m/s].

    ``dv_n_mps``: per leg, an (M, >=2) array of [dv_N, dv_E, ...]; row 0 (the leg start, zero
    by construction) is left out, as in the diagnosis' gaps (pospp.diagnose).
    """
    parts = [np.asarray(d, dtype=float)[1:, :2].ravel() for d in dv_n_mps]
    a = np.concatenate(parts) if parts else np.zeros(0)
    return float(np.sqrt(np.mean(a**2))) if a.size else float("nan")


def refit_summary(refit: Any) -> dict[str, Any]:
    """Summary columns of the calibration's refit with the named effects
    (:class:`pospp.diagnose.refit.Refit`, or None: no columns): the effects removed, the
    refit's body gyro bias and 1-sigma [deg/h] (NaN: not estimated), and B's error at the
    horizon after the compensation, which uses the refit (``dv_after_mps``,
    ``dp_after_m``: replacing the calibration's)."""
    if refit is None:
        return {}
    out: dict[str, Any] = {"refit_effects": ";".join(refit.effects)}
    for i, ax in enumerate("xyz"):
        sig = float(refit.sigma_b_radps[i])
        known = bool(np.isfinite(sig))
        out[f"gyro_bias_{ax}_refit_dph"] = (float(refit.bias_b_radps[i]) / DEG_PER_H_RADPS
                                            if known else float("nan"))
        out[f"gyro_bias_{ax}_refit_sigma_dph"] = sig / DEG_PER_H_RADPS if known else \
            float("nan")
    s = refit.run.summary()
    out.update({k: s[k] for k in ("dv_after_mps", "dp_after_m")})
    return out


def diagnosis_summary(steps: Any) -> dict[str, float]:
    """Summary columns from the diagnosis' first step (its base model is the calibration).

    ``steps``: a sequence of :class:`pospp.diagnose.workflow.DiagnosisStep` (or None when no
    diagnosis ran). ``gap_fit_mps`` is the in-sample residual of the calibration fitted to
    every leg; ``gap_heldout_mps`` the leave-one-leg-out prediction's.
    """
    if not steps:
        return {}
    first = steps[0]
    return {"gap_fit_mps": float(first.gap_before_mps),
            "gap_heldout_mps": float(first.heldout_gap_before_mps)}
