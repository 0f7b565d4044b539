"""One finished pospp run, for analysts: ``pospp.open_run(path)`` -> :class:`Run`.

A run folder (written by ``pospp run`` or ``pospp batch``, marked ``.pospp-run.json``) holds
one Parquet table per output (docs/formats.md). :class:`Run` reads them on first use, by
column name and schema checked (:mod:`pospp.api.tables`), and gives them typed names:

>>> run = open_run("out/sample")                       # doctest: +SKIP
>>> run.status, run.summary["gyro_bias_x_dph"], run.summary.units["gyro_bias_x_dph"]
('ok', 0.94, 'deg/h')
>>> run.trajectory("compensated")[["time_ns", "lat_deg", "lon_deg"]]

Conventions are the tables': NED navigation frame, body FRD (x forward, y right, z down),
UTC int64 ``time_ns``, units in every column name (``_deg``, ``_mps``, ``_dph``). Nothing is
written; plots (:attr:`Run.plot`) import matplotlib only when drawn.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

from pospp.api.tables import column_table, read_documented
from pospp.io import parquet_tables, run_folder

if TYPE_CHECKING:
    from pospp.api.plots import RunPlots
    from pospp.config import PipelineConfig

__all__ = ["Run", "Summary", "TableNotInRun", "open_run"]

SOLUTIONS = ("compensated", "smoothed", "forward")
"""The trajectory's solutions, best first."""
_WHY_ABSENT = {
    "events": "no trigger events in its input ([input] events_topic, docs/formats.md)",
    "evaluation": "no reference given yet: pospp evaluate RUN --truth TRUTH.parquet",
    "sim_comparison": "not compared with a simulation yet: pospp compare-sim RUN",
    "diagnosis": "no diagnosis in this run ([diagnose] off, or no calibration)",
    "diagnosis_curves": "no diagnosis in this run ([diagnose] off, or no calibration)",
    "observability": "an observability study has its own folder (pospp observability)",
}


class TableNotInRun(LookupError):
    """A table the run folder does not hold (the message says why it may be absent)."""


class Summary(dict[str, Any]):
    """The run's one-row ``summary`` table as a dict (column -> value, None for nulls), with
    each column's unit, frame and description from the file (``units["dv_after_mps"]`` is
    ``"m/s"``; ``frames["gyro_bias_x_dph"]`` is ``"b (FRD)"``)."""

    def __init__(self, values: dict[str, Any], columns: pd.DataFrame) -> None:
        super().__init__(values)
        self.units: dict[str, str] = dict(zip(columns.column, columns.unit, strict=True))
        self.frames: dict[str, str] = dict(zip(columns.column, columns.frame, strict=True))
        self.descriptions: dict[str, str] = dict(zip(columns.column, columns.description,
                                                     strict=True))

    def text(self, key: str) -> str:
        """``"0.17 m/s"``: the value with its unit (4 significant digits)."""
        v, unit = self[key], self.units.get(key, "")
        shown = f"{v:.4g}" if isinstance(v, float) else str(v)
        return f"{shown} {unit}".strip()


