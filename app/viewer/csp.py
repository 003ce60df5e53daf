"""The 3-D view's Content-Security-Policy, built from the page viser really serves.

viser's client is one ``index.html``: a single inline loader script whose ``data-p``
attribute packs the app (base-88 text of a zstd frame: ``data-ss`` bytes of CSS, then
``data-cs`` bytes of JavaScript).  The loader compiles a small zstd decoder from
WebAssembly, unpacks the payload, and inserts the CSS as a ``<style>`` element and the
JavaScript as an inline ``<script type="module">``.  The app then opens its websocket from
a ``blob:`` worker.  So the policy allows exactly:

- scripts: the sha256 of every inline script in the served HTML and of the module script
  the loader unpacks (no ``'unsafe-inline'``, no ``'unsafe-eval'``: viser's "run this
  JavaScript" message and any injected ``<script>`` or ``on*=`` handler are refused);
  ``'wasm-unsafe-eval'`` compiles WebAssembly only (the loader's and the app's decoders);
- styles: the unpacked stylesheet's hash would do for the loader, but the app's UI kit
  (Mantine) writes its theme variables into ``<style>`` elements at run time, so
  ``style-src`` needs ``'unsafe-inline'`` (styles cannot run script);
- ``connect-src``: the view's own websocket origins (the ones the handshake accepts) and
  ``data:`` (the app fetches its inlined WebAssembly from ``data:`` URLs): a page opened
  with ``?websocket=`` pointing anywhere else cannot connect there;
- ``worker-src blob:``, ``img-src 'self' data: blob:``, ``font-src 'self' data:``;
- ``frame-ancestors``: the view itself and the console pages that frame it (the console at
  the API's port on each host the view may be opened from); ``object-src 'none'``,
  ``base-uri 'none'``, ``form-action 'none'``, everything else ``'none'``.

The hashes are computed from each HTML body the server answers with (cached by the body's
digest), so a viser upgrade that changes its page is hashed anew.  A packed page this
module cannot unpack raises :class:`ClientPageError` (the view then refuses to start:
a policy without the module's hash would leave a blank view, one without hashes an open one).
"""

from __future__ import annotations

import base64
import gzip
import hashlib
import logging
import re
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from html.parser import HTMLParser

log = logging.getLogger("conforma.viewer")
_BASE88 = "!#$%()*+,-./0123456789:;=?@ABCDEFGHIJKLMNOPQRSTUVWXYZ[\\]^_abcdefghijklmnopqrstuvwxyz{|}~"
_BASE88_VALUE = {c: i for i, c in enumerate(_BASE88)}
MAX_UNPACKED_BYTES = 64 * 1024 * 1024  # bound on the unpacked client (viser 1.1: 2.7 MB)
_HTML_TYPE = re.compile(rb"^\s*text/html\b", re.I)


class ClientPageError(ValueError):
    """viser's page holds a packed client this module cannot unpack (the message says why)."""


def sha256_source(text: str) -> str:
    """A CSP hash source (``'sha256-<base64>'``) of ``text`` as UTF-8."""
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode("utf-8")).digest()).decode() + "'"


def base88_decode(text: str) -> bytes:
    """Bytes of viser's base-88 text: 5 characters per 4 bytes (big-endian), a last group of
    r characters giving r - 1 bytes (the loader's own decoding, mirrored)."""
    try:
        values = [_BASE88_VALUE[c] for c in text]
    except KeyError as exc:
        raise ClientPageError(f"the packed client holds a character outside base-88: {exc}") from None
    out = bytearray()
    whole = len(values) - len(values) % 5
    for i in range(0, whole, 5):
        v = 0
        for d in values[i:i + 5]:
            v = v * 88 + d
        out += (v % 2**32).to_bytes(4, "big")
    rest = values[whole:]
    if len(rest) == 1:
        raise ClientPageError("the packed client's base-88 text ends with a lone character")
    if rest:
        v = 0
        for d in rest:
            v = v * 88 + d
        out += (v % 256 ** (len(rest) - 1)).to_bytes(len(rest) - 1, "big")
    return bytes(out)


