"""The ``pospp`` command line: parse, delegate to a stage or the pipeline, print.

Every command is a thin shell over a function of the package (named in its help), so
everything the CLI does can be done from Python too. No command ends with a traceback: every
error is one line ``pospp: error: ...`` on stderr and an exit status from :data:`EXIT_CODES`
(``--debug`` shows the traceback instead). A run's status maps to its exit status in one
place, :func:`exit_code_for_status`; every command ends with one status line
(``pospp COMMAND: STATUS``, :func:`pospp.cli._status.status_line`).
"""

from __future__ import annotations

import gc
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

# One BLAS thread, set before numpy loads OpenBLAS: the calibration's many small dense solves
# run 5-60x slower when OpenBLAS threads compete with numba for 2 cores (docs/benchmarks.md).
# An explicit setting in the environment wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import click  # noqa: E402

from pospp import __version__  # noqa: E402
from pospp.cli._compare_sim import StepLines, compare_sim_lines  # noqa: E402
from pospp.cli._diff import diff  # noqa: E402
from pospp.cli._status import (  # noqa: E402
    EXIT_CODES,
    StageBar,
    diagnosis_step_line,
    exit_code_for_status,
    status_line,
    worst_status,
)
from pospp.config import ConfigError, PipelineConfig, load_config  # noqa: E402

if TYPE_CHECKING:
    from pospp.batch import FlightOutcome

__all__ = ["EXIT_CODES", "entry", "exit_code_for_status", "main"]


def _printable(text: str) -> str:
    """``text`` on one line, undecodable bytes of file names escaped, at most 2000 chars."""
    text = " ".join(text.split()).encode("utf-8", "backslashreplace").decode("utf-8")
    return text if len(text) <= 2000 else f"{text[:2000]}... (--debug for all)"


def _one_line(exc: BaseException) -> str:
    """The error and its notes (``add_note``: what the run kept) on one line."""
    notes = "; ".join(str(n) for n in getattr(exc, "__notes__", ()))
    return _printable(f"{exc}; {notes}" if notes else str(exc)) or type(exc).__name__


def _usage_errors() -> tuple[type[BaseException], ...]:
    """The errors that are the user's to fix in the command or its configuration (exit 2): a
    bad pipeline file or tolerance file, an input that is not a regular file, an output folder
    or file pospp must not write into (or another command holds), a topic the log does not
    have, a reference that is not of this flight."""
    from pospp.evaluate import TruthMismatchError
    from pospp.io.errors import MissingTopicError
    from pospp.io.files import NotRegularFileError
    from pospp.io.run_folder import RunFolderError

    return (ConfigError, RunFolderError, MissingTopicError, TruthMismatchError,
            NotRegularFileError)


def _exit_code_for(exc: BaseException) -> int:
    usage = isinstance(exc, _usage_errors())
    return EXIT_CODES["usage"] if usage else EXIT_CODES["failed"]


class _Cli(click.Group):
    """The command group: turns any error of a command into one line and an exit status."""

    def main(self, args: list[str] | None = None,  # type: ignore[override]
             prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: object) -> object:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except click.exceptions.NoArgsIsHelpError as exc:  # bare "pospp": the help, as is
            click.echo(exc.ctx.get_help() if exc.ctx is not None else exc.format_message())
            sys.exit(EXIT_CODES["usage"])
        except click.ClickException as exc:  # usage errors: one line too (click prints 3)
            click.echo(f"pospp: error: {_printable(exc.format_message())}", err=True)
            sys.exit(exc.exit_code)
        except click.Abort:
            click.echo("pospp: aborted", err=True)
            sys.exit(EXIT_CODES["failed"])
        sys.exit(rv if isinstance(rv, int) else 0)

    def invoke(self, ctx: click.Context) -> object:
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except KeyboardInterrupt:
            if ctx.params.get("debug"):
                raise
            click.echo("pospp: interrupted", err=True)
            ctx.exit(130)
        except Exception as exc:
            if ctx.params.get("debug"):
                raise
            text = _one_line(exc)
            known = isinstance(exc, ValueError | OSError | RuntimeError | KeyError)
            if not known:  # a bug: say so, keep it one line
                text = f"internal error ({type(exc).__name__}): {text}; --debug shows where"
            click.echo(f"pospp: error: {text}", err=True)
            ctx.exit(_exit_code_for(exc))


