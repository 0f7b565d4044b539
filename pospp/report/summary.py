"""The answer of a run, from its tables alone: the headline (status, quality verdict,
calibrated biases with sigma, what was not observable and why, the improvement in-sample and
held out) and the one-screen text summary ``pospp run`` prints.

:func:`headline` is shared by the console (:func:`summary_text`) and the HTML report
(:mod:`pospp.report.html`) so that both say the same thing. Numbers are rounded to their sigma
(:func:`round_to_sigma`); times are UTC and seconds since the run start (:func:`utc_text`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pospp.outputs import not_observable
from pospp.qc.check_record import comparison_text

UNIT_TEXT = {"deg_per_h": "deg/h", "arcsec": "arcsec", "m_per_s": "m/s", "mps": "m/s"}
"""Unit names of the tables -> what a reader expects on a label."""

_PER_LEG = re.compile(r"_leg\d+$")
BODY_AXES = "body axes FRD: x forward, y right, z down"
"""How the headline names the frame of the calibrated values."""
SENSOR_AXES = {"FLU": "FLU: x forward, y left, z up", "FRD": "FRD, as the body",
               "as logged": "as logged, before [input] mounting_rpy_deg"}
"""How it names the IMU's logged axes (summary ``imu_axes``; docs/formats.md)."""


def unit_text(unit: str) -> str:
    """A table unit as printed ("deg_per_h" -> "deg/h")."""
    return UNIT_TEXT.get(unit, unit.replace("_per_", "/"))


def round_to_sigma(value: float | None, sigma: float | None, *, digits: int = 2
                   ) -> tuple[str, str]:
    """``value`` and ``sigma`` as text, both rounded to the sigma's ``digits`` significant
    digits (0.93686, 0.29270 -> "0.94", "0.29"; 313.0, 1915.4 -> "300", "1900")."""
    if value is None or not np.isfinite(value):
        return "n/a", ""
    if sigma is None or not np.isfinite(sigma) or sigma <= 0:
        return f"{value:.4g}", ""
    exp = math.floor(math.log10(sigma)) - (digits - 1)
    dec = max(0, -exp)
    q = 10.0**exp
    v, s = round(value / q) * q, round(sigma / q) * q
    return f"{v:+.{dec}f}", f"{s:.{dec}f}"


def pm_text(value: float | None, sigma: float | None, unit: str = "") -> str:
    """"+0.94 +- 0.29 deg/h" (rounded to the sigma)."""
    v, s = round_to_sigma(value, sigma)
    u = f" {unit_text(unit)}" if unit else ""
    return f"{v} +- {s}{u}" if s else f"{v}{u}"


def utc_text(time_ns: float | np.integer | np.floating | None, *, date: bool = True) -> str:
    """int64 UTC ns -> "2024-06-01 00:05:38.01 UTC" ("" when null)."""
    if time_ns is None or pd.isna(time_ns):
        return ""
    t = pd.Timestamp(int(time_ns), unit="ns", tz="UTC")
    text = t.strftime("%Y-%m-%d %H:%M:%S" if date else "%H:%M:%S")
    return f"{text}.{t.microsecond // 10000:02d}"


def run_start_ns(tables: Mapping[str, pd.DataFrame]) -> int | None:
    """t = 0 of the run (first trajectory epoch; else the first leg or message time)."""
    for name, col in (("trajectory", "time_ns"), ("legs", "start_ns"), ("messages", "time_ns"),
                      ("qc", "time_ns")):
        t = tables.get(name)
        if t is not None and col in t and t[col].notna().any():
            return int(t[col].min())
    return None


@dataclass(frozen=True)
class Estimate:
    """One calibrated parameter; ``why_not`` is "" when observable."""

    name: str
    value: float
    sigma: float
    unit: str
    why_not: str = ""

    @property
    def text(self) -> str:
        return pm_text(self.value, self.sigma, self.unit)


