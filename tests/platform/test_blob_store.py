"""A group of blobs stored at once (``BlobStore.put_many``, what a board job's checkpoint
stores): each file whole under its sha256, on disk before its name and its name before its
row (two flushes of the filesystem for the whole group), a duplicate written once, no
temporary file left behind, an existing blob not rewritten, and a flush that fails leaves
neither a file nor a row."""

from __future__ import annotations

import hashlib
import os
import sys
import threading

import pytest
from sqlmodel import Session, select

from app.platform import blobs
from app.platform.blobs import BlobStore
from app.platform.db import make_engine, migrate
from app.platform.models import Blob


def _files(store: BlobStore) -> list[str]:
    return sorted(p.name for p in store.root.rglob("*") if p.is_file())


def test_a_group_is_written_whole_flushed_before_its_names_and_the_names_before_the_rows(
        settings, monkeypatch):  # type: ignore[no-untyped-def]
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
        flushes: list[tuple[list[str], list[bool], int]] = []
        real_flush = blobs.flush_to_disk

        def flush(root, paths):  # type: ignore[no-untyped-def]
            new = [store.path(sha) for sha in (expected[0], expected[1])]
            rows = len(session.exec(select(Blob)).all())
            flushes.append(([os.path.basename(p) for p in paths], [p.exists() for p in new], rows))
            real_flush(root, paths)

        monkeypatch.setattr(blobs, "flush_to_disk", flush)
        assert store.put_many(session, items) == expected
        session.commit()
        files, folders = flushes[0][0], flushes[1][0]
        assert len(flushes) == 2  # the whole group: the files, then their names
        assert sorted(files) == sorted(f".tmp-{sha}-{os.getpid()}-{threading.get_ident()}" for sha in expected[:2])
        assert flushes[0][1:] == ([False, False], 1)  # the files are on disk before their names and rows
        assert flushes[1][1:] == ([True, True], 1)    # the names before the rows
        assert sorted(folders) == sorted({sha[:2] for sha in expected[:2]})
        for sha, data in zip(expected, items):
            assert store.read(sha) == data and hashlib.sha256(store.read(sha)).hexdigest() == sha
        assert os.stat(store.path(earlier)).st_mtime_ns == mtime
        rows = {b.sha256: b.bytes for b in session.exec(select(Blob)).all()}
        assert rows == {sha: len(data) for sha, data in zip(expected, items)}
    assert _files(store) == sorted(set(expected)) and not leftover.exists()
    engine.dispose()


def test_a_failed_flush_leaves_no_file_and_no_row(settings, monkeypatch):  # type: ignore[no-untyped-def]
    migrate(settings)
    engine = make_engine(settings)
    store = BlobStore(settings.blob_dir)

    def full_disk(root, paths) -> None:  # type: ignore[no-untyped-def]
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(blobs, "flush_to_disk", full_disk)
    with Session(engine) as session:
        with pytest.raises(OSError, match="No space"):
            store.put_many(session, [b"never stored", b"nor this"])
        session.rollback()
        assert session.exec(select(Blob)).all() == []
    assert _files(store) == []
    engine.dispose()


def test_the_filesystem_is_synced_once_on_linux_else_every_path_is_fsynced(tmp_path, monkeypatch):
    paths = [tmp_path / name for name in ("a", "b", "c")]
    for path in paths:
        path.write_bytes(path.name.encode())
    if sys.platform.startswith("linux"):
        assert blobs._SYNCFS is not None
    calls: list[int] = []
    monkeypatch.setattr(blobs, "_SYNCFS", lambda fd: calls.append(fd) or 0)
    monkeypatch.setattr(os, "fsync", lambda fd: pytest.fail("fsync with syncfs at hand"))
    blobs.flush_to_disk(tmp_path, [str(p) for p in paths])
    assert len(calls) == 1
    monkeypatch.setattr(blobs, "_SYNCFS", lambda fd: -1)
    with pytest.raises(OSError, match="syncfs"):
        blobs.flush_to_disk(tmp_path, [str(p) for p in paths])
    synced: list[int] = []
    monkeypatch.setattr(blobs, "_SYNCFS", None)
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd))
    blobs.flush_to_disk(tmp_path, [str(p) for p in paths])
    assert len(synced) == 3
