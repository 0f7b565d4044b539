"""``pospp compare-sim``: a finished run against a simulation of the same flight.

Orchestration only (docs/compare_sim.md): re-read the run's input and configuration (as
:func:`pospp.pipeline.diagnose_run`), run algorithm A, simulate the same flight with
:func:`pospp.sim.api.simulate_along` along A's smoothed trajectory with the configured IMU
grade and a GNSS model from the log (rates, stamps, gaps, reported sigmas), run A on the
simulation the same way, and hand both to the step-wise comparison of
:mod:`pospp.simcompare`. Writes sim_comparison.parquet, sim_model.toml and the report.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from pospp import pipeline
from pospp.config import PipelineConfig
from pospp.io import mcap_reader, parquet_tables, report_files, run_folder
from pospp.io.run_lock import locked
from pospp.nav import filter as nav_filter
from pospp.nav.alignment import AlignmentOptions, gnss_moving_windows
from pospp.sim.api import simulate_along
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel, imu_grade
from pospp.simcompare.compare import Comparison, SimulateFn, compare_flights
from pospp.simcompare.effects import LIBRARY, SimEffect
from pospp.simcompare.stats import FlightStats, Stat, flight_stats, leg_stats
from pospp.simcompare.tables import comparison_columns, model_toml

__all__ = ["SIM_GRADES", "FlightTemplate", "compare_sim_run", "flight_template",
           "log_stats", "simulate_stats"]

SIM_GRADES = {"flight": "paper_flight", "vehicle": "paper_vehicle", "consumer": "mems"}
"""Filter tuning grade ([imu] grade) -> simulator grade of pospp/presets/imu.toml."""
RESIDUAL_NOISE_FACTOR = 1.5
"""The simulated GNSS white noise is at most this times the records' RMS about A's smoothed
solution (which follows part of the noise, so the factor keeps a consistent receiver's
reported sigma)."""
MIN_LEGS = 3
"""B minus A on legs is compared only on flights with at least this many legs (the
leave-one-leg-out prediction needs them)."""
SIM_SEED = 20261123
"""Seed of every simulation of one comparison (common random numbers across its steps)."""


@dataclass(frozen=True)
class FlightTemplate:
    """What the simulation copies from the measured flight.

    Attributes
    ----------
    time_s, lat_rad, lon_rad, height_m : A's smoothed trajectory (s from ``epoch_ns``)
    epoch_ns : int
        The measured log's first IMU stamp.
    imu_dt_ns : int
        IMU interval [ns] (the median of the log's, rounded).
    imu_gaps_s : (K, 2) IMU gaps of the log (start, end) [s from epoch]
    gnss : GnssModel
        Rate, outages, the configured lever arm, the median reported sigmas (reported in the
        simulated covariances), and white noise at those sigmas, or at 1.5 x the RMS of the
        records about A's smoothed solution where that is smaller.
    has_velocity : bool
    vehicle : "car" or "aircraft"
    """

    time_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    height_m: np.ndarray
    epoch_ns: int
    imu_dt_ns: int
    imu_gaps_s: np.ndarray
    gnss: GnssModel
    has_velocity: bool
    vehicle: str


def _gaps(t_s: np.ndarray, factor: float) -> np.ndarray:
    d = np.diff(t_s)
    if d.size == 0:
        return np.zeros((0, 2))
    big = np.flatnonzero(d > factor * np.median(d))
    return np.stack([t_s[big], t_s[big + 1]], axis=1) if big.size else np.zeros((0, 2))


def flight_template(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                    config: PipelineConfig, *, vehicle: str | None = None) -> FlightTemplate:
    """The measured flight's trajectory (A smoothed), stamps, gaps and GNSS model."""
    sol = nav.smoothed if nav.smoothed is not None else nav.forward
    epoch = int(log.imu.time_ns[0])
    t_imu = (log.imu.time_ns - epoch) * 1e-9
    dt_ns = int(round(float(np.median(np.diff(log.imu.time_ns)))))
    t_fix = (log.fix.time_ns - epoch) * 1e-9
    gnss_dt = float(np.median(np.diff(t_fix))) if t_fix.size > 1 else 1.0
    t_s, lat, lon, hgt = _with_static_start(log, nav, t_imu, t_fix, sol,
                                            config.filter_options().alignment)
    mission0 = float(t_s[0])
    outages = tuple((float(a - mission0 + 1e-6), float(b - mission0 - 1e-6))
                    for a, b in _gaps(t_fix, 2.5))
    pos_h, pos_v = _median_sigmas(log.fix.pos_cov_ned_m2)
    vel_h, vel_v = _median_sigmas(log.vel.vel_cov_ned_m2ps2) if len(log.vel) else (0.05, 0.1)
    # receivers often report nominal sigmas far above their noise: never simulate more noise
    # than the records show about A's smoothed solution (else A cannot even align the same way)
    rp, rv = _residual_rms(log, sol, epoch)
    k = RESIDUAL_NOISE_FACTOR
    noise_p = (min(pos_h, k * rp[0]), min(pos_v, k * rp[1]))
    noise_v = (min(vel_h, k * rv[0]), min(vel_v, k * rv[1]))
    gnss = GnssModel(rate_hz=1.0 / gnss_dt, pos_noise_m=noise_p, vel_noise_mps=noise_v,
                     reported_pos_sigma_m=(pos_h, pos_v), reported_vel_sigma_mps=(vel_h, vel_v),
                     lever_arm_b_m=config.gnss.lever_arm_m,
                     outages_s=tuple(o for o in outages if o[1] > o[0] and o[1] > 0))
    if vehicle is None:
        hspan = float(np.ptp(sol.height_m))
        vehicle = "aircraft" if hspan > 30.0 else "car"
    return FlightTemplate(t_s, lat, lon, hgt, epoch, dt_ns, _gaps(t_imu, 1.5), gnss,
                          len(log.vel) > 0, vehicle)


def _with_static_start(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                       t_imu: np.ndarray, t_fix: np.ndarray, sol: nav_filter.NavSolution,
                       options: AlignmentOptions):
    """A's smoothed trajectory (t [s], lat, lon [rad], height [m]), with the log's initial
    static period prepended (at the median of its fixes, 2 Hz) when A found one and started
    after it (motion alignment), so that the simulated flight has the same static start
    (``imu_avar_gyro_static``). The position is held to the last GNSS velocity before A's
    start that is at rest by the alignment's test (:func:`pospp.nav.alignment.
    gnss_moving_windows`, each record alone), not only to the end of A's static period, so
    that the spline of the simulator joins the held position to A's first epoch over the
    start of motion only (not over minutes of rest after an IMU window that moved)."""
    t, lat, lon, hgt = sol.t_s, sol.lat_rad, sol.lon_rad, sol.height_m
    end = nav.alignment.static_end_s
    if end is None or not end < t[0] - 1.0:
        return t, lat, lon, hgt
    m = (t_fix >= t_imu[0]) & (t_fix <= end)
    if not m.any():
        return t, lat, lon, hgt
    end = max(end, _rest_end_s(log, end, float(t[0]) - 1.0, options))
    ts = np.arange(float(t_imu[0]) + 1e-3, end, 0.5)
    fix = log.fix
    pre = [np.full(ts.size, float(np.median(x[m])))
           for x in (fix.lat_rad, fix.lon_rad, fix.height_m)]
    return (np.concatenate([ts, t]), *(np.concatenate([p, x])
                                      for p, x in zip(pre, (lat, lon, hgt), strict=True)))


def _rest_end_s(log: mcap_reader.FlightLog, end_s: float, limit_s: float,
                options: AlignmentOptions) -> float:
    """The last GNSS velocity time [s from the first IMU stamp] in (end_s, limit_s] before
    the first record that moves (``end_s`` when the first one moves or there are none)."""
    if not len(log.vel):
        return end_s
    tv = (log.vel.time_ns - int(log.imu.time_ns[0])) * 1e-9
    m = (tv > end_s) & (tv <= limit_s)
    if not m.any():
        return end_s
    order = np.argsort(tv[m], kind="stable")
    tv = tv[m][order]
    moving = gnss_moving_windows(tv, tv, tv, log.vel.v_n_mps[m][order],
                                 log.vel.vel_cov_ned_m2ps2[m][order], options)
    n_rest = int(np.argmax(moving)) if moving.any() else tv.size
    return float(tv[n_rest - 1]) if n_rest > 0 else end_s


def _residual_rms(log: mcap_reader.FlightLog, sol: nav_filter.NavSolution, epoch_ns: int
                  ) -> tuple[tuple[float, float], tuple[float, float]]:
    """RMS (horizontal per axis, vertical) of the GNSS records minus A's smoothed solution,
    position [m] and velocity [m/s] (inf when there are none in A's span)."""
    from pospp import earth

    def rms(x: np.ndarray) -> tuple[float, float]:
        if x.shape[0] < 3:
            return np.inf, np.inf
        return float(np.sqrt(np.mean(x[:, :2] ** 2))), float(np.sqrt(np.mean(x[:, 2] ** 2)))

    tf = (log.fix.time_ns - epoch_ns) * 1e-9
    m = (tf >= sol.t_s[0]) & (tf <= sol.t_s[-1])
    lat = np.interp(tf[m], sol.t_s, sol.lat_rad)
    r_m, r_n = earth.principal_radii_m(lat)
    dp = np.stack([(log.fix.lat_rad[m] - lat) * r_m,
                   (log.fix.lon_rad[m] - np.interp(tf[m], sol.t_s, sol.lon_rad)) * r_n
                   * np.cos(lat),
                   -(log.fix.height_m[m] - np.interp(tf[m], sol.t_s, sol.height_m))], axis=1)
    tv = (log.vel.time_ns - epoch_ns) * 1e-9
    mv = (tv >= sol.t_s[0]) & (tv <= sol.t_s[-1])
    dv = log.vel.v_n_mps[mv] - np.stack([np.interp(tv[mv], sol.t_s, sol.v_n_mps[:, i])
                                         for i in range(3)], axis=1)
    return rms(dp), rms(dv)


def _median_sigmas(cov: np.ndarray) -> tuple[float, float]:
    d = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))
    return float(np.median(d[:, :2])), float(np.median(d[:, 2]))


