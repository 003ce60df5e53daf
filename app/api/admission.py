"""Admission control: a bounded number of API requests run at once; the rest wait in a
bounded queue for a bounded time, then get a clean 503 problem with ``Retry-After``.

Without it, 200 concurrent submitters ran the database pool dry (``QueuePool limit ...
reached``) and got 500s.  With at most ``max_active`` requests in the routers, each using
at most two pooled connections, the pool (``db_pool_size`` plus overflow) always has room
for them, the workers and the reaper.  Exempt: health, emergency stop and progress streams
(long-lived; they are capped per key where they are served) — a STOP never queues.
"""

from __future__ import annotations

import asyncio
import re

from starlette.types import ASGIApp, Receive, Scope, Send

from app.api.limits import send_problem

_EXEMPT = re.compile(r"^/api/v1/(health$|machines/[^/]+/stop$|jobs/[^/]+/events$)")


class AdmissionMiddleware:
    def __init__(self, app: ASGIApp, *, max_active: int, max_waiting: int, wait_s: float) -> None:
        self.app = app
        self.max_waiting = max_waiting
        self.wait_s = wait_s
        self._slots = asyncio.Semaphore(max_active)
        self._waiting = 0
        self.refused = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        if scope["type"] != "http" or not path.startswith("/api/") or _EXEMPT.match(path):
            await self.app(scope, receive, send)
            return
        if self._waiting >= self.max_waiting:
            await self._refuse(send, f"{self._waiting} requests are already waiting")
            return
        self._waiting += 1
        try:
            async with asyncio.timeout(self.wait_s):
                await self._slots.acquire()
        except TimeoutError:
            await self._refuse(send, f"no request slot became free within {self.wait_s:g} s")
            return
        finally:
            self._waiting -= 1
        try:
            await self.app(scope, receive, send)
        finally:
            self._slots.release()

    async def _refuse(self, send: Send, why: str) -> None:
        self.refused += 1
        await send_problem(send, 503, "Service busy", f"the server is at capacity ({why}); retry later",
                            headers={"Retry-After": "1"})
