"""Monte Carlo of ``pospp compare-sim`` on pospp's simulator (issue 33; docs/compare_sim.md).

    python tests/benchmarks/bench_compare_sim.py null N            # nulls, N seeds per scale
    python tests/benchmarks/bench_compare_sim.py limits [SEEDS]    # each effect's sigma -> limit
    python tests/benchmarks/bench_compare_sim.py iterate [SEEDS] [NAMES]  # the limit at itself
    python tests/benchmarks/bench_compare_sim.py effects N [NAMES] # each effect at 3 x its limit
    python tests/benchmarks/bench_compare_sim.py outsider N
    python tests/benchmarks/bench_compare_sim.py time MCAP PIPELINE [ROUNDS]  # vs pospp run

The flight (about 14 min; short, so that the Monte Carlo is affordable: every statistic the
effects move is there, at sigmas about 1.8 times a 45 min flight's): 300 s at rest (the bias
instability's static Allan variance), a take-off roll to 50 m/s in 40 s (what separates a
GNSS time offset from a forward lever arm), a 100 m climb, three 120 s lines joined by a
right and a left 180 deg turn at 3 deg/s; IMU at 100 Hz, GNSS at 1 Hz with 0.05 / 0.1 m and
0.02 / 0.03 m/s of noise (reported so), antenna at [0.3, 0.1, -1.5] m, configured right.
The pipeline is configured with the ``flight`` grade (paper_flight: ARW 0.01 deg/sqrt(h),
Gauss-Markov drift 0.5 deg/h at 300 s; no accelerometer white noise); the IMU's true gyro
ARW and Gauss-Markov sigma are ``SCALES`` (1/3, 3) times the grade's.

A comparison *names* an effect when a step adds it; ``unexplained`` steps name nothing. The
bias instability is a level of step 0 (the base model) on a flight with a static part: it
counts as named when step 0 reports it differing from the grade, or a step adds it.

Detection limit of an effect: four times the sigma of its fitted size (the z of a single
statistic that the Holm test over the comparison's ~50 statistics at 1 % calls significant),
the sigma measured at an injected size large enough to be named (``limits``); variance-type
effects (vibration, coloured GNSS error, bias instability) have it on the variance: the RMS
limit is sqrt(4 sigma_var).

A variance-type level whose sigma grows with its size (the bias instability: the Allan
variance of 300 s at rest scatters in proportion to the drift's variance, about 19 % of it,
above a floor set by the white noise) has its limit where the sigma is taken at the limit
itself (``iterate``): the size s at which the fitted variance is 4 of its own sigmas above
the prior's, s^2 = s_prior^2 + 4 sigma_var(s), by the iteration s <- sqrt(s_prior^2 + 4
sigma_var(s)) from ``LIMITS`` (s_prior: the configured grade's level, 0 for an effect the
base model has none of). It is measured per noise scale (``SCALE_LIMITS``): the white
noise's floor differs ninefold in variance between the two.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from pospp.compare_sim import compare_log  # noqa: E402
from pospp.config import config_from_dict  # noqa: E402
from pospp.io.mcap_reader import FlightLog  # noqa: E402
from pospp.sim.api import simulate  # noqa: E402
from pospp.sim.gnss import GnssModel  # noqa: E402
from pospp.sim.profile import parse_profile  # noqa: E402
from pospp.sim.sensors import imu_grade  # noqa: E402

SCALES = (1.0 / 3.0, 3.0)
LEVER_B_M = (0.3, 0.1, -1.5)
GNSS = dict(rate_hz=1.0, pos_noise_m=(0.05, 0.1), vel_noise_mps=(0.02, 0.03),
            lever_arm_b_m=LEVER_B_M)
CONFIG = config_from_dict({"input": {"sensor_frame": "frd"}, "imu": {"grade": "flight"},
                           "gnss": {"lever_arm_m": list(LEVER_B_M)},
                           "outputs": {"mcap": False, "report": False, "diagnose": False}})


def profile():
    seg = [{"type": "static", "duration_s": 300.0},
           {"type": "accelerate", "to_speed_mps": 50.0, "duration_s": 40.0},
           {"type": "climb", "rate_mps": 5.0, "delta_m": 100.0},
           {"type": "straight", "duration_s": 120.0},
           {"type": "turn", "angle_deg": 180.0, "rate_dps": 3.0},
           {"type": "straight", "duration_s": 120.0},
           {"type": "turn", "angle_deg": -180.0, "rate_dps": 3.0},
           {"type": "straight", "duration_s": 120.0}]
    return parse_profile({"name": "cs_mc", "start": {"lat_deg": 40.0, "lon_deg": 116.0,
                                                     "height_m": 60.0, "heading_deg": 60.0},
                          "options": {"turn_bank": "coordinated", "blend_s": 5.0},
                          "segment": seg})


def truth_imu(scale: float):
    g = imu_grade("paper_flight")
    return replace(g, gyro_arw_dpsh=tuple(np.multiply(g.gyro_arw_dpsh, scale)),
                   gyro_gm_sigma_dph=tuple(np.multiply(g.gyro_gm_sigma_dph, scale)))


# effect -> (inject(imu, gnss, size) -> (imu, gnss), default size, the named effect, the
# reported parameter(s) compared, the reported value for the size (catalogue sign and unit))
def _vib(imu, gnss, a):
    return replace(imu, accel_vibration_rms_mps2=(a,) * 3, vibration_freq_hz=8.0), gnss


EFFECTS = {
    "vibration": (_vib, 0.05, "vibration", ("accel_vibration_rms",), lambda s: (s,)),
    "time_offset": (lambda i, g, s: (i, replace(g, time_offset_s=s)), 0.03, "time_offset",
                    ("time_offset",), lambda s: (-1e3 * s,)),
    "lever_arm": (lambda i, g, s: (i, replace(g, lever_arm_b_m=tuple(
        np.add(LEVER_B_M, (s, 0.5 * s, 0.0))))), 0.8, "lever_arm",
        ("lever_arm_x", "lever_arm_y"), lambda s: (-s, -0.5 * s)),
    "scale_factor": (lambda i, g, s: (replace(i, gyro_sf_ppm=(0.0, 0.0, s)), g), 1500.0,
                     "scale_factor", ("gyro_sf_z",), lambda s: (s,)),
    "mounting_misalignment": (lambda i, g, s: (_mount(i, s), g), 2000.0,
                              "mounting_misalignment", ("rho_x", "rho_z"),
                              lambda s: (s, 2 * s)),
    "coloured_gnss": (lambda i, g, s: (i, replace(g, pos_gm_sigma_m=(s, 1.5 * s),
                                                  pos_gm_tau_s=60.0)), 0.2, "coloured_gnss",
                      ("pos_gm_sigma_h",), lambda s: (s,)),
    "bias_instability": (lambda i, g, s: (replace(i, gyro_gm_sigma_dph=(s,) * 3), g), 3.0,
                         "bias_instability", ("gyro_gm_sigma",), lambda s: (s,)),
    "accel_bias_ramp": (lambda i, g, s: (replace(i, accel_bias_drift_ugph=(s, 0.0, 0.0)), g),
                        10000.0, "accel_bias_ramp", ("accel_ramp_x",), lambda s: (s,)),
}


def _mount(imu, s_arcsec):
    from pospp.simcompare.effects import mounting_sensor_errors
    from pospp.units import ARCSEC_RAD

    # roll and yaw: the pitch of the attitude model is the flight-path angle, and a pitch
    # mounting reads as an angle of attack (att_offset_pitch's sigma 1140 arcsec here)
    sf, m = mounting_sensor_errors(np.array([s_arcsec, 0.0, 2 * s_arcsec]) * ARCSEC_RAD)
    return replace(imu, gyro_misalign_arcsec=tuple(m), accel_misalign_arcsec=tuple(m),
                   gyro_sf_ppm=tuple(sf), accel_sf_ppm=tuple(sf))


def flight(seed: int, scale: float, effect: str | None = None, size: float = 0.0,
           outsider: bool = False) -> FlightLog:
    imu, gnss = truth_imu(scale), GnssModel(**GNSS)
    if effect is not None:
        imu, gnss = EFFECTS[effect][0](imu, gnss, size)
    sim = simulate(profile(), imu_grade=imu, gnss=gnss, seed=seed, imu_rate_hz=100.0)
    vel = sim.vel
    if outsider:  # a receiver's vertical velocity bias: no effect, no noise level
        vel = replace(vel, v_n_mps=vel.v_n_mps + np.array([0.0, 0.0, -0.05]))
    return FlightLog(sim.imu, sim.fix, vel, f"mc:{seed}")


def run(seed, scale, effect=None, size=0.0, outsider=False):
    t0 = time.perf_counter()
    comp, _ = compare_log(flight(seed, scale, effect, size, outsider), CONFIG)
    return comp, time.perf_counter() - t0


def _reading(comp, effect):
    """(named?, sizes, sigmas) of ``effect`` in the comparison (step 0 for the bias
    instability's level)."""
    name, params = EFFECTS[effect][2], EFFECTS[effect][3]
    for s in comp.steps:
        if s.effect == name:
            d = dict(zip(s.params, zip(s.size, s.sigma, strict=True), strict=True))
            return True, [d[p][0] for p in params], [d[p][1] for p in params]
    if effect == "bias_instability":
        rows = [b for b in comp.base_fit if b.name == "gyro_gm_sigma" and b.differs]
        if rows:
            return True, [rows[0].value], [rows[0].sigma]
    return False, [], []


def mode_null(n: int) -> None:
    for scale in SCALES:
        named = unexpl = 0
        times = []
        for seed in range(n):
            comp, dt = run(100 + seed, scale)
            times.append(dt)
            named += bool(comp.effects_added)
            unexpl += any(s.effect == "unexplained" for s in comp.steps)
            print(f"  null scale {scale:.2f} seed {100 + seed}: named {comp.effects_added} "
                  f"unexplained {[s.target for s in comp.steps if s.effect == 'unexplained']}"
                  f" ({dt:.0f} s)", flush=True)
        print(f"| null | {scale:.2f} | {n} | {n - named} ({100 * (n - named) / n:.0f} %) | "
              f"{unexpl} | {np.mean(times):.0f} s |", flush=True)


def mode_limits(seeds: int, names: list[str]) -> None:
    for name in names:
        _, size, *_ = EFFECTS[name]
        for scale in SCALES:
            sig = []
            for seed in range(seeds):
                comp, _ = run(200 + seed, scale, name, size)
                ok, val, s = _reading(comp, name)
                print(f"  {name} {size} scale {scale:.2f} seed {200 + seed}: named {ok} "
                      f"{np.round(val, 4)} +- {np.round(s, 4)} ({comp.effects_added})",
                      flush=True)
                if ok:
                    sig.append(s[0])
            print(f"| {name} | {scale:.2f} | {size} | {np.median(sig) if sig else np.nan:.4g} |",
                  flush=True)


LIMITS: dict[str, float] = {
    "vibration": 6.4e-4,  # sigma 1.0e-6 m/s^2 at 0.05 m/s^2: sigma_var 1.0e-7 m^2/s^4
    "time_offset": 6.1e-3,  # 4 x 1.53 ms (0.94 ms at 1/3 the noise)
    "lever_arm": 0.35,  # 4 x 0.088 m (x, its sigma with the offset's; 0.056 at 1/3)
    "scale_factor": 832.0,  # 4 x 208 ppm
    "mounting_misalignment": 860.0,  # rho_z = 2 s: 4 x 430 arcsec / 2 (the drift's spread)
    "coloured_gnss": 0.114,  # sigma 0.0081 m at 0.2 m: sigma_var 0.0032 m^2
    "bias_instability": 3.7,  # sigma 0.65 deg/h at 2.65 deg/h (3 x noise): sigma_var 3.5
    "accel_bias_ramp": 7300.0,  # 4 x 1830 ug/h (x, at 10 000 ug/h; 1300 at 1/3)
}
"""Effect -> detection limit (the injected size's unit), from ``limits`` (docs/compare_sim.md):
the larger of the two noise scales'; 3 seeds."""
SCALE_LIMITS: dict[str, dict[float, float]] = {
    # iterate 3 bias_instability: s^2 = 0.5^2 + 4 sigma_var(s) at each scale
    "bias_instability": {SCALES[0]: 1.2, SCALES[1]: 5.9},
}
"""Effect -> noise scale -> detection limit where it is measured per scale (``iterate``)."""
PRIORS = {"bias_instability": float(np.mean(imu_grade("paper_flight").gyro_gm_sigma_dph))}
"""The configured grade's level of a variance-type effect the base model has [its unit]."""


def limit_at(name: str, scale: float) -> float:
    """The detection limit of ``name`` at the noise ``scale``."""
    return SCALE_LIMITS.get(name, {}).get(scale, LIMITS[name])


def mode_iterate(seeds: int, names: list[str], rounds: int = 6) -> None:
    """Per scale, s <- sqrt(s_prior^2 + 4 sigma_var(s)) (module docstring; sigma_var from
    the median over ``seeds`` of the reported upper 1-sigma distance d: (s + d)^2 - s^2) for
    variance-type effects, s <- 4 sigma(s) for the others, until it moves by under 5 %."""
    for name in names:
        var = name in ("vibration", "coloured_gnss", "bias_instability")
        prior = PRIORS.get(name, 0.0)
        for scale in SCALES:
            s = limit_at(name, scale)
            for k in range(rounds):
                sig = []
                for seed in range(seeds):
                    comp, _ = run(200 + seed, scale, name, s)
                    ok, val, sg = _reading(comp, name)
                    print(f"  {name} {s:.4g} scale {scale:.2f} seed {200 + seed}: named {ok} "
                          f"{np.round(val, 4)} +- {np.round(sg, 4)}", flush=True)
                    if ok:
                        sig.append(((val[0] + sg[0]) ** 2 - val[0] ** 2) if var else sg[0])
                if not sig:
                    print(f"| {name} | {scale:.2f} | round {k} | {s:.4g} | not named |")
                    break
                q = float(np.median(sig))
                new = float(np.sqrt(prior ** 2 + 4.0 * q)) if var else 4.0 * q
                print(f"| {name} | {scale:.2f} | round {k} | {s:.4g} | sigma "
                      f"{q:.4g} | -> {new:.4g} |", flush=True)
                if abs(new - s) < 0.05 * s:
                    break
                s = new


def mode_effects(n: int, names: list[str]) -> None:
    for name in names:
        for scale in SCALES:
            size = 3.0 * limit_at(name, scale)
            truth = np.asarray(EFFECTS[name][4](size))
            named = within = 0
            for seed in range(n):
                comp, dt = run(300 + seed, scale, name, size)
                ok, val, _ = _reading(comp, name)
                good = ok and bool(np.all(np.abs(np.asarray(val) - truth)
                                          <= 0.25 * np.abs(truth)))
                named += ok
                within += good
                print(f"  {name} {size:.4g} scale {scale:.2f} seed {300 + seed}: "
                      f"{comp.effects_added} {np.round(val, 4)} (truth {truth}) "
                      f"{'ok' if good else 'MISS'} ({dt:.0f} s)", flush=True)
            print(f"| {name} | {size:.4g} | {scale:.2f} | {named}/{n} | {within}/{n} |",
                  flush=True)


def mode_outsider(n: int) -> None:
    for scale in SCALES:
        ok = 0
        for seed in range(n):
            comp, _ = run(400 + seed, scale, outsider=True)
            good = bool(comp.steps) and comp.effects_added == () and all(
                s.effect == "unexplained" for s in comp.steps)
            ok += good
            print(f"  outsider scale {scale:.2f} seed {400 + seed}: "
                  f"{[(s.target, s.effect) for s in comp.steps]}", flush=True)
        print(f"| outsider | {scale:.2f} | {ok}/{n} unexplained, nothing named |", flush=True)


def mode_time(mcap: str, pipe: str, rounds: int) -> None:
    """``pospp run`` and ``pospp compare-sim`` of one flight, interleaved (the machine's load
    moves both alike), wall-clock per round and their ratio (issue 33 item 5: at most 2)."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        run_dir = Path(d) / "run"
        for k in range(rounds):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "pospp.cli", "run", mcap, "-p", pipe, "-o",
                            str(run_dir), "--force"], check=False, capture_output=True)
            t_run = time.perf_counter() - t0
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "pospp.cli", "compare-sim", str(run_dir),
                            "-o", str(Path(d) / "model.toml")], check=True, capture_output=True)
            t_cs = time.perf_counter() - t0
            print(f"| {k + 1} | {t_run:.1f} | {t_cs:.1f} | {t_cs / t_run:.2f} |", flush=True)


if __name__ == "__main__":
    mode = sys.argv[1]
    if mode == "time":
        mode_time(sys.argv[2], sys.argv[3], int(sys.argv[4]) if len(sys.argv) > 4 else 3)
        sys.exit(0)
    arg = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    names = sys.argv[3:] or list(EFFECTS)
    {"null": lambda: mode_null(arg), "limits": lambda: mode_limits(arg, names),
     "effects": lambda: mode_effects(arg, names), "outsider": lambda: mode_outsider(arg),
     "iterate": lambda: mode_iterate(arg, names)}[mode]()