def _config(path: str | None) -> PipelineConfig:
    return PipelineConfig() if path is None else load_config(path)


@click.group(cls=_Cli, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="pospp")
@click.option("--debug", is_flag=True, help="Show the traceback of an error.")
def main(debug: bool) -> None:
    """pospp: POS post-processing with double strapdown online calibration.

    Exit status: 0 ok, 1 failed, 2 usage or configuration error, 3 degraded (a quality check
    failed; pospp diff: changed), 4 partial (a stage produced nothing). Every command ends
    with a status line: pospp COMMAND: STATUS (detail).
    """


@main.command()
@click.argument("mcap_file", type=click.Path(exists=True, dir_okay=False))
@click.option("-p", "--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False),
              help="Pipeline TOML (pipelines/flight.toml, ...); defaults when omitted.")
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Run folder for the tables, trajectory MCAP and report: absent, empty or "
                   "an earlier pospp run (with --force).")
@click.option("--force", is_flag=True,
              help="Replace an earlier pospp run in the folder (never files pospp did not "
                   "write).")
@click.option("-v", "--verbose", is_flag=True,
              help="Print every calibrated parameter (per-leg misalignments, every "
                   "formulation), not only the headline.")
@click.option("--threads", default=None, type=click.IntRange(min=1),
              help="A re-runs (null realisations, diagnosis) made at once; above 1, A's "
                   "other passes also run alongside the calibration and the null (more "
                   "memory); the outputs do not depend on it.  [default: the cores this "
                   "process may use]")
def run(mcap_file: str, pipeline_file: str | None, out_dir: str, force: bool,
        verbose: bool, threads: int | None) -> None:
    """Process one flight log: A, legs, B, pairs, calibration, compensation, report.

    Calls pospp.pipeline.process_flight. The run is written beside OUT and swapped in whole
    when done.
    """
    with _imports_for_the_process():
        from pospp import pipeline
        from pospp.io.report_files import read_run_tables
        from pospp.report.summary import summary_text

    config = _config(pipeline_file)
    bar = StageBar()
    try:
        outcome = pipeline.process_flight(mcap_file, config, out_dir, progress=bar, force=force,
                                           threads=threads)
    finally:
        bar.close()
    click.echo(summary_text(read_run_tables(outcome.out_dir), verbose=verbose))
    status_line("run", outcome.status, str(outcome.out_dir))
    sys.exit(exit_code_for_status(outcome.status))


@main.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path(exists=True))
@click.option("-p", "--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--out", "out_root", required=True, type=click.Path(file_okay=False),
              help="Root folder: one run folder per flight and manifest.parquet.")
@click.option("-j", "--workers", default=2, show_default=True, help="Local processes.")
@click.option("--scheduler", default=None,
              help="Dask distributed scheduler address (tcp://host:8786) instead of local.")
@click.option("--scheduler-timeout-s", default=10.0, show_default=True,
              help="How long to wait for the scheduler [s].")
@click.option("--force", is_flag=True, help="Re-run flights that are already done.")
@click.option("--threads", default=None, type=click.IntRange(min=1),
              help="A re-runs each flight makes at once; the outputs do not depend on it.  "
                   "[default: the cores shared out among the workers]")
@click.option("--baseline", "baseline_root", default=None,
              type=click.Path(exists=True, file_okay=False),
              help="An earlier batch root: when done, compare every flight with it (pospp "
                   "diff BASELINE ROOT): ROOT/diff.parquet, ROOT/diff.html; exit 3 on a change "
                   "beyond tolerance.")
@click.option("--tolerances", "tolerance_file", default=None,
              type=click.Path(exists=True, dir_okay=False),
              help="Tolerances of the --baseline comparison (TOML, as pospp diff).")
