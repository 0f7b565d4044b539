"""The calibration stage's output tables as column dicts (legs, pairs, calibration,
leg_errors: docs/formats.md), from :class:`pospp.calib.stage.CalibrationRun`'s parts.

Units at this edge: deg, arcsec, deg/h, int64 ns (SI inside). Misalignments in the paper's
axes (phi_x = phi_E, phi_y = phi_N, phi_z = -phi_D); the chosen joint fit's rows also carry
the gyro bias over the flight's legs (``gyro_bias_x_flight``, ...) besides the turn-on
constant (``gyro_bias_x``, ...), each with its own sigma (docs/calibration.md, "Two
quantities, two sigmas").
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pospp.calib.pairs import Pair
from pospp.calib.replay import LegErrors, LegReplay
from pospp.calib.segment import Leg
from pospp.calib.solve import Calibration
from pospp.nav.closed_form import PAPER_FROM_NED
from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS

Row = tuple[str, float, float, str]
"""(parameter, value, sigma, unit) of the calibration table."""


def legs_table(legs: tuple[Leg, ...], epoch_ns: int) -> dict[str, Any]:
    """legs.parquet's columns (run times to UTC ns through ``epoch_ns``)."""

    def ns(t: float) -> int:
        return int(epoch_ns) + int(round(t * 1e9))

    return {
        "leg_id": np.array([g.leg_id for g in legs], dtype=np.int64),
        "start_ns": np.array([ns(g.start_s) for g in legs], dtype=np.int64),
        "end_ns": np.array([ns(g.end_s) for g in legs], dtype=np.int64),
        "duration_s": np.array([g.duration_s for g in legs], dtype=float),
        "heading_deg": np.degrees([g.heading_rad for g in legs]).astype(float),
        "speed_mps": np.array([g.speed_mps for g in legs], dtype=float),
        "height_m": np.array([g.height_m for g in legs], dtype=float),
        "heading_spread_deg": np.degrees([g.heading_spread_rad for g in legs]).astype(float),
        "speed_std_mps": np.array([g.speed_std_mps for g in legs], dtype=float),
        "vertical_speed_mps": np.array([g.vertical_speed_mps for g in legs], dtype=float),
        "heading_rate_max_dps": np.degrees([g.heading_rate_max_radps for g in legs]
                                           ).astype(float),
    }


def pairs_table(pairs: tuple[Pair, ...]) -> dict[str, Any]:
    """pairs.parquet's columns."""
    return {
        "pair_id": np.array([p.pair_id for p in pairs], dtype=np.int64),
        "leg_a": np.array([p.leg_a for p in pairs], dtype=np.int64),
        "leg_b": np.array([p.leg_b for p in pairs], dtype=np.int64),
        "dheading_deg": np.degrees([p.dheading_rad for p in pairs]).astype(float),
        "dspeed_mps": np.array([p.dspeed_mps for p in pairs], dtype=float),
        "cond_raw": np.array([p.cond_raw for p in pairs], dtype=float),
        "cond_scaled": np.array([p.cond_scaled for p in pairs], dtype=float),
        "used": np.array([p.used for p in pairs], dtype=bool),
        "reason": [p.reason for p in pairs],
    }