@dataclass(frozen=True)
class Headline:
    """What an analyst reads first (every field may be missing: NaN, "" or empty)."""

    status: str
    qc_verdict: str
    qc_failed: tuple[str, ...]
    calibration_reason: str
    formulation: str
    results: tuple[Estimate, ...]
    per_leg: tuple[Estimate, ...]
    not_observable: tuple[Estimate, ...]
    dv_before_mps: float
    dv_after_mps: float
    dp_before_m: float
    dp_after_m: float
    gap_uncalibrated_mps: float
    gap_fit_mps: float
    gap_heldout_mps: float
    sensor_axes: tuple[Estimate, ...] = ()
    """The calibrated gyro bias in the IMU's logged axes (summary ``gyro_bias_sensor_*``)."""
    sensor_axes_name: str = ""
    """Those axes in words (``SENSOR_AXES`` of the summary's ``imu_axes``)."""

    @property
    def sensor_axes_text(self) -> str:
        """"x +0.94 +- 0.32, y +0.55 +- 0.33 deg/h" (the gyro bias in the IMU's logged axes)."""
        if not self.sensor_axes:
            return ""
        unit = unit_text(self.sensor_axes[0].unit)
        return ", ".join(f"{e.name[-1]} {pm_text(e.value, e.sigma)}"
                         for e in self.sensor_axes) + f" {unit}"

    refit: tuple[Estimate, ...] = ()
    """The calibration refitted with the effects the diagnosis named outside its model (the
    compensation uses it; summary ``gyro_bias_*_refit_dph``)."""
    refit_effects: str = ""

    @property
    def refit_text(self) -> str:
        """"refitted with accel_bias_change removed: gyro_bias_x ... (the compensation uses
        it)", or "" without a refit."""
        if not self.refit:
            return ""
        base = {e.name: e for e in self.results}
        parts = []
        for e in self.refit:
            b = base.get(e.name)
            moved = (f" (calibration {b.text}, change {e.value - b.value:+.2g})"
                     if b is not None else "")
            parts.append(f"{e.name} {e.text}{moved}")
        return (f"refitted with {self.refit_effects.replace(';', ', ')} removed from B minus A "
                f"(the compensation uses it): " + ", ".join(parts))

    @property
    def in_sample_text(self) -> str:
        if not np.isfinite(self.dv_before_mps):
            return ""
        return (f"B's velocity error at the horizon {self.dv_before_mps:.3g} -> "
                f"{self.dv_after_mps:.2g} m/s, position {self.dp_before_m:.3g} -> "
                f"{self.dp_after_m:.2g} m (RMS over the legs the fit used)")

    @property
    def heldout_text(self) -> str:
        if not np.isfinite(self.gap_heldout_mps):
            return "not computed (no diagnosis in this run)"
        fit = (f"; in-sample fit {self.gap_fit_mps:.2g} m/s" if np.isfinite(self.gap_fit_mps)
               else "")
        return (f"B-minus-A velocity gap {self.gap_uncalibrated_mps:.3g} -> "
                f"{self.gap_heldout_mps:.2g} m/s RMS, each leg predicted by the calibration "
                f"fitted without it{fit}")

    @property
    def per_leg_text(self) -> str:
        if not self.per_leg:
            return ""
        v = np.abs([e.value for e in self.per_leg])
        s = np.array([e.sigma for e in self.per_leg])
        unit = unit_text(self.per_leg[0].unit)
        legs = sorted({e.name[e.name.rindex("_leg") + 4:] for e in self.per_leg})
        return (f"{len(self.per_leg)} per-leg misalignments ({len(legs)} legs): |value| <= "
                f"{v.max():.2g} {unit}, sigma {s.min():.2g}-{s.max():.2g} {unit}")


def _num(row: pd.Series, key: str) -> float:
    v = row.get(key) if row is not None else None
    try:
        return float(v) if v is not None and not pd.isna(v) else float("nan")
    except (TypeError, ValueError):
        return float("nan")


def _chosen_fit(cal: pd.DataFrame | None, formulation: str) -> pd.DataFrame:
    if cal is None or cal.empty:
        return pd.DataFrame(columns=["parameter", "value", "sigma", "unit"])
    joint = cal[cal.pair_id == -1]
    if joint.empty:
        return joint
    forms = list(dict.fromkeys(joint.formulation))
    form = formulation if formulation in forms else ("body" if "body" in forms else forms[0])
    return joint[joint.formulation == form]


