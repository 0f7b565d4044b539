"""ANSFL quadrotor: one untrimmed Xsens DOT recording + the Airdata log -> MCAP + reference.

The processed paths (``ansfl_quadrotor``) are 13-24 s long. The raw DOT recordings run 57 s and
190 s, with hovering and the flights between the paths, and suit a longer INS/GNSS run on real
MEMS data.

Conversion (docs/realdata.md)
-----------------------------
- Units match the processed files: ``SampleTimeFine`` is in µs on the DOT's own clock
  (unwrapped at 2^32), Acc is in m/s^2 and Gyr in deg/s. Rows with a non-finite value (one
  NaN / Infinity row in DOT7's second recording) or an all-zero first sample are dropped and
  counted in the notes.
- Unit naming: processed ``IMU_k`` is the k-th DOT in name order (DOT1, DOT2, DOT4, DOT7). This
  was checked: the processed samples occur verbatim in the raw files.
- DOT clock -> UTC. The processed paths are verbatim cuts of these recordings. Every processed
  path of the same unit found in the recording (matched on exact sample values) gives one
  offset: the UTC of the processed sample (through the Airdata log time) minus its DOT time.
  The median is used, and the spread across paths is reported
  (``checks['dot_clock_offset_spread_s']``). An independent check follows: the lag between the
  IMU heading rate and the DJI yaw rate over the whole recording
  (``checks['imu_lag_vs_reference_s']``).
- Mounting: estimated by ``pospp.convert`` on this recording (hover and accelerations, with
  the DJI attitude as the body attitude); see ``ansfl_quadrotor``.
- GNSS / reference: the Airdata rows over the recording (10 Hz). They have the same columns,
  units, signs and height caveat as GTExtended (``ansfl_quadrotor``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pospp.io.converters._common import (
    ConversionError,
    HeadingRateCheck,
    MountingInput,
    ParsedLog,
    check_gravity,
    read_csv,
    seconds_to_ns,
)
from pospp.io.converters.ansfl_quadrotor import (
    GT_COLUMNS,
    QUADROTOR_MOUNTING_OPTIONS,
    available_paths,
    dji_gnss,
    gt_arrays,
    log_to_utc_offset_s,
    read_path,
    root_and_path,
)
from pospp.types import ImuSamples, ReferenceTrajectory

__all__ = ["parse_ansfl_dot_raw", "raw_files"]

_WRAP_US = 2**32


def raw_files(root: Path) -> list[list[Path]]:
    """Raw DOT files grouped by unit (name order: DOT1, DOT2, DOT4, DOT7), each by start time."""
    files = sorted((root / "raw" / "xsens_dot").glob("Xsens_DOT*_*.csv"))
    units: dict[str, list[Path]] = {}
    for f in files:
        units.setdefault(f.name.split("_")[1], []).append(f)
    return [sorted(v, key=lambda p: p.stem.split("_")[-1]) for _, v in sorted(units.items())]


def _read_dot(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    cols = ["SampleTimeFine", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z"]
    try:
        df = pd.read_csv(path, usecols=cols)
    except (OSError, ValueError) as exc:
        raise ConversionError(f"{path}: cannot read the DOT columns {cols} ({exc})") from exc
    num = np.column_stack([pd.to_numeric(df[c], errors="coerce").to_numpy(dtype=float)
                           for c in cols])
    ok = np.all(np.isfinite(num), axis=1) & np.any(num[:, 1:] != 0.0, axis=1)
    t_us = np.unwrap(num[ok, 0], period=_WRAP_US)
    if np.any(np.diff(t_us) <= 0):
        raise ConversionError(f"{path}: SampleTimeFine does not increase after unwrapping")
    return t_us * 1e-6, num[ok, 1:4], np.radians(num[ok, 4:7]), int((~ok).sum())


def _clock_offsets(root: Path, unit: int, dot_p: Path, t_dev: np.ndarray, f_s: np.ndarray,
                   w_s: np.ndarray) -> tuple[list[float], list[float]]:
    """(UTC - DOT clock) offset from each processed path of ``unit`` found verbatim in the
    recording (matched on exact sample values), and each path's (UTC - log time) offset."""
    offsets: list[float] = []
    path_utc_offsets: list[float] = []
    acc_x = f_s[:, 0]
    for p in available_paths(root):
        gt, im, _ = read_path(root, p, unit)
        row = min(5, len(im) - 1)
        hit = np.flatnonzero((np.abs(acc_x - im["Acc_X"].iloc[row]) < 1e-7)
                             & (np.abs(np.degrees(w_s[:, 2]) - im["Gyr_Z"].iloc[row]) < 1e-7))
        if hit.size != 1:
            continue
        log_ms = gt["time(millisecond)"].to_numpy(dtype=float)
        utc_off, _ = log_to_utc_offset_s(root, log_ms[0] * 1e-3, log_ms[-1] * 1e-3)
        offsets.append(float(log_ms[0] * 1e-3 + im["time"].iloc[row] + utc_off - t_dev[hit[0]]))
        path_utc_offsets.append(utc_off)
    if not offsets:
        raise ConversionError(f"{dot_p}: no processed path of unit {unit} found in this "
                              "recording; cannot place its clock on UTC")
    return offsets, path_utc_offsets


