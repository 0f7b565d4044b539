"""The post-flight pipeline: stage order, stage contracts, outputs of one run.

One way through the data::

    ingest (io) -> A (nav) -> legs, B, pairs, calibration (calib) -> null (its covariance)
      -> compensation (B, and A with the calibrated gyro bias) -> diagnosis -> qc -> write

Each stage takes the frozen results of the stages before it and returns its own; nothing
numeric happens here, only orchestration and the translation of results into output tables
(:mod:`pospp.outputs`). The stage functions are in :mod:`pospp.flight_stages`; files are
touched only through :mod:`pospp.io`.

Failure policy (design.md "nothing is lost"): ingestion problems that make the file unusable
raise :class:`pospp.io.errors.IngestError` with file, topic and time; every later stage that
cannot produce a result (no legs, no admissible pair, ...) records why in the ``messages``
table and the run goes on, writing every table it can. A run is written into a staging folder
and swapped in whole when done (:mod:`pospp.io.run_folder`): a run folder is one complete run,
or one failed run whose messages and summary say why, never a mix of two runs. The commands
that add to a finished run (report, evaluate, diagnose) write into marked run folders only,
each file atomically.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cache, partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pospp import outputs
from pospp.calib.stage import CalibrationRun
from pospp.config import PipelineConfig, config_from_dict
from pospp.diagnose.results import Diagnosis
from pospp.diagnose.tables import diagnosis_columns, residual_curve_columns
from pospp.diagnosis_stage import diagnose_calibration, refit_and_check
from pospp.flight_stages import (
    calibrate_from_a,
    compensated,
    imu_increments,
    ingest,
    lever_arm_passes,
    lever_arm_seen,
    navigate,
    sensor_to_body_dcm,
)
from pospp.io import mcap_reader, parquet_tables, report_files, run_folder, trajectory_mcap
from pospp.io.errors import IngestError
from pospp.io.files import require_regular, sha256_file
from pospp.io.run_lock import locked
from pospp.lever_time_stage import lever_time_estimate, qc_passes
from pospp.memory import release_free_heap, share_one_heap
from pospp.nav import filter as nav_filter
from pospp.null_stage import NullResult, null_needs_gains, null_realisations, null_stage
from pospp.qc.check_record import Check, comparison_text
from pospp.qc.lever_time import LeverTime
from pospp.qc.stage import QualityReport, qc_columns, quality_checks, worst_status
from pospp.threads import available_cores

if TYPE_CHECKING:  # pandas and the report are imported where the run writes its tables
    import pandas as pd

ProgressFn = Callable[[str, float], None]
"""Progress callback: (stage name, fraction of the whole run done in [0, 1])."""

STAGES = ("ingest", "navigate", "calibrate", "null_realisations", "compensate", "diagnose", "qc",
          "write", "report")


@dataclass(frozen=True)
class RunOutcome:
    """What one ``pospp run`` produced.

    Attributes
    ----------
    out_dir : Path
        The run folder.
    status : str
        "ok" (every stage ran and every quality check passed), "partial" (a later stage
        produced nothing, see messages), "degraded" (a quality check failed: the answer is
        suspect, qc.parquet names the check) or "failed" (ingestion or algorithm A failed, only
        messages and summary are written; or a quality check found the answer wrong).
    summary : dict
        The one row of summary.parquet.
    messages : pandas.DataFrame
        The messages table (warnings and errors with their stage).
    wall_time_s : float
    """

    out_dir: Path
    status: str
    summary: dict[str, Any]
    messages: pd.DataFrame
    wall_time_s: float


class _Progress:
    """Stage bookkeeping: progress callback, elapsed time, per-stage wall time, messages.

    A stage's wall time runs from its :meth:`stage` call to the next one; the time before the
    first stage (checking the run folder, hashing the input) counts to the first stage.
    """

    def __init__(self, progress: ProgressFn | None) -> None:
        self._progress = progress
        self.messages: list[dict[str, Any]] = []
        self._t0 = time.perf_counter()
        self._current: str | None = None
        self._current_t0 = self._t0
        self._stage_s: dict[str, float] = {}

    def stage(self, name: str) -> None:
        release_free_heap()  # what the last stage freed (pospp.memory)
        now = time.perf_counter()
        if self._current is not None:
            self._stage_s[self._current] = (self._stage_s.get(self._current, 0.0)
                                            + now - self._current_t0)
            self._current_t0 = now
        self._current = name
        if self._progress is not None:
            self._progress(name, STAGES.index(name) / len(STAGES))

    def done(self) -> None:
        if self._progress is not None:
            self._progress("done", 1.0)

    def note(self, severity: str, stage: str, text: str, time_ns: int | None = None) -> None:
        self.messages.append(
            {"severity": severity, "stage": stage, "time_ns": time_ns, "text": text}
        )

    def rows(self) -> list[dict[str, Any]]:
        """The messages, their text encodable as UTF-8 (file names that do not decode)."""
        return [{**m, "text": run_folder.display_text(str(m["text"]))} for m in self.messages]

    def timings(self) -> dict[str, float]:
        """Summary columns ``wall_time_s`` and ``stage_<name>_s`` [s] up to now (the current
        stage counted until now): wall time since the run started, and each stage begun."""
        now = time.perf_counter()
        times = dict(self._stage_s)
        if self._current is not None:
            times[self._current] = times.get(self._current, 0.0) + now - self._current_t0
        return {"wall_time_s": now - self._t0,
                **{f"stage_{name}_s": times[name] for name in STAGES if name in times}}


def process_flight(
    mcap_path: str | Path,
    config: PipelineConfig,
    out_dir: str | Path,
    *,
    progress: ProgressFn | None = None,
    force: bool = False,
    threads: int | None = None,
) -> RunOutcome:
    """Process one flight log into a run folder (the whole pipeline).

    The run is written into a staging folder beside ``out_dir`` and swapped in whole when done,
    ``out_dir``'s lock held throughout (:class:`pospp.io.run_folder.StagedRun`): ``out_dir``
    holds one complete run or one failed run (its messages and summary, status "failed", and
    no table of an earlier run), never a mix. A run that fails without a verdict on its input
    (an ``OSError`` such as a full disk, a bug) leaves an earlier run in place.

    Parameters
    ----------
    mcap_path : path-like
        ROS 2 MCAP flight log (data contract in docs/formats.md).
    config : PipelineConfig
    out_dir : path-like
        Run folder: absent, empty, or an earlier pospp run (replaced only with ``force``).
        A folder holding files pospp did not write, or the input itself, is refused.
    progress : callable, optional
        Called with (stage, fraction done) at each stage start.
    force : bool
        Replace an earlier pospp run in ``out_dir``.
    threads : int, optional
        int of the embarrassingly parallel loops (B's replays, the null's and the
        diagnosis's A re-runs); None: the cores this process may use
        (:func:`pospp.threads.available_cores`). The outputs do not depend on it.

    Returns
    -------
    RunOutcome

    Raises
    ------
    pospp.io.run_folder.RunFolderError
        ``out_dir`` may not be written, or another command holds it (nothing is touched), or
        files were put into it during the run (nothing replaced).
    pospp.io.errors.IngestError, ValueError
        Only after the failed run (messages and summary recording the failure) is swapped in.
    OSError, ...
        The previous run kept (a note on the exception says so), else a failed run written.
    """
    # the run's clock starts here: wall_time_s is all of process_flight()
    book = _Progress(progress)
    require_regular(mcap_path)  # a FIFO or a device: refused before the folder is touched
    with run_folder.StagedRun(out_dir, input_file=mcap_path, force=force) as run:
        sha = sha256_file(mcap_path) if Path(mcap_path).is_file() else ""
        try:
            outcome = _run_stages(mcap_path, sha, config, run.stage, book,
                                  available_cores() if threads is None else max(1, threads))
        except Exception as exc:  # the failed run recorded, or the previous one kept
            run.fail(exc, partial(_write_failed, mcap_path, sha, config, book=book, exc=exc),
                     input_sha256=sha, config_json=config.to_json())
            raise
        target = run.commit(input_sha256=sha, config_json=config.to_json(),
                            status=outcome.status)
    book.done()
    return replace(outcome, out_dir=target)


def _write_failed(mcap_path: str | Path, sha: str, config: PipelineConfig, out: Path,
                  book: _Progress, exc: Exception) -> None:
    """Messages and summary of a run that ended with an unexpected error ``exc``."""
    book.note("error", "run", f"{type(exc).__name__}: {exc}")
    meta = {"input_file": run_folder.display_path(mcap_path), "input_sha256": sha,
            "config": config.to_dict()}
    summary = {"input_file": meta["input_file"], "input_sha256": sha, "status": "failed",
               **book.timings()}
    parquet_tables.write_table(out / "messages.parquet", outputs.messages_table(book.rows()),
                               "messages", metadata=meta)
    parquet_tables.write_table(out / "summary.parquet", summary, "summary", metadata=meta)


@dataclass
class _RunTables:
    """The run folder's writer: every table with the run's metadata, the summary last."""

    out: Path
    meta: dict[str, Any]
    summary: dict[str, Any]
    book: _Progress

    def write(self, name: str, data: Any) -> None:
        parquet_tables.write_table(self.out / f"{name}.parquet", data, name, metadata=self.meta)

    def finish(self, status: str, *, report: bool = False) -> RunOutcome:
        """messages.parquet, then summary.parquet (a folder with a summary is a finished run);
        with ``report``, the report rendered from the tables, then the summary again with the
        report's time in it (its wall_time_s is the whole run's)."""
        summary, book = self.summary, self.book
        summary["status"] = status
        summary.update(book.timings())
        import pandas as pd

        msgs = pd.DataFrame(book.rows(), columns=["severity", "stage", "time_ns", "text"])
        self.write("messages", outputs.messages_table(book.rows()))
        self.write("summary", summary)
        if report:
            book.stage("report")
            report_from_tables(self.out)
            summary.update(book.timings())
            self.write("summary", summary)
        return RunOutcome(self.out, status, summary, msgs, summary["wall_time_s"])


def _run_stages(mcap_path: str | Path, sha: str, config: PipelineConfig, out: Path,
                book: _Progress, threads: int) -> RunOutcome:
    """Every stage of :func:`process_flight` in the method's order, writing into the (staging)
    folder ``out``: ingest -> navigate (A) -> calibrate (legs, B, pairs, least squares) ->
    null (B minus A's null, the calibration's covariance) -> compensate -> diagnose (and the
    refit with what it names) -> qc -> write. Each stage is a function of the results before
    it; ``threads`` is used only inside the embarrassingly parallel loops (B's replays, the
    null's and the diagnosis's A re-runs)."""
    if threads > 1:
        share_one_heap()  # the loops' threads in one heap, not one each (pospp.memory)
    display = run_folder.display_path(mcap_path)
    run = _RunTables(out, {"input_file": display, "input_sha256": sha,
                           "config": config.to_dict()},
                     {"input_file": display, "input_sha256": sha}, book)
    log = _ingest_stage(mcap_path, config, run)
    nav = _navigate_stage(log, config, run)
    solutions = {"forward": nav.forward}
    if nav.smoothed is not None:
        solutions["smoothed"] = nav.smoothed

    book.stage("calibrate")
    imu = imu_increments(log)
    calib_run, solution_a = calibrate_from_a(imu, nav, config, threads=threads)
    for text in (*calib_run.messages, *(() if calib_run.calibrated else (calib_run.reason,))):
        book.note("warning", "calibrate", text)
    status = "ok" if calib_run.calibrated else "partial"

    null = None  # B minus A's null: the calibration's sigmas and the diagnosis's null
    if calib_run.calibrated and config.pairs.null_realisations > 0 and calib_run.replays:
        book.stage("null_realisations")
        null = null_stage(log, nav, calib_run, config, threads=threads)
        calib_run = null.calibration

    book.stage("compensate")  # A re-run with the calibrated gyro bias
    if calib_run.calibrated and config.compensation.rerun_filter:
        solutions["compensated"] = compensated(log, config, calib_run.gyro_bias_b_radps)

    book.stage("diagnose")
    # A's lever-arm estimate and the joint estimate from it, each made once: diagnosis and QC
    lever = lever_re_estimate(log, lever_arm_seen(nav), config)
    joint = cache(partial(lever_time_estimate, log, nav, config, lever[0]))
    diagnosis = None
    if calib_run.calibrated and config.outputs.diagnose:
        diagnosis = _diagnose_stage(calib_run, imu, solution_a, config, log, nav, null,
                                    lever[0], threads, book, joint)
        status = status if diagnosis is not None else "partial"
    # the refit with the named effects (the compensation uses it) and the model_fit check
    fit = refit_and_check(log, calib_run, diagnosis, imu, solution_a, config, threads,
                          compensate="compensated" in solutions, nav=nav)
    solutions.update(fit.solutions)

    book.stage("qc")  # the run is ok only when every check passes (docs/qc.md)
    report = quality_control(log, nav, calib_run, config, book, lever=lever, also=fit.checks,
                             joint=joint)
    status = worst_status(status, report.status)

    book.stage("write")
    _write_stage(run, log, nav, solutions, calib_run, fit, diagnosis, report, config, status)
    # the report reads the tables back: the run's arrays are let go first, so that it
    # reuses their memory instead of adding to the peak (1.5 h flight: 110 MiB)
    del log, nav, imu, solution_a, calib_run, null, diagnosis, solutions, fit, joint
    return run.finish(status, report=config.outputs.report)


def _ingest_stage(mcap_path: str | Path, config: PipelineConfig, run: _RunTables
                  ) -> mcap_reader.FlightLog:
    """The log as read (``[input]``), its reader's findings noted; a failed run on refusal."""
    book = run.book
    book.stage("ingest")
    try:
        log = ingest(mcap_path, config)
    except (IngestError, FileNotFoundError, ValueError) as exc:
        for issue in getattr(exc, "issues", ()):
            book.messages.append(outputs.issue_message(issue))
        book.note("error", "ingest", str(exc))
        run.finish("failed")
        raise
    for issue in log.issues:
        book.messages.append(outputs.issue_message(issue))
    run.summary.update(outputs.log_summary(log))
    return log


