"""A client that gives up on a circuit import stops the server's work: the import's child
process (app.runtime.isolated) is gone within 2 s of the connection closing, and the server
answers /health promptly all along (a real `conforma serve` over TCP)."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import httpx

from app.reference.s1 import s1_mesh
from tests.e2e.test_serve import env_for, start
from tests.helpers.processes import free_port, stop, wait_healthy

KEY = "e2e-operator-key-1"
HEADERS = {"Authorization": f"Bearer {KEY}"}


def heavy_svg(traces: int = 2000, length_mm: float = 60.0) -> str:
    """``traces`` parallel lines of ``length_mm`` across the S1 part: within every bound of an
    import (5,000 shapes, 250 m drawn), and tens of seconds of mapping at 0.25 mm steps."""
    paths = "".join(f'<path d="M0 {i * 0.01:.2f} L{length_mm:g} {i * 0.01:.2f}" stroke="black" stroke-width="0.2"/>'
                    for i in range(traces))
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">'
            f"{paths}</svg>")


def _ppids() -> dict[int, int]:
    out = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if fields[0] != "Z":
                out[int(entry.name)] = int(fields[1])
    return out


def forked_children(server_pid: int) -> set[int]:
    """Live processes forked by the server's fork server (the import's child among them)."""
    ppids = _ppids()
    servers = {pid for pid, parent in ppids.items() if parent == server_pid
               and b"forkserver" in Path(f"/proc/{pid}/cmdline").read_bytes()}
    return {pid for pid, parent in ppids.items() if parent in servers}


def _health_s(base: str) -> float:
    began = time.perf_counter()
    assert httpx.get(f"{base}/api/v1/health", timeout=30).status_code == 200
    return time.perf_counter() - began


def _raw_import(port: int, part_id: str, svg: str) -> socket.socket:
    """Send a complete import request over a socket of our own, and leave it unanswered."""
    request = httpx.Request("POST", f"http://127.0.0.1:{port}/api/v1/parts/{part_id}/circuits:import", headers=HEADERS,
                            files=[("files", ("heavy.svg", svg.encode()))],
                            data={"options": json.dumps({"dry_run": True})})
    body = request.read()
    head = [f"POST {request.url.raw_path.decode()} HTTP/1.1", f"Host: 127.0.0.1:{port}"]
    head += [f"{k}: {v}" for k, v in request.headers.items() if k.lower() != "host"]
    sock = socket.create_connection(("127.0.0.1", port))
    sock.sendall(("\r\n".join(head) + "\r\n\r\n").encode() + body)
    return sock


def test_a_client_that_disconnects_ends_its_import_s_child_and_the_server_stays_responsive(tmp_path):
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    env = env_for(tmp_path / "data", CONFORMA_API_KEYS=f"{KEY}:operator", CONFORMA_EMBEDDED_WORKER="false")
    server = start(["serve", "--port", str(port)], env, tmp_path / "serve.log")
    try:
        wait_healthy(base, server, log=tmp_path / "serve.log")
        part = httpx.post(f"{base}/api/v1/parts", headers=HEADERS, timeout=60, files={
            "file": ("s1.stl", s1_mesh(grid_mm=2.0).export(file_type="stl"))}).json()
        small = httpx.post(f"{base}/api/v1/parts/{part['id']}/circuits:import", headers=HEADERS, timeout=120,
                           files=[("files", ("one.svg", heavy_svg(1).encode()))],
                           data={"options": json.dumps({"dry_run": True})})
        assert small.status_code == 201, small.text  # the fork server is up
        before = forked_children(server.pid)
        sock = _raw_import(port, part["id"], heavy_svg())
        deadline = time.monotonic() + 30
        while not (children := forked_children(server.pid) - before):
            assert time.monotonic() < deadline, "the import's child never started"
            time.sleep(0.02)
        time.sleep(1.0)  # well inside the import
        assert forked_children(server.pid) & children, "the import ended before the client went away"
        busy_health_s = _health_s(base)
        sock.close()
        closed = time.monotonic()
        while forked_children(server.pid) & children:
            assert time.monotonic() - closed < 2.0, "the import's child outlived its client by 2 s"
            time.sleep(0.02)
        gone_s = time.monotonic() - closed
        assert busy_health_s < 2.0 and _health_s(base) < 2.0
        again = httpx.post(f"{base}/api/v1/parts/{part['id']}/circuits:import", headers=HEADERS, timeout=120,
                           files=[("files", ("one.svg", heavy_svg(1).encode()))],
                           data={"options": json.dumps({"dry_run": True})})
        assert again.status_code == 201, again.text
        print(f"\nimport child gone {gone_s:.2f} s after the client closed; /health {busy_health_s:.3f} s during it")
    finally:
        stop(server)
    assert "Traceback" not in (tmp_path / "serve.log").read_text()  # the cancel is no server error
