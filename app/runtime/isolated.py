"""Run one function on user input in a bounded child process and wait for its answer.

The API process owns the serial ports: a parser that runs out of memory or time there stops
every print.  :func:`call_isolated` runs ``fn(*args)`` in a process forked from the compute
pool's fork server (:func:`app.runtime.compute_pool.mp_context`: it starts in tens of
milliseconds with the compute core imported), with

* its address space capped at its size at start plus ``memory_bytes`` (an allocation beyond
  is a ``MemoryError`` in the child, answered as :class:`~app.domain.errors.TooLarge`);
* a wall-clock limit ``time_s`` (SIGKILL, then :class:`~app.domain.errors.TooLarge`);
* death with its server (``PR_SET_PDEATHSIG`` and :func:`~app.runtime.compute_child.bind_to`) and
  the OOM killer's first choice;
* a ``cancelled`` callback polled while it runs (a client that went away): SIGKILL, then
  :class:`~app.domain.errors.Cancelled`.

The child answers through a pipe: the pickled result, or the :class:`~app.domain.errors.ConformaError`
it raised (class, message, field, value), which is raised again here.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from typing import Any, TypeVar

import app.domain.errors as errors
from app.domain.errors import Cancelled, ConformaError, TooLarge

log = logging.getLogger("conforma.isolated")
T = TypeVar("T")
POLL_S = 0.05


def _child(conn: Any, memory_bytes: int, server_pid: int, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
    """The child's body: limits, then ``fn(*args)``; sends ("ok", result) or ("error", fields)."""
    from app.runtime.compute_child import _vm_size_bytes, bind_to, process_limits

    bind_to(server_pid)  # before the cap: the lifeline thread's stack and arena count in the size at start
    process_limits(_vm_size_bytes() + memory_bytes)
    try:
        answer: tuple[str, Any] = ("ok", fn(*args))
    except MemoryError:
        answer = ("memory", None)
    except ConformaError as exc:
        answer = ("error", (type(exc).__name__, exc.message, exc.field, exc.value))
    except Exception as exc:  # a bug in the function: report it, the parent raises it
        log.exception("isolated %s failed", getattr(fn, "__name__", fn))
        answer = ("crash", f"{type(exc).__name__}: {exc}"[:500])
    try:
        conn.send(answer)
    except MemoryError:
        conn.send(("memory", None))
    finally:
        conn.close()


def _raise(kind: str, payload: Any, what: str, memory_bytes: int) -> None:
    if kind == "memory":
        raise TooLarge(f"{what} needs more than {memory_bytes / 2**20:g} MiB of memory", field="files")
    if kind == "error":
        name, message, field, value = payload
        cls = getattr(errors, name, None)
        if not (isinstance(cls, type) and issubclass(cls, ConformaError)):
            cls = errors.InvalidInput  # a subclass of a core package: its status is InvalidInput's
        raise cls(message, field=field, value=value)
    raise RuntimeError(f"{what} failed in its process: {payload}")


def call_isolated(fn: Callable[..., T], *args: Any, memory_bytes: int, time_s: float, what: str,
                  cancelled: Callable[[], bool] = lambda: False) -> T:
    """``fn(*args)`` in a bounded child process (see the module); ``fn`` and ``args`` must
    pickle.  ``what`` names the work in errors ("the import")."""
    from app.runtime.compute_pool import mp_context

    context = mp_context()
    parent, child = context.Pipe(duplex=False)
    process = context.Process(target=_child, args=(child, memory_bytes, os.getpid(), fn, args),
                              name="conforma-isolated", daemon=True)
    process.start()
    child.close()
    deadline = time.monotonic() + time_s
    try:
        while True:
            if parent.poll(POLL_S):
                try:
                    kind, payload = parent.recv()
                except EOFError:
                    kind, payload = "died", None
                break
            if process.exitcode is not None and not parent.poll(0):
                kind, payload = "died", None
                break
            if cancelled():
                raise Cancelled(f"{what} was cancelled: the client went away")
            if time.monotonic() > deadline:
                raise TooLarge(f"{what} took longer than {time_s:g} s", field="files")
    finally:
        if process.exitcode is None:
            process.kill()
        process.join(5.0)
        parent.close()
        exitcode = process.exitcode
        if exitcode is not None:
            process.close()
    if kind == "ok":
        result: T = payload
        return result
    if kind == "died":
        raise TooLarge(f"{what} needed more than its {memory_bytes / 2**20:g} MiB of memory "
                       f"(its process ended with exit code {exitcode})", field="files")
    _raise(kind, payload, what, memory_bytes)
    raise AssertionError("unreachable")

