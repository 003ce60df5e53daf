"""The gate every HTTP request passes before the routers: authentication before the body,
size limits, and JSON that can be stored.

* A request that carries a body under ``/api/`` is authenticated from its headers first
  (401 / 429 without reading one byte of the body; the role is checked later by the route).
* Multipart uploads may be up to ``upload_bytes``; other bodies up to ``json_bytes``.  A
  declared ``Content-Length`` over the limit is a 413 at once; a chunked body is counted
  as it arrives and answered with 413 the moment it passes the limit (the rest is never
  read; the route sees a disconnect).
* JSON bodies holding a lone UTF-16 surrogate escape (``"\\ud800"``), which Python parses
  but no database or response can encode, are a 422 naming the field.
"""

from __future__ import annotations

import json
import re
from typing import Any

from fastapi import HTTPException
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.deps import authenticate, presented_key
from app.platform.problems import PROBLEM_MEDIA_TYPE, problem

_BODY_METHODS = {"POST", "PUT", "PATCH", "DELETE"}
_SURROGATE_ESCAPE = re.compile(rb"\\u[dD][89a-fA-F]")


def lone_surrogate_path(value: Any, path: tuple[str, ...] = ()) -> tuple[str, ...] | None:
    """The path of the first string (or key) in parsed JSON that is not valid Unicode."""
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            return path
        return None
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, inner in items:
        if isinstance(key, str) and lone_surrogate_path(key, path) is not None:
            return (*path, key.encode("utf-8", "backslashreplace").decode())
        found = lone_surrogate_path(inner, (*path, str(key)))
        if found is not None:
            return found
    return None


async def send_problem(send: Send, status: int, title: str, detail: str, *, errors: list | None = None,
                        headers: dict[str, str] | None = None) -> None:
    body = json.dumps(problem(status, title, detail, errors=errors)).encode()
    raw = [(b"content-type", PROBLEM_MEDIA_TYPE.encode()), (b"content-length", str(len(body)).encode())]
    raw += [(k.lower().encode(), v.encode()) for k, v in (headers or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": raw})
    await send({"type": "http.response.body", "body": body})


class BodyLimitMiddleware:
    def __init__(self, app: ASGIApp, *, upload_bytes: int, json_bytes: int) -> None:
        self.app = app
        self.upload_bytes = upload_bytes
        self.json_bytes = json_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        has_body = scope["method"] in _BODY_METHODS and (
            headers.get("content-length", "0") not in ("", "0") or "transfer-encoding" in headers)
        if has_body and scope["path"].startswith("/api/") and not await self._authenticated(scope, headers, send):
            return
        content_type = headers.get("content-type", "")
        limit = self.upload_bytes if content_type.startswith("multipart/") else self.json_bytes
        declared = headers.get("content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            await self._too_large(send, int(declared), limit)
            return
        if has_body and ("json" in content_type.split(";")[0]):
            await self._json(scope, receive, send, limit)
            return
        await self.app(scope, *self._counted(receive, send, limit))

    async def _authenticated(self, scope: Scope, headers: Headers, send: Send) -> bool:
        state = scope["app"].state
        keyring, throttle = getattr(state, "keyring", None), getattr(state, "login_throttle", None)
        if keyring is None or throttle is None:  # not started yet: the route refuses anyway
            return True
        address = scope["client"][0] if scope.get("client") else "unknown"
        try:
            await run_in_threadpool(authenticate, keyring, throttle, presented_key(headers), address)
        except HTTPException as exc:
            titles = {401: "Unauthorized", 429: "Too many requests"}
            await send_problem(send, exc.status_code, titles.get(exc.status_code, "Error"), str(exc.detail),
                                headers=dict(exc.headers) if exc.headers else None)
            return False
        return True

    def _counted(self, receive: Receive, send: Send, limit: int) -> tuple[Receive, Send]:
        """(receive, send) that answer 413 once more than ``limit`` bytes arrived."""
        seen = 0
        started = rejected = False

        async def counting_receive() -> Message:
            nonlocal seen, rejected
            if rejected:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    rejected = True
                    if not started:
                        await self._too_large(send, seen, limit)
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if rejected:  # the 413 went out; whatever the route answers is dropped
                return
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        return counting_receive, guarded_send

    async def _json(self, scope: Scope, receive: Receive, send: Send, limit: int) -> None:
        """Read a JSON body (up to ``limit``), refuse lone surrogates, then replay it."""
        chunks: list[bytes] = []
        seen = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                return
            chunk = message.get("body", b"")
            seen += len(chunk)
            if seen > limit:
                await self._too_large(send, seen, limit)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        if _SURROGATE_ESCAPE.search(body):
            try:
                path = lone_surrogate_path(json.loads(body))
            except ValueError:
                path = None  # not JSON: the route's parser says so
            if path is not None:
                loc = ["body", *path]
                msg = "a lone UTF-16 surrogate escape is not valid Unicode text"
                await send_problem(send, 422, "Unprocessable input", f"{'.'.join(loc)}: {msg}",
                                    errors=[{"loc": loc, "msg": msg}])
                return
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if replayed:
                return await receive()
            replayed = True
            return {"type": "http.request", "body": body, "more_body": False}

        await self.app(scope, replay, send)

    @staticmethod
    async def _too_large(send: Send, size: int, limit: int) -> None:
        await send_problem(send, 413, "Payload too large",
                            f"the request body ({size} bytes or more) exceeds the limit of {limit} bytes")
