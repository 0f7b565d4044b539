"""B's reach 300 s into each leg does not fall: a guard against losses like issue 35's.

The ratio of the medians over the legs of B's horizontal error at 300 s, before / after
compensation, velocity and position (tests/reference/_reach.py: the pipeline's own stages,
``pipelines/vehicle.toml`` or ``flight.toml`` with the case's lever arm), must stay within
10 % of the value recorded here, on every shared reference case with sensor errors (skipped
when the cases are absent) and on one flight (seed 0) of each point of pospp's simulator
drift grid. The values were measured with the smoothed compensation (this tree; the values
of 4f58f25 are in docs/calibration.md, ``tests/benchmarks/bench_reach.py --code``). A
change that moves them on purpose re-records them here, saying why in its commit.
"""

from __future__ import annotations

import pytest
from _reach import GRID_TAUS_S, cases_in, grid_flight, pipeline_kind, reach_here

pytestmark = pytest.mark.slow

LOSS = 0.10
"""A ratio may fall this far below its recorded value."""

RECORDED_CASES = {  # name: (velocity x, position x)
    "flight_accel_ramp_100hz": (28.3, 20.5),
    "flight_null_200hz": (82.5, 58.0),
    "flight_survey_errors": (117.3, 92.9),
    "flight_time_offset_200hz": (4.5, 2.7),
    "vehicle_bias_200hz": (79.3, 41.3),
}
RECORDED_GRID = {  # tau [s] (None: no drift): (velocity x, position x), seed 0
    100.0: (46.7, 42.0),
    300.0: (61.3, 54.7),
    3600.0: (53.9, 59.8),
    36000.0: (76.5, 62.0),
    None: (64.3, 50.7),
}


def _check(got: dict, recorded: tuple[float, float], what: str) -> None:
    v, p = recorded
    assert got["v"] >= (1.0 - LOSS) * v and got["p"] >= (1.0 - LOSS) * p, (
        f"{what}: reach {got['v']:.1f}x / {got['p']:.1f}x fell more than {LOSS:.0%} below "
        f"the recorded {v:.1f}x / {p:.1f}x ({got['source']})")


@pytest.mark.reference
@pytest.mark.parametrize("name", sorted(RECORDED_CASES))
def test_reference_case_reach_holds(name, reference_cases):
    cases = {n: (m, lev) for n, m, lev in cases_in(reference_cases)}
    mcap, lever = cases[name]
    _check(reach_here(mcap, pipeline_kind(name), lever), RECORDED_CASES[name], name)


@pytest.mark.parametrize("tau_s", GRID_TAUS_S, ids=lambda t: f"tau_{t}")
def test_drift_grid_reach_holds_and_the_smoother_predicts(tau_s):
    """In-sample: the pipeline's reach (the smoothed compensation) holds its recorded value.
    Held out (the fit on the middle three legs, the reach on the first and the last): the
    smoothed history is within 5 % of the better of the constant and the causal mode, in
    velocity and in position (issue 35; 1.4-3.7x better in the 6-seed benchmark)."""
    got = grid_flight(tau_s, 0, n_null=0)
    v, p = got["in"]["smoothed"]
    _check({"v": v, "p": p, "source": "smoothed"}, RECORDED_GRID[tau_s],
           f"drift grid tau {tau_s}")
    held = got["held"]
    for k, what in enumerate(("velocity", "position")):
        best = max(held["constant"][k], held["causal"][k])
        assert held["smoothed"][k] >= 0.95 * best, (tau_s, what, held)
