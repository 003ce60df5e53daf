"""Idempotency-Key on every creating POST: the same key and request return the same
record (created once); the same key with another request is a 422 naming the header;
keys belong to the API key that sent them."""

from __future__ import annotations

import threading

import pytest
import trimesh
from sqlalchemy import func
from sqlmodel import Session, select

from app.platform.models import Job, Machine, Part, Program, Trace, UploadedFile
from tests.conftest import auth

OP, ADMIN = auth("operator"), auth("admin")
BOX = trimesh.creation.box(extents=(40.0, 40.0, 10.0)).export(file_type="stl")
LINE = {"name": "t", "geometry": {"type": "line", "start": [-10, 0], "end": [10, 0]}}


def _count(client, model) -> int:  # type: ignore[no-untyped-def]
    with Session(client.app.state.runtime.engine) as session:
        return session.exec(select(func.count()).select_from(model)).one()


@pytest.fixture
def part_id(client) -> str:  # type: ignore[no-untyped-def]
    return client.post("/api/v1/parts", files={"file": ("box.stl", BOX)}, headers=OP).json()["id"]


def _creations(part_id: str) -> dict:
    """name -> (model, request kwargs) for each creating POST, two different requests each."""
    return {
        "parts": (Part, lambda v: dict(url="/api/v1/parts", files={"file": (f"box{v}.stl", BOX)})),
        "traces": (Trace, lambda v: dict(url=f"/api/v1/parts/{part_id}/traces", json={**LINE, "name": f"t{v}"})),
        "jobs": (Job, lambda v: dict(url="/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": v}})),
        "programs": (Program,
                     lambda v: dict(url="/api/v1/programs", files={"file": ("p.gcode", f"G1 X{v}\n".encode())})),
        "files": (UploadedFile, lambda v: dict(url="/api/v1/files", files={"file": ("d.csv", f"{v},1\n".encode())})),
        "machines": (Machine, lambda v: dict(url="/api/v1/machines", json={"name": f"m{v}", "port": "mock://",
                                                                            "dialect": "marlin"})),
    }


@pytest.mark.parametrize("resource", ["parts", "traces", "jobs", "programs", "files", "machines"])
def test_same_key_same_record_and_a_different_request_is_refused(client, part_id, resource):  # type: ignore[no-untyped-def]
    model, request = _creations(part_id)[resource]
    before = _count(client, model)
    key = {"Idempotency-Key": f"key-{resource}-1"}
    first = client.post(**request(1), headers={**OP, **key})
    again = client.post(**request(1), headers={**OP, **key})
    assert first.status_code in (201, 202), first.text
    assert again.status_code == first.status_code and again.json()["id"] == first.json()["id"]
    assert again.headers["Idempotent-Replayed"] == "true" and "Idempotent-Replayed" not in first.headers
    assert again.headers.get("Location") == first.headers.get("Location")
    assert _count(client, model) == before + 1
    other = client.post(**request(2), headers={**OP, **key})
    assert other.status_code == 422 and other.json()["errors"][0]["loc"] == ["header", "Idempotency-Key"]
    # another API key may use the same Idempotency-Key for its own record
    own = client.post(**request(1), headers={**ADMIN, **key})
    assert own.status_code == first.status_code and own.json()["id"] != first.json()["id"]
    assert _count(client, model) == before + 2
    # without a key every POST creates
    assert client.post(**request(1), headers=OP).json()["id"] != first.json()["id"]


def test_concurrent_first_attempts_create_one_record(client):  # type: ignore[no-untyped-def]
    before = _count(client, Job)
    barrier = threading.Barrier(8)
    answers: list = []

    def submit() -> None:
        barrier.wait()
        answers.append(client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0}},
                                   headers={**OP, "Idempotency-Key": "same-moment"}))

    threads = [threading.Thread(target=submit) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert {a.status_code for a in answers} == {202}
    assert len({a.json()["id"] for a in answers}) == 1
    assert _count(client, Job) == before + 1


def test_bad_keys_are_422(client):  # type: ignore[no-untyped-def]
    for bad in ("", "x" * 256, "with space"):
        response = client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {}},
                               headers={**OP, "Idempotency-Key": bad})
        assert response.status_code == 422, (bad, response.text)
