"""Benchmark: algorithm A (forward filter + RTS smoother) cost per IMU epoch and peak memory.

Run on demand (not part of the test suite):  python tests/benchmarks/bench_filter.py
The record is the "flight" mission of pospp.sim truncated to 1.5 h at 200 Hz (static 10 min,
climb, transit, survey lines with 180 deg turns; paper flight IMU; 1 Hz GNSS with a lever arm),
then cut to 0.5 h and 1 h for the scaling rows. Prints markdown tables; the numbers recorded in
docs/benchmarks.md (## Algorithm A) come from this script. Peak memory is the tracemalloc peak
of one call (numpy allocations: inputs copies, outputs, smoother nodes).
"""

from __future__ import annotations

import dataclasses
import resource
import time
import tracemalloc

import numpy as np

from pospp.nav.filter import FilterOptions, run_integrated_navigation
from pospp.nav.tuning import tuning_preset

LEVER = (0.5, 0.2, -1.2)


def _cut(obj, end_ns):
    keep = obj.time_ns < end_ns
    return dataclasses.replace(obj, **{
        f.name: getattr(obj, f.name)[keep] for f in dataclasses.fields(obj)
        if isinstance(getattr(obj, f.name), np.ndarray)
        and getattr(obj, f.name).shape[:1] == keep.shape})


def _run(sim, end_ns, **kw):
    imu, fix, vel = (_cut(sim.imu, end_ns), _cut(sim.fix, end_ns), _cut(sim.vel, end_ns))
    return imu, lambda: run_integrated_navigation(
        imu, fix, vel, tuning_preset("flight"), epoch_ns=sim.start_time_ns,
        lever_arm_b_m=LEVER, **kw)


def _best(fn, repeat=3):
    """Best wall and best CPU seconds of ``repeat`` calls."""
    wall = cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def main() -> None:
    from pospp.sim.api import GnssModel, simulate

    t0 = time.perf_counter()
    sim = simulate("flight", imu_grade="paper_flight", gnss=GnssModel(lever_arm_b_m=LEVER),
                   seed=7, imu_rate_hz=200.0, duration_s=5400.0)
    print(f"simulated {len(sim.imu)} IMU samples in {time.perf_counter() - t0:.1f} s\n")
    start = sim.start_time_ns
    _run(sim, start + int(600e9))[1]()  # compile / load the numba cache

    print("| record | states | IMU epochs | forward CPU s | forward + smoother CPU s "
          "| CPU us / epoch | wall us / epoch | peak traced MiB |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    cases = [
        ("1.5 h", 5400, "15 + 6 GM (default)", {}),
        ("1.5 h", 5400, "15 (random-walk biases)",
         {"options": FilterOptions(gauss_markov_states=False)}),
        ("1.5 h", 5400, "15 + 6 GM + 6 SF + 3 lever",
         {"estimate_scale_factors": True, "estimate_lever_arm": True}),
        ("1 h", 3600, "15 + 6 GM (default)", {}),
        ("0.5 h", 1800, "15 + 6 GM (default)", {}),
    ]
    for label, dur, states, kw in cases:
        end = start + int(dur * 1e9)
        imu, full = _run(sim, end, **kw)
        opts = kw.get("options", FilterOptions())
        kw_fwd = dict(kw, options=dataclasses.replace(opts, smoother=False))
        _, fwd = _run(sim, end, **kw_fwd)
        _, c_fwd = _best(fwd)
        w_all, c_all = _best(full)
        tracemalloc.start()
        full()
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        n = len(imu)
        print(f"| {label} | {states} | {n} | {c_fwd:.2f} | {c_all:.2f} | "
              f"{c_all / n * 1e6:.2f} | {w_all / n * 1e6:.2f} | {peak:.0f} |")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\nprocess peak RSS (simulation included): {rss:.0f} MiB")


if __name__ == "__main__":
    main()
