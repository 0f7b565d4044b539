"""The null realisations' gain replay against A re-run in full (run on demand).

    python tests/benchmarks/bench_gain_replay.py [survey|sample] [--switch-s 0 60 120]

One null realisation's B minus A response (the pipeline's base: GNSS on A's solution, IMU
summed down to 50 Hz with the legs' epochs kept; grade IMU noise, GNSS 0.05 / 0.1 m,
0.02 m/s, the grade's Gauss-Markov drift) made three ways: A in full, A with the base's
gains from the switch its rule picks (:func:`pospp.nav.filter_state.switch_epoch`), and from
each ``--switch-s`` after the alignment (0: the replay from the start). Prints each one's RMS
gap to the full response as a fraction of the response, three draws. ``survey``: a short
simulated three-leg survey whose first leg starts 84 s after a static alignment; ``sample``:
the bundled sample flight. Results: docs/history/speed_rounds.md, "Speed, seventh round".
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests" / "unit"))

from _missions import SimLog, three_leg_survey  # noqa: E402

from pospp import flight_stages as fs  # noqa: E402
from pospp.calib.replay import SolutionA, replay_velocity_error  # noqa: E402
from pospp.config import config_from_dict, load_config  # noqa: E402
from pospp.diagnose import null_model  # noqa: E402
from pospp.nav import filter as nav_filter  # noqa: E402
from pospp.sim.api import simulate  # noqa: E402
from pospp.sim.gnss import GnssModel  # noqa: E402
from pospp.sim.profile import parse_profile  # noqa: E402


def _case(name: str):
    if name == "sample":
        cfg = load_config(REPO / "pipelines" / "sample.toml")
        return fs.ingest(REPO / "sample_data" / "sample_flight.mcap", cfg), cfg
    profile = dict(three_leg_survey("replay", 120.0, lat_deg=40.0, lon_deg=116.0,
                                    height_m=1000.0, heading_deg=30.0), imu_rate_hz=200)
    gnss = GnssModel(rate_hz=1.0, pos_noise_m=(0.05, 0.1), vel_noise_mps=(0.02, 0.03))
    sim = simulate(parse_profile(profile), imu_grade="paper_flight", gnss=gnss, seed=4)
    cfg = config_from_dict({
        "imu": {"grade": "flight"}, "filter": {"output_rate_hz": 10.0, "smoother": True},
        "legs": {"min_duration_s": 100.0, "min_speed_mps": 20.0},
        "replay": {"reference": "smoothed", "horizon_s": 120.0}})
    return SimLog(sim.imu, sim.fix, sim.vel), cfg


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("case", choices=("survey", "sample"), nargs="?", default="survey")
    ap.add_argument("--switch-s", type=float, nargs="*", default=[0.0, 60.0, 120.0])
    args = ap.parse_args()
    log, cfg = _case(args.case)
    nav = fs.navigate(log, cfg)
    run, _ = fs.calibrate_from_a(fs.imu_increments(log), nav, cfg)
    legs = {leg.leg_id: leg for leg in run.legs}
    base = null_model.decimate_imu(null_model.gnss_on_solution(
        log, nav.smoothed, int(log.imu.time_ns[0]), nav.lever_arm.lever_b_m), 4,
        fs.leg_epochs_ns(log, run.legs))

    def b_minus_a(log_r, **gain_kw):
        nav_r = fs.navigate(log_r, cfg, options=fs.rerun_options(cfg), **gain_kw)
        ref = SolutionA(*nav_filter.solution_a_fields(nav_r, which="smoothed"))
        imu = fs.imu_increments(log_r)
        return nav_r, np.concatenate([replay_velocity_error(
            imu, ref, legs[i], sample_rate_hz=cfg.replay.sample_rate_hz,
            accel_compensation=cfg.replay.accel_compensation)[:, 0:2]
            for i in sorted(run.replays)])

    rec, d0 = b_minus_a(base, record_gains=True)
    gains = rec.gain_replay
    t = gains.t_s
    print(f"{args.case}: legs {[(round(leg.start_s), round(leg.end_s)) for leg in run.legs]}, "
          f"rule's switch +{t[gains.k_from] - t[gains.k_start]:.0f} s after the alignment")
    si = fs.imu_tuning(cfg).noise()
    noise = null_model.NullNoise(
        gyro_arw_radpsqrts=si.gyro_arw_radpsqrts, accel_vrw_mpspsqrts=si.accel_vrw_mpspsqrts,
        pos_sigma_ned_m=np.array([0.05, 0.05, 0.1]), vel_sigma_ned_mps=np.full(3, 0.02),
        gyro_gm_sigma_radps=si.gyro_gm_sigma_radps, gyro_gm_tau_s=si.gyro_gm_tau_s)
    t_align_ns = int(log.imu.time_ns[0]) + round(nav.alignment.t_s * 1e9)
    rng = np.random.default_rng(11)
    for r in range(3):
        pert = null_model.perturb_log(base, noise, rng, from_time_ns=t_align_ns)
        full = b_minus_a(pert)[1] - d0
        size = float(np.sqrt(np.mean(full**2)))
        cells = [f"draw {r}: response {size * 1e3:.1f} mm/s"]
        runs = [("rule", gains)] + [
            (f"+{s:.0f} s", dataclasses.replace(gains, k_from=int(np.searchsorted(
                t, t[gains.k_start] + s)))) for s in args.switch_s]
        for label, g in runs:
            gap = float(np.sqrt(np.mean((b_minus_a(pert, replay=g)[1] - d0 - full) ** 2)))
            cells.append(f"{label} {gap / size:.2%}")
        print(", ".join(cells))


if __name__ == "__main__":
    main()
