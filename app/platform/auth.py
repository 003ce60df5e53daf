"""API keys: static ones from settings and stored ones (only their sha256 is kept).

Roles are ordered viewer < operator < admin.  Lookups of stored keys are cached for a
few seconds per process in a bounded LRU (unknown keys too, so a flood of random keys
costs one query each and a fixed amount of memory); revoking through this process clears
the cache at once.  Failed attempts are counted per client address: after
``LoginThrottle.max_failures`` within ``window_s`` the address gets 429 until the window
passes, for wrong keys only: a valid key is always accepted, also from a throttled address
(an operator's emergency stop is never held off by someone guessing keys beside them).
A throttled address's keys are checked against a snapshot of every stored key's digest,
read in one query at most every ``CACHE_TTL_S`` whatever arrives, so a flood of wrong keys
from there costs no query each.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from collections import OrderedDict, deque

from sqlalchemy import Engine, update
from sqlmodel import Session, col, select

from app.platform.config import ROLES
from app.platform.models import ApiKey, new_id, utcnow

ROLE_RANK = {role: rank for rank, role in enumerate(ROLES)}
CACHE_TTL_S = 5.0
CACHE_MAX_ENTRIES = 4096


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
        self._cache: OrderedDict[str, tuple[str | None, float]] = OrderedDict()
        self._stored: tuple[dict[str, str], float] = ({}, float("-inf"))  # (digest -> role, valid until)
        self._lock = threading.Lock()

    def role_of(self, key: str, *, lookup: bool = True) -> str | None:
        """The key's role, or None if unknown or revoked.  ``lookup=False`` (throttled
        clients) answers from the static keys, the cache and the snapshot of stored keys
        (:meth:`stored_role`): no query per presented key."""
        digest = hash_key(key)
        for known, static_role in self._static.items():
            if hmac.compare_digest(known, digest):
                return static_role
        now = time.monotonic()
        with self._lock:
            cached = self._cache.get(digest)
            if cached is not None:
                self._cache.move_to_end(digest)
        if cached is not None and cached[1] > now:
            return cached[0]
        if not lookup:
            return self.stored_role(digest)
        with Session(self.engine) as session:
            row = session.exec(select(ApiKey).where(ApiKey.key_sha256 == digest,
                                                    col(ApiKey.revoked_at).is_(None))).first()
        role = row.role if row is not None else None
        with self._lock:
            self._cache[digest] = (role, now + CACHE_TTL_S)
            self._cache.move_to_end(digest)
            while len(self._cache) > CACHE_MAX_ENTRIES:
                self._cache.popitem(last=False)
        return role

    def stored_role(self, digest: str) -> str | None:
        """The role of the stored, unrevoked key with sha256 ``digest`` from a snapshot of all
        of them (re-read in one query when older than ``CACHE_TTL_S``)."""
        now = time.monotonic()
        with self._lock:
            stored, valid_until = self._stored
        if valid_until <= now:
            with Session(self.engine) as session:
                rows = session.exec(select(ApiKey.key_sha256, col(ApiKey.role))
                                    .where(col(ApiKey.revoked_at).is_(None))).all()
            stored = {sha: role for sha, role in rows}
            with self._lock:
                self._stored = (stored, now + CACHE_TTL_S)
        return stored.get(digest)

    @property
    def cache_size(self) -> int:
        return len(self._cache)

    def create(self, role: str, name: str = "") -> tuple[ApiKey, str]:
        """Store a new key; returns the record and the key (shown once, never stored)."""
        if role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}")
        key = generate_key()
        record = ApiKey(id=new_id("key"), name=name, role=role, prefix=key[:8], key_sha256=hash_key(key),
                        created_at=utcnow())
        with Session(self.engine, expire_on_commit=False) as session:
            session.add(record)
            session.commit()
        with self._lock:
            self._stored = ({}, float("-inf"))
        return record, key

    def revoke(self, key_id: str) -> bool:
        with Session(self.engine) as session:
            result = session.exec(
                update(ApiKey).where(col(ApiKey.id) == key_id,
                                     col(ApiKey.revoked_at).is_(None)).values(revoked_at=utcnow())
            )
            session.commit()
        with self._lock:
            self._cache.clear()
            self._stored = ({}, float("-inf"))
        return bool(result.rowcount)

    def has_any(self) -> bool:
        if self._static:
            return True
        with Session(self.engine) as session:
            return session.exec(select(col(ApiKey.id)).where(col(ApiKey.revoked_at).is_(None))).first() is not None


class LoginThrottle:
    """Failed key attempts per client address in a sliding window (bounded memory)."""

    def __init__(self, max_failures: int = 20, window_s: float = 60.0, max_addresses: int = 10_000,
                 clock=time.monotonic) -> None:
        self.max_failures = max_failures
        self.window_s = window_s
        self.max_addresses = max_addresses
        self._clock = clock
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()

    def retry_after(self, address: str) -> int | None:
        """Seconds until ``address`` may try again, or None when it is not throttled."""
        now = self._clock()
        with self._lock:
            times = self._failures.get(address)
            if not times:
                return None
            while times and times[0] <= now - self.window_s:
                times.popleft()
            if len(times) < self.max_failures:
                return None
            return max(1, int(times[0] + self.window_s - now + 0.999))

    def failed(self, address: str) -> None:
        now = self._clock()
        with self._lock:
            times = self._failures.setdefault(address, deque(maxlen=self.max_failures))
            times.append(now)
            self._failures.move_to_end(address)
            while len(self._failures) > self.max_addresses:
                self._failures.popitem(last=False)
