"""Benchmark: strapdown kernel cost per IMU epoch, peak memory, scaling with duration.

Run on demand (not part of the test suite):  python tests/benchmarks/bench_strapdown.py
Prints a markdown table; the numbers recorded in docs/benchmarks.md come from this script.
"""

from __future__ import annotations

import resource
import time
import tracemalloc

import numpy as np

from pospp import earth
from pospp.nav import strapdown


def _stationary_increments(n: int, rate_hz: float, rng: np.random.Generator):
    dt = 1.0 / rate_hz
    lat = np.radians(40.0)
    w = earth.earth_rate_n_radps(lat)  # body = NED
    f = -earth.gravity_n_mps2(lat, 0.0)
    dth = np.tile(w * dt, (n, 1)) + rng.normal(0, 1e-7, (n, 3))
    dv = np.tile(f * dt, (n, 1)) + rng.normal(0, 1e-5, (n, 3))
    t = np.arange(n + 1) * dt
    x0 = strapdown.NavState.from_euler(lat, 0.0, 0.0, np.zeros(3), np.zeros(3))
    return t, dth, dv, x0


def main() -> None:
    rng = np.random.default_rng(0)
    t, dth, dv, x0 = _stationary_increments(1000, 200.0, rng)
    strapdown.integrate(t, dth, dv, x0)  # compile / load cache
    print("| epochs | duration at 200 Hz | wall s | us / epoch | peak traced MiB |")
    print("|---:|---:|---:|---:|---:|")
    for hours in (0.25, 0.5, 1.0, 2.0):
        n = int(hours * 3600 * 200)
        t, dth, dv, x0 = _stationary_increments(n, 200.0, rng)
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            strapdown.integrate(t, dth, dv, x0)
            best = min(best, time.perf_counter() - t0)
        tracemalloc.start()
        strapdown.integrate(t, dth, dv, x0)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        print(f"| {n} | {hours:g} h | {best:.3f} | {best / n * 1e6:.3f} | {peak:.0f} |")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\nprocess peak RSS: {rss:.0f} MiB")


if __name__ == "__main__":
    main()
