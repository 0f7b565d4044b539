"""pospp.distributions against scipy.stats, the library it stands in for (issue 18)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from pospp import distributions as dist


@pytest.mark.parametrize("dof", [1, 2, 3, 6, 30, 300])
def test_chi_square_quantiles_are_scipy_stats(dof):
    for p in (1e-6, 0.05, 0.5, 0.95, 0.9999, 1.0 - 1e-9):
        assert dist.chi2_ppf(p, dof) == stats.chi2.ppf(p, dof)
        assert dist.chi2_isf(1.0 - p, dof) == stats.chi2.isf(1.0 - p, dof)


@pytest.mark.parametrize(("d1", "d2"), [(1, 5), (2, 40), (6, 200), (1, 10)])
def test_f_and_t_tails_are_scipy_stats(d1, d2):
    for x in (0.0, 0.3, 1.0, 2.5, 8.0, 40.0):
        assert dist.f_sf(x, d1, d2) == stats.f.sf(x, d1, d2)
        assert dist.t_sf(x, d2) == stats.t.sf(x, d2)
        assert dist.t_sf(-x, d2) == stats.t.sf(-x, d2)


def test_poisson_upper_quantile_is_scipy_stats():
    for mu in (1e-4, 0.03, 0.33, 1.0, 2.7, 10.0, 123.4):
        for q in (1e-6, 1e-3, 0.01, 0.2, 0.5, 0.9):
            assert dist.poisson_isf(q, mu) == stats.poisson.isf(q, mu), (q, mu)
    with pytest.raises(ValueError, match="mu > 0"):
        dist.poisson_isf(1e-3, 0.0)


def test_the_run_does_not_import_scipy_stats():
    # the point of the module: a run's imports leave scipy.stats out (0.3 s, 45 MiB)
    import subprocess
    import sys

    code = "import sys, pospp.pipeline; print('scipy.stats' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
    assert np.isfinite(dist.chi2_ppf(0.9999, 3))


def _slope_z(phi: float, white_share: float, *, draws: int = 400, n: int = 900, **kw):
    """z of the least-squares slope of y = 0 x + e (x +-1 on alternate 120 s legs: the
    regressor constant over the window, as a lever arm's response between turns), e an AR(1) /
    Gauss-Markov series of lag-1 correlation ``phi`` (at 1 Hz) plus white noise of
    ``white_share`` of the variance: the spread over ``draws`` of the z with the white
    formula's sigma, and with it times sqrt(long_run_ratio(**kw)) of the fit's residual."""
    from scipy import signal

    rng = np.random.default_rng(33)
    t = np.arange(n, dtype=float)
    x = np.where((t // 120.0) % 2 == 0, 1.0, -1.0)
    gm = signal.lfilter([np.sqrt(1.0 - phi ** 2)], [1.0, -phi], rng.normal(size=(draws, n)),
                        axis=1)
    e = np.sqrt(1.0 - white_share) * gm + np.sqrt(white_share) * rng.normal(size=(draws, n))
    naive, corrected = [], []
    for y in e:
        b = float(x @ y) / float(x @ x)
        r = y - b * x
        z = b / np.sqrt(float(r @ r) / (n - 1) / float(x @ x))
        naive.append(z)
        corrected.append(z / np.sqrt(dist.long_run_ratio(np.repeat(r[:, None], 3, axis=1), t,
                                                         120.0, **kw)))
    return float(np.std(naive)), float(np.std(corrected))


@pytest.mark.parametrize(("phi", "white_share"), [(0.0, 1.0), (0.8, 0.0), (0.9, 0.0),
                                                  (0.97, 0.0), (0.97, 0.1), (0.9, 0.3)])
def test_long_run_ratio_gives_a_slope_on_coloured_noise_unit_z(phi, white_share):
    """The z of a regression slope on Gauss-Markov residuals (AR(1) at 1 Hz, with white noise
    of a share of the variance; 400 draws of 900 s; the regressor constant over 120 s legs)
    spreads 2.9-5.6 with the white formula's sigma and 1 with the long-run variance ratio of
    the fitted Gauss-Markov + white model over the legs' 120 s (within 0.88-1.12; the spread's
    own sampling error is 3.5 %). The sample's autocorrelations instead of the model's read
    the ratio low (spread 1.14-1.17 at phi 0.8-0.9)."""
    naive, corrected = _slope_z(phi, white_share, gauss_markov=True)
    assert 0.88 < corrected < 1.12
    if phi > 0.0:
        assert naive > 2.5
    if phi == 0.9 and white_share == 0.0:
        assert _slope_z(phi, white_share)[1] > 1.12


def test_gauss_markov_phi_of_white_and_coloured_noise():
    """phi of white noise 0; of a Gauss-Markov error (phi 0.9) under white noise of 30 % of
    the variance (lag-1 autocorrelation 0.63) 0.9 within 0.05."""
    from scipy import signal

    rng = np.random.default_rng(7)
    assert dist.gauss_markov_phi(rng.normal(size=20000)) == pytest.approx(0.0, abs=0.05)
    gm = signal.lfilter([np.sqrt(1.0 - 0.81)], [1.0, -0.9], rng.normal(size=20000))
    x = np.sqrt(0.7) * gm + np.sqrt(0.3) * rng.normal(size=20000)
    assert dist.gauss_markov_phi(x) == pytest.approx(0.9, abs=0.05)
