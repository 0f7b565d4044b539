"""B's reach: its horizontal error 300 s into each leg, before / after compensation.

The measure of issue 35, shared by tests/reference/test_reach.py (slow, fails on a loss) and
tests/benchmarks/bench_reach.py (prints it, for this tree and for another checkout):

    ratio = median over the legs of |dv_h(300 s)| before / median over the legs after
    (velocity), the same for |dr_h| (position)

(the leg end when a leg is shorter), from the pipeline's own calibration stage: the case's
MCAP read as configured, algorithm A, legs, B, the fit and the compensation
(:func:`pospp.pipeline.calibrate_from_a`), the null realisations and the diagnosis left out
(they do not change the compensation). The configuration is ``pipelines/vehicle.toml`` for
a vehicle case and ``pipelines/flight.toml`` otherwise, with the antenna lever arm of the
case's params.json (as tests/reference/test_reference_calib.py configures them).

The drift grid: pospp's simulator, a survey flight (3 min static, 5 lines of 300 s at
60 m/s, 180 deg turns, 100 Hz, 1 Hz GNSS), the ``paper_flight`` IMU (constant [1, -1, 1]
deg/h, ARW 0.01 deg/sqrt(h), 5 ug) with its Gauss-Markov drift replaced by 0.3 deg/h of
correlation time 100 s, 300 s, 1 h, 10 h, or none.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[2]
GRID_TAUS_S: tuple[float | None, ...] = (100.0, 300.0, 3600.0, 36000.0, None)
"""Gauss-Markov correlation times of the drift grid (None: no drift)."""
GRID_DRIFT_DPH = 0.3
GRID_PROFILE = {
    "name": "reach_grid", "imu_rate_hz": 100,
    "start": {"lat_deg": 34.25, "lon_deg": 108.95, "height_m": 2600.0, "heading_deg": 0.0},
    "options": {"turn_bank": "coordinated", "blend_s": 5.0},
    "segment": [
        {"type": "static", "duration_s": 180.0},
        {"type": "accelerate", "to_speed_mps": 60.0, "duration_s": 40.0},
        {"type": "survey", "legs": 5, "heading_deg": 0.0, "leg_duration_s": 300.0,
         "turn_rate_dps": 3.0, "turn_direction": "alternate"},
    ],
}
"""The drift grid's mission (a pospp.sim profile)."""


def pipeline_kind(name: str) -> str:
    """The pipeline file of a case: "vehicle" for a vehicle case, else "flight"."""
    return "vehicle" if name.startswith("vehicle") else "flight"


def pipeline_text(kind: str, lever_arm_m: Any, repo: Path = REPO) -> str:
    """``repo``'s pipelines/<kind>.toml with ``[gnss] lever_arm_m`` set (any checkout)."""
    text = (repo / "pipelines" / f"{kind}.toml").read_text()
    lever = "lever_arm_m = [{:.6g}, {:.6g}, {:.6g}]".format(*map(float, lever_arm_m))
    return re.sub(r"lever_arm_m\s*=\s*\[[^\]]*\]", lever, text, count=1)


def ratios(before: list[tuple[float, float]], after: list[tuple[float, float]]
           ) -> tuple[float, float]:
    """(velocity, position) ratio of the medians over the legs, before / after."""
    b, a = np.asarray(before), np.asarray(after)
    return (float(np.median(b[:, 0]) / np.median(a[:, 0])),
            float(np.median(b[:, 1]) / np.median(a[:, 1])))


def reach_here(mcap: Path | Any, kind: str, lever_arm_m: Any) -> dict[str, Any]:
    """The reach of this tree's pipeline on one MCAP (or a FlightLog already made):
    {"v", "p", "legs", "source"}."""
    import tomllib

    from pospp import flight_stages as fs
    from pospp.config import config_from_dict

    config = config_from_dict(tomllib.loads(pipeline_text(kind, lever_arm_m)))
    log = fs.ingest(mcap, config) if isinstance(mcap, str | Path) else mcap
    nav = fs.navigate(log, config)
    run, _ = fs.calibrate_from_a(fs.imu_increments(log), nav, config)
    imp = run.improvements
    v, p = ratios([(i.vel_before_mps, i.pos_before_m) for i in imp],
                  [(i.vel_after_mps, i.pos_after_m) for i in imp])
    return {"v": v, "p": p, "legs": len(imp), "source": run.compensation_source}


