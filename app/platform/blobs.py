"""Content-addressed files under ``data_dir/blobs/ab/abcdef...`` listed in the ``blobs`` table.

A blob is written to a temporary file, flushed to disk and renamed into place before its row
is inserted, so a crash never leaves a row pointing at a missing or partial file.  A group
(:meth:`BlobStore.put_many`, a board job's hundreds of programs) is flushed with two syncs of
the store's filesystem, one for the files and one for their names, not one fsync per file.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlmodel import Session

from app.platform.models import Blob, utcnow

_BLOBS = Blob.__table__  # type: ignore[attr-defined]



def write_atomically(target: Path, write: Callable[[BinaryIO], object]) -> None:
    """Write ``target`` whole or not at all: ``write`` fills a temporary file beside it, which
    is fsynced and renamed over ``target`` (a reader sees the old file, the new one, or none)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".tmp-")
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _syncfs() -> Callable[[int], int] | None:
    """libc's ``syncfs(fd)`` (Linux), or None where it is missing.  Looked up among the
    symbols the process already has (no ``find_library``: it runs ``ldconfig`` at import)."""
    function = getattr(ctypes.CDLL(None, use_errno=True), "syncfs", None)
    if function is not None:
        function.argtypes, function.restype = [ctypes.c_int], ctypes.c_int
    return function


_SYNCFS = _syncfs()


