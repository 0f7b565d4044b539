"""Single-pass MCAP scanning and batched CDR decoding for :mod:`pospp.io.mcap_reader`.

Private module: the record framing, chunk decompression and numpy decoding behind
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

_GATHER_BATCH = 16384  # messages gathered at a time (bounds the index array to ~100 MB)

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


class Collector:
    """Accumulates the decoded messages of one topic, block by block."""

    def __init__(self, topic: str, spec: Spec, path: str) -> None:
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
        """All blocks concatenated (one concatenate per field, not per block).

        Consumes the blocks: each field's blocks are released as soon as that field is
        concatenated, so the peak is the data plus one field, not twice the data.
        """
        if not self.blocks:
            probe = rm.cdr_dtype(self.spec.layout, 1)
            res = {"time_ns": np.zeros(0, np.int64), "log_time_ns": np.zeros(0, np.int64)}
            for name in self.spec.wanted:
                ftype = probe.fields[name][0]
                base = ftype.base if ftype.subdtype else ftype
                res[name] = np.zeros((0, *ftype.shape), base.newbyteorder("="))
            return res
        keys = list(self.blocks[0])
        out = {k: np.concatenate([b.pop(k) for b in self.blocks]) for k in keys}
        self.blocks = []
        return out


# --------------------------------------------------------------------------- streaming pass

_REC = struct.Struct("<BQ").unpack_from
_U16 = struct.Struct("<H").unpack_from
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression len
_MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_FOOTER = 0x03, 0x04, 0x05, 0x06, 0x02
_OP_DATA_END = 0x0F


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


_MAX_CHUNK_BYTES = 1 << 32  # the mcap library's own record size limit (4 GiB)


def _decompress(chunk: _RawChunk) -> bytes:
    """Chunk records; for a truncated chunk, as many bytes as can be decompressed."""
    if chunk.uncompressed_size > _MAX_CHUNK_BYTES:
        raise ValueError(f"chunk claims {chunk.uncompressed_size} uncompressed bytes (corrupt "
                         "header?)")
    if chunk.compression == "zstd":
        import zstandard

        if chunk.truncated:
            data = zstandard.ZstdDecompressor().decompressobj().decompress(chunk.data)
        else:
            declared = zstandard.frame_content_size(chunk.data)  # -1: not in the frame header
            if declared not in (-1, chunk.uncompressed_size):
                raise ValueError(f"zstd frame declares {declared} bytes, chunk header "
                                 f"{chunk.uncompressed_size}")
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


class Scan:
    """One streaming pass over the file, dispatching messages to collectors by topic.

    Records are framed here (opcode, length) rather than by ``mcap``'s ``StreamReader``, so
    that index records are skipped unparsed and a truncated last chunk is still decompressed
    as far as it goes.
    """

    def __init__(self, path: str, collectors: dict[str, Collector]) -> None:
        self.path = path
        self.by_topic = collectors
        self.schemas: dict[int, Schema] = {}
        self.topics: dict[str, str] = {}  # topic -> schema name
        self.route: dict[int, Collector | None] = {}
        self.issues: list[IngestIssue] = []
        self.complete = False  # reached the Footer with no chunk skipped
        self.damaged = False  # a corrupt chunk was skipped
        self.data_end = False  # the DataEnd record (end of the data section) was read
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
                        else:
                            self._meta(op, body)
                        if short:
                            raise _Truncated("chunk cut off (decoded what it held)")
                    elif op == _OP_FOOTER:
                        self._flush_loose()
                        self.complete = not self.damaged
                        return
                    elif op == _OP_DATA_END:
                        self._flush_loose()
                        self.data_end = True
                        f.seek(ln, 1)
                    else:
                        if good + 9 + ln > size:
                            raise _Truncated("record cut off")
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
                    self.complete = not self.damaged
                    self.issues.append(IngestIssue(
                        "warning", self.path, None, None, None,
                        f"MCAP summary section cut off or corrupt after byte {good} of {size} "
                        f"({exc}); the data section ended properly, all messages were read",
                        log_time_ns=self.last_log_time_ns, byte_offset=good,
                    ))
                    return
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
        except (ValueError, struct.error, IndexError) as exc:
            if chunk.truncated:
                raise _Truncated(f"chunk cut off and undecodable: {exc}") from exc
            self.damaged = True
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
            self.damaged = True
            self.issues.append(
                IngestIssue(
                    "error", self.path, None, None, chunk.start_ns,
                    f"corrupt chunk at byte {offset} skipped: {type(exc).__name__}: {exc}",
                    log_time_ns=chunk.start_ns, byte_offset=offset,
                )
            )
