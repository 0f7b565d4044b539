"""Shared pieces of the converters: report, errors, time systems, CSV reading, GNSS helpers.

Time systems
------------
Every file pospp writes stamps UTC as int64 nanoseconds since the Unix epoch (the ROS 2
convention, ``builtin_interfaces/Time``). GPS time converts with::

    unix_s = gps_week * 604800 + tow_s + GPS_EPOCH_UNIX_S - (GPS - UTC)

where GPS - UTC is the leap-second count in force (IERS Bulletin C; table below). A source whose
absolute time cannot be recovered (GPS seconds of week without the week) keeps its own time base;
the report and the file metadata say which.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from pospp import earth
from pospp.nav.mounting import MountingEstimate

GPS_EPOCH_UNIX_S = 315964800
"""1980-01-06T00:00:00 UTC as Unix seconds (start of GPS time)."""

SECONDS_PER_WEEK = 604800

# (Unix time at which the offset takes effect, GPS - UTC [s]); IERS Bulletin C
_GPS_MINUS_UTC = (
    (362793600, 1),    # 1981-07-01
    (394329600, 2),    # 1982-07-01
    (425865600, 3),    # 1983-07-01
    (489024000, 4),    # 1985-07-01
    (567993600, 5),    # 1988-01-01
    (631152000, 6),    # 1990-01-01
    (662688000, 7),    # 1991-01-01
    (709948800, 8),    # 1992-07-01
    (741484800, 9),    # 1993-07-01
    (773020800, 10),   # 1994-07-01
    (820454400, 11),   # 1996-01-01
    (867715200, 12),   # 1997-07-01
    (915148800, 13),   # 1999-01-01
    (1136073600, 14),  # 2006-01-01
    (1230768000, 15),  # 2009-01-01
    (1341100800, 16),  # 2012-07-01
    (1435708800, 17),  # 2015-07-01
    (1483228800, 18),  # 2017-01-01 (still in force in 2025)
)


class ConversionError(ValueError):
    """A source file is missing, malformed or inconsistent; the message names file and fault."""


@dataclass(frozen=True)
class ConversionReport:
    """What a converter wrote and what it found (no printing; the CLI renders this).

    Attributes
    ----------
    fmt : str
        Converter name (key of ``pospp.io.converters.FORMATS``).
    source : str
        File or folder read.
    mcap_path, reference_path : str or None
        Files written (None when the source has no IMU, or no reference).
    n_imu, n_fix, n_vel, n_reference : int
        Records written per stream.
    imu_rate_hz, gnss_rate_hz : float
        Median rates (NaN when absent).
    start_ns, end_ns : int or None
        Span of the written stamps.
    time_system : str
        What the stamps are (e.g. "UTC ns since Unix epoch, from GPS week/TOW - 18 s").
    height_datum : str
        What ``height_m`` is (ellipsoidal WGS-84, or mean sea level when no undulation was
        known; then a warning says so).
    imu_convention : str
        How the source samples map to the contract's "mean over the interval ending at the
        stamp".
    axes : str
        How the source axes map to body FRD.
    mounting : MountingEstimate or None
        Estimated sensor -> body rotation, where the mounting was unknown.
    checks : dict of str to float
        Measured realism figures (names carry units).
    notes, warnings : tuple of str
    """

    fmt: str
    source: str
    mcap_path: str | None
    reference_path: str | None
    n_imu: int
    n_fix: int
    n_vel: int
    n_reference: int
    imu_rate_hz: float
    gnss_rate_hz: float
    start_ns: int | None
    end_ns: int | None
    time_system: str
    height_datum: str
    imu_convention: str
    axes: str
    mounting: MountingEstimate | None = None
    checks: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


# --------------------------------------------------------------------------- time


def gps_minus_utc_s(unix_s: float) -> int:
    """Leap seconds GPS - UTC in force at a Unix time (0 before 1981-07-01)."""
    n = 0
    for start, value in _GPS_MINUS_UTC:
        if unix_s >= start:
            n = value
    return n


def gps_to_unix_ns(gps_s: ArrayLike) -> NDArray:
    """Continuous GPS seconds (week * 604800 + TOW) -> UTC Unix ns (int64).

    One leap-second value is used for the whole array (the one in force at its first epoch); a
    log spanning a leap second is rejected.
    """
    g = np.asarray(gps_s, dtype=float)
    first = float(g.flat[0]) + GPS_EPOCH_UNIX_S
    leap = gps_minus_utc_s(first - 20.0)
    if gps_minus_utc_s(float(g.max()) + GPS_EPOCH_UNIX_S - leap) != leap:
        raise ConversionError("the log spans a leap second; split it first")
    whole = np.floor(g)
    frac_ns = np.round((g - whole) * 1e9).astype(np.int64)
    return (whole.astype(np.int64) + GPS_EPOCH_UNIX_S - leap) * 1_000_000_000 + frac_ns


def seconds_to_ns(t_s: ArrayLike) -> NDArray:
    """Float seconds -> int64 ns, rounding to the nearest ns (sub-second part separately)."""
    t = np.asarray(t_s, dtype=float)
    whole = np.floor(t)
    return whole.astype(np.int64) * 1_000_000_000 + np.round((t - whole) * 1e9).astype(np.int64)


def median_rate_hz(time_ns: ArrayLike) -> float:
    """1 / median interval [Hz] (NaN for fewer than 2 stamps)."""
    t = np.asarray(time_ns, dtype=np.int64)
    if t.size < 2:
        return float("nan")
    return 1e9 / float(np.median(np.diff(t)))


# --------------------------------------------------------------------------- files


def reference_path_for(out_mcap: str | Path) -> Path:
    """Where a converter writes the reference beside an MCAP: ``<stem>.reference.parquet``."""
    p = Path(out_mcap)
    return p.with_name(p.stem + ".reference.parquet")


def require_file(folder: Path, name: str) -> Path:
    """``folder / name`` or a ConversionError naming what is missing."""
    p = folder / name
    if not p.is_file():
        have = sorted(x.name for x in folder.iterdir()) if folder.is_dir() else []
        raise ConversionError(f"{p}: required file not found (folder holds {have})")
    return p


def read_csv(path: Path, columns: Sequence[str], **kwargs: Any) -> pd.DataFrame:
    """Read a CSV, strip header whitespace, check the named columns exist and are finite."""
    try:
        df = pd.read_csv(path, **kwargs)
    except (OSError, ValueError) as exc:
        raise ConversionError(f"{path}: cannot read as CSV ({exc})") from exc
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ConversionError(f"{path}: missing column(s) {missing}; got {list(df.columns)}")
    for c in columns:
        v = pd.to_numeric(df[c], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise ConversionError(f"{path}: column {c!r} is not a finite number at data row "
                                  f"{int(bad[0])} (value {df[c].iloc[int(bad[0])]!r})")
    return df


def check_increasing(path: Path, name: str, t: NDArray) -> None:
    """Raise unless ``t`` increases strictly (names the first offending row)."""
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise ConversionError(f"{path}: {name} must increase strictly; row {int(bad[0]) + 1} "
                              f"({t[bad[0] + 1]!r}) follows {t[bad[0]]!r}")


def check_gravity(path: Path, f_b_mps2: NDArray, axis_hint: str) -> float:
    """Mean |f| [m/s^2]; raise when it is not about g (units wrong: g instead of m/s^2)."""
    g = float(np.median(np.linalg.norm(f_b_mps2, axis=1)))
    if not 7.0 < g < 13.0:
        raise ConversionError(f"{path}: median |specific force| {g:.3f} is not about 9.8 "
                              f"m/s^2 ({axis_hint}); wrong units (g?) or wrong columns")
    return g


# --------------------------------------------------------------------------- GNSS helpers


def diag_cov(sigma: ArrayLike, n: int) -> NDArray:
    """(n, 3, 3) diagonal covariances from per-axis sigmas, shape (3,) or (n, 3)."""
    s = np.broadcast_to(np.asarray(sigma, dtype=float), (n, 3))
    out = np.zeros((n, 3, 3))
    out[:, [0, 1, 2], [0, 1, 2]] = s**2
    return out


def velocity_from_positions(
    t_s: NDArray, lat_rad: NDArray, lon_rad: NDArray, height_m: NDArray
) -> NDArray:
    """NED velocity [m/s] by central differences of positions (one-sided at the ends).

    Differences are taken in the local NED frame at each epoch
    (``earth.llh_difference_ned_m``), exact for the short baselines involved.
    """
    n = t_s.size
    i0 = np.clip(np.arange(n) - 1, 0, n - 1)
    i1 = np.clip(np.arange(n) + 1, 0, n - 1)
    d = earth.llh_difference_ned_m(lat_rad[i1], lon_rad[i1], height_m[i1],
                                   lat_rad[i0], lon_rad[i0], height_m[i0])
    dt = t_s[i1] - t_s[i0]
    return d / dt[:, None]


def kinematic_attitude(v_n_mps: NDArray, *, min_speed_mps: float = 1.0) -> NDArray:
    """[roll=0, pitch=flight-path angle, yaw=course] (rad) per epoch, held while slow.

    Epochs slower than ``min_speed_mps`` take the values of the nearest faster epoch (the
    first fast epoch before any); all zero when no epoch is fast.
    """
    vh = np.hypot(v_n_mps[:, 0], v_n_mps[:, 1])
    yaw = np.arctan2(v_n_mps[:, 1], v_n_mps[:, 0])
    pitch = np.arctan2(-v_n_mps[:, 2], vh)
    fast = vh > min_speed_mps
    out = np.zeros((v_n_mps.shape[0], 3))
    if not fast.any():
        return out
    idx = np.where(fast, np.arange(fast.size), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = int(np.argmax(fast))
    out[:, 1] = pitch[idx]
    out[:, 2] = np.mod(yaw[idx], 2.0 * math.pi)
    return out


def lag_by_correlation(
    t_a_s: NDArray, x_a: NDArray, t_b_s: NDArray, x_b: NDArray, *, max_lag_s: float,
    step_s: float = 0.005,
) -> tuple[float, float]:
    """Delay of signal b relative to signal a that best aligns them, by cross-correlation.

    Both are resampled on a common grid of ``step_s``; the returned lag L maximises the
    correlation of a(t) with b(t + L) (L > 0: b's stamps are late). Returns (lag_s,
    correlation at that lag).
    """
    lo = max(t_a_s[0], t_b_s[0]) + max_lag_s
    hi = min(t_a_s[-1], t_b_s[-1]) - max_lag_s
    if hi - lo < 10 * max_lag_s:
        return float("nan"), float("nan")
    grid = np.arange(lo, hi, step_s)
    a = np.interp(grid, t_a_s, x_a)
    a = (a - a.mean()) / (a.std() + 1e-300)
    best = (float("nan"), -np.inf)
    for lag in np.arange(-max_lag_s, max_lag_s + step_s / 2, step_s):
        b = np.interp(grid + lag, t_b_s, x_b)
        c = float(np.mean(a * (b - b.mean())) / (b.std() + 1e-300))
        if c > best[1]:
            best = (float(lag), c)
    return best
