"""Converters of measured logs to pospp's data contract (MCAP flight log + reference Parquet).

One module per source format; :func:`convert` picks one by name or by the files present and
returns a :class:`ConversionReport` (no printing: the CLI renders the report). Every converter
writes through ``pospp.io.mcap_writer.write_flight_log`` (IMU in body FRD, mean rate and specific
force over the interval ending at the stamp, UTC int64 ns stamps, GNSS lat / lon in rad with
ellipsoidal height and NED covariances) and ``pospp.io.parquet_tables.
write_reference_trajectory``. Per-dataset units, frames, time systems and assumptions:
docs/realdata.md and each module's docstring.

Formats (``FORMATS`` keys)
--------------------------
- ``ardupilot_csv``: ArduPlane dataflash CSV export (imu.csv, gps.csv, att.csv).
- ``comma2k19``: comma2k19 segment CSV export (imu.csv, gnss_ublox.csv, pose_reference.csv).
- ``ansfl_quadrotor``: ANSFL quadrotor straight-line set (processed/path_N, raw/*Airdata.csv).
- ``ansfl_quadrotor_raw``: one untrimmed Xsens DOT recording of that set with the Airdata log
  over its span (never detected: pass ``fmt=``).
- ``kfgins_rtk``: KF-GINS ``GNSS-RTK.txt`` (reference only, no IMU).
- ``navego_reference``: NaveGo ``ref.csv`` (reference only, no IMU).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from pospp.io.converters._common import ConversionError, ConversionReport

__all__ = ["FORMATS", "ConversionError", "ConversionReport", "convert", "detect_format"]


def _ardupilot(src: Path, out: Path, **kw: Any) -> ConversionReport:
    from pospp.io.converters.ardupilot import convert_ardupilot

    return convert_ardupilot(src, out, **kw)


def _comma(src: Path, out: Path, **kw: Any) -> ConversionReport:
    from pospp.io.converters.comma2k19 import convert_comma2k19

    return convert_comma2k19(src, out, **kw)


def _quad(src: Path, out: Path, **kw: Any) -> ConversionReport:
    from pospp.io.converters.ansfl_quadrotor import convert_ansfl_quadrotor

    return convert_ansfl_quadrotor(src, out, **kw)


def _quad_raw(src: Path, out: Path, **kw: Any) -> ConversionReport:
    from pospp.io.converters.ansfl_dot_raw import convert_ansfl_dot_raw

    return convert_ansfl_dot_raw(src, out, **kw)


def _kfgins(src: Path, out: Path, **kw: Any) -> ConversionReport:
    from pospp.io.converters.gnss_reference import convert_kfgins_rtk

    return convert_kfgins_rtk(src, out, **kw)


def _navego(src: Path, out: Path, **kw: Any) -> ConversionReport:
    from pospp.io.converters.gnss_reference import convert_navego_reference

    return convert_navego_reference(src, out, **kw)


FORMATS: dict[str, Callable[..., ConversionReport]] = {
    "ardupilot_csv": _ardupilot,
    "comma2k19": _comma,
    "ansfl_quadrotor": _quad,
    "ansfl_quadrotor_raw": _quad_raw,
    "kfgins_rtk": _kfgins,
    "navego_reference": _navego,
}
"""Format name -> converter ``(source, out, **options) -> ConversionReport``."""


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
        raise ConversionError(f"{p}: unknown file; give its folder or fmt= one of "
                              f"{sorted(FORMATS)}")
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
    raise ConversionError(f"{p}: no known layout (found {sorted(names)}); pass fmt= one of "
                          f"{sorted(FORMATS)}")


def convert(
    source_dir_or_file: str | Path,
    out_mcap: str | Path,
    *,
    fmt: str | None = None,
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
        A key of :data:`FORMATS`; detected from the files when None.
    **options
        Keyword options of the chosen converter (e.g. ``path=3, imu=2`` for
        ``ansfl_quadrotor``; ``gps_week=`` for ``kfgins_rtk``; ``geoid_undulation_m=``).

    Returns
    -------
    ConversionReport

    Raises
    ------
    ConversionError
        Unknown format, missing or malformed source file (the message names file and fault).
    """
    src = Path(source_dir_or_file)
    name = fmt if fmt is not None else detect_format(src)
    if name not in FORMATS:
        raise ConversionError(f"unknown format {name!r}; known: {sorted(FORMATS)}")
    out = Path(out_mcap)
    out.parent.mkdir(parents=True, exist_ok=True)
    return FORMATS[name](src, out, **options)
