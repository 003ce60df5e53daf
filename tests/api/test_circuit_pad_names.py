"""Names an operator reads: two pads of one footprint that share a number (mounting pads)
get probe rings of different names, and a ring's name says its file and pad."""

from __future__ import annotations

import json

import pytest

from app.reference.s1 import s1_mesh
from tests.conftest import auth

OP = auth("operator")
BOARD = """(kicad_pcb (version 20221018) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))
  (net 0 "")
  (net 1 "GND")
  (footprint "USB_C" (layer "F.Cu") (at 10 -10)
    (property "Reference" "J1")
    (pad "MP" smd rect (at -3 0) (size 1.2 1.2) (layers "F.Cu") (net 1 "GND"))
    (pad "MP" smd rect (at 3 0) (size 1.2 1.2) (layers "F.Cu") (net 1 "GND"))
    (pad "1" smd rect (at 0 0) (size 1.2 1.2) (layers "F.Cu") (net 1 "GND"))
  )
  (segment (start 7 10) (end 13 10) (width 0.25) (layer "F.Cu") (net 1))
)
"""


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=1.0).export(file_type="stl")


def test_two_pads_sharing_a_number_get_rings_of_different_names(client, s1_stl):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()
    done = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", ("usb.kicad_pcb", BOARD.encode()))],
                       data={"options": json.dumps({"origin_mm": [20.0, 20.0]})})
    assert done.status_code == 201, done.text
    body = done.json()
    assert [p["name"] for p in body["pads"]] == ["J1.MP", "J1.MP", "J1.1"]   # as the board names them
    rings = [client.get(f"/api/v1/traces/{tid}", headers=OP).json()["name"] for tid in body["probe_trace_ids"]]
    assert len(rings) == 3 and len(set(rings)) == 3, rings
    assert sorted(rings) == ["usb.kicad_pcb:J1.1 (pad probe)", "usb.kicad_pcb:J1.MP #2 (pad probe)",
                             "usb.kicad_pcb:J1.MP (pad probe)"]