def headline(tables: Mapping[str, pd.DataFrame]) -> Headline:
    """The headline of a run from its tables (summary, qc, calibration, diagnosis,
    leg_errors); older runs without the new summary columns are read from the tables."""
    s = tables.get("summary")
    row = s.iloc[0] if s is not None and not s.empty else pd.Series(dtype=object)
    qc = tables.get("qc")
    failed: tuple[str, ...] = ()
    if qc is not None and not qc.empty:
        failed = tuple(qc.check[~qc.passed.astype(bool)])
        verdict = (f"all {len(qc)} quality checks passed" if not failed else
                   f"{len(failed)} of {len(qc)} quality checks failed: {', '.join(failed)}")
    else:
        verdict = "no quality checks in this run"
    form = str(row.get("calibration_formulation") or "")
    fit = _chosen_fit(tables.get("calibration"), form)
    if not fit.empty:
        form = str(fit.formulation.iloc[0])
    results, per_leg, unobs = [], [], []
    for r in fit.itertuples():
        e = Estimate(r.parameter, float(r.value), float(r.sigma), r.unit,
                     not_observable(r.parameter, float(r.sigma), r.unit))
        if e.why_not:
            unobs.append(e)
        elif _PER_LEG.search(e.name):
            per_leg.append(e)
        else:
            results.append(e)
    results.sort(key=lambda e: (not e.name.startswith(("gyro_bias", "eps")), e.name))
    gap_uncal = _num(row, "gap_uncalibrated_mps")
    le = tables.get("leg_errors")
    if not np.isfinite(gap_uncal) and le is not None and not le.empty:
        b = le[(le.stage == "before") & (le.t_s > 0)]
        gap_uncal = float(np.sqrt(np.mean(np.r_[b.dvn_mps, b.dve_mps] ** 2))) if len(b) else \
            float("nan")
    gap_fit, gap_ho = _num(row, "gap_fit_mps"), _num(row, "gap_heldout_mps")
    diag = tables.get("diagnosis")
    if not np.isfinite(gap_ho) and diag is not None and not diag.empty:
        first = diag.sort_values("step").iloc[0]
        gap_fit, gap_ho = float(first.gap_before_mps), float(first.heldout_gap_before_mps)
    sensor = tuple(Estimate(f"gyro_bias_{ax}", _num(row, f"gyro_bias_sensor_{ax}_dph"),
                            _num(row, f"gyro_bias_sensor_{ax}_sigma_dph"), "deg_per_h")
                   for ax in "xyz"
                   if any(e.name == f"gyro_bias_{ax}" for e in results)
                   and np.isfinite(_num(row, f"gyro_bias_sensor_{ax}_dph")))
    refit = tuple(Estimate(f"gyro_bias_{ax}", _num(row, f"gyro_bias_{ax}_refit_dph"),
                           _num(row, f"gyro_bias_{ax}_refit_sigma_dph"), "deg_per_h")
                  for ax in "xyz" if np.isfinite(_num(row, f"gyro_bias_{ax}_refit_dph")))
    return Headline(
        sensor_axes=sensor, sensor_axes_name=SENSOR_AXES.get(str(row.get("imu_axes")), ""),
        refit=refit, refit_effects=str(row.get("refit_effects") or ""),
        status=str(row.get("status") or "?"), qc_verdict=verdict, qc_failed=failed,
        calibration_reason=str(row.get("calibration_reason") or ""), formulation=form,
        results=tuple(results), per_leg=tuple(per_leg), not_observable=tuple(unobs),
        dv_before_mps=_num(row, "dv_before_mps"), dv_after_mps=_num(row, "dv_after_mps"),
        dp_before_m=_num(row, "dp_before_m"), dp_after_m=_num(row, "dp_after_m"),
        gap_uncalibrated_mps=gap_uncal, gap_fit_mps=gap_fit, gap_heldout_mps=gap_ho,
    )


def _fmt(v: object, spec: str = ".3g") -> str:
    try:
        return "n/a" if v is None or pd.isna(v) else format(v, spec)
    except (TypeError, ValueError):
        return str(v)


