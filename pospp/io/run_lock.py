"""The lock of one run folder: held by every command that writes into it, for the whole command.

``pospp run`` (and each flight of a batch) holds its output folder's lock from its first check
of the folder to the swap that puts the new run in place; ``diagnose``, ``evaluate``,
``report``, ``export`` and ``compare-sim`` hold the run folder's lock while they read it and
add their files. A second command on the same folder is refused at once with a one-line error
naming the holder's pid (issue 38 items 6 and 10: two runs into one new folder replaced each
other without ``--force``; ``diagnose`` during ``run --force`` left the old flight's diagnosis
in the new run).

The lock is ``flock`` on the folder itself (an open descriptor of the directory), not on a file
inside or beside it: the swap exchanges whole folders, so a lock file inside would move with
the old run, and one beside it would be a file pospp leaves in the user's folder. The kernel
releases the lock when its holder dies, even by ``kill -9``. A lock is taken on the folder the
path names at that moment; after taking it the path is checked to still name the same folder
(a swap in between is retried once, then refused). The lock is not reentrant: like two
processes, two threads of one process (a Dask worker's) exclude each other, and a locked
command must not call another.

On a file system without ``flock`` on folders (some network file systems) the lock cannot be
taken: the command goes on unlocked, as pospp did before (``RunLock.held`` is False).
"""

from __future__ import annotations

import errno
import fcntl
import functools
import os
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

from pospp.io.run_folder import RunFolderError, display_path, require_run_folder

__all__ = ["RunBusyError", "RunLock", "holder_pid", "locked"]

_F = TypeVar("_F", bound=Callable[..., Any])


class RunBusyError(RunFolderError):
    """Another pospp command holds the run folder (names the folder and the holder's pid)."""


def holder_pid(folder_ino: int) -> int | None:
    """The pid holding an ``flock`` on the inode ``folder_ino`` (``/proc/locks``, Linux), or
    None when it cannot be told."""
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        parts = line.split()
        # "1: FLOCK  ADVISORY  WRITE 4242 08:02:1316 0 EOF" (a "->" marks a waiter)
        if "FLOCK" not in parts or "->" in parts:
            continue
        i = parts.index("FLOCK")
        try:
            pid, dev_ino = int(parts[i + 3]), parts[i + 4]
        except (IndexError, ValueError):
            continue
        if dev_ino.rsplit(":", 1)[-1] == str(folder_ino):
            return pid
    return None


class RunLock:
    """Exclusive lock of a run folder for one command (context manager).

    Parameters
    ----------
    folder : path-like
        The run folder (its own path, symlinks resolved by the caller).
    create : bool
        Create the folder (empty) when absent, so that a run into a new folder is locked from
        its start; ``created`` then says so (the caller removes it if nothing was put in it).
    what : str
        What the holder does, for the error a second command gets.
    """

    def __init__(self, folder: str | os.PathLike[str], *, create: bool = False,
                 what: str = "a pospp command") -> None:
        self.folder = Path(os.path.abspath(folder))
        self.create = create
        self.what = what
        self.created = False
        self.held = False
        self._fd: int | None = None

    def _open(self) -> int:
        if self.create and not self.folder.exists():
            try:
                self.folder.mkdir(parents=True)
                self.created = True
            except FileExistsError:
                pass
        return os.open(self.folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)
                       | getattr(os, "O_CLOEXEC", 0))

    def __enter__(self) -> RunLock:
        for _ in range(2):
            fd = self._open()
            st = os.fstat(fd)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                pid = holder_pid(st.st_ino)
                os.close(fd)
                raise RunBusyError(
                    f"{display_path(self.folder)}: another pospp command (pid "
                    f"{pid if pid is not None else '?'}) is writing this run folder; wait for "
                    f"it to finish, then run {self.what} again") from None
            except OSError as exc:
                if exc.errno not in (errno.ENOLCK, errno.EINVAL, errno.ENOTSUP, errno.EBADF):
                    os.close(fd)
                    raise
                os.close(fd)  # no flock here (network file system): go on unlocked
                return self
            try:
                same = os.stat(self.folder)
            except FileNotFoundError:
                same = None
            if same is not None and (same.st_dev, same.st_ino) == (st.st_dev, st.st_ino):
                self._fd, self.held = fd, True
                return self
            os.close(fd)  # the path was swapped to another folder meanwhile: once more
        raise RunBusyError(f"{display_path(self.folder)}: the folder keeps changing (another "
                           f"program is replacing it); {self.what} not started")

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()

    def release(self) -> None:
        """Let go of the lock (idempotent)."""
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the flock
        self._fd, self.held = None, False


def locked(what: str) -> Callable[[_F], _F]:
    """Decorator: the function's first argument is a run folder, whose lock (:class:`RunLock`)
    is held for the whole call; ``what`` names the command in the error a second one gets."""
    def wrap(fn: _F) -> _F:
        @functools.wraps(fn)
        def inner(run_dir: Any, *args: Any, **kwargs: Any) -> Any:
            with RunLock(require_run_folder(run_dir), what=what):
                return fn(run_dir, *args, **kwargs)
        return inner  # type: ignore[return-value]
    return wrap
