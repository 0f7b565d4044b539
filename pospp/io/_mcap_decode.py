"""Record framing and batched CDR decoding of MCAP records in memory (:mod:`pospp.io._mcap_scan`).

Private module: the topic specs (:class:`Spec`), the compiled (numba) kernels that frame the
records of a decompressed chunk (:func:`walk_records`) and decode its Message payloads in
place (:func:`_prepare_batch`, :func:`_decode_fixed`), and the per-topic :class:`Collector`
that owns the decoded arrays. Everything here works on a uint8 buffer already in memory; the
file itself (magic, chunks, decompression, CRCs, summary section) is read by
:class:`pospp.io._mcap_scan.Scan`.

Layout of the bytes (MCAP specification, https://mcap.dev/spec): every record is
``opcode u8, length u64, body``; a Message body is ``channel_id u16, sequence u32, log_time u64,
publish_time u64, data``, the data a CDR payload (encapsulation header, then the fields).
"""

from __future__ import annotations

import functools
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from numba import njit

from pospp.io import ros_messages as rm
from pospp.io.errors import IngestError

_LITTLE_ENDIAN = sys.byteorder == "little"
# typed for any buffer: numpy's stubs give ndarray no ``__buffer__`` before Python 3.12
RECORD_HEAD: Callable[[Any, int], tuple[Any, ...]] = struct.Struct("<BQ").unpack_from
"""``RECORD_HEAD(buf, offset) -> (opcode, length)``: an MCAP record's header (u8, u64 LE)."""

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


# --------------------------------------------------------------------------- record framing


@njit(cache=True, nogil=True)
def _walk_pass(buf: np.ndarray, msg_pos: np.ndarray, msg_ch: np.ndarray, meta_pos: np.ndarray,
               fill: bool) -> tuple:  # pragma: no cover - compiled
    """One walk of :func:`walk_records`: counts only, or (``fill``) offsets written too."""
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
def walk_records(buf: np.ndarray) -> tuple:  # pragma: no cover - compiled
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

    The records were framed by :func:`walk_records`, so each lies wholly inside ``buf``
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
        self._row_bytes: int | None = None

    @property
    def row_bytes(self) -> int:
        """Bytes one decoded message takes in this collector's arrays (stamps, fields)."""
        if self._row_bytes is None:
            self._row_bytes = sum(v.itemsize * int(np.prod(v.shape[1:], dtype=np.int64))
                                  for v in self._empty(0).values())
        return self._row_bytes

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
            s, ln = int(starts[i]), int(RECORD_HEAD(buf, int(pos[i]))[1]) - 22
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
            if RECORD_HEAD(buf, int(pos[i]))[1] - 22 == dt.itemsize:
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
