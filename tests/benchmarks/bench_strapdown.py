"""Benchmark: strapdown cost per IMU epoch, peak memory, scaling with duration.

Run on demand (not part of the test suite):  python tests/benchmarks/bench_strapdown.py
Prints a markdown table; the numbers recorded in docs/benchmarks.md come from this script.

Columns: the validated entry point ``strapdown.integrate`` (input checks + kernel + wrapping)
and the compiled kernel alone, each as the best of several runs in wall-clock time and in
process CPU time (the CPU time is the robust figure on a shared machine); peak memory is the
tracemalloc peak of one ``integrate`` call beyond its inputs (numpy reports its buffers to
tracemalloc), next to the size of the output state array (N + 1) x 10 x 8 bytes.
"""

from __future__ import annotations

import resource
import time
import tracemalloc

import numpy as np

from pospp import earth
from pospp.nav import _kernels, strapdown

RATE_HZ = 200.0
REPEATS = 5


def _increments(n: int, rng: np.random.Generator):
    """A level, stationary IMU at 40 N with small noise (the kernel's cost is data-independent)."""
    dt = 1.0 / RATE_HZ
    lat = np.radians(40.0)
    w = earth.earth_rate_n_radps(lat)  # body = NED
    f = -earth.gravity_n_mps2(lat, 0.0)
    dth = np.tile(w * dt, (n, 1)) + rng.normal(0, 1e-6, (n, 3))
    dv = np.tile(f * dt, (n, 1)) + rng.normal(0, 1e-4, (n, 3))
    t = np.arange(n + 1) * dt
    x0 = strapdown.NavState.from_euler(lat, 0.0, 0.0, np.zeros(3), np.zeros(3))
    return t, dth, dv, x0


def _best(fn) -> tuple[float, float]:
    wall, cpu = np.inf, np.inf
    for _ in range(REPEATS):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - w0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def main() -> None:
    rng = np.random.default_rng(0)
    t, dth, dv, x0 = _increments(1000, rng)
    strapdown.integrate(t, dth, dv, x0)  # compile / load the numba cache
    print(
        "| epochs | at 200 Hz | integrate wall us/epoch | integrate CPU us/epoch "
        "| kernel CPU us/epoch | peak MiB (output MiB) |"
    )
    print("|---:|---:|---:|---:|---:|---:|")
    for n in (180_000, 360_000, 720_000):
        t, dth, dv, x0 = _increments(n, rng)
        wall, cpu = _best(lambda t=t, dth=dth, dv=dv, x0=x0: strapdown.integrate(t, dth, dv, x0))
        out = np.empty((n + 1, _kernels.STATE_SIZE))
        z = np.zeros((1, 3))
        dts = np.diff(t)
        _, kcpu = _best(
            lambda dts=dts, dth=dth, dv=dv, x0=x0, out=out, z=z: _kernels.integrate_kernel(
                x0.as_vector(), dts, dth, dv, z, z, np.zeros(3), np.zeros(3), out
            )
        )
        del out
        tracemalloc.start()
        strapdown.integrate(t, dth, dv, x0)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        out_mib = (n + 1) * _kernels.STATE_SIZE * 8 / 2**20
        print(
            f"| {n} | {n / RATE_HZ / 3600:g} h | {wall / n * 1e6:.3f} | {cpu / n * 1e6:.3f} "
            f"| {kcpu / n * 1e6:.3f} | {peak:.0f} ({out_mib:.0f}) |"
        )
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\nprocess peak RSS: {rss:.0f} MiB")


if __name__ == "__main__":
    main()
