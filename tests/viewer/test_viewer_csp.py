"""Every HTTP response of the 3-D view's port carries a Content-Security-Policy; the page's
policy runs exactly the scripts viser serves (their sha256, computed here independently
from the raw page), nothing inline besides, connects only to the view's own websocket and
may be framed only by the view itself and the console."""

from __future__ import annotations

import base64
import gzip
import hashlib
import http.client
import http.server
import re
import threading
from collections.abc import Iterator

import pytest
import viser
import zstandard
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from app.viewer.csp import ClientPageError, base88_decode, client_sources, other_policy
from app.viewer.server import ViewerStartError, check_page_policy
from tests.helpers.async_run import run_async
from tests.viewer.conftest import free_port

API_PORT = 8123
ALPHABET = "!#$%()*+,-./0123456789:;=?@ABCDEFGHIJKLMNOPQRSTUVWXYZ[\\]^_abcdefghijklmnopqrstuvwxyz{|}~"


@pytest.fixture(scope="module")
def view(tmp_path_factory) -> Iterator:  # type: ignore[no-untyped-def]
    from app.platform.config import load_settings
    from app.viewer.server import start_viewer

    settings = load_settings({}, data_dir=tmp_path_factory.mktemp("viewer-csp"), viewer=True,
                             viewer_port=free_port(), port=API_PORT, embedded_worker=False)
    viewer = start_viewer(settings, None)
    try:
        yield viewer
    finally:
        viewer.stop()


def _get(port: int, path: str, gzip_ok: bool = False) -> tuple[int, dict[str, str], bytes]:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        connection.request("GET", path, headers={"Accept-Encoding": "gzip" if gzip_ok else "identity"})
        response = connection.getresponse()
        return response.status, {k.lower(): v for k, v in response.getheaders()}, response.read()
    finally:
        connection.close()


def _upgrade(port: int, token: str | None, origin: str) -> tuple[int, dict[str, str]]:
    """(status, headers) of a websocket handshake; 101 = accepted."""
    async def attempt() -> tuple[int, dict[str, str]]:
        url = f"ws://127.0.0.1:{port}/" + (f"?token={token}" if token else "")
        try:
            async with connect(url, origin=origin, subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[arg-type]
                               open_timeout=10) as ws:
                assert ws.response is not None
                return ws.response.status_code, {k.lower(): v for k, v in ws.response.headers.raw_items()}
        except InvalidStatus as exc:
            return exc.response.status_code, {k.lower(): v for k, v in exc.response.headers.raw_items()}

    return run_async(attempt)


def _directives(policy: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for part in policy.split(";"):
        words = part.split()
        if words:
            assert words[0] not in out, f"directive {words[0]} given twice"
            out[words[0]] = words[1:]
    return out


def _sha(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode()).digest()).decode() + "'"


def _expected_script_hashes(page: str) -> set[str]:
    """The inline scripts of the raw page and the module its loader unpacks, decoded here
    with an independent base-88 decoder (integer arithmetic on the whole number)."""
    scripts = re.findall(r"<script\b([^>]*)>(.*?)</script>", page, re.S)
    expected = {_sha(body) for _attrs, body in scripts}
    for attrs, _body in scripts:
        packed = re.search(r'data-p="([^"]*)"', attrs)
        if packed is None:
            continue
        text = packed.group(1)
        whole = len(text) // 5 * 5
        raw = b"".join(_group(text[i:i + 5], 4) for i in range(0, whole, 5))
        if len(text) > whole:
            raw += _group(text[whole:], len(text) - whole - 1)
        style_len = int(re.search(r'data-ss="(\d+)"', attrs).group(1))  # type: ignore[union-attr]
        code_len = int(re.search(r'data-cs="(\d+)"', attrs).group(1))  # type: ignore[union-attr]
        unpacked = zstandard.ZstdDecompressor().decompress(raw, max_output_size=style_len + code_len)
        expected.add(_sha(unpacked[style_len:].decode()))
    return expected


def _group(chars: str, nbytes: int) -> bytes:
    value = 0
    for c in chars:
        value = value * 88 + ALPHABET.index(c)
    return value.to_bytes(nbytes, "big")


def test_the_page_policy_runs_exactly_the_served_scripts(view):  # type: ignore[no-untyped-def]
    port = view.port
    status, headers, body = _get(port, "/")
    assert status == 200 and headers["content-type"].startswith("text/html")
    page = body.decode()
    d = _directives(headers["content-security-policy"])
    expected = _expected_script_hashes(page)
    assert len(expected) == 2  # viser 1.1: the loader, and the app module it unpacks
    assert set(d["script-src"]) == expected | {"'wasm-unsafe-eval'"}
    assert d["default-src"] == ["'none'"]
    assert d["object-src"] == ["'none'"] and d["base-uri"] == ["'none'"] and d["form-action"] == ["'none'"]
    assert set(d["connect-src"]) == {"'self'", f"ws://127.0.0.1:{port}", f"ws://localhost:{port}", "data:"}
    assert set(d["frame-ancestors"]) == {"'self'", f"http://127.0.0.1:{API_PORT}", f"http://localhost:{API_PORT}"}
    assert d["worker-src"] == ["blob:"]
    assert headers["x-content-type-options"] == "nosniff" and headers["referrer-policy"] == "no-referrer"