def _navigate_stage(log: mcap_reader.FlightLog, config: PipelineConfig, run: _RunTables
                    ) -> nav_filter.FilterResult:
    """Algorithm A (forward and smoother, its gains recorded when the null needs them), its
    rejections and events noted; a failed run naming the reader's finding that caused it."""
    book = run.book
    book.stage("navigate")
    try:
        nav = navigate(log, config, record_gains=null_needs_gains(config))
    except ValueError as exc:
        book.note("error", "navigate", text := log.cause_of(f"algorithm A failed: {exc}"))
        run.finish("failed")
        raise ValueError(text) from exc
    book.messages.extend(outputs.rejection_messages(nav.rejections))
    book.messages.extend(outputs.filter_event_messages(nav.resets, nav.imu_gaps,
                                                       int(log.imu.time_ns[0])))
    return nav


def _diagnose_stage(calib_run: CalibrationRun, imu: Any, solution_a: Any,
                    config: PipelineConfig, log: mcap_reader.FlightLog,
                    nav: nav_filter.FilterResult, null: NullResult | None,
                    lever_estimate: nav_filter.LeverArmEstimate | None, threads: int,
                    book: _Progress, joint: Callable[[], LeverTime | None]) -> Diagnosis | None:
    """The diagnosis (:func:`pospp.diagnosis_stage.diagnose_calibration`) on the null stage's
    realisations and linear system, noted; None (the run then partial) when it could not be
    made."""
    try:
        diagnosis = diagnose_calibration(
            calib_run, imu, solution_a, config, log=log, nav=nav,
            null_dv=None if null is None else null.realisations,
            null_model=None if null is None else null.model, lever_estimate=lever_estimate,
            threads=threads, joint=joint)
    except ValueError as exc:
        book.note("warning", "diagnose", f"no diagnosis: {exc}")
        return None
    book.note("info", "diagnose", f"p-values calibrated on {diagnosis.null_model}")
    if diagnosis.not_evaluated:
        book.note("warning", "diagnose", "not evaluated (the log cannot carry their test, or "
                  f"A's model does not hold on it): {', '.join(diagnosis.not_evaluated)}")
    if diagnosis.location is not None:  # "unexplained": where the gap sits
        book.note("warning", "diagnose", diagnosis.location.text)
    return diagnosis


