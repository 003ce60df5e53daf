"""Row 8b: traces whose work would explode are refused in the request, before any sampling."""

from __future__ import annotations

import time

import numpy as np
import trimesh

from tests.conftest import auth

OP = auth("operator")


def test_a_huge_arc_and_a_100k_point_trace_are_refused_quickly_naming_the_field(client):
    box = trimesh.creation.box([100, 100, 10])
    box.apply_translation([50, 50, 5])
    part = client.post("/api/v1/parts", files={"file": ("b.stl", box.export(file_type="stl"))}, headers=OP).json()
    url = f"/api/v1/parts/{part['id']}/traces"
    arc = {"type": "arc", "center": [50, 50], "radius": 1e9, "start_deg": 0, "end_deg": 90}
    started = time.perf_counter()
    refused = client.post(url, json={"name": "arc", "geometry": arc, "standoff_mm": 0.1}, headers=OP)
    assert refused.status_code == 422 and time.perf_counter() - started < 1.0  # was > 20 s and 1-3 GB
    # the request schema bounds every coordinate-like number (±1e6 mm) first
    assert refused.json()["errors"][0]["loc"] == ["body", "geometry", "arc", "radius"]
    # within the schema's bound, the core's radius limit (1e5 mm) names the field
    arc["radius"] = 5e5
    refused = client.post(url, json={"name": "arc", "geometry": arc, "standoff_mm": 0.1}, headers=OP)
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"] == ["geometry", "radius"]
    points = np.random.default_rng(1).uniform(5, 95, (100_000, 2)).round(3).tolist()
    started = time.perf_counter()
    refused = client.post(url, json={"name": "many", "geometry": {"type": "polyline", "points": points},
                                     "standoff_mm": 0.1}, headers=OP)
    assert refused.status_code == 422 and time.perf_counter() - started < 10.0  # was 78 s and 1.2 GB
    assert refused.json()["errors"][0]["loc"] == ["geometry", "points"]
    assert client.get(url, headers=OP).json()["total"] == 0
