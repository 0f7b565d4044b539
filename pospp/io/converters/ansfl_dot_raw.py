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
- Mounting: estimated on this recording (hover and accelerations, with the DJI attitude as the
  body attitude); see ``ansfl_quadrotor``.
- GNSS / reference: the Airdata rows over the recording (10 Hz). They have the same columns,
  units, signs and height caveat as GTExtended (``ansfl_quadrotor``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pospp.io.converters._common import (
    ConversionError,
    ConversionReport,
    check_gravity,
    lag_by_correlation,
    median_rate_hz,
    read_csv,
    reference_path_for,
    seconds_to_ns,
)
from pospp.io.converters.ansfl_quadrotor import (
    _GT_COLS,
    _available_paths,
    _gt_arrays,
    _log_to_utc_offset_s,
    _read_path,
    _root_and_path,
    dji_gnss,
)
from pospp.io.mcap_writer import write_flight_log
from pospp.io.parquet_tables import write_reference_trajectory
from pospp.nav.mounting import MountingOptions, estimate_mounting
from pospp.types import ImuSamples, ReferenceTrajectory

__all__ = ["convert_ansfl_dot_raw", "raw_files"]

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


def convert_ansfl_dot_raw(
    source: str | Path,
    out_mcap: str | Path,
    *,
    unit: int = 1,
    recording: int = 2,
    geoid_undulation_m: float | None = None,
) -> ConversionReport:
    """Convert one raw DOT recording with the Airdata GNSS/INS solution over its span.

    Parameters
    ----------
    source : path-like
        The dataset folder (``processed/``, ``raw/``).
    out_mcap : path-like
        MCAP to write; the reference goes to ``<stem>.reference.parquet`` beside it.
    unit : int
        1..4, as processed ``IMU_k`` (DOT1, DOT2, DOT4, DOT7).
    recording : int
        1 (about 57 s from 08:11:10 UTC, holds path 1) or 2 (about 190 s from 08:14:37 UTC,
        holds paths 2-4).
    geoid_undulation_m : float, optional
        Added to the DJI altitude when given.

    Returns
    -------
    ConversionReport
    """
    root, _ = _root_and_path(Path(source), None)
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
    offsets: list[float] = []
    path_utc_offsets: list[float] = []
    acc_x = f_s[:, 0]
    for p in _available_paths(root):
        gt, im, _ = _read_path(root, p, unit)
        row = min(5, len(im) - 1)
        hit = np.flatnonzero((np.abs(acc_x - im["Acc_X"].iloc[row]) < 1e-7)
                             & (np.abs(np.degrees(w_s[:, 2]) - im["Gyr_Z"].iloc[row]) < 1e-7))
        if hit.size != 1:
            continue
        log_ms = gt["time(millisecond)"].to_numpy(dtype=float)
        utc_off, _ = _log_to_utc_offset_s(root, log_ms[0] * 1e-3, log_ms[-1] * 1e-3)
        offsets.append(float(log_ms[0] * 1e-3 + im["time"].iloc[row] + utc_off - t_dev[hit[0]]))
        path_utc_offsets.append(utc_off)
    if not offsets:
        raise ConversionError(f"{dot_p}: no processed path of unit {unit} found in this "
                              "recording; cannot place its clock on UTC")
    dev_to_utc = float(np.median(offsets))
    utc_imu = t_dev + dev_to_utc
    # Airdata rows over the recording; the log time base jumps (docs/realdata.md), so the
    # UTC offset is taken around the recording and must be constant there
    raw = sorted((root / "raw").glob("*Airdata.csv"))
    if not raw:
        raise ConversionError(f"{root / 'raw'}: no *Airdata.csv")
    air = read_csv(raw[0], _GT_COLS, usecols=lambda c: c.strip() in _GT_COLS)
    a_all = _gt_arrays(air)
    log = a_all["log_s"]
    lo_log = utc_imu[0] - path_utc_offsets[0]
    hi_log = utc_imu[-1] - path_utc_offsets[0]
    utc_off_rec, half_rec = _log_to_utc_offset_s(root, lo_log, hi_log)
    sel = (log >= lo_log - 0.5) & (log <= hi_log + 0.5)
    a = {k: v[sel] for k, v in a_all.items()}
    utc_gt = a["log_s"] + utc_off_rec
    # mounting on this recording
    rpy = a["rpy"].copy()
    rpy[:, 2] = np.unwrap(rpy[:, 2])
    mounting = estimate_mounting(
        utc_imu - utc_gt[0], f_s, utc_gt - utc_gt[0], a["v_n"], lat_rad=float(a["lat_rad"][0]),
        height_m=float(a["h_m"][0]), body_rpy_rad=rpy,
        options=MountingOptions(window_s=0.5, max_static_accel_mps2=0.3,
                                min_horizontal_accel_mps2=0.3, min_speed_mps=0.0))
    c_bs = mounting.c_bs
    f_b, w_b = f_s @ c_bs.T, w_s @ c_bs.T
    # independent timing check: IMU heading rate vs DJI yaw rate (1 s means)
    r_i = np.interp(utc_imu, utc_gt, rpy[:, 0])
    p_i = np.interp(utc_imu, utc_gt, rpy[:, 1])
    hr = (w_b[:, 1] * np.sin(r_i) + w_b[:, 2] * np.cos(r_i)) / np.cos(p_i)
    yr = np.gradient(rpy[:, 2], utc_gt)
    k_i = max(1, int(round(1.0 / float(np.median(np.diff(utc_imu))))))
    k_g = max(1, int(round(1.0 / float(np.median(np.diff(utc_gt))))))
    lag, corr = lag_by_correlation(
        utc_imu - utc_gt[0], np.convolve(hr, np.ones(k_i) / k_i, mode="same"),
        utc_gt - utc_gt[0], np.convolve(yr, np.ones(k_g) / k_g, mode="same"),
        max_lag_s=1.0, step_s=0.01)
    checks = {
        "gravity_median_mps2": g_med,
        "dot_clock_offset_spread_s": float(np.ptp(offsets)),
        "n_paths_matched": float(len(offsets)),
        "utc_offset_half_width_s": float(half_rec),
        "imu_lag_vs_reference_s": lag,
        "heading_rate_correlation": corr,
    }
    imu_ns = seconds_to_ns(utc_imu)
    gt_ns = seconds_to_ns(utc_gt)
    fix, vel, h, datum, warnings = dji_gnss(a, gt_ns, geoid_undulation_m)
    n = gt_ns.size
    samples = ImuSamples(time_ns=imu_ns, w_ib_b_radps=w_b, f_ib_b_mps2=f_b,
                         frame_id=f"xsens_dot_{unit}")
    time_system = ("UTC ns since the Unix epoch: DOT clock + offset from the processed paths "
                   f"({len(offsets)} matched, spread {np.ptp(offsets):.3f} s); Airdata log "
                   f"time + local UTC offset (+-{half_rec:.2f} s)")
    imu_conv = "DOT SDI output taken as the mean over the interval ending at the stamp"
    axes = (f"Xsens DOT sensor axes rotated to body FRD by the estimated C_bs "
            f"(rpy_deg {np.degrees(mounting.rpy_rad).round(2).tolist()})")
    meta = {"converter": "pospp.io.converters.ansfl_dot_raw", "source": str(dot_p),
            "time_system": time_system, "height_datum": datum, "imu_convention": imu_conv,
            "axes": axes, "c_bs_estimated": repr(np.round(c_bs, 9).tolist()),
            "gnss": "DJI RTK GNSS/INS solution from Airdata (also the reference)"}
    out = write_flight_log(out_mcap, samples, fix, vel, imu_frame_id=samples.frame_id,
                           gnss_frame_id="dji_rtk", metadata=meta)
    ref = ReferenceTrajectory(time_ns=gt_ns, lat_rad=a["lat_rad"], lon_rad=a["lon_rad"],
                              height_m=h, v_n_mps=a["v_n"], rpy_rad=a["rpy"])
    ref_path = write_reference_trajectory(
        reference_path_for(out), ref,
        metadata={"source": str(raw[0]), "frame": "DJI body FRD w.r.t. NED",
                  "time_system": time_system, "height_datum": datum})
    notes = [f"{dot_p.name}: {n_dropped} row(s) dropped (non-finite or all-zero)"]
    return ConversionReport(
        fmt="ansfl_quadrotor_raw", source=str(dot_p), mcap_path=str(out),
        reference_path=str(ref_path), n_imu=len(samples), n_fix=n, n_vel=n, n_reference=n,
        imu_rate_hz=median_rate_hz(imu_ns), gnss_rate_hz=median_rate_hz(gt_ns),
        start_ns=int(min(imu_ns[0], gt_ns[0])), end_ns=int(max(imu_ns[-1], gt_ns[-1])),
        time_system=time_system, height_datum=datum, imu_convention=imu_conv, axes=axes,
        mounting=mounting, checks=checks, notes=tuple(notes), warnings=tuple(warnings),
    )
