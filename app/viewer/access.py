"""Who may open the 3D view: short-lived signed tokens and an Origin check at the websocket
handshake.

viser has no authentication hooks (FIELD_NOTES), but the ``websockets`` server it runs on
takes a documented ``process_request`` callback that can refuse the opening handshake
with an HTTP response.  :func:`guarded_viser_serve` wraps ``websockets.asyncio.server.serve``
only while a viser server starts, chaining our check in front of viser's own callback;
:class:`HandshakeGuard` then refuses every websocket upgrade without a valid token or
from a foreign Origin (401 / 403) before a single scene message is sent.  If viser ever
stops going through that call, :func:`guarded_viser_serve` notices and the start-up fails:
the view is never served open.  The same wrapper chains the view's Content-Security-Policy
(:mod:`app.viewer.csp`) into websockets' documented ``process_response`` hook, which sees
every response of the port (viser's static files, refusals, upgrades): it depends on
websockets' API only, not on viser's internals, so it survives viser upgrades that keep
serving through websockets (and a viser that stopped doing so fails the start-up check
above instead of serving without a policy).

A token is ``<view id>.<expiry (unix s)>.<HMAC-SHA256 hex>`` over the first two parts with
a per-install secret (``CONFORMA_VIEWER_SECRET`` or ``<data dir>/viewer.secret``, created
with mode 0600 on first use).  The view id names whose focus the connection shows.
"""

from __future__ import annotations

import hashlib
import hmac
import http
import inspect
import os
import re
import secrets
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

VIEW_ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,40}$")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")


class TokenError(Exception):
    """The token is missing, malformed, forged or expired (the message says which)."""


@dataclass(frozen=True)
class ViewToken:
    token: str
    view_id: str
    expires_at: float  # unix seconds


def load_secret(data_dir: Path, configured: str | None = None) -> bytes:
    """The signing secret: ``configured`` if given, else ``data_dir/viewer.secret`` (made once)."""
    if configured:
        return configured.encode()
    path = data_dir / "viewer.secret"
    data_dir.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return path.read_bytes().strip()
    with os.fdopen(fd, "w") as handle:
        handle.write(secrets.token_hex(32))
    return path.read_bytes().strip()


class TokenSigner:
    """Mints and checks view tokens (``ttl_s`` seconds of validity, checked at connect)."""

    def __init__(self, secret: bytes, ttl_s: float, clock: Callable[[], float] = time.time) -> None:
        if len(secret) < 16:
            raise ValueError("the viewer secret must have at least 16 bytes")
        self._secret = secret
        self.ttl_s = ttl_s
        self._clock = clock

    def _sign(self, body: str) -> str:
        return hmac.new(self._secret, body.encode(), hashlib.sha256).hexdigest()

    def mint(self, view_id: str | None = None) -> ViewToken:
        view_id = view_id or "view_" + secrets.token_hex(8)
        if not VIEW_ID_RE.match(view_id):
            raise ValueError(f"a view id has 1-40 letters, digits, '_' or '-': {view_id[:60]!r}")
        expires = int(self._clock() + self.ttl_s)
        body = f"{view_id}.{expires}"
        return ViewToken(f"{body}.{self._sign(body)}", view_id, float(expires))

    def verify(self, token: str | None) -> str:
        """The token's view id; TokenError if it is missing, forged or expired."""
        if not token:
            raise TokenError("a view token is required")
        parts = token.split(".")
        if len(parts) != 3 or not VIEW_ID_RE.match(parts[0]) or not parts[1].isdigit():
            raise TokenError("the view token is malformed")
        body = f"{parts[0]}.{parts[1]}"
        if not hmac.compare_digest(self._sign(body), parts[2]):
            raise TokenError("the view token's signature is wrong")
        if int(parts[1]) < self._clock():
            raise TokenError("the view token has expired; reload the page for a new one")
        return parts[0]


