"""slice and toolpath jobs through the HTTP API on analytic parts (boxes with round holes)."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET

import manifold3d
import numpy as np
import pytest
import trimesh
from shapely.geometry import Polygon

from app.gcode.estimator import MachineLimits, estimate_gcode
from app.gcode.reader import read_program
from app.jobs.results.program import ToolpathResult
from hardware.protocol import commands_sha256
from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.jobs.test_program_results import round_trips
from tests.slicing.conftest import to_trimesh
from tests.slicing.readers import read_cli, read_slc

OP = auth("operator")
SIZE = (20.0, 12.0, 3.0)   # box, mm
HOLE_R, SIDES = 3.0, 48    # vertical through hole: a regular 48-gon of circumradius 3 mm


def ngon_area(circumradius: float, n: int) -> float:
    return 0.5 * n * circumradius ** 2 * math.sin(2 * math.pi / n)


def box_with_hole() -> trimesh.Trimesh:
    hole = manifold3d.Manifold.cylinder(SIZE[2] + 2, HOLE_R, HOLE_R, SIDES).translate((10.0, 6.0, -1.0))
    return to_trimesh(manifold3d.Manifold.cube(SIZE) - hole)


NET_AREA = SIZE[0] * SIZE[1] - ngon_area(HOLE_R, SIDES)


def upload(client, mesh: trimesh.Trimesh, name: str = "part.stl") -> str:
    response = client.post("/api/v1/parts", files={"file": (name, mesh.export(file_type="stl"))}, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def submit(client, kind: str, params: dict):
    body = json.dumps({"kind": kind, "params": params})     # allows Infinity / NaN, as a careless client would
    return client.post("/api/v1/jobs", content=body, headers={**OP, "content-type": "application/json"})


def run(client, kind: str, params: dict) -> dict:
    response = submit(client, kind, params)
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=60.0)
    assert job["status"] == "succeeded", job["error"]
    return job


def artifacts(client, job: dict) -> dict:
    out = {}
    for a in job["artifacts"]:
        response = client.get(a["url"], headers=OP)
        assert response.status_code == 200
        assert response.headers["content-type"].split(";")[0] == a["media_type"]
        out[a["name"]] = (a, response.content)
    return out


@pytest.fixture
def part(client) -> str:
    return upload(client, box_with_hole())


def test_uniform_slice_distributes_the_remainder_with_exact_areas_and_readable_exports(client, part):
    job = run(client, "slice", {"part_id": part, "mode": "uniform", "layer_mm": 0.7})
    result = job["result"]
    layers = result["layers"]
    # 3.0 / 0.7 = 4.29 layers: four of 0.75 mm, no 0.2 mm sliver on top
    assert result["layer_count"] == len(layers) == round(SIZE[2] / 0.7) == 4
    assert [lay["thickness"] for lay in layers] == pytest.approx([0.75] * 4)
    assert [lay["z"] for lay in layers] == pytest.approx([0.75, 1.5, 2.25, 3.0])
    assert any("not a multiple" in note for note in result["notes"])
    for lay in layers:
        assert lay["area_mm2"] == pytest.approx(NET_AREA, rel=1e-6)
        assert (lay["rings"], lay["inner_rings"]) == (2, 1)
        assert lay["sigma"] == pytest.approx(ngon_area(HOLE_R, SIDES) / 240.0, rel=1e-6)
        assert lay["reason"].startswith("uniform")
    assert result["volume_mm3"] == pytest.approx(NET_AREA * SIZE[2], rel=1e-6)

    files = artifacts(client, job)
    assert {name: a["media_type"] for name, (a, _) in files.items()} == {
        "layers.slc": "application/octet-stream", "layers.cli": "text/plain",
        "layers.json": "application/json", "layer.svg": "image/svg+xml", "layers.npz": "application/octet-stream"}
    slc = read_slc(files["layers.slc"][1])
    assert slc["header"].startswith("-SLCVER 2.0 -UNIT MM")
    assert [z for z, _ in slc["layers"]] == pytest.approx([lay["z_bottom"] for lay in layers], abs=1e-6)
    assert slc["end_z"] == pytest.approx(SIZE[2], abs=1e-6)
    for z, rings in slc["layers"]:
        outer, hole = (Polygon(r) for r in rings)
        assert outer.exterior.is_ccw and not hole.exterior.is_ccw
        assert outer.area - hole.area == pytest.approx(NET_AREA, rel=1e-6)
    cli = read_cli(files["layers.cli"][1].decode())
    assert cli["n_layers"] == 4 and [z for z, _, _ in cli["layers"]] == pytest.approx([lay["z"] for lay in layers])
    for _, polylines, _ in cli["layers"]:
        assert sorted(d for d, _ in polylines) == [0, 1]
        areas = {d: Polygon(p).area for d, p in polylines}
        assert areas[1] - areas[0] == pytest.approx(NET_AREA, rel=1e-6)
    doc = json.loads(files["layers.json"][1])
    assert [lay["area_mm2"] for lay in doc["layers"]] == pytest.approx([lay["area_mm2"] for lay in layers])
    svg_meta, svg = files["layer.svg"]
    assert svg_meta["meta"]["layer"] == result["svg"]["layer"] == 2        # the middle one
    path = ET.fromstring(svg).find("{http://www.w3.org/2000/svg}path")
    assert path.get("d").count("M ") == 2


def test_cavity_mode_refines_exactly_the_cavity_band(client):
    cavities = [manifold3d.Manifold.cylinder(2.0, 1.2, 1.2, 32).translate((float(x), 5.0, 2.0)) for x in (10, 20, 30)]
    block = manifold3d.Manifold.cube((40.0, 10.0, 6.0)) - manifold3d.Manifold.batch_boolean(cavities,
                                                                                          manifold3d.OpType.Add)
    part = upload(client, to_trimesh(block))
    params = {"part_id": part, "mode": "cavity", "l_min": 0.25, "l_max": 1.0, "sigma0": 0.02, "mu1": 0.2}
    layers = run(client, "slice", params)["result"]["layers"]
    assert sum(lay["thickness"] for lay in layers) == pytest.approx(6.0)
    for lay in layers:
        bottom = lay["z"] - lay["thickness"]
        in_band = 2.0 - 1e-9 <= bottom < 4.0 - 1e-9
        assert lay["thickness"] == pytest.approx(0.25 if in_band else 1.0)
        assert ("multi-cavity" in lay["reason"]) == in_band
        if 2.0 + 1e-9 < lay["z"] < 4.0 - 1e-9:      # the seed's contour is the one at the layer top
            assert lay["inner_rings"] == 3
        elif lay["z"] < 2.0 - 1e-9 or bottom > 4.0 - 1e-9:
            assert lay["inner_rings"] == 0
    assert sum(lay["inner_rings"] == 3 for lay in layers) >= 7


def test_beam_offsets_constant_and_seed_table(client, part):
    d = 0.1
    layers = run(client, "slice", {"part_id": part, "layer_mm": 1.0, "offset_mm": d})["result"]["layers"]
    apothem = HOLE_R * math.cos(math.pi / SIDES)
    grown_hole = SIDES * (apothem + d) ** 2 * math.tan(math.pi / SIDES)   # miter offset of a regular n-gon
    expected = (SIZE[0] - 2 * d) * (SIZE[1] - 2 * d) - grown_hole
    assert [lay["area_mm2"] for lay in layers] == pytest.approx([expected] * 3, rel=1e-6)
    assert all(lay["beam_offset_mm"] == d for lay in layers)

    thin = upload(client, trimesh.creation.box((20.0, 12.0, 0.06)), "thin.stl")
    job = run(client, "slice", {"part_id": thin, "layer_mm": 0.025, "beam": "seed_haz", "remainder": "merge"})
    layers = job["result"]["layers"]
    # published: 23 um heat-affected width at 25 um layers; the 10 um rest merged into a 35 um top layer: 25.5 um
    assert [lay["beam_offset_mm"] for lay in layers] == pytest.approx([0.023, 0.0255])
    for lay in layers:
        width = 2 * lay["beam_offset_mm"]
        assert lay["area_mm2"] == pytest.approx((20.0 - width) * (12.0 - width), rel=1e-6)
    assert job["result"]["beam"]["kind"] == "seed_haz"


def test_toolpath_time_is_the_estimate_of_the_downloaded_program(client, part):
    sliced = run(client, "slice", {"part_id": part, "layer_mm": 1.5})
    limits = {"accel_mm_s2": 800.0, "travel_accel_mm_s2": 1200.0, "junction_deviation_mm": 0.02}
    w = 0.8
    for pattern in ("raster", "hilbert_merged"):
        job = run(client, "toolpath", {"slice_job_id": sliced["id"], "pattern": pattern, "line_width_mm": w,
                                       "print_feed_mm_min": 1800, "placement": {"xy": "as_is"}, **limits})
        result = job["result"]
        assert round_trips(ToolpathResult, job).pattern == pattern
        (meta, gcode), = artifacts(client, job).values()
        assert meta["name"] == "print.gcode" and meta["media_type"] == "text/x-gcode"
        text = gcode.decode()
        assert meta["meta"]["commands_sha256"] == commands_sha256(text.splitlines()).sha256
        estimate = estimate_gcode(text, MachineLimits(**limits))
        assert result["time_s"] == estimate.total_s > 0
        assert [lay["time_s"] for lay in result["layers"]] == list(estimate.layer_times)
        assert result["estimator"]["limits"]["accel_mm_s2"] == 800.0 and "marlin-jd" in result["estimator"]["name"]
        assert "M204 P800" in text and "M205 J0.02" in text and "F1800.0" in text
        # full infill: extruded length x bead width is the section area plus the overlaps (links, perimeter)
        for lay in result["layers"]:
            assert 0.95 * NET_AREA < lay["path_mm"] * w < 1.3 * NET_AREA
        assert result["path_mm"] == pytest.approx(sum(lay["path_mm"] for lay in result["layers"]))
        # every extruding move stays inside the part's footprint, half a bead in
        program = read_program(text)
        beads = program.end[program.dispense, :2]
        assert beads.min() >= w / 2 - 1e-3 and beads[:, 0].max() <= SIZE[0] - w / 2 + 1e-3
        assert beads[:, 1].max() <= SIZE[1] - w / 2 + 1e-3
        # the stored bounds are the machine's: from home (after G28) to the 5 mm lift at the end
        (x0, y0, _), (x1, y1, z1) = meta["meta"]["bounds"]
        np.testing.assert_allclose(meta["meta"]["bounds"], program.bounds().tolist())
        assert z1 == pytest.approx(SIZE[2] + 5.0)


def test_dispense_on_grbl_writes_the_dispenser_commands(client, part):
    sliced = run(client, "slice", {"part_id": part, "layer_mm": 1.5})
    job = run(client, "toolpath", {"slice_job_id": sliced["id"], "pattern": "contour", "line_width_mm": 1.0,
                                   "dialect": "grbl", "mode": "dispense", "dispense_on": "M8", "dispense_off": "M9"})
    text = client.get(job["artifacts"][0]["url"], headers=OP).text
    pieces = sum(lay["pieces"] for lay in job["result"]["layers"])
    assert text.count("\nM8\n") == pieces and text.count("\nM9\n") == pieces + 1   # + the end section
    assert " E" not in text and text.rstrip().endswith("M2")
    assert job["result"]["time_s"] == estimate_gcode(text, MachineLimits()).total_s


def test_same_inputs_give_identical_artifacts(client, part):
    params = {"part_id": part, "mode": "area", "l_min": 0.5, "l_max": 1.0}
    a, b = run(client, "slice", params), run(client, "slice", params)
    assert {x["name"]: x["sha256"] for x in a["artifacts"]} == {x["name"]: x["sha256"] for x in b["artifacts"]}
    assert a["result"] == b["result"]
    tp = [run(client, "toolpath", {"slice_job_id": job["id"], "pattern": "zone", "line_width_mm": 1.0})
          for job in (a, b)]
    texts = [client.get(job["artifacts"][0]["url"], headers=OP).text.splitlines() for job in tp]
    assert texts[0][1:] == texts[1][1:]                  # only the header names the (different) job id
    assert tp[0]["artifacts"][0]["meta"]["commands_sha256"] == tp[1]["artifacts"][0]["meta"]["commands_sha256"]


@pytest.mark.parametrize(("params", "field"), [
    ({"mode": "area", "l_min": 0.2, "l_max": 0.1}, "l_min"),
    ({"layer_mm": 0}, "layer_mm"),
    ({"mode": "spiral"}, "mode"),
    ({"mode": "cavity", "mu0": 0.3, "mu1": 0.2}, "mu0"),
    ({"layer_mm": 1e-5}, "layer_mm"),                       # 300 000 layers
    ({"mode": "area", "l_min": 1e-5}, "l_min"),
    ({"layer_mm": 0.7, "svg_layer": 5}, "svg_layer"),        # layers 0..4
    ({"beam": "seed_haz", "offset_mm": 0.1}, "offset_mm"),
    ({"beam": "table"}, "beam_table"),
    ({"beam": "table", "beam_table": {"thickness_mm": [0.04, 0.02], "width_mm": [0.1, 0.2]}}, "beam_table"),
    ({"eps0": math.inf}, "eps0"),                            # sent as Infinity
    ({"l_max": math.nan}, "l_max"),
    ({"colour": "red"}, "colour"),
])
def test_bad_slice_parameters_are_refused_naming_the_field(client, part, params, field):
    response = submit(client, "slice", {"part_id": part, **params})
    assert response.status_code == 422, response.text
    assert response.json()["errors"][0]["loc"] == ["params", field]
    assert client.get("/api/v1/jobs?kind=slice", headers=OP).json()["total"] == 0


def test_open_and_overlapping_meshes_are_repaired_or_refused_with_the_reason(client):
    box = trimesh.creation.box((10.0, 10.0, 4.0))
    open_box = upload(client, trimesh.Trimesh(box.vertices, box.faces[:-2]), "open.stl")
    refused = submit(client, "slice", {"part_id": open_box, "layer_mm": 1.0, "repair": False})
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"] == ["params", "repair"]
    repaired = run(client, "slice", {"part_id": open_box, "layer_mm": 1.0})["result"]
    assert "filled holes" in repaired["repairs"][0]
    assert [lay["area_mm2"] for lay in repaired["layers"]] == pytest.approx([100.0] * 4)
    overlap = upload(client, trimesh.util.concatenate([box, box.copy().apply_translation((3.0, 0.0, 0.0))]), "two.stl")
    united = run(client, "slice", {"part_id": overlap, "layer_mm": 2.0})["result"]
    assert "overlapping shells" in united["repairs"][0]
    assert united["layers"][0]["area_mm2"] == pytest.approx(130.0)


def test_bad_toolpath_parameters_are_refused_naming_the_field(client, part):
    sliced = run(client, "slice", {"part_id": part, "layer_mm": 1.5})
    cases = [
        ({"dialect": "grbl"}, "dialect"),                     # extrusion needs marlin
        ({"infill": 0}, "infill"),
        ({"pattern": "honeycomb"}, "pattern"),
        ({"print_feed_mm_min": -5}, "print_feed_mm_min"),
        ({"junction_deviation_mm": math.nan}, "junction_deviation_mm"),
        ({"max_feed_mm_s": [300, 300, 10]}, "max_feed_mm_s"),
        ({"mode": "dispense", "dispense_on": "M8\nG28"}, "dispense_on"),
    ]
    for extra, field in cases:
        response = submit(client, "toolpath", {"slice_job_id": sliced["id"], **extra})
        assert response.status_code == 422, (extra, response.text)
        assert response.json()["errors"][0]["loc"][:2] == ["params", field], extra
    toolpath = run(client, "toolpath", {"slice_job_id": sliced["id"], "line_width_mm": 2.0})
    not_a_slice = submit(client, "toolpath", {"slice_job_id": toolpath["id"]})
    assert not_a_slice.status_code == 422 and not_a_slice.json()["errors"][0]["loc"] == ["params", "slice_job_id"]
    assert "succeeded slice job" in not_a_slice.json()["detail"]
    missing = submit(client, "toolpath", {"slice_job_id": "job_nope"})
    assert missing.status_code == 422 and "job_nope" in missing.json()["detail"]
    assert client.get("/api/v1/jobs?kind=toolpath", headers=OP).json()["total"] == 1


def test_a_failed_slice_cannot_be_filled(client):
    low, high = trimesh.creation.box((5.0, 5.0, 1.0)), trimesh.creation.box((5.0, 5.0, 1.0))
    high.apply_translation((0.0, 0.0, 4.0))                 # nothing between z = 0.5 and 3.5
    gap = upload(client, trimesh.util.concatenate([low, high]), "gap.stl")
    failed = wait_for(client, submit(client, "slice", {"part_id": gap, "layer_mm": 1.0}).json()["id"])
    assert failed["status"] == "failed" and "no area" in failed["error"]["detail"]
    assert failed["artifacts"] == []
    refused = submit(client, "toolpath", {"slice_job_id": failed["id"]})
    assert refused.status_code == 422 and "failed slice job" in refused.json()["detail"]


def test_parameter_schemas_are_published_with_units_and_descriptions(client):
    schemas = {k["name"]: k["params_schema"] for k in client.get("/api/v1/job-kinds", headers=OP).json()}
    for kind in ("slice", "toolpath"):
        props = schemas[kind]["properties"]
        assert all(p.get("description") for p in props.values()), kind
        assert schemas[kind]["additionalProperties"] is False
    assert set(schemas["slice"]["properties"]["mode"]["enum"]) == {"uniform", "area", "cavity", "cusp"}
    assert {"l_min", "l_max", "eps0", "sigma0", "mu0", "mu1", "offset_mm", "svg_layer"} <= \
        set(schemas["slice"]["properties"])
    assert set(schemas["toolpath"]["properties"]["pattern"]["enum"]) == {
        "raster", "lines", "contour", "zone", "hilbert", "hilbert_merged"}


def test_svg_layer_beyond_the_adaptive_count_draws_the_last_layer_and_says_so(client, part):
    # constant section: the area rule keeps l_max, so 3 layers; 6 would have been possible at l_min
    job = run(client, "slice", {"part_id": part, "mode": "area", "l_min": 0.5, "l_max": 1.0, "svg_layer": 4})
    result = job["result"]
    assert result["layer_count"] == 3 and result["svg"]["layer"] == 2
    assert any("svg_layer 4" in note for note in result["notes"])
    svg = next(a for a in job["artifacts"] if a["name"] == "layer.svg")
    assert svg["meta"] == {"layer": 2, "z": pytest.approx(3.0)}


def printed_bounds(client, job) -> np.ndarray:
    """(2, 3) extent of the extruding moves of a job's print.gcode (the stored bounds also
    hold the travel from home, which is the machine's own place)."""
    text = client.get(job["artifacts"][0]["url"], headers=OP).text
    program = read_program(text)
    ends = program.end[program.dispense, :3]
    return np.stack([ends.min(axis=0), ends.max(axis=0)])


