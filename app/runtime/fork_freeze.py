"""Imported LAST by the compute fork server (:func:`app.runtime.compute_pool.mp_context`):
what the fork server's imports made is collected once and frozen (:func:`gc.freeze`) before
it forks a compute process, so those objects are shared with every process it forks.

A forked process shares its parent's memory until it writes to a page.  CPython's cycle
collector writes into the header of every object it examines, so the first full collection
in a compute process (after a job: :meth:`app.runtime.compute_child.ChildRuntime.report`,
or one the interpreter starts on its own) would copy every page of the fork server's heap
that holds such an object: measured, ~60 MiB of the ~150 MiB a compute process shares with
the fork server (``tests/runtime/test_fork_freeze.py``).  Frozen objects are never examined,
so those pages stay shared.  The objects are the imported modules, which live as long as
the process anyway.  Import it only in a process that forks workers after its imports.
"""

from __future__ import annotations

import gc


def freeze_imports() -> int:
    """Collect once, then move every object tracked so far out of the collector's sight;
    returns how many objects are frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


FROZEN = freeze_imports()
