"""Benchmark: simulator cost (1.5 h and the whole flight preset at 200 Hz), phases, memory.

Run on demand (not part of the test suite):  python tests/benchmarks/bench_simulate.py
Prints a markdown table; the numbers in docs/benchmarks.md (## Simulator) come from it.
With ``--closure`` it prints instead the closure table of docs/simulator.md (error-free presets
through increments_from_rates + strapdown.integrate, max errors against the truth).

Each case is ``pospp.sim.api.simulate("flight", imu_grade="paper_flight", gnss=<1 Hz with
lever arm>, seed=1, imu_rate_hz=200)``, truncated to the duration shown; wall-clock and
process CPU time (the CPU time is the robust figure on a shared machine), the phase timings
recorded in ``params["numerics"]["timings_s"]``, the peak RSS of the process after
``simulate`` and again after writing the files (each case runs in its own subprocess), and the
time to write the files (MCAP, truth and bias Parquet, params JSON) into a temporary folder.
"""

from __future__ import annotations

import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from pospp import earth, rotation, units
from pospp.io.simulation_files import write_simulation
from pospp.nav.strapdown import increments_from_rates, integrate
from pospp.sim.api import simulate
from pospp.sim.gnss import GnssModel

GNSS = GnssModel(rate_hz=1.0, lever_arm_b_m=(0.5, 0.2, -1.2))


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10


def _run(duration_s: float | None) -> None:
    simulate("sample", imu_rate_hz=50.0, duration_s=10.0)  # warm numba caches of the checks
    w0, c0 = time.perf_counter(), time.process_time()
    sim = simulate("flight", imu_grade="paper_flight", gnss=GNSS, seed=1, imu_rate_hz=200.0,
                   duration_s=duration_s)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    peak = _peak_mib()
    n = len(sim.imu)
    ph = sim.params["numerics"]["timings_s"]
    with tempfile.TemporaryDirectory() as d:
        w1 = time.perf_counter()
        paths = write_simulation(sim, d, "bench")
        write_s = time.perf_counter() - w1
        mcap_mib = paths["mcap"].stat().st_size / 2**20
    print(
        f"| {sim.truth.t_s[-1] / 3600:.2f} h | {n} | {wall:.1f} | {cpu:.1f} | "
        f"{cpu / n * 1e6:.1f} | {ph['increments_s']:.1f} | {ph['imu_errors_s']:.1f} | "
        f"{ph['truth_s']:.1f} | {peak:.0f} | {write_s:.1f} ({mcap_mib:.0f} MiB) | "
        f"{_peak_mib():.0f} |", flush=True
    )


def _closure(sim, window_s: float | None) -> tuple[float, float, float]:
    t_s, dth, dv = increments_from_rates(sim.imu.time_ns, sim.imu.w_ib_b_radps,
                                         sim.imu.f_ib_b_mps2, epoch_ns=sim.start_time_ns)
    n = len(t_s)
    step = n if window_s is None else int(round(window_s / (t_s[1] - t_s[0])))
    worst = np.zeros(3)
    tr = sim.truth
    for a in range(0, n - 1, step):
        b = min(n - 1, a + step)
        out = integrate(t_s[a : b + 1], dth[a:b], dv[a:b], tr.state(a + 1),
                        previous_increments=None if a == 0 else (dth[a - 1], dv[a - 1]))
        s = slice(a + 1, b + 2)
        dp = earth.llh_difference_ned_m(out.lat_rad, out.lon_rad, out.height_m,
                                        tr.lat_rad[s], tr.lon_rad[s], tr.height_m[s])
        att = rotation.angle_between_rad(out.c_nb, rotation.dcm_from_quat(tr.q_nb[s]))
        worst = np.maximum(worst, [np.abs(dp).max(), np.abs(out.v_n_mps - tr.v_n_mps[s]).max(),
                                   att.max() / units.ARCSEC_RAD])
    return tuple(worst)


def closure_table() -> None:
    print("| preset | rate | span | position m | velocity m/s | attitude arcsec |")
    print("|---|---|---|---|---|---|")
    for preset, rate, window in (("vehicle", 200.0, None), ("sample", 100.0, None),
                                 ("flight", 200.0, None), ("flight", 200.0, 1800.0),
                                 ("grid", 200.0, None), ("grid", 200.0, 1800.0)):
        sim = simulate(preset, seed=1, imu_rate_hz=rate)
        p, v, a = _closure(sim, window)
        span = "whole" if window is None else f"restarted every {window:g} s"
        print(f"| {preset} | {rate:g} Hz | {span} | {p:.1e} | {v:.1e} | {a:.1e} |", flush=True)


def main() -> None:
    print("| mission | IMU samples | wall s | CPU s | CPU us/sample | increments s | errors s "
          "| truth s | peak RSS MiB | write s (MCAP) | peak RSS with write MiB |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for case in ("5400", "all"):
        subprocess.run([sys.executable, __file__, "--case", case], check=True)


if __name__ == "__main__":
    if "--closure" in sys.argv:
        closure_table()
    elif "--case" in sys.argv:
        arg = sys.argv[sys.argv.index("--case") + 1]
        _run(None if arg == "all" else float(arg))
    else:
        main()
