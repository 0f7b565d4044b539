"""Regenerate the numbers and figures of docs/results.md (run on demand, about 5 min).

Run from the repository root: ``python docs/_make_results.py [OUT_DIR]`` (default
``/tmp/pospp_results``). It converts the measured logs of ``../shared/data`` (never copied into
the repository), simulates the SYNTHETIC tactical-grade IMU along the KF-GINS RTK drive, runs
the pipelines of ``pipelines/realdata/``, evaluates against the references, runs the
shortest-leg study, prints the Markdown tables of docs/results.md and writes
``docs/img/results_*.png``.
"""

from __future__ import annotations

import functools
import json
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pospp import flight_stages, pipeline  # noqa: E402
from pospp.api.studies import evaluate_run  # noqa: E402
from pospp.calib import stage as calib_stage  # noqa: E402
from pospp.calib.noise_model import noise_basis  # noqa: E402
from pospp.calib.replay import ImuIncrements, SolutionA  # noqa: E402
from pospp.calib.stage import CalibrationOptions, calibrate_flight  # noqa: E402
from pospp.config import config_from_dict, load_config  # noqa: E402
from pospp.convert import convert  # noqa: E402
from pospp.io.mcap_reader import read_flight_log  # noqa: E402
from pospp.io.parquet_tables import read_reference_trajectory  # noqa: E402
from pospp.io.simulation_files import write_simulation  # noqa: E402
from pospp.nav import filter as nav_filter  # noqa: E402
from pospp.nav.strapdown import increments_from_rates  # noqa: E402
from pospp.nav.tuning import tuning_preset  # noqa: E402
from pospp.sim.api import simulate, simulate_along  # noqa: E402
from pospp.sim.gnss import GnssModel  # noqa: E402
from pospp.sim.profile import parse_profile  # noqa: E402
from pospp.sim.sensors import ImuErrorModel  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
IMG = ROOT / "docs" / "img"
DPH = np.pi / 180.0 / 3600.0

TACTICAL = ImuErrorModel(
    gyro_bias_dph=(5.0, -4.0, 3.0), gyro_arw_dpsh=(0.1, 0.1, 0.1),
    gyro_gm_sigma_dph=(0.5, 0.5, 0.5), gyro_gm_tau_s=600.0,
    accel_bias_ug=(300.0, -200.0, 250.0), accel_vrw_mpsph=(0.05, 0.05, 0.05),
    accel_gm_sigma_ug=(50.0, 50.0, 50.0), accel_gm_tau_s=600.0)
"""The synthetic tactical IMU (body FRD): 5/-4/3 deg/h constant gyro bias, 0.5 deg/h
Gauss-Markov drift (600 s), ARW 0.1 deg/sqrt(h), 300/-200/250 ug accelerometer bias."""
MEMS = ImuErrorModel(
    gyro_bias_dph=(360.0, -288.0, 216.0), gyro_arw_dpsh=(0.6, 0.6, 0.6),
    gyro_gm_sigma_dph=(10.0, 10.0, 10.0), gyro_gm_tau_s=300.0,
    accel_bias_ug=(3000.0, -2000.0, 2500.0), accel_vrw_mpsph=(0.3, 0.3, 0.3),
    accel_gm_sigma_ug=(300.0, 300.0, 300.0), accel_gm_tau_s=300.0)
"""A synthetic consumer-MEMS IMU for the shortest-leg study."""
KFGINS_GNSS = GnssModel(rate_hz=1.0, pos_noise_m=(0.02, 0.04), vel_noise_mps=(0.02, 0.03))

# (run name, MCAP stem, pipeline, conversion (source, options) or None, reference file stem)
RUNS = [
    ("ansfl_quadrotor_straightline", "quad", ("ansfl_quadrotor_straightline",
     {"fmt": "ansfl_quadrotor_raw", "unit": 1, "recording": 2}), "quad.reference"),
    ("ardupilot_plane_testlog2", "ardupilot", ("ardupilot_plane_testlog2", {}), None),
    ("comma2k19_example1", "comma", ("comma2k19_example1", {}), "comma.reference"),
    ("kfgins_synthetic_tactical", "kfgins_tactical", None, "kfgins_tactical.truth"),
]


