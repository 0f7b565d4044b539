"""Trajectories without IMU -> reference Parquet: KF-GINS RTK text file, NaveGo reference CSV.

Sources (docs/realdata.md, ``gnss_reference_only``):

- ``kfgins_dataset1/GNSS-RTK.txt``: whitespace-separated GPS seconds of week, latitude and
  longitude (deg), ellipsoidal height (m), std north / east / down (m); 1 Hz RTK.
- ``navego_ekinox_turin/ref.csv``: GPS seconds of week, lat / lon (deg), h (m, ellipsoidal per
  NaveGo), NED velocity (m/s), roll / pitch / yaw (deg); 1 Hz, from NovAtel Inertial Explorer.

Conversion
----------
- Time: GPS seconds of week; the week is not in either file. With ``gps_week`` given the stamps
  are UTC Unix ns (GPS - UTC leap seconds applied); without it they are GPS seconds of week in
  ns (no leap seconds, no week), said in the file metadata and the report.
- RTK file: velocity by central differences of the positions in local NED (one-sided at the
  ends, ``_common.velocity_from_positions``); attitude is kinematic, not measured: roll 0, pitch
  = flight-path angle, yaw = course, held through stops (below 1 m/s). The RTK sigmas are
  summarised in the metadata (the reference table has no sigma columns).
- NaveGo reference: copied (deg -> rad -> deg round trip), yaw wrapped to [0, 360).
The reference Parquet goes to ``out`` if it ends in ``.parquet``, else to
``<stem>.reference.parquet`` beside it; no MCAP is written (no IMU).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pospp.io.converters._common import (
    SECONDS_PER_WEEK,
    ConversionError,
    ParsedLog,
    check_increasing,
    gps_to_unix_ns,
    kinematic_attitude,
    read_csv,
    seconds_to_ns,
    velocity_from_positions,
)
from pospp.types import ReferenceTrajectory

__all__ = ["parse_kfgins_rtk", "parse_navego_reference"]

_NO_IMU = "no IMU in the source"


def _stamps(tow_s: np.ndarray, gps_week: int | None) -> tuple[np.ndarray, str]:
    if gps_week is None:
        return seconds_to_ns(tow_s), "GPS time of week in ns (week unknown; no leap seconds)"
    return (gps_to_unix_ns(gps_week * SECONDS_PER_WEEK + tow_s),
            f"UTC ns since the Unix epoch from GPS week {gps_week} + TOW")


def _source_file(source: Path, name: str) -> Path:
    if source.is_file():
        return source
    p = source / name
    if not p.is_file():
        raise ConversionError(f"{source}: expected the file {name} or a folder holding it")
    return p


def parse_kfgins_rtk(source: str | Path, *, gps_week: int | None = None) -> ParsedLog:
    """Parse the KF-GINS ``GNSS-RTK.txt`` into a reference trajectory (module docstring).

    Parameters
    ----------
    source : path-like
        ``GNSS-RTK.txt`` or a folder holding it.
    gps_week : int, optional
        GPS week of the data (not in the file).
    """
    path = _source_file(Path(source), "GNSS-RTK.txt")
    try:
        raw = np.loadtxt(path, dtype=float, ndmin=2)
    except ValueError as exc:
        raise ConversionError(f"{path}: not whitespace-separated numbers ({exc})") from exc
    if raw.shape[1] != 7:
        raise ConversionError(f"{path}: expected 7 columns (tow, lat, lon, h, std N/E/D); got "
                              f"{raw.shape[1]}")
    if not np.all(np.isfinite(raw)):
        row = int(np.argmin(np.all(np.isfinite(raw), axis=1)))
        raise ConversionError(f"{path}: non-finite value in row {row}")
    tow = raw[:, 0]
    check_increasing(path, "GPS seconds of week (column 1)", tow)
    if np.any(np.abs(raw[:, 1]) > 90.0) or np.any(np.abs(raw[:, 2]) > 180.0):
        raise ConversionError(f"{path}: latitude / longitude out of range; expected degrees")
    lat, lon, h = np.radians(raw[:, 1]), np.radians(raw[:, 2]), raw[:, 3]
    v_n = velocity_from_positions(tow - tow[0], lat, lon, h)
    rpy = kinematic_attitude(v_n)
    time_ns, time_system = _stamps(tow, gps_week)
    ref = ReferenceTrajectory(time_ns=time_ns, lat_rad=lat, lon_rad=lon, height_m=h,
                              v_n_mps=v_n, rpy_rad=rpy)
    std = raw[:, 4:7]
    meta = {
        "source": str(path), "time_system": time_system,
        "height_datum": "WGS-84 ellipsoid (as the source states)",
        "velocity": "central differences of RTK positions in local NED",
        "attitude": "kinematic, not measured: roll 0, pitch flight-path angle, yaw course",
        "rtk_std_median_ned_m": repr(np.median(std, axis=0).round(4).tolist()),
        "rtk_std_max_ned_m": repr(std.max(axis=0).round(4).tolist()),
    }
    warnings = () if gps_week is not None else (
        "GPS week unknown: time_ns is GPS seconds of week, not UTC",)
    return ParsedLog(
        fmt="kfgins_rtk", source=str(path), imu=None, fix=None, vel=None, reference=ref,
        time_system=time_system, height_datum="WGS-84 ellipsoid", imu_convention=_NO_IMU,
        axes=_NO_IMU, reference_metadata=meta, reference_only_out=True,
        checks={"rtk_std_north_median_m": float(np.median(std[:, 0])),
                "rtk_std_down_median_m": float(np.median(std[:, 2])),
                "duration_s": float(tow[-1] - tow[0])},
        notes=("velocity from position differences; attitude kinematic (roll 0)",),
        warnings=warnings,
    )


def parse_navego_reference(source: str | Path, *, gps_week: int | None = None) -> ParsedLog:
    """Parse NaveGo's ``ref.csv`` (Inertial Explorer reference) into a reference trajectory."""
    path = _source_file(Path(source), "ref.csv")
    cols = ["gps_tow_s", "lat_deg", "lon_deg", "h_m", "vn_m_s", "ve_m_s", "vd_m_s",
            "roll_deg", "pitch_deg", "yaw_deg"]
    df: pd.DataFrame = read_csv(path, cols)
    tow = df["gps_tow_s"].to_numpy(dtype=float)
    check_increasing(path, "gps_tow_s", tow)
    time_ns, time_system = _stamps(tow, gps_week)
    ref = ReferenceTrajectory(
        time_ns=time_ns, lat_rad=np.radians(df["lat_deg"].to_numpy(float)),
        lon_rad=np.radians(df["lon_deg"].to_numpy(float)), height_m=df["h_m"].to_numpy(float),
        v_n_mps=df[["vn_m_s", "ve_m_s", "vd_m_s"]].to_numpy(float),
        rpy_rad=np.radians(df[["roll_deg", "pitch_deg", "yaw_deg"]].to_numpy(float)))
    return ParsedLog(
        fmt="navego_reference", source=str(path), imu=None, fix=None, vel=None, reference=ref,
        time_system=time_system, height_datum="WGS-84 ellipsoid", imu_convention=_NO_IMU,
        axes=_NO_IMU, reference_only_out=True, reference_metadata={
            "source": str(path), "time_system": time_system,
            "height_datum": "WGS-84 ellipsoid (NaveGo reference)",
            "attitude": "Ekinox body w.r.t. NED from Inertial Explorer"},
        warnings=() if gps_week is not None else (
            "GPS week unknown: time_ns is GPS seconds of week, not UTC",),
    )
