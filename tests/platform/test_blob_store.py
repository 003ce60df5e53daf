"""A group of blobs stored at once (``BlobStore.put_many``, what a board job's checkpoint
stores): each file whole under its sha256, the group made durable by ONE flush of the
filesystem before any of its files is renamed into place (an fsync each where the platform
has no syncfs), a duplicate written once, no temporary file left behind, an existing blob
not rewritten, and a write or a flush that fails leaves none of the group's files and no row."""

from __future__ import annotations

import hashlib
import os
import threading

import pytest
from sqlmodel import Session, select

from app.platform import blobs
from app.platform.blobs import BlobStore
from app.platform.db import make_engine, migrate
from app.platform.models import Blob


def _files(store: BlobStore) -> list[str]:
    return sorted(p.name for p in store.root.rglob("*") if p.is_file())


def _blobs(store: BlobStore) -> list[str]:
    """The blob files in place (not the temporary ones)."""
    return [name for name in _files(store) if not name.startswith(".tmp-")]


def _temporaries(store: BlobStore) -> list[str]:
    return [p.name for p in store.root.rglob(".tmp-*")]


def _recording_syncfs(store: BlobStore, seen: list[tuple[list[str], list[str]]]):  # type: ignore[no-untyped-def]
    """A syncfs that records (the blob files, the temporary files) present when it is called."""
    real = blobs._SYNCFS
    assert real is not None, "this platform has syncfs (Linux)"

    def syncfs(fd: int) -> int:
        seen.append((_blobs(store), _temporaries(store)))
        return real(fd)  # type: ignore[no-any-return]
    return syncfs


@pytest.mark.skipif(blobs._SYNCFS is None, reason="syncfs is Linux's")
def test_a_group_is_written_whole_flushed_once_before_any_file_is_renamed(settings, monkeypatch):  # type: ignore[no-untyped-def]
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
        seen: list[tuple[list[str], list[str]]] = []
        monkeypatch.setattr(blobs, "_SYNCFS", _recording_syncfs(store, seen))
        assert store.put_many(session, items) == expected
        session.commit()
        assert synced == []  # no fsync per file...
        # ...one flush, while the two new files (the duplicate and the stored one not again) were
        # temporaries and only the blob stored before was in place
        assert len(seen) == 1 and seen[0][0] == [earlier] and len(seen[0][1]) == 2
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


def test_without_syncfs_each_new_file_is_fsynced_before_it_is_renamed(settings, monkeypatch):  # type: ignore[no-untyped-def]
    migrate(settings)
    engine = make_engine(settings)
    store = BlobStore(settings.blob_dir)
    items = [b"one", b"two", b"one"]
    synced: list[tuple[list[str], int]] = []
    real_fsync = os.fsync
    monkeypatch.setattr(blobs, "_SYNCFS", None)
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append((_blobs(store), fd)), real_fsync(fd)))
    with Session(engine) as session:
        shas = store.put_many(session, items)
        session.commit()
    assert [files for files, _ in synced] == [[], []]  # each new file once, none renamed yet
    assert [store.read(sha) for sha in shas] == items and not _temporaries(store)
    engine.dispose()


@pytest.mark.parametrize("failing", ["flush", "second write"])
def test_a_group_that_fails_part_way_leaves_none_of_its_files(settings, monkeypatch, failing):  # type: ignore[no-untyped-def]
    """The first file of the group was written whole before the failure: it is not visible
    either (all of a group or none of it), and no temporary file stays."""
    migrate(settings)
    engine = make_engine(settings)
    store = BlobStore(settings.blob_dir)
    if failing == "flush":
        def full_disk(root: str, paths: list[str]) -> None:
            raise OSError(28, "No space left on device")
        monkeypatch.setattr(blobs, "sync_written", full_disk)
    else:
        real_write, calls = os.write, []

        def write(fd: int, data) -> int:  # type: ignore[no-untyped-def]
            calls.append(fd)
            if len(calls) == 2:
                raise OSError(28, "No space left on device")
            return real_write(fd, data)
        monkeypatch.setattr(os, "write", write)
    with Session(engine) as session:
        with pytest.raises(OSError, match="No space"):
            store.put_many(session, [b"first, whole", b"second", b"third"])
        session.rollback()
        assert session.exec(select(Blob)).all() == []
    monkeypatch.undo()
    assert _files(store) == [] and _temporaries(store) == []
    engine.dispose()
