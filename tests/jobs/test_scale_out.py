"""The scale-out profile on real PostgreSQL + Redis (skipped, with the reason, when absent;
under ``CI=true`` a missing server fails the test: ``tests/helpers/real_components.py``).

Same models, same migrations, same job code: only CONFORMA_DATABASE_URL and
CONFORMA_QUEUE_URL change.  Servers default to the project machines' 127.0.0.1:5432 and
:6379 (override with CONFORMA_TEST_DATABASE_URL / CONFORMA_TEST_QUEUE_URL).
"""

from __future__ import annotations

import os
import secrets
import time

import pytest

from tests.helpers.real_components import missing

PG_ADMIN_URL = os.environ.get("CONFORMA_TEST_DATABASE_URL", "postgresql://postgres@127.0.0.1:5432/postgres")
REDIS_URL = os.environ.get("CONFORMA_TEST_QUEUE_URL", "redis://127.0.0.1:6379/15")


def _postgres_database():
    try:
        import psycopg
    except ImportError as exc:
        missing("PostgreSQL", f"psycopg is not installed: {exc}")
    try:
        admin = psycopg.connect(PG_ADMIN_URL, autocommit=True, connect_timeout=2)
    except Exception as exc:  # pragma: no cover - depends on the machine
        missing("PostgreSQL", f"not reachable at {PG_ADMIN_URL}: {exc}")
    name = f"conforma_test_{secrets.token_hex(4)}"
    admin.execute(f'CREATE DATABASE "{name}"')
    return admin, name


def _redis():
    try:
        import redis
    except ImportError as exc:
        missing("Redis", f"the redis client is not installed: {exc}")
    client = redis.Redis.from_url(REDIS_URL, socket_connect_timeout=2)
    try:
        client.ping()
    except Exception as exc:  # pragma: no cover
        missing("Redis", f"not reachable at {REDIS_URL}: {exc}")
    return client


@pytest.fixture
def scale_settings(settings_factory):
    redis_client = _redis()
    admin, name = _postgres_database()
    base = PG_ADMIN_URL.rsplit("/", 1)[0]
    for key in redis_client.scan_iter("huey.*conforma-*"):
        redis_client.delete(key)
    yield settings_factory(database_url=f"{base}/{name}", queue_url=REDIS_URL, lease_s=1.0)
    admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
    admin.close()


def test_jobs_run_on_postgres_and_redis(scale_settings):
    from fastapi.testclient import TestClient

    from app.main import create_app
    from tests.conftest import auth

    with TestClient(create_app(scale_settings)) as client:
        health = client.get("/api/v1/health").json()
        assert health["database"] == "postgresql" and health["queue"] == "redis"
        ids = [client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0.05, "artifact": True}},
                           headers=auth("operator")).json()["id"] for _ in range(5)]
        # the first compute jobs wait for the pool's forkserver to import the compute core:
        # ~6 s on an idle two-core box, ~30 s at load 10 (measured); the jobs themselves take 50 ms
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            states = [client.get(f"/api/v1/jobs/{i}", headers=auth("operator")).json()["status"] for i in ids]
            if all(s == "succeeded" for s in states):
                break
            time.sleep(0.05)
        assert states == ["succeeded"] * 5
        job = client.get(f"/api/v1/jobs/{ids[0]}", headers=auth("operator")).json()
        assert client.get(job["artifacts"][0]["url"], headers=auth("operator")).status_code == 200


def test_reaper_requeues_on_postgres(scale_settings):
    from app.platform.db import migrate
    from app.runtime.engine import Runtime

    migrate(scale_settings)
    runtime = Runtime(scale_settings)
    try:
        job = runtime.submit("test_sleep", {"seconds": 0})
        assert runtime.store.claim(job.id, "crashed") is not None
        runtime.start_workers(("default",))
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and runtime.store.status(job.id)[0] != "succeeded":
            time.sleep(0.05)
        assert runtime.store.status(job.id)[0] == "succeeded"
    finally:
        runtime.stop()
