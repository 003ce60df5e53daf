"""``Idempotency-Key`` on creating POSTs (parts, traces, jobs, programs, files, machines).

A client that did not see the answer to a POST (timeout, dropped connection, 503) sends it
again with the same key and gets the same record back, never a second one:

* the answer is stored (``IdempotencyRecord``: status, body, Location) in the *same
  transaction* that creates the record, so a record exists exactly when its key does;
* a retry with the same key and the same request replays it (header ``Idempotent-Replayed:
  true``); the same key with a different request is a 422 naming the header;
* two concurrent first attempts both try to insert the key; the second one's transaction
  fails on the key's primary key, is rolled back whole, and replays the first one's answer.

Keys belong to the API key that sent them (two clients may use the same key) and are
printable ASCII up to 255 characters.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Header, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session

from app.domain.errors import InvalidInput
from app.platform.models import IdempotencyRecord, utcnow

IdempotencyKey = Annotated[str | None, Header(
    alias="Idempotency-Key", min_length=1, max_length=255, pattern=r"^[\x21-\x7e]+$",
    description="retry-safe creation: the same key and request return the same record (printable ASCII)")]
FIELD = "header.Idempotency-Key"


@dataclass(frozen=True)
class Claim:
    owner: str
    key: str
    scope: str
    request_sha256: str


def claim(request: Request, key: str | None, *fingerprint: bytes | str) -> Claim | None:
    """The claim of this request on ``key`` (None without a key).  ``fingerprint`` is what
    makes two requests the same (the validated body, an upload's bytes and fields)."""
    if key is None:
        return None
    scope = f"{request.method} {request.url.path}"
    digest = hashlib.sha256(scope.encode())
    for part in fingerprint:
        chunk = part.encode("utf-8", "surrogatepass") if isinstance(part, str) else part
        digest.update(len(chunk).to_bytes(8, "big"))
        digest.update(chunk)
    return Claim(getattr(request.state, "key_sha256", ""), key, scope, digest.hexdigest())


def replay(session: Session, claim: Claim | None) -> JSONResponse | None:
    """The stored answer for ``claim``'s key, or None if the key is new.  422 if the key was
    used for a different request."""
    if claim is None:
        return None
    row = session.get(IdempotencyRecord, (claim.owner, claim.key))
    if row is None:
        return None
    if row.scope != claim.scope or row.request_sha256 != claim.request_sha256:
        raise InvalidInput(f"Idempotency-Key {claim.key!r} was already used for a different request "
                           f"({row.scope}); use a new key for a new request", field=FIELD, value=claim.key)
    headers = {"Idempotent-Replayed": "true"}
    if row.location:
        headers["Location"] = row.location
    return JSONResponse(row.body, status_code=row.status_code, headers=headers)


def remember(session: Session, claim: Claim | None, status_code: int, body: BaseModel,
             location: str | None = None) -> None:
    """Add the answer to ``session`` (committed with the record it describes)."""
    if claim is None:
        return
    session.add(IdempotencyRecord(owner=claim.owner, key=claim.key, scope=claim.scope,
                                  request_sha256=claim.request_sha256, status_code=status_code,
                                  body=body.model_dump(mode="json"), location=location, created_at=utcnow()))


def commit(session: Session, claim: Claim | None) -> JSONResponse | None:
    """Commit; if a concurrent request committed the same key first, roll back and return
    its answer (None when this commit succeeded).  Other integrity errors propagate."""
    try:
        session.commit()
        return None
    except IntegrityError:
        session.rollback()
        winner = lost_race(session, claim)
        if winner is None:
            raise
        return winner


def lost_race(session: Session, claim: Claim | None) -> JSONResponse | None:
    """After a failed commit: the answer of the request that took the key first, if any."""
    if claim is None:
        return None
    session.expire_all()
    return replay(session, claim)


def canonical(body: Any) -> str:
    """A request model as canonical JSON (field order and spacing do not matter)."""
    return body.model_dump_json() if isinstance(body, BaseModel) else str(body)