def reach_of_checkout(code: Path, mcap: Path, kind: str, lever_arm_m: Any) -> dict[str, Any]:
    """The reach of another checkout's pipeline (``code``: its root) on one MCAP, through
    its own CLI (``python -m pospp.cli run``, PYTHONPATH=code) and its leg_errors.parquet."""
    import pyarrow.parquet as pq

    with tempfile.TemporaryDirectory() as tmp:
        toml = Path(tmp) / "pipeline.toml"
        toml.write_text(pipeline_text(kind, lever_arm_m, code))
        out = Path(tmp) / "run"
        env = {**os.environ, "PYTHONPATH": str(code)}
        subprocess.run([sys.executable, "-m", "pospp.cli", "run", str(mcap), "-p", str(toml),
                        "-o", str(out)], env=env, check=False, capture_output=True, cwd=tmp)
        le = pq.read_table(out / "leg_errors.parquet").to_pandas()
    rows: dict[str, list[tuple[float, float]]] = {"before": [], "after": []}
    for stage in rows:
        for _, g in le[le.stage == stage].groupby("leg_id"):
            g = g.sort_values("t_s")
            k = min(int(np.searchsorted(g.t_s.to_numpy(), 300.0 - 1e-9)), len(g) - 1)
            r = g.iloc[k]
            rows[stage].append((float(np.hypot(r.dvn_mps, r.dve_mps)),
                                float(np.hypot(r.dpn_m, r.dpe_m))))
    v, p = ratios(rows["before"], rows["after"])
    return {"v": v, "p": p, "legs": len(rows["after"]), "source": ""}


def grid_simulation(tau_s: float | None, seed: int, *, errors: bool = True) -> Any:
    """One flight of the drift grid (module docstring), simulated by pospp.sim (``errors``
    False: the same flight with an error-free IMU)."""
    from pospp.sim.api import simulate
    from pospp.sim.profile import parse_profile
    from pospp.sim.sensors import imu_grade

    model = imu_grade("paper_flight" if errors else "errorfree")
    sigma = 0.0 if tau_s is None or not errors else GRID_DRIFT_DPH
    model = dataclasses.replace(model, gyro_gm_sigma_dph=(sigma,) * 3,
                                gyro_gm_tau_s=float(tau_s or 300.0))
    return simulate(parse_profile(GRID_PROFILE), imu_grade=model, seed=seed, imu_rate_hz=100.0)


def grid_mcap(tau_s: float | None, seed: int, folder: Path) -> Path:
    """:func:`grid_simulation` written as an MCAP (with truth and params) into ``folder``."""
    from pospp.io.simulation_files import write_simulation

    name = f"grid_tau{'none' if tau_s is None else int(tau_s)}_seed{seed}"
    return write_simulation(grid_simulation(tau_s, seed), folder, name)["mcap"]


def cases_in(folder: Path) -> list[tuple[str, Path, list[float]]]:
    """(name, MCAP, lever arm) of every case in a reference-case folder, by name."""
    out = []
    for params in sorted(Path(folder).glob("*.params.json")):
        name = params.name[: -len(".params.json")]
        lever = json.loads(params.read_text())["gnss"]["lever_arm_m"]
        out.append((name, params.with_name(f"{name}.mcap"), lever))
    return out


MODES = ("constant", "causal", "smoothed")
"""Compensation modes the drift grid compares (pospp.calib.compensate.COMPENSATION_MODES)."""


