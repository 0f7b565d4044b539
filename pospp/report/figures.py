"""Report figures, drawn from the output tables alone (pandas DataFrames in, Figures out).

Nothing here reads or writes files: :mod:`pospp.report.html` embeds the figures, and
:mod:`pospp.io` writes the page. Column names are the documented output schemas
(docs/formats.md).

Every figure function takes ``backend``: "mpl" (default) returns a matplotlib Figure (Agg;
matplotlib is imported at the first such call), "svg" a :class:`pospp.report.svg.Figure`
drawn by pospp's own SVG writer through the same calls. The HTML report uses "svg" (no
matplotlib import in a run: docs/history/speed_rounds.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from pospp.report import svg
from pospp.units import ARCSEC_RAD

Figure = Any  # a matplotlib Figure or a pospp.report.svg.Figure

_R_M = 6371000.0  # mean Earth radius, only to draw a local map in metres

# matplotlib's tab10, then tab20's lighter ten, then tab20b's and tab20c's even entries
_LEG_PALETTE = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
    "#bcbd22", "#17becf", "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5", "#c49c94",
    "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5", "#393b79", "#6b6ecf", "#637939", "#b5cf6b",
    "#8c6d31", "#e7ba52", "#843c39", "#d6616b", "#7b4173", "#ce6dbd", "#3182bd", "#9ecae1",
    "#e6550d", "#fdae6b", "#31a354", "#a1d99b", "#756bb1", "#bcbddc", "#636363", "#bdbdbd")


def pyplot() -> Any:
    """matplotlib.pyplot with the Agg backend (imported at the first call: about 0.7 s)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def subplots(backend: str, *args: Any, **kw: Any) -> tuple[Any, Any]:
    """``pyplot.subplots`` of the backend: "mpl" (pyplot with Agg), "svg" (the report's own
    writer) or "figure" (a plain matplotlib ``Figure``, outside pyplot: no global backend is
    set, so a notebook's stays as it was; ``pospp.api``'s plots)."""
    if backend == "svg":
        return svg.subplots(*args, **kw)
    if backend == "figure":
        from matplotlib.figure import Figure as PlainFigure

        size = {k: kw.pop(k) for k in ("figsize", "dpi") if k in kw}
        fig = PlainFigure(**size)
        return fig, fig.subplots(*args, **kw)
    if backend != "mpl":
        raise ValueError(f"unknown figure backend {backend!r} (mpl, svg, figure)")
    return pyplot().subplots(*args, **kw)


