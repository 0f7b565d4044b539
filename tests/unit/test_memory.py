"""pospp.memory: freed heap pages go back to the operating system (glibc)."""

from __future__ import annotations

import platform

import numpy as np
import pytest

from pospp.memory import release_free_heap


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                    reason="malloc_trim is glibc's")
def test_freed_heap_returns_to_the_system():
    # a freed 4 MiB block raises glibc's mmap threshold: the next ones of that size live on
    # the heap, where freeing them does not shrink the process until the heap is trimmed
    first = np.ones(4 << 19)
    del first
    blocks = [np.ones(4 << 17) for _ in range(60)]  # 60 x 4 MiB, touched
    keep = np.ones(4 << 17)  # allocated last, above them: the heap's top is not free
    del blocks
    before = _rss_mib()
    assert release_free_heap()
    after = _rss_mib()
    assert before - after > 150, (before, after)
    assert keep.sum() == 4 << 17
