"""Security headers on every response; a strict Content-Security-Policy on the pages.

The operator's pages hold the API key (local storage) and the emergency STOP button, so
they may not be framed by anyone (``frame-ancestors 'none'``), run only their own scripts,
and frame only the 3D view's port.  API responses get ``nosniff`` and no referrer; the
interactive docs (``/docs``, which load Swagger UI from a CDN) keep their own scripts but
may not be framed either.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

_COMMON = ((b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"))
_NO_FRAMING = ((b"x-frame-options", b"DENY"),)
_API_PREFIXES = ("/api/", "/docs", "/redoc", "/openapi.json")


def page_policy(viewer_port: int | None) -> str:
    """The pages' CSP; the 3D view is framed from its own port on any host name the page uses."""
    frames = f" http://*:{viewer_port} https://*:{viewer_port}" if viewer_port else ""
    return ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
            f"connect-src 'self'; frame-src 'self'{frames}; frame-ancestors 'none'; object-src 'none'; "
            "base-uri 'none'; form-action 'self'")


class SecurityHeadersMiddleware:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path: str = scope.get("path", "")
        extra: tuple[tuple[bytes, bytes], ...] = _COMMON + _NO_FRAMING
        if path.startswith(_API_PREFIXES):
            extra += ((b"content-security-policy", b"frame-ancestors 'none'"),)
        else:
            viewer = getattr(scope["app"].state, "viewer", None) if "app" in scope else None
            extra += ((b"content-security-policy", page_policy(viewer.port if viewer else None).encode()),)

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                present = {k.lower() for k, _ in message.get("headers", [])}
                message["headers"] = list(message.get("headers", [])) + [h for h in extra if h[0] not in present]
            await send(message)

        await self.app(scope, receive, with_headers)