def simulate_kfgins(out: Path, grade: str) -> Path:
    """SYNTHETIC: an IMU of ``grade`` simulated along the KF-GINS RTK drive (seed 8, 100 Hz)."""
    convert(DATA / "gnss_reference_only" / "kfgins_dataset1", out / "kfgins.mcap",
            fmt="kfgins_rtk")
    ref = read_reference_trajectory(out / "kfgins.reference.parquet")
    t_s = (ref.time_ns - ref.time_ns[0]) / 1e9
    model = {"tactical": TACTICAL, "mems": MEMS}[grade]
    sim = simulate_along(t_s, ref.lat_rad, ref.lon_rad, ref.height_m, vehicle="car",
                         imu_grade=model, gnss=KFGINS_GNSS, seed=8, imu_rate_hz=100.0,
                         name=f"kfgins_{grade}")
    return write_simulation(sim, out)["mcap"]


def mean_bias_dph(out: Path, stem: str) -> np.ndarray:
    """Mean realised body gyro bias over the whole simulated run [deg/h]."""
    b = pd.read_parquet(out / f"{stem}.bias.parquet")
    return b[["gyro_bias_x_dph", "gyro_bias_y_dph", "gyro_bias_z_dph"]].mean().to_numpy()


def leg_study(out: Path, stem: str, pipe: str, grade: str,
              durations_s: tuple[float, ...] = (10.0, 15.0, 20.0, 30.0)) -> pd.DataFrame:
    """Shortest usable leg: calibrate with legs >= d for each d, both noise models."""
    cfg = load_config(ROOT / "pipelines" / "realdata" / f"{pipe}.toml")
    cfg = replace(cfg, imu=replace(cfg.imu, grade=grade))
    log = pipeline.ingest(out / f"{stem}.mcap", cfg)
    nav = pipeline.navigate(log, cfg)
    imu = pipeline.imu_increments(log)
    ref = SolutionA(*nav_filter.solution_a_fields(nav, which="smoothed"))
    truth = mean_bias_dph(out, stem)
    rows = []
    for d in durations_s:
        for noise in ("gyro_rw", "white"):
            legs = replace(cfg.legs, min_duration_s=d, duration_tolerance_s=0.0)
            r = calibrate_flight(imu, ref, CalibrationOptions(
                legs_cfg=legs.thresholds(), replay_cfg=cfg.replay.options(),
                pairs_cfg=cfg.pairs.policy(), noise=noise,
                gyro_arw_dpsh=flight_stages.imu_tuning(cfg).gyro_arw_dpsh))
            row = {"grade": grade, "min_duration_s": d, "noise": noise, "n_legs": len(r.legs),
                   "n_pairs_used": r.summary().get("n_pairs_used", 0)}
            if r.calibrated:
                cal = pd.DataFrame(r.tables(0)["calibration"])
                cal = cal[(cal.pair_id == -1) & (cal.formulation == "body")].set_index("parameter")
                for ax, k in (("x", 0), ("y", 1)):
                    v, s = cal.loc[f"gyro_bias_{ax}", ["value", "sigma"]]
                    row |= {f"bias_{ax}_dph": v, f"sigma_{ax}_dph": s,
                            f"z_{ax}": (v - truth[k]) / s}
            rows.append(row)
    return pd.DataFrame(rows)


def _noise_step(step_s: float) -> None:
    """What-if: the gyro_rw least squares on samples every ``step_s`` (pipeline: 10 s).

    pospp.calib.stage calls ``noise_basis(rep)`` with its default 10 s step and does not expose
    it; this swaps the stage's reference for the study only (restore with 10.0).
    """
    calib_stage.noise_basis = functools.partial(noise_basis, noise_step_s=step_s)


def back_and_forth(leg_s: float, n_legs: int = 4) -> object:
    """A car driving a straight road back and forth: 300 s static, n legs of ``leg_s`` at
    12 m/s joined by 180 deg U-turns (15 deg/s)."""
    return parse_profile({
        "name": f"back_and_forth_{leg_s:g}s",
        "start": {"lat_deg": 30.5, "lon_deg": 114.5, "height_m": 20.0, "heading_deg": 0.0},
        "options": {"turn_bank": "none", "blend_s": 2.0},
        "segment": [
            {"type": "static", "duration_s": 300.0},
            {"type": "accelerate", "to_speed_mps": 12.0, "duration_s": 20.0},
            {"type": "survey", "legs": n_legs, "heading_deg": 0.0, "leg_duration_s": leg_s,
             "turn_rate_dps": 15.0, "turn_direction": "alternate"},
            {"type": "accelerate", "to_speed_mps": 0.0, "duration_s": 20.0},
            {"type": "static", "duration_s": 30.0}]})


