"""A pour with holes through the API: stored with its holes and net (and its copper area),
and a circuit program over a solid pour that would short other nets' pads is refused at
submission, naming the nets, the items and where."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
from shapely.geometry import box

from app.reference.s1 import s1_mesh
from tests.circuits.boards import PourBoard, gerber_x2
from tests.conftest import auth

OP = auth("operator")
BOARD = PourBoard()
ORIGIN = (10.0, 10.0)


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=1.0).export(file_type="stl")


@pytest.fixture
def part(client, s1_stl):
    return client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()


def _import(client, part, text, **options):
    return client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", ("top.gbr", text.encode()))],
                       data={"options": json.dumps({"origin_mm": list(ORIGIN), **options})})


def test_pour_holes_are_stored_and_a_short_is_refused(client, part):
    done = _import(client, part, gerber_x2(BOARD))
    assert done.status_code == 201, done.text
    (area,) = done.json()["areas"]
    holes = [box(x - s / 2, y - s / 2, x + s / 2, y + s / 2) for x, y, s in BOARD.holes]
    expected = shapely.affinity.translate(box(0, 0, BOARD.width, BOARD.height).difference(shapely.union_all(holes)),
                                          *ORIGIN)
    assert area["source"]["net"] == "GND" and len(area["holes_xy_mm"]) == 2
    assert area["area_mm2"] == pytest.approx(expected.area, abs=1e-6)
    record = client.get(f"/api/v1/circuit-imports/{done.json()['import_id']}", headers=OP).json()
    assert record["areas"][0]["holes_xy_mm"] == area["holes_xy_mm"]
    # any job stands in for the loop: the net check runs first, the loop's own check after it
    other = client.post("/api/v1/jobs", headers=OP, json={"kind": "probe_plan", "params": {
        "trace_ids": [done.json()["traces"][0]["trace"]["id"]]}})
    assert other.status_code == 202, other.text
    not_a_loop = other.json()["id"]
    ok = client.post("/api/v1/jobs", headers=OP, json={"kind": "circuit_program", "params": {
        "import_id": done.json()["import_id"], "closed_loop_job_id": not_a_loop}})
    assert ok.status_code == 422 and "closed_loop" in ok.text and "short" not in ok.text

    solid = _import(client, part, gerber_x2(BOARD, with_holes=False))
    assert solid.status_code == 201, solid.text
    refused = client.post("/api/v1/jobs", headers=OP, json={"kind": "circuit_program", "params": {
        "import_id": solid.json()["import_id"], "closed_loop_job_id": not_a_loop}})
    assert refused.status_code == 422, refused.text
    problem = refused.json()
    assert "the print would short nets" in problem["detail"] and "GND" in problem["detail"]
    assert "area 0 (net GND)" in problem["detail"]
    error = problem["errors"][0]
    assert error["loc"] == ["params", "import_id"]
    short = error["value"]
    assert short["net_pairs"] == 2 and "GND" in short["nets"] and "area 0" in short["items"]
    (x, y, _, net), = [p for p in BOARD.pads if p[3] in short["nets"] and p[3] != "GND"]
    assert shapely.Point(short["at_mm"]).distance(shapely.Point(x + ORIGIN[0], y + ORIGIN[1])) <= 0.75 + 1e-6


def test_the_preview_patch_leaves_the_holes_open():
    import trimesh

    from app.viewer.circuit_preview import _patch
    from tests.circuits.boards import hole_polygons

    flat = trimesh.creation.box(extents=[100, 100, 2])
    outline = [[0, 0], [BOARD.width, 0], [BOARD.width, BOARD.height], [0, BOARD.height]]
    verts, faces = _patch(outline, flat, [h.tolist() for h in hole_polygons(BOARD)])
    tri = verts[faces][:, :, :2]
    area = 0.5 * abs((tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1])
                     - (tri[:, 2, 0] - tri[:, 0, 0]) * (tri[:, 1, 1] - tri[:, 0, 1])).sum()
    assert area == pytest.approx(BOARD.pour_area(), abs=1e-6)


@pytest.mark.parametrize("mapping", ["project", "wrap"])
@pytest.mark.parametrize(("kind", "name"), [("kicad", "board.kicad_pcb"), ("gerber", "top.gbr"), ("dxf", "cu.dxf")])
def test_a_board_with_a_sliver_imports_with_a_note(client, part, kind, name, mapping):
    from tests.circuits.boards import sliver_tracks

    done = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", (name, sliver_tracks(kind).encode()))],
                       data={"options": json.dumps({"origin_mm": [0, 0] if kind != "kicad" else [0, 20],
                                                    "mapping": mapping})})
    assert done.status_code == 201, done.text
    body = done.json()
    assert len(body["traces"]) == 2 and all(t["on_part"] for t in body["traces"])
    assert not [w for w in body["warnings"] if w["kind"] == "leaves_part"]
    assert any("shorter than" in n for n in body["files"][0]["notes"])


def test_a_kicad_board_as_saved_lands_over_the_part_with_vias_and_outline(client, part):
    """KiCad's page origin is far from the board: with no origin given, the board's centre (its
    Edge.Cuts outline's) goes over the middle of the part; vias and the outline are reported."""
    from tests.circuits.boards import kicad_pads_board

    far = kicad_pads_board().replace("(at 40 20)", "(at 140 120)").replace("(start 30 30) (end 45 30)",
                                                                             "(start 130 130) (end 145 130)")
    far = far.replace("(via (at 45 30)", "(via (at 145 130)")
    for a, b in (("(start 0 0)", "(start 100 100)"), ("(end 60 0)", "(end 160 100)"),
                 ("(start 60 0)", "(start 160 100)"),
                 ("(end 60 40)", "(end 160 140)"), ("(start 60 40)", "(start 160 140)"),
                 ("(end 0 40)", "(end 100 140)"), ("(start 0 40)", "(start 100 140)"), ("(end 0 0)", "(end 100 100)")):
        far = far.replace(a, b)
    response = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                           files=[("files", ("board.kicad_pcb", far.encode()))],
                           data={"options": json.dumps({"dry_run": True})})
    assert response.status_code == 201, response.text
    body = response.json()
    mesh = s1_mesh(grid_mm=1.0)
    middle = mesh.bounds[:, :2].mean(axis=0)
    assert body["placement"]["anchor"] == "board_center"
    assert body["placement"]["anchor_mm"] == pytest.approx([130, -120])      # KiCad (130, 120), y up
    assert body["placement"]["origin_mm"] == pytest.approx(middle.tolist())
    (edge,) = body["outline"]
    edge = np.array(edge)
    np.testing.assert_allclose(0.5 * (edge.min(0) + edge.max(0)), middle, atol=1e-6)
    assert all(t["on_part"] for t in body["traces"]) and all(p["on_part"] for p in body["pads"])
    (via,) = body["vias"]
    # the via sits 15 mm right of and 10 mm below the board's centre (KiCad y down)
    np.testing.assert_allclose(via["center_mm"][:2], middle + [15, -10], atol=1e-6)
    assert via["on_part"] and via["net"] == "SIG" and body["files"][0]["vias"] == 1
    assert len(body["traces"]) == 1                     # Edge.Cuts is the boundary, not four traces


