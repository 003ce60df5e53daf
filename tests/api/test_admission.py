"""Admission control on its own: a bounded number of requests run, a bounded number wait,
the rest (and those that wait too long) get a 503 problem with Retry-After; exempt paths
(health, STOP, progress streams) never wait."""

from __future__ import annotations

import asyncio

import httpx

from app.api.admission import AdmissionMiddleware
from tests.helpers.async_run import run_async


def _app(release: asyncio.Event):  # type: ignore[no-untyped-def]
    async def app(scope, receive, send):  # type: ignore[no-untyped-def]
        if scope["path"].startswith("/api/v1/slow"):
            await release.wait()
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    return app


def test_over_capacity_requests_get_503_with_retry_after():
    async def scenario() -> tuple[list[int], list[str | None], int, int]:
        release = asyncio.Event()
        guarded = AdmissionMiddleware(_app(release), max_active=2, max_waiting=3, wait_s=5)
        transport = httpx.ASGITransport(app=guarded)
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as client:
            tasks = [asyncio.create_task(client.get(f"/api/v1/slow/{i}")) for i in range(8)]
            await asyncio.sleep(0.2)  # 2 running, 3 waiting, 3 refused at once
            stop = await client.post("/api/v1/machines/m1/stop")  # exempt: answered while all is busy
            health = await client.get("/api/v1/health")
            release.set()
            answers = await asyncio.gather(*tasks)
        return ([a.status_code for a in answers], [a.headers.get("retry-after") for a in answers],
                stop.status_code, health.status_code)

    codes, retry_after, stop, health = run_async(scenario)
    assert sorted(codes) == [200] * 5 + [503] * 3
    assert all(r == "1" for c, r in zip(codes, retry_after) if c == 503)
    assert stop == 200 and health == 200


def test_a_request_that_waits_too_long_gets_503():
    async def scenario() -> list[int]:
        release = asyncio.Event()
        guarded = AdmissionMiddleware(_app(release), max_active=1, max_waiting=10, wait_s=0.3)
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=guarded), base_url="http://t") as client:
            first = asyncio.create_task(client.get("/api/v1/slow/a"))
            await asyncio.sleep(0.05)
            second = await client.get("/api/v1/parts")
            release.set()
            return [(await first).status_code, second.status_code]

    assert run_async(scenario) == [200, 503]
