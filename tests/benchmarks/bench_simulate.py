"""Benchmark: simulator cost (1.5 h and the whole flight preset at 200 Hz), phases, memory.

Run on demand (not part of the test suite):  python tests/benchmarks/bench_simulate.py
Prints a markdown table; the numbers in docs/benchmarks.md (## Simulator) come from it.

Each case is ``pospp.sim.api.simulate("flight", imu_grade="paper_flight", gnss=<1 Hz with
lever arm>, seed=1, imu_rate_hz=200)``, truncated to the duration shown; wall-clock and
process CPU time (the CPU time is the robust figure on a shared machine), the phase timings
recorded in ``params["numerics"]["timings_s"]``, the process peak RSS so far (the cases run
shortest first, so each row's peak is that case's or the previous one's), and the time to
write the three files (MCAP, truth Parquet, params JSON) into a temporary folder.
"""

from __future__ import annotations

import resource
import tempfile
import time

from pospp.io.simulation_files import write_simulation
from pospp.sim.api import simulate
from pospp.sim.gnss import GnssModel

GNSS = GnssModel(rate_hz=1.0, lever_arm_b_m=(0.5, 0.2, -1.2))


def _run(duration_s: float | None) -> None:
    w0, c0 = time.perf_counter(), time.process_time()
    sim = simulate("flight", imu_grade="paper_flight", gnss=GNSS, seed=1, imu_rate_hz=200.0,
                   duration_s=duration_s)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
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
        f"{ph['truth_s']:.1f} | {peak:.0f} | {write_s:.1f} ({mcap_mib:.0f} MiB) |"
    )


def main() -> None:
    simulate("sample", imu_rate_hz=50.0, duration_s=10.0)  # warm numba caches of the checks
    print("| mission | IMU samples | wall s | CPU s | CPU us/sample | increments s | errors s "
          "| truth s | peak RSS MiB | write s (MCAP) |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    _run(5400.0)
    _run(None)


if __name__ == "__main__":
    main()