def _thin(df: pd.DataFrame, max_points: int = 4000) -> pd.DataFrame:
    """Every k-th row so that a plotted series has at most ``max_points`` (a 1.5 h flight at
    10 Hz is 54,000 epochs per solution: more than a figure can show, and slow to draw)."""
    step = max(1, -(-len(df) // max_points))
    return df.iloc[::step]


def _local_en_m(lat_deg: np.ndarray, lon_deg: np.ndarray, lat0: float, lon0: float
                ) -> tuple[np.ndarray, np.ndarray]:
    e = np.radians(lon_deg - lon0) * _R_M * np.cos(np.radians(lat0))
    n = np.radians(lat_deg - lat0) * _R_M
    return e, n


def leg_colors(n: int) -> list[tuple[float, float, float, float]]:
    """``n`` colours for legs (RGBA in [0, 1]): tab10's ten, then tab20's lighter ten, then
    tab20b and tab20c (40 distinct before any repeats; every leg is also labelled with its
    number)."""
    base = [(int(h[1:3], 16) / 255.0, int(h[3:5], 16) / 255.0, int(h[5:7], 16) / 255.0)
            for h in _LEG_PALETTE]
    return [(*base[i % len(base)], 1.0) for i in range(n)]


def _label_ends(ax: Any, curves: list[tuple[np.ndarray, np.ndarray, str, tuple]]) -> None:
    """Write each curve's label at its last point, in its colour (readable past ten legs)."""
    for x, y, text, color in curves:
        if len(x):
            ax.annotate(text, (x[-1], y[-1]), fontsize=7, color=color, xytext=(2, 0),
                        textcoords="offset points", va="center")


def _unit(unit: str) -> str:
    return {"deg_per_h": "deg/h"}.get(unit, unit.replace("_per_", "/"))


def trajectory_map(trajectory: pd.DataFrame, legs: pd.DataFrame, *, backend: str = "mpl"
                   ) -> Figure:
    """Map of the smoothed (or forward) trajectory, legs coloured and numbered."""
    fig, ax = subplots(backend, figsize=(7.5, 6.0))
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.09, top=0.93)
    sol = "smoothed" if (trajectory.solution == "smoothed").any() else "forward"
    tr = _thin(trajectory[trajectory.solution == sol], 3000)
    lat0, lon0 = float(tr.lat_deg.iloc[0]), float(tr.lon_deg.iloc[0])
    e, n = _local_en_m(tr.lat_deg.to_numpy(), tr.lon_deg.to_numpy(), lat0, lon0)
    ax.plot(e / 1e3, n / 1e3, color="0.6", lw=0.8, label=f"{sol} trajectory")
    colors = leg_colors(len(legs))
    t = tr.time_ns.to_numpy()
    for i, leg in enumerate(legs.itertuples()):
        m = (t >= leg.start_ns) & (t <= leg.end_ns)
        if not m.any():
            continue
        ax.plot(e[m] / 1e3, n[m] / 1e3, color=colors[i], lw=2.5)
        k = np.flatnonzero(m)[m.sum() // 2]
        ax.annotate(str(leg.leg_id), (e[k] / 1e3, n[k] / 1e3), fontsize=9, weight="bold",
                    color=colors[i], xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel("east (km)")
    ax.set_ylabel("north (km)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("Trajectory and straight legs (numbered)")
    ax.grid(alpha=0.3)
    return fig


def leg_error_curves(leg_errors: pd.DataFrame, quantity: str, *, backend: str = "mpl"
                     ) -> Figure:
    """B minus A per leg, before and after compensation (paper Fig. 8, 9, 13, 14), one scale
    per column so that before and after compare at a glance; each curve labelled with its leg.

    ``quantity`` is "velocity" (dvn_mps, dve_mps) or "position" (dpn_m, dpe_m).
    """
    cols, unit = (("dvn_mps", "dve_mps"), "m/s") if quantity == "velocity" else (
        ("dpn_m", "dpe_m"), "m")
    fig, axes = subplots(backend, 2, 2, figsize=(10, 6.5), sharex=True, sharey="col")
    fig.subplots_adjust(left=0.08, right=0.97, bottom=0.08, top=0.9, hspace=0.25, wspace=0.2)
    ids = sorted(leg_errors.leg_id.unique())
    colors = dict(zip(ids, leg_colors(len(ids)), strict=True))
    for row, stage in enumerate(("before", "after")):
        d = leg_errors[leg_errors.stage == stage]
        for col, (c, name) in enumerate(zip(cols, ("north", "east"), strict=True)):
            ax = axes[row, col]
            curves = []
            for leg_id, g in d.groupby("leg_id"):
                x, y = g.t_s.to_numpy(), g[c].to_numpy()
                ax.plot(x, y, color=colors[leg_id], lw=1.1)
                curves.append((x, y, str(leg_id), colors[leg_id]))
            _label_ends(ax, curves)
            ax.set_title(f"{name} {quantity} error, {stage} compensation", fontsize=10)
            ax.set_ylabel(f"B minus A ({unit})")
            ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time since leg start (s)")
    fig.suptitle(f"B's {quantity} error per leg (curves labelled with the leg number; "
                 "same scale before and after)", fontsize=10)
    return fig


def calibration_bars(calibration: pd.DataFrame, *, backend: str = "mpl") -> Figure:
    """Calibrated values with 1-sigma error bars, per pair and formulation."""
    params = [p for p in ("gyro_bias_x", "gyro_bias_y", "eps_n", "eps_e")
              if p in set(calibration.parameter)]
    n_ax = max(1, len(params))
    fig, axes = subplots(backend, 1, n_ax, figsize=(3.2 * n_ax, 3.8))
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.22, top=0.82, wspace=0.35)
    axes = np.atleast_1d(axes)
    for ax, p in zip(axes, params, strict=False):
        d = calibration[calibration.parameter == p].reset_index(drop=True)
        labels = ["all" if r.pair_id == -1 else str(r.pair_id) for r in d.itertuples()]
        joint = (d.pair_id == -1).to_numpy()
        x = np.arange(len(d))
        ax.errorbar(x[~joint], d.value[~joint], yerr=d.sigma[~joint], fmt="o", ms=3,
                    capsize=2, color="C0")
        ax.errorbar(x[joint], d.value[joint], yerr=d.sigma[joint], fmt="s", ms=5, capsize=3,
                    color="C3")
        step = max(1, len(d) // 16)
        ax.set_xticks(x[::step], labels[::step], fontsize=7)
        unit = _unit(d.unit.iloc[0]) if len(d) else ""
        ax.set_title(f"{p} ({unit}), {d.formulation.iloc[0] if len(d) else ''}", fontsize=9)
        ax.set_xlabel("pair (all = joint fit)", fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle("Calibrated drift per pair and joint (red), 1-sigma bars", fontsize=10)
    return fig


def observability_curves(observability: pd.DataFrame, *, backend: str = "mpl") -> Figure:
    """Condition number versus heading difference (Fig. 4) and speed difference (Fig. 5)."""
    fig, (a1, a2) = subplots(backend, 1, 2, figsize=(10, 4))
    d0 = observability[observability.dspeed_mps == 0.0]
    for form, g in d0.groupby("formulation"):
        a1.semilogy(g.dheading_deg, g.cond_scaled, "o-", ms=3, label=f"{form} (scaled)")
    a1.set_xlabel("heading difference dH [deg]")
    a1.set_ylabel("condition number")
    a1.set_title("Fig. 4: cond vs dH at equal speed")
    a1.grid(alpha=0.3, which="both")
    a1.legend(fontsize=8)
    paper = observability[observability.formulation == "paper"]
    for dh, g in paper.groupby("dheading_deg"):
        if dh in (0.0, 30.0, 90.0, 180.0) or len(paper.dheading_deg.unique()) <= 4:
            a2.semilogy(g.dspeed_mps, g.cond_scaled, "o-", ms=3, label=f"dH = {dh:g} deg")
    a2.set_xlabel("speed difference dV [m/s]")
    a2.set_title("Fig. 5: cond vs dV (paper formulation)")
    a2.grid(alpha=0.3, which="both")
    a2.legend(fontsize=8)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.13, top=0.9, wspace=0.25)
    return fig


def trajectory_sigmas(trajectory: pd.DataFrame, *, backend: str = "mpl") -> Figure:
    """Position and attitude standard deviations over time, forward versus smoothed."""
    fig, (a1, a2) = subplots(backend, 2, 1, figsize=(10, 5.5), sharex=True)
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.1, top=0.97, hspace=0.1)
    t0 = trajectory.time_ns.min()
    for sol, g in trajectory.groupby("solution"):
        g = _thin(g, 2000)
        t = (g.time_ns - t0) * 1e-9
        if "north_sigma_m" in g:
            a1.semilogy(t, np.hypot(g.north_sigma_m, g.east_sigma_m), label=f"{sol} horiz.")
        if "yaw_sigma_deg" in g:
            a2.semilogy(t, g.yaw_sigma_deg * 3600, label=f"{sol} yaw")
            a2.semilogy(t, g.roll_sigma_deg * 3600, ls="--", label=f"{sol} roll")
    a1.set_ylabel("position sigma (m)")
    a2.set_ylabel("attitude sigma (arcsec)")
    a2.set_xlabel("time since start (s)")
    for a in (a1, a2):
        a.grid(alpha=0.3, which="both")
        a.legend(fontsize=8)
    return fig


def diagnosis_steps(diagnosis: pd.DataFrame, *, backend: str = "mpl") -> Figure:
    """Gap before and after each step of the model-discrepancy workflow."""
    fig, ax = subplots(backend, figsize=(7, 3.8))
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.25, top=0.95)
    x = np.arange(len(diagnosis))
    ax.bar(x - 0.2, diagnosis.gap_before_mps, 0.4, label="fit residual before")
    ax.bar(x + 0.2, diagnosis.gap_after_mps, 0.4, label="fit residual after")
    ax.plot(x, diagnosis.heldout_gap_after_mps, "ko-", label="held-out gap after")
    ax.set_xticks(x, diagnosis.effect, rotation=30, fontsize=8)
    ax.set_ylabel("RMS velocity gap (m/s)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def evaluation_errors(errors: dict, *, t0_ns: int | None = None, skip_s: float = 0.0,
                      backend: str = "mpl") -> Figure:
    """Solution minus reference over time: horizontal position, velocity, tilt and heading.

    ``errors`` maps a solution name to a :class:`pospp.evaluate.SolutionErrors` (SI, NED).
    Epochs within ``skip_s`` of each solution's first are left out, as in the evaluation
    table, so that the alignment does not set the scale.
    """
    fig, axes = subplots(backend, 4, 1, figsize=(10, 8), sharex=True)
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.07, top=0.95, hspace=0.12)
    t0 = t0_ns if t0_ns is not None else min(int(e.time_ns[0]) for e in errors.values())
    arcsec = ARCSEC_RAD
    for name, e in errors.items():
        keep = e.time_ns >= e.time_ns[0] + int(round(skip_s * 1e9))
        step = max(1, -(-int(keep.sum()) // 4000))
        idx = np.flatnonzero(keep)[::step]
        t = (e.time_ns[idx] - t0) * 1e-9
        pos, vel, att = e.pos_ned_m[idx], e.vel_ned_mps[idx], e.att_ned_rad[idx]
        axes[0].plot(t, np.hypot(pos[:, 0], pos[:, 1]), lw=0.8, label=name)
        axes[1].plot(t, np.hypot(vel[:, 0], vel[:, 1]), lw=0.8)
        axes[2].plot(t, np.hypot(att[:, 0], att[:, 1]) / arcsec, lw=0.8)
        axes[3].plot(t, att[:, 2] / arcsec, lw=0.8)
    labels = ("horizontal position (m)", "horizontal velocity (m/s)", "tilt (arcsec)",
              "heading phi_D (arcsec)")
    for ax, lab in zip(axes, labels, strict=True):
        ax.set_ylabel(lab, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    skipped = f" (first {skip_s:g} s left out)" if skip_s > 0 else ""
    axes[0].set_title(f"Solution minus reference{skipped}")
    axes[-1].set_xlabel("time since start (s)")
    return fig


def diagnosis_curves(curves: pd.DataFrame, *, backend: str = "mpl") -> Figure:
    """The gap over time per leg: B minus A minus the model, before and after the diagnosis
    (fitted and held-out), horizontal magnitude; each leg labelled at its end."""
    fig, axes = subplots(backend, 1, 2, figsize=(10, 3.8), sharey=True)
    fig.subplots_adjust(left=0.08, right=0.97, bottom=0.14, top=0.9, wspace=0.08)
    ids = sorted(curves.leg_id.unique())
    colors = dict(zip(ids, leg_colors(len(ids)), strict=True))
    for ax, kind in zip(axes, ("fit", "heldout"), strict=True):
        g = curves[curves.kind == kind]
        ends = []
        for leg, gl in g.groupby("leg_id"):
            for model, ls in (("before", "--"), ("after", "-")):
                c = gl[gl.model == model]
                y = np.hypot(c.dvn_mps, c.dve_mps).to_numpy()
                ax.plot(c.t_s, y, ls=ls, color=colors[leg], lw=1)
            ends.append((c.t_s.to_numpy(), y, str(leg), colors[leg]))
        _label_ends(ax, ends)
        ax.set_title(f"gap, {'fitted (in-sample)' if kind == 'fit' else 'held out'}; "
                     "dashed: calibration only, solid: with the effects found", fontsize=9)
        ax.set_xlabel("time since leg start (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("|B - A - model| (m/s)")
    return fig


def sensor_errors(biases: pd.DataFrame | None, calibrated: dict[str, tuple[float, float]],
                  *, span_s: float | None = None, backend: str = "mpl") -> Figure:
    """Algorithm A's estimated gyro (and accelerometer) biases over time with their 1-sigma
    band, beside the calibrated constant gyro bias (dashed line and band).

    ``biases``: the ``biases`` table (time_ns, solution, gyro_bias_x_dph, ...,
    accel_bias_z_ug and ``*_sigma`` columns) or None; ``calibrated``: parameter name
    ("gyro_bias_x", ...) -> (value, sigma) in deg/h; ``span_s``: the run's length (the time
    axis when there is no ``biases`` table).
    """
    has_accel = biases is not None and any(c.startswith("accel_bias") for c in biases)
    fig, axes = subplots(backend, 2 if has_accel else 1, 1,
                         figsize=(10, 5.5 if has_accel else 3.2), sharex=True, squeeze=False)
    axes = axes[:, 0]
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.12 if not has_accel else 0.08,
                        top=0.9, hspace=0.12)
    t0 = None
    if biases is not None and not biases.empty:
        sols = list(dict.fromkeys(biases.solution))
        sol = next((s for s in ("smoothed", "forward") if s in sols), sols[0])
        b = _thin(biases[biases.solution == sol], 2000)
        t0 = int(b.time_ns.min())
        t = (b.time_ns.to_numpy() - t0) * 1e-9
        for row, (kind, unit) in enumerate((("gyro", "deg/h"), ("accel", "ug"))[:len(axes)]):
            ax = axes[row]
            for i, axn in enumerate("xyz"):
                col = f"{kind}_bias_{axn}_{'dph' if kind == 'gyro' else 'ug'}"
                if col not in b:
                    continue
                v = b[col].to_numpy(dtype=float)
                ax.plot(t, v, color=f"C{i}", lw=1, label=f"A ({sol}) {axn}")
                sc = col.replace("_dph", "_sigma_dph").replace("_ug", "_sigma_ug")
                if sc in b:
                    sg = b[sc].to_numpy(dtype=float)
                    ax.fill_between(t, v - sg, v + sg, color=f"C{i}", alpha=0.15, lw=0)
            ax.set_ylabel(f"{kind} bias ({unit})")
            ax.grid(alpha=0.3)
        axes[-1].set_xlabel("time since start (s)")
    else:
        axes[0].set_xlabel("time since start (s); A's bias estimates are not in this run")
        if span_s:
            axes[0].set_xlim(0.0, span_s)
    for i, axn in enumerate("xyz"):
        if f"gyro_bias_{axn}" in calibrated:
            v, sg = calibrated[f"gyro_bias_{axn}"]
            axes[0].axhline(v, color=f"C{i}", ls="--", lw=1.5, label=f"calibrated {axn}")
            axes[0].axhspan(v - sg, v + sg, color=f"C{i}", alpha=0.1)
    axes[0].set_ylabel("gyro bias (deg/h)")
    axes[0].legend(fontsize=7, ncol=3, loc="upper right")
    axes[0].set_title("Gyro bias: A's estimate over time (solid, 1-sigma band) and the "
                      "calibration (dashed)", fontsize=10)
    return fig