@dataclass(frozen=True)
class ClientSources:
    """What a served page runs: hash sources of its scripts and of its stylesheets."""

    scripts: tuple[str, ...]
    styles: tuple[str, ...]


class _PageScan(HTMLParser):
    """Collects inline ``<script>`` / ``<style>`` texts and the packed client's attributes."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.scripts: list[str] = []
        self.styles: list[str] = []
        self.packed: list[dict[str, str]] = []
        self._open: tuple[str, list[str]] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag in ("script", "style"):
            values = {k: v or "" for k, v in attrs}
            if tag == "script" and "src" in values:
                return  # external scripts are not served by viser; 'self' is not allowed, so it would be refused
            if tag == "script" and "data-p" in values:
                self.packed.append(values)
            self._open = (tag, [])

    def handle_data(self, data: str) -> None:
        if self._open is not None:
            self._open[1].append(data)

    def handle_endtag(self, tag: str) -> None:
        if self._open is not None and tag == self._open[0]:
            (self.scripts if tag == "script" else self.styles).append("".join(self._open[1]))
            self._open = None


def _unpack(attrs: dict[str, str]) -> tuple[str, str]:
    """(stylesheet, module script) packed in a loader script's data attributes."""
    import zstandard

    try:
        style_len, code_len = int(attrs.get("data-ss", "")), int(attrs.get("data-cs", ""))
    except ValueError:
        raise ClientPageError("the packed client's data-ss / data-cs are not byte counts") from None
    total = style_len + code_len
    if style_len < 0 or code_len < 0 or total > MAX_UNPACKED_BYTES:
        raise ClientPageError(f"the packed client claims {total} bytes (limit {MAX_UNPACKED_BYTES})")
    try:
        raw = zstandard.ZstdDecompressor().decompress(base88_decode(attrs["data-p"]), max_output_size=total)
    except zstandard.ZstdError as exc:
        raise ClientPageError(f"the packed client is not a zstd frame: {exc}") from None
    if len(raw) != total:
        raise ClientPageError(f"the packed client unpacks to {len(raw)} bytes, not data-ss + data-cs = {total}")
    decode = lambda b: b.decode("utf-8", errors="replace")  # noqa: E731 (TextDecoder's default)
    return decode(raw[:style_len]), decode(raw[style_len:])


def client_sources(page: str) -> ClientSources:
    """Hash sources of everything ``page`` (viser's HTML) runs and styles inline, including
    the stylesheet and module script its packed loader inserts."""
    scan = _PageScan()
    scan.feed(page.replace("\r\n", "\n").replace("\r", "\n"))  # the HTML parser's newline normalisation
    scan.close()
    scripts, styles = list(scan.scripts), list(scan.styles)
    for attrs in scan.packed:
        style, code = _unpack(attrs)
        if code:
            scripts.append(code)
        if style:
            styles.append(style)
    unique = lambda texts: tuple(dict.fromkeys(sha256_source(t) for t in texts))  # noqa: E731
    return ClientSources(unique(scripts), unique(styles))


def _nameable(origin: str) -> bool:
    """CSP source expressions cannot name an IPv6 literal host (``[::1]``): such an origin is
    covered by ``'self'`` alone (when it is the page's own)."""
    return "[" not in origin


def view_origins_to_ws(origins: Iterable[str]) -> list[str]:
    """The websocket origins (ws / wss) of page origins (http / https), IPv6 literals left out."""
    return sorted({("wss://" + o[len("https://"):]) if o.startswith("https://") else ("ws://" + o[len("http://"):])
                   for o in origins if o.startswith(("http://", "https://")) and _nameable(o)})


