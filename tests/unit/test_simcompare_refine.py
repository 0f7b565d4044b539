"""The secant refinement of a simulated effect's fit (pospp.simcompare.compare._refine, issue 33):
its slope and its test of the fitted size against zero when the simulated statistic is noisy.

The response is a closed form: S(u) = 4.5 u plus a jitter of +-0.015 that changes over
0.004 in u (a simulated statistic's noise, far steeper than the response over a small step),
the gap 0.385 +- 0.0355 (the Monte Carlo's coloured GNSS error at 1/3 the noise, seed 305:
gnss_pos_gated against the position error's variance [m^2]).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pospp.simcompare import compare as C
from pospp.simcompare.stats import FlightStats, Stat

SLOPE, JITTER, PERIOD = 4.5, 0.015, 0.004
GAP, SIGMA = 0.385, 0.0355


def _response(u: float) -> float:
    return SLOPE * u + JITTER * np.sin(2.0 * np.pi * u / PERIOD)


def _refined():
    effect = SimpleNamespace(refine=6, apply=lambda imu, gnss, u, ctx: (float(u[0]), gnss))

    def simulate(u, gnss):
        return FlightStats({"s": Stat(_response(u), 0.0, np.inf)}, np.nan)

    base = FlightStats({"s": Stat(_response(0.0), 0.0, np.inf)}, np.nan)
    g, w = np.array([GAP]), np.array([1.0 / SIGMA ** 2])
    trial = 0.04
    h = np.array([[(_response(trial) - _response(0.0)) / trial]])
    fit = C._wls(h, g, w)
    return C._refine(effect, ["s"], ([0], np.zeros(1)), h, g, w, fit, base, simulate, None,
                     None, None), g, w


def test_a_secant_step_below_the_noise_does_not_set_the_slope():
    """The best iterate fits the gap within its sigma; its sigma is the response's (0.0355 /
    4.5 = 0.0079) within a factor 1.5, not a slope taken over a step the jitter dominates
    (the last secant steps, 0.004 apart, read 0.04 for 0.008 on seed 305 and dropped the size
    as under 2 sigma); and its chi-square against zero is the drop of the weighted residual
    from u = 0, 117.6 less the iterate's."""
    (res, u, cov, chi), g, w = _refined()
    assert res < 1.0
    assert u[0] == pytest.approx(GAP / SLOPE, abs=2.0 * SIGMA / SLOPE)
    assert np.sqrt(cov[0, 0]) == pytest.approx(SIGMA / SLOPE, rel=0.5)
    assert chi == pytest.approx(float(np.sum(w * g * g)) - res)
    assert abs(u[0]) > C.MIN_COMPONENT_Z * np.sqrt(cov[0, 0])
