"""Row 9 (NPZ half): an upload's arrays are checked from their headers before it is stored."""

from __future__ import annotations

import tracemalloc

import numpy as np

from tests.conftest import auth
from tests.platform.test_array_files import bomb, npy, npz

OP = auth("operator")


def test_an_npz_bomb_is_refused_at_upload_without_inflating_it(client):
    data = bomb(800)  # 0.8 MB holding an 800 MiB array
    tracemalloc.start()  # traces the server's threads too (the test client runs it in-process)
    try:
        response = client.post("/api/v1/files", files={"file": ("heights.npz", data)}, headers=OP)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert response.status_code == 422, response.text
    assert response.json()["errors"][0]["loc"] == ["file"] and "800.0 MiB" in response.json()["detail"]
    assert peak < 20 * 2**20  # a few copies of the 0.8 MB body, never the 800 MiB (was +750 MB)
    assert client.get("/api/v1/files", headers=OP).json()["total"] == 0


def test_sound_npz_and_npy_uploads_are_kept_and_truncated_or_pickled_ones_refused(client):
    good = client.post("/api/v1/files", files={"file": ("h.npz", npz(heights=np.ones((20, 30))))}, headers=OP)
    assert good.status_code == 201 and good.json()["media_type"] == "application/zip"
    assert client.post("/api/v1/files", files={"file": ("h.npy", npy(np.ones(5)))}, headers=OP).status_code == 201
    truncated = client.post("/api/v1/files", files={"file": ("h.npy", npy(np.ones(5))[:-8])}, headers=OP)
    pickled = client.post("/api/v1/files", files={"file": ("o.npz", npz(o=np.array([None], dtype=object)))},
                          headers=OP)
    assert truncated.status_code == pickled.status_code == 422
    assert "object arrays" in pickled.json()["detail"]