def batch(inputs: tuple[str, ...], pipeline_file: str | None, out_root: str, workers: int,
          scheduler: str | None, scheduler_timeout_s: float, force: bool,
          threads: int | None, baseline_root: str | None, tolerance_file: str | None) -> None:
    """Process an archive: MCAP files and/or folders of them (pospp.batch.run_batch).

    Each flight's line gives its result (ok, degraded, partial, failed, as pospp run) and what
    this batch did (ran, skipped, resumed); the manifest keeps both.
    """
    from pospp.batch import baseline_diff, find_flight_logs, run_batch

    if tolerance_file and not baseline_root:
        raise click.UsageError("--tolerances needs --baseline")
    files = find_flight_logs(inputs, out_root)
    if not files:
        raise click.UsageError(f"no .mcap files found in {', '.join(inputs)}")
    config = _config(pipeline_file)
    tolerances = None
    if tolerance_file:
        from pospp.api.diff import load_tolerances

        tolerances = load_tolerances(tolerance_file)

    def show(o: FlightOutcome) -> None:
        from pospp.report.summary import pm_text

        tail = f": {o.error}" if o.error else ""
        if o.gyro_bias_x_dph is not None and o.gyro_bias_y_dph is not None:
            tail += (f"  gyro bias x {pm_text(o.gyro_bias_x_dph, o.gyro_bias_x_sigma_dph)}, y "
                     f"{pm_text(o.gyro_bias_y_dph, o.gyro_bias_y_sigma_dph)} deg/h (body FRD)")
        if o.qc_failed_checks:
            tail += f"  QC failed: {o.qc_failed_checks}"
        click.echo(_printable(f"{o.status or '-':8s} {o.action:7s} {o.duration_s:7.1f} s  "
                              f"{o.file}{tail}"))

    rows = run_batch(files, config, out_root, workers=workers, scheduler=scheduler,
                     scheduler_timeout_s=scheduler_timeout_s, force=force, on_result=show,
                     threads=threads)
    statuses = [r.status or "failed" for r in rows]
    counts = ", ".join(f"{statuses.count(k)} {k}" for k in ("ok", "degraded", "partial",
                                                           "failed") if statuses.count(k))
    actions = ", ".join(f"{a} {n}" for a in ("ran", "resumed", "skipped")
                        if (n := sum(r.action == a for r in rows)))
    detail = (f"{len(rows)} flights: {counts}; {actions}; manifest "
              f"{Path(out_root) / 'manifest.parquet'}")
    if baseline_root:
        from pospp.api.diff_text import diff_lines, diff_status

        result = baseline_diff(out_root, baseline_root, tolerances)
        for line in diff_lines(result):
            click.echo(line)
        statuses.append(diff_status(result))
        detail += f"; against the baseline: {diff_status(result)}"
    status_line("batch", worst_status(*statuses), _printable(detail))
    sys.exit(exit_code_for_status(*statuses))


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
def report(run_dir: str) -> None:
    """Re-render RUN_DIR/report.html from the run's tables (pospp.pipeline.write_report)."""
    with _imports_for_the_process():
        from pospp.pipeline import write_report

    page = write_report(run_dir)
    click.echo(str(page))
    status_line("report", "ok", str(page))


@main.command()
@click.option("--preset", default=None,
              help="Mission preset: flight, vehicle, grid, sample, flight_wander.")
@click.option("--profile", "profile_file", type=click.Path(exists=True, dir_okay=False),
              default=None, help="Mission profile TOML instead of a preset.")
@click.option("--imu-grade", default="flight", show_default=True,
              help="IMU error grade: flight, vehicle (the paper's), errorfree, or a grade of "
                   "pospp/presets/imu.toml.")
@click.option("--seed", default=1, show_default=True, type=int)
@click.option("--rate-hz", "imu_rate_hz", default=None, type=float,
              help="IMU rate [Hz] (default: the profile's).")
@click.option("--gnss-rate-hz", default=1.0, show_default=True, type=float)
@click.option("--lever-arm-m", nargs=3, type=float, default=(0.0, 0.0, 0.0), show_default=True,
              help="GNSS antenna position in the body frame FRD [m].")
@click.option("--outage", "outages", nargs=2, type=float, multiple=True,
              help="GNSS outage START_S END_S from the mission start (repeatable).")
@click.option("--model", "model_file", type=click.Path(exists=True, dir_okay=False),
              default=None,
              help="Model TOML with [imu] and [gnss] tables (pospp compare-sim's "
                   "sim_model.toml): the IMU and GNSS models from it. --imu-grade, "
                   "--gnss-rate-hz, --lever-arm-m and --outage given explicitly replace its "
                   "values.")
@click.option("-o", "--out", "out_mcap", required=True, type=click.Path(dir_okay=False),
              help="Output MCAP; NAME.truth.parquet and NAME.params.json are written beside.")