def test_a_pour_patch_follows_a_curved_part():
    """A 20 x 10 mm pour on a dome of radius 150 mm: every triangle's middle lies on the part
    (within 5 um), where a few long flat triangles cut up to 0.3 mm under it."""
    import trimesh

    from app.geometry.drape import top_surface_z
    from app.viewer.circuit_preview import _patch
    from tests.circuits.boards import hole_polygons

    dome = trimesh.creation.icosphere(subdivisions=6, radius=150.0)
    outline = np.array([[0, 0], [BOARD.width, 0], [BOARD.width, BOARD.height], [0, BOARD.height]]) - [10, 5]
    holes = [h - [10, 5] for h in hole_polygons(BOARD)]
    verts, faces = _patch(outline.tolist(), dome, [h.tolist() for h in holes])
    middles = verts[faces].mean(axis=1)
    surface = top_surface_z(dome, middles[:, :2]).z
    assert (middles[:, 2] - surface).min() >= -0.005


def test_a_program_that_would_open_a_net_is_refused(client, part):
    """The board's dropped dot and narrow pour neck split SIG and GND in the print: the
    committed import stores the file's connections and the program is refused naming the net
    and the gap (from the board's numbers), moved by the placement."""
    from tests.circuits.boards import OPENS, open_board

    done = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", ("board.kicad_pcb", open_board().encode()))],
                       data={"options": json.dumps({"origin_mm": [0, 20]})})
    assert done.status_code == 201, done.text
    record = client.get(f"/api/v1/circuit-imports/{done.json()['import_id']}", headers=OP).json()
    assert {c["net"] for c in record["files"][0]["connections"]} == {"SIG", "GND"}
    loop = client.post("/api/v1/jobs", headers=OP, json={"kind": "probe_plan", "params": {
        "trace_ids": [done.json()["traces"][0]["trace"]["id"]]}}).json()["id"]
    refused = client.post("/api/v1/jobs", headers=OP, json={"kind": "circuit_program", "params": {
        "import_id": done.json()["import_id"], "closed_loop_job_id": loop}})
    assert refused.status_code == 422, refused.text
    problem = refused.json()
    assert "the print would open net" in problem["detail"] and "1 more net" in problem["detail"]
    value = problem["errors"][0]["value"]
    assert problem["errors"][0]["loc"] == ["params", "import_id"] and value["nets_open"] == 2
    gap, at = OPENS[value["net"]]
    assert value["gap_mm"] == pytest.approx(gap, abs=5e-3)
    where = shapely.LineString([(at[0], at[1] + 20), (at[2], at[3] + 20)])
    assert shapely.Point(value["at_mm"]).distance(where) <= 5e-3
    # a line fine enough for the neck, from a board without the dot: no open; the loop check follows
    fine = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", ("board.kicad_pcb", open_board(dot=False).encode()))],
                       data={"options": json.dumps({"origin_mm": [0, 20]})})
    ok = client.post("/api/v1/jobs", headers=OP, json={"kind": "circuit_program", "params": {
        "import_id": fine.json()["import_id"], "closed_loop_job_id": loop, "line_width_mm": 0.05}})
    assert ok.status_code == 422 and "closed_loop" in ok.text and "open" not in ok.json()["detail"]


