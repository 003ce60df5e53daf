"""Circuit import over HTTP: dry run stores nothing, commit stores every trace with its
source, bad files are a 422 naming the line or entity and store nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.reference.s1 import s1_mesh
from tests.circuits.test_importers import GERBER_INCH, KICAD
from tests.conftest import auth

OP = auth("operator")

GERBER_MM = """%FSLAX46Y46*%
%MOMM*%
%ADD10C,0.200000*%
%ADD11C,1.000000*%
D10*
G01*
X0Y0D02*
X20000000Y0D01*
X0Y5000000D02*
X20000000Y5000000D01*
D11*
X25000000Y2500000D03*
M02*
"""


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=1.0).export(file_type="stl")


@pytest.fixture
def part(client, s1_stl):
    response = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP)
    assert response.status_code == 201
    return response.json()


def _import(client, part, name, data, **options):
    return client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", (name, data.encode()))], data={"options": json.dumps(options)})


def _count(client, part):
    return client.get(f"/api/v1/parts/{part['id']}/traces", headers=OP).json()["total"]


def test_gerber_dry_run_then_import_with_sources(client, part):
    dry = _import(client, part, "top.gbr", GERBER_MM, origin_mm=[5, 10], dry_run=True)
    assert dry.status_code == 201, dry.text
    body = dry.json()
    assert body["dry_run"] and _count(client, part) == 0
    assert [t["layout_length_mm"] for t in body["traces"]] == pytest.approx([20.0, 20.0], abs=1e-9)
    assert body["pads"][0]["center_mm"][:2] == pytest.approx([30.0, 12.5], abs=1e-9)
    done = _import(client, part, "top.gbr", GERBER_MM, origin_mm=[5, 10], standoff_mm=0.08)
    assert done.status_code == 201, done.text
    stored = done.json()["traces"]
    assert _count(client, part) == 3                          # two traces and the pad's probe ring
    ring_id = done.json()["pads"][0]["probe_trace_id"]
    assert done.json()["probe_trace_ids"] == [ring_id]
    ring = client.get(f"/api/v1/traces/{ring_id}", headers=OP).json()
    assert ring["source"]["role"] == "pad_probe"
    radius = np.linalg.norm(np.array(ring["nominal"]["points"])[:, :2] - [30.0, 12.5], axis=1)
    assert radius.max() < 0.5 and radius.min() > 0.1         # inside the 1 mm pad, half way in
    record = client.get(f"/api/v1/circuit-imports/{done.json()['import_id']}", headers=OP).json()
    assert record["probe_trace_ids"] == [ring_id] and len(record["trace_ids"]) == 2
    first = client.get(f"/api/v1/traces/{stored[0]['trace']['id']}", headers=OP).json()
    assert first["source"]["file"] == "top.gbr" and first["source"]["width_mm"] == pytest.approx(0.2)
    assert first["width_mm"] == pytest.approx(0.2) and first["standoff_mm"] == 0.08
    points = np.array(first["nominal"]["points"])
    np.testing.assert_allclose(points[[0, -1], :2], [[5, 10], [25, 10]], atol=1e-6)


def test_wrap_mapping_reports_stretch(client, part):
    response = _import(client, part, "top.gbr", GERBER_MM, origin_mm=[5, 10], mapping="wrap", dry_run=True)
    assert response.status_code == 201, response.text
    for t in response.json()["traces"]:
        assert t["stretch"] == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize(("name", "data", "where"), [
    ("top.gbr", GERBER_INCH.replace("D11*", "D13*"), "line 14"),
    ("board.kicad_pcb", KICAD[: KICAD.index("(arc")], "line 1"),
])
def test_bad_files_are_422_naming_the_line_and_store_nothing(client, part, name, data, where):
    response = _import(client, part, name, data, origin_mm=[5, 10])
    assert response.status_code == 422
    assert where in response.json()["detail"]
    assert _count(client, part) == 0


def test_wrong_layer_and_leaving_the_part_store_nothing(client, part):
    response = _import(client, part, "board.kicad_pcb", KICAD, layers=["In1.Cu"])
    assert response.status_code == 422 and "In1.Cu" in response.json()["detail"]
    off = _import(client, part, "top.gbr", GERBER_MM, origin_mm=[-100, 10])
    assert off.status_code == 422
    assert _count(client, part) == 0
    bad_options = _import(client, part, "top.gbr", GERBER_MM, mapping="bend")
    assert bad_options.status_code == 422 and "options.mapping" in bad_options.json()["detail"]