def flush_to_disk(root: Path, paths: list[str]) -> None:
    """Put ``paths`` (files or folders under ``root``) on disk: one ``syncfs`` of ``root``'s
    filesystem (every dirty page of it, so one call for hundreds of files; it reports
    write-back errors since Linux 5.8), else an fsync of each path.  OSError when it fails."""
    if _SYNCFS is not None:
        fd = os.open(root, os.O_RDONLY | os.O_CLOEXEC)
        try:
            if _SYNCFS(fd) != 0:
                error = ctypes.get_errno()
                raise OSError(error, f"syncfs {root}: {os.strerror(error)}")
        finally:
            os.close(fd)
        return
    for path in paths:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class BlobStore:
    """Bytes in, sha256 out; files are immutable once written."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def path(self, sha256: str) -> Path:
        return self.root / sha256[:2] / sha256

    def put(self, session: Session, data: bytes) -> str:
        """Store ``data`` (idempotent) and list it in ``session``; returns its sha256."""
        digest = hashlib.sha256(data).hexdigest()
        target = self.path(digest)
        if not target.exists():
            write_atomically(target, lambda handle: handle.write(data))
        return _record(session, digest, len(data))

    def put_many(self, session: Session, items: list[bytes]) -> list[str]:
        """:meth:`put` of each of ``items``, their rows inserted in ONE statement (a board job
        stores hundreds at once); their sha256 in order.  The new files are written as
        temporary files, flushed together (:func:`flush_to_disk`), renamed into place and
        their names flushed, all before the rows: a failure before the renames leaves no
        file, one after them files without rows (complete; the sweep removes them)."""
        digests = [hashlib.sha256(data).hexdigest() for data in items]
        sizes: dict[str, int] = {}
        folders: set[str] = set()
        written: list[tuple[str, str]] = []
        try:
            for digest, data in zip(digests, items):
                if digest not in sizes and not os.path.exists(target := self._target(digest, folders)):
                    written.append((self._write_temporary(target, data), target))
                sizes[digest] = len(data)
            if written:
                flush_to_disk(self.root, [tmp for tmp, _ in written])
                for tmp, target in written:
                    os.replace(tmp, target)
                flush_to_disk(self.root, sorted({os.path.dirname(target) for _, target in written}))
        except BaseException:
            for tmp, _ in written:
                Path(tmp).unlink(missing_ok=True)
            raise
        if sizes:
            now = utcnow()
            session.connection().execute(_insert_new(session), [
                {"sha256": sha, "bytes": size, "created_at": now} for sha, size in sizes.items()])
        return digests

    def _target(self, digest: str, folders: set[str]) -> str:
        """The blob's file name; its folder created unless in ``folders`` (the ones known to
        exist, grown as they are created)."""
        folder = os.path.join(self.root, digest[:2])
        if folder not in folders:
            os.makedirs(folder, exist_ok=True)
            folders.add(folder)
        return os.path.join(folder, digest)

    @staticmethod
    def _write_temporary(target: str, data: bytes) -> str:
        """``data`` written (not flushed) to a temporary file beside ``target``; its name.  The
        name is the blob's, this process's and this thread's (no other writer uses it; one a
        dead process with the same pid left is overwritten), not one of random names tried
        until one is free."""
        tmp = f"{os.path.dirname(target)}/.tmp-{os.path.basename(target)}-{os.getpid()}-{threading.get_ident()}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
            finally:
                os.close(fd)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return tmp

    def put_file(self, session: Session, handle: BinaryIO, chunk: int = 1 << 20) -> str:
        """Store the rest of the open binary file ``handle`` from its start (idempotent),
        copying and hashing it chunk by chunk (memory: one chunk); returns its sha256."""
        handle.seek(0)
        self.root.mkdir(parents=True, exist_ok=True)
        digest, size = hashlib.sha256(), 0
        fd, tmp = tempfile.mkstemp(dir=self.root, prefix=".tmp-")
        try:
            with os.fdopen(fd, "wb") as out:
                while block := handle.read(chunk):
                    digest.update(block)
                    out.write(block)
                    size += len(block)
                out.flush()
                os.fsync(out.fileno())
            sha = digest.hexdigest()
            target = self.path(sha)
            target.parent.mkdir(parents=True, exist_ok=True)
            if target.exists():
                Path(tmp).unlink()
            else:
                os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return _record(session, sha, size)

    def read(self, sha256: str) -> bytes:
        return self.path(sha256).read_bytes()


#: a temporary or row-less file younger than this may belong to a write in flight (another
#: process renames a blob into place before it inserts its row): the sweep leaves it
SWEEP_GRACE_S = 3600.0


def sweep_blobs(store: BlobStore, session: Session, grace_s: float = SWEEP_GRACE_S,
                now: float | None = None) -> dict[str, int]:
    """Delete what crashes left in ``store`` and no row lists: ``.tmp-*`` files and blob files
    whose sha256 has no row, both only when older than ``grace_s``.  Returns the counts
    ``{"temporary": n, "orphans": m}``."""
    import time

    from sqlmodel import select

    now = time.time() if now is None else now
    counts = {"temporary": 0, "orphans": 0}
    if not store.root.is_dir():
        return counts
    known: set[str] | None = None
    for path in store.root.rglob("*"):
        try:
            if not path.is_file() or now - path.stat().st_mtime < grace_s:
                continue
        except OSError:
            continue
        if path.name.startswith(".tmp-"):
            path.unlink(missing_ok=True)
            counts["temporary"] += 1
            continue
        if len(path.name) != 64 or path.parent.name != path.name[:2]:
            continue
        if known is None:
            known = set(session.exec(select(Blob.sha256)).all())
        if path.name not in known:
            path.unlink(missing_ok=True)
            counts["orphans"] += 1
    return counts


def _insert_new(session: Session) -> Any:
    """``INSERT INTO blobs ... ON CONFLICT DO NOTHING`` in the session's dialect, its values
    bound per execution (one compiled statement, executed for one row or many)."""
    insert = pg_insert if session.get_bind().dialect.name == "postgresql" else sqlite_insert
    return insert(_BLOBS).on_conflict_do_nothing()


def _record(session: Session, sha: str, size: int) -> str:
    """Insert the blob's row unless it exists (the file is already in place); its sha256."""
    session.connection().execute(_insert_new(session), {"sha256": sha, "bytes": size, "created_at": utcnow()})
    return sha
