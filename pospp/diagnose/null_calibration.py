"""Each nested F-test's null distribution from B-minus-A null realisations
(:func:`pospp.diagnose.workflow.diagnose_replays`; moved out of that module).

Frames and units as the workflow's (NED, SI). No I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pospp.calib.replay import LegReplay
from pospp.diagnose._linear import Problem, Term, f_test
from pospp.diagnose.null_model import calibrated_p_value, few_parameter_p_value
from pospp.threads import map_in_threads

FEW_PARAMETERS = 3
"""Nested tests of up to this many parameters (the library's candidates) get the predictive
F(1, R) of :func:`pospp.diagnose.null_model.few_parameter_p_value`."""


class NullCalibration:
    """Each nested F-test's null distribution from B-minus-A null realisations.

    The same design as the flight's problem, with the data replaced by each realisation
    (:mod:`pospp.diagnose.null_model`) and, when ``whitening`` is given, the whitening
    re-estimated on each realisation as it was on the flight (the statistic is then the
    same function of the data on both); the flight's F gets the p-value of
    :func:`pospp.diagnose.null_model.calibrated_p_value` against the R null F statistics.
    """

    def __init__(self, prob: Problem, null_dv: Sequence[Sequence[NDArray]],
                 whitening: Callable[[tuple[LegReplay, ...]], tuple[float, float]] | None = None,
                 threads: int = 1):
        self._threads = threads  # realisations refitted at once (the same fits at any number)
        if whitening is None:
            self.probs = [prob.with_data([np.asarray(d)[1:, 0:2] for d in real])
                          for real in null_dv]
        else:
            def rewhitened(real: Sequence[NDArray]) -> Problem:
                reps = tuple(replace(r, dv_n_mps=np.asarray(d))
                             for r, d in zip(prob.reps, real, strict=True))
                return prob.rewhitened(reps, *whitening(reps))

            self.probs = map_in_threads(rewhitened, null_dv, threads)
        self._rss: dict[tuple[int, ...], tuple[list[Term], list[tuple[float, int]]]] = {}

    def _fits(self, terms: Sequence[Term]) -> list[tuple[float, int]]:
        key = tuple(id(t) for t in terms)
        if key not in self._rss:  # the entry holds the terms: freed ids could be reused
            fits = map_in_threads(lambda q: q.fit(terms), self.probs, self._threads)
            self._rss[key] = (list(terms), [(f.rss_w, f.rank) for f in fits])
        return self._rss[key][1]

    def statistics(self, terms0: Sequence[Term], terms1: Sequence[Term]) -> NDArray:
        """The nested F of terms0 within terms1 on every realisation."""
        out = []
        for (r0, k0), (r1, k1), q in zip(self._fits(terms0), self._fits(terms1), self.probs,
                                         strict=True):
            out.append(f_test(r0, r1, k1 - k0, q.n - k1)[0])
        return np.array(out)

    def noise_factor(self, terms0: Sequence[Term], terms1: Sequence[Term]) -> float:
        """The RSS reduction that noise alone gives terms1 beyond terms0, per parameter and in
        units of the residual variance: the mean of the null F statistics (1 for white noise;
        B minus A's correlated noise reads far above it in the smooth lack-of-fit basis)."""
        f = self.statistics(terms0, terms1)
        f = f[np.isfinite(f)]
        return float(np.mean(f)) if f.size else 1.0

    def p_value(self, f: float, p_nominal: float, terms0: Sequence[Term],
                terms1: Sequence[Term]) -> float:
        """The flight's p-value against the null statistics: the predictive F(1, R) of a
        test of at most :data:`FEW_PARAMETERS` parameters (the candidates), the predictive
        log-normal of the many-parameter ones (the lack of fit); nominal when uncalibrated."""
        r = self._fits(terms1)[0][1] - self._fits(terms0)[0][1] if self.probs else 0
        rule = few_parameter_p_value if 0 < r <= FEW_PARAMETERS else calibrated_p_value
        p = rule(f, self.statistics(terms0, terms1))
        return p_nominal if not np.isfinite(p) else p
