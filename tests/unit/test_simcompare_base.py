"""Step 0 of compare-sim: the base model fitted to the log (pospp.simcompare.base_model,
issue 33 item 1).

Each estimator is checked on series whose level is known: white noise drawn here, the
simulator's own Gauss-Markov sequence for the Allan variance's closed form, GNSS residuals
with and without a coloured part; then on pospp's simulator with the IMU's true noise three
times below and above the configured grade, where the comparison must report the levels as
fitted (not as effects) and name nothing.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from pospp.compare_sim import compare_log
from pospp.config import config_from_dict
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import _gauss_markov, imu_grade
from pospp.simcompare import base_model as bm
from pospp.simcompare.stats import allan_products


def test_gauss_markov_allan_variance_closed_form_against_the_simulator():
    """The Allan variance per unit variance of a first-order Gauss-Markov process at tau =
    10 s, T = 300 s (closed form 0.02168; 2 tau / 3 T = 0.0222 to first order) against the
    simulator's own sequence (pospp.sim.sensors._gauss_markov, 100 Hz, 40 runs of 2000 s):
    within its Monte Carlo sigma."""
    g = bm.gm_allan_per_variance(10.0, 300.0)
    assert g == pytest.approx(2 * 10 / (3 * 300), rel=0.03)
    rng = np.random.default_rng(3)
    t = np.arange(200_000) * 0.01
    vals = []
    for _ in range(40):
        x = _gauss_markov(rng, t.size, 0.01, np.ones(3), 300.0)
        _, d = allan_products(t, x, np.ones(t.size, bool), 10.0)
        vals.append(d.mean())
    v = np.array(vals)
    assert abs(v.mean() - g) < 4.0 * v.std(ddof=1) / math.sqrt(v.size), (v.mean(), g)


def test_white_level_unbiased_with_an_honest_sigma_and_blind_to_a_line():
    """White noise of variance 4.2e-8 per sample at 50 Hz on 34 s of parts (the car track's
    steady parts, pieces of one Welch segment): the mean of 200 estimates is within 1.5 % of
    the truth, their scatter (7 %) is the reported sigma's to 20 %; a vibration line 30 times
    the noise at 8 Hz does not move the level."""
    t = np.arange(9000) * 0.02
    mask = ((t % 20.0) < 4.2) & (t > 10.0)  # stretches of 4.2 s
    rng = np.random.default_rng(0)
    est, sig = [], []
    for _ in range(200):
        x = rng.standard_normal((t.size, 3)) * math.sqrt(4.2e-8)
        v, s, used = bm.imu_white_noise(t, x, mask)
        est.append(v)
        sig.append(s)
    est, sig = np.array(est), np.array(sig)
    assert used == pytest.approx(34.0, abs=1.0)
    np.testing.assert_allclose(est.mean(axis=0) / 4.2e-8, 1.0, atol=0.015)
    np.testing.assert_allclose(sig.mean(axis=0) / est.std(axis=0), 1.0, atol=0.2)
    x = rng.standard_normal((t.size, 3)) * math.sqrt(4.2e-8)
    line = 30.0 * math.sqrt(4.2e-8) * np.sin(2 * np.pi * 8.0 * t)[:, None]
    np.testing.assert_allclose(bm.imu_white_noise(t, x + line, mask)[0],
                               bm.imu_white_noise(t, x, mask)[0], rtol=0.05)


def test_gnss_white_noise_without_the_coloured_part():
    """Residuals: white 0.05 m (0.1 m vertical) plus a Gauss-Markov error of 0.3 m at 60 s
    (0.45 m vertical), 1 Hz, 1800 records. Half the mean square first difference reads
    about 0.065 m; the structure function at 1, 2, 3 records extrapolated to 0 reads the
    white 0.05 m within 10 % (and within 3 of its sigmas). Without the colour: 0.05 m within
    5 %, the lag-1 autocorrelation about 0."""
    rng = np.random.default_rng(7)
    t = np.arange(1800.0)
    white = rng.standard_normal((t.size, 3)) * [0.05, 0.05, 0.1]
    gm = _gauss_markov(rng, t.size, 1.0, np.array([0.3, 0.3, 0.45]), 60.0)
    first = math.sqrt(0.5 * np.mean(np.diff(white + gm, axis=0)[:, :2] ** 2))
    assert first > 0.06
    val, sig, lag, n = bm.gnss_white_noise(t, white + gm)
    assert n == t.size and val[0] == pytest.approx(0.05, rel=0.1)
    assert abs(val[0] - 0.05) < 3.0 * sig[0] + 0.002 and val[1] == pytest.approx(0.1, rel=0.15)
    val, _, lag, _ = bm.gnss_white_noise(t, white)
    assert val[0] == pytest.approx(0.05, rel=0.05) and abs(lag[0]) < 4.0 * lag[1]


def test_levels_never_negative_and_reported_against_their_prior():
    """A variance fitted below zero is a level of 0 with its upper 1-sigma distance as its
    sigma; a fit far from its prior says so in words."""
    rows = bm._level_rows("gyro_gm_sigma", "deg_per_h", np.array([-1e-12, 4e-12, 0.0]),
                          np.array([1e-12, 1e-12, 1e-12]), 4.85e-6, np.full(3, 0.5), "test")
    assert [r.value >= 0.0 and r.sigma > 0.0 for r in rows] == [True] * 3
    assert rows[0].value == 0.0 and rows[0].sigma == pytest.approx(1e-6 / 4.85e-6)
    p = bm.BaseParameter("gyro_arw_x", 0.002, 0.0001, 0.01, "deg_per_sqrt_h", "test")
    assert p.differs and p.text() == ("gyro_arw_x 0.002 +- 0.0001 deg_per_sqrt_h fitted, "
                                      "prior 0.01 (differs)")
    assert not bm.BaseParameter("x", 0.0102, 0.0001, 0.01, "u", "t").differs  # under 10 %


@pytest.mark.parametrize("scale", [1.0 / 3.0, 3.0])
def test_true_noise_three_times_off_the_grade_is_a_base_model_refit(scale):
    """Issue 33: a tactical IMU whose white noise and bias instability are 3 times below or
    above the configured grade's. Before step 0 the comparison simulated the grade and
    called the difference `unexplained` (or vibration, with a negative RMS); now the fitted
    ARW is the truth's within 25 %, reported as differing from the grade, and nothing is
    named."""
    from test_simcompare import measured

    g = imu_grade("tactical")
    imu = replace(g, gyro_arw_dpsh=tuple(np.multiply(g.gyro_arw_dpsh, scale)),
                  accel_vrw_mpsph=tuple(np.multiply(g.accel_vrw_mpsph, scale)),
                  gyro_gm_sigma_dph=tuple(np.multiply(g.gyro_gm_sigma_dph, scale)))
    comp, _ = compare_log(measured(imu, seed=3), config_from_dict({"imu": {"grade": "tactical"}}))
    fit = {b.name: b for b in comp.base_fit}
    for a in "xyz":
        b = fit[f"gyro_arw_{a}"]
        assert b.value == pytest.approx(0.1 * scale, rel=0.25) and b.prior == 0.1 and b.differs
        assert fit[f"accel_vrw_{a}"].value == pytest.approx(0.05 * scale, rel=0.25)
    assert comp.effects_added == () and not comp.steps, [(s.target, s.effect)
                                                          for s in comp.steps]


def test_gyrocompass_resolves_below_the_earth_rates_horizontal_part():
    """compare-sim re-tunes A only on a fitted drift a gyrocompass cannot resolve: at or
    above Omega cos(lat) (15.041 deg/h x cos 40 deg = 11.52 deg/h); the grade's 0.5 deg/h, a
    drift over-read at 3.4 deg/h and one fitted 11.4 resolve; 11.6 does not, nor anything at
    the pole; no drift row (the flight had no static part) leaves A as configured."""
    from pospp.simcompare.base_model import BaseFit, BaseParameter, gyrocompass_resolves

    def fit(gm_dph):
        rows = (BaseParameter("gyro_gm_sigma", gm_dph, 0.6, 0.5, "deg_per_h", "test"),)
        return BaseFit(rows, imu_grade("tactical"), GnssModel())

    lat = np.radians(40.0)
    for gm in (0.5, 3.4, 11.4):
        assert gyrocompass_resolves(fit(gm), lat)
    assert not gyrocompass_resolves(fit(11.6), lat)
    assert not gyrocompass_resolves(fit(0.5), np.radians(90.0))
    assert gyrocompass_resolves(BaseFit((), imu_grade("tactical"), GnssModel()), lat)
