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