def console_origins(view_origins: Iterable[str], api_port: int) -> list[str]:
    """The console origins that frame the view: each view origin's scheme and host at the
    API's port (the console builds the view's address from its own host name)."""
    out = set()
    for origin in view_origins:
        scheme, _, rest = origin.partition("://")
        host = rest.rsplit(":", 1)[0] if not rest.endswith("]") else rest
        if scheme in ("http", "https") and host:
            out.add(f"{scheme}://{host}:{api_port}")
    return sorted(o for o in out if _nameable(o))


def page_policy(sources: ClientSources, ws_origins: Iterable[str], ancestors: Iterable[str]) -> str:
    """The CSP of the view's HTML page (see the module docstring)."""
    return "; ".join([
        "default-src 'none'",
        "script-src " + " ".join([*sources.scripts, "'wasm-unsafe-eval'"]),
        "style-src 'unsafe-inline'",
        "img-src 'self' data: blob:",
        "font-src 'self' data:",
        "connect-src " + " ".join(["'self'", *ws_origins, "data:"]),
        "worker-src blob:",
        "frame-ancestors " + " ".join(["'self'", *ancestors]),
        "object-src 'none'",
        "base-uri 'none'",
        "form-action 'none'",
    ])


def other_policy(ancestors: Iterable[str]) -> str:
    """The CSP of every other response of the view's port (files, errors, refusals)."""
    return "; ".join(["default-src 'none'", "frame-ancestors " + " ".join(["'self'", *ancestors]),
                      "object-src 'none'", "base-uri 'none'", "form-action 'none'"])


class ViewPolicy:
    """Adds the CSP to each response of the view's port (a websockets ``process_response``):
    HTML bodies get :func:`page_policy` with their own hashes, everything else
    :func:`other_policy`.  ``view_origins`` and ``api_port`` are read on each response
    (the view's port is known only once it is bound)."""

    def __init__(self, view_origins: Callable[[], frozenset[str]], api_port: int | None) -> None:
        self._view_origins = view_origins
        self._api_port = api_port
        self._lock = threading.Lock()
        self._sources: dict[bytes, ClientSources] = {}

    def _ancestors(self) -> list[str]:
        return console_origins(self._view_origins(), self._api_port) if self._api_port else []

    def sources_of(self, body: bytes, encoding: str) -> ClientSources:
        """The hash sources of an HTML body (gzip or identity), cached by its digest."""
        key = hashlib.sha256(body).digest()
        with self._lock:
            cached = self._sources.get(key)
        if cached is not None:
            return cached
        text = (gzip.decompress(body) if encoding.strip().lower() == "gzip" else body).decode("utf-8", "replace")
        sources = client_sources(text)
        with self._lock:
            if len(self._sources) > 16:
                self._sources.clear()
            self._sources[key] = sources
        return sources

    def policy_for(self, content_type: str, encoding: str, body: bytes) -> str:
        ancestors = self._ancestors()
        if body and _HTML_TYPE.match(content_type.encode()):
            return page_policy(self.sources_of(body, encoding), view_origins_to_ws(self._view_origins()), ancestors)
        return other_policy(ancestors)

    def __call__(self, connection: object, request: object, response: object) -> None:
        headers = response.headers  # type: ignore[attr-defined]
        try:
            policy = self.policy_for(headers.get("Content-Type", ""), headers.get("Content-Encoding", ""),
                                     response.body or b"")  # type: ignore[attr-defined]
        except (ClientPageError, OSError, EOFError) as exc:  # an unreadable page runs nothing
            log.error("viewer: cannot hash the page viser serves (%s); serving it with no script allowed", exc)
            policy = other_policy(self._ancestors())
        if "Content-Security-Policy" in headers:
            del headers["Content-Security-Policy"]
        headers["Content-Security-Policy"] = policy
        headers["X-Content-Type-Options"] = "nosniff"
        headers["Referrer-Policy"] = "no-referrer"