def _write_stage(run: _RunTables, log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                 solutions: dict[str, Any], calib_run: CalibrationRun, fit: Any,
                 diagnosis: Diagnosis | None, report: QualityReport, config: PipelineConfig,
                 status: str) -> None:
    """Every table but messages and summary, the summary's columns, and trajectory.mcap (its
    metadata record with the run's ``status``)."""
    epoch_ns = int(log.imu.time_ns[0])
    best_name = next(k for k in ("compensated", "smoothed", "forward") if k in solutions)
    calib_tables = {**calib_run.tables(epoch_ns), **fit.tables(epoch_ns)}
    # the largest table written first and let go before the others are made
    run.write("trajectory", outputs.trajectory_table(solutions, epoch_ns))
    tables: dict[str, Any] = {}
    tables["biases"] = outputs.bias_table(
        {"forward": nav.forward_biases, "smoothed": nav.smoothed_biases}, epoch_ns)
    tables["qc"] = qc_columns(report, epoch_ns)
    tables.update(calib_tables)
    if diagnosis is not None:
        tables["diagnosis"] = diagnosis_columns(diagnosis)
        tables["diagnosis_curves"] = residual_curve_columns(diagnosis)
    if len(log.events_ns):
        tables["events"] = outputs.event_poses_table(
            log.events_ns, solutions[best_name], best_name, epoch_ns, config.sensor,
            lambda text: run.book.note("warning", "write", text))
    for name, table in tables.items():
        run.write(name, table)
    summary = run.summary
    summary["qc_failed_checks"] = report.failed_names
    summary["qc_suggestions"] = report.suggestions
    c_bs = sensor_to_body_dcm(config.input.sensor_frame, config.input.mounting_rpy_deg)
    summary.update(outputs.with_sensor_axes(calib_run.summary(), c_bs))
    summary.update(outputs.refit_summary(fit.refit))
    summary.update(outputs.diagnosis_summary(diagnosis.steps if diagnosis is not None else None))
    summary["calibration_reason"] = calib_run.reason
    if config.outputs.mcap:
        trajectory_mcap.trajectory_messages(
            solutions[best_name], epoch_ns, rate_hz=config.outputs.mcap_rate_hz,
            legs=calib_tables.get("legs")).finish(run.out / "trajectory.mcap", {
                "input_file": run.meta["input_file"], "input_sha256": run.meta["input_sha256"],
                "status": status, "solution": best_name})


