"""Dependencies shared by the routers: runtime, sessions, and role checks."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, HTTPException, Query, Request, Security
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from sqlmodel import Session

from app.auth import KeyRing, role_allows
from app.jobs.runtime import Runtime

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


def _require(need: str):  # type: ignore[no-untyped-def]
    async def check(
        keyring: Annotated[KeyRing, Depends(get_keyring)],
        bearer: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)] = None,
        header_key: Annotated[str | None, Security(_header)] = None,
    ) -> str:
        key = bearer.credentials if bearer is not None else header_key
        if not key:
            raise HTTPException(401, "an API key is required (Authorization: Bearer <key> or X-API-Key)",
                                headers={"WWW-Authenticate": "Bearer"})
        role = keyring.role_of(key)  # static keys and cached stored keys: no I/O on the hot path
        if role is None:
            raise HTTPException(401, "the API key is not valid (unknown or revoked)", headers={"WWW-Authenticate": "Bearer"})
        if not role_allows(role, need):
            raise HTTPException(403, f"this needs the {need} role; the key has the {role} role")
        return role

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