def simulate_log(tpl: FlightTemplate, imu: ImuErrorModel, gnss: GnssModel, *,
                 seed: int = SIM_SEED) -> mcap_reader.FlightLog:
    """The flight simulated along the template: same IMU interval and gaps, GNSS rate, gaps
    and sigmas; the IMU's first stamp is A's first epoch."""
    t = tpl.time_s
    start = tpl.epoch_ns + int(round(t[0] * 1e9)) - tpl.imu_dt_ns
    sim = simulate_along(t, tpl.lat_rad, tpl.lon_rad, tpl.height_m, vehicle=tpl.vehicle,
                         imu_grade=imu, gnss=gnss, seed=seed, imu_rate_hz=1e9 / tpl.imu_dt_ns,
                         start_time_ns=start)
    ims = sim.imu
    ts = (ims.time_ns - tpl.epoch_ns) * 1e-9
    keep = np.ones(ts.shape, bool)
    for a, b in tpl.imu_gaps_s:
        keep &= ~((ts > a) & (ts < b))
    if not keep.all():
        cut: dict[str, Any] = {k: v[keep] for k, v in vars(ims).items()
                               if isinstance(v, np.ndarray) and v.shape[:1] == keep.shape}
        ims = replace(ims, **cut)
    vel = sim.vel if tpl.has_velocity else replace(
        sim.vel, **{k: v[:0] for k, v in vars(sim.vel).items() if isinstance(v, np.ndarray)})
    return mcap_reader.FlightLog(ims, sim.fix, vel, "simulation")