def test_copper_graphics_are_warned_about_unless_asked(client, part):
    from tests.circuits.test_kicad_graphics import _board

    def run(**options):
        return client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                           files=[("files", ("g.kicad_pcb", _board().encode()))],
                           data={"options": json.dumps({"origin_mm": [0, 30], "dry_run": True, **options})}).json()

    plain = run()
    assert plain["areas"] == [] and len(plain["traces"]) == 1
    (warning,) = [w for w in plain["warnings"] if w["kind"] == "not_printed"]
    assert "5 copper graphic(s)" in warning["message"] and warning["file"] == "g.kicad_pcb"
    asked = run(copper_graphics=True)
    assert len(asked["areas"]) == 4 and len(asked["traces"]) == 2
    assert not [w for w in asked["warnings"] if w["kind"] == "not_printed"]
    assert sum(a["area_mm2"] for a in asked["areas"]) == pytest.approx(
        4 + (4.2 * 2.2 - 3.8 * 1.8 - (4 - np.pi) * 0.1 ** 2) + np.pi * 1.1 ** 2 + 1, abs=1e-2)   # arcs within 1 um


def test_the_layer_stack_and_vias_are_in_the_response_and_the_stored_import(client, part):
    from tests.circuits.test_layer_stack import STACK, four_layers

    done = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                       files=[("files", ("b.kicad_pcb", four_layers().encode()))],
                       data={"options": json.dumps({"origin_mm": [5, 30], "layer": "bottom"})})
    assert done.status_code == 201, done.text
    body = done.json()
    (stack_file,) = body["files"]
    assert [(r["layer"], r["side"], r["printed"], r["tracks"]) for r in stack_file["stack"]] == [
        (name, side, name == "B.Cu", tracks) for name, (side, tracks, *_) in STACK.items()]
    assert [t["source"]["side"] for t in body["traces"]] == ["bottom"]
    assert {p["source"]["layer"] for p in body["pads"]} == {"B.Cu"}
    (via,) = body["vias"]                         # the blind via does not reach B.Cu
    assert via["layers"] == ["F.Cu", "B.Cu"] and via["sides"] == ["top", "bottom"]
    record = client.get(f"/api/v1/circuit-imports/{body['import_id']}", headers=OP).json()
    (stored,) = record["files"]
    assert stored["stack"] == stack_file["stack"] and stored["interconnects"][0]["center_mm"] == via["center_mm"]
    assert record["options"]["layer"] == "bottom"