def lever_re_estimate(log: mcap_reader.FlightLog, seen: np.ndarray, config: PipelineConfig
                      ) -> tuple[nav_filter.LeverArmEstimate | None, str | None]:
    """(:func:`pospp.flight_stages.lever_arm_passes`' estimate, None), or (None, why A
    failed); (None, None) when A estimates the lever arm itself (``[gnss]
    estimate_lever_arm``)."""
    if config.gnss.estimate_lever_arm:
        return None, None
    try:
        return lever_arm_passes(log, seen, config), None
    except ValueError as exc:
        return None, str(exc)


def quality_control(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                    calib_run: CalibrationRun | None, config: PipelineConfig,
                    book: _Progress | None = None, *,
                    lever: tuple[nav_filter.LeverArmEstimate | None, str | None] | None = None,
                    also: tuple[Check, ...] = (),
                    joint: Callable[[], LeverTime | None] | None = None) -> QualityReport:
    """The QC stage (pospp.qc): every check, with the lever arm re-estimated by A.

    Unless A already estimated it, the lever arm is estimated by one more forward pass of A
    with lever-arm states (:func:`lever_arm_estimate`; about a fifth of A's time). Failed
    checks are noted in ``book`` (stage "qc"). ``lever``: that estimate and why it failed, when
    already made (:func:`lever_re_estimate`); None: made here. ``also``: later stages' checks.
    ``joint()``: the joint estimate the diagnosis shares (None: made here when needed).
    """
    estimate, failure = (lever_re_estimate(log, lever_arm_seen(nav), config) if lever is None
                         else lever)
    if failure is not None and book is not None:
        book.note("warning", "qc", f"lever arm not re-estimated: {failure}")
    report = quality_checks(
        log, nav, calib_run, config, lever_estimate=estimate,
        c_bs=sensor_to_body_dcm(config.input.sensor_frame, config.input.mounting_rpy_deg),
        **qc_passes(log, nav, config, estimate, joint))
    report = replace(report, checks=report.checks + tuple(also))
    if book is not None:
        for c in report.failed:
            book.note("error" if c.severity == "failed" else "warning", "qc",
                      f"QC check {c.name} failed "
                      f"({comparison_text(c.value, c.threshold, c.unit)})"
                      + (f": {c.suggestion}" if c.suggestion else ""))
    return report