def token_from_path(path: str) -> str | None:
    """The ``token`` query parameter of a request target such as ``/?token=...``."""
    values = parse_qs(urlsplit(path).query).get("token")
    return values[0] if values else None


def allowed_origins(host: str, port: int, extra: Iterable[str] = ()) -> frozenset[str]:
    """Origins a view page may be served from: the view's own address on loopback (and on
    the bound host unless it is a wildcard), plus configured ones."""
    hosts = set(LOOPBACK_HOSTS)
    if host not in ("0.0.0.0", "::", ""):
        hosts.add(f"[{host}]" if ":" in host else host)
    return frozenset({f"http://{h}:{port}" for h in hosts} | {o.rstrip("/") for o in extra if o})


class HandshakeGuard:
    """The ``process_request`` check: plain HTTP (viser's static client, which holds no data)
    passes; a websocket upgrade needs an allowed Origin and a valid token.  Accepted
    connections are remembered with their view id (``view_of``)."""

    def __init__(self, signer: TokenSigner, origins: Callable[[], frozenset[str]]) -> None:
        self.signer = signer
        self._origins = origins
        self._views: weakref.WeakKeyDictionary[Any, str] = weakref.WeakKeyDictionary()
        self._lock = threading.Lock()
        self.refused = 0

    def __call__(self, connection: Any, request: Any) -> Any:
        if (request.headers.get("Upgrade") or "").lower() != "websocket":
            return None
        origin = (request.headers.get("Origin") or "").rstrip("/")
        if origin not in self._origins():
            return self._refuse(connection, http.HTTPStatus.FORBIDDEN, f"origin {origin or '(none)'!r} is not allowed")
        try:
            view_id = self.signer.verify(token_from_path(request.path))
        except TokenError as exc:
            return self._refuse(connection, http.HTTPStatus.UNAUTHORIZED, str(exc))
        with self._lock:
            self._views[connection] = view_id
        return None

    def _refuse(self, connection: Any, status: http.HTTPStatus, reason: str) -> Any:
        self.refused += 1
        return connection.respond(status, reason + "\n")

    def view_of(self, connection: Any) -> str | None:
        """The view id the connection was accepted for (forgotten once read)."""
        with self._lock:
            return self._views.pop(connection, None)


@contextmanager
def guarded_viser_serve(guard: Callable[[Any, Any], Any],
                        respond: Callable[[Any, Any, Any], Any] | None = None) -> Iterator[threading.Event]:
    """While active, ``websockets.asyncio.server.serve`` runs ``guard`` before the caller's
    own ``process_request``, and ``respond`` (e.g. the view's CSP) on every response after the
    caller's own ``process_response``: websockets calls it for the static files viser serves
    from its ``process_request``, for refusals and for accepted upgrades alike.  Yields an
    event set once a server was built through it."""
    import websockets.asyncio.server as ws_server

    original = ws_server.serve
    installed = threading.Event()

    async def _call(hook: Any, *args: Any) -> Any:
        answer = hook(*args)
        return await answer if inspect.isawaitable(answer) else answer

    class _GuardedServe(original):  # type: ignore[misc, valid-type]
        def __init__(self, handler: Any, *args: Any, process_request: Any = None, process_response: Any = None,
                     **kwargs: Any) -> None:
            inner, inner_response = process_request, process_response

            async def process(connection: Any, request: Any) -> Any:
                refusal = guard(connection, request)
                if refusal is not None or inner is None:
                    return refusal
                return await _call(inner, connection, request)

            async def processed(connection: Any, request: Any, response: Any) -> Any:
                replaced = await _call(inner_response, connection, request, response) if inner_response else None
                final = replaced if replaced is not None else response
                if respond is not None:
                    await _call(respond, connection, request, final)
                return replaced

            super().__init__(handler, *args, process_request=process, process_response=processed, **kwargs)
            installed.set()

    ws_server.serve = _GuardedServe  # type: ignore[misc]  # websockets' serve, patched while viser starts
    try:
        yield installed
    finally:
        ws_server.serve = original  # type: ignore[misc]
