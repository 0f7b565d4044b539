"""Independent runs of the compiled kernels on several threads (issue 18).

A's and B's compiled kernels (:mod:`pospp.nav._filter_kernel`, :mod:`pospp.nav.smoother`,
:mod:`pospp.nav._kernels`, :mod:`pospp.nav.error_model`) release the GIL (``nogil``), so
independent A re-runs (the null realisations, the diagnosis's signature columns) overlap on a
machine's cores. Results come back in the items' order, so a caller's outputs do not depend
on the number of threads.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import Any


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask; ``os.cpu_count`` where the
    platform has none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def map_in_threads(fn: Callable[[Any], Any], items: Iterable[Any], threads: int) -> list[Any]:
    """``[fn(x) for x in items]`` on up to ``threads`` threads, results in the items' order.

    An exception raised by ``fn`` is raised here (the first in the items' order) after the
    running calls end.
    """
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=min(threads, len(items))) as pool:
        return list(pool.map(fn, items))