def leg_length_study(grade: str, leg_s: tuple[float, ...] = (10.0, 15.0, 20.0, 30.0, 60.0,
                                                             120.0, 300.0)) -> pd.DataFrame:
    """Shortest usable leg per IMU grade (SYNTHETIC, controlled): legs of each length flown,
    calibrated as the pipeline does (gyro_rw, 10 s noise step), with a 2 s noise step
    (what-if) and with white noise. Per row: legs found, median per-pair sigma of the body
    gyro bias x/y, and the all-pairs estimate against the mean realised bias."""
    model = {"tactical": TACTICAL, "mems": MEMS}[grade]
    turn_on_dph = tuning_preset(grade).gyro_bias_sigma_dph
    rows = []
    for L in leg_s:
        sim = simulate(back_and_forth(L), imu_grade=model, gnss=KFGINS_GNSS, seed=3,
                       imu_rate_hz=100.0)
        cfg = config_from_dict({
            "imu": {"grade": grade},
            "legs": {"min_duration_s": 0.6 * L, "duration_tolerance_s": 0.0, "trim_s": 1.0,
                     "smoothing_s": 2.0},
            "replay": {"horizon_s": L}})
        epoch = int(sim.imu.time_ns[0])
        nav = nav_filter.run_integrated_navigation(
            sim.imu, sim.fix, sim.vel, flight_stages.imu_tuning(cfg), epoch_ns=epoch,
            output_rate_hz=10.0)
        imu = ImuIncrements(*increments_from_rates(
            sim.imu.time_ns, sim.imu.w_ib_b_radps, sim.imu.f_ib_b_mps2, epoch_ns=epoch))
        ref = SolutionA(*nav_filter.solution_a_fields(nav, which="smoothed"))
        truth = sim.imu_errors.gyro_bias_radps.mean(axis=0) / DPH
        for label, noise, step in (("pipeline (gyro_rw, 10 s)", "gyro_rw", 10.0),
                                   ("gyro_rw, 2 s step", "gyro_rw", 2.0),
                                   ("white", "white", 10.0)):
            _noise_step(step)
            row = {"grade": grade, "leg_flown_s": L, "model": label}
            try:
                r = calibrate_flight(imu, ref, CalibrationOptions(
                legs_cfg=cfg.legs.thresholds(), replay_cfg=cfg.replay.options(),
                pairs_cfg=cfg.pairs.policy(), noise=noise,
                gyro_arw_dpsh=flight_stages.imu_tuning(cfg).gyro_arw_dpsh))
            except (IndexError, ValueError) as exc:
                rows.append(row | {"result": f"fails: {type(exc).__name__}"})
                continue
            finally:
                _noise_step(10.0)
            row |= {"legs_found_s": "/".join(f"{lg.duration_s:.0f}" for lg in r.legs)}
            if not r.calibrated:
                rows.append(row | {"result": r.reason[:60]})
                continue
            cal = pd.DataFrame(r.tables(0)["calibration"])
            cal = cal[(cal.formulation == "body")]
            pp = cal[(cal.pair_id >= 0) & cal.parameter.isin(["gyro_bias_x", "gyro_bias_y"])]
            joint = cal[cal.pair_id == -1].set_index("parameter")
            z = [(joint.loc[f"gyro_bias_{a}", "value"] - truth[k])
                 / joint.loc[f"gyro_bias_{a}", "sigma"] for k, a in enumerate("xy")]
            sig_pair = float(pp.sigma.median())
            rows.append(row | {
                "pair_sigma_dph": sig_pair,
                "sigma_over_turn_on": sig_pair / turn_on_dph,
                "all_x_dph": joint.loc["gyro_bias_x", "value"],
                "all_y_dph": joint.loc["gyro_bias_y", "value"],
                "true_x_dph": truth[0], "true_y_dph": truth[1],
                "all_sigma_dph": float(joint.loc["gyro_bias_x", "sigma"]),
                "max_abs_z": float(np.max(np.abs(z))),
                "result": "ok"})
    return pd.DataFrame(rows)


