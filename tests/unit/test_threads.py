"""pospp.threads: results in the items' order, errors raised, the kernels run concurrently."""

from __future__ import annotations

import threading
import time
from concurrent.futures import CancelledError, ThreadPoolExecutor

import pytest

from pospp.threads import Later, SharedWork, available_cores, first_kept, map_in_threads


def test_results_in_the_items_order_whatever_finishes_first():
    def slow_first(x: int) -> int:
        time.sleep(0.05 if x == 0 else 0.0)
        return x * x

    assert map_in_threads(slow_first, range(5), 3) == [0, 1, 4, 9, 16]
    assert map_in_threads(slow_first, range(5), 1) == [0, 1, 4, 9, 16]
    assert map_in_threads(slow_first, [], 2) == []


def test_an_error_in_one_item_is_raised():
    def fail_on_two(x: int) -> int:
        if x == 2:
            raise ValueError("item 2")
        return x

    with pytest.raises(ValueError, match="item 2"):
        map_in_threads(fail_on_two, range(4), 2)


def test_runs_on_several_threads_when_asked():
    seen: set[int] = set()
    barrier = threading.Barrier(2, timeout=10)

    def meet(_: int) -> None:
        seen.add(threading.get_ident())
        barrier.wait()  # returns only when two calls run at once

    map_in_threads(meet, range(2), 2)
    assert len(seen) == 2


def test_the_re_run_kernels_release_the_gil():
    """The kernels an A re-run and a B replay spend their time in are compiled nogil, so
    that threads overlap them (a kernel without it would serialise the threads silently)."""
    from pospp.nav import _filter_kernel, _kernels, error_model, smoother

    for kernel in (_filter_kernel.forward_kernel, smoother.rts_backward,
                   smoother.correct_states, _kernels.integrate_kernel,
                   error_model._transition_kernel):
        assert kernel.targetoptions.get("nogil") is True, kernel


def test_available_cores_is_the_affinity_mask():
    import os

    assert available_cores() == len(os.sched_getaffinity(0))


def test_first_kept_takes_the_same_items_at_any_thread_count():
    # the null realisations' contract: the first n results that are not None, in the items'
    # order, and never an item taken beyond what might still be needed
    def attempt(x):
        time.sleep(0.01 * (x % 3))
        return None if x in (2, 5) else 10 * x

    for threads in (1, 2, 3):
        taken: list[int] = []

        def items(into=taken):
            for i in range(100):
                into.append(i)
                yield i

        assert first_kept(attempt, items(), 4, threads) == [0, 10, 30, 40]
        assert taken == [0, 1, 2, 3, 4]  # one more than 4 for the failed 2, none beyond
        assert first_kept(attempt, iter([2, 5, 1]), 3, threads) == [10]  # items run out

    def fail_on_three(x):
        if x == 3:
            raise ValueError("three")
        return x

    with pytest.raises(ValueError, match="three"):
        first_kept(fail_on_three, iter(range(10)), 8, 2)


def test_later_without_a_pool_is_made_where_it_is_used_once():
    calls: list[int] = []

    def make(x: int, *, y: int) -> int:
        calls.append(x)
        return x + y

    later = Later(None, make, 2, y=3)
    assert calls == []  # nothing made until asked for (a stage that does not use it)
    assert later.result() == 5 and later.result() == 5 and calls == [2]
    assert later.take() == 5
    with pytest.raises(RuntimeError, match="taken"):
        later.result()
    with pytest.raises(RuntimeError, match="taken"):
        later.take()


def test_later_with_a_pool_runs_alongside_and_raises_where_used():
    started = threading.Event()

    def make() -> str:
        started.set()
        return threading.current_thread().name

    def fail() -> None:
        raise ValueError("the pass failed")

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="lane") as pool:
        later, bad = Later(pool, make), Later(pool, fail)
        assert started.wait(5.0)  # started without being asked for
        assert later.take().startswith("lane")
        with pytest.raises(ValueError, match="the pass failed"):
            bad.result()
    assert Later(None, lambda: None).take() is None  # None is a value, taken once


def test_a_cancelled_later_is_not_made_and_says_so():
    """A Later no one will ask for (a speculative pass whose guess A refuted): not made when
    its pool has not started it, never made without one; asking for it raises."""
    release, made = threading.Event(), []
    with ThreadPoolExecutor(max_workers=1) as pool:
        busy = Later(pool, release.wait, 5.0)  # holds the lane's one worker
        queued = Later(pool, made.append, "queued")
        queued.cancel()
        release.set()
        assert busy.result() is True
    assert made == []
    with pytest.raises(CancelledError):
        queued.result()
    lazy = Later(None, made.append, "lazy")
    lazy.cancel()
    with pytest.raises(CancelledError):
        lazy.result()
    assert made == []


def test_shared_work_is_joined_by_the_thread_waiting_for_it():
    """The lane's calls (SharedWork.map on the pool's thread) are helped by the thread that
    waits for the lane's result: the lane's first call can only end once another thread
    ran a second; every call runs once, the results in the items' order."""
    shared, ran, gate = SharedWork(), {}, threading.Event()

    def item(x):
        if x == 0:
            assert gate.wait(10.0)  # a helper has run another item
        else:
            gate.set()
        ran.setdefault(x, []).append(threading.current_thread().name)
        return x * x

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="lane") as pool:
        later = Later(pool, shared.map, item, range(5), helped=shared)
        assert later.take() == [0, 1, 4, 9, 16]
    assert sorted(ran) == [0, 1, 2, 3, 4] and all(len(v) == 1 for v in ran.values())
    assert ran[0][0].startswith("lane")
    assert any(not v[0].startswith("lane") for v in ran.values())


def test_shared_work_raises_the_first_error_in_order_after_every_call_and_alone_runs_all():
    shared, ran = SharedWork(), []

    def item(x):
        ran.append(x)
        if x in (1, 3):
            raise ValueError(f"item {x}")
        return x

    with pytest.raises(ValueError, match="item 1"):
        map_in_threads(item, range(5), shared)  # no helper: all in this thread
    assert ran == [0, 1, 2, 3, 4]
    assert map_in_threads(lambda x: -x, [2, 5], shared) == [-2, -5]
