"""Single-pass MCAP scanning and batched CDR decoding for :mod:`pospp.io.mcap_reader`.

Private module: the record framing, chunk decompression and compiled (numba) decoding behind
``read_flight_log``. Why pospp frames records itself rather than iterating with
``mcap.reader.make_reader(...).iter_messages()`` is measured in docs/formats.md ("Why a
hand-written framing"): the library builds one Python ``Message`` object per record, which costs
about 4x the time of this pass on a 1.08 M-message file; chunk CRCs, compression and the
Schema/Channel records are still handled with the library's own ``mcap.records`` and the
``zstandard`` / ``lz4`` codecs it depends on.

Layout of the bytes walked here (MCAP specification, https://mcap.dev/spec): every record is
``opcode u8, length u64, body``; a Message body is ``channel_id u16, sequence u32, log_time u64,
publish_time u64, data``; a Chunk body is ``message_start_time u64, message_end_time u64,
uncompressed_size u64, uncompressed_crc u32, compression string, records_length u64, records``.
"""

from __future__ import annotations

import functools
import struct
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.records import Channel, Schema
from mcap_ros2.decoder import DecoderFactory
from numba import njit
from numba.core.errors import NumbaError

from pospp.io import ros_messages as rm
from pospp.io.errors import IngestError, IngestIssue

_LITTLE_ENDIAN = sys.byteorder == "little"

# --------------------------------------------------------------------------- topic specs


def _vec(v: Any) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


@dataclass(frozen=True)
class Spec:
    """How to decode one message type: layout, fields wanted, generic-decoder extractor."""

    type_name: str
    layout: tuple[tuple[str, str, int], ...]
    wanted: tuple[str, ...]
    from_decoded: Callable[[Any], dict[str, Any]]
    any_stamped: bool = False
    """Accept any message type whose first field is a ``std_msgs/Header`` (only its stamp is
    read), not only ``type_name``."""


