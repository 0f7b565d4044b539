"""Render the run report as one self-contained HTML page from the output tables alone.

``render_report(tables)`` takes a mapping of table name -> DataFrame (as read back from the
run folder by :func:`pospp.io.parquet_tables.read_table`) and returns the HTML text; figures
are embedded as base64 PNG so the page is a single file that opens anywhere.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Mapping

import matplotlib.pyplot as plt
import pandas as pd
from matplotlib.figure import Figure

from pospp.report import figures

_CSS = """
body{font-family:system-ui,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;
color:#222;padding:0 1em}
h1{border-bottom:2px solid #246;padding-bottom:.2em}h2{color:#246;margin-top:1.6em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0}
td,th{border:1px solid #ccc;padding:.25em .5em;text-align:right}
th{background:#eef}img{max-width:100%;border:1px solid #eee}
.warn{color:#a40}.err{color:#b00;font-weight:bold}.muted{color:#777}
"""


def _img(fig: Figure) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="figure" src="data:image/png;base64,{data}"/>'


def _table(df: pd.DataFrame, *, max_rows: int = 60, floatfmt: str = "{:.4g}") -> str:
    if df is None or df.empty:
        return '<p class="muted">(none)</p>'
    shown = df.head(max_rows)
    body = shown.to_html(index=False, float_format=lambda v: floatfmt.format(v), border=0,
                         escape=True)
    more = f'<p class="muted">{len(df) - max_rows} more rows</p>' if len(df) > max_rows else ""
    return body + more


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
    parts.append(_table(ordered[["check", "passed", "value", "threshold", "unit", "severity",
                                 "measure"]]))
    return parts


def render_report(tables: Mapping[str, pd.DataFrame], *, title: str = "pospp run report") -> str:
    """HTML report of a run; sections appear only for the tables present."""
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
             f"</title><style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"]
    parts.extend(_qc_section(tables.get("qc"), tables.get("summary")))
    summary = tables.get("summary")
    if summary is not None and not summary.empty:
        row = summary.iloc[0]
        parts.append("<h2>Summary</h2><table>")
        for k, v in row.items():
            text = f"{v:.4g}" if isinstance(v, float) else str(v)
            parts.append(f"<tr><th style='text-align:left'>{html.escape(str(k))}</th>"
                         f"<td>{html.escape(text)}</td></tr>")
        parts.append("</table>")
    traj, legs = tables.get("trajectory"), tables.get("legs")
    if traj is not None and not traj.empty:
        parts.append("<h2>Trajectory and legs</h2>")
        parts.append(_img(figures.trajectory_map(traj, legs if legs is not None else
                                                 pd.DataFrame(columns=["leg_id", "start_ns",
                                                                       "end_ns"]))))
        parts.append(_img(figures.trajectory_sigmas(traj)))
    if legs is not None:
        parts.append("<h3>Legs</h3>" + _table(legs))
    pairs = tables.get("pairs")
    if pairs is not None:
        parts.append("<h2>Pairs and observability</h2>" + _table(pairs))
    obs = tables.get("observability")
    if obs is not None and not obs.empty:
        parts.append(_img(figures.observability_curves(obs)))
    cal = tables.get("calibration")
    if cal is not None:
        parts.append("<h2>Calibration</h2>")
        if not cal.empty:
            parts.append(_img(figures.calibration_bars(cal)))
        parts.append(_table(cal, max_rows=200))
    le = tables.get("leg_errors")
    if le is not None and not le.empty:
        parts.append("<h2>Algorithm B error per leg, before and after compensation</h2>")
        parts.append(_img(figures.leg_error_curves(le, "velocity")))
        parts.append(_img(figures.leg_error_curves(le, "position")))
    diag = tables.get("diagnosis")
    if diag is not None and not diag.empty:
        parts.append("<h2>Model-discrepancy diagnosis</h2>")
        parts.append(_img(figures.diagnosis_steps(diag)) + _table(diag))
        curves = tables.get("diagnosis_curves")
        if curves is not None and not curves.empty:
            parts.append(_img(figures.diagnosis_curves(curves)))
    parts.extend(sim_comparison_section(tables.get("sim_comparison")))
    ev = tables.get("evaluation")
    if ev is not None and not ev.empty:
        wide = ev.pivot_table(index=["metric", "unit"], columns="solution", values="value")
        parts.append("<h2>Against the reference</h2>" + _table(wide.reset_index()))
    msgs = tables.get("messages")
    if msgs is not None:
        parts.append("<h2>Messages and warnings</h2>" + _table(msgs, max_rows=200))
    parts.append("<p class='muted'>Generated by pospp from the run's Parquet tables.</p>"
                 "</body></html>")
    return "\n".join(parts)


def sim_comparison_section(sc: pd.DataFrame | None) -> list[str]:
    """``pospp compare-sim``: |gap| / sigma per statistic, configured model versus the last
    step's model (figure), the steps (effect, fitted size, target gap before and after) and
    every statistic's gap (table)."""
    if sc is None or sc.empty:
        return []
    stats = sc[sc.kind == "statistic"]
    base = stats[stats.step == 0].set_index("measure")
    last_step = int(stats.step.max())
    last = stats[stats.step == last_step].set_index("measure")
    fig, ax = plt.subplots(figsize=(9, 3.6))
    names = list(base.index)
    x = range(len(names))
    ax.bar([i - 0.2 for i in x], base.z_before.abs().reindex(names), 0.4,
           label="configured model")
    if last_step > 0:
        ax.bar([i + 0.2 for i in x], last.z_after.abs().reindex(names), 0.4,
               label=f"after step {last_step}")
    ax.set_xticks(list(x), names, rotation=70, fontsize=7)
    ax.set_yscale("symlog", linthresh=3.0)
    ax.set_ylabel("|measured - simulated| / sigma")
    ax.legend(fontsize=8)
    fig.tight_layout()
    eff = sc[sc.kind == "effect"][["step", "measure", "effect", "parameter", "value", "sigma",
                                   "unit", "gap_before", "gap_after", "z_before", "z_after"]]
    cols = ["measure", "measured", "simulated_before", "gap_before", "sigma_gap", "z_before",
            "p_before", "significant_before"]
    return ["<h2>Measured flight versus its simulation (compare-sim)</h2>",
            _img(fig), "<h3>Steps</h3>", _table(eff),
            "<h3>Gaps of the configured model</h3>", _table(base.reset_index()[cols])]
