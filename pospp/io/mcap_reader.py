"""Read a ROS 2 MCAP flight log into IMU and GNSS arrays, checking the data contract.

Frames and units
----------------
- IMU messages (``sensor_msgs/msg/Imu``) are in the sensor frame s as logged (FLU per REP-103
  for the simulators); ``angular_velocity`` [rad/s] and ``linear_acceleration`` [m/s^2] are
  the MEAN rate and MEAN specific force over the interval that ends at ``header.stamp``.
  They are rotated here, and only here, into the body frame b (FRD) with the mounting DCM
  ``C_bs``: ``w_ib_b = C_bs @ w_is_s``, ``f_ib_b = C_bs @ f_s``. Default ``C_bs = FLU_TO_FRD =
  diag(1, -1, -1)``.
- GNSS fixes (``sensor_msgs/msg/NavSatFix``): latitude/longitude [deg] -> [rad], altitude above
  the WGS-84 ellipsoid [m], ``position_covariance`` (3x3 row-major, ENU, m^2) -> NED:
  ``P_ned = T P_enu T^T`` with ``T = [[0,1,0],[1,0,0],[0,0,-1]]`` (``v_ned = [v_N, v_E, -v_U]
  = T v_enu``).
- GNSS velocities (``geometry_msgs/msg/TwistWithCovarianceStamped``): ``twist.linear`` ENU [m/s]
  -> ``v_n`` NED; the linear 3x3 block of the 6x6 covariance -> NED the same way.
- Sample times are ``header.stamp`` (int64 ns), never the MCAP log time.

Speed
-----
The file is read in ONE sequential pass by :mod:`pospp.io._mcap_scan` (the compiled chunk framing
and decoding in :mod:`pospp.io._mcap_decode`; no summary section
needed, so a truncated file yields everything before the break, including the readable part of a
cut-off zstd/lz4 chunk). Records are framed there (index records skipped unparsed; Schema and
Channel records parsed by ``mcap.records``); docs/formats.md gives the measured reason for not
using ``mcap.reader.make_reader(...).iter_messages()``. Each chunk is decompressed, its records
are framed by one compiled pass, and the messages of each wanted channel are decoded by one
compiled pass per chunk (``_decode_fixed``: the fixed little-endian CDR layout of
``pospp.io.ros_messages.cdr_dtype`` for the message's frame_id length) straight into arrays
allocated once from the summary's Statistics message counts (read first from the end of the
file; without them the arrays grow by doubling). The first message of every (channel, layout)
is also decoded by ``mcap_ros2``'s generic decoder and the two must agree bit for bit, else
that layout falls back to the generic decoder; messages that are not little-endian plain CDR
always go through it. The IMU vectors are rotated to the body frame in place, and the checks
keep their (N, 3) temporaries a block long, so that the peak is close to the decoded arrays
plus one chunk (docs/history/speed_rounds.md, "The reader, third round").

Checks
------
Each raises ``IngestError`` or records an ``IngestIssue`` (docs/formats.md lists them): missing
required topic (the available ones are listed), wrong schema or encoding, IMU stamps not
strictly increasing (error), GNSS duplicate stamps (dropped, warning) or backwards (error),
NaN/inf and values beyond their physical limits (``pospp.io._bounds``: error naming the
first bad message), IMU gaps over 3 nominal intervals and interval
changes (warnings), IMU magnitudes that look like g or deg/s (error), IMU turn rates that
disagree with the GNSS course rate by a factor near 180/pi (error: deg/s logged as rad/s),
NO_FIX fixes (dropped, warning), truncated or corrupt file (error issue, ``complete=False``,
data read so far kept; a corrupt chunk is skipped and reading goes on), a Footer record before
the end of the file, a data-section CRC that does not match, and message counts that disagree
with the summary's Statistics (each an error issue, ``complete=False``). Chunk decompression is
bounded by the chunk header's size and by ``max_chunk_bytes``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pospp.io._blockwise import rotation_sums, row_norms
from pospp.io._bounds import check_values
from pospp.io._mcap_chunk import MAX_CHUNK_BYTES
from pospp.io._mcap_decode import EVENT_SPEC, FIX_SPEC, IMU_SPEC, VEL_SPEC, Collector
from pospp.io._mcap_scan import Scan
from pospp.io.errors import IngestError, IngestIssue, MissingTopicError
from pospp.io.files import require_regular
from pospp.types import (
    ENU_TO_NED,
    FLU_TO_FRD,
    GnssFixes,
    GnssVelocities,
    ImuSamples,
    apply_rotation,
    check_dcm,
    empty_velocities,
    rotate_covariance,
)
from pospp.units import G0_MPS2, S_PER_NS, time_ns_from_t_s

__all__ = ["FlightLog", "read_flight_log"]

_GAP_FACTOR = 3.0  # an IMU interval longer than this many nominal intervals is a gap
_MAX_LISTED = 100  # at most this many individual gap / rate-change issues


# --------------------------------------------------------------------------- public data


@dataclass(frozen=True)
class FlightLog:
    """Everything read from one MCAP file.

    Attributes
    ----------
    imu, fix, vel : ImuSamples, GnssFixes, GnssVelocities
        Body FRD / NED, SI (``vel`` empty when the file has no velocity topic).
    path : str
        The file read.
    issues : tuple of IngestIssue
        Warnings and infos, and the errors that did not stop reading (docs/formats.md).
    complete : bool
        False when data are missing or altered: the file is truncated or its record framing
        broke (the arrays hold what was read before the break, the readable part of a cut-off
        chunk included), a Footer record appears before the end, a corrupt chunk was skipped
        (reading went on after it), the data-section CRC (when stored) does not match, or the
        summary's Statistics count other numbers of messages on the topics read. ``issues``
        then holds an ``IngestIssue`` of severity ``"error"`` with the byte offset and the log
        time reached. A damaged summary section after the data (index only) leaves
        ``complete`` True, with a warning.
    """

    imu: ImuSamples
    fix: GnssFixes
    vel: GnssVelocities
    path: str
    issues: tuple[IngestIssue, ...] = ()
    complete: bool = True
    events_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """Header stamps of the trigger events (``events_topic``), int64 ns, sorted (empty when
    no events topic was asked for or found)."""

    def cause_of(self, failure: str) -> str:
        """``failure`` (a later stage's one-line error) led by the damage the reader found,
        when it found any: a skipped chunk shows downstream as an IMU gap or a failed
        alignment, and the line must name the corruption, not only that symptom."""
        broken = [i for i in self.issues if i.severity == "error"]
        if not broken:
            return failure
        at = "" if broken[0].byte_offset is None else f" at byte {broken[0].byte_offset}"
        more = f" (and {len(broken) - 1} more)" if len(broken) > 1 else ""
        return f"{Path(self.path).name} is damaged{at}: {broken[0].message}{more}; then {failure}"


# --------------------------------------------------------------------------- checks & assembly


def _window(a: dict[str, np.ndarray], start_ns: int | None, end_ns: int | None) -> dict:
    """Keep samples with ``start_ns <= time_ns < end_ns``; add ``index`` (file order: None
    while it is the identity, so that a whole log needs no index array)."""
    out: dict[str, np.ndarray | None] = {**a, "index": None}
    keep = np.ones(len(a["time_ns"]), bool)
    if start_ns is not None:
        keep &= a["time_ns"] >= start_ns
    if end_ns is not None:
        keep &= a["time_ns"] < end_ns
    return out if keep.all() else _subset(out, keep)


def _subset(a: dict, keep: np.ndarray) -> dict:
    """The samples where ``keep`` (bool) holds, ``index`` kept pointing at file order."""
    idx = a["index"]
    out = {k: v[keep] for k, v in a.items() if k != "index"}
    out["index"] = np.flatnonzero(keep) if idx is None else idx[keep]
    return out


def _index(a: dict, i: int) -> int:
    """File-order index of sample ``i`` of ``a``."""
    return int(i) if a["index"] is None else int(a["index"][i])


def _absolute_window(
    imu_time_ns: np.ndarray, start_ns: int | None, end_ns: int | None,
    window_s: tuple[float | None, float | None],
) -> tuple[int | None, int | None]:
    """The window ``[start_ns, end_ns)`` intersected with ``window_s`` [s] after the file's
    first IMU header stamp (the one place a time window is resolved; ``[input] start_s, end_s``).
    """
    start_s, end_s = window_s
    if len(imu_time_ns) == 0 or (start_s is None and end_s is None):
        return start_ns, end_ns
    first_ns = int(imu_time_ns[0])
    if start_s is not None:
        lo = int(time_ns_from_t_s(start_s, first_ns))
        start_ns = lo if start_ns is None else max(start_ns, lo)
    if end_s is not None:
        hi = int(time_ns_from_t_s(end_s, first_ns))
        end_ns = hi if end_ns is None else min(end_ns, hi)
    return start_ns, end_ns


def _check_order(a: dict, topic: str, path: str, *, drop_duplicates: bool,
                 issues: list[IngestIssue]) -> dict:
    """Stamps must increase strictly; GNSS duplicates may be dropped (with an issue)."""
    t = a["time_ns"]
    d = np.diff(t)
    if drop_duplicates and np.any(d == 0):
        dup = np.flatnonzero(d == 0) + 1
        issues.append(IngestIssue(
            "warning", path, topic, _index(a, dup[0]), int(t[dup[0]]),
            f"{dup.size} message(s) with a duplicate header stamp dropped (kept the first of "
            "each stamp)", log_time_ns=int(a["log_time_ns"][dup[0]]),
        ))
        keep = np.ones(len(t), bool)
        keep[dup] = False
        a = _subset(a, keep)
        t = a["time_ns"]
        d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = bad[0] + 1
        what = "duplicates" if d[bad[0]] == 0 else f"goes back {-int(d[bad[0]])} ns from"
        raise IngestError(
            f"header stamp {what} the previous message's ({int(t[i - 1])} ns); stamps must "
            f"increase strictly ({bad.size} such message(s) in total)",
            file=path, topic=topic, index=_index(a, i), time_ns=int(t[i]),
            log_time_ns=int(a["log_time_ns"][i]),
        )
    return a


def _imu_timing_issues(a: dict, topic: str, path: str) -> list[IngestIssue]:
    """Gaps (> 3 nominal intervals) and changes of the sampling interval."""
    t = a["time_ns"]
    out: list[IngestIssue] = []
    if len(t) < 3:
        return out
    nominal = float(np.median(np.diff(t), overwrite_input=True))  # one (N,) temporary at a time
    d = np.diff(t)
    gaps = np.flatnonzero(d > _GAP_FACTOR * nominal)
    for g in gaps[:_MAX_LISTED]:
        out.append(IngestIssue(
            "warning", path, topic, _index(a, g + 1), int(t[g + 1]),
            f"IMU gap of {d[g] * 1e-9:.6f} s ({d[g] / nominal:.1f} nominal intervals of "
            f"{nominal * 1e-6:.3f} ms) after stamp {int(t[g])} ns",
            log_time_ns=int(a["log_time_ns"][g + 1]),
        ))
    if gaps.size > _MAX_LISTED:
        out.append(IngestIssue(
            "warning", path, topic, None, None,
            f"{gaps.size} IMU gaps in total; only the first {_MAX_LISTED} are listed",
        ))
    # rate changes: median interval per block of 1000 intervals (a last partial block counts
    # when it holds at least 250) versus the overall median; the change is located at the
    # first interval, from the previous block on, that is nearer the new median
    block = 1000
    edges = list(range(0, len(d), block))
    if len(edges) > 1 and len(d) - edges[-1] < block // 4:
        edges.pop()
    if len(edges) >= 2:
        full = min(len(d) // block, len(edges))  # whole blocks: one median call for all
        last = np.median(d[edges[-1] :]) if len(edges) > full else None
        med = np.median(d[: full * block].reshape(full, block), axis=1, overwrite_input=True)
        med = med if last is None else np.append(med, last)
        off = np.abs(med - nominal) > 0.02 * nominal
        starts = np.flatnonzero(off & ~np.r_[False, off[:-1]])
        d = np.diff(t) if starts.size else d  # the blocks were reordered by their medians
        for b in starts[:_MAX_LISTED]:
            lo = edges[max(b - 1, 0)]
            seg = d[lo : edges[b] + block]
            k = lo + int(np.argmax(np.abs(seg - med[b]) < np.abs(seg - nominal)))
            j = k + 1  # the sample that ends the first changed interval
            out.append(IngestIssue(
                "warning", path, topic, _index(a, j), int(t[j]),
                f"IMU sampling interval changes to {med[b] * 1e-6:.3f} ms (nominal "
                f"{nominal * 1e-6:.3f} ms, {1e9 / nominal:.2f} Hz)",
                log_time_ns=int(a["log_time_ns"][j]),
            ))
    return out


def _check_imu_units(w: np.ndarray, f: np.ndarray, topic: str, path: str) -> None:
    """Reject specific force in g, and rates that look like deg/s."""
    with np.errstate(over="ignore"):  # finite but absurd values: inf, rejected below
        fmed = float(np.median(row_norms(f), overwrite_input=True))
    if 0.5 < fmed < 1.5:
        raise IngestError(
            f"median |linear_acceleration| = {fmed:.4f}: looks like g, not m/s^2 "
            f"(expected about {G0_MPS2:.2f} m/s^2)", file=path, topic=topic,
        )
    if not 0.5 * G0_MPS2 < fmed < 1.5 * G0_MPS2:
        raise IngestError(
            f"median |linear_acceleration| = {fmed:.4g} m/s^2, expected about {G0_MPS2:.2f} "
            "m/s^2 (specific force of a vehicle near the Earth's surface)",
            file=path, topic=topic,
        )
    with np.errstate(over="ignore"):
        wmag = row_norms(w)
    i = int(np.argmax(wmag))
    wmax = float(wmag[i])
    wmed = float(np.median(wmag, overwrite_input=True))
    if wmed > 1.0 or wmax > 40.0:
        raise IngestError(
            f"|angular_velocity| median {wmed:.4g}, max {wmax:.4g} (sample {i}): looks like "
            "deg/s, not rad/s (expected median < 1 rad/s and max < 40 rad/s)",
            file=path, topic=topic, index=i,
        )


_TURN_RATE_MIN_RADPS = np.deg2rad(1.0)  # GNSS intervals turning faster than this are compared
_COURSE_SPEED_MIN_MPS = 3.0  # course over ground is only defined above this speed
_MIN_TURN_INTERVALS = 5


def _check_rate_units_against_gnss(imu: ImuSamples, vel: GnssVelocities, topic: str,
                                   path: str) -> None:
    """Compare the IMU rotation angle with the GNSS course change over turning intervals.

    For each pair of consecutive GNSS velocities with horizontal speed above 3 m/s and a
    course rate above 1 deg/s, the IMU rotation angle over the same interval,
    ``|sum_k w_k dt_k|`` [rad], is divided by the course change ``|d psi|`` [rad]. In a turn the
    body turns with its course (plus bank and crab changes), so the median ratio is near 1; a
    gyro logged in deg/s gives about 57. A median above 10 over at least 5 intervals is an
    error. Fewer turning intervals: no verdict (the magnitude check still applies).
    """
    if len(vel) < _MIN_TURN_INTERVALS + 1 or len(imu) < 3:
        return
    t = imu.time_ns
    tv = vel.time_ns
    speed = np.hypot(vel.v_n_mps[:, 0], vel.v_n_mps[:, 1])
    course = np.arctan2(vel.v_n_mps[:, 1], vel.v_n_mps[:, 0])
    dpsi = np.angle(np.exp(1j * np.diff(course)))
    dtv = np.diff(tv) * S_PER_NS
    ok = (speed[:-1] > _COURSE_SPEED_MIN_MPS) & (speed[1:] > _COURSE_SPEED_MIN_MPS)
    ok &= (tv[:-1] >= t[0]) & (tv[1:] <= t[-1]) & (dtv > 0)
    ok &= np.abs(dpsi) > _TURN_RATE_MIN_RADPS * np.where(dtv > 0, dtv, 1.0)
    k = np.flatnonzero(ok)
    if k.size < _MIN_TURN_INTERVALS:
        return
    ia = np.searchsorted(t, tv[k], side="right")
    ib = np.searchsorted(t, tv[k + 1], side="right")
    cum = rotation_sums(imu.w_ib_b_radps, t, np.concatenate([ia, ib]))
    angle = np.linalg.norm(cum[len(k) :] - cum[: len(k)], axis=1)
    ratio = float(np.median(angle / np.abs(dpsi[k])))
    if ratio > 10.0:
        j = int(k[np.argmax(angle / np.abs(dpsi[k]))])
        raise IngestError(
            f"IMU rotation over {k.size} turning GNSS intervals is {ratio:.1f} times the GNSS "
            f"course change (median; expected about 1, 57.3 = 180/pi means angular_velocity "
            f"is in deg/s, not rad/s)", file=path, topic=topic,
            index=int(np.searchsorted(t, tv[j], side="right")), time_ns=int(tv[j]),
        )


def _assemble_imu(a: dict, col: Collector, c_bs: np.ndarray, check_units: bool,
                  issues: list[IngestIssue]) -> ImuSamples:
    topic, path = col.topic, col.path
    if len(a["time_ns"]) == 0:
        raise IngestError("no IMU messages (in the time window)", file=path, topic=topic)
    a = _check_order(a, topic, path, drop_duplicates=False, issues=issues)
    check_values(a, "imu", ("angular_velocity", "linear_acceleration"), topic, path)
    issues.extend(_imu_timing_issues(a, topic, path))
    if check_units:
        _check_imu_units(a["angular_velocity"], a["linear_acceleration"], topic, path)
    if len(col.frame_ids) > 1:
        issues.append(IngestIssue("warning", path, topic, None, None,
                                  f"several IMU frame_ids: {col.frame_ids}"))
    w, f = a["angular_velocity"], a["linear_acceleration"]  # the reader's own arrays
    return ImuSamples(
        time_ns=a["time_ns"],
        w_ib_b_radps=apply_rotation(c_bs, w, out=w),  # in place: no second copy of the log
        f_ib_b_mps2=apply_rotation(c_bs, f, out=f),
        frame_id=col.frame_ids[0] if col.frame_ids else "",
    )


def _assemble_fix(a: dict, col: Collector, issues: list[IngestIssue]) -> GnssFixes:
    topic, path = col.topic, col.path
    nofix = a["status"] < 0
    if nofix.any():
        i = int(np.argmax(nofix))
        issues.append(IngestIssue(
            "warning", path, topic, _index(a, i), int(a["time_ns"][i]),
            f"{int(nofix.sum())} fix(es) with status NO_FIX dropped",
            log_time_ns=int(a["log_time_ns"][i]),
        ))
        a = _subset(a, ~nofix)
    if len(a["time_ns"]) == 0:
        raise IngestError("no usable GNSS fixes (in the time window)", file=path, topic=topic)
    a = _check_order(a, topic, path, drop_duplicates=True, issues=issues)
    check_values(a, "fix", ("latitude", "longitude", "altitude", "position_covariance"), topic,
                 path)
    bad = (np.abs(a["latitude"]) > 90.0) | (np.abs(a["longitude"]) > 180.0)
    if bad.any():
        i = int(np.argmax(bad))
        raise IngestError(
            f"latitude/longitude out of range: {a['latitude'][i]}, {a['longitude'][i]} "
            "(expected degrees, |lat| <= 90, |lon| <= 180)", file=path, topic=topic,
            index=_index(a, i), time_ns=int(a["time_ns"][i]),
        )
    unknown = a["position_covariance_type"] == 0
    if unknown.any():
        i = int(np.argmax(unknown))
        issues.append(IngestIssue(
            "warning", path, topic, _index(a, i), int(a["time_ns"][i]),
            f"{int(unknown.sum())} fix(es) with position_covariance_type UNKNOWN",
        ))
    cov_enu = a["position_covariance"].reshape(-1, 3, 3)
    return GnssFixes(
        time_ns=a["time_ns"],
        lat_rad=np.deg2rad(a["latitude"]),
        lon_rad=np.deg2rad(a["longitude"]),
        height_m=a["altitude"],
        pos_cov_ned_m2=rotate_covariance(ENU_TO_NED, cov_enu),
        status=a["status"].astype(np.int8),
    )


def _assemble_vel(a: dict, col: Collector, issues: list[IngestIssue]) -> GnssVelocities:
    topic, path = col.topic, col.path
    if len(a["time_ns"]) == 0:
        return empty_velocities()
    a = _check_order(a, topic, path, drop_duplicates=True, issues=issues)
    cov_enu = a["covariance"].reshape(-1, 6, 6)[:, :3, :3]
    check_values({**a, "cov": cov_enu}, "vel", ("linear", "cov"), topic, path)
    return GnssVelocities(
        time_ns=a["time_ns"],
        v_n_mps=apply_rotation(ENU_TO_NED, a["linear"]),
        vel_cov_ned_m2ps2=rotate_covariance(ENU_TO_NED, np.ascontiguousarray(cov_enu)),
    )


def _assemble_events(a: dict, col: Collector, issues: list[IngestIssue]) -> np.ndarray:
    """Event stamps, checked like GNSS stamps (duplicates dropped with a warning)."""
    if len(a["time_ns"]) == 0:
        return np.zeros(0, np.int64)
    check_values(a, "events", (), col.topic, col.path)
    return _check_order(a, col.topic, col.path, drop_duplicates=True, issues=issues)["time_ns"]


def _check_read_arguments(path: str, max_chunk_bytes: int, imu_topic: str, fix_topic: str,
                          vel_topic: str, events_topic: str) -> None:
    """Chunk cap a positive integer, the file present, the topics distinct."""
    if isinstance(max_chunk_bytes, bool) or not isinstance(max_chunk_bytes, int | np.integer) \
            or max_chunk_bytes <= 0:
        raise ValueError(f"max_chunk_bytes must be a positive integer, got {max_chunk_bytes!r}")
    if not os.path.exists(path):
        raise FileNotFoundError(f"MCAP file not found: {path}")
    require_regular(path)  # a FIFO or a device: refused, never read forever
    if len({imu_topic, fix_topic, vel_topic}) != 3 or events_topic in (imu_topic, fix_topic,
                                                                       vel_topic):
        raise ValueError(f"topics must differ: {imu_topic!r}, {fix_topic!r}, {vel_topic!r}"
                         + (f", {events_topic!r}" if events_topic else ""))


def _check_topics(scan: Scan, cols: dict[str, Collector], path: str,
                  required: tuple[str, str], vel_topic: str, events_topic: str,
                  issues: list[IngestIssue], note: str, broken: list[IngestIssue]) -> None:
    """Required topics present (else IngestError listing the available ones); an absent
    velocity or events topic and generically decoded messages noted in ``issues``."""
    available = ", ".join(f"{t} ({s})" for t, s in sorted(scan.topics.items())) or "none"
    for topic in required:
        if topic not in scan.topics:
            raise (IngestError if broken else MissingTopicError)(
                f"required topic {topic!r} ({cols[topic].spec.type_name}) not found; "
                f"available topics: {available}{note}", file=path, topic=topic,
                byte_offset=broken[0].byte_offset if broken else None, issues=tuple(issues),
            )
    if vel_topic not in scan.topics:
        issues.append(IngestIssue(
            "warning", path, vel_topic, None, None,
            f"optional topic {vel_topic!r} not found (no GNSS velocity); available: {available}",
        ))
    if events_topic and events_topic not in scan.topics:
        issues.append(IngestIssue(
            "info", path, events_topic, None, None,
            f"events topic {events_topic!r} not found (no trigger events); available: "
            f"{available}",
        ))
    for col in cols.values():
        if col.slow_messages and col.spec is not EVENT_SPEC:
            issues.append(IngestIssue(
                "info", path, col.topic, None, None,
                f"{col.slow_messages} message(s) decoded by the generic decoder (not "
                "little-endian plain CDR, or an unexpected layout)",
            ))


def _assemble_all(
    cols: dict[str, Collector], topics: tuple[str, str, str], events_topic: str,
    c_bs: np.ndarray, start_ns: int | None, end_ns: int | None,
    window_s: tuple[float | None, float | None], check_units: bool, issues: list[IngestIssue],
) -> tuple[ImuSamples, GnssFixes, GnssVelocities, np.ndarray | None]:
    """The windowed, checked IMU, fixes, velocities and event stamps (None: no events topic)."""
    imu_topic, fix_topic, vel_topic = topics
    imu_raw = cols[imu_topic].arrays()
    start_ns, end_ns = _absolute_window(imu_raw["time_ns"], start_ns, end_ns, window_s)
    imu = _assemble_imu(_window(imu_raw, start_ns, end_ns), cols[imu_topic], c_bs, check_units,
                        issues)
    if len(imu) < 2:
        raise IngestError(f"{len(imu)} IMU sample in the time window [{start_ns}, {end_ns}) ns"
                          " (at least 2 needed)", file=cols[imu_topic].path, topic=imu_topic)
    fix = _assemble_fix(_window(cols[fix_topic].arrays(), start_ns, end_ns),
                        cols[fix_topic], issues)
    vel = _assemble_vel(_window(cols[vel_topic].arrays(), start_ns, end_ns),
                        cols[vel_topic], issues)
    del imu_raw  # the raw log time stamps go now, before the rate check's temporaries
    if check_units and len(vel):
        _check_rate_units_against_gnss(imu, vel, imu_topic, cols[imu_topic].path)
    events_ns = _assemble_events(_window(cols[events_topic].arrays(), start_ns, end_ns),
                                 cols[events_topic], issues) if events_topic else None
    return imu, fix, vel, events_ns


def read_flight_log(
    path: str | Path,
    *,
    imu_topic: str = "/imu/data",
    fix_topic: str = "/gnss/fix",
    vel_topic: str = "/gnss/vel",
    c_bs: np.ndarray = FLU_TO_FRD,
    start_ns: int | None = None,
    end_ns: int | None = None,
    window_s: tuple[float | None, float | None] = (None, None),
    check_units: bool = True,
    max_chunk_bytes: int = MAX_CHUNK_BYTES,
    events_topic: str = "",
) -> FlightLog:
    """Read IMU and GNSS data from a ROS 2 MCAP file, rotate to FRD/NED, check the contract.

    Parameters
    ----------
    path : str or Path
        The MCAP file (ROS 2 profile, CDR messages).
    imu_topic, fix_topic : str
        Required topics (``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/NavSatFix``).
    vel_topic : str
        Optional ``geometry_msgs/msg/TwistWithCovarianceStamped`` topic; when absent, the
        velocities are empty and a warning issue says so.
    c_bs : (3, 3) array_like
        Mounting DCM, sensor s -> body b (FRD): ``w_ib_b = C_bs @ w_s``. Default FLU -> FRD.
    start_ns, end_ns : int, optional
        Keep samples whose header stamp is in ``[start_ns, end_ns)``.
    window_s : (float or None, float or None)
        Keep samples whose header stamp is ``[start, end)`` seconds after the file's first IMU
        header stamp (config ``[input] start_s, end_s``); None: open. Intersected with
        ``start_ns, end_ns``. At least two IMU samples must remain.
    check_units : bool
        Reject IMU data whose magnitudes look like g or deg/s (keyword, default True).
    max_chunk_bytes : int
        Cap on one chunk's decompressed size [bytes] (default ``MAX_CHUNK_BYTES``, 256 MiB;
        config ``[input] max_chunk_mib``): a chunk whose header claims more is skipped as
        corrupt, and no decompression produces more than its header claims, so a corrupt or
        hostile file cannot exhaust memory.
    events_topic : str
        Optional topic of trigger events (camera, lidar): ``sensor_msgs/msg/TimeReference``
        or any stamped message (``std_msgs/Header`` first, or a Header topic);
        "" (default): none. Their header stamps become ``FlightLog.events_ns``; a named topic
        that is absent gives an info issue.

    Returns
    -------
    FlightLog
        ``complete=False`` (and an error-severity issue) when the file is truncated or corrupt.

    Raises
    ------
    IngestError
        Missing required topic, wrong schema, stamps not strictly increasing (IMU; GNSS other
        than duplicates), non-finite values, implausible units, undecodable messages.
    FileNotFoundError
    """
    path = str(path)
    c = check_dcm(c_bs)
    _check_read_arguments(path, max_chunk_bytes, imu_topic, fix_topic, vel_topic, events_topic)
    cols = {
        imu_topic: Collector(imu_topic, IMU_SPEC, path),
        fix_topic: Collector(fix_topic, FIX_SPEC, path),
        vel_topic: Collector(vel_topic, VEL_SPEC, path),
    }
    if events_topic:
        cols[events_topic] = Collector(events_topic, EVENT_SPEC, path)
    scan = Scan(path, cols, max_chunk_bytes=max_chunk_bytes)
    scan.run()
    issues = list(scan.issues)
    broken = [i for i in issues if i.severity == "error"]
    note = f" (the file is truncated or corrupt: {broken[0]})" if broken else ""
    _check_topics(scan, cols, path, (imu_topic, fix_topic), vel_topic, events_topic, issues,
                  note, broken)
    try:
        imu, fix, vel, events_ns = _assemble_all(cols, (imu_topic, fix_topic, vel_topic),
                                                 events_topic, c, start_ns, end_ns,
                                                 window_s, check_units, issues)
    except IngestError as exc:
        raise IngestError(
            exc.reason + note, file=exc.file, topic=exc.topic, index=exc.index,
            time_ns=exc.time_ns, log_time_ns=exc.log_time_ns,
            byte_offset=exc.byte_offset if exc.byte_offset is not None else (
                broken[0].byte_offset if broken else None),
            issues=tuple(issues),
        ) from exc
    if fix.time_ns[-1] < imu.time_ns[0] or fix.time_ns[0] > imu.time_ns[-1]:
        issues.append(IngestIssue(
            "warning", path, fix_topic, None, int(fix.time_ns[0]),
            f"GNSS stamps [{fix.time_ns[0]}, {fix.time_ns[-1]}] ns do not overlap the IMU "
            f"stamps [{imu.time_ns[0]}, {imu.time_ns[-1]}] ns: different time bases?",
        ))
    extra = {} if events_ns is None else {"events_ns": events_ns}
    return FlightLog(imu=imu, fix=fix, vel=vel, path=path, issues=tuple(issues),
                     complete=scan.complete, **extra)
