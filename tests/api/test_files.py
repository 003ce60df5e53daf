"""Uploaded data files: typed by their bytes, readable back, bad files refused."""

from __future__ import annotations

import hashlib
import io

import numpy as np
import pytest

from tests.conftest import auth

OP = auth("operator")


def npz_bytes() -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, heights=np.zeros((2, 3, 4)), layers=np.array([1, 2]))
    return buffer.getvalue()


@pytest.mark.parametrize(("name", "data", "media"), [
    ("heights.npz", npz_bytes(), "application/zip"),
    ("mask.png", b"\x89PNG\r\n\x1a\n" + b"\0" * 20, "image/png"),
    ("points.csv", b"x,y,z\n1,2,3\n", "text/csv"),
])
def test_upload_and_read_back(client, name, data, media):
    response = client.post("/api/v1/files", files={"file": (name, data)}, headers=OP)
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["media_type"] == media and body["bytes"] == len(data)
    assert body["sha256"] == hashlib.sha256(data).hexdigest()
    content = client.get(f"/api/v1/files/{body['id']}/content", headers=OP)
    assert content.content == data and content.headers["content-type"].startswith(media)
    assert client.get("/api/v1/files", headers=OP).json()["total"] == 1


@pytest.mark.parametrize(("name", "data", "needle"), [
    ("empty.npz", b"", "empty"), ("blob.bin", b"\x00\x01garbage", "unsupported"), ("bad.csv", b"\xff\xfe", "UTF-8")])
def test_bad_files_are_refused(client, name, data, needle):
    response = client.post("/api/v1/files", files={"file": (name, data)}, headers=OP)
    assert response.status_code == 422 and needle in response.json()["detail"]
    assert client.get("/api/v1/files", headers=OP).json()["total"] == 0
