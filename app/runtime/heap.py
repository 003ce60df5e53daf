"""Handing freed heap memory back to the system (glibc's malloc; elsewhere these do nothing).

CPython keeps small objects in its own arenas (returned when empty); numpy arrays, large
strings and bytes come from malloc.  glibc keeps what is freed for reuse and gives back only
the top of each heap once it passes a threshold that grows with the largest block freed, so
a process that built one large result (a board job's arrays, a thousand traces' JSON) stays
at that peak's resident size long after.  And each thread that allocates may get a heap
(an *arena*) of its own, up to 8 per core, each holding its own freed memory.

* :func:`trim_heap` (``malloc_trim(0)``) returns every free page of every arena: the top of
  each, and whole free pages inside them (glibc >= 2.8, by ``madvise``).  Cheap (milliseconds
  on a few hundred MiB); called after each job.
* :func:`map_large_blocks` (``mallopt(M_MMAP_THRESHOLD, n)``) maps every block of ``n`` bytes
  or more on its own and unmaps it when freed.  glibc's threshold otherwise rises to the
  largest mapped block freed (up to 32 MiB), and the arrays below it then come from the heap,
  where a freed one is kept for reuse and a long-lived block above it keeps the heap from
  shrinking: a job's numpy temporaries (a planner's blocks of a few MiB) leave the process at
  the sum of what it ever held there.  Fixed, the process's resident size follows the arrays
  it holds (a compute process sets LARGE_BLOCK_BYTES before its first job, the server when
  its app is built).  A mapped
  block costs its page faults once per allocation; the arithmetic is the same.  A fixed
  threshold also fixes glibc's *trim* threshold, at its 128 KiB default unless set: every
  free that leaves more than that at the top of the heap hands it back (``sbrk``), and the
  next allocation faults the same pages in again (measured on the thin tube's slice exports
  and G-code writer, blocks of a few hundred KiB: 30-80 % more CPU each than with the
  dynamic thresholds).  Keeping free memory at the top costs resident memory in jobs that
  hold large working sets (the 1000-trace board's compute process peaked 24 MiB higher with
  4 or 8 MiB kept), so the threshold is set per job (:func:`keep_heap_top`): the kinds that
  churn medium blocks (slicing, toolpaths) keep ``HEAP_TOP_KEEP_BYTES`` (glibc's own dynamic
  rule keeps twice the mmap threshold; the tube's churn needed 4-8 MiB), every other job
  glibc's ``GLIBC_TRIM_BYTES``; :func:`trim_heap` still returns it all.
* :func:`limit_arenas` (``mallopt(M_ARENA_MAX, n)``) caps the number of arenas of a
  process with many threads; threads then share the existing arenas (contention only for
  threads that allocate at the same moment).  Set before the threads start: the server sets
  SERVER_ARENAS when its app is built.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import threading

log = logging.getLogger("conforma.heap")
M_ARENA_MAX = -8  # glibc's mallopt parameters
M_MMAP_THRESHOLD = -3
M_TRIM_THRESHOLD = -1
LARGE_BLOCK_BYTES = 2 ** 20  # the server and the compute processes map blocks of this size or more on their own
HEAP_TOP_KEEP_BYTES = 8 * 2 ** 20  # free bytes the heap's top may keep without handing them back (M_TRIM_THRESHOLD)
GLIBC_TRIM_BYTES = 128 * 2 ** 10  # glibc's default M_TRIM_THRESHOLD
SERVER_ARENAS = 2  # the server's threads (requests, queue consumers, machines) share this many
_libc_lock = threading.Lock()
_libc: list[ctypes.CDLL | None] = []  # empty: not looked up yet; [None]: no glibc


def _glibc() -> ctypes.CDLL | None:
    """The C library when it is glibc (it has malloc_trim and mallopt), else None."""
    with _libc_lock:
        if not _libc:
            try:
                libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                _libc.append(libc if hasattr(libc, "malloc_trim") and hasattr(libc, "mallopt") else None)
            except OSError:
                _libc.append(None)
        return _libc[0]


def trim_heap() -> bool:
    """Return the free pages of every malloc arena to the system; True when some were."""
    libc = _glibc()
    if libc is None:
        return False
    return bool(libc.malloc_trim(0))


def _mallopt(param: int, name: str, value: int) -> bool:
    """``mallopt(param, value)`` in glibc; True when glibc took it (a refusal is logged)."""
    libc = _glibc()
    if libc is None:
        return False
    ok = bool(libc.mallopt(param, int(value)))
    if not ok:
        log.warning("mallopt(%s, %d) was refused", name, value)
    return ok


def limit_arenas(count: int) -> bool:
    """At most ``count`` malloc arenas in this process (threads started later share them);
    True when glibc took the setting."""
    return _mallopt(M_ARENA_MAX, "M_ARENA_MAX", count)


def map_large_blocks(threshold_bytes: int, keep_bytes: int = GLIBC_TRIM_BYTES) -> bool:
    """Map every malloc block of ``threshold_bytes`` or more on its own, unmapped when freed
    (a fixed threshold: glibc no longer raises it), and let the heap's top keep up to
    ``keep_bytes`` free before handing it back (:func:`keep_heap_top`); True when glibc took
    both settings."""
    mapped = _mallopt(M_MMAP_THRESHOLD, "M_MMAP_THRESHOLD", threshold_bytes)
    return keep_heap_top(keep_bytes) and mapped


def keep_heap_top(keep_bytes: int) -> bool:
    """Let the heap's top keep up to ``keep_bytes`` free before handing it back to the system
    (``M_TRIM_THRESHOLD``; fixed at glibc's 128 KiB once the mmap threshold is: see the
    module's notes); True when glibc took it."""
    return _mallopt(M_TRIM_THRESHOLD, "M_TRIM_THRESHOLD", keep_bytes)
