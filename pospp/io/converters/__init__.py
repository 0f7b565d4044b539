"""Converters of measured logs to pospp's data contract (MCAP flight log + reference Parquet).

One module per source format. Converters only parse: :func:`parse` picks one by name or by the
files present and returns a :class:`ParsedLog` (IMU mean rate and specific force over the
interval ending at the stamp, UTC int64 ns stamps, GNSS lat / lon in rad with ellipsoidal height
and NED covariances, the reference trajectory). Where the IMU mounting is unknown the IMU stays in
sensor axes and ``ParsedLog.mounting`` holds the inputs of its estimate; ``pospp.convert`` (the
convert command) runs the estimate in the numeric layer (``pospp.nav.mounting``), applies it with
:func:`apply_mounting`, and writes with :func:`write_parsed` (``write_flight_log`` and
``write_reference_trajectory``), returning a :class:`ConversionReport` (no printing: the CLI
renders the report). Per-dataset units, frames, time systems and assumptions: docs/realdata.md
and each module's docstring.

Formats (``FORMATS`` keys)
--------------------------
- ``ardupilot_csv``: ArduPlane dataflash CSV export (imu.csv, gps.csv, att.csv).
- ``comma2k19``: comma2k19 segment CSV export (imu.csv, gnss_ublox.csv, pose_reference.csv).
- ``ansfl_quadrotor``: ANSFL quadrotor straight-line set (processed/path_N, raw/*Airdata.csv).
- ``ansfl_quadrotor_raw``: one untrimmed Xsens DOT recording of that set with the Airdata log
  over its span (never detected: ``--format ansfl_quadrotor_raw``, ``fmt=``).
- ``kfgins_rtk``: KF-GINS ``GNSS-RTK.txt`` (reference only, no IMU).
- ``navego_reference``: NaveGo ``ref.csv`` (reference only, no IMU).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from pospp.io.converters._common import (
    ConversionError,
    ConversionReport,
    MountingInput,
    ParsedLog,
    apply_mounting,
    write_parsed,
)

__all__ = ["FORMATS", "ConversionError", "ConversionReport", "MountingInput", "ParsedLog",
           "UnknownOptionError", "apply_mounting", "detect_format", "format_options", "parse",
           "write_parsed"]


def _ardupilot(src: Path, **kw: Any) -> ParsedLog:
    from pospp.io.converters.ardupilot import parse_ardupilot

    return parse_ardupilot(src, **kw)


def _comma(src: Path, **kw: Any) -> ParsedLog:
    from pospp.io.converters.comma2k19 import parse_comma2k19

    return parse_comma2k19(src, **kw)


def _quad(src: Path, **kw: Any) -> ParsedLog:
    from pospp.io.converters.ansfl_quadrotor import parse_ansfl_quadrotor

    return parse_ansfl_quadrotor(src, **kw)


def _quad_raw(src: Path, **kw: Any) -> ParsedLog:
    from pospp.io.converters.ansfl_dot_raw import parse_ansfl_dot_raw

    return parse_ansfl_dot_raw(src, **kw)


def _kfgins(src: Path, **kw: Any) -> ParsedLog:
    from pospp.io.converters.gnss_reference import parse_kfgins_rtk

    return parse_kfgins_rtk(src, **kw)


def _navego(src: Path, **kw: Any) -> ParsedLog:
    from pospp.io.converters.gnss_reference import parse_navego_reference

    return parse_navego_reference(src, **kw)


FORMATS: dict[str, Callable[..., ParsedLog]] = {
    "ardupilot_csv": _ardupilot,
    "comma2k19": _comma,
    "ansfl_quadrotor": _quad,
    "ansfl_quadrotor_raw": _quad_raw,
    "kfgins_rtk": _kfgins,
    "navego_reference": _navego,
}
"""Format name -> parser ``(source, **options) -> ParsedLog``."""
_PARSER_FUNCTIONS = {
    "ardupilot_csv": ("ardupilot", "parse_ardupilot"),
    "comma2k19": ("comma2k19", "parse_comma2k19"),
    "ansfl_quadrotor": ("ansfl_quadrotor", "parse_ansfl_quadrotor"),
    "ansfl_quadrotor_raw": ("ansfl_dot_raw", "parse_ansfl_dot_raw"),
    "kfgins_rtk": ("gnss_reference", "parse_kfgins_rtk"),
    "navego_reference": ("gnss_reference", "parse_navego_reference"),
}
"""Format name -> (module of pospp.io.converters, function): where each parser's options are
declared (its keyword parameters)."""


class UnknownOptionError(ConversionError):
    """An option the chosen format's parser does not take (a usage error of ``convert``)."""


def format_options(name: str) -> tuple[str, ...]:
    """The options (keyword parameters) the parser of format ``name`` takes."""
    import importlib
    import inspect

    module, function = _PARSER_FUNCTIONS[name]
    fn = getattr(importlib.import_module(f"pospp.io.converters.{module}"), function)
    return tuple(list(inspect.signature(fn).parameters)[1:])


def detect_format(source: str | Path) -> str:
    """Name the format of a source file or folder from the files it holds.

    Raises
    ------
    ConversionError
        No known layout matches (the message lists what was found).
    """
    p = Path(source)
    if p.is_file():
        if p.name == "GNSS-RTK.txt":
            return "kfgins_rtk"
        if p.name == "ref.csv":
            return "navego_reference"
        raise ConversionError(f"{p}: unknown file; give its folder, or the format with "
                              f"--format NAME (fmt= in Python), one of {sorted(FORMATS)}")
    if not p.is_dir():
        raise ConversionError(f"{p}: no such file or folder")
    names = {x.name for x in p.iterdir()}
    if {"imu.csv", "gps.csv", "att.csv"} <= names:
        return "ardupilot_csv"
    if {"imu.csv", "gnss_ublox.csv", "pose_reference.csv"} <= names:
        return "comma2k19"
    if "processed" in names or {"GTExtended.csv", "IMU_1.csv"} <= names:
        return "ansfl_quadrotor"
    if "GNSS-RTK.txt" in names:
        return "kfgins_rtk"
    if "ref.csv" in names:
        return "navego_reference"
    raise ConversionError(f"{p}: no known layout (found {sorted(names)}); give the format "
                          f"with --format NAME (fmt= in Python), one of {sorted(FORMATS)}")


def parse(source_dir_or_file: str | Path, *, fmt: str | None = None,
          **options: Any) -> ParsedLog:
    """Parse a measured log into the data contract (nothing is written, nothing estimated).

    Parameters
    ----------
    source_dir_or_file : path-like
        The dataset folder (or, for the reference-only formats, the file).
    fmt : str, optional
        A key of :data:`FORMATS`; detected from the files when None.
    **options
        Keyword options of the chosen parser (e.g. ``path=3, imu=2`` for
        ``ansfl_quadrotor``; ``gps_week=`` for ``kfgins_rtk``; ``geoid_undulation_m=``).

    Raises
    ------
    ConversionError
        Unknown format, missing or malformed source file (the message names file and fault).
    """
    src = Path(source_dir_or_file)
    name = fmt if fmt is not None else detect_format(src)
    if name not in FORMATS:
        raise ConversionError(f"unknown format {name!r}; known: {sorted(FORMATS)}")
    known = format_options(name)
    unknown = sorted(set(options) - set(known))
    if unknown:  # a TypeError of the parser's call was an "internal error" (issue 38 item 13)
        raise UnknownOptionError(f"format {name!r} has no option {', '.join(map(repr, unknown))}; "
                              f"its options: {', '.join(known) or 'none'}")
    return FORMATS[name](src, **options)