@locked("pospp report")
def write_report(run_dir: str | Path) -> Path:
    """Render report.html of a run folder from its tables alone (``pospp report``)."""
    return report_from_tables(run_folder.require_run_folder(run_dir))


def report_from_tables(run_dir: Path) -> Path:
    """Write RUN_DIR/report.html from the run's tables; return its path. Takes no lock:
    the caller holds the run's (``process_flight``, ``pospp report``, ``pospp compare-sim``)."""
    from pospp.report.html import render_report

    tables = report_files.read_run_tables(run_dir)
    title = f"pospp run report: {Path(str(tables['summary'].input_file.iloc[0])).name}" \
        if "summary" in tables else "pospp run report"
    return report_files.write_text(Path(run_dir) / "report.html",
                                   render_report(tables, title=title))


def reopen_run(run_dir: str | Path) -> tuple[Path, dict[str, Any], Path, PipelineConfig]:
    """A finished run's folder, summary metadata, input file and configuration.

    For the commands that work on a finished run (``pospp diagnose``, ``pospp compare-sim``):
    the folder must be a pospp run, and its input must still be there, unchanged (SHA-256).
    """
    run = run_folder.require_run_folder(run_dir)
    meta = parquet_tables.read_metadata(run / "summary.parquet")
    path = Path(meta["input_file"])
    if not path.is_file():
        raise FileNotFoundError(f"{run}: the run's input {path} is no longer there")
    if sha256_file(path) != meta["input_sha256"]:
        raise ValueError(f"{run}: the run's input {path} changed since the run (SHA-256)")
    return run, meta, path, config_from_dict(meta["config"], source=f"{run}/summary.parquet")


