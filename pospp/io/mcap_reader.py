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
The file is read in ONE sequential pass (no summary section needed, so a truncated file
yields everything before the break, including the readable part of a cut-off zstd/lz4 chunk).
Records are framed here (index records skipped unparsed; Schema and Channel records parsed by
``mcap.records``). Each chunk is decompressed and its records are walked with ``struct``;
the payloads of the wanted topics are gathered with numpy and decoded through one structured
dtype per (frame_id length) layout (``pospp.io.ros_messages.cdr_dtype``), for all messages of
the chunk at once. The first message of every (channel, layout) is also decoded by
``mcap_ros2``'s generic decoder and the two must agree bit for bit, else that layout falls back
to the generic decoder; messages that are not little-endian plain CDR always go through it.

Checks
------
Each raises ``IngestError`` or records an ``IngestIssue`` (docs/formats.md lists them): missing
required topic (the available ones are listed), wrong schema or encoding, IMU stamps not
strictly increasing (error), GNSS duplicate stamps (dropped, warning) or backwards (error),
NaN/inf (error naming the first bad message), IMU gaps over 3 nominal intervals and interval
changes (warnings), IMU magnitudes that look like g or deg/s (error), NO_FIX fixes (dropped,
warning), truncated or corrupt file (error issue, ``complete=False``, data read so far kept).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Schema
from mcap_ros2.decoder import DecoderFactory

from pospp.io import ros_messages as rm
from pospp.io.errors import IngestError, IngestIssue

__all__ = [
    "ENU_TO_NED",
    "FLU_TO_FRD",
    "FlightLog",
    "GnssFixes",
    "GnssVelocities",
    "ImuSamples",
    "apply_rotation",
    "read_flight_log",
]

FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])
"""C_bs for a REP-103 FLU sensor and an FRD body: x_b = x_s, y_b = -y_s, z_b = -z_s."""
FLU_TO_FRD.setflags(write=False)

ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""T with v_ned = T @ v_enu (T is its own inverse and transpose)."""
ENU_TO_NED.setflags(write=False)

G_MPS2 = 9.80665  # standard gravity, only for the units-plausibility check
_GAP_FACTOR = 3.0  # an IMU interval longer than this many nominal intervals is a gap
_MAX_LISTED = 100  # at most this many individual gap / rate-change issues
_GATHER_BATCH = 16384  # messages gathered at a time (bounds the index array to ~100 MB)


# --------------------------------------------------------------------------- public data


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples in the body frame (FRD) after the mounting rotation.

    Attributes
    ----------
    time_ns : (N,) int64
        End of each sampling interval (``header.stamp``) [ns].
    w_ib_b_radps : (N, 3) float64
        Mean angular rate of b w.r.t. inertial space over the interval, resolved in b [rad/s].
    f_ib_b_mps2 : (N, 3) float64
        Mean specific force over the interval, resolved in b [m/s^2] (about [0, 0, -g] level).
    frame_id : str
        ``header.frame_id`` of the sensor as logged (informational).
    """

    time_ns: np.ndarray
    w_ib_b_radps: np.ndarray
    f_ib_b_mps2: np.ndarray
    frame_id: str = ""

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])


@dataclass(frozen=True)
class GnssFixes:
    """GNSS antenna positions.

    Attributes
    ----------
    time_ns : (M,) int64
    lat_rad, lon_rad : (M,) float64
        Geodetic latitude and longitude (WGS-84) [rad].
    height_m : (M,) float64
        Height above the WGS-84 ellipsoid [m].
    pos_cov_ned_m2 : (M, 3, 3) float64
        Position covariance in NED [m^2].
    status : (M,) int8
        ``sensor_msgs/NavSatStatus.status`` (0 fix, 1 SBAS, 2 GBAS; -1 no-fix is dropped).
    """

    time_ns: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    height_m: np.ndarray
    pos_cov_ned_m2: np.ndarray
    status: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])


@dataclass(frozen=True)
class GnssVelocities:
    """GNSS antenna velocities.

    Attributes
    ----------
    time_ns : (K,) int64
    v_n_mps : (K, 3) float64
        Velocity in NED [m/s].
    vel_cov_ned_m2ps2 : (K, 3, 3) float64
        Velocity covariance in NED [m^2/s^2].
    """

    time_ns: np.ndarray
    v_n_mps: np.ndarray
    vel_cov_ned_m2ps2: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])


@dataclass(frozen=True)
class FlightLog:
    """Everything read from one MCAP file.

    ``complete`` is False when the file is truncated or corrupt; then ``issues`` holds an
    ``IngestIssue`` of severity ``"error"`` saying where reading broke, and the arrays hold what
    was read before the break.
    """

    imu: ImuSamples
    fix: GnssFixes
    vel: GnssVelocities
    path: str
    issues: tuple[IngestIssue, ...] = ()
    complete: bool = True


