"""Report figures, drawn from the output tables alone (pandas DataFrames in, Figures out).

Nothing here reads or writes files: :mod:`pospp.report.html` embeds the figures, and
:mod:`pospp.io` writes the page. Column names are the documented output schemas
(docs/formats.md).
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

_R_M = 6371000.0  # mean Earth radius, only to draw a local map in metres


def _thin(df: pd.DataFrame, max_points: int = 4000) -> pd.DataFrame:
    """Every k-th row so that a plotted series has at most ``max_points`` (a 1.5 h flight at
    10 Hz is 54,000 epochs per solution: more than a figure can show, and slow to draw)."""
    step = max(1, -(-len(df) // max_points))
    return df.iloc[::step]


def _local_en_m(lat_deg: np.ndarray, lon_deg: np.ndarray, lat0: float, lon0: float):
    e = np.radians(lon_deg - lon0) * _R_M * np.cos(np.radians(lat0))
    n = np.radians(lat_deg - lat0) * _R_M
    return e, n


def trajectory_map(trajectory: pd.DataFrame, legs: pd.DataFrame) -> Figure:
    """Map of the smoothed (or forward) trajectory, legs coloured and numbered."""
    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    sol = "smoothed" if (trajectory.solution == "smoothed").any() else "forward"
    tr = _thin(trajectory[trajectory.solution == sol])
    lat0, lon0 = float(tr.lat_deg.iloc[0]), float(tr.lon_deg.iloc[0])
    e, n = _local_en_m(tr.lat_deg.to_numpy(), tr.lon_deg.to_numpy(), lat0, lon0)
    ax.plot(e / 1e3, n / 1e3, color="0.6", lw=0.8, label=f"{sol} trajectory")
    cmap = plt.get_cmap("tab10")
    t = tr.time_ns.to_numpy()
    for i, leg in enumerate(legs.itertuples()):
        m = (t >= leg.start_ns) & (t <= leg.end_ns)
        if not m.any():
            continue
        ax.plot(e[m] / 1e3, n[m] / 1e3, color=cmap(i % 10), lw=2.5)
        k = np.flatnonzero(m)[m.sum() // 2]
        ax.annotate(str(leg.leg_id), (e[k] / 1e3, n[k] / 1e3), fontsize=10, weight="bold",
                    color=cmap(i % 10), xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel("east [km]")
    ax.set_ylabel("north [km]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("Trajectory and straight legs (numbered)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def leg_error_curves(leg_errors: pd.DataFrame, quantity: str) -> Figure:
    """B minus A per leg, before and after compensation (paper Fig. 8, 9, 13, 14).

    ``quantity`` is "velocity" (dvn_mps, dve_mps) or "position" (dpn_m, dpe_m).
    """
    cols, unit = (("dvn_mps", "dve_mps"), "m/s") if quantity == "velocity" else (
        ("dpn_m", "dpe_m"), "m")
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    cmap = plt.get_cmap("tab10")
    for row, stage in enumerate(("before", "after")):
        d = leg_errors[leg_errors.stage == stage]
        for col, (c, name) in enumerate(zip(cols, ("north", "east"), strict=True)):
            ax = axes[row, col]
            for i, (leg_id, g) in enumerate(d.groupby("leg_id")):
                ax.plot(g.t_s, g[c], color=cmap(i % 10), lw=1.2, label=f"leg {leg_id}")
            ax.set_title(f"{name} {quantity} error, {stage} compensation")
            ax.set_ylabel(unit)
            ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time since leg start [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper right", fontsize=8, ncol=1)
    fig.tight_layout(rect=(0, 0, 0.9, 1))
    return fig


def calibration_bars(calibration: pd.DataFrame) -> Figure:
    """Calibrated values with 1-sigma error bars, per pair and formulation."""
    params = [p for p in ("gyro_bias_x", "gyro_bias_y", "eps_n", "eps_e")
              if p in set(calibration.parameter)]
    fig, axes = plt.subplots(1, max(1, len(params)), figsize=(3.2 * max(1, len(params)), 3.8))
    axes = np.atleast_1d(axes)
    for ax, p in zip(axes, params, strict=False):
        d = calibration[calibration.parameter == p].reset_index(drop=True)
        labels = [f"{r.pair_id}/{r.formulation[:1]}" for r in d.itertuples()]
        ax.errorbar(np.arange(len(d)), d.value, yerr=d.sigma, fmt="o", capsize=3)
        ax.set_xticks(np.arange(len(d)), labels, rotation=60, fontsize=7)
        unit = d.unit.iloc[0] if len(d) else ""
        ax.set_title(f"{p} [{unit}]")
        ax.grid(alpha=0.3)
    fig.suptitle("Calibrated drift per pair (pair/formulation; -1 = joint fit)")
    fig.tight_layout()
    return fig


def observability_curves(observability: pd.DataFrame) -> Figure:
    """Condition number versus heading difference (Fig. 4) and speed difference (Fig. 5)."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
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
    fig.tight_layout()
    return fig


