"""Small hardening cases, each as it can be met: lone surrogates, huge
coordinates, degenerate meshes, download names, auth before the body, chunked overflow,
throttled failed keys, a bounded key cache, security headers."""

from __future__ import annotations

import re
from urllib.parse import unquote

import numpy as np
import pytest
import trimesh

from app.platform.auth import CACHE_MAX_ENTRIES, LoginThrottle
from tests.conftest import auth

OP, VIEWER = auth("operator"), auth("viewer")
BOX = trimesh.creation.box(extents=(40.0, 40.0, 10.0))


def _stl(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    return trimesh.Trimesh(vertices, faces, process=False).export(file_type="stl")


@pytest.mark.parametrize("headers", [OP, VIEWER])
def test_a_lone_surrogate_is_a_422_naming_the_field(client, headers):  # type: ignore[no-untyped-def]
    part = client.post("/api/v1/parts", files={"file": ("b.stl", BOX.export(file_type="stl"))}, headers=OP).json()
    body = b'{"name": "a\\ud800", "geometry": {"type": "line", "start": [0, 0], "end": [1, 1]}}'
    response = client.post(f"/api/v1/parts/{part['id']}/traces", content=body,
                           headers={**headers, "content-type": "application/json"})
    assert response.status_code == 422 and response.json()["errors"][0]["loc"] == ["body", "name"]
    nested = client.post("/api/v1/jobs", content=b'{"kind": "test_sleep", "params": {"x": ["\\udc00"]}}',
                         headers={**OP, "content-type": "application/json"})
    assert nested.status_code == 422 and nested.json()["errors"][0]["loc"] == ["body", "params", "x", "0"]
    pair = client.post("/api/v1/jobs", content=b'{"kind": "\\ud83d\\ude00", "params": {}}',
                       headers={**OP, "content-type": "application/json"})  # a valid pair is just text
    assert pair.status_code == 422 and "\U0001F600" in pair.json()["detail"]


@pytest.mark.parametrize("value", [1e308, -1e308, 1e200, 1.000001e6])
def test_huge_coordinates_are_a_422_naming_the_field(client, value):  # type: ignore[no-untyped-def]
    part = client.post("/api/v1/parts", files={"file": ("b.stl", BOX.export(file_type="stl"))}, headers=OP).json()
    body = {"name": "t", "geometry": {"type": "line", "start": [0, value], "end": [1, 1]}}
    response = client.post(f"/api/v1/parts/{part['id']}/traces", json=body, headers=OP)
    assert response.status_code == 422
    assert response.json()["errors"][0]["loc"] == ["body", "geometry", "line", "start", "1"]


def test_degenerate_and_unbounded_meshes_are_refused_at_upload(client):  # type: ignore[no-untyped-def]
    flat = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3.0]])
    degenerate = _stl(flat, np.array([[0, 1, 2], [1, 2, 3]]))
    huge = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in BOX.vertices * 1e200) + \
        "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in BOX.faces)  # text: binary STL would cast to inf
    for name, data, word in (("m.stl", degenerate, "degenerate"), ("m.obj", huge.encode(), "within")):
        response = client.post("/api/v1/parts", files={"file": (name, data)}, headers=OP)
        assert response.status_code == 422, response.text
        assert response.json()["errors"][0]["loc"] == ["file"] and word in response.json()["detail"]
    assert client.get("/api/v1/parts", headers=OP).json()["total"] == 0


def test_download_names_follow_rfc_6266(client):  # type: ignore[no-untyped-def]
    file = client.post("/api/v1/files", files={"file": ("ключ.csv", b"1,2\n")}, headers=OP).json()
    response = client.get(f"/api/v1/files/{file['id']}/content", headers=OP)
    assert response.status_code == 200 and response.content == b"1,2\n"
    disposition = response.headers["content-disposition"]
    assert disposition.isascii()
    assert unquote(re.search(r"filename\*=UTF-8''(\S+)", disposition).group(1)) == "ключ.csv"
    assert 'filename="download.csv"' in disposition


@pytest.fixture
def live(settings_factory):  # type: ignore[no-untyped-def]
    """A real uvicorn server (in a thread) with a 1 MiB upload limit: (host, port)."""
    import threading
    import time

    import uvicorn

    from app.main import create_app
    from tests.helpers.processes import free_port

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings_factory(max_upload_mb=1)), host="127.0.0.1",
                                           port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    yield "127.0.0.1", port
    server.should_exit = True
    thread.join(10)