def parse_ansfl_dot_raw(
    source: str | Path,
    *,
    unit: int = 1,
    recording: int = 2,
    geoid_undulation_m: float | None = None,
) -> ParsedLog:
    """Parse one raw DOT recording with the Airdata GNSS/INS solution over its span.

    The IMU stays in sensor axes; ``mounting`` holds the inputs of its estimate on this
    recording, which ``pospp.convert`` makes and applies.

    Parameters
    ----------
    source : path-like
        The dataset folder (``processed/``, ``raw/``).
    unit : int
        1..4, as processed ``IMU_k`` (DOT1, DOT2, DOT4, DOT7).
    recording : int
        1 (about 57 s from 08:11:10 UTC, holds path 1) or 2 (about 190 s from 08:14:37 UTC,
        holds paths 2-4).
    geoid_undulation_m : float, optional
        Added to the DJI altitude when given.

    Returns
    -------
    ParsedLog
    """
    root, _ = root_and_path(Path(source), None)
    groups = raw_files(root)
    if not 1 <= unit <= len(groups):
        raise ConversionError(f"{root / 'raw' / 'xsens_dot'}: unit {unit} not found; "
                              f"{len(groups)} units present")
    if not 1 <= recording <= len(groups[unit - 1]):
        raise ConversionError(f"{root / 'raw' / 'xsens_dot'}: recording {recording} of unit "
                              f"{unit} not found; have {[p.name for p in groups[unit - 1]]}")
    dot_p = groups[unit - 1][recording - 1]
    t_dev, f_s, w_s, n_dropped = _read_dot(dot_p)
    g_med = check_gravity(dot_p, f_s, "Acc_* expected in m/s^2")
    # clock: processed paths of this unit found verbatim in the recording
    offsets, path_utc_offsets = _clock_offsets(root, unit, dot_p, t_dev, f_s, w_s)
    dev_to_utc = float(np.median(offsets))
    utc_imu = t_dev + dev_to_utc
    # Airdata rows over the recording; the log time base jumps (docs/realdata.md), so the
    # UTC offset is taken around the recording and must be constant there
    raw = sorted((root / "raw").glob("*Airdata.csv"))
    if not raw:
        raise ConversionError(f"{root / 'raw'}: no *Airdata.csv")
    air = read_csv(raw[0], GT_COLUMNS, usecols=lambda c: c.strip() in GT_COLUMNS)
    a_all = gt_arrays(air)
    log = a_all["log_s"]
    lo_log = utc_imu[0] - path_utc_offsets[0]
    hi_log = utc_imu[-1] - path_utc_offsets[0]
    utc_off_rec, half_rec = log_to_utc_offset_s(root, lo_log, hi_log)
    sel = (log >= lo_log - 0.5) & (log <= hi_log + 0.5)
    a = {k: v[sel] for k, v in a_all.items()}
    utc_gt = a["log_s"] + utc_off_rec
    rpy = a["rpy"].copy()
    rpy[:, 2] = np.unwrap(rpy[:, 2])
    mounting = MountingInput(
        t_s=utc_imu - utc_gt[0], f_s_mps2=f_s, t_vel_s=utc_gt - utc_gt[0], v_n_mps=a["v_n"],
        lat_rad=float(a["lat_rad"][0]), height_m=float(a["h_m"][0]), body_rpy_rad=rpy,
        options=dict(QUADROTOR_MOUNTING_OPTIONS), apply=True,
        description=f"unit {unit}: mounting estimated on this recording")
    checks = {
        "gravity_median_mps2": g_med,
        "dot_clock_offset_spread_s": float(np.ptp(offsets)),
        "n_paths_matched": float(len(offsets)),
        "utc_offset_half_width_s": float(half_rec),
    }
    imu_ns = seconds_to_ns(utc_imu)
    gt_ns = seconds_to_ns(utc_gt)
    fix, vel, h, datum, warnings = dji_gnss(a, gt_ns, geoid_undulation_m)
    samples = ImuSamples(time_ns=imu_ns, w_ib_b_radps=w_s, f_ib_b_mps2=f_s,
                         frame_id=f"xsens_dot_{unit}")
    time_system = ("UTC ns since the Unix epoch: DOT clock + offset from the processed paths "
                   f"({len(offsets)} matched, spread {np.ptp(offsets):.3f} s); Airdata log "
                   f"time + local UTC offset (+-{half_rec:.2f} s)")
    imu_conv = "DOT SDI output taken as the mean over the interval ending at the stamp"
    meta = {"converter": "pospp.io.converters.ansfl_dot_raw", "source": str(dot_p),
            "time_system": time_system, "height_datum": datum, "imu_convention": imu_conv,
            "gnss": "DJI RTK GNSS/INS solution from Airdata (also the reference)"}
    ref = ReferenceTrajectory(time_ns=gt_ns, lat_rad=a["lat_rad"], lon_rad=a["lon_rad"],
                              height_m=h, v_n_mps=a["v_n"], rpy_rad=a["rpy"])
    notes = [f"{dot_p.name}: {n_dropped} row(s) dropped (non-finite or all-zero)"]
    return ParsedLog(
        fmt="ansfl_quadrotor_raw", source=str(dot_p), imu=samples, fix=fix, vel=vel,
        reference=ref, time_system=time_system, height_datum=datum, imu_convention=imu_conv,
        axes="Xsens DOT sensor axes", metadata=meta, reference_metadata={
            "source": str(raw[0]), "frame": "DJI body FRD w.r.t. NED",
            "time_system": time_system, "height_datum": datum},
        imu_frame_id=samples.frame_id, gnss_frame_id="dji_rtk", checks=checks,
        notes=tuple(notes), warnings=tuple(warnings), mounting=mounting,
        heading_check=HeadingRateCheck(t_imu_s=utc_imu, t_ref_s=utc_gt, rpy_ref_rad=rpy,
                                       max_lag_s=1.0),
    )