def empty_velocities() -> GnssVelocities:
    """A GnssVelocities with no samples."""
    return GnssVelocities(
        np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3))
    )


def apply_rotation(c_ab: np.ndarray, v_b: np.ndarray) -> np.ndarray:
    """``v_a = C_ab @ v_b`` for rows of ``v_b`` (N, 3).

    A signed permutation (entries in {-1, 0, 1}, e.g. FLU->FRD, ENU->NED) is applied by
    indexing and sign flips, so it is exact and invertible bit for bit (no ``0 * x`` sums that
    turn -0.0 into +0.0); any other DCM by matrix product.
    """
    c = np.asarray(c_ab, dtype=float)
    v = np.asarray(v_b, dtype=float)
    nz = c != 0.0
    if np.all(np.isin(c, (-1.0, 0.0, 1.0))) and np.all(nz.sum(axis=1) == 1):
        cols = np.argmax(nz, axis=1)
        return v[..., cols] * c[np.arange(3), cols]
    return v @ c.T


def _rotate_cov(c_ab: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """``P_a = C_ab P_b C_ab^T`` for (N, 3, 3) stacks (exact for signed permutations)."""
    p_c = apply_rotation(c_ab, p_b)  # rows of P rotated: P C^T
    return np.swapaxes(apply_rotation(c_ab, np.swapaxes(p_c, -1, -2)), -1, -2)  # C (P C^T)


def check_dcm(c_bs: Any, name: str = "c_bs") -> np.ndarray:
    """Validate a DCM: shape (3, 3), orthonormal to 1e-9, determinant +1."""
    c = np.asarray(c_bs, dtype=float)
    if c.shape != (3, 3):
        raise ValueError(f"{name} must have shape (3, 3), got {c.shape}")
    err = np.abs(c @ c.T - np.eye(3)).max()
    if err > 1e-9 or np.linalg.det(c) < 0:
        raise ValueError(
            f"{name} must be a rotation (orthonormal, det +1); got |C C^T - I|max={err:.2e}, "
            f"det={np.linalg.det(c):+.6f}"
        )
    return c


# --------------------------------------------------------------------------- topic specs


def _vec(v: Any) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


@dataclass(frozen=True)
class _Spec:
    """How to decode one message type: layout, fields wanted, generic-decoder extractor."""

    type_name: str
    layout: tuple[tuple[str, str, int], ...]
    wanted: tuple[str, ...]
    from_decoded: Callable[[Any], dict[str, Any]]


_IMU_SPEC = _Spec(
    rm.IMU_TYPE,
    rm.IMU_FIELDS,
    ("angular_velocity", "linear_acceleration"),
    lambda m: {
        "angular_velocity": _vec(m.angular_velocity),
        "linear_acceleration": _vec(m.linear_acceleration),
    },
)
_FIX_SPEC = _Spec(
    rm.NAVSATFIX_TYPE,
    rm.NAVSATFIX_FIELDS,
    ("status", "latitude", "longitude", "altitude", "position_covariance",
     "position_covariance_type"),
    lambda m: {
        "status": m.status.status,
        "latitude": m.latitude,
        "longitude": m.longitude,
        "altitude": m.altitude,
        "position_covariance": tuple(m.position_covariance),
        "position_covariance_type": m.position_covariance_type,
    },
)
_VEL_SPEC = _Spec(
    rm.TWIST_COV_STAMPED_TYPE,
    rm.TWIST_COV_STAMPED_FIELDS,
    ("linear", "covariance"),
    lambda m: {"linear": _vec(m.twist.twist.linear), "covariance": tuple(m.twist.covariance)},
)


def _gather(buf: np.ndarray, starts: np.ndarray, offset: int, width: int) -> np.ndarray:
    """Bytes ``buf[s + offset : s + offset + width]`` for every s in ``starts``: (n, width)."""
    return buf[(starts + offset)[:, None] + np.arange(width)]


def _field_values(buf: np.ndarray, starts: np.ndarray, dt: np.ndarray, name: str) -> np.ndarray:
    """Field ``name`` of layout ``dt`` for messages starting at ``starts``: (n,) or (n, k)."""
    ftype, offset = dt.fields[name][:2]
    base = ftype.base if ftype.subdtype else ftype
    raw = np.ascontiguousarray(_gather(buf, starts, offset, ftype.itemsize))
    vals = raw.view(base.newbyteorder("<") if base.itemsize > 1 else base)
    vals = vals.reshape(len(starts), *ftype.shape) if ftype.shape else vals[:, 0]
    return vals.astype(base.newbyteorder("="), copy=False)


class _Collector:
    """Accumulates the decoded messages of one topic, block by block."""

    def __init__(self, topic: str, spec: _Spec, path: str) -> None:
        self.topic = topic
        self.spec = spec
        self.path = path
        self.blocks: list[dict[str, np.ndarray]] = []
        self.count = 0
        self.frame_ids: list[str] = []
        self.channels: dict[int, Schema | None] = {}
        self._decoders: dict[int, Callable[[bytes], Any]] = {}
        self._verified: dict[tuple[int, int], bool] = {}  # (channel, frame_len) -> fast ok
        self.slow_messages = 0

    # -- generic path
    def _decoder(self, channel_id: int) -> Callable[[bytes], Any]:
        dec = self._decoders.get(channel_id)
        if dec is None:
            dec = DecoderFactory().decoder_for("cdr", self.channels[channel_id])
            if dec is None:
                raise IngestError(
                    f"no ROS 2 decoder for the schema of {self.topic!r}", file=self.path,
                    topic=self.topic,
                )
            self._decoders[channel_id] = dec
        return dec

    def _decode_slow(self, channel_id: int, payload: bytes, index: int) -> dict[str, Any]:
        try:
            msg = self._decoder(channel_id)(payload)
        except Exception as exc:  # noqa: BLE001 - any decoder failure is a corrupt message
            raise IngestError(
                f"cannot decode {self.spec.type_name} message: {exc}", file=self.path,
                topic=self.topic, index=index,
            ) from exc
        vals = self.spec.from_decoded(msg)
        vals["time_ns"] = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        vals["frame_id"] = msg.header.frame_id
        return vals

    # -- one batch of messages of one channel
    def add(self, channel_id: int, buf: np.ndarray, pos: np.ndarray) -> None:
        """Decode the Message records starting at ``pos`` (record offsets) in ``buf``."""
        n = len(pos)
        first_index = self.count
        rec_len = _gather(buf, pos, 1, 8).copy().view("<u8")[:, 0].astype(np.int64)
        log_time = _gather(buf, pos, 15, 8).copy().view("<u8")[:, 0].astype(np.int64)
        starts = pos + 31  # opcode 1 + length 8 + channel 2 + sequence 4 + 2 x time 8
        plen = rec_len - 22
        out: dict[str, np.ndarray] = {"time_ns": np.zeros(n, np.int64), "log_time_ns": log_time}
        probe = rm.cdr_dtype(self.spec.layout, 1)
        for name in self.spec.wanted:
            ftype = probe.fields[name][0]
            base = ftype.base if ftype.subdtype else ftype
            out[name] = np.zeros((n, *ftype.shape), base.newbyteorder("="))
        slow = np.ones(n, bool)
        ok_hdr = plen >= 16
        if ok_hdr.any():
            hdr = np.zeros((n, 16), np.uint8)
            hdr[ok_hdr] = _gather(buf, starts[ok_hdr], 0, 16)
            le = ok_hdr & (hdr[:, 0] == 0) & (hdr[:, 1] == 1)
            flen = hdr[:, 12:16].copy().view("<u4")[:, 0].astype(np.int64)
            for fl in np.unique(flen[le]):
                dt = rm.cdr_dtype(self.spec.layout, int(fl))
                grp = np.flatnonzero(le & (flen == fl) & (plen == dt.itemsize))
                if grp.size == 0 or not self._layout_ok(channel_id, buf, starts, grp[0], dt):
                    continue
                for name in self.spec.wanted:
                    out[name][grp] = _field_values(buf, starts[grp], dt, name)
                sec = _field_values(buf, starts[grp], dt, "sec")
                nsec = _field_values(buf, starts[grp], dt, "nanosec")
                out["time_ns"][grp] = rm.stamp_ns(sec, nsec)
                chars = _field_values(buf, starts[grp], dt, "frame_id")
                self._note_frames(chars)
                slow[grp] = False
        for i in np.flatnonzero(slow):
            s, ln = int(starts[i]), int(plen[i])
            vals = self._decode_slow(channel_id, buf[s : s + ln].tobytes(), first_index + i)
            for name in self.spec.wanted:
                out[name][i] = vals[name]
            out["time_ns"][i] = vals["time_ns"]
            if vals["frame_id"] not in self.frame_ids:
                self.frame_ids.append(vals["frame_id"])
            self.slow_messages += 1
        self.blocks.append(out)
        self.count += n

    def _note_frames(self, chars: np.ndarray) -> None:
        rows = chars if np.all(chars == chars[0]) else np.unique(chars, axis=0)
        for row in rows[:1] if rows is chars else rows:
            fid = row.tobytes().rstrip(b"\x00").decode("utf-8", "replace")
            if fid not in self.frame_ids:
                self.frame_ids.append(fid)

    def _layout_ok(
        self, channel_id: int, buf: np.ndarray, starts: np.ndarray, i: int, dt: np.dtype
    ) -> bool:
        """Fast layout checked once per (channel, layout) against the generic decoder."""
        key = (channel_id, dt.itemsize)
        if key not in self._verified:
            s = int(starts[i])
            ref = self._decode_slow(channel_id, buf[s : s + dt.itemsize].tobytes(), self.count)
            one = starts[i : i + 1]
            same = all(
                np.array_equal(
                    _field_values(buf, one, dt, name)[0].tobytes(),
                    np.asarray(ref[name], dtype=_field_values(buf, one, dt, name).dtype).tobytes(),
                )
                for name in self.spec.wanted
            )
            self._verified[key] = same
        return self._verified[key]

    def arrays(self) -> dict[str, np.ndarray]:
        """All blocks concatenated (one concatenate per field, not per block)."""
        if not self.blocks:
            probe = rm.cdr_dtype(self.spec.layout, 1)
            res = {"time_ns": np.zeros(0, np.int64), "log_time_ns": np.zeros(0, np.int64)}
            for name in self.spec.wanted:
                ftype = probe.fields[name][0]
                base = ftype.base if ftype.subdtype else ftype
                res[name] = np.zeros((0, *ftype.shape), base.newbyteorder("="))
            return res
        return {k: np.concatenate([b[k] for b in self.blocks]) for k in self.blocks[0]}


# --------------------------------------------------------------------------- streaming pass

_REC = struct.Struct("<BQ").unpack_from
_U16 = struct.Struct("<H").unpack_from
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression len
_MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_FOOTER = 0x03, 0x04, 0x05, 0x06, 0x02


class _Truncated(Exception):
    """The file ends inside a record or before the Footer."""


@dataclass(frozen=True)
class _RawChunk:
    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data: bytes
    truncated: bool


def _parse_chunk(body: bytes, truncated: bool) -> _RawChunk:
    if len(body) < _CHUNK_HEAD.size:
        raise _Truncated("chunk header cut off")
    start, end, usize, crc, clen = _CHUNK_HEAD.unpack_from(body, 0)
    p = _CHUNK_HEAD.size
    comp = body[p : p + clen].decode("utf-8")
    p += clen
    (dlen,) = struct.unpack_from("<Q", body, p) if len(body) >= p + 8 else (None,)
    if dlen is None:
        raise _Truncated("chunk header cut off")
    data = body[p + 8 : p + 8 + dlen]
    return _RawChunk(start, end, usize, crc, comp, data, truncated or len(data) < dlen)


def _decompress(chunk: _RawChunk) -> bytes:
    """Chunk records; for a truncated chunk, as many bytes as can be decompressed."""
    if chunk.compression == "zstd":
        import zstandard

        if chunk.truncated:
            data = zstandard.ZstdDecompressor().decompressobj().decompress(chunk.data)
        else:
            data = zstandard.ZstdDecompressor().decompress(
                chunk.data, max_output_size=chunk.uncompressed_size
            )
    elif chunk.compression == "lz4":
        import lz4.frame

        if chunk.truncated:
            data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data)
        else:
            data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
    if chunk.truncated:
        return data
    if len(data) != chunk.uncompressed_size:
        raise ValueError(
            f"chunk decompressed to {len(data)} bytes, header says {chunk.uncompressed_size}"
        )
    if chunk.crc != 0 and zlib.crc32(data) != chunk.crc:
        raise ValueError("chunk CRC mismatch")
    return data


