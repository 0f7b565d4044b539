"""File primitives of pospp.io: atomic writes, content hashes, opening inputs.

Every file pospp writes goes through :func:`atomic_path` (temporary name, fsync, rename), so a
crash never leaves a half-written output under the final name. Every input pospp reads (MCAP
log, pipeline file, reference trajectory) is opened by :func:`open_regular`, which refuses
what is not a regular file: a named pipe (FIFO) or a device would block the reader forever or
never end (issue 38 item 12).
"""

from __future__ import annotations

import hashlib
import os
import stat
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

__all__ = ["NotRegularFileError", "atomic_path", "file_kind", "open_regular", "require_regular",
           "sha256_file"]

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


class NotRegularFileError(ValueError):
    """An input path that is not a regular file (a pipe, a device, a folder)."""


def file_kind(mode: int) -> str:
    """What a ``st_mode`` is, in words ("a named pipe (FIFO)", ...; "a regular file")."""
    return next((text for test, text in _KINDS if test(mode)),
                "a regular file" if stat.S_ISREG(mode) else "not a regular file")


def open_regular(path: str | Path) -> BinaryIO:
    """Open ``path`` for binary reading only if it is a regular file (after symlinks).

    Opened with ``O_NONBLOCK`` first, so that a named pipe without a writer does not block the
    open itself; its type is then taken from the open descriptor (``fstat``: no race with a
    rename) and anything but a regular file is refused before a byte is read.

    Raises
    ------
    FileNotFoundError
    NotRegularFileError
        ``path`` is a FIFO, a device, a socket or a folder (the message names which).
    """
    shown = os.fsdecode(os.fspath(path)).encode("utf-8", "surrogateescape").decode(
        "utf-8", "backslashreplace")
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise NotRegularFileError(f"{shown}: is {file_kind(mode)}, not a regular file; "
                                      "pospp reads inputs from regular files only")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def require_regular(path: str | Path) -> None:
    """Raise :class:`NotRegularFileError` when ``path`` exists and is not a regular file
    (nothing opened: a FIFO is judged by ``stat``); a missing path passes (callers say)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not stat.S_ISREG(mode):
        open_regular(path).close()  # raises the error naming what it is


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success fsync it and ``os.replace`` it.

    On any exception the temporary file is removed and ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:  # make the rename durable; not possible on every platform
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


def sha256_file(path: str | Path, *, chunk_bytes: int = 1 << 20) -> str:
    """SHA-256 hex digest of a regular file, read in chunks (constant memory); a FIFO or a
    device is refused (:class:`NotRegularFileError`), never read forever."""
    h = hashlib.sha256()
    with open_regular(path) as f:
        while block := f.read(chunk_bytes):
            h.update(block)
    return h.hexdigest()
