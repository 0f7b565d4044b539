"""Render the run report as one self-contained HTML page from the output tables alone.

``render_report(tables)`` takes a mapping of table name -> DataFrame (as read back from the
run folder by :func:`pospp.io.parquet_tables.read_table`) and returns the HTML text; figures
are drawn as SVG by :mod:`pospp.report.svg` and embedded as base64 data (a matplotlib figure,
compare-sim's, as PNG) so the page is a single file that opens anywhere.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from pospp.outputs import not_observable
from pospp.report import figures, svg
from pospp.report.summary import (
    BODY_AXES,
    Headline,
    group_messages,
    headline,
    pm_text,
    run_start_ns,
    unit_text,
    utc_text,
)

_CSS = """
body{font-family:system-ui,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em auto;max-width:1100px;
color:#222;padding:0 1em}
h1{border-bottom:2px solid #246;padding-bottom:.2em;font-size:1.5em}h2{color:#246;margin-top:1.6em}
.tw{max-width:100%;overflow-x:auto}.tw.tall{max-height:28em;overflow-y:auto}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0}
td,th{border:1px solid #ccc;padding:.25em .5em;text-align:right;white-space:nowrap}
td.l,th.l{text-align:left;white-space:normal;overflow-wrap:break-word;min-width:6em}
th{background:#eef;position:sticky;top:0}img{max-width:100%;height:auto;border:1px solid #eee}
.warn{color:#a40}.err{color:#b00;font-weight:bold}.muted{color:#777}.ok{color:#161}
.answer{border:2px solid #246;border-radius:6px;padding:.6em 1em;background:#f6f8fc}
.answer table{font-size:.95em}.flag{color:#a40;font-weight:bold}
.badge{display:inline-block;padding:.1em .6em;border-radius:4px;color:#fff;font-weight:bold}
.b-ok{background:#2a7}.b-partial{background:#c80}.b-degraded{background:#c60}
.b-failed{background:#b00}details{margin:.5em 0}summary{cursor:pointer;color:#246}
"""


_FIG = "svg"
"""Backend of the report's figures (:mod:`pospp.report.figures`)."""


def _img(fig: Any) -> str:
    """The figure as an ``<img>`` with its data inline: SVG text (pospp.report.svg) or, for a
    matplotlib figure, PNG at 80 dpi."""
    if isinstance(fig, svg.Figure):
        data = base64.b64encode(fig.to_svg().encode("utf-8")).decode("ascii")
        return (f'<img alt="figure" width="{fig.width_px:.0f}" height="{fig.height_px:.0f}" '
                f'src="data:image/svg+xml;base64,{data}"/>')
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    figures.pyplot().close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="figure" src="data:image/png;base64,{data}"/>'


def _cell(v: object, decimals: int | None = None) -> str:
    if v is None or v is pd.NA or (isinstance(v, float | np.floating) and not np.isfinite(v)):
        return "&ndash;"
    if isinstance(v, bool | np.bool_):
        return "yes" if v else "no"
    if isinstance(v, float | np.floating):
        if decimals is not None:
            return html.escape(f"{v:.{decimals}f}")
        a = abs(float(v))
        return html.escape(f"{v:.3g}" if a == 0 or 1e-3 <= a < 1e5 else f"{v:.2e}")
    return html.escape(str(v))


_PER_CELL = frozenset({"value", "threshold", "sigma", "statistic"})


def _decimals(col: pd.Series) -> int | None:
    """Fixed decimals for a float column: 4 significant digits at its largest value (None:
    too small for fixed notation)."""
    a = np.abs(col.to_numpy(dtype=float, na_value=np.nan))
    big = np.nanmax(a) if np.isfinite(a).any() else 0.0
    if big == 0.0:
        return 0
    dec = 3 - int(np.floor(np.log10(big)))
    return max(0, dec) if dec <= 6 else None


def _table(df: pd.DataFrame | None, *, max_rows: int = 60, tall: bool = False,
           left: tuple[str, ...] = ()) -> str:
    """An HTML table that scrolls inside the page (never widens it); ``max_rows`` rows, the
    rest counted; NaN shown as a dash, floats to 3 significant digits."""
    if df is None or df.empty:
        return '<p class="muted">(none)</p>'
    shown = df.head(max_rows)
    left_cols = set(left) | {c for c in shown.columns if shown[c].dtype == object and
                             shown[c].astype(str).str.len().max() > 24}
    head = "".join(f"<th class='{'l' if c in left_cols else ''}'>{html.escape(str(c))}</th>"
                   for c in shown.columns)
    # one unit per column: fixed decimals; long-form value columns (unit in a "unit" column)
    # are formatted cell by cell
    dec = [_decimals(shown[c]) if shown[c].dtype.kind == "f" and not (
        "unit" in shown and c in _PER_CELL) else None for c in shown.columns]
    rows = []
    for rec in shown.itertuples(index=False):
        rows.append("<tr>" + "".join(
            f"<td class='{'l' if c in left_cols else ''}'>{_cell(v, d)}</td>"
            for c, v, d in zip(shown.columns, rec, dec, strict=True)) + "</tr>")
    more = f'<p class="muted">{len(df) - max_rows} more rows</p>' if len(df) > max_rows else ""
    cls = "tw tall" if tall or len(shown) > 25 else "tw"
    return (f"<div class='{cls}'><table><thead><tr>{head}</tr></thead><tbody>"
            + "".join(rows) + "</tbody></table></div>" + more)


def _with_times(df: pd.DataFrame, t0_ns: int | None, cols: tuple[str, ...]) -> pd.DataFrame:
    """Replace int64 ns columns by "UTC" text and seconds since the run start."""
    out = df.copy()
    for c in cols:
        if c not in out:
            continue
        at = list(out.columns).index(c)
        stem = c[:-3] if c.endswith("_ns") else c
        utc = [utc_text(v, date=False) for v in out[c]]
        secs = [(float(v) - t0_ns) * 1e-9 if t0_ns is not None and not pd.isna(v)
                else float("nan") for v in out[c]]
        out = out.drop(columns=c)
        out.insert(at, f"{stem} t (s)", np.round(secs, 1))
        out.insert(at + 1, f"{stem} UTC", utc)
    return out


def _qc_section(qc: pd.DataFrame | None, summary: pd.DataFrame | None) -> list[str]:
    """Run status and the quality checks (qc.parquet), failed ones first, with suggestions."""
    if qc is None or qc.empty:
        return []
    status = str(summary.status.iloc[0]) if summary is not None and "status" in summary \
        and not summary.empty else "?"
    failed = qc[~qc.passed.astype(bool)]
    cls = "muted" if status == "ok" else ("err" if status == "failed" else "warn")
    parts = [f"<h2>Quality checks</h2><p class='{cls}'>status: {html.escape(status)}; "
             f"{len(qc) - len(failed)} of {len(qc)} checks passed"
             + (f"; failed: {html.escape(', '.join(failed.check))}" if len(failed) else "")
             + "</p>"]
    for row in failed.itertuples():
        if row.suggestion:
            parts.append(f"<p class='{cls}'>{html.escape(row.check)}: "
                         f"{html.escape(row.suggestion)}</p>")
    ordered = pd.concat([failed, qc[qc.passed.astype(bool)]])
    cols = [c for c in ("check", "passed", "value", "threshold", "unit", "severity", "measure")
            if c in ordered]  # runs written before a column existed still render
    # 'severity' is the status a failure of the check imposes, not the check's outcome
    shown = ordered[cols].rename(columns={"severity": "status if failed"})
    parts.append(_table(shown, left=("check", "measure")))
    return parts


def _pm(value: float, sigma: float, unit: str = "") -> str:
    """pm_text with a real plus-minus sign (HTML-escaped)."""
    return html.escape(pm_text(value, sigma, unit).replace(" +- ", " \u00b1 "))


_PM = " \u00b1 "


def _answer_section(h: Headline, tables: Mapping[str, pd.DataFrame]) -> list[str]:
    """The answer first: verdict, calibrated values with sigma, what was not observable and
    why, the improvement in-sample and held out (each labelled)."""
    st = html.escape(h.status)
    parts = ["<div class='answer' id='answer'><h2 style='margin-top:.2em'>The answer</h2>",
             f"<p><span class='badge b-{st}' id='status'>{st}</span> "
             f"<span id='qc-verdict'>{html.escape(h.qc_verdict)}</span></p>"]
    rows = []
    for e in h.results:
        what = ("the gyro bias over this flight's legs, which the compensation used"
                if e.name.startswith("gyro_bias") and e.name.endswith("_flight") else
                "the turn-on constant, for a next flight or a lab" if e.name.startswith(
                    "gyro_bias") else "calibrated")
        rows.append(f"<tr><th class='l'>{html.escape(e.name)}</th><td class='headline'>"
                    f"{_pm(e.value, e.sigma, e.unit)}</td><td class='l'>{what} "
                    f"({html.escape(h.formulation)} formulation, all pairs, 1-sigma; "
                    f"{html.escape(BODY_AXES)})</td></tr>")
    if h.sensor_axes:
        rows.append(f"<tr><th class='l'>gyro bias, IMU axes</th><td class='headline'>"
                    f"{html.escape(h.sensor_axes_text.replace(' +- ', _PM))}</td>"
                    f"<td class='l'>the same, in the IMU's axes "
                    f"({html.escape(h.sensor_axes_name)})</td></tr>")
    for e in h.refit:
        rows.append(f"<tr><th class='l'>{html.escape(e.name)}</th><td class='headline'>"
                    f"{_pm(e.value, e.sigma, e.unit)}</td><td class='l'>refitted with "
                    f"{html.escape(h.refit_effects.replace(';', ', '))} removed from B minus A "
                    "(the diagnosis named them outside the calibration's model); the "
                    "compensation uses it</td></tr>")
    for e in h.not_observable:
        rows.append(f"<tr><th class='l'>{html.escape(e.name)}</th><td class='flag'>not "
                    f"observable</td><td class='l'>{html.escape(e.why_not)}</td></tr>")
    if h.per_leg:
        rows.append(f"<tr><th class='l'>per-leg misalignments</th><td>"
                    f"{len(h.per_leg)} values</td><td class='l'>{html.escape(h.per_leg_text)}"
                    " (Calibration section)</td></tr>")
    if h.in_sample_text:
        rows.append("<tr><th class='l'>improvement, in-sample</th><td class='headline'>"
                    f"{h.dv_before_mps:.3g} &rarr; {h.dv_after_mps:.2g} m/s</td><td class='l'>"
                    f"{html.escape(h.in_sample_text)}</td></tr>")
        ho = (f"{h.gap_uncalibrated_mps:.3g} &rarr; {h.gap_heldout_mps:.2g} m/s"
              if np.isfinite(h.gap_heldout_mps) else "&ndash;")
        rows.append(f"<tr><th class='l'>improvement, held out</th><td class='headline'>{ho}"
                    f"</td><td class='l'>{html.escape(h.heldout_text)}</td></tr>")
    if not rows and h.calibration_reason:
        rows.append(f"<tr><th class='l'>calibration</th><td class='flag'>none</td>"
                    f"<td class='l'>{html.escape(h.calibration_reason)}</td></tr>")
    if rows:
        parts.append("<div class='tw'><table>" + "".join(rows) + "</table></div>")
    s = tables.get("summary")
    if s is not None and not s.empty:
        r = s.iloc[0]
        t0 = run_start_ns(tables)
        n_legs = r.get("n_legs")
        facts = [f"{float(r.duration_s):.0f} s of IMU data" if "duration_s" in r and
                 pd.notna(r.duration_s) else "",
                 f"from {utc_text(t0)} UTC" if t0 is not None else "",
                 f"{int(n_legs)} legs, {int(r.n_pairs_used)} pairs used"
                 if n_legs is not None and pd.notna(n_legs) and "n_pairs_used" in r
                 and pd.notna(r.n_pairs_used) else ""]
        parts.append(f"<p class='muted'>{html.escape(', '.join(f for f in facts if f))}</p>")
    parts.append("</div>")
    return parts


def _calibration_section(cal: pd.DataFrame, h: Headline) -> list[str]:
    parts = ["<h2>Calibration</h2>"]
    if cal.empty:
        return [*parts, f"<p class='warn'>{html.escape(h.calibration_reason)}</p>"]
    parts.append(_img(figures.calibration_bars(cal, backend=_FIG)))
    joint = cal[cal.pair_id == -1]
    order = [(f != h.formulation, "_leg" in p, p == "phi_z", not p.startswith(("gyro", "eps")))
             for f, p in zip(joint.formulation, joint.parameter, strict=True)]
    joint = joint.iloc[sorted(range(len(joint)), key=order.__getitem__)]
    rows = []
    for r in joint.itertuples():
        why = not_observable(r.parameter, r.sigma, r.unit)
        rows.append({"formulation": r.formulation + (" (applied)" if r.formulation ==
                                                     h.formulation else ""),
                     "parameter": r.parameter,
                     "value \u00b1 1-sigma": "not observable" if why else
                     pm_text(r.value, r.sigma).replace(" +- ", " \u00b1 "),
                     "unit": unit_text(r.unit), "note": why})
    parts.append("<h3>Joint fit over all used pairs</h3>"
                 + _table(pd.DataFrame(rows), max_rows=400, left=("parameter", "note")))
    pp = cal[cal.pair_id != -1]
    per_pair = pd.DataFrame({
        "pair_id": pp.pair_id, "formulation": pp.formulation, "parameter": pp.parameter,
        "value \u00b1 1-sigma": [pm_text(v, e).replace(" +- ", " \u00b1 ")
                                 for v, e in zip(pp.value, pp.sigma, strict=True)],
        "unit": pp.unit.map(unit_text)})
    parts.append(f"<details><summary>Per-pair fits ({len(per_pair)} rows)</summary>"
                 + _table(per_pair, max_rows=100_000, tall=True) + "</details>")
    return parts


def _diagnosis_section(diag: pd.DataFrame, curves: pd.DataFrame | None) -> list[str]:
    d = diag.sort_values("step")
    first, last = d.iloc[0], d.iloc[-1]
    named = d[~d.effect.isin(["none", "unexplained"])]
    text = (f"The calibrated model leaves an RMS velocity gap of {first.gap_before_mps:.2g} m/s "
            f"on the legs it was fitted to (in-sample) and {first.heldout_gap_before_mps:.2g} "
            "m/s predicting each leg from the others (held out). ")
    if len(named):
        text += ("Effects the data support, in order: " + ", ".join(
            f"{r.effect} ({_shape_prefix(r)}{pm_text(r.value, r.sigma, unit_text(r.unit))})"
            for r in named.itertuples())
            + f"; held-out gap after them {last.heldout_gap_after_mps:.2g} m/s. ")
    else:
        text += "No effect of the library is supported by the data. "
    text += ("The lack-of-fit test finds structure no tested effect explains "
             f"(p = {last.p_value:.2g})." if last.effect == "unexplained" else
             f"The lack-of-fit test finds no remaining structure (p = {last.p_value:.2g}).")
    text += _diagnosis_worth_text(d)
    parts = ["<h2>Model-discrepancy diagnosis</h2>", f"<p>{html.escape(text)}</p>"]
    if len(d) > 1:
        parts.append(_img(figures.diagnosis_steps(d, backend=_FIG)))
    if curves is not None and not curves.empty:
        parts.append(_img(figures.diagnosis_curves(curves, backend=_FIG)))
    shape = d["shape"].fillna("") if "shape" in d else pd.Series("", index=d.index)
    view = pd.DataFrame({
        "step": d.step, "effect": [f"{e} ({s})" if s else e for e, s in
                                   zip(d.effect, shape, strict=True)],
        "value \u00b1 1-sigma": [pm_text(r.value, r.sigma, r.unit).replace(" +- ", " \u00b1 ")
                                  if np.isfinite(r.value) else "" for r in d.itertuples()],
        "p-value": d.p_value, "test": d.criterion if "criterion" in d else "",
        "gap in-sample (m/s)": [f"{a:.3g} -> {b:.3g}" for a, b in
                                zip(d.gap_before_mps, d.gap_after_mps, strict=True)],
        "gap held out (m/s)": [f"{a:.3g} -> {b:.3g}" for a, b in
                               zip(d.heldout_gap_before_mps, d.heldout_gap_after_mps,
                                   strict=True)],
    })
    parts.append(_table(view))
    return parts


def _shape_prefix(row: Any) -> str:
    """"ramp: " for a family's row with a shape, "" otherwise."""
    shape = getattr(row, "shape", "")
    return f"{shape}: " if isinstance(shape, str) and shape else ""


def _diagnosis_worth_text(d: pd.DataFrame) -> str:
    """What each row is worth at the horizon against the calibration's residual."""
    if "gap_horizon_m" not in d or not np.isfinite(d.residual_horizon_m.iloc[-1]):
        return ""
    last = d.iloc[-1]
    rows = [f"{r.effect} {1e3 * r.gap_horizon_mps:.3g} mm/s, {r.gap_horizon_m:.3g} m"
            for r in d.itertuples() if np.isfinite(r.gap_horizon_m)]
    text = (f" What each row is worth at the {last.horizon_s:.0f} s horizon (B's error it "
            "causes beyond the model before it, RMS over the legs; closing row: the structured "
            f"gap left): {'; '.join(rows)}, against the calibration's own residual of "
            f"{1e3 * last.residual_horizon_mps:.3g} mm/s, {last.residual_horizon_m:.3g} m.")
    where = last.get("gap_location", "") if last.effect == "unexplained" else ""
    null = last.get("null_model", "")
    return (text + (f" {where}" if isinstance(where, str) and where else "")
            + (f" The p-values are calibrated on {null}." if isinstance(null, str) and null
               else ""))


def _messages_section(msgs: pd.DataFrame, t0_ns: int | None) -> list[str]:
    grouped = group_messages(msgs)
    view = _with_times(grouped, t0_ns, ("first_ns", "last_ns"))
    return [f"<h2>Messages and warnings</h2><p class='muted'>{len(msgs)} messages, "
            f"{len(grouped)} distinct (identical up to numbers: counted once, first and last "
            "time shown)</p>", _table(view, max_rows=300, left=("text",))]


def render_report(tables: Mapping[str, pd.DataFrame], *, title: str = "pospp run report") -> str:
    """HTML report of a run, the answer first; sections appear only for the tables present."""
    parts = [f"<!doctype html><html><head><meta charset='utf-8'>"
             "<meta name='viewport' content='width=device-width, initial-scale=1'>"
             f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
             f"<h1>{html.escape(title)}</h1>"]
    h = headline(tables)
    t0 = run_start_ns(tables)
    parts.extend(_answer_section(h, tables))
    parts.extend(_qc_section(tables.get("qc"), tables.get("summary")))
    cal = tables.get("calibration")
    if cal is not None:
        parts.extend(_calibration_section(cal, h))
    traj, legs = tables.get("trajectory"), tables.get("legs")
    biases = tables.get("biases")
    if (biases is not None and not biases.empty) or h.results:
        parts.append("<h2>Sensor errors: A's estimate over time and the calibration</h2>")
        calibrated = {e.name: (e.value, e.sigma) for e in h.results
                      if e.name.startswith("gyro_bias")}
        span_s = None if traj is None or traj.empty else float(
            (traj.time_ns.max() - traj.time_ns.min()) * 1e-9)
        parts.append(_img(figures.sensor_errors(biases, calibrated, span_s=span_s,
                                                   backend=_FIG)))
        if biases is None or biases.empty:
            parts.append("<p class='muted'>biases.parquet (A's bias estimates) is not in this "
                         "run: only the calibrated values are drawn.</p>")
    if traj is not None and not traj.empty:
        parts.append("<h2>Trajectory and legs</h2>")
        no_legs = pd.DataFrame(columns=["leg_id", "start_ns", "end_ns"])
        parts.append(_img(figures.trajectory_map(traj, legs if legs is not None else no_legs,
                                                 backend=_FIG)))
    if legs is not None:
        parts.append("<h3>Legs</h3>" + _table(_with_times(legs, t0, ("start_ns", "end_ns"))))
    le = tables.get("leg_errors")
    if le is not None and not le.empty:
        parts.append("<h2>Algorithm B error per leg, before and after compensation</h2>")
        parts.append(_img(figures.leg_error_curves(le, "velocity", backend=_FIG)))
        parts.append(_img(figures.leg_error_curves(le, "position", backend=_FIG)))
    pairs = tables.get("pairs")
    if pairs is not None:
        parts.append("<h2>Pairs and observability</h2>" + _table(pairs, left=("reason",)))
    obs = tables.get("observability")
    if obs is not None and not obs.empty:
        parts.append(_img(figures.observability_curves(obs, backend=_FIG)))
    diag = tables.get("diagnosis")
    if diag is not None and not diag.empty:
        parts.extend(_diagnosis_section(diag, tables.get("diagnosis_curves")))
    parts.extend(sim_comparison_section(tables.get("sim_comparison")))
    ev = tables.get("evaluation")
    if ev is not None and not ev.empty:
        wide = ev.pivot_table(index=["metric", "unit"], columns="solution", values="value")
        wide.columns = [str(c) for c in wide.columns]
        skip = ev.skip_s.dropna() if "skip_s" in ev else pd.Series(dtype=float)
        note = f" (first {skip.iloc[0]:g} s left out)" if len(skip) and skip.iloc[0] > 0 else ""
        parts.append(f"<h2>Against the reference{note}</h2>" + _table(wide.reset_index()))
    if traj is not None and not traj.empty:
        parts.append("<h2>Algorithm A's uncertainty</h2>"
                     + _img(figures.trajectory_sigmas(traj, backend=_FIG)))
    msgs = tables.get("messages")
    if msgs is not None:
        parts.extend(_messages_section(msgs, t0))
    summary = tables.get("summary")
    if summary is not None and not summary.empty:
        row = summary.iloc[0]
        kv = pd.DataFrame({"column": [str(k) for k in row.index],
                           "value": list(row.values)})
        parts.append("<details><summary>summary.parquet, every column</summary>"
                     + _table(kv, max_rows=200, left=("value",)) + "</details>")
    parts.append("<p class='muted'>Generated by pospp from the run's Parquet tables.</p>"
                 "</body></html>")
    return "\n".join(parts)


def sim_comparison_section(sc: pd.DataFrame | None) -> list[str]:
    """``pospp compare-sim``: the base model fitted to the log (step 0: each level with its
    sigma and prior), |gap| / sigma per statistic, base model versus the last step's model
    (figure), the steps (effect, fitted size, target gap before and after, the reading) and
    every statistic's gap (table)."""
    if sc is None or sc.empty:
        return []
    stats = sc[sc.kind == "statistic"]
    base = stats[stats.step == 0].set_index("measure")
    last_step = int(stats.step.max())
    last = stats[stats.step == last_step].set_index("measure")
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(9, 3.6))
    names = list(base.index)
    x = range(len(names))
    ax.bar([i - 0.2 for i in x], base.z_before.abs().reindex(names), 0.4,
           label="base model")
    if last_step > 0:
        ax.bar([i + 0.2 for i in x], last.z_after.abs().reindex(names), 0.4,
               label=f"after step {last_step}")
    ax.set_xticks(list(x), names, rotation=70, fontsize=7)
    ax.set_yscale("symlog", linthresh=3.0)
    ax.set_ylabel("|measured - simulated| / sigma")
    ax.legend(fontsize=8)
    fig.tight_layout()
    eff = sc[sc.kind == "effect"][["step", "measure", "effect", "parameter", "value", "sigma",
                                   "unit", "gap_before", "gap_after", "z_before", "z_after"]
                                  + (["note"] if "note" in sc else [])]
    eff = eff.assign(unit=eff["unit"].map(unit_text))
    cols = ["measure", "measured", "simulated_before", "gap_before", "sigma_gap", "z_before",
            "p_before", "significant_before"]
    out = ["<h2>Measured flight versus its simulation (compare-sim)</h2>"]
    if "kind" in sc and (sc.kind == "base").any():
        fit = sc[sc.kind == "base"][["parameter", "value", "sigma", "unit", "prior",
                                     "significant_before", "measure"]]
        fit = fit.rename(columns={"significant_before": "differs from prior",
                                  "measure": "measured on"})
        out += ["<h3>Base model fitted to the log (step 0)</h3>",
                _table(fit.assign(unit=fit["unit"].map(unit_text)))]
    return [*out, _img(fig), "<h3>Steps</h3>", _table(eff),
            "<h3>Gaps of the base model</h3>", _table(base.reset_index()[cols])]
