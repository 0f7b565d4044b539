"""Where a batch's flights run: this process, local worker processes, or a Dask cluster.

Local workers are long-lived processes (their imports and compiled kernels serve every flight
they run), each fed one flight at a time over a pipe, so the batch knows which flight every
worker holds. A worker that dies (``kill -9``, the kernel's out-of-memory killer) fails that
flight alone, named, with the signal; a new worker takes its place and the batch goes on; the
staging folder the dead worker left is removed. Workers die with the batch process: Linux
``PR_SET_PDEATHSIG`` plus a watchdog thread.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from pospp.batch.flight import process_one
from pospp.batch.outcome import FlightOutcome
from pospp.io import run_folder

Task = tuple[str, dict[str, Any], str, bool, str, int | None, int | None, bool]
"""The arguments of :func:`pospp.batch.flight.process_one` for one flight."""
Record = Callable[[FlightOutcome], None]
_STAGING = ".pospp-staging-"
_TRASH = ".pospp-trash-"


def _die_with_parent(parent_pid: int) -> None:
    """Worker start: end this worker when the batch process dies (even kill -9)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:  # other platforms, and a second line of defence
        while True:
            time.sleep(1.0)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="pospp-parent-watch", daemon=True).start()


def clean_leftovers(root: Path) -> list[str]:
    """Remove the staging and trash folders that dead runs left directly under ``root``
    (:func:`pospp.io.run_folder.recover` of each one's target); returns the targets."""
    targets = set()
    try:
        names = [e.name for e in os.scandir(root)]
    except OSError:
        return []
    for name in names:
        for tag in (_STAGING, _TRASH):
            if name.startswith(".") and tag in name:
                targets.add(name[1:name.index(tag)])
    for t in sorted(targets):
        if t:
            run_folder.recover(root / t)
    return sorted(targets)


def _worker_loop(conn: Connection, parent_pid: int) -> None:
    _die_with_parent(parent_pid)
    while True:
        try:
            task = conn.recv()
        except EOFError:
            return
        if task is None:
            return
        conn.send(process_one(*task))


@dataclass
class _Worker:
    process: Any
    conn: Connection
    task: Task | None = None


def _start_worker() -> _Worker:
    ctx = multiprocessing.get_context()
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_worker_loop, args=(child, os.getpid()), daemon=True,
                       name="pospp-batch-worker")
    proc.start()
    child.close()
    return _Worker(proc, parent)


def _died(worker: _Worker, task: Task, root: Path) -> FlightOutcome:
    """The outcome of a flight whose worker process ended without an answer."""
    worker.process.join()  # reaped, so its staging folder is seen as a dead run's
    code = worker.process.exitcode
    how = (f"killed by {signal.Signals(-code).name}" if code is not None and code < 0
           else f"exited with status {code}")
    clean_leftovers(root)
    return FlightOutcome(run_folder.display_path(task[0]), "", "failed", 0.0,
                         f"the worker process {worker.process.pid} running this flight was "
                         f"{how} (out of memory?); the batch went on without it",
                         run_dir=task[4], action="resumed" if task[7] else "ran")


def run_local(tasks: list[Task], workers: int, root: Path, record: Record) -> None:
    """Run ``tasks`` on ``workers`` local processes, calling ``record`` with each outcome."""
    pending = list(reversed(tasks))
    pool: list[_Worker] = []

    def give(w: _Worker) -> None:
        w.task = pending.pop()
        try:
            w.conn.send(w.task)
        except OSError:  # died while idle: its sentinel says so below
            pass

    try:
        while pending or any(w.task is not None for w in pool):
            for w in pool:
                if w.task is None and pending:
                    give(w)
            while pending and len(pool) < workers:
                pool.append(_start_worker())
                give(pool[-1])
            busy = [w for w in pool if w.task is not None]
            ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy])
            for w in busy:
                if w.conn in ready or w.process.sentinel in ready:
                    task, w.task = w.task, None
                    assert task is not None
                    try:
                        outcome = w.conn.recv() if w.conn.poll() else None
                    except (EOFError, OSError):
                        outcome = None
                    if outcome is None:
                        record(_died(w, task, root))
                        pool.remove(w)
                    else:
                        record(outcome)
    finally:
        for w in pool:
            try:
                w.conn.send(None)
            except OSError:
                pass
        for w in pool:
            w.process.join(timeout=5.0)
            if w.process.is_alive():
                w.process.kill()
                w.process.join()


def run_dask(tasks: list[Task], client: Any, record: Record) -> None:
    """Run ``tasks`` on a Dask cluster; a flight whose worker is lost fails alone, named."""
    from dask.distributed import as_completed as dask_completed

    futures = {client.submit(process_one, *t, pure=False): t for t in tasks}
    for fut in dask_completed(list(futures)):
        try:
            record(fut.result())
        except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: that flight only
            t = futures[fut]
            text = " ".join(str(exc).split())[:300] or type(exc).__name__
            record(FlightOutcome(run_folder.display_path(t[0]), "", "failed", 0.0,
                                 f"the Dask worker running this flight was lost "
                                 f"({type(exc).__name__}: {text})", run_dir=t[4],
                                 action="resumed" if t[7] else "ran"))