def headline_lines(h: Headline) -> list[str]:
    """The answer first, a few lines: verdict, calibrated values, what was not observable,
    the improvement in-sample and held out."""
    lines = [f"  status: {h.status} ({h.qc_verdict})"]
    if h.results:
        lines.append(f"  calibrated ({h.formulation} formulation, all pairs; {BODY_AXES}): "
                     + ", ".join(f"{e.name} {e.text}" for e in h.results))
        if any(e.name.endswith("_flight") for e in h.results):
            lines.append("    (gyro_bias_*: the turn-on constant, for a next flight or a lab; "
                         "gyro_bias_*_flight: the bias over this flight's legs, which the "
                         "compensation used)")
        if h.sensor_axes:
            lines.append(f"  the same gyro bias in the IMU's axes ({h.sensor_axes_name}): "
                         f"{h.sensor_axes_text}")
    elif h.calibration_reason and h.calibration_reason != "ok":
        lines.append(f"  calibration: {h.calibration_reason}")
    if h.refit_text:
        lines.append(f"  {h.refit_text}")
    if h.not_observable:
        lines.append("  not observable (no result): " + ", ".join(
            f"{e.name} (sigma {e.sigma:.4g} {unit_text(e.unit)})" for e in h.not_observable))
    if h.in_sample_text:
        lines.append(f"  improvement, in-sample: {h.in_sample_text}")
        lines.append(f"  improvement, held out: {h.heldout_text}")
    return lines


def timing_lines(summary: pd.DataFrame) -> list[str]:
    """The run's wall time and each stage's (summary columns ``wall_time_s``,
    ``stage_<name>_s``), one line; none for a summary without them."""
    r = summary.iloc[0]
    wall = r.get("wall_time_s")
    if wall is None or pd.isna(wall):
        return []
    stages = [(c[len("stage_"):-len("_s")], r[c]) for c in summary.columns
              if c.startswith("stage_") and c.endswith("_s") and pd.notna(r[c])]
    parts = ", ".join(f"{name} {value:.1f}" for name, value in stages)
    return [f"  time: {wall:.1f} s wall" + (f" ({parts} s)" if parts else "")]


def summary_text(tables: Mapping[str, pd.DataFrame], *, verbose: bool = False) -> str:
    """The headline first, then legs, pairs and the calibration block (per-leg
    misalignments and the other formulations only when ``verbose``), then messages."""
    lines: list[str] = []
    s = tables.get("summary")
    h = headline(tables)
    r = s.iloc[0] if s is not None and not s.empty else None
    if r is not None:
        lines.append(f"pospp run: {r.get('input_file')}")
        lines.extend(headline_lines(h))
        lines.extend(qc_lines(tables.get("qc"))[1:] if h.qc_failed else [])
        t0 = run_start_ns(tables)
        lines.append(f"  data: {_fmt(r.get('duration_s'), '.1f')} s of IMU at "
                     f"{_fmt(r.get('imu_rate_hz'), '.0f')} Hz, "
                     f"{_fmt(r.get('n_gnss_fixes'), 'd')} GNSS fixes"
                     + (f", from {utc_text(t0)} UTC" if t0 is not None else ""))
        lines.extend(timing_lines(s))
    legs = tables.get("legs")
    if legs is not None:
        t0 = run_start_ns(tables) or 0
        lines.append(f"  legs: {len(legs)} straight uniform legs")
        for row in legs.itertuples():
            lines.append(f"    leg {row.leg_id:2d}: t {(row.start_ns - t0) * 1e-9:7.0f} s "
                         f"({utc_text(row.start_ns, date=False)} UTC)  {row.duration_s:5.0f} s  "
                         f"heading {row.heading_deg:6.1f} deg  speed {row.speed_mps:5.1f} m/s")
    pairs = tables.get("pairs")
    if pairs is not None:
        used = int(pairs.used.sum()) if len(pairs) else 0
        lines.append(f"  pairs: {used} used of {len(pairs)}")
        for row in pairs.itertuples():
            lines.append(f"    pair {row.pair_id} (legs {row.leg_a},{row.leg_b}): dH "
                         f"{row.dheading_deg:5.1f} deg  cond {row.cond_scaled:8.3g}  "
                         f"{'used' if row.used else 'rejected'}: {row.reason}")
    if h.results or h.not_observable or h.per_leg:
        lines.append(f"  calibration ({h.formulation} formulation, all pairs combined):")
        for e in h.results:
            lines.append(f"    {e.name:14s} {e.text}")
        for e in h.not_observable:
            lines.append(f"    {e.name:14s} not observable ({e.why_not})")
        if verbose:
            lines.extend(f"    {e.name:14s} {e.text}" for e in h.per_leg)
        elif h.per_leg:
            lines.append(f"    {h.per_leg_text} (--verbose lists them)")
        cal = tables.get("calibration")
        if verbose and cal is not None:
            other = cal[(cal.pair_id == -1) & (cal.formulation != h.formulation)]
            for row in other.itertuples():
                flag = not_observable(row.parameter, row.sigma, row.unit)
                text = f"not observable ({flag})" if flag else pm_text(row.value, row.sigma,
                                                                         row.unit)
                lines.append(f"    {row.formulation:6s} {row.parameter:14s} {text}")
    lines.extend(message_lines(tables.get("messages")))
    return "\n".join(lines)


