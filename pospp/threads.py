"""Independent runs of the compiled kernels on several threads.

A's and B's compiled kernels (:mod:`pospp.nav._filter_kernel`, :mod:`pospp.nav.smoother`,
:mod:`pospp.nav._kernels`, :mod:`pospp.nav.error_model`) release the GIL (``nogil``), so
independent A re-runs (the null realisations, the diagnosis's signature columns) overlap on a
machine's cores. Results come back in the items' order, so a caller's outputs do not depend
on the number of threads.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask; ``os.cpu_count`` where the
    platform has none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def map_in_threads(fn: Callable[[Any], Any], items: Iterable[Any], threads: int
                   ) -> list[Any]:
    """``[fn(x) for x in items]`` on up to ``threads`` threads, results in the items' order.

    An exception raised by ``fn`` is raised here (the first in the items' order) after the
    running calls end.
    """
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