@click.pass_context
def simulate(ctx: click.Context, preset: str | None, profile_file: str | None, imu_grade: str,
             seed: int, imu_rate_hz: float | None, gnss_rate_hz: float,
             lever_arm_m: tuple[float, float, float], outages: tuple, model_file: str | None,
             out_mcap: str) -> None:
    """Simulate a mission with exact IMU increments and known truth (pospp.sim.simulate)."""
    from dataclasses import replace

    from pospp.io.simulation_files import write_simulation
    from pospp.sim.api import simulate as run_simulation
    from pospp.sim.gnss import GnssModel, gnss_model_file

    if (preset is None) == (profile_file is None):
        raise click.UsageError("give exactly one of --preset and --profile")
    _check_choice("--preset", preset, _simulation_choices()[0])

    def given(name: str) -> bool:
        return ctx.get_parameter_source(name) != click.core.ParameterSource.DEFAULT

    if model_file is not None and not given("imu_grade"):
        imu_grade = model_file
    grade = {"flight": "paper_flight", "vehicle": "paper_vehicle"}.get(imu_grade, imu_grade)
    if not grade.endswith(".toml"):
        _check_choice("--imu-grade", grade, ["flight", "vehicle", *_simulation_choices()[1]])
    gnss = GnssModel(rate_hz=gnss_rate_hz, lever_arm_b_m=lever_arm_m,
                     outages_s=tuple(tuple(o) for o in outages))
    if model_file is not None:
        try:
            from_file = gnss_model_file(model_file)
        except (ValueError, TypeError) as exc:
            raise click.UsageError(str(exc)) from exc
        if from_file is not None:
            over: dict[str, Any] = {k: v for k, p, v in (("rate_hz", "gnss_rate_hz", gnss.rate_hz),
                                                          ("lever_arm_b_m", "lever_arm_m",
                                                           gnss.lever_arm_b_m),
                                                          ("outages_s", "outages",
                                                           gnss.outages_s)) if given(p)}
            gnss = replace(from_file, **over)
    bar = StageBar()
    try:
        source: str = profile_file or preset or ""
        sim = run_simulation(source, imu_grade=grade, gnss=gnss, seed=seed,
                             imu_rate_hz=imu_rate_hz, progress=bar)
    finally:
        bar.close()
    out = Path(out_mcap)
    paths = write_simulation(sim, out.parent, out.stem)
    click.echo(f"{len(sim.imu)} IMU samples, {len(sim.fix)} GNSS fixes, {len(sim.legs)} true "
               f"straight legs")
    for kind, path in paths.items():
        click.echo(f"  {kind}: {path}")
    status_line("simulate", "ok", str(paths.get("mcap", out)))


def _simulation_choices() -> tuple[list[str], list[str]]:
    """The mission presets and IMU grades ``pospp simulate`` knows (pospp/presets)."""
    from pospp.sim.profile import preset_names
    from pospp.sim.sensors import grade_names

    return preset_names(), grade_names()


def _check_choice(option: str, value: str | None, choices: list[str]) -> None:
    """A usage error (exit 2) naming the option when ``value`` is not one of ``choices``."""
    if value is not None and value not in choices:
        raise click.UsageError(f"{option} {value!r}: expected one of {', '.join(choices)}")


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
@click.option("--format", "fmt", required=True,
              help="An export format of docs/formats.md, 'Exports' (pospp.io.exports."
                   "EXPORT_FORMATS): sbet (Applanix SBET binary), csv (GPS week / seconds of "
                   "week), geojson and kml (the track, the legs and the events), ...")
@click.option("--rate", "rate_hz", default=None, type=click.FloatRange(min=0, min_open=True),
              help="Thin the trajectory to about this rate [Hz] (default: every epoch).")
@click.option("-o", "--out", "out_file", default=None, type=click.Path(dir_okay=False),
              help="Output file (default: RUN_DIR/trajectory.EXT, or events.EXT with "
                   "--events; EXT the format's: out for sbet, else its name).")
@click.option("--solution", default="best", show_default=True,
              type=click.Choice(["best", "compensated", "smoothed", "forward"]),
              help="Which solution of trajectory.parquet (best: compensated > smoothed > "
                   "forward).")
@click.option("--events", "events", is_flag=True,
              help="The sensor's pose at each trigger (events.parquet) instead of the "
                   "trajectory: sbet, csv one record each; geojson, kml one point each.")
