"""The circuit import's dry run drawn in 3-D on the part before accepting: with a view_id the
dry run draws the draped traces, the pads and areas as patches and the pads' probe rings into
that view (nothing stored); traces a warning names are drawn again in red."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.reference.s1 import s1_mesh
from tests.api.test_circuits import GERBER_MM
from tests.conftest import auth
from tests.helpers.processes import free_port

OP = auth("operator")


@pytest.fixture
def vclient(settings_factory):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings_factory(viewer=True, viewer_port=free_port())),
                    raise_server_exceptions=False) as test_client:
        yield test_client


def _dry(client, part_id, data, **options):
    return client.post(f"/api/v1/parts/{part_id}/circuits:import", headers=OP,
                       files=[("files", ("top.gbr", data.encode()))],
                       data={"options": json.dumps({"dry_run": True, **options})})


def test_the_dry_run_is_drawn_on_the_part_in_the_view(vclient):
    stl = s1_mesh(grid_mm=1.0).export(file_type="stl")
    part = vclient.post("/api/v1/parts", files={"file": ("s1.stl", stl)}, headers=OP).json()
    view = vclient.post("/api/v1/viewer/token", json={}, headers=OP).json()["view_id"]
    # two traces 5 mm apart (widths 0.2) and a third crossing the first: a "too close" warning
    close = GERBER_MM.replace("X0Y5000000D02*", "X10000000Y-3000000D02*\nX10000000Y3000000D01*\nX0Y5000000D02*")
    wrapped = _dry(vclient, part["id"], GERBER_MM, origin_mm=[5, 10], mapping="wrap", view_id=view)
    assert wrapped.status_code == 201 and wrapped.json()["preview"]["drawn"], wrapped.text
    response = _dry(vclient, part["id"], close, origin_mm=[5, 10], view_id=view)
    assert response.status_code == 201, response.text
    body = response.json()
    assert vclient.get(f"/api/v1/parts/{part['id']}/traces", headers=OP).json()["total"] == 0   # nothing stored
    preview = body["preview"]
    assert preview["drawn"] and preview["view_id"] == view
    scene = vclient.get("/api/v1/viewer/scene", params={"view_id": view}, headers=OP).json()
    assert scene["focus"] == {"part_id": part["id"], "preview": body["import_id"]}
    nodes = scene["nodes"]
    assert nodes["/focus/part"]["kind"] == "mesh"
    traces = {k: v for k, v in nodes.items() if k.startswith("/focus/traces/")}
    assert len(traces) == 3
    warned = {i for w in body["warnings"] for i in w.get("traces", [])}
    assert warned, body["warnings"]
    red = nodes["/focus/toolpaths/warnings/dispense"]
    drawn = {i: len(t["trace"]["nominal"]["points"]) - 1 for i, t in enumerate(body["traces"])}
    assert red["count"] == sum(drawn[i] for i in warned)      # exactly the warned traces' segments
    pads = nodes["/focus/fields/pads"]
    assert pads["kind"] == "surface" and pads["count"] >= 4
    rings = nodes["/focus/probes/pad_probe_rings/planned"]
    assert rings["count"] == len(body["probe_paths"][0]["points"])
    # the ring's points lie on the part inside the pad (centre 30, 12.5; diameter 1 mm)
    ring = np.array(body["probe_paths"][0]["points"])
    assert np.linalg.norm(ring[:, :2] - [30.0, 12.5], axis=1).max() < 0.5


def test_without_the_viewer_the_dry_run_says_so(client):
    stl = s1_mesh(grid_mm=2.0).export(file_type="stl")
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", stl)}, headers=OP).json()
    body = _dry(client, part["id"], GERBER_MM, origin_mm=[5, 10], view_id="v1").json()
    assert body["preview"] == {"view_id": "v1", "drawn": False, "reason": "the 3D view is off on this server"}
    assert len(body["traces"]) == 2