def bma_leg_stats(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                  config: PipelineConfig) -> dict[str, Stat]:
    """B minus A on the flight's legs, as the leg-based workflow sees them: the calibration
    stage as configured, then :func:`pospp.diagnose.workflow.diagnose_replays` with its base model
    only (the pipeline's formulation, transition and gyro-random-walk weighting; no
    candidates), whose per-leg gaps give :func:`pospp.simcompare.stats.leg_stats`. Empty
    when the flight has fewer than 3 legs or no calibration."""
    from pospp.diagnose.workflow import diagnose_replays

    imu = pipeline.imu_increments(log)
    try:
        calib_run, _ = pipeline.calibrate_from_a(imu, nav, config)
    except ValueError:
        return {}
    if not calib_run.calibrated or len(calib_run.replays) < MIN_LEGS:
        return {}
    replays = [calib_run.replays[i] for i in sorted(calib_run.replays)]
    d = diagnose_replays(replays, base_formulation=config.pairs.formulation,
                 base_transition=config.pairs.transition, noise="gyro_rw",
                 gyro_arw_radpsqrts=pipeline.imu_tuning(config).noise().gyro_arw_radpsqrts,
                 effects=(), max_steps=0)
    return leg_stats(np.array([g.gap_before_mps for g in d.legs]),
                     np.array([g.heldout_gap_before_mps for g in d.legs]))


def log_stats(log: mcap_reader.FlightLog, config: PipelineConfig, *, vehicle: str,
              nav: nav_filter.FilterResult | None = None
              ) -> tuple[FlightStats, nav_filter.FilterResult]:
    """Run A as configured (unless ``nav`` is given) and once more forward with lever-arm and
    scale-factor states, and return the flight's statistics (A's time axis: from the log's
    first IMU stamp), with B minus A on its legs where it has legs."""
    if nav is None:
        nav = pipeline.navigate(log, config)
    est_cfg = replace(config, gnss=replace(config.gnss, estimate_lever_arm=True),
                      filter=replace(config.filter, estimate_scale_factors=True))
    opts = replace(config.filter_options(), smoother=False)
    try:
        est = pipeline.navigate(log, est_cfg, options=opts)
    except ValueError:
        est = None
    epoch = int(log.imu.time_ns[0])
    t_imu = (log.imu.time_ns - epoch) * 1e-9
    fs = flight_stats(t_imu, log.imu.w_ib_b_radps, log.imu.f_ib_b_mps2, nav, est,
                      vehicle=vehicle, gnss_sigma=reported_sigmas(log, epoch))
    return FlightStats({**fs.stats, **bma_leg_stats(log, nav, config)}, fs.hf_peak_hz), nav


