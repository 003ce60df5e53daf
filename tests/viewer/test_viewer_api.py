"""The viewer through the API: focus on parts and jobs of every kind, read back what is
shown.  Job results are read from the records and artifacts (runtime), never over HTTP."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from sqlmodel import Session

from app.five_axis.kinematics import (
    tool_axis_from_angles,
    workpiece_to_machine,
)
from app.platform.artifacts import add_artifact
from app.platform.models import Job, JobReference, new_id, utcnow
from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.viewer.conftest import free_port

OP = auth("operator")


@pytest.fixture
def vclient(settings_factory):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings_factory(viewer=True, viewer_port=free_port())),
                    raise_server_exceptions=False) as test_client:
        yield test_client


@pytest.fixture
def part_and_trace(vclient):  # type: ignore[no-untyped-def]
    stl = s1_mesh(grid_mm=2.0).export(file_type="stl")
    part = vclient.post("/api/v1/parts", files={"file": ("s1.stl", stl)}, headers=OP).json()
    trace = vclient.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[6].to_api(), headers=OP).json()
    return part, trace


def focus(client, **target) -> dict:  # type: ignore[no-untyped-def]
    response = client.post("/api/v1/viewer/focus", json=target, headers=OP)
    assert response.status_code == 200, response.text
    assert client.get("/api/v1/viewer/scene", headers=OP).json() == response.json()
    return response.json()


def stored_job(client, kind: str, part_id: str, params: dict, result: dict,  # type: ignore[no-untyped-def]
               artifacts: dict[str, bytes]) -> str:
    """A succeeded job record with artifacts, as a worker would leave it."""
    runtime = client.app.state.runtime
    with Session(runtime.engine) as session:
        job = Job(id=new_id("job"), kind=kind, status="succeeded", progress=1.0, params=params, result=result,
                  created_at=utcnow())
        session.add(job)
        session.flush()
        session.add(JobReference(job_id=job.id, ref_kind="part", ref_id=part_id))
        for name, data in artifacts.items():
            add_artifact(session, runtime.blobs, job.id, name, data, "application/octet-stream")
        session.commit()
        return job.id


def test_where_the_view_is(vclient, client):
    info = vclient.get("/api/v1/viewer", headers=OP).json()
    assert info["enabled"] and info["host"] == "127.0.0.1" and info["url"] == f"http://127.0.0.1:{info['port']}/"
    assert client.get("/api/v1/viewer", headers=OP).json() == {"enabled": False, "host": None, "port": None,
                                                               "url": None}
    off = client.post("/api/v1/viewer/focus", json={"part_id": "x"}, headers=OP)
    assert off.status_code == 409 and "not running" in off.json()["detail"]
    assert vclient.get("/api/v1/viewer").status_code == 401


def test_bad_focus_requests(vclient):
    assert vclient.post("/api/v1/viewer/focus", json={}, headers=OP).status_code == 422
    both = vclient.post("/api/v1/viewer/focus", json={"part_id": "a", "job_id": "b"}, headers=OP)
    assert both.status_code == 422 and "exactly one" in both.json()["detail"]
    missing = vclient.post("/api/v1/viewer/focus", json={"job_id": "job_missing"}, headers=OP)
    assert missing.status_code == 404 and missing.json()["errors"][0]["loc"] == ["job_id"]


def test_part_probe_plan_and_reconstruction_scenes(vclient, part_and_trace):
    part, trace = part_and_trace
    shown = focus(vclient, part_id=part["id"])
    assert shown["nodes"]["/focus/part"]["count"] == part["faces"]
    assert shown["nodes"]["/focus/traces/S1-trace-7"]["count"] == len(trace["nominal"]["points"]) - 1

    plan = wait_for(vclient, vclient.post("/api/v1/jobs", json={"kind": "probe_plan", "params": {
        "trace_id": trace["id"], "method": "uniform", "count": 9}}, headers=OP).json()["id"])
    shown = focus(vclient, job_id=plan["id"])
    assert shown["focus"] == {"job_id": plan["id"], "part_id": part["id"]}
    assert shown["nodes"]["/focus/probes/plan/planned"]["count"] == 9

    planned = np.asarray(plan["result"]["points"])
    truth = as_made(seed=1, amplitude_mm=0.1)
    measured = np.column_stack([planned[:, :2], truth.true_height(planned[:, :2])])
    rec = wait_for(vclient, vclient.post("/api/v1/jobs", json={"kind": "reconstruct", "params": {
        "trace_id": trace["id"], "points": measured.tolist()}}, headers=OP).json()["id"])
    assert rec["status"] == "succeeded", rec["error"]
    shown = focus(vclient, job_id=rec["id"])
    node = shown["nodes"]["/focus/probes/measured/measured"]
    assert node["count"] == 9
    # one colour scale for the probes and the deviation ribbon on the part: the largest
    # |measured - nominal| or |rebuilt deviation| (planned points lie on the nominal)
    rebuilt = np.abs(np.asarray(rec["result"]["deviation"]["samples"])[:, 1]).max()
    limit = max(np.abs(measured[:, 2] - planned[:, 2]).max(), rebuilt)
    assert node["deviation_limit_mm"] == pytest.approx(limit, abs=2e-3)
    ribbon = shown["nodes"]["/focus/fields/S1-trace-7_deviation"]
    assert ribbon["group"] == "deviation" and ribbon["signed"] is True
    [legend] = shown["legends"]
    assert legend["unit"] == "µm" and legend["hi"] == pytest.approx(node["deviation_limit_mm"] * 1000)
    assert shown["nodes"]["/focus/curves/S1-trace-7_reconstructed"]["role"] == "reconstructed"
    plot = shown["plots"]["deviation/S1-trace-7"]
    samples = np.asarray(rec["result"]["deviation"]["samples"])
    assert plot["x"] == pytest.approx(samples[:, 0].tolist()) and plot["y"] == pytest.approx(samples[:, 1].tolist())
    assert set(shown["groups"]) == {"part", "traces", "probes", "curves", "deviation"}


def test_slice_layers_and_jetting_heights_get_sliders(vclient, part_and_trace):
    part, _ = part_and_trace
    square = [[0, 0], [10, 0], [10, 10], [0, 10]]
    layers = {"units": "mm", "layers": [{"index": i, "z_top": 0.5 * (i + 1), "islands": [
        {"outer": square, "holes": [[[2, 2], [2, 4], [4, 4], [4, 2]]] if i else []}]} for i in range(4)]}
    slice_id = stored_job(vclient, "slice", part["id"], {"part_id": part["id"]}, {"layers": []},
                          {"layers.json": json.dumps(layers).encode()})
    shown = focus(vclient, job_id=slice_id)
    assert shown["nodes"]["/focus/layers/slices/all"]["count"] == 4 + 3 * 8
    assert shown["nodes"]["/focus/layers/slices/current"]["count"] == 8
    assert shown["sliders"]["slices"]["max"] == 3 and shown["sliders"]["slices"]["labels"][3] == "layer 3 z=2.000 mm"

    buf = io.BytesIO()
    heights = np.stack([np.full((20, 30), 0.002 * k, np.float32) for k in (1, 2)])
    np.savez(buf, heights=heights, layers=np.array([100, 200]), pitch_mm=np.float64(0.0847))
    jet_id = stored_job(vclient, "jetting", part["id"], {"dpi": 300}, {"layers": []}, {"heights.npz": buf.getvalue()})
    shown = focus(vclient, job_id=jet_id)
    node = shown["nodes"]["/focus/heights/heights"]
    assert node["count"] == 2 * 19 * 29 and node["label"] == "layer 200"
    assert node["height_range_mm"] == pytest.approx([0.002, 0.004])
    assert shown["sliders"]["heights"]["labels"] == ["layer 100", "layer 200"]


def test_a_jetting_runs_measured_maps_get_a_slider(vclient, part_and_trace):
    part, _ = part_and_trace
    maps = {}
    for layer in range(1, 26):
        buf = io.BytesIO()
        np.savez(buf, heights=np.full((20, 30), np.nan, np.float32),
                 filled=np.full((20, 30), 0.001 * layer, np.float32),
                 pattern=np.ones((20, 30), bool), mask=np.ones((20, 30), bool), pitch_mm=np.float64(0.0847))
        maps[f"measured_{layer:04d}.npz"] = buf.getvalue()
    job_id = stored_job(vclient, "jetting_run", part["id"], {"dpi": 300}, {"layers": []}, maps)
    shown = focus(vclient, job_id=job_id)
    labels = shown["sliders"]["measured"]["labels"]
    assert len(labels) == 20 and labels[0] == "layer 1 (measured)" and labels[-1] == "layer 25 (measured)"
    node = shown["nodes"]["/focus/heights/measured"]
    assert node["height_range_mm"] == pytest.approx([0.001, 0.025])  # over the maps shown


def test_five_axis_program_is_shown_in_part_coordinates_with_nozzle_axes(vclient, part_and_trace):
    part, _ = part_and_trace
    t = np.linspace(0, 1, 25)
    contact = np.column_stack([10 + 20 * t, 20 + 0 * t, 5 + 2 * np.sin(3 * t)])
    a, c = np.radians(30 * t), np.radians(-40 + 80 * t)
    pivot = np.array([30.0, 20.0, 0.0])
    machine = workpiece_to_machine(contact, a, c, pivot)
    lines = ["G21", "G90", (f"G0 X{machine[0, 0]:.6f} Y{machine[0, 1]:.6f} Z{machine[0, 2]:.6f} "
                            f"A{np.degrees(a[0]):.6f} C{np.degrees(c[0]):.6f}"), "M8"]
    lines += [f"G1 X{m[0]:.6f} Y{m[1]:.6f} Z{m[2]:.6f} A{np.degrees(ai):.6f} C{np.degrees(ci):.6f} F100"
              for m, ai, ci in zip(machine[1:], a[1:], c[1:])]
    lines += ["M9", "G0 Z50"]
    job_id = stored_job(vclient, "five_axis", part["id"], {"pivot": pivot.tolist(), "dispense_on": "M8",
                                                           "dispense_off": "M9"},
                        {"dispense_on": "M8", "dispense_off": "M9"}, {"five_axis.gcode": "\n".join(lines).encode()})
    shown = focus(vclient, job_id=job_id)
    assert shown["nodes"]["/focus/toolpaths/five_axis/dispense"]["count"] == 24
    assert shown["nodes"]["/focus/axes/nozzle_axis"]["count"] == 24
    viewer = vclient.app.state.viewer
    handle = viewer.builder._handles["/focus/toolpaths/five_axis/dispense"][1]
    assert np.allclose(handle.points[:, 1], contact[1:], atol=1e-4)  # back in part coordinates
    glyphs = viewer.builder._handles["/focus/axes/nozzle_axis"][1].points
    directions = glyphs[:, 1] - glyphs[:, 0]
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    assert np.allclose(directions, tool_axis_from_angles(a[1:], c[1:]), atol=1e-5)


def test_compensation_toolpaths_and_unfinished_jobs(vclient, part_and_trace):
    part, _ = part_and_trace
    nominal = "G21\nG90\nG0 X0 Y0 Z5\nM106\nG1 X10 Z1\nG1 X20\nM107\nG0 Z5\n"
    printed = "G21\nG90\nG0 X0 Y0 Z5\nM106\nG1 X10 Z1.1\nG1 X20 Z1.05\nM107\nG0 Z5\n"
    result = {"dispense_on": "M106", "dispense_off": "M107", "segments": 2, "length_mm": 20.0,
              "max_chord_error_mm": 0.0, "standoff_mm": 0.1, "method": "deviation", "span_mm": [0.0, 20.0],
              "trace_extent_mm": [0.0, 20.0], "extension_mm": [0.0, 0.0], "nominal_segments": 2, "slope": None,
              "points": [[0.0, 0.0, 1.0], [10.0, 0.0, 1.1], [20.0, 0.0, 1.05]], "tool": {"tool": None},
              "warnings": []}  # a whole compensate result (the viewer reads it through CompensateResult)
    job_id = stored_job(vclient, "compensate", part["id"], {}, result,
                        {"nominal.gcode": nominal.encode(), "print.gcode": printed.encode()})
    nodes = focus(vclient, job_id=job_id)["nodes"]
    assert nodes["/focus/toolpaths/nominal/dispense"]["role"] == "nominal"
    assert nodes["/focus/toolpaths/print/dispense"] == {"kind": "segments", "group": "toolpaths", "count": 2,
                                                       "visible": True, "role": "compensated", "move": "dispense"}
    assert nodes["/focus/toolpaths/print/travel"]["count"] == 2

    queued = vclient.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 5}}, headers=OP).json()
    shown = focus(vclient, job_id=queued["id"])
    assert shown["notes"] and ("queued" in shown["notes"][0] or "running" in shown["notes"][0])
    vclient.post(f"/api/v1/jobs/{queued['id']}/cancel", headers=OP)