def quad_what_if(out: Path) -> pd.DataFrame:
    """The quadrotor's 6-10 s legs calibrated with a 2 s noise step (what-if, not the
    pipeline) and with white noise."""
    cfg = load_config(ROOT / "pipelines" / "realdata" / "ansfl_quadrotor_straightline.toml")
    cfg = replace(cfg, legs=replace(cfg.legs, min_duration_s=5.0))
    log = pipeline.ingest(out / "quad.mcap", cfg)
    nav = pipeline.navigate(log, cfg)
    imu = pipeline.imu_increments(log)
    ref = SolutionA(*nav_filter.solution_a_fields(nav, which="smoothed"))
    rows = []
    for label, noise, step in (("gyro_rw, 2 s step", "gyro_rw", 2.0),
                               ("white", "white", 10.0)):
        _noise_step(step)
        try:
            r = calibrate_flight(imu, ref, CalibrationOptions(
                legs_cfg=cfg.legs.thresholds(), replay_cfg=cfg.replay.options(),
                pairs_cfg=cfg.pairs.policy(), noise=noise,
                gyro_arw_dpsh=flight_stages.imu_tuning(cfg).gyro_arw_dpsh))
        finally:
            _noise_step(10.0)
        cal = pd.DataFrame(r.tables(0)["calibration"])
        c = cal[(cal.formulation == "body") & cal.parameter.isin(["gyro_bias_x",
                                                                  "gyro_bias_y"])]
        for _, x in c.iterrows():
            rows.append({"model": label, "pair_id": x.pair_id, "parameter": x.parameter,
                         "value_dph": x.value, "sigma_dph": x.sigma})
        s = r.summary()
        rows.append({"model": label, "pair_id": "B at horizon", "parameter": "dv before/after",
                     "value_dph": s.get("dv_before_mps"), "sigma_dph": s.get("dv_after_mps")})
    return pd.DataFrame(rows)


def reference_gyro_bias_dph(out: Path, stem: str) -> tuple[np.ndarray, np.ndarray]:
    """Independent check of a quadrotor calibration: IMU rate minus the DJI attitude's rate.

    The body rate of the reference is the rotation vector of C_nb(k)^T C_nb(k+1) over each
    0.1 s interval (body axes); the IMU rate is averaged over the same interval. Their
    difference is the gyro bias (plus the Earth rate, at most 15 deg/h, and the DJI attitude's
    own errors). Returns the median difference and its robust spread per axis [deg/h].
    """
    from scipy.spatial.transform import Rotation

    log = read_flight_log(out / f"{stem}.mcap")
    ref = read_reference_trajectory(out / f"{stem}.reference.parquet")
    rot = Rotation.from_euler("ZYX", ref.rpy_rad[:, ::-1])
    t_ref = (ref.time_ns - log.imu.time_ns[0]) / 1e9
    w_ref = (rot[:-1].inv() * rot[1:]).as_rotvec() / np.diff(t_ref)[:, None]
    t_imu = (log.imu.time_ns - log.imu.time_ns[0]) / 1e9
    dt = np.diff(np.concatenate([[t_imu[0] - np.median(np.diff(t_imu))], t_imu]))
    angle = np.vstack([np.zeros(3), np.cumsum(log.imu.w_ib_b_radps * dt[:, None], axis=0)])
    t_edge = np.concatenate([[t_imu[0] - dt[0]], t_imu])
    ang_ref = np.stack([np.interp(t_ref, t_edge, angle[:, i]) for i in range(3)], axis=1)
    w_imu = np.diff(ang_ref, axis=0) / np.diff(t_ref)[:, None]
    inside = (t_ref[:-1] > t_edge[0]) & (t_ref[1:] < t_edge[-1])
    d = (w_imu - w_ref)[inside] / DPH
    med = np.median(d, axis=0)
    return med, 1.4826 * np.median(np.abs(d - med), axis=0) / np.sqrt(len(d))


def table_md(df: pd.DataFrame, floatfmt: str = "{:.3g}") -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        cells = [floatfmt.format(v) if isinstance(v, float) else str(v) for v in r]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    IMG.mkdir(parents=True, exist_ok=True)
    simulate_kfgins(out, "tactical")
    results = {}
    for name, stem, conv, ref in RUNS:
        if conv is not None:
            src, opts = conv
            convert(DATA / src, out / f"{stem}.mcap", **opts)
        cfg = load_config(ROOT / "pipelines" / "realdata" / f"{name}.toml")
        run_dir = out / f"run_{stem}"
        outcome = pipeline.process_flight(out / f"{stem}.mcap", cfg, run_dir, force=True)
        tables = {k: pd.read_parquet(run_dir / f"{k}.parquet") for k in
                  ("legs", "pairs", "calibration", "leg_errors", "diagnosis", "messages")
                  if (run_dir / f"{k}.parquet").is_file()}
        if ref is not None:
            skip = 300.0 if name.startswith("kfgins") else 0.0
            tables["evaluation"] = evaluate_run(run_dir, out / f"{ref}.parquet", skip_s=skip)
            shutil.copyfile(run_dir / "evaluation.png", IMG / f"results_{stem}_evaluation.png")
        results[name] = (outcome, tables)
        print(f"\n## {name}: status {outcome.status}")
        print(json.dumps({k: v for k, v in outcome.summary.items()
                          if k not in ("input_sha256",)}, default=str))
        for k in ("legs", "pairs", "diagnosis", "evaluation"):
            if k in tables:
                print(f"\n{k}:\n{tables[k].to_string(max_colwidth=40)}")
        if "calibration" in tables:
            c = tables["calibration"]
            print(c[(c.pair_id == -1)].to_string())
        m = tables["messages"]
        print("\nmessages:", m.groupby(["severity", "stage"]).size().to_dict())
    print("\ntactical injected mean bias [deg/h]:", mean_bias_dph(out, "kfgins_tactical"))
    qb, qs = reference_gyro_bias_dph(out, "quad")
    print(f"quadrotor gyro bias from IMU minus DJI attitude rate [deg/h] {qb.round(0)} "
          f"+- {qs.round(0)}")
    print("\nquadrotor what-if (6-10 s legs):\n" + table_md(quad_what_if(out)))
    # shortest usable leg: real KF-GINS geometry, then controlled back-and-forth legs
    kf = leg_study(out, "kfgins_tactical", "kfgins_synthetic_tactical", "tactical",
                   durations_s=(10.0, 15.0, 20.0))
    print("\nKF-GINS legs >= d:\n" + table_md(kf))
    study = pd.concat([leg_length_study("tactical"), leg_length_study("mems")])
    print("\nshortest-leg study:\n" + table_md(study))
    figures(results, study, out)


