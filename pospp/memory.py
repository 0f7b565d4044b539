"""Freed heap memory given back to the operating system between pipeline stages (issue 18).

glibc's allocator keeps what a stage frees in its heap (its mmap threshold grows to 32 MiB
after large frees, so numpy's large temporaries end up on the heap too) and the process's
resident set then only grows: on the 1.5 h, 200 Hz flight the freed memory of one stage
stacked under the next and the run peaked at 960 MiB, against 821 MiB with the free pages
returned at each stage's end (docs/benchmarks.md, "Speed and memory, fifth round").
``malloc_trim(0)`` returns the free pages (all of them since glibc 2.8, not only the heap's
top) at a cost of a few milliseconds. Elsewhere (another C library, macOS, Windows) it is a
no-op.

Threads: glibc gives each new thread that allocates a heap ("arena") of its own, up to eight
per core, and what one thread frees stays in its arena for that thread. A run on two
threads (the null's workers, the second lane: :mod:`pospp.passes_ahead`) then held the
memory of each thread's largest pass at once in separate heaps: 1051-1065 MiB peak on the
1.5 h flight, against 930-947 MiB with one heap for all threads (``MALLOC_ARENA_MAX=1``, or
this module's call) at the same wall time (12.0-13.8 s against 11.9-13.0 s; docs/benchmarks.md,
eighth round).
:func:`share_one_heap` sets that limit from inside the process.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from functools import lru_cache
from typing import Any

M_ARENA_MAX = -8
"""glibc's ``mallopt`` parameter for the most arenas (malloc.h)."""


@lru_cache(maxsize=1)
def _libc() -> Any:
    name = ctypes.util.find_library("c")
    if name is None:  # pragma: no cover - no C library found
        return None
    try:
        return ctypes.CDLL(name)
    except OSError:  # pragma: no cover
        return None


def _glibc_function(name: str) -> Any:
    libc = _libc()
    return getattr(libc, name, None) if libc is not None else None


def share_one_heap() -> bool:
    """Make threads that allocate from now on share glibc's main heap (``mallopt(M_ARENA_MAX,
    1)``, what ``MALLOC_ARENA_MAX=1`` does at start-up) instead of each making its own; True
    where glibc took it. An environment that sets ``MALLOC_ARENA_MAX`` itself keeps its
    value."""
    mallopt = _glibc_function("mallopt")
    if mallopt is None or "MALLOC_ARENA_MAX" in os.environ:  # pragma: no cover - not glibc
        return False
    return bool(mallopt(M_ARENA_MAX, 1))


def release_free_heap() -> bool:
    """Give the heap's free pages back to the operating system; True where glibc did."""
    trim = _glibc_function("malloc_trim")
    if trim is None:  # pragma: no cover - not glibc
        return False
    trim(0)
    return True
