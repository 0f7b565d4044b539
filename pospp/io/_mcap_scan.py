"""Single-pass MCAP scanning and batched CDR decoding for :mod:`pospp.io.mcap_reader`.

Private module: the file's record framing, chunk decompression, CRCs and summary checks behind
``read_flight_log``; the compiled (numba) framing of each decompressed chunk and the batched
decoding of its messages are in :mod:`pospp.io._mcap_decode`. pospp frames records itself
rather than iterating with ``mcap.reader.make_reader(...).iter_messages()`` (one Python
``Message`` per record; docs/formats.md "Why a hand-written framing"); chunk CRCs,
compression and the Schema/Channel records are handled with ``mcap.records`` and the
``zstandard`` / ``lz4`` codecs.

Layout of the bytes walked here (MCAP specification, https://mcap.dev/spec): every record is
``opcode u8, length u64, body``; a Message body is ``channel_id u16, sequence u32, log_time u64,
publish_time u64, data``; a Chunk body is ``message_start_time u64, message_end_time u64,
uncompressed_size u64, uncompressed_crc u32, compression string, records_length u64, records``.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from io import BytesIO
from typing import Any

import numpy as np
from isal.isal_zlib import crc32  # zlib's CRC-32, 10x faster (README)
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.records import Channel, Schema
from numba.core.errors import NumbaError

from pospp.io._mcap_chunk import (
    MAX_CHUNK_BYTES,
    RawChunk,
    Truncated,
    decompress,
    is_corrupt_data_error,
    parse_chunk,
)
from pospp.io._mcap_decode import RECORD_HEAD, Collector, walk_records
from pospp.io.errors import IngestError, IngestIssue
from pospp.io.files import open_regular

# --------------------------------------------------------------------------- streaming pass

_U16 = struct.Struct("<H").unpack_from
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

DECODED_PER_FILE_BYTE = 64
"""Largest decoded size per byte of the file: the decoded arrays of a log may take at most
this many times its size (and at least :data:`MIN_DECODED_BYTES`); legitimate logs decode to
1-6 x, decompression bombs to thousands (docs/decisions.md, docs/formats.md)."""
MIN_DECODED_BYTES = 64 * 1024 * 1024
_READ_PIECE = 1 << 20  # bytes read at a time when a byte range is only checksummed



@dataclass(frozen=True)
class _Stats:
    """The summary section's Statistics record (the fields pospp checks)."""

    message_count: int
    start_ns: int
    end_ns: int
    per_channel: dict[int, int]
    offset: int


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
        if tail[-len(_MAGIC):] != _MAGIC or RECORD_HEAD(tail, 0) != (_OP_FOOTER, _FOOTER_LEN):
            return {}
        start, footer_at = struct.unpack_from("<Q", tail, 9)[0], size - tail_len
        if not len(_MAGIC) <= start < footer_at or footer_at - start > _MAX_SUMMARY_BYTES:
            return {}
        f.seek(start)
        data = f.read(footer_at - start)
        pos = 0
        while pos + 9 <= len(data):
            op, ln = RECORD_HEAD(data, pos)
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
        self.decoded_bytes = 0  # what the collectors' arrays hold so far
        self.max_decoded_bytes = MIN_DECODED_BYTES  # set from the file size by run()

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

        The framing is one compiled pass (:func:`walk_records`); Schema and Channel records
        are then read in order, and the messages dispatched by channel. With ``partial`` (a
        truncated chunk), stop quietly at the first incomplete record. Returns the number of
        bytes walked.
        """
        arr = np.frombuffer(buf, dtype=np.uint8)
        n_msg, msg_pos, msg_ch, n_meta, meta_pos, pos, err = walk_records(arr)
        for p in meta_pos[:n_meta].tolist():
            self._meta(buf[p], buf[p + 9 : p + 9 + RECORD_HEAD(buf, p)[1]])
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
            self._budget(col, len(p))
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
            crc, n = crc32(b, crc), n - len(b)
        f.seek(here)
        return crc

    def run(self) -> None:
        with open_regular(self.path) as f:
            size = os.fstat(f.fileno()).st_size
            self.max_decoded_bytes = max(MIN_DECODED_BYTES, DECODED_PER_FILE_BYTE * size)
            if f.read(8) != _MAGIC:
                raise IngestError("not an MCAP file (bad magic bytes)", file=self.path)
            self._hints = _count_hints(f, size)
            good = 8
            try:
                while True:
                    head = f.read(9)
                    if len(head) < 9:
                        raise Truncated("file ends without a Footer record")
                    op, ln = RECORD_HEAD(head, 0)
                    if op in (_OP_CHUNK, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_STATISTICS):
                        if self.data_end and op in (_OP_CHUNK, _OP_MESSAGE):
                            self._data_after_data_end(op, good)
                        body = f.read(min(ln, size - f.tell()))  # a corrupt length
                        # must not allocate more than the file holds
                        short = len(body) < ln
                        if op == _OP_CHUNK:
                            self._flush_loose()
                            self._chunk(parse_chunk(body, short), good)
                        elif short:
                            raise Truncated("record cut off")
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
                            raise Truncated("chunk cut off (decoded what it held)")
                    elif op == _OP_FOOTER and self._footer_at_end(f, good, ln, size):
                        self._flush_loose()
                        self._check_statistics()
                        self.complete = not self.damaged
                        return
                    else:
                        if good + 9 + ln > size:
                            raise Truncated("record cut off")
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
            except (Truncated, ValueError, struct.error, UnicodeDecodeError, IndexError) as exc:
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

    def _chunk(self, chunk: RawChunk, offset: int) -> None:
        try:
            data = decompress(chunk, self.max_chunk_bytes)
            self._records(data, partial=chunk.truncated)
            if chunk.overstated_by:
                self._overstated(chunk, offset)
        except (IngestError, NumbaError):
            raise  # a compiled pass that fails is pospp's error, not a corrupt chunk
        except Exception as exc:  # noqa: BLE001 - zstd/lz4 errors have their own classes
            if not is_corrupt_data_error(exc):
                raise  # a TypeError or AttributeError is pospp's bug, not the file's
            if chunk.truncated:
                raise Truncated(f"chunk cut off and undecodable: {exc}") from exc
            cause = str(exc) if isinstance(exc, ValueError | struct.error | IndexError) else (
                f"{type(exc).__name__}: {exc}")
            self._error(
                f"corrupt chunk at byte {offset} skipped (log times "
                f"{chunk.start_ns}..{chunk.end_ns} ns): {cause}",
                offset, log_time_ns=chunk.start_ns, time_ns=chunk.start_ns,
            )

    def _overstated(self, chunk: RawChunk, offset: int) -> None:
        """A chunk whose ``records_length`` claims more than its record holds, and whose
        records passed the size check: kept. With a CRC that matched, the records are intact
        (a warning); without one (CRC 0), nothing vouches for them (an error issue: the file
        is damaged, ``complete`` False)."""
        text = (f"chunk at byte {offset}: its records_length claims {chunk.overstated_by} bytes "
                f"more than the record holds (a corrupt header); the {len(chunk.data)} bytes "
                "of records present")
        if chunk.crc:
            self._warning(f"MCAP {text} match the chunk's size and CRC: kept", offset)
        else:
            self._error(f"MCAP corrupt: {text} match the chunk's size but it has no CRC to "
                        "check them against: kept, unverified", offset,
                        log_time_ns=chunk.start_ns, time_ns=chunk.start_ns)

    def _budget(self, col: Collector, n: int) -> None:
        """Count ``n`` more messages of ``col`` against the decoded-size budget; beyond it, the
        file is refused (an :class:`IngestError`, one line) before they are decoded."""
        self.decoded_bytes += n * col.row_bytes
        if self.decoded_bytes > self.max_decoded_bytes:
            raise IngestError(
                f"the messages decode to more than {DECODED_PER_FILE_BYTE} times the file's "
                f"size ({self.max_decoded_bytes / 2**20:.0f} MiB of samples; stopped in "
                f"{col.topic!r} at log time {self._when()}): a decompression bomb or a corrupt "
                "file, refused", file=self.path, topic=col.topic)
