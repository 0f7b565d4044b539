"""The diagnosis as flat tables (dicts of arrays; :mod:`pospp.io` writes them).

diagnosis.parquet (one row per step), the candidates tested, the per-leg gaps and the residual
curves of :class:`pospp.diagnose.results.Diagnosis`. Units in the column names (SI: m/s, m,
s); effect sizes in each row's display ``unit``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from pospp.diagnose.results import Diagnosis

DIAGNOSIS_COLUMNS = (
    "step", "effect", "value", "sigma", "unit", "statistic", "p_value", "criterion",
    "significant", "delta_bic", "explained_fraction", "gap_before_mps", "gap_after_mps",
    "heldout_gap_before_mps", "heldout_gap_after_mps", "confounded_with", "parameters",
    "parameter_values", "parameter_sigmas", "horizon_s", "gap_horizon_mps", "gap_horizon_m",
    "residual_horizon_mps", "residual_horizon_m", "gap_legs", "gap_channel", "gap_part",
    "gap_basis", "gap_location", "null_model", "shape", "shape_parameters", "null_rebuilt",
    "null_rebuilt_with",
)
"""Columns of diagnosis.parquet, in order (docs/formats.md): the step, its effect and
statistics, what a gap is worth at the horizon, the null the p-values are calibrated on, the
family's shape and whether the null was re-made under the alternative."""


def diagnosis_columns(diagnosis: Diagnosis) -> dict[str, NDArray]:
    """diagnosis.parquet as a dict of arrays, one row per step (:data:`DIAGNOSIS_COLUMNS`).

    ``confounded_with``, ``parameters``, ``parameter_values``, ``parameter_sigmas`` are
    ";"-joined strings (values in the row's ``unit``) so that the table stays flat.
    ``gap_horizon_*`` / ``residual_horizon_*``: what the row is worth at the horizon against
    the calibration's own residual (:mod:`pospp.diagnose.locate`). ``gap_legs`` ...
    ``gap_location``: where the structured gap sits, on an "unexplained" closing row only
    (empty strings elsewhere). ``null_model``: what the p-values are calibrated on (every row).
    """
    s = diagnosis.steps
    loc = diagnosis.location

    def where(x, text: object) -> str:
        return str(text) if loc is not None and x is s[-1] else ""

    def join(a) -> str:
        return ";".join(f"{float(v):.6g}" for v in a)

    return {
        "step": np.array([x.step for x in s], dtype=np.int64),
        "effect": np.array([x.effect for x in s], dtype=object),
        "value": np.array([x.value for x in s], dtype=float),
        "sigma": np.array([x.sigma for x in s], dtype=float),
        "unit": np.array([x.unit for x in s], dtype=object),
        "statistic": np.array([x.statistic for x in s], dtype=float),
        "p_value": np.array([x.p_value for x in s], dtype=float),
        "criterion": np.array([x.criterion for x in s], dtype=object),
        "significant": np.array([x.significant for x in s], dtype=bool),
        "delta_bic": np.array([x.delta_bic for x in s], dtype=float),
        "explained_fraction": np.array([x.explained_fraction for x in s], dtype=float),
        "gap_before_mps": np.array([x.gap_before_mps for x in s], dtype=float),
        "gap_after_mps": np.array([x.gap_after_mps for x in s], dtype=float),
        "heldout_gap_before_mps": np.array([x.heldout_gap_before_mps for x in s], dtype=float),
        "heldout_gap_after_mps": np.array([x.heldout_gap_after_mps for x in s], dtype=float),
        "confounded_with": np.array([";".join(x.confounded_with) for x in s], dtype=object),
        "parameters": np.array([";".join(x.parameters) for x in s], dtype=object),
        "parameter_values": np.array([join(x.values) for x in s], dtype=object),
        "parameter_sigmas": np.array([join(x.sigmas) for x in s], dtype=object),
        "horizon_s": np.array([x.horizon_s for x in s], dtype=float),
        "gap_horizon_mps": np.array([x.gap_horizon_mps for x in s], dtype=float),
        "gap_horizon_m": np.array([x.gap_horizon_m for x in s], dtype=float),
        "residual_horizon_mps": np.array([x.residual_horizon_mps for x in s], dtype=float),
        "residual_horizon_m": np.array([x.residual_horizon_m for x in s], dtype=float),
        "gap_legs": np.array([where(x, loc and ";".join(str(v) for v in loc.legs)) for x in s],
                             dtype=object),
        "gap_channel": np.array([where(x, loc and loc.channel) for x in s], dtype=object),
        "gap_part": np.array([where(x, loc and loc.part) for x in s], dtype=object),
        "gap_basis": np.array([where(x, loc and loc.basis) for x in s], dtype=object),
        "gap_location": np.array([where(x, loc and loc.text) for x in s], dtype=object),
        "null_model": np.array([diagnosis.null_model for _ in s], dtype=object),
        "shape": np.array([x.shape for x in s], dtype=object),
        "shape_parameters": np.array([x.shape_parameters for x in s], dtype=object),
        "null_rebuilt": np.array([bool(diagnosis.null_rebuilt_with) for _ in s], dtype=bool),
        "null_rebuilt_with": np.array([";".join(diagnosis.null_rebuilt_with) for _ in s],
                                      dtype=object),
    }


