"""A group of blobs stored at once (``BlobStore.put_many``, what a board job's checkpoint
stores): each file whole under its sha256, fsynced before its row, a duplicate written
once, no temporary file left behind, an existing blob not rewritten, and a write that fails
leaves neither a file nor a row."""

from __future__ import annotations

import hashlib
import os
import threading

import pytest
from sqlmodel import Session, select

from app.platform.blobs import BlobStore
from app.platform.db import make_engine, migrate
from app.platform.models import Blob


def _files(store: BlobStore) -> list[str]:
    return sorted(p.name for p in store.root.rglob("*") if p.is_file())


def test_a_group_is_written_whole_each_file_fsynced_before_the_rows(settings, monkeypatch):  # type: ignore[no-untyped-def]
    migrate(settings)
    engine = make_engine(settings)
    store = BlobStore(settings.blob_dir)
    items = [b"G1 X1 Y2\n" * 50, b"", b"second", b"G1 X1 Y2\n" * 50]
    expected = [hashlib.sha256(data).hexdigest() for data in items]
    with Session(engine) as session:
        earlier = store.put(session, b"second")  # already stored: its file is not written again
        session.commit()
        mtime = os.stat(store.path(earlier)).st_mtime_ns
        # a temporary file a dead writer with this pid and thread left: overwritten, not appended to
        leftover = store.path(expected[0]).parent / f".tmp-{expected[0]}-{os.getpid()}-{threading.get_ident()}"
        leftover.parent.mkdir(parents=True, exist_ok=True)
        leftover.write_bytes(b"half of something else" * 100)
        synced: list[int] = []
        real_fsync = os.fsync
        monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
        assert store.put_many(session, items) == expected
        session.commit()
        assert len(synced) == 2  # the two new files, each once (the duplicate and the stored one not again)
        for sha, data in zip(expected, items):
            assert store.read(sha) == data and hashlib.sha256(store.read(sha)).hexdigest() == sha
        assert os.stat(store.path(earlier)).st_mtime_ns == mtime
        rows = {b.sha256: b.bytes for b in session.exec(select(Blob)).all()}
        assert rows == {sha: len(data) for sha, data in zip(expected, items)}
    assert _files(store) == sorted(set(expected)) and not leftover.exists()
    engine.dispose()


def test_a_failed_write_leaves_no_file_and_no_row(settings, monkeypatch):  # type: ignore[no-untyped-def]
    migrate(settings)
    engine = make_engine(settings)
    store = BlobStore(settings.blob_dir)

    def full_disk(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with Session(engine) as session:
        with pytest.raises(OSError, match="No space"):
            store.put_many(session, [b"never stored"])
        session.rollback()
        assert session.exec(select(Blob)).all() == []
    assert _files(store) == []
    engine.dispose()
