"""A Gerber circuit onto the real part on the mock: import -> closed loop (probe, rebuild,
compensate every trace) -> one circuit program -> print.  What the mock deposited holds every
trace at its standoff within 10 um of the TRUE (as-made) surface, and covers every pad; the
pads are probed themselves (the import's probe rings go into the loop): stations lie on every
pad, and the pad fills sit at their standoff within 10 um too."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Polygon

from app.jobs.results.models import PrintResult
from app.jobs.results.program import CircuitProgramResult
from app.jobs.simulation import deposited_since, true_height_of
from app.reference.evaluation import evaluate_deposition
from app.reference.s1 import as_made, s1_mesh
from hardware.mock import get_world
from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.jobs.test_program_results import round_trips

OP = auth("operator")
STANDOFF = 0.08
LINE = 0.2

GERBER = """G04 three traces (one 0.5 mm wide) and three round pads, mm*
%FSLAX46Y46*%
%MOMM*%
%ADD10C,0.200000*%
%ADD11C,1.200000*%
%ADD12C,0.500000*%
D10*
G01*
X8000000Y10000000D02*
X40000000Y10000000D01*
X8000000Y20000000D02*
X40000000Y24000000D01*
D12*
X8000000Y30000000D02*
X40000000Y30000000D01*
D11*
X44000000Y10000000D03*
X44000000Y24000000D03*
X44000000Y30000000D03*
M02*
"""


@pytest.fixture(scope="module")
def meshes():
    truth = as_made(seed=11, amplitude_mm=0.15)
    return s1_mesh(grid_mm=0.3).export(file_type="stl"), truth.mesh(grid_mm=0.3).export(file_type="stl")


def test_gerber_circuit_printed_at_its_standoff_with_pads_covered(client, meshes):
    nominal_stl, true_stl = meshes
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", nominal_stl)}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", true_stl)}, headers=OP).json()
    imported = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                           files=[("files", ("top.gbr", GERBER.encode()))],
                           data={"options": json.dumps({"origin_mm": [0, 0], "standoff_mm": STANDOFF})})
    assert imported.status_code == 201, imported.text
    body = imported.json()
    trace_ids = [t["trace"]["id"] for t in body["traces"]]
    assert len(trace_ids) == 3 and len(body["pads"]) == 3
    assert len(body["probe_trace_ids"]) == 3 and all(p["probe_trace_id"] for p in body["pads"])
    machine = client.post("/api/v1/machines", json={
        "name": "circuit", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "placement": {"dz": 0.03}, "probe_noise_mm": 0.001,
                 "faults": {"seed": 3}}}, headers=OP).json()
    loop = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": trace_ids + body["probe_trace_ids"], "machine_id": machine["id"],
        "probe": {"method": "deviation"}, "sigma_mm": 0.001}}, headers=OP)
    assert loop.status_code == 202, loop.text
    loop = wait_for(client, loop.json()["id"], timeout=240)
    assert loop["status"] == "succeeded", loop["error"]
    pads = [Polygon(p["outline_xy_mm"]) for p in body["pads"]]
    entries = {e["trace_id"]: e for e in loop["result"]["traces"]}
    for pad in body["pads"]:
        run = client.get(f"/api/v1/jobs/{entries[pad['probe_trace_id']]['probe_run']}?include=result",
                         headers=OP).json()
        stations = shapely.points(np.array([p["nominal"][:2] for p in run["result"]["points"]]))
        on_pad = shapely.contains(Polygon(pad["outline_xy_mm"]), stations)
        print(f"pad {pad['name']}: {int(on_pad.sum())} of {len(on_pad)} probe stations on the pad")
        assert len(on_pad) >= 3 and on_pad.all()
    program = client.post("/api/v1/jobs", json={"kind": "circuit_program", "params": {
        "import_id": body["import_id"], "closed_loop_job_id": loop["id"], "machine_id": machine["id"],
        "line_width_mm": LINE}}, headers=OP)
    assert program.status_code == 202, program.text
    program = wait_for(client, program.json()["id"], timeout=120)
    assert program["status"] == "succeeded", program["error"]
    result = program["result"]
    assert result["travel_mm"] <= result["travel_input_order_mm"] + 1e-9
    assert round_trips(CircuitProgramResult, program).strokes == result["strokes"]
    world = get_world(machine["id"])
    start = len(world.deposition_log)
    printed = client.post(f"/api/v1/machines/{machine['id']}/print",
                          json={"job_id": program["id"], "artifact": "circuit.gcode"}, headers=OP)
    assert printed.status_code == 202, printed.text
    printed = wait_for(client, printed.json()["id"], timeout=240)
    assert printed["status"] == "succeeded", printed["error"]
    assert round_trips(PrintResult, printed).executed == printed["result"]["total"]
    moves = deposited_since(world, start)
    truth = true_height_of(world)
    mid = 0.5 * (moves[:, 0, :2] + moves[:, 1, :2])
    for t in body["traces"]:
        stored = client.get(f"/api/v1/traces/{t['trace']['id']}", headers=OP).json()
        centre = LineString(np.array(stored["nominal"]["points"])[:, :2])
        near = shapely.distance(shapely.points(mid), centre) <= 0.02
        on_trace = moves[near]
        assert len(on_trace) > 10
        report = evaluate_deposition(on_trace, truth, STANDOFF)
        print(f"{t['name']}: standoff error max {report.max_abs_error_mm * 1000:.2f} um over "
              f"{report.length_mm:.2f} mm")
        assert report.max_abs_error_mm <= 0.010, (t["name"], report.max_abs_error_mm)
        assert report.length_mm >= 0.95 * t["layout_length_mm"]
    beads = shapely.union_all([LineString(m[:, :2]).buffer(LINE / 2) for m in moves])
    for pad in pads:
        print(f"pad covered {beads.intersection(pad).area / pad.area:.4f}")
        assert beads.intersection(pad).area >= 0.98 * pad.area
        inside = shapely.contains(pad, shapely.points(mid))
        report = evaluate_deposition(moves[inside], truth, STANDOFF)
        print(f"pad fill: standoff error max {report.max_abs_error_mm * 1000:.2f} um over {report.length_mm:.2f} mm")
        assert inside.sum() > 10 and report.max_abs_error_mm <= 0.010
    wide = shapely.union_all([LineString(m[:, :2]).buffer(LINE / 2) for m in moves
                              if abs(0.5 * (m[0, 1] + m[1, 1]) - 30.0) < 0.4 and m[:, 0].max() < 40.0])
    band = LineString([(9.0, 30.0), (39.0, 30.0)]).buffer(0.25, cap_style="flat")
    assert wide.intersection(band).area >= 0.98 * band.area          # the 0.5 mm trace printed in 3 passes
