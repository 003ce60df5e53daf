"""Server-Sent Events of job progress: async streams fed by one poller thread, capped per key.

An open stream holds no request thread and runs no query of its own: one daemon thread
reads the watched jobs' ``(revision, status, progress, message)`` in a single query
every ``poll_s`` and wakes the streams whose job changed (``loop.call_soon_threadsafe``).
So a hundred open streams cost one small query per poll, and neither ``/health`` nor an
emergency stop waits behind them.  Each API key may hold ``per_key`` streams at once;
beyond that the request gets a 429 problem with ``Retry-After``.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import threading
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import Engine, bindparam, inspect, select

from app.platform.models import TERMINAL_STATES, Job

KEEPALIVE_S = 15.0
_JOBS = inspect(Job).local_table
_SNAPSHOTS = (select(_JOBS.c.id, _JOBS.c.revision, _JOBS.c.status, _JOBS.c.progress, _JOBS.c.message)
              .where(_JOBS.c.id.in_(bindparam("ids", expanding=True))))


@dataclass(eq=False)
class _Subscriber:
    job_id: str
    loop: asyncio.AbstractEventLoop
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    snapshot: dict[str, Any] | None = None
    missing: bool = False


class TooManyStreams(Exception):
    """The caller's key holds ``per_key`` streams already (429)."""


class JobWatch:
    """The progress streams of one app (see the module docstring)."""

    def __init__(self, engine: Engine, *, per_key: int, poll_s: float = 0.1) -> None:
        self.engine = engine
        self.per_key = per_key
        self.poll_s = poll_s
        self._subscribers: set[_Subscriber] = set()
        self._per_key: dict[str, int] = {}
        self._lock = threading.Lock()
        self._active = threading.Event()
        self._thread = threading.Thread(target=self._poll_forever, daemon=True, name="sse-poller")
        self._thread.start()

    # admission ---------------------------------------------------------------------
    @staticmethod
    def key_of(credential: str | None) -> str:
        return hashlib.sha256((credential or "").encode()).hexdigest()

    def admit(self, key: str) -> None:
        """Count one more stream for ``key``; ``TooManyStreams`` beyond the cap."""
        with self._lock:
            if self._per_key.get(key, 0) >= self.per_key:
                raise TooManyStreams(f"this API key already holds {self.per_key} open progress streams")
            self._per_key[key] = self._per_key.get(key, 0) + 1

    def release(self, key: str) -> None:
        with self._lock:
            left = self._per_key.get(key, 0) - 1
            if left > 0:
                self._per_key[key] = left
            else:
                self._per_key.pop(key, None)

    def open_streams(self) -> int:
        with self._lock:
            return len(self._subscribers)

    # streaming -----------------------------------------------------------------------
    async def subscribe(self, job_id: str) -> _Subscriber | None:
        """Watch ``job_id``; None when it does not exist.  The answer comes from the
        poller's next round (one query for every stream opened meanwhile): no thread is
        taken per request."""
        subscriber = _Subscriber(job_id, asyncio.get_running_loop())
        with self._lock:
            self._subscribers.add(subscriber)
            self._active.set()
        try:
            await subscriber.wake.wait()  # left set: the stream sends this first snapshot
        except BaseException:
            self._drop(subscriber)
            raise
        if subscriber.missing:
            self._drop(subscriber)
            return None
        return subscriber

    def _drop(self, subscriber: _Subscriber) -> None:
        with self._lock:
            self._subscribers.discard(subscriber)

    async def events(self, subscriber: _Subscriber, last_event_id: str | None, key: str) -> AsyncIterator[str]:
        """The SSE text of the subscriber's job: ``status`` on each change of status,
        ``progress`` otherwise, keepalive comments; ends when the job finishes (or
        disappears).  Releases the subscription and the key's slot at the end."""
        seen = int(last_event_id) if last_event_id and last_event_id.isdigit() else -1
        last_status = None
        try:
            while True:
                try:
                    await asyncio.wait_for(subscriber.wake.wait(), KEEPALIVE_S)
                except TimeoutError:
                    yield ": keepalive\n\n"
                    continue
                subscriber.wake.clear()
                if subscriber.missing:
                    return
                job = subscriber.snapshot
                if job is None:
                    continue
                if job["revision"] != seen:
                    seen = job["revision"]
                    event = "status" if job["status"] != last_status else "progress"
                    last_status = job["status"]
                    yield f"id: {seen}\nevent: {event}\ndata: {job['data']}\n\n"
                if job["status"] in TERMINAL_STATES:
                    return
        finally:
            self._drop(subscriber)
            self.release(key)

    def _poll_forever(self) -> None:
        while True:
            self._active.wait()
            with self._lock:
                subscribers = list(self._subscribers)
                if not subscribers:
                    self._active.clear()
                    continue
            try:
                self._poll(subscribers)
            except Exception:  # the database is busy or gone: try again next round
                pass
            time.sleep(self.poll_s)

    def _poll(self, subscribers: list[_Subscriber]) -> None:
        ids = sorted({s.job_id for s in subscribers})
        with self.engine.connect() as conn:
            rows = {r.id: dict(r._mapping) for r in conn.execute(_SNAPSHOTS, {"ids": ids})}
        for snapshot in rows.values():  # serialised once for every stream of the job
            snapshot["data"] = json.dumps({k: snapshot[k] for k in ("id", "status", "progress", "message")})
        for subscriber in subscribers:
            row = rows.get(subscriber.job_id)
            old = subscriber.snapshot
            if row is None:
                subscriber.missing = True
            elif old is not None and old["revision"] == row["revision"]:
                continue
            subscriber.snapshot = row
            try:
                subscriber.loop.call_soon_threadsafe(subscriber.wake.set)
            except RuntimeError:  # its event loop is closed
                pass
