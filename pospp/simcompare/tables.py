"""The comparison as columns (sim_comparison.parquet) and the fitted model as TOML text."""

from __future__ import annotations

from typing import Any

import numpy as np

from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel
from pospp.simcompare.base_model import BaseParameter
from pospp.simcompare.compare import Comparison, Gap
from pospp.simcompare.stats import STAT_UNITS

__all__ = ["comparison_columns", "model_toml"]

_COLS = ("step", "kind", "measure", "effect", "parameter", "value", "sigma", "unit",
         "gap_before", "gap_after", "sigma_gap", "z_before", "z_after", "p_before",
         "significant_before", "significant_after", "measured", "simulated_before",
         "simulated_after", "prior", "note")


def _stat_row(step: int, effect: str, name: str, b: Gap, a: Gap | None) -> dict[str, Any]:
    nan = float("nan")
    return {"step": step, "kind": "statistic", "measure": name, "effect": effect,
            "parameter": "", "value": nan, "sigma": nan, "unit": STAT_UNITS[name],
            "gap_before": b.gap, "gap_after": a.gap if a else nan, "sigma_gap": b.sigma,
            "z_before": b.z, "z_after": a.z if a else nan, "p_before": b.p_adjusted,
            "significant_before": b.significant,
            "significant_after": bool(a.significant) if a else False,
            "measured": b.measured, "simulated_before": b.simulated,
            "simulated_after": a.simulated if a else nan, "prior": nan, "note": ""}


def _base_row(b: BaseParameter) -> dict[str, Any]:
    nan = float("nan")
    return {"step": 0, "kind": "base", "measure": b.source, "effect": "base_model",
            "parameter": b.name, "value": b.value, "sigma": b.sigma, "unit": b.unit,
            "gap_before": nan, "gap_after": nan, "sigma_gap": nan, "z_before": nan,
            "z_after": nan, "p_before": nan, "significant_before": bool(b.differs),
            "significant_after": False, "measured": nan, "simulated_before": b.simulated,
            "simulated_after": nan, "prior": b.prior,
            "note": b.text() if b.fitted else f"not fitted: {b.source}"}


def comparison_columns(c: Comparison) -> dict[str, list]:
    """Long-form rows of sim_comparison.parquet (schema in pospp.io.parquet_tables): the base
    model's fitted levels (kind "base", step 0; ``significant_before``: the fit differs
    from its prior; ``simulated_before``: the level simulated, the fit or the prior; the
    ``gyro_gm_sigma`` row's ``note`` also says how A was tuned where not as configured,
    ``Comparison.a_tuning``), every statistic at step 0 and at each step (kind "statistic";
    at step 0 ``note`` says when the base model's drift masks the effects fitted on it:
    ``Comparison.masked``),
    and each step's effect parameters (kind "effect", in the catalogue's units and signs,
    the reading in ``note``) and what else the reading determines (kind "reading": the
    combination of confounded effects, their correlations)."""
    rows = [_base_row(b) for b in c.base_fit]
    for r in rows:  # how A was tuned, on the drift's row
        if c.a_tuning and r["parameter"] == "gyro_gm_sigma":
            r["note"] = f"{r['note']}; {c.a_tuning}"
    masked = {m.statistic: m.text() for m in c.masked}
    rows += [{**_stat_row(0, "", n, g, None), "note": masked.get(n, "")}
             for n, g in c.base.items()]
    for s in c.steps:
        for n, b in s.before.items():
            rows.append(_stat_row(s.step, s.effect, n, b, s.after.get(n)))
        b, a = s.before[s.target], s.after.get(s.target)
        params = [(f"{s.candidate}:{p}" if s.candidate else p, v, sg, u) for p, v, sg, u in
                  zip(s.params, s.size, s.sigma, s.param_units(), strict=True)]
        for kind, group in (("effect", params), ("reading", s.extra)):
            for p, v, sg, u in group:
                r = _stat_row(s.step, s.effect, s.target, b, a)
                r.update(kind=kind, parameter=p, value=float(v), sigma=float(sg), unit=u,
                         note=s.note)
                rows.append(r)
        if not s.params:
            r = _stat_row(s.step, s.effect, s.target, b, a)
            r.update(kind="effect", note=s.note)
            rows.append(r)
    return {k: [r[k] for r in rows] for k in _COLS}


def _fmt(v: Any) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(float(np.round(v, 12)))
    return repr(v)


def model_toml(imu: ImuErrorModel, gnss: GnssModel, *, header: str = "") -> str:
    """A model file: ``[imu]`` (ImuErrorModel fields) and ``[gnss]`` (GnssModel fields).

    ``pospp simulate --imu-grade FILE.toml`` reads its ``[imu]`` table
    (:func:`pospp.sim.sensors.imu_model_file`).
    """
    lines = [f"# {h}" for h in header.splitlines()] if header else []
    for name, d in (("imu", imu.as_dict()), ("gnss", gnss.as_dict())):
        lines += ["", f"[{name}]"]
        for k, v in d.items():
            if k == "outages_s" or v is None:
                continue
            lines.append(f"{k} = {_fmt(v)}")
    return "\n".join(lines).lstrip("\n") + "\n"