def test_toolpath_is_placed_on_the_bed_and_refused_outside_the_machine(client, part):
    sliced = run(client, "slice", {"part_id": part, "layer_mm": 1.5})
    job = run(client, "toolpath", {"slice_job_id": sliced["id"], "line_width_mm": 1.0})   # default placement
    placement = job["result"]["placement"]
    assert placement["xy"] == "center" and placement["drop_to_bed"] is True
    assert "default" in placement["volume_mm"]["source"]
    (x0, y0, z0), (x1, y1, z1) = printed_bounds(client, job)
    assert (x0 + x1) / 2 == pytest.approx(100.0, abs=0.51) and (y0 + y1) / 2 == pytest.approx(100.0, abs=0.51)
    assert 0 < z0 <= 1.5 + 1e-9 and job["artifacts"][0]["meta"]["bounds"][1][2] == pytest.approx(SIZE[2] + 5.0)
    # a given offset on a given bed: the part's minimum corner goes there
    job = run(client, "toolpath", {"slice_job_id": sliced["id"], "line_width_mm": 1.0,
                                   "placement": {"xy": "offset", "offset_mm": [30, 40]},
                                   "volume_mm": {"x": [0, 60], "y": [0, 60], "z": [0, 20]}})
    (x0, y0, _), (x1, y1, _) = printed_bounds(client, job)
    assert x0 >= 30 and y0 >= 40 and x1 <= 50 and y1 <= 52
    # a machine too small: refused at submission with the axis and the amount
    response = submit(client, "toolpath", {"slice_job_id": sliced["id"], "line_width_mm": 1.0,
                                           "volume_mm": {"x": [0, 15], "y": [0, 100], "z": [0, 100]}})
    assert response.status_code == 422, response.text
    problem = response.json()
    error = problem["errors"][0]
    assert "placement" in str(error["loc"]) and "on X" in problem["detail"]
    assert "2.5" in problem["detail"]       # a 20 mm wide part centred on a 15 mm bed: 2.5 mm over each side


