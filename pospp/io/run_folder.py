"""Run folders on disk: the marker, the staging folder and its swap, the batch lock.

Nothing of the user's is lost:

- A run folder holds a marker file ``.pospp-run.json`` with the run's identity (pospp version,
  input path and SHA-256, configuration SHA-256, status, creation time in UTC).
- An output folder is used only when it is absent, empty, or a pospp run holding nothing but
  files pospp writes; replacing an earlier run needs ``force``; a folder holding files pospp
  did not write is refused even with ``force`` (the error names a few of them); a folder that
  contains the input file is always refused.
- A run writes into a staging folder beside the target (``.NAME.pospp-staging-PID-HEX``, same
  file system) and swaps it in whole when done: on Linux one ``renameat2(RENAME_EXCHANGE)``,
  elsewhere two renames (target -> trash, staging -> target) with a recovery step that puts the
  trash back when a crash fell between them. A kill at any point leaves the previous complete
  run or the new one, plus leftovers that the next run into the same target removes.
- A batch root is locked with ``flock`` on ``.pospp-batch.lock`` holding the pid; the kernel
  releases it when the holder dies, even by ``kill -9``.

A run holds its folder's lock (:mod:`pospp.io.run_lock`) from its first
check to the swap (:class:`StagedRun`), and checks the folder again at the swap: files put
into it meanwhile stop the swap, never vanish with the previous run. A run that ends without a
verdict on its input (a full disk, a missing file: any error but a ``ValueError``) leaves the
previous run in place. A command that writes a file derived from a run (``export -o``,
``compare-sim -o``) obeys the same rules (:func:`check_output_file`): never the run's input,
never a file of a run folder but its own, an existing file only with ``force``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fcntl
import hashlib
import json
import os
import shutil
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any

from pospp import __version__
from pospp.io.files import atomic_path
from pospp.io.parquet_tables import TABLES

__all__ = ["MARKER", "BatchLock", "RunFolderError", "StagedRun", "check_output_file",
           "check_target", "discard", "display_path", "display_text", "new_staging",
           "read_marker", "refuse_symlink_loop", "require_run_folder", "swap_in",
           "write_marker"]

MARKER = ".pospp-run.json"
"""Marker file of a run folder (JSON, the run's identity)."""
LOCK_NAME = ".pospp-batch.lock"
_STAGING = ".pospp-staging-"
_TRASH = ".pospp-trash-"
_OTHER_OUTPUTS = frozenset({"report.html", "trajectory.mcap", "evaluation.png",
                            "observability.png", MARKER,
                            # pospp compare-sim's fitted model (pospp.compare_sim)
                            "sim_model.toml"})
_RENAME_EXCHANGE = 2  # linux/fs.h


class RunFolderError(ValueError):
    """An output folder that pospp must not write into (names the folder and why)."""


def display_path(path: str | os.PathLike[str]) -> str:
    """``path`` as printable UTF-8 text: undecodable bytes of the name escaped as ``\\xNN``."""
    return display_text(os.fspath(path))


def display_text(text: str) -> str:
    """``text`` encodable as UTF-8: bytes smuggled in by surrogateescape shown as ``\\xNN``."""
    try:
        raw = text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:
        raw = text.encode("utf-8", "backslashreplace")
    return raw.decode("utf-8", "backslashreplace")


def _few(names: list[str], n: int = 5) -> str:
    shown = ", ".join(display_path(x) for x in sorted(names)[:n])
    return shown + (f" and {len(names) - n} more" if len(names) > n else "")


def is_pospp_file(name: str) -> bool:
    """True for a file name a run folder may hold (tables, report, MCAP, figures, temporaries,
    ``pospp export``'s default files: :data:`pospp.io.exports.DEFAULT_NAMES`)."""
    from pospp.io.exports import DEFAULT_NAMES  # the export registry's (imports this module)

    if name in _OTHER_OUTPUTS or name in DEFAULT_NAMES:
        return True
    if name.endswith(".parquet") and name[: -len(".parquet")] in TABLES:
        return True
    return name.startswith(".") and name.endswith(".tmp")


def read_marker(folder: str | Path) -> dict[str, Any] | None:
    """The marker of ``folder``, or None when it has none (or an unreadable one)."""
    try:
        data = json.loads((Path(folder) / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("pospp_run") == 1 else None


def write_marker(folder: str | Path, *, input_file: str | Path, input_sha256: str,
                 config_json: str, status: str) -> dict[str, Any]:
    """Write ``folder/.pospp-run.json`` atomically and return its content."""
    marker = {
        "pospp_run": 1,
        "pospp_version": __version__,
        "input_file": os.fsdecode(os.path.abspath(input_file)),
        "input_sha256": input_sha256,
        "config_sha256": config_sha256(config_json),
        "status": status,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    with atomic_path(Path(folder) / MARKER) as tmp:
        Path(tmp).write_text(json.dumps(marker, indent=1), encoding="utf-8")
    return marker


def config_sha256(config_json: str) -> str:
    """The configuration hash stored in the marker (SHA-256 of the canonical JSON)."""
    return hashlib.sha256(config_json.encode()).hexdigest()


def require_run_folder(folder: str | Path) -> Path:
    """``folder`` if it is a pospp run folder; else a clear error (for diagnose/report/evaluate)."""
    p = Path(folder)
    if not p.is_dir():
        raise FileNotFoundError(f"run folder not found: {display_path(p)}")
    if read_marker(p) is None:
        raise RunFolderError(f"{display_path(p)}: not a pospp run folder (no {MARKER}); "
                             "give a folder written by pospp run")
    return p


def _pid_alive(pid: int | None) -> bool:
    if pid is None or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _leftovers(target: Path, tag: str) -> list[Path]:
    prefix = f".{target.name}{tag}"
    try:
        return [p for p in target.parent.iterdir() if p.name.startswith(prefix)]
    except OSError:
        return []


def _owner_pid(p: Path, target: Path, tag: str) -> int | None:
    rest = p.name[len(f".{target.name}{tag}"):]
    head = rest.split("-", 1)[0]
    return int(head) if head.isdigit() else None


def recover(target: str | Path) -> None:
    """Finish or undo a swap a crash interrupted; remove staging and trash left by dead runs."""
    target = Path(os.path.abspath(target))
    trash = [p for p in _leftovers(target, _TRASH)
             if not _pid_alive(_owner_pid(p, target, _TRASH))]
    if not target.exists() and trash:
        # killed between "target -> trash" and "staging -> target": put the old run back
        newest = max(trash, key=lambda p: p.stat().st_mtime)
        os.rename(newest, target)
        trash.remove(newest)
    for p in trash + [p for p in _leftovers(target, _STAGING)
                      if not _pid_alive(_owner_pid(p, target, _STAGING))]:
        shutil.rmtree(p, ignore_errors=True)


def refuse_symlink_loop(path: str | Path) -> None:
    """A :class:`RunFolderError` at once when ``path`` (or a folder on the way to it) is a
    symbolic link loop: nothing could be written there, and finding out only at the final
    swap would cost the whole run."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise RunFolderError(f"{display_path(path)}: a symbolic link loop (too many levels "
                                 "of symbolic links); choose another output folder") from None


def check_target(target: str | Path, *, input_file: str | Path, force: bool) -> Path:
    """Check that a run may be written to ``target``; returns its absolute path.

    Raises
    ------
    RunFolderError
        ``target`` is a file, contains the input, holds files pospp did not write, or holds an
        earlier pospp run and ``force`` is False.
    """
    t = Path(os.path.abspath(target))
    refuse_symlink_loop(t)
    if t.is_symlink():  # swap the folder the link points to, keep the link
        t = Path(os.path.realpath(t))
    shown = display_path(t)
    if not t.name:
        raise RunFolderError(f"{shown}: not usable as a run folder")
    recover(t)
    if t.exists() and not t.is_dir():
        raise RunFolderError(f"{shown}: exists and is not a folder")
    inp = Path(os.path.abspath(input_file))
    real_t, real_inp = Path(os.path.realpath(t)), Path(os.path.realpath(inp))
    if t == inp or t in inp.parents or real_t == real_inp or real_t in real_inp.parents:
        raise RunFolderError(f"{shown}: the output folder contains the input "
                             f"{display_path(inp.name)}; choose another output folder")
    if not t.exists():
        return t
    names = [p.name for p in t.iterdir()]
    if not names:
        return t
    marker = read_marker(t)
    foreign = [n for n in names if not is_pospp_file(n)]
    if marker is None:
        raise RunFolderError(f"{shown}: not empty and not a pospp run folder (no {MARKER}; "
                             f"holds {_few(names)}); choose an empty or new folder")
    if foreign:
        raise RunFolderError(f"{shown}: holds files pospp did not write ({_few(foreign)}); "
                             "pospp will not replace it, even with --force")
    if not force:
        raise RunFolderError(f"{shown}: already holds a pospp run (of "
                             f"{display_path(marker.get('input_file', '?'))}, "
                             f"{marker.get('created_utc', '?')}); use --force to replace it")
    return t


def new_staging(target: str | Path) -> Path:
    """Create the staging folder beside ``target`` (same file system) and return it."""
    t = Path(os.path.abspath(target))
    t.parent.mkdir(parents=True, exist_ok=True)
    stage = t.parent / f".{t.name}{_STAGING}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    stage.mkdir()
    return stage


def discard(stage: str | Path) -> None:
    """Remove a staging folder (a run that ends without a result to keep)."""
    shutil.rmtree(stage, ignore_errors=True)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _exchange(a: Path, b: Path) -> bool:
    """Atomically exchange two paths (Linux renameat2); False when not available."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    rc = fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(a))


def swap_in(stage: str | Path, target: str | Path) -> Path:
    """Replace ``target`` by the complete ``stage`` folder as one step; returns ``target``."""
    stage, t = Path(stage), Path(os.path.abspath(target))
    _fsync_dir(stage)
    if not t.exists():
        os.rename(stage, t)
    elif _exchange(stage, t):
        shutil.rmtree(stage, ignore_errors=True)  # now holds the previous run
    else:
        trash = t.parent / f".{t.name}{_TRASH}{os.getpid()}-{uuid.uuid4().hex[:8]}"
        os.rename(t, trash)
        os.rename(stage, t)
        shutil.rmtree(trash, ignore_errors=True)
    _fsync_dir(t.parent)
    return t


def _contents(folder: Path) -> tuple[frozenset[str], dict[str, Any] | None]:
    """The names in ``folder`` and its marker (empty and None when it is absent)."""
    try:
        return frozenset(p.name for p in folder.iterdir()), read_marker(folder)
    except FileNotFoundError:
        return frozenset(), None


class StagedRun:
    """The folder side of one run (context manager): locked, staged, checked again, swapped.

    Entering checks ``out_dir`` (:func:`check_target`: nothing is touched when it is refused),
    takes its lock (:class:`pospp.io.run_lock.RunLock`, creating it empty when absent) for the
    whole run, checks it again under the lock, notes what it holds and makes the staging
    folder :attr:`stage`. :meth:`commit` writes the marker, checks that the folder still holds
    what it held (files added during the run stop the swap: a :class:`RunFolderError` naming
    them, nothing replaced) and swaps the staging folder in. Leaving discards a staging folder
    that was not swapped in, removes the folder the lock created if it is still empty, and
    lets go of the lock.
    """

    def __init__(self, out_dir: str | Path, *, input_file: str | Path, force: bool) -> None:
        self.input_file, self.force = input_file, force
        self.target = check_target(out_dir, input_file=input_file, force=force)
        self._stage: Path | None = None
        self.committed = False
        self._before: tuple[frozenset[str], dict[str, Any] | None] = (frozenset(), None)
        self._lock: Any = None

    def __enter__(self) -> StagedRun:
        from pospp.io.run_lock import RunLock

        self._lock = RunLock(self.target, create=True, what="pospp run").__enter__()
        try:
            check_target(self.target, input_file=self.input_file, force=self.force)
            self._before = _contents(self.target)
            self._stage = new_staging(self.target)
        except BaseException:
            self._leave()
            raise
        return self

    @property
    def stage(self) -> Path:
        """The staging folder the run writes into (inside the ``with`` block, until the swap)."""
        if self._stage is None:
            raise RuntimeError("StagedRun.stage outside its with block or after the swap")
        return self._stage

    @property
    def replaces_a_run(self) -> bool:
        """The folder held an earlier run when this one started."""
        return self._before[1] is not None

    def commit(self, *, input_sha256: str, config_json: str, status: str) -> Path:
        """Marker, the folder checked again, the swap; returns the run folder."""
        write_marker(self.stage, input_file=self.input_file, input_sha256=input_sha256,
                     config_json=config_json, status=status)
        names, marker = _contents(self.target)
        added = sorted(names - self._before[0])
        if added or marker != self._before[1]:
            what = f"files were put into it ({_few(added)})" if added else \
                "another run was written into it"
            raise RunFolderError(f"{display_path(self.target)}: {what} during this run; "
                                 "nothing was replaced and this run was not kept: move them "
                                 "elsewhere and run again")
        swap_in(self.stage, self.target)
        self._stage, self.committed = None, True
        return self.target

    def fail(self, exc: Exception, write_failed: Callable[[Path], None], *,
             input_sha256: str, config_json: str) -> None:
        """The run ended with ``exc``. A verdict on its input (a ``ValueError``: the log or
        the configuration refused, algorithm A failed), or a folder that held no run, gets
        the failed run (``write_failed(stage)`` writes its messages and summary, unless the run
        wrote its summary itself) swapped in. Anything else (a full disk, a lost file, a bug)
        leaves the previous run in place, and a note on ``exc`` says so; so does a failed
        run that cannot be written."""
        if isinstance(exc, ValueError) or not self.replaces_a_run:
            try:
                if not (self.stage / "summary.parquet").is_file():
                    write_failed(self.stage)
                self.commit(input_sha256=input_sha256, config_json=config_json,
                            status="failed")
            except Exception:  # noqa: BLE001 - e.g. a full disk: the first error is reported
                pass
        if not self.committed and self.replaces_a_run:
            exc.add_note(f"{display_path(self.target)}: the previous run is kept (this one did "
                         "not complete)")

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._leave()

    def _leave(self) -> None:
        if self._stage is not None:
            discard(self._stage)
            self._stage = None
        if self._lock is not None:
            if self._lock.created and not self.committed:
                try:
                    self.target.rmdir()  # only when still empty
                except OSError:
                    pass
            self._lock.release()
            self._lock = None


def check_output_file(path: str | Path, *, run: str | Path, own_names: frozenset[str],
                      force: bool) -> Path:
    """A file a command derived from the run folder ``run`` may write; its absolute path.

    The rules of ``pospp run`` for one file: never the run's input log (its marker names it,
    symlinks resolved); inside a pospp run folder only the command's own files
    (``own_names``) of this same run (never a table, the marker, the report or another run's
    file); elsewhere an existing file only with ``force``; never a folder, FIFO or device.

    Raises
    ------
    RunFolderError
    """
    p = Path(os.path.abspath(path))
    real = Path(os.path.realpath(p))
    shown = display_path(p)
    marker = read_marker(run) or {}
    source = marker.get("input_file")
    if source and real == Path(os.path.realpath(source)):
        raise RunFolderError(f"{shown}: is the run's input log; choose another output file")
    if real.exists() and not real.is_file():
        raise RunFolderError(f"{shown}: exists and is not a regular file")
    if read_marker(real.parent) is not None:
        if real.parent != Path(os.path.realpath(run)) or real.name not in own_names:
            raise RunFolderError(
                f"{shown}: is in the pospp run folder {display_path(real.parent)}, where this "
                f"command writes only {', '.join(sorted(own_names))} of its own run; choose "
                "another path")
        return real
    if real.exists() and not force:
        raise RunFolderError(f"{shown}: exists; use --force to replace it")
    return real


class BatchLock:
    """Exclusive lock of a batch root (``ROOT/.pospp-batch.lock``, flock, holder's pid inside).

    Use as a context manager; a second holder gets a :class:`RunFolderError` naming the pid.
    """

    def __init__(self, root: str | Path) -> None:
        self.path = Path(root) / LOCK_NAME
        self._fd: int | None = None

    def __enter__(self) -> BatchLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise RunFolderError(f"{display_path(self.path.parent)}: another pospp batch "
                                 f"(pid {holder}) is working on this root; wait for it or "
                                 "stop it") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None
