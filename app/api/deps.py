"""Dependencies shared by the routers: runtime, sessions, and role checks."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Query, Request, Security
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from sqlmodel import Session

from app.platform.auth import KeyRing, LoginThrottle, hash_key, role_allows
from app.runtime.engine import Runtime

_bearer = HTTPBearer(auto_error=False, description="API key as a bearer token")
_header = APIKeyHeader(name="X-API-Key", auto_error=False, description="API key")


# Dependencies are ``async`` when they do no blocking I/O: FastAPI runs sync dependencies
# in the thread pool, one hand-off each, which dominated the cost of small reads.
async def get_runtime(request: Request) -> Runtime:
    return request.app.state.runtime


async def get_keyring(request: Request) -> KeyRing:
    return request.app.state.keyring


async def get_session(runtime: Annotated[Runtime, Depends(get_runtime)]) -> AsyncIterator[Session]:
    """A session for the request; it opens a connection only at its first query."""
    session = Session(runtime.engine, expire_on_commit=False)
    try:
        yield session
    finally:
        session.close()


def authenticate(keyring: KeyRing, throttle: LoginThrottle, key: str | None, address: str) -> str:
    """The role of ``key``; 401 when missing or unknown, 429 (Retry-After) for an address
    with too many recent failures: a wrong key from there is refused without a look-up, a
    valid key (static or stored) always works from it."""
    if not key:
        raise HTTPException(401, "an API key is required (Authorization: Bearer <key> or X-API-Key)",
                            headers={"WWW-Authenticate": "Bearer"})
    wait = throttle.retry_after(address)
    role = keyring.role_of(key, lookup=wait is None)  # throttled: the stored keys' snapshot, no query per key
    if role is None:
        if wait is not None:
            raise HTTPException(429, f"too many failed API key attempts from {address}; retry in {wait} s",
                                headers={"Retry-After": str(wait)})
        throttle.failed(address)
        raise HTTPException(401, "the API key is not valid (unknown or revoked)",
                            headers={"WWW-Authenticate": "Bearer"})
    return role


def presented_key(headers: Any) -> str | None:
    """The key of ``Authorization: Bearer <key>`` or ``X-API-Key``."""
    scheme, _, credentials = (headers.get("authorization") or "").partition(" ")
    if scheme.lower() == "bearer" and credentials.strip():
        return credentials.strip()
    return headers.get("x-api-key") or None


def _require(need: str):
    async def check(
        request: Request,
        keyring: Annotated[KeyRing, Depends(get_keyring)],
        bearer: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)] = None,
        header_key: Annotated[str | None, Security(_header)] = None,
    ) -> str:
        key = bearer.credentials if bearer is not None else header_key
        address = request.client.host if request.client else "unknown"
        role = authenticate(keyring, request.app.state.login_throttle, key, address)
        if not role_allows(role, need):
            raise HTTPException(403, f"this needs the {need} role; the key has the {role} role")
        request.state.key_sha256 = hash_key(key or "")  # whose Idempotency-Keys these are
        return role

    check.needs_role = need  # type: ignore[attr-defined]  # read by app.api.openapi_errors
    return check


Viewer = Depends(_require("viewer"))
Operator = Depends(_require("operator"))
Admin = Depends(_require("admin"))
RuntimeDep = Annotated[Runtime, Depends(get_runtime)]
SessionDep = Annotated[Session, Depends(get_session)]


# Paging of every list endpoint (``?limit=&offset=``); bounded so that SQL never sees an
# out-of-range integer.
Limit = Annotated[int, Query(ge=1, le=1000, description="page size")]
Offset = Annotated[int, Query(ge=0, le=2**31 - 1, description="items to skip")]
