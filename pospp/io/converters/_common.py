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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from pospp import earth
from pospp.io.mcap_writer import write_flight_log
from pospp.io.parquet_tables import write_reference_trajectory
from pospp.types import GnssFixes, GnssVelocities, ImuSamples, ReferenceTrajectory

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


class MountingLike(Protocol):
    """What the converters read of a mounting estimate (``pospp.nav.mounting.MountingEstimate``
    is one; io does not import nav)."""

    @property
    def c_bs(self) -> NDArray: ...
    @property
    def rpy_rad(self) -> NDArray: ...
    @property
    def tilt_sigma_rad(self) -> float: ...
    @property
    def heading_sigma_rad(self) -> float: ...
    @property
    def levelling_residual_rad(self) -> float: ...
    @property
    def heading_scatter_rad(self) -> float: ...


@dataclass(frozen=True)
class MountingInput:
    """The parsed data a mounting estimate needs; the converter makes no estimate (converters
    only parse). ``pospp.convert`` passes these to
    ``pospp.nav.mounting.estimate_mounting`` (same argument names).

    Attributes
    ----------
    t_s, f_s_mps2 : (N,), (N, 3)
        IMU times [s, any origin shared with ``t_vel_s``] and specific force in sensor axes.
    t_vel_s, v_n_mps : (M,), (M, 3)
        Velocity times [s] and NED velocity [m/s].
    lat_rad, height_m : float
        Where (for gravity).
    body_rpy_rad : (M, 3) or None
        Body attitude at ``t_vel_s`` (yaw unwrapped); None: level, yaw along the course.
    options : dict
        Keyword options of ``pospp.nav.mounting.MountingOptions`` for this source.
    apply : bool
        True: the IMU of the parsed log is in sensor axes and is rotated into body FRD by the
        estimate; False: the estimate is only reported (a failure becomes a note).
    description : str
        What is estimated from what, for the notes.
    """

    t_s: NDArray
    f_s_mps2: NDArray
    t_vel_s: NDArray
    v_n_mps: NDArray
    lat_rad: float
    height_m: float
    body_rpy_rad: NDArray | None
    options: dict[str, Any]
    apply: bool
    description: str


@dataclass(frozen=True)
class HeadingRateCheck:
    """Inputs of the timing check run once the body axes are known: the IMU heading rate
    ``(w_y sin(roll) + w_z cos(roll)) / cos(pitch)`` against the reference yaw rate, both as 1 s
    moving means, aligned by :func:`lag_by_correlation`. Times [s] on one base."""

    t_imu_s: NDArray
    t_ref_s: NDArray
    rpy_ref_rad: NDArray
    """Reference attitude at ``t_ref_s``, yaw unwrapped."""
    max_lag_s: float


@dataclass(frozen=True)
class ParsedLog:
    """A source parsed into the data contract, not yet written (``write_parsed`` writes it).

    ``imu`` is in body FRD, or in sensor axes when ``mounting.apply`` (``apply_mounting``
    rotates it). The text fields and ``checks`` / ``notes`` / ``warnings`` go to the
    :class:`ConversionReport`; ``metadata`` to the MCAP, ``reference_metadata`` to the
    reference Parquet.
    """

    fmt: str
    source: str
    imu: ImuSamples | None
    fix: GnssFixes | None
    vel: GnssVelocities | None
    reference: ReferenceTrajectory | None
    time_system: str
    height_datum: str
    imu_convention: str
    axes: str
    metadata: dict[str, str] = field(default_factory=dict)
    reference_metadata: dict[str, Any] = field(default_factory=dict)
    imu_frame_id: str = "imu_link"
    gnss_frame_id: str = "gnss_antenna"
    checks: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    mounting: MountingInput | None = None
    heading_check: HeadingRateCheck | None = None
    reference_only_out: bool = False
    """True for the reference-only formats: ``out`` ending in .parquet is the reference."""


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
    mounting : MountingLike or None
        Estimated sensor -> body rotation, where the mounting was unknown (a
        ``pospp.nav.mounting.MountingEstimate``, made by ``pospp.convert``).
    checks : dict of str to float
        Measured realism figures (names carry units).
    notes, warnings : tuple of str
    hints : tuple of str
        What to do next with this log (``pospp.convert``: e.g. a clip too short for a run).
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
    mounting: MountingLike | None = None
    checks: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    hints: tuple[str, ...] = ()


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


# --------------------------------------------------------------------------- write


def _moving_mean_1s(t_s: NDArray, x: NDArray) -> NDArray:
    k = max(1, int(round(1.0 / float(np.median(np.diff(t_s))))))
    return np.convolve(x, np.ones(k) / k, mode="same")


