"""False cuts of a static start by the GNSS velocity test of the alignment (docs/filter.md).

    PYTHONPATH=. python tests/benchmarks/bench_static_test.py [N_SEEDS] [RATE_HZ ...]

The simulator's receiver at rest (:func:`pospp.sim.gnss.simulate_gnss`, ``GnssModel``
defaults: velocity noise 0.02, 0.02, 0.03 m/s, reported as such) for 20 minutes, seeds
1..N (default 100) per rate (default 1 and 10 Hz), 1 s windows: how many seeds the speed
threshold alone (no covariances, the test before) and the chi^2(3) test
(:func:`pospp.nav.alignment.gnss_moving_windows`) cut, and when the speed alone cuts first.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pospp.nav.alignment import AlignmentOptions, gnss_moving_windows  # noqa: E402
from pospp.sim.gnss import GnssModel, simulate_gnss  # noqa: E402
from pospp.sim.trajectory import MotionSample  # noqa: E402

DURATION_S = 1200.0


class Still:
    """A receiver at rest (the velocities are its noise)."""

    def evaluate(self, ts):
        n = np.asarray(ts).size
        z3 = np.zeros((n, 3))
        return MotionSample(np.asarray(ts), np.full(n, 0.8), np.full(n, 0.1),
                            np.full(n, 100.0), z3, z3, z3, z3)


def main(n_seeds: int, rates: list[float]) -> None:
    opt = AlignmentOptions()
    w0 = np.arange(0.0, DURATION_S, 1.0)
    w1 = w0 + 0.999
    for rate in rates:
        first_old, cut_new = [], 0
        for seed in range(1, n_seeds + 1):
            _, v = simulate_gnss(Still(), DURATION_S, GnssModel(rate_hz=rate),
                                 start_time_ns=0, seed=seed)
            t = v.time_ns * 1e-9
            old = gnss_moving_windows(w0, w1, t, v.v_n_mps, None, opt)
            new = gnss_moving_windows(w0, w1, t, v.v_n_mps, v.vel_cov_ned_m2ps2, opt)
            first_old.append(w1[np.argmax(old)] if old.any() else np.inf)
            cut_new += int(new.any())
        fo = np.array(first_old)
        print(f"{rate:g} Hz, {n_seeds} seeds, 20 min at rest: speed alone cuts "
              f"{int(np.isfinite(fo).sum())} (within 10 min {int((fo < 600).sum())}, median "
              f"first cut {np.median(fo):.0f} s); chi^2(3) test cuts {cut_new}", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]) if args else 100, [float(a) for a in args[1:]] or [1.0, 10.0])
