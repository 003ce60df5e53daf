"""Files a crash leaves in the blob store (temporary files, blob files whose row was never
inserted) are swept at start once older than the grace period; everything else stays."""

from __future__ import annotations

import os
import time

from sqlmodel import Session

from app.platform.blobs import SWEEP_GRACE_S, BlobStore, sweep_blobs
from app.platform.db import make_engine, migrate


def _age(path, seconds: float) -> None:  # type: ignore[no-untyped-def]
    then = time.time() - seconds
    os.utime(path, (then, then))


def test_old_leftovers_go_young_ones_and_listed_blobs_stay(settings):  # type: ignore[no-untyped-def]
    migrate(settings)
    engine = make_engine(settings)
    store = BlobStore(settings.blob_dir)
    with Session(engine) as session:
        kept = store.put(session, b"listed")
        session.commit()
        _age(store.path(kept), 2 * SWEEP_GRACE_S)
        orphan, young = "ab" * 32, "cd" * 32
        for sha, age in ((orphan, 2 * SWEEP_GRACE_S), (young, 10.0)):
            store.path(sha).parent.mkdir(parents=True, exist_ok=True)
            store.path(sha).write_bytes(b"no row")
            _age(store.path(sha), age)
        tmp = store.path(kept).parent / ".tmp-crashed"
        tmp.write_bytes(b"half")
        _age(tmp, 2 * SWEEP_GRACE_S)
        assert sweep_blobs(store, session) == {"temporary": 1, "orphans": 1}
    assert store.path(kept).exists() and store.path(young).exists()
    assert not store.path(orphan).exists() and not tmp.exists()
    engine.dispose()


def test_the_server_sweeps_at_start(settings):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    stale = settings.blob_dir / "ef" / (".tmp-" + "x" * 8)
    stale.parent.mkdir(parents=True, exist_ok=True)
    stale.write_bytes(b"half")
    _age(stale, 2 * SWEEP_GRACE_S)
    with TestClient(create_app(settings)):
        assert not stale.exists()