def _chunks_until_answer(address: tuple[str, int], key: str, chunks: int = 400) -> tuple[int, int]:
    """Stream a chunked multipart upload of ``chunks`` x 64 KiB; (HTTP status, chunks sent
    before the answer arrived)."""
    import select
    import socket

    with socket.create_connection(address) as sock:
        sock.sendall((f"POST /api/v1/files HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\n"
                      "Content-Type: multipart/form-data; boundary=b\r\nTransfer-Encoding: chunked\r\n\r\n").encode())
        part = b'--b\r\nContent-Disposition: form-data; name="file"; filename="big.csv"\r\n\r\n'
        sock.sendall(f"{len(part):x}\r\n".encode() + part + b"\r\n")
        chunk = b"10000\r\n" + b"1," * 32768 + b"\r\n"
        for sent in range(chunks):
            if select.select([sock], [], [], 0.02)[0]:
                break
            try:
                sock.sendall(chunk)
            except OSError:
                break
        else:
            sent = chunks
        sock.settimeout(10)
        status = int(sock.recv(4096).split(b" ", 2)[1])
    return status, sent


def test_no_body_is_read_before_the_key_is_checked(live):  # type: ignore[no-untyped-def]
    status, sent = _chunks_until_answer(live, "not-a-key-at-all")
    assert status == 401 and sent <= 3  # answered from the headers alone


def test_a_chunked_body_over_the_limit_is_a_413_at_the_limit(live):  # type: ignore[no-untyped-def]
    status, sent = _chunks_until_answer(live, "operator-key-123")
    assert status == 413 and sent <= 48  # the limit is 16 chunks; without the cut-off all 400 go


def test_failed_keys_are_throttled_and_a_valid_key_still_works(client):  # type: ignore[no-untyped-def]
    answers = [client.get("/api/v1/parts", headers={"Authorization": f"Bearer wrong-{i}"}) for i in range(25)]
    codes = [a.status_code for a in answers]
    assert codes[:20] == [401] * 20 and set(codes[20:]) == {429}
    assert int(answers[-1].headers["Retry-After"]) >= 1
    assert client.get("/api/v1/parts", headers=OP).status_code == 200


def test_the_unknown_key_cache_is_bounded(client, monkeypatch):  # type: ignore[no-untyped-def]
    assert CACHE_MAX_ENTRIES == 4096
    monkeypatch.setattr("app.platform.auth.CACHE_MAX_ENTRIES", 100)  # the same code path, fewer queries
    keyring = client.app.state.keyring
    for i in range(350):
        assert keyring.role_of(f"unknown-{i}") is None
    assert keyring.cache_size == 100
    assert keyring.role_of("operator-key-123") == "operator"


def test_throttle_window_passes():
    now = [0.0]
    throttle = LoginThrottle(max_failures=3, window_s=10, max_addresses=2, clock=lambda: now[0])
    for _ in range(3):
        throttle.failed("a")
    assert throttle.retry_after("a") == 10
    now[0] = 10.5
    assert throttle.retry_after("a") is None
    throttle.failed("b"), throttle.failed("c"), throttle.failed("d")
    assert len(throttle._failures) == 2


def test_pages_carry_security_headers(client):  # type: ignore[no-untyped-def]
    page = client.get("/machines.html")
    assert page.status_code == 200
    csp = page.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp and "unsafe-inline" not in csp
    assert page.headers["x-content-type-options"] == "nosniff" and page.headers["referrer-policy"] == "no-referrer"
    assert page.headers["x-frame-options"] == "DENY"
    api = client.get("/api/v1/health")
    assert api.headers["x-content-type-options"] == "nosniff"
    assert "frame-ancestors 'none'" in api.headers["content-security-policy"]


def test_pages_have_no_inline_scripts_or_styles():
    from pathlib import Path

    for page in Path("web").glob("*.html"):
        text = page.read_text()
        assert not re.search(r"<script(?![^>]*\bsrc=)[^>]*>", text), page
        assert " style=" not in text and "<style" not in text and " onclick=" not in text, page
    for script in Path("web/js").glob("*.js"):
        assert 'setAttribute("style"' not in script.read_text() and "style: " not in script.read_text(), script
