"""Chunk records of an MCAP file: parsing the header, bounded decompression, CRC and sizes.

Private module of :mod:`pospp.io._mcap_scan` (the streaming pass). A Chunk body is
``message_start_time u64, message_end_time u64, uncompressed_size u64, uncompressed_crc u32,
compression string, records_length u64, records`` (MCAP specification,
https://mcap.dev/spec). Decompression is bounded by the chunk header's size and by
``max_chunk_bytes``; a chunk's records are checked by size and CRC whenever the file holds
them whole, whatever its ``records_length`` claims.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from isal.isal_zlib import crc32  # zlib's CRC-32, 10x faster (README)
from mcap.exceptions import McapError

_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression len

MAX_CHUNK_BYTES = 256 * 1024 * 1024
"""Default cap on one chunk's decompressed size [bytes] (``max_chunk_bytes``): a chunk whose
header claims more is corrupt (or written with huge chunks: raise the cap), and no chunk's
decompression may produce more than the smaller of this and what its header claims."""
_LZ4_PIECE = 16 * 1024 * 1024  # lz4 output produced at a time beyond the first call


class Truncated(Exception):
    """The file ends inside a record or before the Footer."""


@dataclass(frozen=True)
class RawChunk:
    """One Chunk record's header fields and its (still compressed) records.

    ``start_ns`` / ``end_ns``: message_start_time / message_end_time [ns, log time];
    ``uncompressed_size`` [bytes] and ``crc`` (CRC-32 of the uncompressed records, 0: none)
    as the header claims them; ``compression``: "" (none), "lz4" or "zstd".
    """

    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data: bytes | memoryview
    truncated: bool
    """The file ends inside the chunk: ``data`` is what the file holds of its records."""
    overstated_by: int = 0
    """Bytes that ``records_length`` claims beyond the end of a whole Chunk record (its
    header is corrupt; the records present are still checked by size and CRC)."""


def parse_chunk(body: bytes, truncated: bool) -> RawChunk:
    """The :class:`RawChunk` of one Chunk record's body (layout in the module docstring).

    ``truncated``: the file ends inside this record. Raises :class:`Truncated` when the
    header itself is cut off.
    """
    if len(body) < _CHUNK_HEAD.size:
        raise Truncated("chunk header cut off")
    start, end, usize, crc, clen = _CHUNK_HEAD.unpack_from(body, 0)
    p = _CHUNK_HEAD.size
    comp = body[p : p + clen].decode("utf-8")
    p += clen
    (dlen,) = struct.unpack_from("<Q", body, p) if len(body) >= p + 8 else (None,)
    if dlen is None:
        raise Truncated("chunk header cut off")
    data = memoryview(body)[p + 8 : p + 8 + dlen]  # not a copy of the compressed records
    # records_length beyond a whole record is a corrupt header, not a cut file: the records
    # present are checked like any chunk's (size, CRC), never let through unchecked
    short = dlen - len(data)
    return RawChunk(start, end, usize, crc, comp, data, truncated and short > 0,
                     0 if truncated else short)


def _lz4_bounded(data: bytes | memoryview, limit: int) -> bytes | bytearray:
    """Decompress an lz4 frame, producing at most ``limit + 1`` bytes (one more than allowed,
    so that the caller sees an overrun); the readable part of a cut-off frame is returned."""
    import lz4.frame

    dec = lz4.frame.LZ4FrameDecompressor()
    first = dec.decompress(data, max_length=min(limit + 1, _LZ4_PIECE))
    if dec.eof or dec.needs_input or len(first) > limit:
        return first
    # the claimed size (+1) allocated once and filled: a growing buffer's realloc may copy,
    # holding old and new at once (a 64 MiB claim then peaked at 167 MiB, depending on the
    # allocator's state; now at most the claim plus two pieces)
    out = bytearray(limit + 1)
    n = len(first)
    out[:n] = first
    del first
    while n <= limit and not (dec.eof or dec.needs_input):
        piece = dec.decompress(b"", max_length=min(limit + 1 - n, _LZ4_PIECE))
        out[n:n + len(piece)] = piece
        n += len(piece)
    del out[n:]
    return out


_CORRUPT_DATA_ERRORS = (ValueError, struct.error, IndexError, KeyError, EOFError,
                        OverflowError, RuntimeError, zlib.error, McapError, MemoryError)
"""What corrupt chunk bytes raise: the record walk's bounds and struct errors, lz4's
RuntimeError, zlib, the mcap library's errors, a declared size that cannot be allocated
(UnicodeDecodeError is a ValueError); zstandard's ZstdError is matched by name (imported
lazily)."""


def is_corrupt_data_error(exc: BaseException) -> bool:
    """True when ``exc`` is what corrupt chunk bytes raise (:data:`_CORRUPT_DATA_ERRORS`, or
    zstandard's ``ZstdError``), False for anything else (a bug in pospp, which propagates)."""
    return isinstance(exc, _CORRUPT_DATA_ERRORS) or type(exc).__name__ == "ZstdError"


def decompress(chunk: RawChunk,
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
    if chunk.crc != 0 and crc32(data) != chunk.crc:
        raise ValueError("chunk CRC mismatch")
    return data
