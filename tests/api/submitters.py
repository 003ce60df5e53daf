"""Many concurrent job submitters against a real server (used by tests/api/test_capacity.py
with 200 and by tests/bench/test_bench_capacity.py with 1,000)."""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from tests.helpers.async_run import run_async

JOB = {"kind": "test_sleep", "params": {"seconds": 0}}


@dataclass
class Outcome:
    codes: Counter = field(default_factory=Counter)
    ids_by_key: dict[str, set[str]] = field(default_factory=dict)
    bad_busy: list[str] = field(default_factory=list)  # 429/503 without Retry-After or problem body
    latencies_s: list[float] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def accepted_ids(self) -> set[str]:
        return set().union(*self.ids_by_key.values()) if self.ids_by_key else set()


async def _submit_all(base: str, key: str, clients: int, retries: int) -> Outcome:
    """``clients`` submitters at once, each with its own Idempotency-Key and connection; the
    first ``retries`` of them send the same request again at the same moment (a retry)."""
    outcome = Outcome()
    limits = httpx.Limits(max_connections=clients + retries, max_keepalive_connections=0)
    async with httpx.AsyncClient(base_url=base, limits=limits, timeout=120,
                                 headers={"Authorization": f"Bearer {key}"}) as client:
        start = asyncio.Event()

        async def one(i: int) -> None:
            await start.wait()
            began = time.monotonic()
            response = await client.post("/api/v1/jobs", json=JOB, headers={"Idempotency-Key": f"submit-{i}"})
            outcome.latencies_s.append(time.monotonic() - began)
            outcome.codes[response.status_code] += 1
            if response.status_code == 202:
                outcome.ids_by_key.setdefault(f"submit-{i}", set()).add(response.json()["id"])
            elif response.status_code in (429, 503):
                if "Retry-After" not in response.headers or response.json().get("status") != response.status_code:
                    outcome.bad_busy.append(response.text[:200])

        tasks = [asyncio.create_task(one(i)) for i in [*range(clients), *range(retries)]]
        await asyncio.sleep(0.05)
        began = time.monotonic()
        start.set()
        await asyncio.gather(*tasks)
        outcome.seconds = time.monotonic() - began
    return outcome


def submit_all(base: str, key: str, clients: int, retries: int = 0) -> Outcome:
    return run_async(lambda: _submit_all(base, key, clients, retries))


def count_jobs(base: str, key: str) -> int:
    response = httpx.get(f"{base}/api/v1/jobs", params={"kind": "test_sleep", "limit": 1},
                         headers={"Authorization": f"Bearer {key}"}, timeout=60)
    return response.json()["total"]


@contextmanager
def capacity_server(data_dir: Path, log: Path, key: str) -> Iterator[str]:
    """A real ``conforma serve`` (no embedded worker) accepting ``key`` as an operator: its URL."""
    from tests.e2e.test_serve import env_for, free_port, start, stop, wait_healthy

    port = free_port()
    proc = start(["serve", "--port", str(port)],
                 env_for(data_dir, CONFORMA_API_KEYS=f"{key}:operator", CONFORMA_LOG_LEVEL="warning",
                         CONFORMA_EMBEDDED_WORKER="false"), log)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_healthy(base, proc, log=log)  # its output when it exits at start
        yield base
    finally:
        stop(proc)