class Run:
    """A finished pospp run folder. Open one with :func:`open_run`.

    Every table property returns a fresh DataFrame with the documented columns
    (docs/formats.md; later pospp versions may add columns, read them by name). A table the
    run does not hold raises :class:`TableNotInRun` saying why (:meth:`has` asks first).
    """

    def __init__(self, path: Path, marker: dict[str, Any]) -> None:
        self.path = path
        """The run folder."""
        self.marker = dict(marker)
        """The run's identity (``.pospp-run.json``): pospp version, input and its SHA-256,
        configuration hash, status, creation time (UTC)."""
        self._cache: dict[str, pd.DataFrame] = {}

    def __repr__(self) -> str:
        return f"<pospp Run {run_folder.display_path(self.path)}: {self.status}>"

    # ----------------------------------------------------------------- tables, generic

    def tables(self) -> list[str]:
        """Names of the documented tables the folder holds (``TABLES`` order)."""
        return [n for n in parquet_tables.TABLES if (self.path / f"{n}.parquet").is_file()]

    def has(self, name: str) -> bool:
        """Whether the run holds table ``name``."""
        return (self.path / f"{name}.parquet").is_file()

    def table(self, name: str) -> pd.DataFrame:
        """Table ``name`` (a key of ``pospp.io.parquet_tables.TABLES``) as a DataFrame.

        Raises
        ------
        KeyError
            ``name`` is not a documented table.
        TableNotInRun
            The folder does not hold it.
        pospp.api.tables.SchemaError
            Its columns do not match the documented schema.
        """
        if name not in parquet_tables.TABLES:
            raise KeyError(f"no table {name!r} in docs/formats.md; tables: "
                           f"{', '.join(parquet_tables.TABLES)}")
        if name not in self._cache:
            file = self.path / f"{name}.parquet"
            if not file.is_file():
                why = _WHY_ABSENT.get(name, "the run failed before writing it"
                                      if self.status == "failed" else "not written by this run")
                raise TableNotInRun(f"{run_folder.display_path(self.path)}: no {name}.parquet "
                                    f"({why})")
            self._cache[name] = read_documented(file, name)
        return self._cache[name].copy()

    def columns(self, name: str) -> pd.DataFrame:
        """Column, type, unit, frame and description of table ``name`` as stored."""
        self.table(name)
        return column_table(self.path / f"{name}.parquet")

    # ------------------------------------------------------------------- the answer

    @property
    def status(self) -> str:
        """"ok", "degraded", "partial" or "failed" (docs/qc.md), as ``pospp run`` said."""
        if self.has("summary"):
            s = self.table("summary")
            if "status" in s and pd.notna(s.status.iloc[0]):
                return str(s.status.iloc[0])
        return str(self.marker.get("status", "failed"))

    @property
    def summary(self) -> Summary:
        """The run's key figures (:class:`Summary`: a dict with ``units``, ``frames``)."""
        row = self.table("summary").iloc[0]
        values = {k: (None if not isinstance(v, str) and pd.isna(v) else
                      v.item() if hasattr(v, "item") else v) for k, v in row.items()}
        return Summary(values, self.columns("summary"))

    def trajectory(self, solution: str | None = "compensated") -> pd.DataFrame:
        """Rows of one solution of ``trajectory.parquet`` in time order: "compensated"
        (default), "smoothed", "forward", "best" (the first of those the run has) or None
        (all, with the ``solution`` column)."""
        traj = self.table("trajectory")
        have = list(dict.fromkeys(traj.solution))
        name = (next((s for s in SOLUTIONS if s in have), None) if solution == "best"
                else solution)
        if name is None and solution is None:
            return traj
        if name not in have:
            raise TableNotInRun(f"{run_folder.display_path(self.path)}: no {solution!r} "
                                f"solution in trajectory.parquet (it has {', '.join(have)})")
        rows = traj[traj.solution == name].sort_values("time_ns", kind="stable")
        return rows.reset_index(drop=True)

    @property
    def legs(self) -> pd.DataFrame:
        """Straight uniform legs: start, end, heading, speed, height (``legs``)."""
        return self.table("legs")

    @property
    def pairs(self) -> pd.DataFrame:
        """Leg pairs: heading and speed change, condition numbers, used or why not (``pairs``)."""
        return self.table("pairs")

    @property
    def calibration(self) -> pd.DataFrame:
        """Calibrated parameters per pair and formulation, long form (``calibration``)."""
        return self.table("calibration")

    @property
    def leg_errors(self) -> pd.DataFrame:
        """B minus A per leg before and after compensation (``leg_errors``)."""
        return self.table("leg_errors")

    @property
    def qc(self) -> pd.DataFrame:
        """Every quality check: statistic, threshold, passed, suggestion (``qc``)."""
        return self.table("qc")

    @property
    def diagnosis(self) -> pd.DataFrame:
        """The model-discrepancy workflow's steps (``diagnosis``)."""
        return self.table("diagnosis")

    @property
    def events(self) -> pd.DataFrame:
        """The sensor's pose at each trigger event (``events``)."""
        return self.table("events")

    @property
    def biases(self) -> pd.DataFrame:
        """Algorithm A's estimated IMU biases over time, body FRD (``biases``)."""
        return self.table("biases")

    @property
    def messages(self) -> pd.DataFrame:
        """Every warning and error with stage and time (``messages``)."""
        return self.table("messages")

    @property
    def evaluation(self) -> pd.DataFrame:
        """Errors against a reference, after ``pospp evaluate`` (``evaluation``)."""
        return self.table("evaluation")

    # ---------------------------------------------------------------- configuration

    @property
    def config(self) -> PipelineConfig:
        """The pipeline configuration the run used (from the summary's file metadata)."""
        from pospp.config import config_from_dict

        meta = parquet_tables.read_metadata(self.path / "summary.parquet")
        return config_from_dict(meta["config"], source=f"{self.path}/summary.parquet")

    @property
    def input_file(self) -> Path:
        """The flight log the run read (as recorded; it may have moved since)."""
        return Path(str(self.marker.get("input_file", "")))

    @property
    def plot(self) -> RunPlots:
        """The report's figures as matplotlib figures (``run.plot.leg_errors()``)."""
        from pospp.api.plots import RunPlots

        return RunPlots(self)


def open_run(path: str | Path) -> Run:
    """Open a pospp run folder.

    Raises
    ------
    FileNotFoundError
        No such folder.
    pospp.io.run_folder.RunFolderError
        ``path`` is not a pospp run folder (no marker): one line naming it.
    """
    folder = run_folder.require_run_folder(path)
    marker = run_folder.read_marker(folder)
    assert marker is not None  # require_run_folder checked it
    return Run(Path(folder), marker)
