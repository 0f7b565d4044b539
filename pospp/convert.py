"""The convert command: parse a measured log, estimate its IMU mounting, write the contract.

Three steps, each in its own layer (converters only parse):

1. ``pospp.io.converters.parse``: the source format -> :class:`~pospp.io.converters.ParsedLog`
   (IMU in sensor axes where the mounting is unknown, with the inputs of its estimate);
2. :func:`estimate_parsed_mounting`: ``pospp.nav.mounting.estimate_mounting`` on those inputs
   (numeric layer), then ``apply_mounting`` rotates the IMU into body FRD, ``f_b = C_bs f_s``
   (or, for a mounting that is only reported, nothing is rotated);
3. ``pospp.io.converters.write_parsed``: MCAP flight log and reference Parquet, and the
   :class:`~pospp.io.converters.ConversionReport`.

No printing: the CLI renders the report.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from pospp.io.converters import (
    ConversionReport,
    MountingInput,
    ParsedLog,
    apply_mounting,
    parse,
    write_parsed,
)
from pospp.io.converters.ansfl_quadrotor import unit_mounting_input
from pospp.nav.mounting import MountingEstimate, MountingOptions, estimate_mounting

__all__ = ["convert", "estimate_parsed_mounting", "estimate_unit_mounting"]


def _estimate(m: MountingInput) -> MountingEstimate:
    return estimate_mounting(m.t_s, m.f_s_mps2, m.t_vel_s, m.v_n_mps, lat_rad=m.lat_rad,
                             height_m=m.height_m, body_rpy_rad=m.body_rpy_rad,
                             options=MountingOptions(**m.options))


def estimate_parsed_mounting(parsed: ParsedLog, *, mounting: MountingEstimate | None = None
                             ) -> tuple[ParsedLog, MountingEstimate | None]:
    """Estimate (or take ``mounting``) and apply the IMU mounting of a parsed log.

    Returns the log (IMU in body FRD when its mounting is applied) and the estimate (None when
    the format has no mounting to estimate, or a report-only estimate failed: a note says why).

    Raises
    ------
    ValueError
        The estimate of a mounting that must be applied failed (too few windows), or
        ``mounting`` was given for a format whose axes are known.
    """
    m = parsed.mounting
    if m is None:
        if mounting is not None:
            raise ValueError(f"{parsed.fmt}: the IMU axes are known; no mounting to apply")
        return parsed, None
    if mounting is None:
        if m.apply:
            mounting = _estimate(m)
        else:
            try:
                mounting = _estimate(m)
            except ValueError as exc:
                note = f"{m.description} not estimated: {exc}"
                return replace(parsed, notes=(*parsed.notes, note)), None
    return (apply_mounting(parsed, mounting) if m.apply else parsed), mounting


def convert(
    source_dir_or_file: str | Path,
    out_mcap: str | Path,
    *,
    fmt: str | None = None,
    mounting: MountingEstimate | None = None,
    **options: Any,
) -> ConversionReport:
    """Convert a measured log to an MCAP flight log (and a reference Parquet where it has one).

    Parameters
    ----------
    source_dir_or_file : path-like
        The dataset folder (or, for the reference-only formats, the file).
    out_mcap : path-like
        MCAP to write. A reference goes to ``<stem>.reference.parquet`` beside it; formats
        without IMU write only that reference (or ``out_mcap`` itself if it ends in .parquet).
    fmt : str, optional
        A key of ``pospp.io.converters.FORMATS``; detected from the files when None.
    mounting : MountingEstimate, optional
        A mounting to apply instead of estimating one (e.g. from a longer recording).
    **options
        Keyword options of the chosen parser (e.g. ``path=3, imu=2`` for
        ``ansfl_quadrotor``; ``gps_week=`` for ``kfgins_rtk``; ``geoid_undulation_m=``).

    Raises
    ------
    ConversionError
        Unknown format, missing or malformed source file (the message names file and fault).
    """
    parsed = parse(source_dir_or_file, fmt=fmt, **options)
    parsed, estimate = estimate_parsed_mounting(parsed, mounting=mounting)
    out = Path(out_mcap)
    out.parent.mkdir(parents=True, exist_ok=True)
    report = write_parsed(parsed, out, mounting=estimate)
    hint = HINTS.get(report.fmt)
    return replace(report, hints=hint(report, source_dir_or_file)) if hint else report


def _span_s(rep: ConversionReport) -> float:
    return (rep.end_ns - rep.start_ns) * 1e-9 if rep.start_ns is not None and \
        rep.end_ns is not None else 0.0


def _run_with(pipeline: str) -> Callable[[ConversionReport, str | Path], tuple[str, ...]]:
    def hint(rep: ConversionReport, source: str | Path) -> tuple[str, ...]:
        return (f"process it with: pospp run {rep.mcap_path} -p pipelines/realdata/"
                f"{pipeline} -o OUT (docs/realdata.md, docs/results.md)",)
    return hint


def _ansfl_clip(rep: ConversionReport, source: str | Path) -> tuple[str, ...]:
    return (f"this is one of the authors' trimmed paths, {_span_s(rep):.0f} s: too short for "
            "a pospp run, whose alignment needs a 30 s static period or steady GNSS velocity "
            "above 5 m/s (none here); for a run convert the whole DOT recording: pospp "
            f"convert {source} -o OUT.mcap --format ansfl_quadrotor_raw --option unit=1 "
            "--option recording=2",
            "then: pospp run OUT.mcap -p pipelines/realdata/ansfl_quadrotor_straightline.toml "
            "-o OUT (docs/results.md)")


HINTS: dict[str, Callable[[ConversionReport, str | Path], tuple[str, ...]]] = {
    "ansfl_quadrotor": _ansfl_clip,
    "ansfl_quadrotor_raw": _run_with("ansfl_quadrotor_straightline.toml"),
    "ardupilot_csv": _run_with("ardupilot_plane_testlog2.toml"),
    "comma2k19": _run_with("comma2k19_example1.toml"),
}
"""Format -> what to do next with the converted log (``ConversionReport.hints``; the CLI
prints them): the documented pipeline file, or why this log cannot make a run and which
conversion does."""


def estimate_unit_mounting(source: str | Path, imu: int | str = 1, *,
                           options: MountingOptions | None = None) -> MountingEstimate:
    """C_bs of one DOT unit of the ANSFL quadrotor set from all its processed paths together."""
    m = unit_mounting_input(source, imu)
    return _estimate(m if options is None else replace(m, options=asdict(options)))