def reported_sigmas(log: mcap_reader.FlightLog, epoch_ns: int
                    ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The records' reported NED sigmas: kind (0 position, 1 velocity) -> (times [s from
    ``epoch_ns``], (M, 3) sigmas [m, m/s])."""
    out = {}
    for kind, tab, cov in ((0, log.fix, log.fix.pos_cov_ned_m2),
                           (1, log.vel, log.vel.vel_cov_ned_m2ps2)):
        if len(tab):
            out[kind] = ((tab.time_ns - epoch_ns) * 1e-9,
                         np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None)))
    return out


def simulate_stats(tpl: FlightTemplate, config: PipelineConfig) -> SimulateFn:
    """simulate(imu, gnss, draw=0) -> statistics of A on the simulated flight (for
    compare_flights): draw 0 with ``SIM_SEED``, draw k with ``SIM_SEED + k``."""

    def run(imu: ImuErrorModel, gnss: GnssModel, draw: int = 0) -> FlightStats:
        return log_stats(simulate_log(tpl, imu, gnss, seed=SIM_SEED + draw), config,
                         vehicle=tpl.vehicle)[0]

    return run


def base_imu_model(config: PipelineConfig) -> ImuErrorModel:
    """The simulator's IMU model for the configured grade (SIM_GRADES maps the names)."""
    return imu_grade(SIM_GRADES.get(config.imu.grade, config.imu.grade))


def compare_log(log: mcap_reader.FlightLog, config: PipelineConfig, *,
                nav: nav_filter.FilterResult | None = None, vehicle: str | None = None,
                imu: ImuErrorModel | None = None, gnss: GnssModel | None = None,
                max_steps: int = 4, library: tuple[SimEffect, ...] = LIBRARY
                ) -> tuple[Comparison, FlightTemplate]:
    """The whole comparison for one log (numeric; no files); ``library``: the effects
    (default :data:`pospp.simcompare.effects.LIBRARY`)."""
    if nav is None:
        nav = pipeline.navigate(log, config)
    tpl = flight_template(log, nav, config, vehicle=vehicle)
    measured, _ = log_stats(log, config, vehicle=tpl.vehicle, nav=nav)
    imu = base_imu_model(config) if imu is None else imu
    gnss = tpl.gnss if gnss is None else gnss
    return compare_flights(measured, simulate_stats(tpl, config), imu, gnss,
                           max_steps=max_steps, library=library), tpl


@locked("pospp compare-sim")
def compare_sim_run(run_dir: str | Path, *, out: str | Path | None = None,
                    max_steps: int = 4, library: tuple[SimEffect, ...] = LIBRARY,
                    force: bool = False) -> Comparison:
    """``pospp compare-sim RUN_DIR``: write sim_comparison.parquet and sim_model.toml.

    ``out`` is the model file (default RUN_DIR/sim_model.toml; never the run's input or
    another file of a run folder, an existing one only with ``force``:
    :func:`pospp.io.run_folder.check_output_file`). The report is re-rendered. The run
    folder's lock is held throughout.
    """
    run, meta, path, config = pipeline.reopen_run(run_dir)
    model_file = run_folder.check_output_file(out or run / "sim_model.toml", run=run,
                                              own_names=frozenset({"sim_model.toml"}),
                                              force=force)
    log = pipeline.ingest(path, config)
    try:
        comp, tpl = compare_log(log, config, max_steps=max_steps, library=library)
    except ValueError as exc:  # e.g. a flight too short or too slow to simulate along
        raise ValueError(f"{run}: cannot compare {path.name} with its simulation: {exc}") from exc
    out_meta = {k: meta[k] for k in ("input_file", "input_sha256", "config")}
    out_meta["vehicle"] = tpl.vehicle
    parquet_tables.write_table(run / "sim_comparison.parquet", comparison_columns(comp),
                               "sim_comparison", metadata=out_meta)
    named = ", ".join(comp.effects_added) or "none"
    header = (f"pospp compare-sim of {path.name}: effects added: {named}.\n"
              f"Simulate with: pospp simulate --model THIS_FILE.toml ... ([imu]: "
              f"pospp.sim.sensors.ImuErrorModel fields, [gnss]: pospp.sim.gnss.GnssModel).")
    report_files.write_text(model_file, model_toml(comp.imu_model, comp.gnss_model,
                                                   header=header))
    pipeline._render_report(run)
    return comp