def heading_rate_lag(check: HeadingRateCheck, w_ib_b_radps: NDArray) -> tuple[float, float]:
    """(lag [s], correlation) of the IMU heading rate against the reference yaw rate."""
    rpy = check.rpy_ref_rad
    r_i = np.interp(check.t_imu_s, check.t_ref_s, rpy[:, 0])
    p_i = np.interp(check.t_imu_s, check.t_ref_s, rpy[:, 1])
    hr = (w_ib_b_radps[:, 1] * np.sin(r_i) + w_ib_b_radps[:, 2] * np.cos(r_i)) / np.cos(p_i)
    yaw_rate = np.gradient(rpy[:, 2], check.t_ref_s)
    t0 = check.t_ref_s[0]
    return lag_by_correlation(
        check.t_imu_s - t0, _moving_mean_1s(check.t_imu_s, hr), check.t_ref_s - t0,
        _moving_mean_1s(check.t_ref_s, yaw_rate), max_lag_s=check.max_lag_s, step_s=0.01)


def apply_mounting(parsed: ParsedLog, mounting: MountingLike) -> ParsedLog:
    """Rotate a sensor-axes IMU into body FRD by ``C_bs`` (``f_b = C_bs f_s``), run the
    heading-rate check, and say so in the axes text, metadata, checks and notes."""
    if parsed.imu is None or parsed.mounting is None or not parsed.mounting.apply:
        raise ValueError(f"{parsed.fmt}: no sensor-axes IMU to rotate")
    c_bs = np.asarray(mounting.c_bs, dtype=float)
    imu = parsed.imu
    w_b = imu.w_ib_b_radps @ c_bs.T
    f_b = imu.f_ib_b_mps2 @ c_bs.T
    axes = (f"{parsed.axes} rotated to body FRD by the estimated C_bs "
            f"(rpy_deg {np.degrees(mounting.rpy_rad).round(2).tolist()})")
    checks = dict(parsed.checks)
    checks["mean_f_b_z_mps2"] = float(f_b[:, 2].mean())
    if parsed.heading_check is not None:
        lag, corr = heading_rate_lag(parsed.heading_check, w_b)
        checks["imu_lag_vs_reference_s"] = lag
        checks["heading_rate_correlation"] = corr
    metadata = {
        **parsed.metadata, "axes": axes, "c_bs_estimated": repr(np.round(c_bs, 9).tolist()),
        "mounting_tilt_sigma_deg": f"{np.degrees(mounting.tilt_sigma_rad):.3f}",
        "mounting_heading_sigma_deg": f"{np.degrees(mounting.heading_sigma_rad):.3f}",
    }
    note = (f"{parsed.mounting.description} (levelling residual "
            f"{np.degrees(mounting.levelling_residual_rad):.2f} deg, heading scatter "
            f"{np.degrees(mounting.heading_scatter_rad):.2f} deg)")
    return replace(
        parsed, imu=ImuSamples(imu.time_ns, w_b, f_b, imu.frame_id), axes=axes,
        metadata=metadata, checks=checks, notes=(note, *parsed.notes),
    )


def write_parsed(parsed: ParsedLog, out: str | Path, *,
                 mounting: MountingLike | None = None) -> ConversionReport:
    """Write the MCAP (when the source has an IMU) and the reference Parquet (when it has one).

    ``out`` is the MCAP; the reference goes to ``<stem>.reference.parquet`` beside it. For the
    reference-only formats, ``out`` ending in .parquet is the reference itself.
    """
    out_p = Path(out)
    mcap_path = ref_path = None
    if parsed.imu is not None and parsed.fix is not None:
        mcap_path = write_flight_log(out_p, parsed.imu, parsed.fix, parsed.vel,
                                     imu_frame_id=parsed.imu_frame_id,
                                     gnss_frame_id=parsed.gnss_frame_id,
                                     metadata=parsed.metadata)
    if parsed.reference is not None:
        target = out_p if parsed.reference_only_out and out_p.suffix == ".parquet" \
            else reference_path_for(mcap_path or out_p)
        ref_path = write_reference_trajectory(target, parsed.reference,
                                              metadata=parsed.reference_metadata)
    spans = (parsed.imu, parsed.fix) if parsed.imu is not None else (parsed.reference,)
    streams = [x.time_ns for x in spans if x is not None]
    gnss_ns = parsed.fix.time_ns if parsed.fix is not None else (
        parsed.reference.time_ns if parsed.reference is not None else np.zeros(0, np.int64))
    return ConversionReport(
        fmt=parsed.fmt, source=parsed.source,
        mcap_path=None if mcap_path is None else str(mcap_path),
        reference_path=None if ref_path is None else str(ref_path),
        n_imu=0 if parsed.imu is None else len(parsed.imu),
        n_fix=0 if parsed.fix is None else len(parsed.fix),
        n_vel=0 if parsed.vel is None else len(parsed.vel),
        n_reference=0 if parsed.reference is None else len(parsed.reference),
        imu_rate_hz=float("nan") if parsed.imu is None else median_rate_hz(parsed.imu.time_ns),
        gnss_rate_hz=median_rate_hz(gnss_ns),
        start_ns=int(min(int(t[0]) for t in streams)) if streams else None,
        end_ns=int(max(int(t[-1]) for t in streams)) if streams else None,
        time_system=parsed.time_system, height_datum=parsed.height_datum,
        imu_convention=parsed.imu_convention, axes=parsed.axes, mounting=mounting,
        checks=parsed.checks, notes=parsed.notes, warnings=parsed.warnings,
    )