def grid_flight(tau_s: float | None, seed: int, *, n_null: int = 10) -> dict[str, Any]:
    """One flight of the drift grid through the pipeline's stages, measured three ways.

    A (pospp's filter and smoother, ``pipelines/flight.toml``), legs, B and the fit as
    :func:`pospp.pipeline.calibrate_from_a` makes them; then for each of :data:`MODES`:

    - in-sample: B's reach ratios on all legs of the joint fit;
    - held out: the fit made on the middle legs only (2..L-1), the reach on the first and
      last legs (the calibration's reach back and ahead; median over those two legs);

    and the two quantities' errors over their sigmas (``n_null`` null realisations and the
    calibration's covariance from them as the pipeline makes them, :func:`pospp.null_stage.
    null_stage`): the turn-on constant against the simulated
    constant, the flight's bias against the realised mean gyro error (constant, drift and
    white noise: the simulated rates minus the error-free run's) over the fitted legs
    (``n_null`` 0: the reach alone).

    Returns ``{"in": {mode: (v, p)}, "held": {...}, "z_const": (2,), "z_flight": (2,),
    "err_const_dph", "err_flight_dph", "sigma_const_dph", "sigma_flight_dph", "source",
    "drift_dph", "drift_tau_s"}``.
    """
    import tomllib

    from pospp import flight_stages as fs
    from pospp.calib.bias_smoother import span_means
    from pospp.calib.compensate import COMPENSATION_MODES, ModeInputs, compensate_legs
    from pospp.calib.replay import ReplayOptions
    from pospp.config import config_from_dict
    from pospp.io.mcap_reader import FlightLog
    from pospp.null_stage import null_needs_gains, null_stage
    from pospp.units import DEG_PER_H_RADPS

    sim = grid_simulation(tau_s, seed)
    clean = grid_simulation(tau_s, seed, errors=False)
    config = config_from_dict(tomllib.loads(pipeline_text("flight", [0.0, 0.0, 0.0])))
    log = FlightLog(sim.imu, sim.fix, sim.vel, f"grid tau {tau_s} seed {seed}")
    nav = fs.navigate(log, config, record_gains=null_needs_gains(config))
    imu = fs.imu_increments(log)
    made = fs.calibration_replays(imu, nav, config)
    fwd = fs.forward_bias_record(nav, config.imu.tuning())
    rc = config.replay.options()
    ids = sorted(made.replays)

    def reach(run: Any, legs: list[int]) -> dict[str, tuple[float, float]]:
        out = {}
        for mode in MODES:
            choice = COMPENSATION_MODES[mode](ModeInputs(
                imu, made.solution_a, made.replays, run.chosen, run.gyro_bias_sigma_b_radps,
                rc, fwd))
            _, imp = compensate_legs(imu, made.solution_a, {i: made.replays[i] for i in legs},
                                     run.chosen, replay=ReplayOptions(horizon_s=rc.horizon_s),
                                     **choice.kwargs)
            out[mode] = ratios([(i.vel_before_mps, i.pos_before_m) for i in imp],
                               [(i.vel_after_mps, i.pos_after_m) for i in imp])
        return out

    run, _ = fs.calibrate_from_a(imu, nav, config, made)
    mid = ids[1:-1]
    sub = fs.LegReplays(made.solution_a, tuple(g for g in made.legs if g.leg_id in mid),
                        {i: made.replays[i] for i in mid}, ())
    run_mid, _ = fs.calibrate_from_a(imu, nav, config, sub)
    result: dict[str, Any] = {"in": reach(run, ids), "held": reach(run_mid, [ids[0], ids[-1]])}
    if n_null == 0:
        return result
    stage = null_stage(log, nav, run, config, n=n_null, seed=seed)
    null, run = stage.realisations, stage.calibration
    const = np.array(sim.params["imu_errors"]["gyro_bias_dph"]) * DEG_PER_H_RADPS
    err_rate = sim.imu.w_ib_b_radps - clean.imu.w_ib_b_radps
    epoch = int(sim.imu.time_ns[0])
    spans = [(epoch + round(run.replays[i].t0_s * 1e9),
              epoch + round((run.replays[i].t0_s + run.replays[i].t_s[-1]) * 1e9))
             for i in run.chosen.leg_ids]
    length = np.array([run.replays[i].t_s[-1] for i in run.chosen.leg_ids])
    flight_truth = length @ span_means(sim.imu.time_ns, err_rate, spans) / length.sum()
    e_c = (run.gyro_bias_b_radps - const)[:2]
    e_f = (run.flight_gyro_bias_b_radps - flight_truth)[:2]
    s_c, s_f = run.gyro_bias_sigma_b_radps[:2], run.flight_gyro_bias_sigma_b_radps[:2]
    result.update(z_const=e_c / s_c, z_flight=e_f / s_f, err_const_dph=e_c / DEG_PER_H_RADPS,
                  err_flight_dph=e_f / DEG_PER_H_RADPS, sigma_const_dph=s_c / DEG_PER_H_RADPS,
                  sigma_flight_dph=s_f / DEG_PER_H_RADPS, source=run.compensation_source,
                  drift_dph=run.drift_sigma_radps / DEG_PER_H_RADPS,
                  drift_tau_s=run.drift_tau_s, sigma_source=run.sigma_source,
                  n_null=len(null))
    return result