def test_every_response_of_the_view_port_carries_the_csp(view):  # type: ignore[no-untyped-def]
    port = view.port
    html_policy = _get(port, "/")[1]["content-security-policy"]
    gz_status, gz_headers, gz_body = _get(port, "/", gzip_ok=True)
    assert gz_status == 200 and gz_headers["content-encoding"] == "gzip" and gzip.decompress(gz_body)
    assert gz_headers["content-security-policy"] == html_policy  # hashed from the gzip body alike
    assert _get(port, "/index.html")[1]["content-security-policy"] == html_policy
    rest = other_policy([f"http://127.0.0.1:{API_PORT}", f"http://localhost:{API_PORT}"])
    for path in ("/missing.js", "/%2e%2e/%2e%2e/etc/passwd", "/assets/", "/?websocket=ws://evil.example/"):
        status, headers, _ = _get(port, path)
        expected = html_policy if path.startswith("/?") else rest
        assert headers["content-security-policy"] == expected, (path, status)
    own = f"http://127.0.0.1:{port}"
    token = view.guard.signer.mint("csp_view").token
    for token_sent, origin, status_expected in ((None, own, 401), (token, "http://evil.example", 403),
                                                (token, own, 101)):
        status, headers = _upgrade(port, token_sent, origin)
        assert status == status_expected
        assert headers["content-security-policy"] == rest


def test_no_inline_or_eval_source_and_no_wildcard_in_any_directive(view):  # type: ignore[no-untyped-def]
    d = _directives(_get(view.port, "/")[1]["content-security-policy"])
    for directive, sources in d.items():
        assert "*" not in sources and "http:" not in sources and "https:" not in sources, directive
        if directive != "style-src":  # Mantine writes its theme into <style> elements at run time
            assert "'unsafe-inline'" not in sources, directive
        assert "'unsafe-eval'" not in sources and "'strict-dynamic'" not in sources, directive
        assert not any(s.startswith("'nonce-") for s in sources), directive


def test_base88_decoding_mirrors_the_loader():
    data = bytes(range(256)) * 3 + b"\x00\xff\x10"
    for n in (0, 1, 2, 3, 4, 5, 7, 8, 771):
        chunk = data[:n]
        text = "".join(_encode(chunk[i:i + 4]) for i in range(0, len(chunk), 4))
        assert base88_decode(text) == chunk
    with pytest.raises(ClientPageError):
        base88_decode("abcde" + "x")      # a lone last character encodes no byte
    with pytest.raises(ClientPageError):
        base88_decode("ab&de")            # outside the alphabet


def _encode(group: bytes) -> str:
    """viser's packer: 4 bytes -> 5 characters; a last group of k bytes -> k + 1 characters."""
    value = int.from_bytes(group, "big")
    width = 5 if len(group) == 4 else len(group) + 1
    chars = []
    for _ in range(width):
        value, digit = divmod(value, 88)
        chars.append(ALPHABET[digit])
    return "".join(reversed(chars))


def test_a_packed_page_that_cannot_be_unpacked_is_refused():
    page = '<script data-p="{}" data-ss="1" data-cs="1">loader()</script>'
    with pytest.raises(ClientPageError):
        client_sources(page.format("!!!!!!!!!!"))                 # not a zstd frame
    with pytest.raises(ClientPageError):
        client_sources(page.replace('data-ss="1"', 'data-ss="999999999"').format("!!!!!"))
    plain = client_sources("<html><script>a()</script><style>b{}</style><script src=/x.js></script></html>")
    assert plain.scripts == (_sha("a()"),) and plain.styles == (_sha("b{}"),)


def test_a_view_served_without_the_hashed_policy_does_not_start():
    """The start-up check reads the page back: a page without its script hashes is an error."""
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            body = b"<html><script>x()</script></html>"
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        with pytest.raises(ViewerStartError, match="without its script hashes"):
            check_page_policy("127.0.0.1", server.server_address[1], timeout_s=10)
    finally:
        server.shutdown()
        server.server_close()


def test_a_page_is_hashed_once_not_per_request(view, monkeypatch):  # type: ignore[no-untyped-def]
    """The hashes are cached by the body's digest: repeated page requests unpack nothing."""
    import app.viewer.csp as csp

    assert _get(view.port, "/")[0] == 200
    calls: list[int] = []
    real = csp.client_sources
    monkeypatch.setattr(csp, "client_sources", lambda page: calls.append(1) or real(page))
    for _ in range(3):
        assert "'sha256-" in _get(view.port, "/")[1]["content-security-policy"]
    assert calls == []
