"""API keys: static ones from settings and stored ones (only their sha256 is kept).

Roles are ordered viewer < operator < admin.  Lookups of stored keys are cached for a
few seconds per process; revoking through this process clears the cache at once.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time

from sqlalchemy import Engine, update
from sqlmodel import Session, select

from app.config import ROLES
from app.models import ApiKey, new_id, utcnow

ROLE_RANK = {role: rank for rank, role in enumerate(ROLES)}
CACHE_TTL_S = 5.0


def hash_key(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


def generate_key() -> str:
    return "cf_" + secrets.token_urlsafe(24)


def role_allows(have: str, need: str) -> bool:
    return ROLE_RANK[have] >= ROLE_RANK[need]


class KeyRing:
    """Resolves a presented key to its role."""

    def __init__(self, engine: Engine, static_keys: dict[str, str]) -> None:
        self.engine = engine
        self._static = {hash_key(k): role for k, role in static_keys.items()}
        self._cache: dict[str, tuple[str | None, float]] = {}
        self._lock = threading.Lock()

    def role_of(self, key: str) -> str | None:
        digest = hash_key(key)
        for known, role in self._static.items():
            if hmac.compare_digest(known, digest):
                return role
        now = time.monotonic()
        with self._lock:
            cached = self._cache.get(digest)
        if cached is not None and cached[1] > now:
            return cached[0]
        with Session(self.engine) as session:
            row = session.exec(select(ApiKey).where(ApiKey.key_sha256 == digest, ApiKey.revoked_at.is_(None))).first()
        role = row.role if row is not None else None
        with self._lock:
            self._cache[digest] = (role, now + CACHE_TTL_S)
        return role

    def create(self, role: str, name: str = "") -> tuple[ApiKey, str]:
        """Store a new key; returns the record and the key (shown once, never stored)."""
        if role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}")
        key = generate_key()
        record = ApiKey(id=new_id("key"), name=name, role=role, prefix=key[:8], key_sha256=hash_key(key), created_at=utcnow())
        with Session(self.engine, expire_on_commit=False) as session:
            session.add(record)
            session.commit()
        return record, key

    def revoke(self, key_id: str) -> bool:
        with Session(self.engine) as session:
            result = session.exec(  # type: ignore[call-overload]
                update(ApiKey).where(ApiKey.id == key_id, ApiKey.revoked_at.is_(None)).values(revoked_at=utcnow())
            )
            session.commit()
        with self._lock:
            self._cache.clear()
        return bool(result.rowcount)

    def has_any(self) -> bool:
        if self._static:
            return True
        with Session(self.engine) as session:
            return session.exec(select(ApiKey.id).where(ApiKey.revoked_at.is_(None))).first() is not None