IMU_SPEC = Spec(
    rm.IMU_TYPE,
    rm.IMU_FIELDS,
    ("angular_velocity", "linear_acceleration"),
    lambda m: {
        "angular_velocity": _vec(m.angular_velocity),
        "linear_acceleration": _vec(m.linear_acceleration),
    },
)
FIX_SPEC = Spec(
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
VEL_SPEC = Spec(
    rm.TWIST_COV_STAMPED_TYPE,
    rm.TWIST_COV_STAMPED_FIELDS,
    ("linear", "covariance"),
    lambda m: {"linear": _vec(m.twist.twist.linear), "covariance": tuple(m.twist.covariance)},
)

EVENT_SPEC = Spec(
    rm.TIME_REFERENCE_TYPE,
    rm.TIME_REFERENCE_FIELDS,
    (),
    lambda m: {},
    any_stamped=True,
)
"""Trigger events (``sensor_msgs/msg/TimeReference``, or any stamped trigger message): only
the header stamp is kept. The trailing ``source`` string makes the layout variable, so these
few messages go through the generic decoder."""


def _gather(buf: np.ndarray, starts: np.ndarray, offset: int, width: int) -> np.ndarray:
    """Bytes ``buf[s + offset : s + offset + width]`` for every s in ``starts``: (n, width),
    C-contiguous.

    Rows taken from a sliding-window view of ``buf`` (one index per row, not per byte: about
    ten times faster than an (n, width) index array); an index past the end raises
    IndexError.
    """
    if width > len(buf):
        raise IndexError(f"{width} bytes wanted from a buffer of {len(buf)}")
    win = np.ndarray((len(buf) - width + 1, width), np.uint8, buffer=buf,
                     strides=(buf.strides[0], buf.strides[0]))
    return win[starts + offset]


@functools.lru_cache(maxsize=256)
def _cdr_dtype(layout: tuple[tuple[str, str, int], ...], frame_id_len: int) -> np.dtype:
    """:func:`pospp.io.ros_messages.cdr_dtype`, built once per layout and frame_id length."""
    return rm.cdr_dtype(layout, frame_id_len)


def _field_values(buf: np.ndarray, starts: np.ndarray, dt: np.dtype, name: str) -> np.ndarray:
    """Field ``name`` of layout ``dt`` for messages starting at ``starts``: (n,) or (n, k)."""
    assert dt.fields is not None  # a structured dtype (_cdr_dtype)
    ftype, offset = dt.fields[name][:2]
    base = ftype.base if ftype.subdtype else ftype
    raw = np.ascontiguousarray(_gather(buf, starts, offset, ftype.itemsize))
    vals = raw.view(base.newbyteorder("<") if base.itemsize > 1 else base)
    vals = vals.reshape(len(starts), *ftype.shape) if ftype.shape else vals[:, 0]
    return vals.astype(base.newbyteorder("="), copy=False)


_MIN_CAPACITY = 4096  # rows allocated at least when a collector grows without a hint


@njit(cache=True, nogil=True)
def _prepare_batch(buf: np.ndarray, pos: np.ndarray, state: np.ndarray, log_out: np.ndarray,
                   row0: int) -> int:  # pragma: no cover - compiled
    """Log times of the Message records at ``pos`` into ``log_out[row0:]``; ``state`` 2 (the
    generic decoder) for payloads shorter than a CDR header or not little-endian plain CDR
    (encapsulation bytes 0x00 0x01), 0 (not decoded yet) for the others.

    The records were framed by :func:`_walk_records`, so each lies wholly inside ``buf``
    when it is long enough for its log time; returns the index of the first that is not
    (its log time would overrun ``buf``), else -1.
    """
    for i in range(pos.shape[0]):
        p = pos[i]
        if p + 23 > buf.shape[0]:
            return i
        t = np.int64(0)
        ln = np.int64(0)
        for k in range(8):
            t |= np.int64(buf[p + 15 + k]) << np.int64(8 * k)
            ln |= np.int64(buf[p + 1 + k]) << np.int64(8 * k)
        log_out[row0 + i] = t
        s = p + 31  # opcode 1 + length 8 + channel 2 + sequence 4 + 2 x time 8
        if ln - 22 < 16 or buf[s] != 0 or buf[s + 1] != 1:
            state[i] = 2
        else:
            state[i] = 0
    return -1


@njit(cache=True, nogil=True)
def _decode_fixed(buf: np.ndarray, pos: np.ndarray, state: np.ndarray, frame_len: int,
                  itemsize: int, fast: bool, f_off: np.ndarray, outs: tuple,
                  time_out: np.ndarray, row0: int,
                  ref_frame: np.ndarray) -> tuple:  # pragma: no cover - compiled
    """Decode, in one pass, the pending (``state`` 0) messages whose frame_id length is
    ``frame_len``: each field ``j`` (``f_off[j]`` bytes into the payload, ``outs[j].shape[1]``
    bytes wide, little-endian) is copied into row ``row0 + i`` of ``outs[j]`` (uint8 views of
    the output arrays) and the header stamp ``sec * 1e9 + nanosec`` [ns] into ``time_out``;
    their ``state`` becomes 3. With ``fast`` False, or a payload length other than
    ``itemsize`` (the fixed layout's), ``state`` becomes 2 instead (the generic decoder).

    Returns (how many decoded messages have a frame_id other than ``ref_frame``, how many
    were decoded).
    """
    n_other = 0
    n_done = 0
    for i in range(pos.shape[0]):
        if state[i] != 0:
            continue
        p = pos[i]
        s = p + 31
        fl = np.int64(0)
        ln = np.int64(0)
        for k in range(4):
            fl |= np.int64(buf[s + 12 + k]) << np.int64(8 * k)
        if fl != frame_len:
            continue
        for k in range(8):
            ln |= np.int64(buf[p + 1 + k]) << np.int64(8 * k)
        if not fast or ln - 22 != itemsize:
            state[i] = 2
            continue
        row = row0 + i
        for j in range(len(outs)):
            o = outs[j]
            src = s + f_off[j]
            for k in range(o.shape[1]):
                o[row, k] = buf[src + k]
        sec = np.int64(0)
        nsec = np.int64(0)
        for k in range(4):
            sec |= np.int64(buf[s + 4 + k]) << np.int64(8 * k)
            nsec |= np.int64(buf[s + 8 + k]) << np.int64(8 * k)
        if sec >= 2**31:  # int32 seconds
            sec -= 2**32
        time_out[row] = sec * 1_000_000_000 + nsec
        for k in range(frame_len):
            if buf[s + 16 + k] != ref_frame[k]:
                n_other += 1
                break
        state[i] = 3
        n_done += 1
    return n_other, n_done


class Collector:
    """Accumulates the decoded messages of one topic into arrays grown as needed.

    The arrays are allocated once for the message count of the summary's Statistics record
    when it is known (:meth:`reserve`), else grown by doubling; rows are written in place by
    the compiled :func:`_decode_fixed`, so no per-batch blocks are kept and concatenated.
    """

    def __init__(self, topic: str, spec: Spec, path: str) -> None:
        self.topic = topic
        self.spec = spec
        self.path = path
        self.count = 0
        self.frame_ids: list[str] = []
        self.channels: dict[int, Schema | None] = {}
        self._decoders: dict[int, Callable[[bytes], Any]] = {}
        self._verified: dict[tuple[int, int], bool] = {}  # (channel, frame_len) -> fast ok
        self.slow_messages = 0
        self._hint = 0
        self._out: dict[str, np.ndarray] = {}
        self._views: tuple[np.ndarray, ...] = ()
        self._fast: dict[int, tuple] = {}  # channel -> checked (frame_len, size, offsets, frame)

    def reserve(self, n: int) -> None:
        """Expect ``n`` more messages (a channel's Statistics count): one allocation."""
        self._hint += max(int(n), 0)

    def _empty(self, n: int) -> dict[str, np.ndarray]:
        probe = _cdr_dtype(self.spec.layout, 1)
        assert probe.fields is not None  # a structured dtype
        res = {"time_ns": np.empty(n, np.int64), "log_time_ns": np.empty(n, np.int64)}
        for name in self.spec.wanted:
            ftype = probe.fields[name][0]
            base = ftype.base if ftype.subdtype else ftype
            res[name] = np.empty((n, *ftype.shape), base.newbyteorder("="))
        return res

    def _ensure(self, n: int) -> None:
        """Room for ``n`` more rows (kept rows copied when the arrays must grow)."""
        cap = len(self._out["time_ns"]) if self._out else 0
        if self.count + n <= cap:
            return
        new_cap = max(self.count + n, 2 * cap, _MIN_CAPACITY, self._hint if not cap else 0)
        new = self._empty(new_cap)
        for k, a in self._out.items():
            new[k][: self.count] = a[: self.count]
        self._out = new
        # one zero-width view when only the stamp is wanted (trigger events): the compiled
        # pass cannot type an empty tuple
        self._views = tuple(new[name].reshape(new_cap, -1).view(np.uint8)
                            for name in self.spec.wanted) or (np.zeros((new_cap, 0), np.uint8),)

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
        header = getattr(msg, "header", None)
        if header is None and hasattr(msg, "stamp") and hasattr(msg, "frame_id"):
            header = msg  # a std_msgs/Header published as the trigger itself
        if header is None:
            raise IngestError(f"{self.topic!r} messages have no std_msgs/Header (a stamped "
                              "message is expected)", file=self.path, topic=self.topic,
                              index=index)
        vals["time_ns"] = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        vals["frame_id"] = header.frame_id
        return vals

    # -- one batch of messages of one channel
    def add(self, channel_id: int, buf: np.ndarray, pos: np.ndarray) -> None:
        """Decode the Message records starting at ``pos`` (record offsets) in ``buf``.

        Little-endian plain CDR messages go through :func:`_decode_fixed`, one pass per
        frame_id length (one in the usual case), once their layout has been checked against
        the generic decoder (:meth:`_layout_ok`); the others through the generic decoder.
        """
        n = len(pos)
        self._ensure(n)
        row0 = self.count
        out = self._out
        state = np.empty(n, np.int8)
        if _prepare_batch(buf, pos, state, out["log_time_ns"], row0) >= 0:
            raise IndexError("a Message record too short for its log time ends the chunk")
        starts = pos + 31
        known = self._fast.get(channel_id)
        if known is not None:  # the layout of this channel's last batch, checked then
            if self._decode_known(buf, starts, pos, state, row0, *known) == n and _LITTLE_ENDIAN:
                self.count += n
                return
        pending = np.flatnonzero(state == 0)
        while pending.size:
            self._decode_pass(channel_id, buf, pos, starts, state, int(pending[0]), row0)
            pending = np.flatnonzero(state == 0)
        if not _LITTLE_ENDIAN:  # the fast path copied little-endian bytes
            done = row0 + np.flatnonzero((state == 1) | (state == 3))
            for name in self.spec.wanted:
                out[name][done] = out[name][done].byteswap()
        for i in np.flatnonzero(state == 2):
            s, ln = int(starts[i]), int(_REC(buf, int(pos[i]))[1]) - 22
            vals = self._decode_slow(channel_id, buf[s : s + ln].tobytes(), row0 + int(i))
            for name in self.spec.wanted:
                out[name][row0 + i] = vals[name]
            out["time_ns"][row0 + i] = vals["time_ns"]
            if vals["frame_id"] not in self.frame_ids:
                self.frame_ids.append(vals["frame_id"])
            self.slow_messages += 1
        self.count += n

    def _decode_pass(self, channel_id: int, buf: np.ndarray, pos: np.ndarray,
                     starts: np.ndarray, state: np.ndarray, i: int, row0: int) -> None:
        """Decode the pending messages with the frame_id length of message ``i`` (state 1),
        or hand them to the generic decoder (state 2) when that layout fails its check."""
        s = int(starts[i])
        fl = int.from_bytes(buf[s + 12 : s + 16].tobytes(), "little")
        dt = _cdr_dtype(self.spec.layout, fl) if fl >= 1 else None
        j = -1  # a message of this frame_id length and the layout's payload length
        if dt is not None:
            if _REC(buf, int(pos[i]))[1] - 22 == dt.itemsize:
                j = i
            else:
                same = np.flatnonzero(state == 0)
                same = same[_gather(buf, starts[same], 12, 4).view("<u4")[:, 0] == fl]
                plen = _gather(buf, pos[same], 1, 8).view("<u8")[:, 0].astype(np.int64) - 22
                hit = same[plen == dt.itemsize]
                j = int(hit[0]) if hit.size else -1
        if dt is None or j < 0 or not self._layout_ok(channel_id, buf, starts, j, dt):
            # the generic decoder for all pending messages of this frame_id length
            _decode_fixed(buf, pos, state, fl, 0, False, np.zeros(len(self._views),
                          np.int64), self._views, self._out["time_ns"], row0,
                          np.zeros(0, np.uint8))
            return
        assert dt.fields is not None  # a structured dtype
        off = np.array([dt.fields[f][1] for f in self.spec.wanted] or [0], np.int64)
        known = (fl, dt.itemsize, off, buf[int(starts[j]) + 16 : int(starts[j]) + 16 + fl].copy())
        self._fast[channel_id] = known
        self._decode_known(buf, starts, pos, state, row0, *known)

    def _decode_known(self, buf: np.ndarray, starts: np.ndarray, pos: np.ndarray,
                      state: np.ndarray, row0: int, fl: int, itemsize: int, off: np.ndarray,
                      ref_frame: np.ndarray) -> int:
        """:func:`_decode_fixed` with a checked layout; frame_ids noted. Returns the number
        of messages decoded."""
        n_other, n_done = _decode_fixed(buf, pos, state, fl, itemsize, True, off, self._views,
                                        self._out["time_ns"], row0, ref_frame)
        if n_done == len(pos) and not n_other:
            self._note_frame(ref_frame, 0, fl)
            return n_done
        mine = np.flatnonzero(state == 3)
        state[mine] = 1
        if n_other:  # several frame_ids: each noted, in sorted order
            for row in np.unique(_gather(buf, starts[mine], 16, fl), axis=0):
                self._note_frame(row, 0, fl)
        elif n_done:
            self._note_frame(ref_frame, 0, fl)
        return n_done

    def _note_frame(self, buf: np.ndarray, start: int, length: int) -> None:
        fid = buf[start : start + length].tobytes().rstrip(b"\x00").decode("utf-8", "replace")
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
        """The decoded fields, ``count`` rows each; the collector lets go of them.

        Rows past ``count`` (a Statistics count above what was read, or growth) were never
        written, so their pages are not resident; the arrays returned are views of the first
        ``count`` rows, not copies.
        """
        out = self._out or self._empty(0)
        self._out, self._views = {}, ()
        return {k: v[: self.count] for k, v in out.items()}


# --------------------------------------------------------------------------- streaming pass

# typed for any buffer: numpy's stubs give ndarray no ``__buffer__`` before Python 3.12
_REC: Callable[[Any, int], tuple[Any, ...]] = struct.Struct("<BQ").unpack_from
_U16 = struct.Struct("<H").unpack_from
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression len
# Statistics: message_count u64, schema_count u16, channel_count u32, attachment_count u32,
# metadata_count u32, chunk_count u32, message_start_time u64, message_end_time u64,
# channel_message_counts byte length u32 (then channel_id u16, count u64 pairs)
_STATS_HEAD = struct.Struct("<QHIIIIQQI")
_MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_FOOTER = 0x03, 0x04, 0x05, 0x06, 0x02
_OP_STATISTICS, _OP_DATA_END = 0x0B, 0x0F
_FOOTER_LEN = 20  # summary_start u64, summary_offset_start u64, summary_crc u32
_MAX_SUMMARY_BYTES = 64 * 1024 * 1024  # a larger summary section is not read for hints
_MAX_RATIO = 64  # no hint above 64 x (file bytes / 31-byte minimal Message record) messages

MAX_CHUNK_BYTES = 256 * 1024 * 1024
"""Default cap on one chunk's decompressed size [bytes] (``max_chunk_bytes``): a chunk whose
header claims more is corrupt (or written with huge chunks: raise the cap), and no chunk's
decompression may produce more than the smaller of this and what its header claims."""
_LZ4_PIECE = 16 * 1024 * 1024  # lz4 output produced at a time beyond the first call
_READ_PIECE = 1 << 20  # bytes read at a time when a byte range is only checksummed


@njit(cache=True, nogil=True)
def _walk_pass(buf: np.ndarray, msg_pos: np.ndarray, msg_ch: np.ndarray, meta_pos: np.ndarray,
               fill: bool) -> tuple:  # pragma: no cover - compiled
    """One walk of :func:`_walk_records`: counts only, or (``fill``) offsets written too."""
    n = buf.shape[0]
    n_msg = 0
    n_meta = 0
    pos: int | np.int64 = 0  # int64 once a record length is added
    while pos < n:
        if pos + 9 > n:
            return n_msg, n_meta, pos, 1
        ln = np.uint64(0)
        for k in range(8):
            ln |= np.uint64(buf[pos + 1 + k]) << np.uint64(8 * k)
        if ln > np.uint64(n - pos - 9):
            return n_msg, n_meta, pos, 1
        op = buf[pos]
        if op == 0x05:
            if pos + 11 > n:
                return n_msg, n_meta, pos, 1
            if fill:
                msg_pos[n_msg] = pos
                msg_ch[n_msg] = np.int64(buf[pos + 9]) | (np.int64(buf[pos + 10]) << 8)
            n_msg += 1
        elif op == 0x03 or op == 0x04:
            if fill:
                meta_pos[n_meta] = pos
            n_meta += 1
        elif op == 0:
            return n_msg, n_meta, pos, 2
        pos += 9 + np.int64(ln)
    return n_msg, n_meta, pos, 0


@njit(cache=True, nogil=True)
def _walk_records(buf: np.ndarray) -> tuple:  # pragma: no cover - compiled
    """Frame the records of ``buf`` (uint8): ``opcode u8, length u64, body`` each.

    Returns (message count, message record offsets, their channel ids, Schema/Channel count,
    their offsets, offset reached, status): status 0 when the walk ended exactly at the end,
    1 when a record overruns the buffer (or a Message is too short for its channel id) at
    the offset reached, 2 at a record with the reserved opcode 0 (zeros: a bomb's output
    or a hole are not walked). Two passes: the first counts, so that the offset arrays are
    allocated to size (not one slot per 9 bytes of the chunk).
    """
    none = np.empty(0, np.int64)
    n_msg, n_meta, _, _ = _walk_pass(buf, none, none, none, False)
    msg_pos = np.empty(n_msg, np.int64)
    msg_ch = np.empty(n_msg, np.int64)
    meta_pos = np.empty(n_meta, np.int64)
    n_msg, n_meta, pos, status = _walk_pass(buf, msg_pos, msg_ch, meta_pos, True)
    return n_msg, msg_pos, msg_ch, n_meta, meta_pos, pos, status


class _Truncated(Exception):
    """The file ends inside a record or before the Footer."""


@dataclass(frozen=True)
class _RawChunk:
    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data: bytes | memoryview
    truncated: bool


@dataclass(frozen=True)
class _Stats:
    """The summary section's Statistics record (the fields pospp checks)."""

    message_count: int
    start_ns: int
    end_ns: int
    per_channel: dict[int, int]
    offset: int


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
    data = memoryview(body)[p + 8 : p + 8 + dlen]  # not a copy of the compressed records
    return _RawChunk(start, end, usize, crc, comp, data, truncated or len(data) < dlen)


def _parse_stats(body: bytes, offset: int) -> _Stats:
    if len(body) < _STATS_HEAD.size:
        raise ValueError(f"Statistics record of {len(body)} bytes is too short")
    count, _, _, _, _, _, start, end, clen = _STATS_HEAD.unpack_from(body, 0)
    p = _STATS_HEAD.size
    if clen % 10 or p + clen > len(body):
        raise ValueError(f"Statistics channel counts of {clen} bytes do not fit the record")
    per_channel = dict(struct.iter_unpack("<HQ", body[p : p + clen]))
    return _Stats(count, start, end, per_channel, offset)


def _count_hints(f: Any, size: int) -> dict[int, int]:
    """Per-channel message counts of the summary's Statistics record, as allocation hints.

    Read before the data (Footer at the end -> summary section -> Statistics); any doubt
    (no Footer, no Statistics, unreadable records) gives no hints, and the collectors then
    grow their arrays as they go. Only sizes depend on these numbers, never what is read;
    the counts are checked against the data at the end (:meth:`Scan._check_statistics`).
    """
    tail_len = 9 + _FOOTER_LEN + len(_MAGIC)
    if size < len(_MAGIC) + tail_len:
        return {}
    try:
        f.seek(size - tail_len)
        tail = f.read(tail_len)
        if tail[-len(_MAGIC):] != _MAGIC or _REC(tail, 0) != (_OP_FOOTER, _FOOTER_LEN):
            return {}
        start, footer_at = struct.unpack_from("<Q", tail, 9)[0], size - tail_len
        if not len(_MAGIC) <= start < footer_at or footer_at - start > _MAX_SUMMARY_BYTES:
            return {}
        f.seek(start)
        data = f.read(footer_at - start)
        pos = 0
        while pos + 9 <= len(data):
            op, ln = _REC(data, pos)
            if op == _OP_STATISTICS:
                cap = _MAX_RATIO * size // 31
                counts = _parse_stats(data[pos + 9 : pos + 9 + ln], start + pos).per_channel
                return {ch: min(n, cap) for ch, n in counts.items()}
            pos += 9 + ln
        return {}
    except (ValueError, struct.error):
        return {}
    finally:
        f.seek(len(_MAGIC))


def _lz4_bounded(data: bytes | memoryview, limit: int) -> bytes | bytearray:
    """Decompress an lz4 frame, producing at most ``limit + 1`` bytes (one more than allowed,
    so that the caller sees an overrun); the readable part of a cut-off frame is returned."""
    import lz4.frame

    dec = lz4.frame.LZ4FrameDecompressor()
    first = dec.decompress(data, max_length=min(limit + 1, _LZ4_PIECE))
    if dec.eof or dec.needs_input or len(first) > limit:
        return first
    out = bytearray(first)  # grows in place (realloc), not by doubling copies
    while len(out) <= limit and not (dec.eof or dec.needs_input):
        out += dec.decompress(b"", max_length=min(limit + 1 - len(out), _LZ4_PIECE))
    return out


def _decompress(chunk: _RawChunk,
                max_bytes: int = MAX_CHUNK_BYTES) -> bytes | bytearray | memoryview:
    """Chunk records; for a truncated chunk, as many bytes as can be decompressed.

    Memory is bounded: a header claiming more than ``max_bytes`` is rejected before anything
    is decompressed, and decompression stops one byte past what the header claims (zstd
    through a bounded ``stream_reader.read``, lz4 through ``max_length``), so a chunk that
    would inflate to gigabytes costs at most ``max_bytes`` (lz4: plus 32 MiB of pieces).
    """
    usize = chunk.uncompressed_size
    if usize > max_bytes:
        raise ValueError(f"chunk claims {usize} uncompressed bytes, over the cap of {max_bytes} "
                         "(max_chunk_bytes; a corrupt header, or raise the cap)")
    data: bytes | bytearray | memoryview
    if chunk.compression == "zstd":
        import zstandard

        declared = zstandard.frame_content_size(chunk.data) if len(chunk.data) >= 18 else -1
        if not chunk.truncated and declared not in (-1, usize):
            raise ValueError(f"zstd frame declares {declared} bytes, chunk header {usize}")
        if not chunk.truncated and declared == usize and usize > 0:
            data = zstandard.ZstdDecompressor().decompress(chunk.data)  # allocates usize
        else:  # no size in the frame, or cut off: read at most usize + 1 bytes
            reader = zstandard.ZstdDecompressor().stream_reader(chunk.data,
                                                                 read_across_frames=False)
            data = reader.read(usize + 1)
    elif chunk.compression == "lz4":
        data = _lz4_bounded(chunk.data, usize)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
    if len(data) > usize:
        raise ValueError(f"chunk decompresses to more than the {usize} bytes its header claims")
    if chunk.truncated:
        return data
    if len(data) != usize:
        raise ValueError(f"chunk decompressed to {len(data)} bytes, header says {usize}")
    if chunk.crc != 0 and zlib.crc32(data) != chunk.crc:
        raise ValueError("chunk CRC mismatch")
    return data


def log_time_text(ns: int | None, first_ns: int | None = None) -> str:
    """``2024-06-01T00:27:14.120Z`` (UTC) for an MCAP log time [ns], with the seconds since
    ``first_ns`` when given."""
    if ns is None:
        return "no message read"
    iso = np.datetime_as_string(np.datetime64(int(ns) // 1_000_000, "ms"), unit="ms")
    if first_ns is None:
        return f"{iso}Z"
    return f"{iso}Z ({(int(ns) - int(first_ns)) * 1e-9:.1f} s after the first message)"


class Scan:
    """One streaming pass over the file, dispatching messages to collectors by topic.

    Records are framed here (opcode, length) rather than by ``mcap``'s ``StreamReader``, so
    that index records are skipped unparsed and a truncated last chunk is still decompressed
    as far as it goes. ``complete`` ends True only when the Footer is found at the very end
    (followed by the closing magic), no chunk was skipped, the DataEnd's data-section CRC
    (when non-zero) matches, and the summary's Statistics (when present and not corrupt)
    agree with the message counts read on the channels of the collected topics.
    """

    def __init__(self, path: str, collectors: dict[str, Collector], *,
                 max_chunk_bytes: int = MAX_CHUNK_BYTES) -> None:
        self.path = path
        self.by_topic = collectors
        self.max_chunk_bytes = int(max_chunk_bytes)
        self.schemas: dict[int, Schema] = {}
        self.topics: dict[str, str] = {}  # topic -> schema name
        self.route: dict[int, Collector | None] = {}
        self.issues: list[IngestIssue] = []
        self.complete = False  # reached the Footer with no chunk skipped
        self.damaged = False  # data known missing or altered (a chunk skipped, a CRC, counts)
        self.data_end = False  # the DataEnd record (end of the data section) was read
        self.last_log_time_ns: int | None = None
        self.first_log_time_ns: int | None = None
        self.read_counts: dict[int, int] = {}  # channel id -> Message records framed
        self.stats: _Stats | None = None
        self._loose: list[bytes] = []
        self._after_data_end_noted = False
        self._hints: dict[int, int] = {}  # channel id -> Statistics message count

    # -- issues
    def _when(self) -> str:
        return log_time_text(self.last_log_time_ns, self.first_log_time_ns)

    def _error(self, message: str, offset: int, *, log_time_ns: int | None = None,
               time_ns: int | None = None) -> None:
        self.damaged = True
        self.issues.append(IngestIssue(
            "error", self.path, None, None, time_ns, message,
            log_time_ns=self.last_log_time_ns if log_time_ns is None else log_time_ns,
            byte_offset=offset,
        ))

    def _warning(self, message: str, offset: int) -> None:
        self.issues.append(IngestIssue(
            "warning", self.path, None, None, None, message,
            log_time_ns=self.last_log_time_ns, byte_offset=offset,
        ))

    # -- records
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
            if got != col.spec.type_name and not (col.spec.any_stamped and schema is not None):
                raise IngestError(
                    f"topic {rec.topic!r} has schema {got!r}, expected {col.spec.type_name!r}",
                    file=self.path, topic=rec.topic,
                )
            assert schema is not None  # "<no schema>" raised above
            if rec.message_encoding != "cdr" or schema.encoding != "ros2msg":
                raise IngestError(
                    f"topic {rec.topic!r} is {rec.message_encoding!r} / {schema.encoding!r}, "
                    "expected 'cdr' messages with a 'ros2msg' schema",
                    file=self.path, topic=rec.topic,
                )
            col.channels[rec.id] = schema
            col.reserve(self._hints.get(rec.id, 0))
        self.route[rec.id] = col

    def _meta(self, op: int, body: bytes | bytearray | memoryview) -> None:
        stream = ReadDataStream(BytesIO(body))
        try:
            rec = Schema.read(stream) if op == _OP_SCHEMA else Channel.read(stream)
        except McapError as exc:  # EndOfFile: the fields overrun the record
            what = "Schema" if op == _OP_SCHEMA else "Channel"
            raise ValueError(f"{what} record of {len(body)} bytes unreadable "
                             f"({type(exc).__name__})") from exc
        if op == _OP_SCHEMA:
            self._schema(rec)
        else:
            self._channel(rec)

    def _records(self, buf: bytes | bytearray | memoryview, *, partial: bool = False) -> int:
        """Walk the records of a decompressed chunk (or a block of loose messages).

        The framing is one compiled pass (:func:`_walk_records`); Schema and Channel records
        are then read in order, and the messages dispatched by channel. With ``partial`` (a
        truncated chunk), stop quietly at the first incomplete record. Returns the number of
        bytes walked.
        """
        arr = np.frombuffer(buf, dtype=np.uint8)
        n_msg, msg_pos, msg_ch, n_meta, meta_pos, pos, err = _walk_records(arr)
        for p in meta_pos[:n_meta].tolist():
            self._meta(buf[p], buf[p + 9 : p + 9 + _REC(buf, p)[1]])
        if err and not partial:
            raise ValueError(f"record overruns the chunk at offset {pos}" if err == 1 else
                             f"record with the reserved opcode 0x00 at offset {pos}")
        msg_pos, msg_ch = msg_pos[:n_msg], msg_ch[:n_msg]
        if n_msg == 0:
            return pos
        chans = np.flatnonzero(np.bincount(msg_ch))  # channel ids are u16
        if len(chans) > 1:  # in order of first appearance
            chans = chans[np.argsort([int(np.argmax(msg_ch == c)) for c in chans])]
        for ch in chans.tolist():
            if ch not in self.route:
                raise ValueError(f"message on channel {ch} before its Channel record")
            p = msg_pos if len(chans) == 1 else msg_pos[msg_ch == ch]
            self.read_counts[ch] = self.read_counts.get(ch, 0) + len(p)
            col = self.route[ch]
            if col is None:
                continue
            col.add(ch, arr, p)
            first_t = struct.unpack_from("<Q", buf, int(p[0]) + 15)[0]
            last_t = struct.unpack_from("<Q", buf, int(p[-1]) + 15)[0]
            self.first_log_time_ns = min(self.first_log_time_ns or first_t, first_t)
            self.last_log_time_ns = max(self.last_log_time_ns or 0, last_t)
        return pos

    def _flush_loose(self) -> None:
        if self._loose:
            buf = b"".join(self._loose)
            self._loose = []
            self._records(buf)

    @staticmethod
    def _crc_of(f: Any, start: int, stop: int) -> int:
        """CRC-32 of the file's bytes [start, stop), read in pieces; the position is kept."""
        here = f.tell()
        f.seek(start)
        crc, n = 0, stop - start
        while n > 0:
            b = f.read(min(n, _READ_PIECE))
            if not b:
                break
            crc, n = zlib.crc32(b, crc), n - len(b)
        f.seek(here)
        return crc

    def run(self) -> None:
        size = Path(self.path).stat().st_size
        with open(self.path, "rb") as f:
            if f.read(8) != _MAGIC:
                raise IngestError("not an MCAP file (bad magic bytes)", file=self.path)
            self._hints = _count_hints(f, size)
            good = 8
            try:
                while True:
                    head = f.read(9)
                    if len(head) < 9:
                        raise _Truncated("file ends without a Footer record")
                    op, ln = _REC(head, 0)
                    if op in (_OP_CHUNK, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_STATISTICS):
                        if self.data_end and op in (_OP_CHUNK, _OP_MESSAGE):
                            self._data_after_data_end(op, good)
                        body = f.read(min(ln, size - f.tell()))  # a corrupt length
                        # must not allocate more than the file holds
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
                        elif op == _OP_STATISTICS and self.data_end:
                            self.stats = _parse_stats(body, good)
                        elif op == _OP_STATISTICS:  # a summary record in the data section
                            self._error(f"MCAP corrupt: Statistics record at byte {good} before "
                                        f"the DataEnd record (a corrupt opcode?); skipped its {ln} "
                                        f"bytes and read on (log time reached {self._when()})",
                                        good)
                        else:
                            self._meta(op, body)
                        if short:
                            raise _Truncated("chunk cut off (decoded what it held)")
                    elif op == _OP_FOOTER and self._footer_at_end(f, good, ln, size):
                        self._flush_loose()
                        self._check_statistics()
                        self.complete = not self.damaged
                        return
                    else:
                        if good + 9 + ln > size:
                            raise _Truncated("record cut off")
                        if op == _OP_FOOTER:
                            self._flush_loose()
                            self._misplaced_footer(good, ln, size)
                            f.seek(ln, 1)
                        elif op == _OP_DATA_END:
                            self._flush_loose()
                            self._data_end(f, f.read(ln), good)
                        else:
                            f.seek(ln, 1)
                    good = f.tell()
            except IngestError:
                raise
            except (_Truncated, ValueError, struct.error, UnicodeDecodeError, IndexError) as exc:
                try:
                    self._flush_loose()
                except (ValueError, struct.error):
                    self._loose = []
                if self.data_end:  # only the summary (index) section is damaged
                    self._warning(
                        f"MCAP summary section cut off or corrupt after byte {good} of {size} "
                        f"({exc}); the data section ended properly, all messages were read",
                        good,
                    )
                    self._check_statistics()
                    self.complete = not self.damaged
                    return
                self._error(
                    f"MCAP truncated or corrupt after byte {good} of {size} ({exc}); kept "
                    f"the messages read before it (log time reached {self._when()}; last good "
                    f"log time {self.last_log_time_ns} ns)", good,
                )

    def _footer_at_end(self, f: Any, offset: int, ln: int, size: int) -> bool:
        """A Footer is the last record, followed by the closing magic and nothing else.

        When it is, checks the summary CRC (a mismatch: warning, the Statistics not used) and
        returns True; otherwise leaves the file position after the record header.
        """
        end = offset + 9 + ln
        if ln < _FOOTER_LEN or end + len(_MAGIC) != size:
            return False
        body = f.read(ln)
        if f.read(len(_MAGIC)) != _MAGIC:
            f.seek(offset + 9)
            return False
        summary_start, _, summary_crc = struct.unpack_from("<QQI", body, 0)
        if summary_crc and self.data_end and summary_start:
            if summary_start > offset:
                self._summary_unusable(f"Footer's summary_start {summary_start} is outside the "
                                       "file", offset)
                return True
            crc = self._crc_of(f, summary_start, offset + 9 + 16)  # to summary_offset_start
            if crc != summary_crc:
                self._summary_unusable(f"summary CRC mismatch (Footer says {summary_crc:#010x}, "
                                       f"the bytes give {crc:#010x})", summary_start)
        return True

    def _summary_unusable(self, why: str, offset: int) -> None:
        self.stats = None
        self._warning(f"MCAP summary section corrupt: {why}; its Statistics are not used to "
                      "check the data (the data section ended properly)", offset)

    def _misplaced_footer(self, offset: int, ln: int, size: int) -> None:
        text = (f"Footer record at byte {offset} of {size} is not at the end of the file (a "
                f"corrupt opcode?); skipped its {ln} bytes and read on (log time reached "
                f"{self._when()})")
        if self.data_end:
            self._warning(f"MCAP summary section corrupt: {text}", offset)
        else:
            self._error(f"MCAP corrupt: {text}", offset)

    def _data_after_data_end(self, op: int, offset: int) -> None:
        if not self._after_data_end_noted:
            self._after_data_end_noted = True
            what = "Chunk" if op == _OP_CHUNK else "Message"
            self._error(f"MCAP corrupt: {what} record at byte {offset} after the DataEnd record "
                        f"(a corrupt opcode?); read on (log time reached {self._when()})", offset)

    def _data_end(self, f: Any, body: bytes, offset: int) -> None:
        """DataEnd: the data-section CRC (when non-zero) must match the bytes before it.

        The CRC is computed only when the record carries one, by reading the data section a
        second time (from the page cache: about 2 % of the decode time, docs/benchmarks.md).
        """
        if self.data_end:
            self._error(f"MCAP corrupt: a second DataEnd record at byte {offset} (log time "
                        f"reached {self._when()})", offset)
        self.data_end = True
        want = struct.unpack_from("<I", body, 0)[0] if len(body) >= 4 else 0
        crc_before = self._crc_of(f, 0, offset) if want else 0
        if want and want != crc_before:
            self._error(f"MCAP data section CRC mismatch: DataEnd at byte {offset} says "
                        f"{want:#010x}, the {offset} bytes before it give {crc_before:#010x} "
                        "(some record of the data section is altered)", offset)

    def _check_statistics(self) -> None:
        """Message counts of the summary's Statistics against those framed in the data.

        Per channel for the channels of the collected topics when the record has per-channel
        counts, else the total over all channels. Counts are of Message records as framed, so
        GNSS messages dropped later (duplicate stamps, NO_FIX) do not enter.
        """
        s = self.stats
        if s is None:
            return
        wrong: list[str] = []
        if s.per_channel:
            for ch, col in sorted(self.route.items()):
                if col is None:
                    continue
                want, got = s.per_channel.get(ch, 0), self.read_counts.get(ch, 0)
                if want != got:
                    wrong.append(f"{want} messages on {col.topic}, read {got}")
        else:
            want, got = s.message_count, sum(self.read_counts.values())
            if want != got:
                wrong.append(f"{want} messages in all, read {got}")
        if wrong:
            self._error(
                f"MCAP data missing: the summary's Statistics say {'; '.join(wrong)} (messages "
                f"from {log_time_text(s.start_ns)} to {log_time_text(s.end_ns)}, read to "
                f"{self._when()})", s.offset,
            )

    def _chunk(self, chunk: _RawChunk, offset: int) -> None:
        try:
            data = _decompress(chunk, self.max_chunk_bytes)
            self._records(data, partial=chunk.truncated)
        except (IngestError, NumbaError):
            raise  # a compiled pass that fails is pospp's error, not a corrupt chunk
        except Exception as exc:  # noqa: BLE001 - zstd/lz4 errors have their own classes
            if chunk.truncated:
                raise _Truncated(f"chunk cut off and undecodable: {exc}") from exc
            cause = str(exc) if isinstance(exc, ValueError | struct.error | IndexError) else (
                f"{type(exc).__name__}: {exc}")
            self._error(
                f"corrupt chunk at byte {offset} skipped (log times "
                f"{chunk.start_ns}..{chunk.end_ns} ns): {cause}",
                offset, log_time_ns=chunk.start_ns, time_ns=chunk.start_ns,
            )
