"""Independent runs of the compiled kernels on several threads (issue 18).

A's and B's compiled kernels (:mod:`pospp.nav._filter_kernel`, :mod:`pospp.nav.smoother`,
:mod:`pospp.nav._kernels`, :mod:`pospp.nav.error_model`) release the GIL (``nogil``), so
independent A re-runs (the null realisations, the diagnosis's signature columns) overlap on a
machine's cores. Results come back in the items' order, so a caller's outputs do not depend
on the number of threads.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import CancelledError, Future, ThreadPoolExecutor
from functools import partial
from typing import Any


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask; ``os.cpu_count`` where the
    platform has none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


class SharedWork:
    """Calls a thread maps (:meth:`map`) that another thread waiting for that thread's result
    helps with (:meth:`help_until`): the second lane's A re-runs (:mod:`pospp.passes_ahead`),
    which the main thread joins when it has nothing left to do but wait for them (measured on
    the 1.5 h flight: the main thread waited 0.9 s for the lane's last re-runs). Each call runs
    once, on whichever thread takes it first; results come back in the items' order, so they
    do not depend on who ran them."""

    def __init__(self) -> None:
        self._ready = threading.Condition()
        self._queue: deque[tuple[Future[Any], Callable[[Any], Any], Any]] = deque()

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        """``[fn(x) for x in items]``, run in this thread and in any thread helping; the
        first exception in the items' order is raised after every call ended."""
        futures: list[Future[Any]] = []
        with self._ready:
            for x in items:
                futures.append(Future())
                self._queue.append((futures[-1], fn, x))
            self._ready.notify_all()
        self._run_queued()
        return [f.result() for f in futures]

    def help_until(self, future: Future[Any]) -> None:
        """Run the queued calls (and those queued later) until ``future`` is done."""
        future.add_done_callback(lambda _: self._notify())
        while not future.done():
            self._run_queued()
            with self._ready:
                if not self._queue and not future.done():
                    self._ready.wait()

    def _notify(self) -> None:
        with self._ready:
            self._ready.notify_all()

    def _run_queued(self) -> None:
        while True:
            with self._ready:
                if not self._queue:
                    return
                fut, fn, x = self._queue.popleft()
            if fut.set_running_or_notify_cancel():
                try:
                    fut.set_result(fn(x))
                except BaseException as exc:  # noqa: BLE001 - raised by map in order
                    fut.set_exception(exc)
                finally:
                    self._notify()


Threads = int | SharedWork
"""Threads for independent calls: a count (:func:`map_in_threads`), or the second lane's
:class:`SharedWork` (its thread, and the main thread when it waits)."""


def map_in_threads(fn: Callable[[Any], Any], items: Iterable[Any], threads: Threads
                   ) -> list[Any]:
    """``[fn(x) for x in items]`` on up to ``threads`` threads, results in the items' order
    (``threads`` a :class:`SharedWork`: on its threads).

    An exception raised by ``fn`` is raised here (the first in the items' order) after the
    running calls end.
    """
    if isinstance(threads, SharedWork):
        return threads.map(fn, items)
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=min(threads, len(items))) as pool:
        return list(pool.map(fn, items))


def first_kept(fn: Callable[[Any], Any], items: Iterable[Any], n: int, threads: int
               ) -> list[Any]:
    """The first ``n`` results of ``fn`` that are not None, over ``items`` in their order, on
    up to ``threads`` worker threads.

    The items are taken from ``items`` in this thread while the workers run (an item's
    making overlaps the others' ``fn``), never more than still might be needed: at most
    ``threads`` in flight, and no more than ``n`` minus the results kept. So the same items
    are taken, and the same results kept, at any number of threads (the null realisations:
    their draws from one generator, in order). An exception raised by ``fn`` is raised here
    after the calls in flight end.
    """
    out: list[Any] = []
    it = iter(items)
    if threads <= 1:
        while len(out) < n:
            try:
                x = next(it)
            except StopIteration:
                break
            r = fn(x)
            if r is not None:
                out.append(r)
        return out
    pending: deque[Future[Any]] = deque()
    done = False
    with ThreadPoolExecutor(max_workers=threads) as pool:
        while len(out) < n:
            while not done and len(pending) < threads and len(out) + len(pending) < n:
                try:
                    x = next(it)
                except StopIteration:
                    done = True
                    break
                pending.append(pool.submit(fn, x))
            if not pending:
                break
            r = pending.popleft().result()
            if r is not None:
                out.append(r)
    return out


class Later:
    """``fn(*args, **kwargs)``, made on ``pool``'s thread when a pool is given (from now on,
    alongside the caller), else in the caller's thread when :meth:`result` is first asked
    for: the same value either way, and without a pool the same order of work as a plain
    call where the result is used. An exception raised by ``fn`` is raised by
    :meth:`result`."""

    def __init__(self, pool: ThreadPoolExecutor | None, fn: Callable[..., Any], *args: Any,
                 helped: SharedWork | None = None, **kwargs: Any) -> None:
        self._call: Callable[[], Any] | None = partial(fn, *args, **kwargs)
        self._future = pool.submit(self._call) if pool is not None else None
        self._helped = helped if pool is not None else None
        self._value: Any = None
        self._taken = False
        self._cancelled = False

    def result(self) -> Any:
        """The value (made now when there is no pool and it was not made before). ``helped``
        (with a pool): the :class:`SharedWork` ``fn`` maps its calls on, which the thread
        asking for the value helps with while it waits."""
        if self._taken:
            raise RuntimeError("Later.result: the value was taken")
        if self._cancelled:
            raise CancelledError("Later.result: cancelled")
        if self._future is not None:
            if self._helped is not None:
                self._helped.help_until(self._future)
            return self._future.result()
        if self._call is not None:
            self._value, self._call = self._call(), None
        return self._value

    def cancel(self) -> None:
        """A value no one will ask for: not made when its pool has not started it (one
        already running ends and is let go of), never made without a pool; :meth:`result`
        then raises ``concurrent.futures.CancelledError``."""
        if self._future is not None:
            self._future.cancel()
        self._future, self._call, self._helped, self._cancelled = None, None, None, True

    def take(self) -> Any:
        """The value, which this object then lets go of (its only user has it: its memory is
        freed with that user's last reference); asking again raises RuntimeError."""
        if self._taken:
            raise RuntimeError("Later.take: the value was already taken")
        value = self.result()
        self._future, self._call, self._value, self._taken = None, None, None, True
        return value
