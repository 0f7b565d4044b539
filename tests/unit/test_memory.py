"""pospp.memory: freed heap pages go back to the operating system (glibc)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

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


_HEAPS = r"""
import ctypes, ctypes.util, sys, tempfile, threading
from pospp.memory import share_one_heap
if sys.argv[1] == "one":
    assert share_one_heap()
def work():
    blocks = [bytearray(200_000) for _ in range(50)]  # glibc malloc, below the mmap threshold
    del blocks
ts = [threading.Thread(target=work) for _ in range(4)]
for t in ts: t.start()
for t in ts: t.join()
libc = ctypes.CDLL(ctypes.util.find_library("c"))
libc.fopen.restype = ctypes.c_void_p
with tempfile.NamedTemporaryFile(suffix=".xml") as f:
    fp = libc.fopen(f.name.encode(), b"w")
    libc.malloc_info(0, ctypes.c_void_p(fp))
    libc.fclose(ctypes.c_void_p(fp))
    print(open(f.name).read().count('<heap nr="'))
"""


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                    reason="arenas are glibc's")
def test_threads_share_one_heap_when_asked():
    # glibc's malloc_info lists one <heap> per arena: threads that allocate get their own
    # (what held a two-thread run's passes apart, +160 MiB), and none after share_one_heap
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}

    def heaps(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", _HEAPS, mode], capture_output=True,
                             text=True, env=env, check=True)
        return int(out.stdout.strip())

    assert heaps("own") > 1
    assert heaps("one") == 1
