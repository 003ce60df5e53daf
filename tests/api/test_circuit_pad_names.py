"""Names an operator reads: two pads of one footprint that share a number (mounting pads)
get probe rings of different names, and a ring's name says its file and pad; jobs in lists
are titled part · trace (net) · what they are, one step back through the jobs they read."""

from __future__ import annotations

import json

import pytest

from app.reference.s1 import s1_mesh
from tests.api.test_machines import register
from tests.circuits.boards import USB_PADS_BOARD as BOARD
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=1.0).export(file_type="stl")


def _imported(client, s1_stl):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, data={"name": "dome"}, headers=OP).json()
    return part, client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", ("usb.kicad_pcb", BOARD.encode()))],
                             data={"options": json.dumps({"origin_mm": [20.0, 20.0]})})


def test_pad_rings_have_their_own_names_and_jobs_are_listed_by_part_trace_and_net(client, s1_stl):
    part, done = _imported(client, s1_stl)
    assert done.status_code == 201, done.text
    body = done.json()
    assert [p["name"] for p in body["pads"]] == ["J1.MP", "J1.MP", "J1.1"]   # as the board names them
    rings = [client.get(f"/api/v1/traces/{tid}", headers=OP).json()["name"] for tid in body["probe_trace_ids"]]
    assert len(rings) == 3 and len(set(rings)) == 3, rings
    assert sorted(rings) == ["usb.kicad_pcb:J1.1 (pad probe)", "usb.kicad_pcb:J1.MP #2 (pad probe)",
                             "usb.kicad_pcb:J1.MP (pad probe)"]

    # jobs in lists: part · trace (net) · kind
    assert part["name"] == "dome"
    (trace,) = [t["trace"] for t in done.json()["traces"]]
    plan = client.post("/api/v1/jobs", headers=OP, json={"kind": "probe_plan", "params": {
        "trace_id": trace["id"], "method": "uniform", "count": 6}}).json()
    wait_for(client, plan["id"], timeout=60)
    machine = register(client).json()
    run = client.post("/api/v1/jobs", headers=OP, json={"kind": "probe_run", "params": {
        "plan_job_id": plan["id"], "machine_id": machine["id"]}})
    assert run.status_code == 202, run.text
    rings = done.json()["probe_trace_ids"]
    several = client.post("/api/v1/jobs", headers=OP, json={"kind": "probe_plan", "params": {
        "trace_ids": [trace["id"], *rings], "method": "uniform", "count": 6}}).json()
    client.post(f"/api/v1/jobs/{run.json()['id']}/cancel", headers=OP)
    titles = {j["id"]: j["title"] for j in client.get("/api/v1/jobs", headers=OP).json()["items"]}
    name = client.get(f"/api/v1/traces/{trace['id']}", headers=OP).json()["name"]
    assert titles[plan["id"]] == f"dome · {name} (GND) · probe plan"
    assert titles[run.json()["id"]] == f"dome · {name} (GND) · probe run"     # through its plan
    assert titles[several["id"]] == f"dome · {name} (GND) · probe plan"      # the pad rings are probed, not named
