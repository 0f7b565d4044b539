"""pospp.threads: results in the items' order, errors raised, the kernels run concurrently."""

from __future__ import annotations

import threading
import time

import pytest

from pospp.threads import available_cores, first_kept, map_in_threads


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
