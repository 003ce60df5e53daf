"""A job's artifacts stored a few at a time: the same rows, files and order as one by one."""

from __future__ import annotations

from sqlmodel import Session, select

from app.platform.models import Artifact
from app.runtime.context import JobContext


def _rows(runtime, job_id: str) -> list[tuple[str, str, int, str, dict]]:
    with Session(runtime.engine) as session:
        rows = session.exec(select(Artifact).where(Artifact.job_id == job_id).order_by(Artifact.id)).all()
        return [(r.name, r.sha256, r.bytes, r.media_type, r.meta) for r in rows]


def test_a_batch_stores_what_one_by_one_stores_and_flushes_at_its_bound(runtime):
    files = [("a.txt", b"alpha" * 10, "text/plain", {"n": 1}), ("b.bin", bytes(range(200)), "application/octet-stream",
             None), ("c.txt", b"gamma", "text/plain", {"n": 3}), ("d.txt", b"delta" * 30, "text/plain", {})]
    one = runtime.store.claim(runtime.submit("test_sleep", {"seconds": 0}).id, "w1")
    ctx = JobContext(runtime, one)
    for name, data, media, meta in files:
        ctx.artifact(name, data, media, meta)
    expected = _rows(runtime, one.job_id)

    together = runtime.store.claim(runtime.submit("test_sleep", {"seconds": 0}).id, "w1")
    ctx = JobContext(runtime, together)
    with ctx.artifact_batch(max_bytes=240) as batch:
        batch.add(*files[0])  # 50 bytes wait
        assert _rows(runtime, together.job_id) == []
        batch.add(*files[1])  # 250 >= 240: both stored now
        assert [row[0] for row in _rows(runtime, together.job_id)] == ["a.txt", "b.bin"]
        batch.add(*files[2])
        batch.add(*files[3])  # 155 bytes wait until the end of the block
        assert len(_rows(runtime, together.job_id)) == 2
    assert _rows(runtime, together.job_id) == expected
    for _, sha, size, _, _ in expected:
        assert len(runtime.blobs.read(sha)) == size


def test_a_batch_left_by_an_error_stores_nothing_more(runtime):
    claim = runtime.store.claim(runtime.submit("test_sleep", {"seconds": 0}).id, "w1")
    ctx = JobContext(runtime, claim)
    try:
        with ctx.artifact_batch() as batch:
            batch.add("half.txt", b"half", "text/plain")
            raise RuntimeError("the job failed half way")
    except RuntimeError:
        pass
    assert _rows(runtime, claim.job_id) == []
