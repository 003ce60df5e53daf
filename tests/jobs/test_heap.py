"""Freed heap memory handed back to the system (app.runtime.heap), in a process of its own."""

from __future__ import annotations

import multiprocessing
import sys

import pytest


def _resident_mib() -> float:
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS:")) / 1024


def _child(queue) -> None:  # type: ignore[no-untyped-def]
    import numpy as np

    from app.runtime.heap import limit_arenas, trim_heap

    capped = limit_arenas(2)
    before = _resident_mib()
    # 200 MiB in 64 KiB arrays (below malloc's mmap threshold: from the heap itself), each
    # followed by a small block that stays: the heap's top never comes free, only its inside
    blocks, kept = [], []
    for _ in range(3200):
        blocks.append(np.ones(8192))
        kept.append(np.ones(16))
    del blocks
    freed = _resident_mib()
    trimmed = trim_heap()
    queue.put((before, freed, _resident_mib(), trimmed, capped))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim: Linux")
def test_trim_heap_returns_the_free_pages_inside_the_heap_and_the_arena_cap_is_taken():
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_child, args=(queue,))
    process.start()
    before, freed, trimmed, said, capped = queue.get(timeout=120)
    process.join(timeout=60)
    assert freed - before > 150       # freed by Python, still resident: glibc keeps it for reuse
    assert said and freed - trimmed > 150 and trimmed - before < 50
    assert capped


def _large_blocks_child(queue, fixed: bool) -> None:  # type: ignore[no-untyped-def]
    import numpy as np

    from app.runtime.heap import map_large_blocks

    taken = map_large_blocks(2 ** 20) if fixed else None
    np.ones(2 ** 21)  # a 16 MiB block, mapped and freed: glibc's own threshold rises to it
    before = _resident_mib()
    # 200 MiB in 4 MiB arrays (over the fixed threshold, under the risen one), each followed
    # by a 200 KiB one that stays (too large for a free piece of the heap: carved from its
    # top): in the heap the top never comes free, only its inside
    blocks, kept = [], []
    for _ in range(50):
        blocks.append(np.ones(2 ** 19))
        kept.append(np.ones(25_600))
    del blocks
    queue.put((before, _resident_mib(), taken))


def _each_in_a_fresh_process(child, variants) -> dict:  # type: ignore[no-untyped-def]
    """``{variant: what child(queue, variant) put}``, each variant in a process of its own
    (spawned: a fresh heap with glibc's own settings)."""
    context = multiprocessing.get_context("spawn")
    out = {}
    for variant in variants:
        queue = context.Queue()
        process = context.Process(target=child, args=(queue, variant))
        process.start()
        out[variant] = queue.get(timeout=120)
        process.join(timeout=60)
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux")
def test_with_large_blocks_mapped_freed_arrays_leave_at_once_and_without_they_stay():
    out = _each_in_a_fresh_process(_large_blocks_child, (False, True))
    before, freed, _ = out[False]
    assert freed - before > 150  # glibc's rising threshold: the arrays came from the heap and stay
    before, freed, taken = out[True]
    assert taken and freed - before < 30  # the 10 MiB kept, the 200 MiB gone


def _heap_top_child(queue, keep: int | None) -> None:  # type: ignore[no-untyped-def]
    import numpy as np

    from app.runtime.heap import keep_heap_top, map_large_blocks

    taken = map_large_blocks(2 ** 20) if keep is None else map_large_blocks(2 ** 20, keep)
    if keep is not None:
        assert keep_heap_top(keep)  # as the compute process sets it per job
    rounds = []
    for _ in range(3):
        # 6 MiB in 512 KiB arrays (under the mmap threshold: carved from the heap's top), freed
        blocks = [np.ones(2 ** 16) for _ in range(12)]
        held = _resident_mib()
        del blocks
        rounds.append(held - _resident_mib())
    queue.put((rounds, taken))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux")
def test_with_large_blocks_mapped_the_heap_top_keeps_a_few_mib_instead_of_handing_back_each_free():
    """glibc's trim threshold is fixed with the mmap threshold (128 KiB unless set): every
    free at the heap's top went back to the system and was faulted in again by the next
    allocation.  With the churning kinds' keep (8 MiB) a job's freed 6 MiB stays for the
    next allocation; with glibc's 128 KiB (every other job's) it leaves at each free."""
    from app.runtime.heap import HEAP_TOP_KEEP_BYTES

    out = _each_in_a_fresh_process(_heap_top_child, (HEAP_TOP_KEEP_BYTES, None))
    kept, taken = out[HEAP_TOP_KEEP_BYTES]
    assert taken and max(kept) < 1.0  # nothing handed back: the next arrays reuse the pages
    given_back, taken = out[None]
    assert taken and min(given_back) > 4.0  # the freed 6 MiB left at once, each round


def test_the_kinds_that_churn_medium_blocks_keep_the_heap_top_and_the_others_do_not():
    from app.runtime.heap import HEAP_TOP_KEEP_BYTES
    from app.runtime.registry import get_kind, load_kinds

    load_kinds([])
    assert get_kind("slice").heap_keep_bytes == get_kind("toolpath").heap_keep_bytes == HEAP_TOP_KEEP_BYTES
    assert get_kind("reconstruct").heap_keep_bytes == get_kind("compensate").heap_keep_bytes == 0