def candidate_columns(diagnosis: Diagnosis) -> dict[str, NDArray]:
    """Every candidate test (one row per step and candidate) as a dict of arrays."""
    c = diagnosis.candidates
    names = ("step", "effect", "n_parameters", "value", "sigma", "unit", "statistic", "p_value",
             "delta_bic", "explained_fraction", "gap_after_mps", "heldout_gap_after_mps",
             "significant", "gap_horizon_mps", "gap_horizon_m", "shape")
    return {k: np.array([getattr(x, k) for x in c]) for k in names}


def leg_gap_columns(diagnosis: Diagnosis) -> dict[str, NDArray]:
    """Per-leg gaps before (base model) and after (final model), with the thirds of each leg."""
    g = diagnosis.legs
    out = {k: np.array([getattr(x, k) for x in g]) for k in (
        "leg_id", "start_s", "duration_s", "heading_deg", "speed_mps", "gap_before_mps",
        "gap_after_mps", "heldout_gap_before_mps", "heldout_gap_after_mps")}
    for j, ph in enumerate(("early", "middle", "late")):
        out[f"gap_{ph}_before_mps"] = np.array([x.phase_gap_before_mps[j] for x in g])
        out[f"gap_{ph}_after_mps"] = np.array([x.phase_gap_after_mps[j] for x in g])
    return out


def residual_curve_columns(diagnosis: Diagnosis) -> dict[str, NDArray]:
    """B minus A minus the model over time, long form, for figures of the gap shrinking.

    Columns: leg_id, t_s (since the leg start), model ("before": base model, "after": final
    model), kind ("fit": all legs fitted, "heldout": leave-one-leg-out prediction), dvn_mps,
    dve_mps.
    """
    parts: dict[str, list[NDArray]] = {k: [] for k in ("leg_id", "t_s", "model", "kind",
                                                        "dvn_mps", "dve_mps")}
    curves = (("before", "fit", diagnosis.residuals_before_n_mps),
              ("after", "fit", diagnosis.residuals_after_n_mps),
              ("before", "heldout", diagnosis.heldout_before_n_mps),
              ("after", "heldout", diagnosis.heldout_after_n_mps))
    for model, kind, res in curves:
        for leg, t, r in zip(diagnosis.legs, diagnosis.t_s, res, strict=True):
            parts["leg_id"].append(np.full(t.size, leg.leg_id, dtype=np.int64))
            parts["t_s"].append(t)
            parts["model"].append(np.full(t.size, model, dtype=object))
            parts["kind"].append(np.full(t.size, kind, dtype=object))
            parts["dvn_mps"].append(r[:, 0])
            parts["dve_mps"].append(r[:, 1])
    return {k: np.concatenate(v) for k, v in parts.items()}
