"""A compute process freezes what it holds at start-up; what jobs make is still collected."""

from __future__ import annotations

import gc
import multiprocessing
import weakref


class _Node:
    pass


def _child(queue) -> None:  # type: ignore[no-untyped-def]
    from app.runtime.compute_child import freeze_startup_objects

    before = gc.get_freeze_count()
    freeze_startup_objects()
    frozen = gc.get_freeze_count()
    a, b = _Node(), _Node()          # a cycle made after start-up, as a job's meshes are
    a.other, b.other = b, a
    alive = weakref.ref(a)
    del a, b
    gc.collect()
    queue.put((before, frozen, alive() is None))


def test_start_up_objects_are_frozen_and_job_cycles_still_collected():
    context = multiprocessing.get_context("spawn")   # a process of its own: freezing is for its life
    queue = context.Queue()
    process = context.Process(target=_child, args=(queue,))
    process.start()
    before, frozen, collected = queue.get(timeout=120)
    process.join(timeout=60)
    assert frozen > before + 1000   # the imported modules' objects
    assert collected
