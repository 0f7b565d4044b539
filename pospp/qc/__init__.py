"""Self-checks of a run: named checks whose failure makes a run not ``ok``.

:mod:`pospp.qc.checks` holds the numeric checks (arrays in, frozen :class:`Check` out);
:mod:`pospp.qc.stage` runs them on a run's stage results and derives the run status.
Every check, its statistic, threshold, false-alarm level and measured margins: docs/qc.md.
"""