MAX_MESSAGE_KINDS = 6
"""Kinds of warnings (messages equal up to their numbers) the console lists."""


def message_lines(msgs: pd.DataFrame | None) -> list[str]:
    """The messages' counts by severity, then the errors and warnings grouped (identical up
    to their numbers, :func:`group_messages`), most frequent first; the quality checks' own
    messages are left out (their lines come first) and info is only counted."""
    if msgs is None or not len(msgs):
        return []
    n = {k: int((msgs.severity == k).sum()) for k in ("error", "warning", "info")}
    shown = group_messages(msgs[(msgs.severity != "info") & (msgs.stage != "qc")])
    lines = [f"  messages: {n['error']} errors, {n['warning']} warnings, {n['info']} info "
             "(messages.parquet)"]
    for g in shown.head(MAX_MESSAGE_KINDS).itertuples():
        times = f" x{g.count}" if g.count > 1 else ""
        lines.append(f"    {g.severity}: {g.text}{times}")
    if len(shown) > MAX_MESSAGE_KINDS:
        lines.append(f"    and {len(shown) - MAX_MESSAGE_KINDS} more kinds (messages.parquet)")
    return lines


_NUMBER = re.compile(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")


def group_messages(msgs: pd.DataFrame) -> pd.DataFrame:
    """Identical messages (numbers aside) grouped: severity, stage, count, first and last
    time_ns, and the first one's text; errors first, then by count."""
    cols = ["severity", "stage", "count", "first_ns", "last_ns", "text"]
    if msgs is None or msgs.empty:
        return pd.DataFrame(columns=cols)
    d = msgs.assign(_key=msgs.text.astype(str).str.replace(_NUMBER, "#", regex=True))
    g = d.groupby(["severity", "stage", "_key"], sort=False, dropna=False)
    out = g.agg(count=("text", "size"), first_ns=("time_ns", "min"),
                last_ns=("time_ns", "max"), text=("text", "first")).reset_index()
    rank = out.severity.map({"error": 0, "warning": 1}).fillna(2)
    out = out.assign(_rank=rank).sort_values(["_rank", "count"], ascending=[True, False],
                                             kind="stable")
    return out[cols].reset_index(drop=True)


def qc_lines(qc: pd.DataFrame | None) -> list[str]:
    """The failed quality checks (qc.parquet) with what the data suggest, one line each."""
    if qc is None or qc.empty:
        return []
    failed = qc[~qc.passed.astype(bool)]
    if failed.empty:
        return [f"  quality checks: all {len(qc)} passed"]
    lines = [f"  quality checks FAILED: {', '.join(failed.check)} (qc.parquet)"]
    for row in failed.itertuples():
        tail = f": {row.suggestion}" if row.suggestion else ""
        lines.append(f"    {row.check} ({row.severity}) "
                     f"{comparison_text(row.value, row.threshold, row.unit)}{tail}")
    return lines
