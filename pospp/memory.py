"""Freed heap memory given back to the operating system between pipeline stages.

glibc's allocator keeps what a stage frees in its heap and the process's resident set then
only grows; :func:`release_free_heap` (``malloc_trim(0)``, a few milliseconds) returns the free
pages at each stage's end. glibc also gives each new thread that allocates a heap ("arena") of
its own, where what that thread frees stays: :func:`share_one_heap` (``M_ARENA_MAX`` = 1) puts
the threads of the run's parallel loops (B's replays, the A re-runs) in one heap. Elsewhere
(another C library, macOS, Windows) both are no-ops. Measured effect: docs/history/
speed_rounds.md, "Speed and memory, fifth round" and "Speed, eighth round".
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