def calibration_rows(cal: Calibration) -> list[Row]:
    """(parameter, value, sigma, unit) rows of one calibration in the output convention.

    Misalignments in the paper's axes (phi_x = phi_E, phi_y = phi_N, phi_z = -phi_D, arcsec;
    per-leg tilts of ``body`` as phi_x_leg<i>, phi_y_leg<i>); nav-frame drifts eps_e, eps_n
    and body gyro biases gyro_bias_x/y/z (FRD) in deg/h.
    """
    rows: list[Row] = []
    sig = cal.sigma
    if cal.formulation == "paper":
        m = PAPER_FROM_NED
        x = m @ cal.x
        s = np.sqrt(np.diag(m @ cal.cov @ m.T))
        for name, v, e in zip(("phi_x", "phi_y", "phi_z", "eps_e", "eps_n"), x, s, strict=True):
            k, u = (ARCSEC_RAD, "arcsec") if name.startswith("phi") else (DEG_PER_H_RADPS,
                                                                           "deg_per_h")
            rows.append((name, float(v / k), float(e / k), u))
        return rows
    out_name = {"phi_n": "phi_y", "phi_e": "phi_x", "phi_d": "phi_z"}
    for name, v, e in zip(cal.names, cal.x, sig, strict=True):
        if name.startswith("gyro_bias"):
            rows.append((name, float(v / DEG_PER_H_RADPS), float(e / DEG_PER_H_RADPS),
                         "deg_per_h"))
            continue
        base, _, leg = name.partition("_leg")
        sign = -1.0 if base == "phi_d" else 1.0
        label = out_name[base] + (f"_leg{leg}" if leg else "")
        rows.append((label, float(sign * v / ARCSEC_RAD), float(e / ARCSEC_RAD), "arcsec"))
    return rows


def calibration_table(pairs: tuple[Pair, ...], joint: tuple[Calibration, ...],
                      extra: Mapping[str, list[Row]] | None = None) -> dict[str, Any]:
    """Long-form rows of every pair's and every joint fit's calibration; ``extra``: more rows
    of a joint fit, by formulation (the flight's gyro bias of the chosen one)."""
    cols: dict[str, list] = {k: [] for k in ("pair_id", "formulation", "transition",
                                             "parameter", "value", "sigma", "unit")}
    items = [(p.pair_id, c) for p in pairs for c in p.calibrations] + [(-1, c) for c in joint]
    more = extra or {}
    for pid, cal in items:
        rows = calibration_rows(cal) + (list(more.get(cal.formulation, ())) if pid == -1
                                        else [])
        for name, v, s, u in rows:
            cols["pair_id"].append(pid)
            cols["formulation"].append(cal.formulation)
            cols["transition"].append(cal.transition)
            cols["parameter"].append(name)
            cols["value"].append(v)
            cols["sigma"].append(s)
            cols["unit"].append(u)
    out: dict[str, Any] = dict(cols)
    out["pair_id"] = np.array(cols["pair_id"], dtype=np.int64)
    out["value"] = np.array(cols["value"], dtype=float)
    out["sigma"] = np.array(cols["sigma"], dtype=float)
    return out


def leg_errors_table(before: Mapping[int, LegReplay], after: Mapping[int, LegErrors]
                      ) -> dict[str, Any]:
    """leg_errors.parquet's columns: B minus A per leg before and after compensation."""
    stages: tuple[tuple[str, Mapping[int, LegReplay | LegErrors]], ...] = (
        ("before", before), ("after", after))
    parts = [(lid, stage, rep) for stage, reps in stages for lid, rep in sorted(reps.items())]
    if not parts:
        return {"leg_id": np.zeros(0, np.int64), "stage": [], "t_s": np.zeros(0),
                "dvn_mps": np.zeros(0), "dve_mps": np.zeros(0), "dpn_m": np.zeros(0),
                "dpe_m": np.zeros(0)}
    return {
        "leg_id": np.concatenate([np.full(r.t_s.size, lid, np.int64) for lid, _, r in parts]),
        "stage": [stage for _, stage, r in parts for _ in range(r.t_s.size)],
        "t_s": np.concatenate([r.t_s for _, _, r in parts]),
        "dvn_mps": np.concatenate([r.dv_n_mps[:, 0] for _, _, r in parts]),
        "dve_mps": np.concatenate([r.dv_n_mps[:, 1] for _, _, r in parts]),
        "dpn_m": np.concatenate([r.dr_n_m[:, 0] for _, _, r in parts]),
        "dpe_m": np.concatenate([r.dr_n_m[:, 1] for _, _, r in parts]),
    }
