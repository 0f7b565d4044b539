"""ANSFL quadrotor straight-line set (Xsens DOT IMUs + DJI RTK solution) -> MCAP + reference.

Source (docs/realdata.md, ``ansfl_quadrotor_straightline``): the authors' time-aligned segments
``processed/path_N/{IMU_k,IMUAvg,GTExtended}.csv`` and the Airdata export of the whole flight
``raw/*Airdata.csv`` (for the UTC time of the log time base).

Conversion
----------
- IMU: Xsens DOT sensor axes s (not stated relative to the airframe; z is roughly up: about
  +9.5 m/s^2 on z in level flight), specific force m/s^2, rate deg/s -> rad/s. The mounting
  C_bs of the chosen unit is unknown; :func:`unit_mounting_input` gathers the windows of all
  four paths together for ``pospp.convert`` to estimate it with :mod:`pospp.nav.mounting`
  (one mounting per unit for the whole flight), using the
  drone's own attitude (roll, pitch, compass heading) as the body attitude, since the drone does
  not always fly nose first (path 4 flies backwards). The IMU is written in body FRD, rotated by
  that estimate; the estimate and its quality figures go into the report and the MCAP metadata.
- Sample convention: the DOT's 120 Hz output comes from its strapdown-integration (SDI)
  increments, so each sample is taken as the mean over the interval ending at its stamp (no
  shift). The source does not say; the residual timing is checked against the reference yaw
  rate (``checks['imu_lag_vs_reference_s']``).
- Time: ``IMU_k.time`` counts from the path's first GTExtended epoch, whose ``time(millisecond)``
  is on the Airdata log time base. Log time -> UTC by the offset between ``datetime(utc)`` (whole
  seconds) and ``time(millisecond)`` around the path: the midpoint of the interval allowed by
  the second boundaries (about +-0.1 s; the Airdata log time jumps by 73 s at 155 s, so the
  offset is taken locally). The authors' IMU-to-GT alignment is kept as is.
- GNSS and reference: the drone's RTK GNSS/INS solution from GTExtended (10 Hz): latitude /
  longitude (deg), ``xSpeed`` north, ``ySpeed`` east, ``zSpeed`` positive down (checked on the
  whole Airdata log: correlation with d(altitude)/dt is -0.95), roll / pitch / compass heading
  (deg). The compass heading agrees with the GNSS course within about 1 deg on the nose-first
  paths, so it is taken as true, not magnetic, heading. The same solution serves as the fix
  topic (nominal sigma 0.05 m horizontal, 0.1 m vertical, velocity 0.1 m/s: RTK, and the
  speeds are rounded to 0.1 m/s) and as the reference; it is not independent of itself.
- Height: ``altitude_above_seaLevel`` is DJI's take-off altitude plus barometric climb (about 10
  m here), not an ellipsoidal height; no geoid model is shipped with pospp, so the height is
  written as given unless ``geoid_undulation_m`` is passed, and a warning says so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pospp import earth
from pospp.io.converters._common import (
    ConversionError,
    HeadingRateCheck,
    MountingInput,
    ParsedLog,
    check_gravity,
    check_increasing,
    diag_cov,
    read_csv,
    require_file,
    seconds_to_ns,
)
from pospp.types import GnssFixes, GnssVelocities, ImuSamples, ReferenceTrajectory

__all__ = ["parse_ansfl_quadrotor", "unit_mounting_input"]

GT_COLUMNS = ["time(millisecond)", "latitude", "longitude", "altitude_above_seaLevel(meters)",
            "xSpeed(m/s)", "ySpeed(m/s)", "zSpeed(m/s)", "roll(degrees)", "pitch(degrees)",
            "compass_heading(degrees)"]
"""The columns read from ``GTExtended.csv`` (and from the Airdata log, which has them too)."""
_IMU_COLS = ["time", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z"]



QUADROTOR_MOUNTING_OPTIONS = {"window_s": 0.5, "max_static_accel_mps2": 0.3,
                              "min_horizontal_accel_mps2": 0.3, "min_speed_mps": 0.0}
"""Mounting-estimate options for the DOT units on the quadrotor (hover and short pushes)."""


def dji_height(h_m: np.ndarray, geoid_undulation_m: float | None
               ) -> tuple[np.ndarray, str, list[str]]:
    """DJI's altitude above sea level -> height [m], its datum text and the warnings.

    DJI logs take-off altitude plus barometric climb above sea level, not an ellipsoidal
    height: with the geoid undulation N given, h = H + N; without it the height is kept as
    logged and a warning says so.
    """
    if geoid_undulation_m is None:
        return h_m, ("DJI altitude_above_seaLevel (take-off altitude + baro climb); NOT "
                     "ellipsoidal"), [
            "height_m is DJI's altitude above sea level, not ellipsoidal: pass "
            "geoid_undulation_m (and beware its barometric origin)"]
    return (h_m + geoid_undulation_m,
            f"DJI altitude above sea level + N, N = {geoid_undulation_m} m (given)", [])


def dji_gnss(a: dict, gt_ns: np.ndarray, geoid_undulation_m: float | None
             ) -> tuple[GnssFixes, GnssVelocities, np.ndarray, str, list[str]]:
    """The DJI RTK/INS solution as pospp's GNSS fixes and velocities (one place for both
    quadrotor formats): NED covariances 0.05/0.05/0.1 m and 0.1 m/s per axis (1-sigma, the
    dataset's nominal RTK accuracy), status GBAS; heights through :func:`dji_height`.

    Returns (fix, vel, height_m, datum text, warnings).
    """
    h, datum, warnings = dji_height(a["h_m"], geoid_undulation_m)
    n = gt_ns.size
    fix = GnssFixes(time_ns=gt_ns, lat_rad=a["lat_rad"], lon_rad=a["lon_rad"], height_m=h,
                    pos_cov_ned_m2=diag_cov([0.05, 0.05, 0.1], n),
                    status=np.full(n, 2, dtype=np.int8))
    vel = GnssVelocities(time_ns=gt_ns, v_n_mps=a["v_n"],
                         vel_cov_ned_m2ps2=diag_cov([0.1, 0.1, 0.1], n))
    return fix, vel, h, datum, warnings

def root_and_path(source: Path, path: int | None) -> tuple[Path, int]:
    """Dataset root and path number, from the root (with ``path``) or a ``path_N`` folder."""
    if source.name.startswith("path_") and (source / "GTExtended.csv").is_file():
        n = int(source.name.split("_")[1])
        if path is not None and path != n:
            raise ConversionError(f"{source}: folder is path {n} but path={path} was given")
        return source.parent.parent, n
    if not (source / "processed").is_dir():
        raise ConversionError(f"{source}: expected the dataset folder (with processed/ and raw/)"
                              " or a processed/path_N folder")
    return source, 1 if path is None else path


def _imu_file(root: Path, path: int, imu: int | str) -> Path:
    name = "IMUAvg.csv" if imu == "avg" else f"IMU_{int(imu)}.csv"
    return require_file(root / "processed" / f"path_{path}", name)


def read_path(root: Path, path: int, imu: int | str) -> tuple[pd.DataFrame, pd.DataFrame, Path]:
    """(GTExtended rows, IMU rows, IMU file) of ``processed/path_N``; ``imu`` a unit number
    or ``"avg"``. Raises ConversionError for a missing file or column or a time that does
    not increase."""
    gt_p = require_file(root / "processed" / f"path_{path}", "GTExtended.csv")
    imu_p = _imu_file(root, path, imu)
    gt = read_csv(gt_p, GT_COLUMNS)
    im = read_csv(imu_p, _IMU_COLS)
    check_increasing(gt_p, "time(millisecond)", gt["time(millisecond)"].to_numpy(float))
    check_increasing(imu_p, "time", im["time"].to_numpy(float))
    return gt, im, imu_p


def available_paths(root: Path) -> list[int]:
    """The numbers N of the ``processed/path_N`` folders that hold a ``GTExtended.csv``."""
    out = []
    for d in sorted((root / "processed").glob("path_*")):
        if (d / "GTExtended.csv").is_file():
            out.append(int(d.name.split("_")[1]))
    return out


def log_to_utc_offset_s(root: Path, lo_s: float, hi_s: float) -> tuple[float, float]:
    """(UTC - log time) offset [s] around log times [lo, hi], and its half-width [s]."""
    raw = sorted((root / "raw").glob("*Airdata.csv"))
    if not raw:
        raise ConversionError(f"{root / 'raw'}: no *Airdata.csv (needed for the UTC time base)")
    a = pd.read_csv(raw[0], usecols=["time(millisecond)", "datetime(utc)"])
    t = a["time(millisecond)"].to_numpy(dtype=float) * 1e-3
    utc = (pd.to_datetime(a["datetime(utc)"]) - pd.Timestamp("1970-01-01")).dt.total_seconds()
    utc = utc.to_numpy(dtype=float)
    m = (t >= lo_s - 20.0) & (t <= hi_s + 20.0)
    if m.sum() < 20:
        raise ConversionError(f"{raw[0]}: log time {lo_s:.1f}-{hi_s:.1f} s not covered")
    lower = float(np.max(utc[m] - t[m]))       # true UTC >= the whole second shown
    upper = float(np.min(utc[m] + 1.0 - t[m]))  # true UTC < the next second
    if abs(lower - upper) > 1.0:
        raise ConversionError(f"{raw[0]}: UTC minus log time is not constant near "
                              f"{lo_s:.1f}-{hi_s:.1f} s (log time jumps?)")
    return 0.5 * (lower + upper), 0.5 * abs(upper - lower)


def gt_arrays(gt: pd.DataFrame) -> dict[str, np.ndarray]:
    """The DJI solution's columns in SI: ``log_s`` (log time [s]), ``lat_rad``, ``lon_rad``,
    ``h_m`` (as logged, see the module docstring), ``v_n`` (N, 3) NED [m/s], ``rpy`` (N, 3)
    roll, pitch, compass heading [rad]."""
    v = gt[["xSpeed(m/s)", "ySpeed(m/s)", "zSpeed(m/s)"]].to_numpy(dtype=float)
    rpy = np.radians(gt[["roll(degrees)", "pitch(degrees)", "compass_heading(degrees)"]]
                     .to_numpy(dtype=float))
    return {
        "log_s": gt["time(millisecond)"].to_numpy(dtype=float) * 1e-3,
        "lat_rad": np.radians(gt["latitude"].to_numpy(dtype=float)),
        "lon_rad": np.radians(gt["longitude"].to_numpy(dtype=float)),
        "h_m": gt["altitude_above_seaLevel(meters)"].to_numpy(dtype=float),
        "v_n": v, "rpy": rpy,
    }


def unit_mounting_input(source: str | Path, imu: int | str = 1) -> MountingInput:
    """The mounting-estimate inputs of one DOT unit (or the average) from all processed paths.

    Windows of every path are stacked on the common log time base; the body attitude is the
    drone's roll, pitch and compass heading (module docstring).
    """
    root, _ = root_and_path(Path(source), None)
    ts, fs, tv, vv, rr = [], [], [], [], []
    lat0 = h0 = None
    for p in available_paths(root):
        gt, im, imu_p = read_path(root, p, imu)
        a = gt_arrays(gt)
        ts.append(a["log_s"][0] + im["time"].to_numpy(dtype=float))
        fs.append(im[["Acc_X", "Acc_Y", "Acc_Z"]].to_numpy(dtype=float))
        tv.append(a["log_s"])
        vv.append(a["v_n"])
        rr.append(a["rpy"])
        if lat0 is None:
            lat0, h0 = float(a["lat_rad"][0]), float(a["h_m"][0])
    if not ts or lat0 is None or h0 is None:
        raise ConversionError(f"{root / 'processed'}: no path_N folders")
    rpy = np.concatenate(rr)
    rpy[:, 2] = np.unwrap(rpy[:, 2])
    return MountingInput(
        t_s=np.concatenate(ts), f_s_mps2=np.concatenate(fs), t_vel_s=np.concatenate(tv),
        v_n_mps=np.concatenate(vv), lat_rad=lat0, height_m=h0, body_rpy_rad=rpy,
        options=dict(QUADROTOR_MOUNTING_OPTIONS), apply=True,
        description=f"unit {imu}: mounting estimated from all paths")


def parse_ansfl_quadrotor(
    source: str | Path,
    *,
    path: int | None = None,
    imu: int | str = 1,
    geoid_undulation_m: float | None = None,
) -> ParsedLog:
    """Parse one processed path of the ANSFL quadrotor set into the data contract.

    The IMU stays in the DOT's sensor axes; ``mounting`` holds the inputs of its estimate (all
    paths of the unit) and ``pospp.convert`` rotates it into body FRD.

    Parameters
    ----------
    source : path-like
        The dataset folder (``processed/``, ``raw/``) or one ``processed/path_N`` folder.
    path : int, optional
        Path number 1..4 (default 1, or the folder's own number).
    imu : int or "avg"
        DOT unit 1..4, or "avg" for the authors' average of the four.
    geoid_undulation_m : float, optional
        Added to the logged altitude when given (module docstring).

    Returns
    -------
    ParsedLog
    """
    if imu != "avg" and imu not in (1, 2, 3, 4):
        raise ValueError(f"imu must be 1, 2, 3, 4 or 'avg'; got {imu!r}")
    root, p = root_and_path(Path(source), path)
    gt, im, imu_p = read_path(root, p, imu)
    a = gt_arrays(gt)
    t_imu_log = a["log_s"][0] + im["time"].to_numpy(dtype=float)
    f_s = im[["Acc_X", "Acc_Y", "Acc_Z"]].to_numpy(dtype=float)
    w_s = np.radians(im[["Gyr_X", "Gyr_Y", "Gyr_Z"]].to_numpy(dtype=float))
    g_med = check_gravity(imu_p, f_s, "Acc_* expected in m/s^2")
    offset_s, half_width_s = log_to_utc_offset_s(root, a["log_s"][0], a["log_s"][-1])
    imu_ns = seconds_to_ns(t_imu_log + offset_s)
    gt_ns = seconds_to_ns(a["log_s"] + offset_s)
    rpy = a["rpy"]
    rpy_unwrapped = rpy.copy()
    rpy_unwrapped[:, 2] = np.unwrap(rpy[:, 2])
    fix, vel, h, datum, warnings = dji_gnss(a, gt_ns, geoid_undulation_m)
    samples = ImuSamples(time_ns=imu_ns, w_ib_b_radps=w_s, f_ib_b_mps2=f_s,
                         frame_id=f"xsens_dot_{imu}")
    ref = ReferenceTrajectory(time_ns=gt_ns, lat_rad=a["lat_rad"], lon_rad=a["lon_rad"],
                              height_m=h, v_n_mps=a["v_n"], rpy_rad=rpy)
    time_system = ("UTC ns since the Unix epoch: Airdata log time + (datetime(utc) - log "
                   f"time) offset, +-{half_width_s:.2f} s")
    imu_conv = "DOT SDI output taken as the mean over the interval ending at the stamp"
    meta = {
        "converter": "pospp.io.converters.ansfl_quadrotor", "source": str(imu_p),
        "path": str(p), "imu": str(imu), "time_system": time_system, "height_datum": datum,
        "imu_convention": imu_conv,
        "gnss": "DJI RTK GNSS/INS solution (also the reference)",
    }
    lat0 = float(a["lat_rad"][0])
    checks: dict[str, float] = {
        "gravity_median_mps2": g_med, "utc_offset_half_width_s": half_width_s,
        "reference_speed_max_mps": float(np.hypot(a["v_n"][:, 0], a["v_n"][:, 1]).max()),
        "gravity_model_mps2": float(earth.normal_gravity_mps2(lat0, float(h[0]))),
    }
    mounting = unit_mounting_input(root, imu)
    return ParsedLog(
        fmt="ansfl_quadrotor", source=str(root), imu=samples, fix=fix, vel=vel, reference=ref,
        time_system=time_system, height_datum=datum, imu_convention=imu_conv,
        axes="Xsens DOT sensor axes", metadata=meta, reference_metadata={
            "source": str(root / "processed" / f"path_{p}" / "GTExtended.csv"),
            "frame": "DJI body FRD w.r.t. NED (compass heading as yaw)",
            "time_system": time_system, "height_datum": datum},
        imu_frame_id=samples.frame_id, gnss_frame_id="dji_rtk", checks=checks,
        warnings=tuple(warnings),
        notes=tuple(x for x in (
            f"path {p}",
            "IMUAvg is the authors' average of the raw outputs of the four units; their "
            "estimated mountings agree within about 2 deg (docs/realdata.md)"
            if imu == "avg" else "") if x),
        mounting=mounting,
        heading_check=HeadingRateCheck(t_imu_s=t_imu_log, t_ref_s=a["log_s"],
                                       rpy_ref_rad=rpy_unwrapped, max_lag_s=0.5),
    )

