"""A small HTTP/1.1 keep-alive load generator on raw asyncio streams.

Python HTTP clients (httpx) cost more CPU per request than the server under test, so
they measure themselves; this one writes a fixed request and parses only the status line
and Content-Length.  Closed loop: each of ``clients`` connections sends its next request
when the previous answer arrives.  Open loop: requests are offered at ``rate`` per second
spread over the connections, and latency counts from the scheduled send time
(no coordinated omission).
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LoadResult:
    requests: int
    errors: int
    seconds: float
    latencies_ms: np.ndarray

    @property
    def rate(self) -> float:
        return self.requests / self.seconds

    def pct(self, q: float) -> float:
        return float(np.percentile(self.latencies_ms, q))


async def _read_response(reader: asyncio.StreamReader) -> int:
    status_line = await reader.readline()
    status = int(status_line.split()[1])
    length = 0
    chunked = False
    while True:
        line = await reader.readline()
        if line in (b"\r\n", b""):
            break
        name, _, value = line.decode().partition(":")
        if name.lower() == "content-length":
            length = int(value)
        elif name.lower() == "transfer-encoding" and "chunked" in value:
            chunked = True
    if chunked:
        raise RuntimeError("chunked responses are not supported by the load generator")
    await reader.readexactly(length)
    return status


async def _run(host: str, port: int, path: str, headers: dict[str, str], clients: int, seconds: float,
               rate: float | None) -> LoadResult:
    request = (f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\n"
               + "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n").encode()
    latencies: list[float] = []
    errors = 0
    start = time.perf_counter()
    stop_at = start + seconds
    interval = clients / rate if rate else 0.0

    async def client(index: int) -> None:
        nonlocal errors
        reader, writer = await asyncio.open_connection(host, port)
        next_send = start + (index * interval / clients if rate else 0.0)
        while True:
            now = time.perf_counter()
            if rate:
                if next_send > now:
                    await asyncio.sleep(next_send - now)
                scheduled = next_send
                next_send += interval
            else:
                scheduled = now
            if scheduled >= stop_at:
                break
            writer.write(request)
            status = await _read_response(reader)
            latencies.append(time.perf_counter() - scheduled)
            errors += status != 200
        writer.close()

    await asyncio.gather(*(client(i) for i in range(clients)))
    elapsed = time.perf_counter() - start
    return LoadResult(len(latencies), errors, elapsed, np.array(latencies) * 1000.0)


def run_load(url: str, *, headers: dict[str, str] | None = None, clients: int = 64, seconds: float = 5.0,
             rate: float | None = None) -> LoadResult:
    """Load ``url`` (http://host:port/path) closed-loop, or open-loop at ``rate`` req/s."""
    rest = url.split("://", 1)[1]
    hostport, _, path = rest.partition("/")
    host, _, port = hostport.partition(":")
    return asyncio.run(_run(host, int(port or 80), "/" + path, headers or {}, clients, seconds, rate))