@click.option("--force", is_flag=True, help="Replace an existing -o file (never the run's "
              "input or a run folder's other files).")
def export(run_dir: str, fmt: str, rate_hz: float | None, out_file: str | None,
           solution: str, events: bool, force: bool) -> None:
    """Export a run's trajectory or trigger poses for other tools (pospp.io.exports)."""
    from pospp.io.exports import FORMATS, export_run

    _check_choice("--format", fmt, list(FORMATS))
    path = export_run(run_dir, fmt, rate_hz=rate_hz, out=out_file, solution=solution,
                      data="events" if events else "trajectory", force=force)
    click.echo(str(path))
    status_line("export", "ok", str(path))


@main.command()
@click.argument("source", type=click.Path(exists=True))
@click.option("-o", "--out", "out_mcap", required=True, type=click.Path(dir_okay=False),
              help="Output MCAP (a reference goes to STEM.reference.parquet beside it).")
@click.option("--format", "fmt", default=None,
              help="Source format (detected when omitted); see docs/realdata.md.")
@click.option("--option", "options", multiple=True, metavar="KEY=VALUE",
              help="Converter option, e.g. --option path=3 --option imu=avg (repeatable).")
def convert(source: str, out_mcap: str, fmt: str | None, options: tuple[str, ...]) -> None:
    """Convert a measured log to the MCAP data contract (pospp.convert.convert)."""
    from pospp.convert import convert as run_convert
    from pospp.io.converters import FORMATS

    _check_choice("--format", fmt, sorted(FORMATS))
    kw: dict[str, Any] = {}
    for item in options:
        key, sep, value = item.partition("=")
        if not sep:
            raise click.UsageError(f"--option {item!r}: expected KEY=VALUE")
        try:
            kw[key] = int(value)
        except ValueError:
            try:
                kw[key] = float(value)
            except ValueError:
                kw[key] = value
    from pospp.io.converters import UnknownOptionError

    try:
        rep = run_convert(source, out_mcap, fmt=fmt, **kw)
    except UnknownOptionError as exc:
        raise click.UsageError(f"--option: {exc}") from None
    click.echo(f"{rep.fmt}: {rep.n_imu} IMU samples ({rep.imu_rate_hz or 0:.1f} Hz), "
               f"{rep.n_fix} GNSS fixes, {rep.n_reference} reference epochs")
    for label, path in (("mcap", rep.mcap_path), ("reference", rep.reference_path)):
        if path:
            click.echo(f"  {label}: {path}")
    for w in rep.warnings:
        click.echo(f"  warning: {w}")
    for hint in rep.hints:
        click.echo(f"  hint: {hint}")
    status_line("convert", "ok", f"{len(rep.warnings)} warning(s)" if rep.warnings else "")


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
@click.option("--truth", "truth_file", required=True, type=click.Path(exists=True,
              dir_okay=False), help="Reference trajectory Parquet (docs/formats.md).")
@click.option("--skip-s", default=0.0, show_default=True,
              help="Leave out the first seconds of each solution (alignment).")
def evaluate(run_dir: str, truth_file: str, skip_s: float) -> None:
    """Errors of a run's solutions against a reference: evaluation.parquet, evaluation.png.

    Calls pospp.evaluate.solution_errors for every solution in RUN_DIR/trajectory.parquet.
    """
    with _imports_for_the_process():
        from pospp.api.studies import evaluate_run
        from pospp.evaluate import TruthMismatchError

    try:
        table = evaluate_run(run_dir, truth_file, skip_s=skip_s)
    except TruthMismatchError as exc:  # name the file given
        raise TruthMismatchError(f"--truth {truth_file}: {exc}") from exc
    wide = table.pivot(index="metric", columns="solution", values="value")
    units = table.groupby("metric").unit.first()
    wide.insert(0, "unit", units)
    click.echo(wide.to_string(float_format=lambda v: f"{v:.4g}"))
    status_line("evaluate", "ok", str(Path(run_dir) / "evaluation.parquet"))


@main.command()
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(file_okay=False))
@click.option("--speed-mps", default=60.0, show_default=True, help="Leg a's speed [m/s].")
@click.option("--duration-s", default=300.0, show_default=True, help="Leg duration [s].")
@click.option("--lat-deg", default=40.0, show_default=True, help="Latitude [deg].")
@click.option("--transition", type=click.Choice(["closed_form", "numerical"]),
              default="closed_form", show_default=True)