@locked("pospp diagnose")
def diagnose_run(run_dir: str | Path, *, progress: ProgressFn | None = None) -> Diagnosis:
    """``pospp diagnose RUN_DIR``: the discrepancy workflow on a finished run.

    Re-reads the run's input and configuration (from the summary's metadata), re-runs A and
    the calibration stage (deterministic, so it reproduces the run's B-minus-A curves), runs
    the workflow, and writes diagnosis.parquet and the report.
    """
    run, meta, path, config = reopen_run(run_dir)
    book = _Progress(progress)
    book.stage("ingest")
    log = ingest(path, config)
    book.stage("navigate")
    nav = navigate(log, config, record_gains=null_needs_gains(config))
    book.stage("calibrate")
    imu = imu_increments(log)
    calib_run, solution_a = calibrate_from_a(imu, nav, config)
    if not calib_run.calibrated:
        raise ValueError(f"{run}: no calibration to diagnose: {calib_run.reason}")
    book.stage("null_realisations")
    threads = available_cores()
    if threads > 1:
        share_one_heap()  # as in a run (pospp.memory)
    null_dv = (null_realisations(log, nav, calib_run, config, config.pairs.null_realisations,
                                 threads=threads)
               if config.pairs.null_realisations > 0 else None)
    book.stage("diagnose")
    lever = lever_re_estimate(log, lever_arm_seen(nav), config)[0]  # as a run makes it
    diagnosis = diagnose_calibration(
        calib_run, imu, solution_a, config, log=log, nav=nav, null_dv=null_dv, threads=threads,
        lever_estimate=lever, joint=cache(partial(lever_time_estimate, log, nav, config, lever)))
    book.stage("write")
    out_meta = {k: meta[k] for k in ("input_file", "input_sha256", "config")}
    parquet_tables.write_table(run / "diagnosis.parquet", diagnosis_columns(diagnosis),
                               "diagnosis", metadata=out_meta)
    parquet_tables.write_table(run / "diagnosis_curves.parquet",
                               residual_curve_columns(diagnosis), "diagnosis_curves",
                               metadata=out_meta)
    report_from_tables(run)
    book.done()
    return diagnosis
