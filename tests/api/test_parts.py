"""Parts: every supported format in, checked facts out; bad files refused without a trace."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
import trimesh

from app.parts.intake import export_mesh
from tests.conftest import auth

OP = auth("operator")


def box_bytes(fmt: str) -> bytes:
    box = trimesh.creation.box([40.0, 60.0, 10.0])
    if fmt == "stl_ascii":
        return (box.export(file_type="stl_ascii").encode() if isinstance(box.export(file_type="stl_ascii"), str)
                else box.export(file_type="stl_ascii"))
    if fmt == "glb":  # as glTF specifies: metres, +Y up
        return export_mesh(box, "glb")
    data = box.export(file_type=fmt)
    return data.encode() if isinstance(data, str) else data


def upload(client, name: str, data: bytes, headers=OP):
    return client.post("/api/v1/parts", files={"file": (name, data)}, headers=headers)


@pytest.mark.parametrize(("fmt", "ext"), [("stl", "stl"), ("stl_ascii", "stl"), ("obj", "obj"), ("ply", "ply"),
                                          ("off", "off"), ("3mf", "3mf"), ("glb", "glb")])
def test_upload_every_format_reports_true_geometry(client, fmt, ext):
    response = upload(client, f"block.{ext}", box_bytes(fmt))
    assert response.status_code == 201, response.text
    part = response.json()
    assert part["faces"] == 12 and part["vertices"] == 8
    assert np.allclose(part["bounds"], [[-20, -30, -5], [20, 30, 5]])
    assert part["watertight"] is True
    assert part["volume_mm3"] == pytest.approx(40 * 60 * 10)
    assert part["area_mm2"] == pytest.approx(2 * (40 * 60 + 40 * 10 + 60 * 10))


def test_download_round_trips(client):
    part = upload(client, "block.stl", box_bytes("stl")).json()
    for fmt, ft in (("stl", "stl"), ("glb", "glb")):
        data = client.get(f"/api/v1/parts/{part['id']}/mesh?format={fmt}", headers=OP)
        assert data.status_code == 200
        mesh = trimesh.load(io.BytesIO(data.content), file_type=ft, force="mesh")
        mm3_per_unit = 1e9 if fmt == "glb" else 1.0   # GLB is in metres, as glTF specifies
        assert mesh.volume * mm3_per_unit == pytest.approx(24000.0)
        again = upload(client, f"again.{fmt}", data.content).json()
        assert np.allclose(again["bounds"], part["bounds"], atol=1e-5)
    assert client.get(f"/api/v1/parts/{part['id']}/mesh?format=obj", headers=OP).status_code == 422


def nan_obj() -> bytes:
    return b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n"


def zip_bomb() -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("3D/3dmodel.model", b"\0" * (400 * 2**20))
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("name", "data", "status", "needle"),
    [
        ("garbage.stl", bytes(range(256)) * 40, 422, "not a valid binary STL"),
        ("empty.stl", b"", 422, "empty"),
        ("nan.obj", nan_obj(), 422, "non-finite"),
        ("nofaces.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", 422, "no faces"),
        ("part.step", b"ISO-10303-21;", 422, "unsupported mesh format"),
        ("bomb.3mf", zip_bomb(), 422, "zip bomb"),
        ("notzip.3mf", b"not a zip at all", 422, "zip"),
    ],
)
def test_bad_meshes_are_refused_and_nothing_is_stored(client, settings, name, data, status, needle):
    response = upload(client, name, data)
    assert response.status_code == status, response.text
    assert needle in response.json()["detail"]
    assert response.json()["errors"][0]["loc"] == ["file"]
    assert client.get("/api/v1/parts", headers=OP).json()["total"] == 0
    assert not any(p.is_file() for p in settings.blob_dir.rglob("*")) if settings.blob_dir.exists() else True


def test_upload_over_the_size_limit_is_413(settings_factory):
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings_factory(max_upload_mb=0.001))) as client:
        response = upload(client, "big.stl", box_bytes("stl") * 2)
        assert response.status_code == 413 and "exceeds the limit" in response.json()["detail"]
        assert client.get("/api/v1/parts", headers=OP).json()["total"] == 0


def test_viewer_cannot_upload_and_delete_needs_operator(client):
    assert upload(client, "block.stl", box_bytes("stl"), headers=auth("viewer")).status_code == 403
    part = upload(client, "block.stl", box_bytes("stl")).json()
    assert client.delete(f"/api/v1/parts/{part['id']}", headers=auth("viewer")).status_code == 403
    assert client.delete(f"/api/v1/parts/{part['id']}", headers=OP).status_code == 204
    assert client.get(f"/api/v1/parts/{part['id']}", headers=OP).status_code == 404


def test_same_bytes_share_one_blob(client, settings):
    data = box_bytes("stl")
    first, second = upload(client, "a.stl", data).json(), upload(client, "b.stl", data).json()
    assert first["sha256"] == second["sha256"] and first["id"] != second["id"]
    assert len([p for p in settings.blob_dir.rglob("*") if p.is_file()]) == 1