def observability(out_dir: str, speed_mps: float, duration_s: float, lat_deg: float,
                  transition: str) -> None:
    """Condition number versus heading and speed change (paper Fig. 4, 5).

    Writes OUT/observability.parquet and OUT/observability.png
    (pospp.calib.observability.observability_table).
    """
    with _imports_for_the_process():
        from pospp.api.studies import observability_study

    table = observability_study(out_dir, speed_mps=speed_mps, duration_s=duration_s,
                                lat_deg=lat_deg, transition=transition)
    for form, g in table[table.dspeed_mps == 0.0].groupby("formulation"):
        best = g.loc[g.cond_scaled.idxmin()]
        click.echo(f"{form}: smallest scaled condition number {best.cond_scaled:.3g} at dH = "
                   f"{best.dheading_deg:g} deg (equal speeds)")
    click.echo(f"tables and figure in {out_dir}")
    status_line("observability", "ok", out_dir)


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
def diagnose(run_dir: str) -> None:
    """Model-discrepancy workflow on a finished run: RUN_DIR/diagnosis.parquet.

    Predicts B's error on every leg with the calibrated model, measures the gap, tests the
    library of candidate effects, adds the one the data supports and repeats
    (pospp.diagnose.workflow.diagnose_replays).
    """
    with _imports_for_the_process():
        from pospp.pipeline import diagnose_run

    bar = StageBar()
    try:
        diag = diagnose_run(run_dir, progress=bar)
    finally:
        bar.close()
    for s in diag.steps:
        click.echo(diagnosis_step_line(s))
    status_line("diagnose", "ok", str(Path(run_dir) / "diagnosis.parquet"))


@main.command("compare-sim")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
@click.option("-o", "--out", "out_model", default=None, type=click.Path(dir_okay=False),
              help="Model file to write (default RUN_DIR/sim_model.toml).")
@click.option("--max-steps", default=4, show_default=True, type=int,
              help="Effects to add at most.")
@click.option("--force", is_flag=True, help="Replace an existing -o file (never the run's "
              "input or a run folder's other files).")
def compare_sim(run_dir: str, out_model: str | None, max_steps: int, force: bool) -> None:
    """Measured flight versus its simulation: RUN_DIR/sim_comparison.parquet.

    Fits the base model to the log (white noise, bias instability, biases, GNSS noise; the
    configured IMU grade as prior), simulates the run's flight along A's trajectory with it,
    compares statistics every flight has, names the library effect that explains the
    largest significant gap (the lever arm and the GNSS time offset jointly, or the
    combination when the flight cannot separate them), adds it and repeats
    (pospp.compare_sim, docs/compare_sim.md). Writes the fitted model as a TOML file that
    pospp simulate --model accepts. Progress: a line per step on stderr.
    """
    from pospp.compare_sim import compare_sim_run

    lines = StepLines()
    try:
        comp = compare_sim_run(run_dir, out=out_model, max_steps=max_steps, force=force,
                               progress=lines.step, on_flight=lines.flight)
    finally:
        lines.close()
    for line in compare_sim_lines(comp):
        click.echo(line)
    n_left = sum(g.significant for g in comp.final.values())
    status_line("compare-sim", "ok", f"{n_left} statistic(s) left significant")


main.add_command(diff)


@contextmanager
def _imports_for_the_process() -> Iterator[None]:
    """Imports whose objects live as long as the process (``pospp.pipeline``: numba, pandas,
    scipy): the cyclic garbage collector off while they load, their objects frozen after
    (``gc.freeze``), so that neither the imports' collections nor the run's walk them again
    (docs/history/speed_rounds.md). Cyclic garbage made by the imports themselves is kept."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def entry() -> None:
    """The ``pospp`` console script (and ``python -m pospp.cli``): :func:`main`, then the
    garbage collector frozen before the interpreter ends (its teardown otherwise walks the
    objects numba, pandas and scipy hold, 0.2-0.4 s after a sample run; 0.03-0.08 s frozen).
    Every ``atexit`` handler and stream flush still runs. Not in :func:`main`, which tests
    call in their own process."""
    try:
        main()
    finally:
        gc.disable()
        gc.freeze()


if __name__ == "__main__":  # pragma: no cover
    entry()
