"""A toolpath job's preview through the API: the part and the program in one frame, the layer
slider hiding what is above, per-layer z, height and time as the job computed them, and a
mock machine's head drawn where the mock says it is."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.viewer.test_viewer_api import focus, vclient  # noqa: F401 (fixture)

OP = auth("operator")


@pytest.fixture
def toolpath_job(vclient):  # type: ignore[no-untyped-def]  # noqa: F811
    """A 20 x 12 x 1 mm box with its corner at the origin, sliced at 0.25 mm and filled; the
    toolpath centres it on the default 200 x 200 mm bed (so ~90 mm away from its own frame)."""
    mesh = trimesh.creation.box(extents=(20, 12, 1))
    mesh.apply_translation([10, 6, 0.5])
    buf = io.BytesIO()
    mesh.export(buf, file_type="stl")
    part = vclient.post("/api/v1/parts", files={"file": ("box.stl", buf.getvalue())}, headers=OP).json()
    sliced = wait_for(vclient, vclient.post("/api/v1/jobs", json={"kind": "slice", "params": {
        "part_id": part["id"], "layer_mm": 0.25}}, headers=OP).json()["id"], timeout=60)
    assert sliced["status"] == "succeeded", sliced
    job = wait_for(vclient, vclient.post("/api/v1/jobs", json={"kind": "toolpath", "params": {
        "slice_job_id": sliced["id"], "pattern": "raster", "mode": "dispense"}}, headers=OP).json()["id"], timeout=60)
    assert job["status"] == "succeeded", job
    return part, job


def _part_vertices(vclient) -> np.ndarray:  # type: ignore[no-untyped-def]  # noqa: F811
    builder = vclient.app.state.viewer.builder           # the default view's recording builder
    return np.asarray(builder._handles["/focus/part"][1].vertices, float)


def test_part_and_program_in_one_frame_with_the_layers_the_job_computed(vclient, toolpath_job):  # noqa: F811
    part, job = toolpath_job
    shift = np.asarray(job["result"]["placement"]["shift_mm"])
    assert np.abs(shift[:2]).max() > 50                                   # the job did move the part
    shown = focus(vclient, job_id=job["id"])
    [(name, preview)] = shown["previews"].items()
    rows = job["result"]["layers"]
    assert preview["layer_count"] == len(rows) == 4 and preview["layer"] == 3
    assert [r["z_mm"] for r in preview["layers"]] == pytest.approx([r["z"] + shift[2] for r in rows])
    assert [r["height_mm"] for r in preview["layers"]] == pytest.approx([r["thickness"] for r in rows])
    assert [r["time_s"] for r in preview["layers"]] == pytest.approx([r["time_s"] for r in rows], rel=1e-9)
    legend = {row["type"] for row in preview["legend"]}
    assert {"perimeter", "infill", "travel", "dispense_on", "dispense_off"} <= legend
    # one frame: every dispensed move lies over the drawn part (within half a bead)
    vertices = _part_vertices(vclient)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    assert lo == pytest.approx(np.asarray(part["bounds"][0]) + shift, abs=1e-6)
    builder = vclient.app.state.viewer.builder
    for kind in ("perimeter", "infill"):
        segs = np.asarray(builder._handles[f"/focus/preview/{name}/{kind}"][1].points, float).reshape(-1, 3)
        assert (segs[:, :2] >= lo[:2] - 0.25).all() and (segs[:, :2] <= hi[:2] + 0.25).all()
        assert (segs[:, 2] > lo[2]).all() and (segs[:, 2] <= hi[2] + 1e-6).all()


def test_the_layer_request_hides_the_layers_above(vclient, toolpath_job):  # noqa: F811
    part, job = toolpath_job
    top = focus(vclient, job_id=job["id"])
    name = next(iter(top["previews"]))
    moved = vclient.post("/api/v1/viewer/layer", json={"layer": 1}, headers=OP)
    assert moved.status_code == 200, moved.text
    shot = moved.json()
    assert shot["previews"][name]["layer"] == 1 and shot["sliders"][name]["value"] == 1
    z1 = shot["previews"][name]["layers"][1]["z_mm"]
    builder = vclient.app.state.viewer.builder
    for kind in ("perimeter", "infill"):
        drawn = np.asarray(builder._handles[f"/focus/preview/{name}/{kind}"][1].points, float)
        assert drawn[:, :, 2].max() == pytest.approx(z1)                   # nothing above layer 1
        assert (shot["nodes"][f"/focus/preview/{name}/{kind}"]["count"]
                < top["nodes"][f"/focus/preview/{name}/{kind}"]["count"])
    bad = vclient.post("/api/v1/viewer/layer", json={"layer": -1}, headers=OP)
    assert bad.status_code == 422
    focus(vclient, part_id=part["id"])                                       # a part alone: no preview
    none = vclient.post("/api/v1/viewer/layer", json={"layer": 0}, headers=OP)
    assert none.status_code == 409 and none.json()["errors"][0]["loc"] == ["view_id"]


def test_the_head_is_drawn_where_the_mock_machine_is(vclient, toolpath_job):  # noqa: F811
    from hardware.mock import get_world

    _, job = toolpath_job
    focus(vclient, job_id=job["id"])
    machine = vclient.post("/api/v1/machines", json={"name": "head-mock", "port": "mock://"}, headers=OP).json()
    assert vclient.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP).status_code == 200
    assert vclient.post(f"/api/v1/machines/{machine['id']}/home", headers=OP).status_code == 200
    jog = vclient.post(f"/api/v1/machines/{machine['id']}/jog", json={"dx_mm": 95, "dy_mm": 97, "dz_mm": 3},
                       headers=OP)
    assert jog.status_code == 200, jog.text
    head = vclient.post("/api/v1/viewer/head", json={"machine_id": machine["id"]}, headers=OP)
    assert head.status_code == 200, head.text
    body = head.json()
    truth = list(get_world(machine["id"]).position)[:3]
    assert body["drawn"] and body["position_mm"] == pytest.approx(truth) and body["state"] == "idle"
    assert body["scene"]["nodes"]["/focus/head"]["position_mm"] == pytest.approx(truth)
    missing = vclient.post("/api/v1/viewer/head", json={"machine_id": "mach_missing"}, headers=OP)
    assert missing.status_code == 404 and missing.json()["errors"][0]["loc"] == ["machine_id"]


def test_a_circuit_program_is_previewed_by_stroke_kind_on_the_placed_part(vclient):  # noqa: F811
    """A circuit program written after a loop in machine coordinates: its strokes typed trace / pad,
    one layer, dispense on/off, and the part moved by the loop's placement into the program's frame."""
    from app.circuits.program import Stroke, write_circuit_program
    from app.geometry.placement import Placement
    from tests.viewer.test_viewer_api import stored_job

    mesh = trimesh.creation.box(extents=(30, 20, 2))
    mesh.apply_translation([15, 10, 1])
    buf = io.BytesIO()
    mesh.export(buf, file_type="stl")
    part = vclient.post("/api/v1/parts", files={"file": ("board.stl", buf.getvalue())}, headers=OP).json()
    placement = Placement(dx=50.0, dy=40.0, dz=0.5, rz_rad=np.radians(90.0))
    trace = placement.apply(np.array([[5.0, 5.0, 2.1], [25.0, 5.0, 2.1], [25.0, 15.0, 2.1]]))
    pad = placement.apply(np.array([[10.0, 12.0, 2.1], [11.0, 12.0, 2.1]]))
    program = write_circuit_program([Stroke(trace, "trace", "T1", 300.0), Stroke(pad, "pad", "P1", 300.0)],
                                    dialect="marlin", dispense_on="M42 P6 S255", dispense_off="M42 P6 S0",
                                    clearance_mm=1.0, part_top_mm=2.5)
    job_id = stored_job(vclient, "circuit_program", part["id"], {}, {
        "dispense_on": "M42 P6 S255", "dispense_off": "M42 P6 S0", "surface": {"placement": placement.to_dict()}},
        {"circuit.gcode": program.text.encode()})
    shown = focus(vclient, job_id=job_id)
    preview = shown["previews"]["circuit.gcode"]
    counts = {row["type"]: row["moves"] for row in preview["legend"]}
    assert counts["trace"] == 2 and counts["pad"] == 1                       # the profile's own on/off lines
    assert counts["dispense_on"] == counts["dispense_off"] == 2 and preview["layer_count"] == 1
    assert preview["layers"][0]["z_mm"] == pytest.approx(trace[0, 2])
    builder = vclient.app.state.viewer.builder
    drawn = np.asarray(builder._handles["/focus/preview/circuit.gcode/trace"][1].points, float).reshape(-1, 3)
    assert drawn == pytest.approx(np.repeat(trace, 2, axis=0)[1:-1])
    part_drawn = _part_vertices(vclient)
    expected = placement.apply(np.asarray(mesh.vertices))
    assert part_drawn.min(axis=0) == pytest.approx(expected.min(axis=0), abs=1e-5)
    assert part_drawn.max(axis=0) == pytest.approx(expected.max(axis=0), abs=1e-5)
