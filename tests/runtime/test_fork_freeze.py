"""A compute process forked by the fork server starts with the fork server's imports frozen
(app.runtime.fork_freeze): its first full collection copies none of the pages it shares."""

from __future__ import annotations

import gc
import os

import pytest

from app.runtime.compute_pool import mp_context

MIB = 2 ** 20


def _private_bytes() -> int:
    """This process's private resident memory (clean + dirty), bytes."""
    total = 0
    with open("/proc/self/smaps_rollup") as rollup:
        for line in rollup:
            if line.startswith(("Private_Clean:", "Private_Dirty:")):
                total += int(line.split()[1]) * 1024
    return total


def _child(queue) -> None:  # type: ignore[no-untyped-def]
    frozen = gc.get_freeze_count()  # before this process froze anything itself
    before = _private_bytes()
    gc.collect()
    queue.put((frozen, _private_bytes() - before))


@pytest.mark.skipif(not os.path.exists("/proc/self/smaps_rollup"), reason="needs Linux's /proc")
def test_a_forked_compute_process_shares_the_fork_servers_imports_through_a_full_collection():
    context = mp_context()
    queue = context.Queue()
    process = context.Process(target=_child, args=(queue,))
    process.start()
    frozen, copied = queue.get(timeout=300)
    process.join(timeout=60)
    assert frozen > 100_000  # the compute core's, the job kinds' and the ECAD libraries' objects
    # without the freeze the collection writes into every object's header: ~60 MiB copied
    assert copied < 16 * MIB, copied / MIB