def trajectory_sigmas(trajectory: pd.DataFrame) -> Figure:
    """Position and attitude standard deviations over time, forward versus smoothed."""
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    t0 = trajectory.time_ns.min()
    for sol, g in trajectory.groupby("solution"):
        g = _thin(g)
        t = (g.time_ns - t0) * 1e-9
        if "north_sigma_m" in g:
            a1.semilogy(t, np.hypot(g.north_sigma_m, g.east_sigma_m), label=f"{sol} horiz.")
        if "yaw_sigma_deg" in g:
            a2.semilogy(t, g.yaw_sigma_deg * 3600, label=f"{sol} yaw")
            a2.semilogy(t, g.roll_sigma_deg * 3600, ls="--", label=f"{sol} roll")
    a1.set_ylabel("position sigma [m]")
    a2.set_ylabel("attitude sigma [arcsec]")
    a2.set_xlabel("time since start [s]")
    for a in (a1, a2):
        a.grid(alpha=0.3, which="both")
        a.legend(fontsize=8)
    fig.tight_layout()
    return fig


def diagnosis_steps(diagnosis: pd.DataFrame) -> Figure:
    """Gap before and after each step of the model-discrepancy workflow."""
    fig, ax = plt.subplots(figsize=(7, 3.8))
    x = np.arange(len(diagnosis))
    ax.bar(x - 0.2, diagnosis.gap_before_mps, 0.4, label="fit residual before")
    ax.bar(x + 0.2, diagnosis.gap_after_mps, 0.4, label="fit residual after")
    ax.plot(x, diagnosis.heldout_gap_after_mps, "ko-", label="held-out gap after")
    ax.set_xticks(x, diagnosis.effect, rotation=30, fontsize=8)
    ax.set_ylabel("RMS velocity gap [m/s]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def evaluation_errors(errors: dict, *, t0_ns: int | None = None) -> Figure:
    """Solution minus reference over time: horizontal position, velocity, tilt and heading.

    ``errors`` maps a solution name to a :class:`pospp.evaluate.SolutionErrors` (SI, NED).
    """
    fig, axes = plt.subplots(4, 1, figsize=(10, 8), sharex=True)
    t0 = t0_ns if t0_ns is not None else min(int(e.time_ns[0]) for e in errors.values())
    arcsec = np.pi / 180.0 / 3600.0
    for name, e in errors.items():
        t = (e.time_ns - t0) * 1e-9
        axes[0].plot(t, np.hypot(e.pos_ned_m[:, 0], e.pos_ned_m[:, 1]), lw=0.8, label=name)
        axes[1].plot(t, np.hypot(e.vel_ned_mps[:, 0], e.vel_ned_mps[:, 1]), lw=0.8)
        axes[2].plot(t, np.hypot(e.att_ned_rad[:, 0], e.att_ned_rad[:, 1]) / arcsec, lw=0.8)
        axes[3].plot(t, e.att_ned_rad[:, 2] / arcsec, lw=0.8)
    labels = ("horizontal position [m]", "horizontal velocity [m/s]", "tilt [arcsec]",
              "heading phi_D [arcsec]")
    for ax, lab in zip(axes, labels, strict=True):
        ax.set_ylabel(lab, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[0].set_title("Solution minus reference")
    axes[-1].set_xlabel("time since start [s]")
    fig.tight_layout()
    return fig


def diagnosis_curves(curves: pd.DataFrame) -> Figure:
    """The gap over time per leg: B minus A minus the model, before and after the diagnosis
    (fitted and held-out), horizontal magnitude."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    cmap = plt.get_cmap("tab10")
    for ax, kind in zip(axes, ("fit", "heldout"), strict=True):
        g = curves[curves.kind == kind]
        for i, (leg, gl) in enumerate(g.groupby("leg_id")):
            for model, ls in (("before", "--"), ("after", "-")):
                c = gl[gl.model == model]
                ax.plot(c.t_s, np.hypot(c.dvn_mps, c.dve_mps), ls=ls, color=cmap(i % 10),
                        lw=1, label=f"leg {leg} {model}")
        ax.set_title(f"gap, {'fitted' if kind == 'fit' else 'held-out prediction'}")
        ax.set_xlabel("time since leg start [s]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("|B - A - model| [m/s]")
    axes[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return fig