class _Pass:
    """One streaming pass over the file, dispatching messages to collectors by topic.

    Records are framed here (opcode, length) rather than by ``mcap``'s ``StreamReader``, so
    that index records are skipped unparsed and a truncated last chunk is still decompressed
    as far as it goes.
    """

    def __init__(self, path: str, collectors: dict[str, _Collector]) -> None:
        self.path = path
        self.by_topic = collectors
        self.schemas: dict[int, Schema] = {}
        self.topics: dict[str, str] = {}  # topic -> schema name
        self.route: dict[int, _Collector | None] = {}
        self.issues: list[IngestIssue] = []
        self.complete = False
        self.last_log_time_ns: int | None = None
        self._loose: list[bytes] = []

    def _schema(self, rec: Schema) -> None:
        self.schemas[rec.id] = rec

    def _channel(self, rec: Channel) -> None:
        if rec.id in self.route:
            return
        schema = self.schemas.get(rec.schema_id)
        self.topics[rec.topic] = schema.name if schema else "<no schema>"
        col = self.by_topic.get(rec.topic)
        if col is not None:
            got = schema.name if schema else "<no schema>"
            if got != col.spec.type_name:
                raise IngestError(
                    f"topic {rec.topic!r} has schema {got!r}, expected {col.spec.type_name!r}",
                    file=self.path, topic=rec.topic,
                )
            if rec.message_encoding != "cdr" or schema.encoding != "ros2msg":
                raise IngestError(
                    f"topic {rec.topic!r} is {rec.message_encoding!r} / {schema.encoding!r}, "
                    "expected 'cdr' messages with a 'ros2msg' schema",
                    file=self.path, topic=rec.topic,
                )
            col.channels[rec.id] = schema
        self.route[rec.id] = col

    def _meta(self, op: int, body: bytes) -> None:
        stream = ReadDataStream(BytesIO(body))
        if op == _OP_SCHEMA:
            self._schema(Schema.read(stream))
        else:
            self._channel(Channel.read(stream))

    def _records(self, buf: bytes, *, partial: bool = False) -> int:
        """Walk the records of a decompressed chunk (or a block of loose messages).

        With ``partial`` (a truncated chunk), stop quietly at the first incomplete record.
        Returns the number of bytes walked.
        """
        pos, n = 0, len(buf)
        by_channel: dict[int, list[int]] = {}
        while pos < n:
            end = n + 1 if pos + 9 > n else pos + 9 + _REC(buf, pos)[1]
            if end > n:
                if partial:
                    break
                raise ValueError(f"record overruns the chunk at offset {pos}")
            op = buf[pos]
            if op == _OP_MESSAGE:
                ch = _U16(buf, pos + 9)[0]
                lst = by_channel.get(ch)
                if lst is None:
                    lst = by_channel[ch] = []
                lst.append(pos)
            elif op in (_OP_SCHEMA, _OP_CHANNEL):
                self._meta(op, buf[pos + 9 : end])
            pos = end
        arr = np.frombuffer(buf, dtype=np.uint8)
        for ch, lst in by_channel.items():
            if ch not in self.route:
                raise ValueError(f"message on channel {ch} before its Channel record")
            col = self.route[ch]
            if col is None:
                continue
            p = np.asarray(lst, dtype=np.int64)
            for k in range(0, len(p), _GATHER_BATCH):
                col.add(ch, arr, p[k : k + _GATHER_BATCH])
            last = int(p[-1])
            self.last_log_time_ns = max(self.last_log_time_ns or 0,
                                        struct.unpack_from("<Q", buf, last + 15)[0])
        return pos

    def _flush_loose(self) -> None:
        if self._loose:
            buf = b"".join(self._loose)
            self._loose = []
            self._records(buf)

    def run(self) -> None:
        size = Path(self.path).stat().st_size
        with open(self.path, "rb") as f:
            if f.read(8) != _MAGIC:
                raise IngestError("not an MCAP file (bad magic bytes)", file=self.path)
            good = 8
            try:
                while True:
                    head = f.read(9)
                    if len(head) < 9:
                        raise _Truncated("file ends without a Footer record")
                    op, ln = _REC(head, 0)
                    if op in (_OP_CHUNK, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                        body = f.read(ln)
                        short = len(body) < ln
                        if op == _OP_CHUNK:
                            self._flush_loose()
                            self._chunk(_parse_chunk(body, short), good)
                        elif short:
                            raise _Truncated("record cut off")
                        elif op == _OP_MESSAGE:
                            self._loose.append(head + body)
                            if len(self._loose) >= 10000:
                                self._flush_loose()
                        else:
                            self._meta(op, body)
                        if short:
                            raise _Truncated("chunk cut off (decoded what it held)")
                    elif op == _OP_FOOTER:
                        self._flush_loose()
                        self.complete = True
                        return
                    else:
                        if good + 9 + ln > size:
                            raise _Truncated("record cut off")
                        f.seek(ln, 1)
                    good = f.tell()
            except IngestError:
                raise
            except (_Truncated, ValueError, struct.error, UnicodeDecodeError) as exc:
                self._flush_loose()
                self.issues.append(
                    IngestIssue(
                        "error", self.path, None, None, None,
                        f"MCAP truncated or corrupt after byte {good} of {size} ({exc}); kept "
                        f"the messages read before it (last good log time "
                        f"{self.last_log_time_ns} ns)",
                        log_time_ns=self.last_log_time_ns, byte_offset=good,
                    )
                )

    def _chunk(self, chunk: _RawChunk, offset: int) -> None:
        try:
            data = _decompress(chunk)
            self._records(data, partial=chunk.truncated)
        except IngestError:
            raise
        except (ValueError, struct.error) as exc:
            if chunk.truncated:
                raise _Truncated(f"chunk cut off and undecodable: {exc}") from exc
            self.issues.append(
                IngestIssue(
                    "error", self.path, None, None, chunk.start_ns,
                    f"corrupt chunk at byte {offset} skipped (log times "
                    f"{chunk.start_ns}..{chunk.end_ns} ns): {exc}",
                    log_time_ns=chunk.start_ns, byte_offset=offset,
                )
            )
        except Exception as exc:  # zstd/lz4 errors have their own classes
            if chunk.truncated:
                raise _Truncated(f"chunk cut off and undecodable: {exc}") from exc
            self.issues.append(
                IngestIssue(
                    "error", self.path, None, None, chunk.start_ns,
                    f"corrupt chunk at byte {offset} skipped: {type(exc).__name__}: {exc}",
                    log_time_ns=chunk.start_ns, byte_offset=offset,
                )
            )


# --------------------------------------------------------------------------- checks & assembly


def _window(a: dict[str, np.ndarray], start_ns: int | None, end_ns: int | None) -> dict:
    """Keep samples with ``start_ns <= time_ns < end_ns``; add ``index`` (file order)."""
    a = dict(a)
    a["index"] = np.arange(len(a["time_ns"]))
    keep = np.ones(len(a["time_ns"]), bool)
    if start_ns is not None:
        keep &= a["time_ns"] >= start_ns
    if end_ns is not None:
        keep &= a["time_ns"] < end_ns
    if keep.all():
        return a
    return {k: v[keep] for k, v in a.items()}


def _check_order(a: dict, topic: str, path: str, *, drop_duplicates: bool,
                 issues: list[IngestIssue]) -> dict:
    """Stamps must increase strictly; GNSS duplicates may be dropped (with an issue)."""
    t = a["time_ns"]
    d = np.diff(t)
    if drop_duplicates and np.any(d == 0):
        dup = np.flatnonzero(d == 0) + 1
        issues.append(IngestIssue(
            "warning", path, topic, int(a["index"][dup[0]]), int(t[dup[0]]),
            f"{dup.size} message(s) with a duplicate header stamp dropped (kept the first of "
            "each stamp)", log_time_ns=int(a["log_time_ns"][dup[0]]),
        ))
        keep = np.ones(len(t), bool)
        keep[dup] = False
        a = {k: v[keep] for k, v in a.items()}
        t = a["time_ns"]
        d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = bad[0] + 1
        what = "duplicates" if d[bad[0]] == 0 else f"goes back {-int(d[bad[0]])} ns from"
        raise IngestError(
            f"header stamp {what} the previous message's ({int(t[i - 1])} ns); stamps must "
            f"increase strictly ({bad.size} such message(s) in total)",
            file=path, topic=topic, index=int(a["index"][i]), time_ns=int(t[i]),
            log_time_ns=int(a["log_time_ns"][i]),
        )
    return a


def _check_finite(a: dict, names: tuple[str, ...], topic: str, path: str) -> None:
    bad = np.zeros(len(a["time_ns"]), bool)
    for name in names:
        v = a[name]
        bad |= ~np.isfinite(v).reshape(len(v), -1).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        fields = [n for n in names if not np.isfinite(a[n][i]).all()]
        raise IngestError(
            f"non-finite value (NaN or inf) in {', '.join(fields)} = "
            f"{[a[n][i].tolist() for n in fields]} ({int(bad.sum())} bad message(s) in total)",
            file=path, topic=topic, index=int(a["index"][i]), time_ns=int(a["time_ns"][i]),
            log_time_ns=int(a["log_time_ns"][i]),
        )


def _imu_timing_issues(a: dict, topic: str, path: str) -> list[IngestIssue]:
    """Gaps (> 3 nominal intervals) and changes of the sampling interval."""
    t = a["time_ns"]
    out: list[IngestIssue] = []
    if len(t) < 3:
        return out
    d = np.diff(t)
    nominal = float(np.median(d))
    gaps = np.flatnonzero(d > _GAP_FACTOR * nominal)
    for g in gaps[:_MAX_LISTED]:
        out.append(IngestIssue(
            "warning", path, topic, int(a["index"][g + 1]), int(t[g + 1]),
            f"IMU gap of {d[g] * 1e-9:.6f} s ({d[g] / nominal:.1f} nominal intervals of "
            f"{nominal * 1e-6:.3f} ms) after stamp {int(t[g])} ns",
            log_time_ns=int(a["log_time_ns"][g + 1]),
        ))
    if gaps.size > _MAX_LISTED:
        out.append(IngestIssue(
            "warning", path, topic, None, None,
            f"{gaps.size} IMU gaps in total; only the first {_MAX_LISTED} are listed",
        ))
    # rate changes: median interval per block of 1000 samples vs the overall median
    block = 1000
    nb = len(d) // block
    if nb >= 2:
        med = np.median(d[: nb * block].reshape(nb, block), axis=1)
        off = np.abs(med - nominal) > 0.02 * nominal
        starts = np.flatnonzero(off & ~np.r_[False, off[:-1]])
        for b in starts[:_MAX_LISTED]:
            j = b * block + 1
            out.append(IngestIssue(
                "warning", path, topic, int(a["index"][j]), int(t[j]),
                f"IMU sampling interval changes to {med[b] * 1e-6:.3f} ms (nominal "
                f"{nominal * 1e-6:.3f} ms, {1e9 / nominal:.2f} Hz)",
                log_time_ns=int(a["log_time_ns"][j]),
            ))
    return out


def _check_imu_units(w: np.ndarray, f: np.ndarray, topic: str, path: str) -> None:
    """Reject specific force in g, and rates that look like deg/s."""
    fmag = np.linalg.norm(f, axis=1)
    wmag = np.linalg.norm(w, axis=1)
    fmed = float(np.median(fmag))
    if 0.5 < fmed < 1.5:
        raise IngestError(
            f"median |linear_acceleration| = {fmed:.4f}: looks like g, not m/s^2 "
            f"(expected about {G_MPS2:.2f} m/s^2)", file=path, topic=topic,
        )
    if not 0.5 * G_MPS2 < fmed < 1.5 * G_MPS2:
        raise IngestError(
            f"median |linear_acceleration| = {fmed:.4g} m/s^2, expected about {G_MPS2:.2f} "
            "m/s^2 (specific force of a vehicle near the Earth's surface)",
            file=path, topic=topic,
        )
    wmed, wmax = float(np.median(wmag)), float(wmag.max())
    if wmed > 1.0 or wmax > 40.0:
        i = int(np.argmax(wmag))
        raise IngestError(
            f"|angular_velocity| median {wmed:.4g}, max {wmax:.4g} (sample {i}): looks like "
            "deg/s, not rad/s (expected median < 1 rad/s and max < 40 rad/s)",
            file=path, topic=topic, index=i,
        )


def _assemble_imu(a: dict, col: _Collector, c_bs: np.ndarray, check_units: bool,
                  issues: list[IngestIssue]) -> ImuSamples:
    topic, path = col.topic, col.path
    if len(a["time_ns"]) == 0:
        raise IngestError("no IMU messages (in the time window)", file=path, topic=topic)
    a = _check_order(a, topic, path, drop_duplicates=False, issues=issues)
    _check_finite(a, ("angular_velocity", "linear_acceleration"), topic, path)
    issues.extend(_imu_timing_issues(a, topic, path))
    if check_units:
        _check_imu_units(a["angular_velocity"], a["linear_acceleration"], topic, path)
    if len(col.frame_ids) > 1:
        issues.append(IngestIssue("warning", path, topic, None, None,
                                  f"several IMU frame_ids: {col.frame_ids}"))
    return ImuSamples(
        time_ns=a["time_ns"],
        w_ib_b_radps=apply_rotation(c_bs, a["angular_velocity"]),
        f_ib_b_mps2=apply_rotation(c_bs, a["linear_acceleration"]),
        frame_id=col.frame_ids[0] if col.frame_ids else "",
    )


def _assemble_fix(a: dict, col: _Collector, issues: list[IngestIssue]) -> GnssFixes:
    topic, path = col.topic, col.path
    nofix = a["status"] < 0
    if nofix.any():
        i = int(np.argmax(nofix))
        issues.append(IngestIssue(
            "warning", path, topic, int(a["index"][i]), int(a["time_ns"][i]),
            f"{int(nofix.sum())} fix(es) with status NO_FIX dropped",
            log_time_ns=int(a["log_time_ns"][i]),
        ))
        a = {k: v[~nofix] for k, v in a.items()}
    if len(a["time_ns"]) == 0:
        raise IngestError("no usable GNSS fixes (in the time window)", file=path, topic=topic)
    a = _check_order(a, topic, path, drop_duplicates=True, issues=issues)
    _check_finite(a, ("latitude", "longitude", "altitude", "position_covariance"), topic, path)
    bad = (np.abs(a["latitude"]) > 90.0) | (np.abs(a["longitude"]) > 180.0)
    if bad.any():
        i = int(np.argmax(bad))
        raise IngestError(
            f"latitude/longitude out of range: {a['latitude'][i]}, {a['longitude'][i]} "
            "(expected degrees, |lat| <= 90, |lon| <= 180)", file=path, topic=topic,
            index=int(a["index"][i]), time_ns=int(a["time_ns"][i]),
        )
    unknown = a["position_covariance_type"] == 0
    if unknown.any():
        i = int(np.argmax(unknown))
        issues.append(IngestIssue(
            "warning", path, topic, int(a["index"][i]), int(a["time_ns"][i]),
            f"{int(unknown.sum())} fix(es) with position_covariance_type UNKNOWN",
        ))
    cov_enu = a["position_covariance"].reshape(-1, 3, 3)
    return GnssFixes(
        time_ns=a["time_ns"],
        lat_rad=np.deg2rad(a["latitude"]),
        lon_rad=np.deg2rad(a["longitude"]),
        height_m=a["altitude"],
        pos_cov_ned_m2=_rotate_cov(ENU_TO_NED, cov_enu),
        status=a["status"].astype(np.int8),
    )


def _assemble_vel(a: dict, col: _Collector, issues: list[IngestIssue]) -> GnssVelocities:
    topic, path = col.topic, col.path
    if len(a["time_ns"]) == 0:
        return empty_velocities()
    a = _check_order(a, topic, path, drop_duplicates=True, issues=issues)
    cov_enu = a["covariance"].reshape(-1, 6, 6)[:, :3, :3]
    _check_finite({**a, "cov": cov_enu}, ("linear", "cov"), topic, path)
    return GnssVelocities(
        time_ns=a["time_ns"],
        v_n_mps=apply_rotation(ENU_TO_NED, a["linear"]),
        vel_cov_ned_m2ps2=_rotate_cov(ENU_TO_NED, np.ascontiguousarray(cov_enu)),
    )


def read_flight_log(
    path: str | Path,
    *,
    imu_topic: str = "/imu/data",
    fix_topic: str = "/gnss/fix",
    vel_topic: str = "/gnss/vel",
    c_bs: np.ndarray = FLU_TO_FRD,
    start_ns: int | None = None,
    end_ns: int | None = None,
    check_units: bool = True,
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
    check_units : bool
        Reject IMU data whose magnitudes look like g or deg/s (keyword, default True).

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
    if not Path(path).is_file():
        raise FileNotFoundError(f"MCAP file not found: {path}")
    if len({imu_topic, fix_topic, vel_topic}) != 3:
        raise ValueError(f"topics must differ: {imu_topic!r}, {fix_topic!r}, {vel_topic!r}")
    cols = {
        imu_topic: _Collector(imu_topic, _IMU_SPEC, path),
        fix_topic: _Collector(fix_topic, _FIX_SPEC, path),
        vel_topic: _Collector(vel_topic, _VEL_SPEC, path),
    }
    scan = _Pass(path, cols)
    scan.run()
    issues = list(scan.issues)
    available = ", ".join(f"{t} ({s})" for t, s in sorted(scan.topics.items())) or "none"
    note = "" if scan.complete else " (the file is truncated or corrupt: see the issues)"
    for topic in (imu_topic, fix_topic):
        if topic not in scan.topics:
            raise IngestError(
                f"required topic {topic!r} ({cols[topic].spec.type_name}) not found; "
                f"available topics: {available}{note}", file=path, topic=topic,
            )
    if vel_topic not in scan.topics:
        issues.append(IngestIssue(
            "warning", path, vel_topic, None, None,
            f"optional topic {vel_topic!r} not found (no GNSS velocity); available: {available}",
        ))
    for col in cols.values():
        if col.slow_messages:
            issues.append(IngestIssue(
                "info", path, col.topic, None, None,
                f"{col.slow_messages} message(s) decoded by the generic decoder (not "
                "little-endian plain CDR, or an unexpected layout)",
            ))
    imu = _assemble_imu(_window(cols[imu_topic].arrays(), start_ns, end_ns), cols[imu_topic],
                        c, check_units, issues)
    fix = _assemble_fix(_window(cols[fix_topic].arrays(), start_ns, end_ns), cols[fix_topic],
                        issues)
    vel = _assemble_vel(_window(cols[vel_topic].arrays(), start_ns, end_ns), cols[vel_topic],
                        issues)
    if fix.time_ns[-1] < imu.time_ns[0] or fix.time_ns[0] > imu.time_ns[-1]:
        issues.append(IngestIssue(
            "warning", path, fix_topic, None, int(fix.time_ns[0]),
            f"GNSS stamps [{fix.time_ns[0]}, {fix.time_ns[-1]}] ns do not overlap the IMU "
            f"stamps [{imu.time_ns[0]}, {imu.time_ns[-1]}] ns: different time bases?",
        ))
    return FlightLog(imu=imu, fix=fix, vel=vel, path=path, issues=tuple(issues),
                     complete=scan.complete)
