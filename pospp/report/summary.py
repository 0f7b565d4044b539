"""The one-screen text summary of a run, from its tables alone (what ``pospp run`` prints)."""

from __future__ import annotations

from collections.abc import Mapping

import pandas as pd


def _fmt(v: object, spec: str = ".3g") -> str:
    try:
        return "n/a" if v is None or pd.isna(v) else format(v, spec)
    except (TypeError, ValueError):
        return str(v)


def summary_text(tables: Mapping[str, pd.DataFrame]) -> str:
    """Legs found, pairs used, calibrated values with sigma, B's error before/after."""
    lines: list[str] = []
    s = tables.get("summary")
    if s is not None and not s.empty:
        r = s.iloc[0]
        lines.append(f"pospp run: {r.get('input_file')}  status: {r.get('status')}")
        lines.extend(qc_lines(tables.get("qc")))
        lines.append(f"  data: {_fmt(r.get('duration_s'), '.1f')} s of IMU at "
                     f"{_fmt(r.get('imu_rate_hz'), '.0f')} Hz, "
                     f"{_fmt(r.get('n_gnss_fixes'), 'd')} GNSS fixes")
    legs = tables.get("legs")
    if legs is not None:
        lines.append(f"  legs: {len(legs)} straight uniform legs")
        for row in legs.itertuples():
            lines.append(f"    leg {row.leg_id}: {row.duration_s:6.0f} s  heading "
                         f"{row.heading_deg:6.1f} deg  speed {row.speed_mps:5.1f} m/s")
    pairs = tables.get("pairs")
    if pairs is not None:
        used = int(pairs.used.sum()) if len(pairs) else 0
        lines.append(f"  pairs: {used} used of {len(pairs)}")
        for row in pairs.itertuples():
            lines.append(f"    pair {row.pair_id} (legs {row.leg_a},{row.leg_b}): dH "
                         f"{row.dheading_deg:5.1f} deg  cond {row.cond_scaled:8.3g}  "
                         f"{'used' if row.used else 'rejected'}: {row.reason}")
    cal = tables.get("calibration")
    if cal is not None and not cal.empty:
        joint = cal[cal.pair_id == -1] if (cal.pair_id == -1).any() else cal
        lines.append("  calibration (all pairs combined):")
        for row in joint.itertuples():
            lines.append(f"    {row.formulation:6s} {row.parameter:14s} {row.value:+10.4g} "
                         f"+- {row.sigma:.3g} {row.unit}")
    if s is not None and not s.empty:
        r = s.iloc[0]
        if "dv_before_mps" in r and not pd.isna(r.get("dv_before_mps")):
            lines.append(
                f"  B error at the horizon: velocity {_fmt(r.get('dv_before_mps'))} -> "
                f"{_fmt(r.get('dv_after_mps'))} m/s, position {_fmt(r.get('dp_before_m'))} -> "
                f"{_fmt(r.get('dp_after_m'))} m")
    msgs = tables.get("messages")
    if msgs is not None and len(msgs):
        n_err = int((msgs.severity == "error").sum())
        n_warn = int((msgs.severity == "warning").sum())
        lines.append(f"  messages: {n_err} errors, {n_warn} warnings (messages.parquet)")
        for row in msgs[msgs.stage == "calibrate"].itertuples():
            lines.append(f"    {row.severity}: {row.text}")
    return "\n".join(lines)


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
        lines.append(f"    {row.check} ({row.severity}) {_fmt(row.value, '.4g')} > "
                     f"{_fmt(row.threshold, '.4g')} {row.unit}{tail}")
    return lines
