"""pospp's Python API to finished runs and batch roots (docs/api.md).

- :func:`open_run` -> :class:`Run`: one run folder's tables, typed and documented
  (:mod:`pospp.api.run`), its figures (:mod:`pospp.api.plots`).
- :func:`open_archive` -> :class:`Archive`: a batch root by its manifest
  (:mod:`pospp.api.archive`).
- :func:`diff_paths`: what changed between two runs or two roots, against
  :class:`Tolerances` (:mod:`pospp.api.diff`; ``pospp diff``).

The same names are importable from ``pospp`` itself (loaded on first use, so ``import pospp``
stays light).
"""

from pospp.api.archive import Archive, open_archive
from pospp.api.diff import DiffResult, Tolerances, diff_paths, diff_runs, load_tolerances
from pospp.api.run import Run, Summary, TableNotInRun, open_run
from pospp.api.tables import SchemaError

__all__ = ["Archive", "DiffResult", "Run", "SchemaError", "Summary", "TableNotInRun",
           "Tolerances", "diff_paths", "diff_runs", "load_tolerances", "open_archive",
           "open_run"]
