"""ArduPlane dataflash log exported to CSV (``imu.csv``, ``gps.csv``, ``att.csv``) -> MCAP.

Source (docs/realdata.md, ``ardupilot_plane_testlog2``): APM 2.x era log, IMU at 50 Hz stamped
in ms since autopilot boot, GPS at 5 Hz with GPS week / time of week and the boot time at which
the autopilot logged it.

Conversion
----------
- Axes: ArduPilot's body frame is x forward, y right, z down = pospp's FRD; rates rad/s and
  specific force m/s^2 (|f| about 9.6 at rest, -9.6 on z level): copied unchanged.
- Sample convention: the APM MPU-6000 driver averages the 1 kHz samples accumulated since the
  last read, so a logged value is taken as the mean over the interval ending at its stamp (the
  data contract) with no shift.
- Time: boot ms -> GPS time by the median of (GPS time - boot time) over the GPS records, plus
  the GNSS latency: GPS records are logged when they arrive, after their measurement epoch. The
  latency is estimated (or given) as the delay that best aligns the GNSS course rate with the
  IMU heading rate ``(w_y sin(roll) + w_z cos(roll)) / cos(pitch)`` (roll / pitch from the
  onboard AHRS, ``att.csv``) by cross-correlation. GPS time -> UTC with the leap seconds in force
  (16 s in November 2013). GNSS stamps are their own measurement epochs (week, TOW).
- GNSS velocity: north / east = speed * cos / sin(course); down = ``vz_m_s``, which is positive
  down (checked: correlation with -d(alt)/dt is +0.99).
- Height: ``alt_m`` is above mean sea level (u-blox hMSL); no geoid model is shipped with pospp, so
  the undulation must be given (``geoid_undulation_m``) or the MSL height is written and a
  warning says so.
- GNSS accuracy: not logged beyond HDOP; sigma_N = sigma_E = HDOP * UERE / sqrt(2) with a
  nominal UERE of 3 m (single-frequency, no SBAS), sigma_D = 2 * sigma_N; velocity 0.3 m/s
  horizontal, 0.5 m/s vertical (nominal u-blox figures). Duplicate GPS epochs are dropped.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from pospp.io.converters._common import (
    SECONDS_PER_WEEK,
    ConversionError,
    ParsedLog,
    check_gravity,
    check_increasing,
    diag_cov,
    gps_to_unix_ns,
    lag_by_correlation,
    read_csv,
    require_file,
)
from pospp.types import GnssFixes, GnssVelocities, ImuSamples

__all__ = ["parse_ardupilot"]

UERE_M = 3.0
"""Nominal user equivalent range error of a 2013 single-frequency receiver [m] (assumption)."""


def _heading_rate(t_s: NDArray, w: NDArray, att_t_s: NDArray, roll_deg: NDArray,
                  pitch_deg: NDArray) -> NDArray:
    r = np.radians(np.interp(t_s, att_t_s, roll_deg))
    p = np.radians(np.interp(t_s, att_t_s, pitch_deg))
    return (w[:, 1] * np.sin(r) + w[:, 2] * np.cos(r)) / np.cos(p)


def _gnss_lag_s(t_boot: NDArray, w: NDArray, att: pd.DataFrame, t_meas_boot: NDArray,
                spd: NDArray, crs: NDArray, min_speed_mps: float, checks: dict[str, float],
                warnings: list[str]) -> float:
    """Delay of the GNSS epochs ``t_meas_boot`` (boot base, before latency) that aligns the
    GNSS course rate with the IMU heading rate over the fast flight (NaN and a warning when
    there is too little of it)."""
    att_t = att["time_boot_ms"].to_numpy(dtype=float) * 1e-3
    hr = _heading_rate(t_boot, w, att_t, att["roll_deg"].to_numpy(float),
                       att["pitch_deg"].to_numpy(float))
    course_rate = np.gradient(np.unwrap(crs), t_meas_boot)
    fast = spd > min_speed_mps
    if fast.sum() <= 50:
        warnings.append("too little fast flight to estimate the GNSS latency")
        return float("nan")
    lo, hi = t_meas_boot[fast][0], t_meas_boot[fast][-1]
    sel = (t_meas_boot >= lo) & (t_meas_boot <= hi)
    lag, corr = lag_by_correlation(t_boot, hr, t_meas_boot[sel], course_rate[sel],
                                   max_lag_s=1.0)
    checks["gnss_lag_estimate_s"] = lag
    checks["heading_rate_correlation"] = corr
    return lag


def _gnss_records(gps: pd.DataFrame, fix_ns: NDArray, v_n: NDArray,
                  geoid_undulation_m: float | None, warnings: list[str]
                  ) -> tuple[GnssFixes, GnssVelocities, str]:
    """Fixes (sigma from HDOP x ``UERE_M``), velocities (nominal sigma) and the height datum
    (MSL unless the geoid undulation is given: then a warning)."""
    height = gps["alt_m"].to_numpy(dtype=float)
    if geoid_undulation_m is None:
        datum = "mean sea level (u-blox hMSL); geoid undulation NOT applied"
        warnings.append("height_m is above mean sea level, not the WGS-84 ellipsoid: no geoid "
                        "undulation known for the site; pass geoid_undulation_m")
    else:
        height = height + geoid_undulation_m
        datum = f"WGS-84 ellipsoid = MSL + N, N = {geoid_undulation_m} m (given)"
    hdop = gps["hdop"].to_numpy(dtype=float)
    s_h = hdop * UERE_M / math.sqrt(2.0)
    n_fix = len(gps)
    fix = GnssFixes(
        time_ns=fix_ns,
        lat_rad=np.radians(gps["lat_deg"].to_numpy(dtype=float)),
        lon_rad=np.radians(gps["lon_deg"].to_numpy(dtype=float)),
        height_m=height,
        pos_cov_ned_m2=diag_cov(np.column_stack([s_h, s_h, 2.0 * s_h]), n_fix),
        status=np.zeros(n_fix, dtype=np.int8),
    )
    vel = GnssVelocities(time_ns=fix_ns, v_n_mps=v_n,
                         vel_cov_ned_m2ps2=diag_cov([0.3, 0.3, 0.5], n_fix))
    return fix, vel, datum


def parse_ardupilot(
    source: str | Path,
    *,
    geoid_undulation_m: float | None = None,
    gnss_latency_s: float | None = None,
    min_speed_for_lag_mps: float = 8.0,
) -> ParsedLog:
    """Parse the ArduPlane CSV export in folder ``source`` into the data contract.

    Parameters
    ----------
    source : path-like
        Folder with ``imu.csv``, ``gps.csv`` and ``att.csv``.
    geoid_undulation_m : float, optional
        N (ellipsoid minus MSL) at the site [m]; when None the MSL height is written.
    gnss_latency_s : float, optional
        Delay between a GPS record's measurement epoch and its boot-time log stamp [s]; when
        None it is estimated (module docstring) and reported in ``checks``.
    min_speed_for_lag_mps : float
        GNSS epochs slower than this are left out of the latency estimate.

    Returns
    -------
    ParsedLog
    """
    src = Path(source)
    imu_p, gps_p, att_p = (require_file(src, n) for n in ("imu.csv", "gps.csv", "att.csv"))
    wcols = ["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]
    fcols = ["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]
    imu = read_csv(imu_p, ["time_boot_ms", *wcols, *fcols])
    gcols = ["status", "gps_tow_ms", "gps_week", "hdop", "lat_deg", "lon_deg", "alt_m",
             "ground_speed_m_s", "ground_course_deg", "vz_m_s", "time_boot_ms"]
    gps = read_csv(gps_p, gcols)
    att = read_csv(att_p, ["time_boot_ms", "roll_deg", "pitch_deg"])
    t_boot = imu["time_boot_ms"].to_numpy(dtype=float) * 1e-3
    check_increasing(imu_p, "time_boot_ms", t_boot)
    w = imu[wcols].to_numpy(dtype=float)
    f = imu[fcols].to_numpy(dtype=float)
    g_med = check_gravity(imu_p, f, "acc_*_m_s2 expected in m/s^2")
    rest = slice(0, min(len(f), 50 * 60))
    f_rest = f[rest].mean(axis=0)
    if f_rest[2] > -0.8 * g_med:
        raise ConversionError(f"{imu_p}: mean specific force over the first minute is "
                              f"{f_rest.round(3).tolist()} m/s^2; expected about -g on z "
                              "(body FRD, level at rest)")
    warnings: list[str] = []
    notes: list[str] = []
    n_raw = len(gps)
    gps = gps[gps["status"] >= 3].drop_duplicates("gps_tow_ms", keep="first")
    if len(gps) < n_raw:
        notes.append(f"{n_raw - len(gps)} GPS record(s) without 3-D fix or duplicated dropped")
    gps_s = (gps["gps_week"].to_numpy(dtype=float) * SECONDS_PER_WEEK
             + gps["gps_tow_ms"].to_numpy(dtype=float) * 1e-3)
    check_increasing(gps_p, "gps_week/gps_tow_ms", gps_s)
    g_boot = gps["time_boot_ms"].to_numpy(dtype=float) * 1e-3
    offset_s = float(np.median(gps_s - g_boot))  # GPS time of a boot-time *log* stamp
    spd = gps["ground_speed_m_s"].to_numpy(dtype=float)
    crs = np.radians(gps["ground_course_deg"].to_numpy(dtype=float))
    v_n = np.column_stack([spd * np.cos(crs), spd * np.sin(crs),
                           gps["vz_m_s"].to_numpy(dtype=float)])
    checks: dict[str, float] = {"gravity_median_mps2": g_med}
    # latency: align GNSS course rate with the IMU heading rate (both on the boot time base)
    lag = _gnss_lag_s(t_boot, w, att, gps_s - offset_s, spd, crs, min_speed_for_lag_mps,
                      checks, warnings)
    latency = gnss_latency_s if gnss_latency_s is not None else (lag if np.isfinite(lag) else 0.0)
    checks["gnss_latency_applied_s"] = latency
    imu_gps_s = t_boot + offset_s + latency
    imu_ns = gps_to_unix_ns(imu_gps_s)
    fix_ns = gps_to_unix_ns(gps_s)
    fix, vel, datum = _gnss_records(gps, fix_ns, v_n, geoid_undulation_m, warnings)
    samples = ImuSamples(time_ns=imu_ns, w_ib_b_radps=w, f_ib_b_mps2=f, frame_id="base_link")
    time_system = ("UTC ns since the Unix epoch: IMU boot ms + median(GPS - boot) + GNSS "
                   "latency, GPS -> UTC with the leap seconds in force (16 s)")
    imu_conv = "mean over the interval ending at the stamp (APM driver averages 1 kHz samples)"
    axes = "ArduPilot body x fwd, y right, z down = FRD (identity)"
    meta = {
        "converter": "pospp.io.converters.ardupilot", "source": str(src),
        "time_system": time_system, "height_datum": datum, "imu_convention": imu_conv,
        "axes": axes, "gnss_latency_s": f"{latency:.4f}",
        "gnss_sigma": f"pos HDOP*{UERE_M}/sqrt2 m horizontal, x2 vertical; vel 0.3/0.5 m/s",
    }
    return ParsedLog(
        fmt="ardupilot_csv", source=str(src), imu=samples, fix=fix, vel=vel, reference=None,
        time_system=time_system, height_datum=datum, imu_convention=imu_conv, axes=axes,
        metadata=meta, imu_frame_id="base_link", checks=checks, notes=tuple(notes),
        warnings=tuple(warnings),
    )