def figures(results: dict, study: pd.DataFrame, out: Path) -> None:
    # B's error over each usable leg, before and after compensation (only the KF-GINS run
    # calibrates)
    le = results["kfgins_synthetic_tactical"][1]["leg_errors"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for (leg, stage), g in le.groupby(["leg_id", "stage"]):
        c = "C3" if stage == "before" else "C0"
        lab = stage if leg == 0 else None
        axes[0].plot(g.t_s, np.hypot(g.dvn_mps, g.dve_mps), color=c, lw=0.8, label=lab)
        axes[1].plot(g.t_s, np.hypot(g.dpn_m, g.dpe_m), color=c, lw=0.8, label=lab)
    axes[0].set_ylabel("|B - A| horizontal velocity [m/s]")
    axes[1].set_ylabel("|B - A| horizontal position [m]")
    for ax in axes:
        ax.set_xlabel("time since leg start [s]")
        ax.legend()
    fig.suptitle("SYNTHETIC tactical IMU along the KF-GINS drive: B's error over each leg, "
                 "before and after compensation", fontsize=9)
    fig.tight_layout()
    fig.savefig(IMG / "results_leg_errors.png", dpi=110)
    # per-pair calibrated body gyro bias vs injected (KF-GINS synthetic)
    cal = results["kfgins_synthetic_tactical"][1]["calibration"]
    truth = mean_bias_dph(out, "kfgins_tactical")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, axis, k in ((axes[0], "x", 0), (axes[1], "y", 1)):
        c = cal[(cal.formulation == "body") & (cal.parameter == f"gyro_bias_{axis}")]
        ax.errorbar(np.arange(len(c)), c.value, yerr=c.sigma, fmt="o", ms=3)
        ax.axhline(truth[k], color="k", lw=1, label="injected (mean realised)")
        ax.set_xticks(np.arange(len(c)), [str(p) if p >= 0 else "all" for p in c.pair_id],
                      fontsize=6)
        ax.set_xlabel("pair id")
        ax.set_ylabel(f"gyro bias {axis} [deg/h]")
        ax.set_ylim(truth[k] - 15, truth[k] + 15)
        ax.legend()
    fig.suptitle("SYNTHETIC tactical IMU along the KF-GINS drive: body gyro bias per pair "
                 "(1 sigma)", fontsize=9)
    fig.tight_layout()
    fig.savefig(IMG / "results_kfgins_pairs.png", dpi=110)
    # shortest-leg study
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, grade in zip(axes, ("tactical", "mems"), strict=True):
        g0 = study[(study.grade == grade) & (study.result == "ok")]
        for i, (model, g) in enumerate(g0.groupby("model", sort=False)):
            ax.plot(g.leg_flown_s, g.sigma_over_turn_on, "o-", color=f"C{i}",
                    label=f"{model}: pair sigma / turn-on")
            ax.plot(g.leg_flown_s, g.max_abs_z, "^--", color=f"C{i}", alpha=0.6,
                    label=f"{model}: max |error| / sigma (all pairs)")
        ax.axhline(1 / 3, color="k", lw=0.8, ls=":")
        ax.axhline(3.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("leg flown [s]")
        ax.set_ylabel("solid: pair sigma / turn-on sigma; dashed: |error| / sigma")
        ax.set_title(f"SYNTHETIC {grade} IMU, back-and-forth legs", fontsize=9)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(IMG / "results_min_leg.png", dpi=110)

if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("/tmp/pospp_results"))