def test_toolpath_on_a_registered_machine_uses_its_travel_limits(client, part):
    volume = {"x": [-50, 10], "y": [-40, 20], "z": [0, 30]}
    machine = client.post("/api/v1/machines", json={"name": "small bed", "port": "mock://small", "dialect": "marlin",
                                                   "profile": {"volume_mm": volume}}, headers=OP)
    assert machine.status_code == 201, machine.text
    machine_id = machine.json()["id"]
    sliced = run(client, "slice", {"part_id": part, "layer_mm": 1.5})
    job = run(client, "toolpath", {"slice_job_id": sliced["id"], "line_width_mm": 1.0, "machine_id": machine_id})
    assert machine_id in job["result"]["placement"]["volume_mm"]["source"]
    (x0, y0, _), (x1, y1, _) = printed_bounds(client, job)
    # centred on the machine's own bed (-50..10, -40..20), not on the default 200 x 200 bed
    assert (x0 + x1) / 2 == pytest.approx(-20.0, abs=0.51) and (y0 + y1) / 2 == pytest.approx(-10.0, abs=0.51)
    # a machine whose bed is too small: refused at submission, naming the machine's limits
    small = client.post("/api/v1/machines", json={"name": "tiny bed", "port": "mock://tiny", "dialect": "marlin",
                                                 "profile": {"volume_mm": {"x": [0, 15], "y": [0, 100],
                                                                           "z": [0, 100]}}}, headers=OP)
    refused = submit(client, "toolpath", {"slice_job_id": sliced["id"], "line_width_mm": 1.0,
                                          "machine_id": small.json()["id"]})
    assert refused.status_code == 422 and "on X" in refused.json()["detail"], refused.text
    missing = submit(client, "toolpath", {"slice_job_id": sliced["id"], "machine_id": "mach_nope"})
    assert missing.status_code in (404, 422) and "mach_nope" in missing.text


def test_a_thin_walled_tube_prints_its_wall_and_a_part_with_nothing_to_extrude_fails_with_the_reason(client):
    from tests.helpers.real_parts import thin_tube

    printed = run(client, "slice", {"part_id": upload(client, thin_tube(0.305, 10.0, 1.0)), "layer_mm": 0.25})
    job = run(client, "toolpath", {"slice_job_id": printed["id"]})
    assert job["result"]["path_mm"] == pytest.approx(4 * 2 * math.pi * (10.0 - 0.1525) * math.cos(math.pi / 128),
                                                     rel=2e-3)
    nothing = run(client, "slice", {"part_id": upload(client, thin_tube(0.08, 10.0, 1.0)), "layer_mm": 0.25})
    response = submit(client, "toolpath", {"slice_job_id": nothing["id"]})
    failed = wait_for(client, response.json()["id"], timeout=60.0)
    assert failed["status"] == "failed" and failed["error"]["status"] == 422
    assert "no extrusion" in failed["error"]["detail"]
    assert failed["error"]["errors"][0]["loc"] == ["params", "line_width_mm"]
