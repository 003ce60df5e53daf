"""Real-world fixtures through the API, as a new user would send them: each is imported in
the right units, repaired or refused clearly, sliced without a sliver, and placed on the bed
(the program's first move inside the machine's volume)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.helpers.real_parts import bolt, inch_3mf, metre_glb, metre_stl, teapot_like, two_body_badly_wound

OP = auth("operator")
BED = {"x": [0, 200], "y": [0, 200], "z": [0, 200]}


def upload(client, name: str, data: bytes, **form) -> dict:
    response = client.post("/api/v1/parts", files={"file": (name, data)}, data=form, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()


def run(client, kind: str, params: dict, status: str = "succeeded") -> dict:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=120.0)
    assert job["status"] == status, job["error"]
    return job


def first_move(gcode: str) -> tuple[float, float, float]:
    """The first absolute position the program moves to with X, Y and Z all known."""
    pos: dict[str, float] = {}
    for line in gcode.splitlines():
        command = line.split(";", 1)[0].strip().upper()
        if not re.match(r"^G0?[01]\b", command):
            continue
        for axis, value in re.findall(r"([XYZ])(-?[\d.]+)", command):
            pos[axis] = float(value)
        if len(pos) == 3:
            return pos["X"], pos["Y"], pos["Z"]
    raise AssertionError("no move with X, Y and Z")


def slice_and_place(client, part: dict, layer_mm: float, **slice_params) -> tuple[dict, dict, str]:
    sliced = run(client, "slice", {"part_id": part["id"], "layer_mm": layer_mm, **slice_params})
    thicknesses = [lay["thickness"] for lay in sliced["result"]["layers"]]
    assert min(thicknesses) >= 0.5 * layer_mm - 1e-9, "a sliver layer"
    assert sum(thicknesses) == pytest.approx(part["bounds"][1][2] - part["bounds"][0][2], abs=1e-6)
    path = run(client, "toolpath", {"slice_job_id": sliced["id"], "line_width_mm": 1.0, "infill": 0.25,
                                    "volume_mm": BED})
    gcode = client.get(path["artifacts"][0]["url"], headers=OP).text
    x, y, z = first_move(gcode)
    assert 0 <= x <= 200 and 0 <= y <= 200 and 0 <= z <= 200
    (x0, y0, z0), (x1, y1, z1) = path["artifacts"][0]["meta"]["bounds"]
    assert min(x0, y0, z0) >= 0 and max(x1, y1, z1) <= 200
    assert z0 == pytest.approx(thicknesses[0], abs=1e-4)     # the first layer printed on the bed (z = 0)
    return sliced, path, gcode


def test_inch_3mf_is_read_in_inches_and_placed(client):
    part = upload(client, "bracket.3mf", inch_3mf((1.0, 2.0, 0.5)))
    assert part["units"] == "inch" and part["frame"]["units_source"] == "file"
    assert np.allclose(np.ptp(np.array(part["bounds"]), axis=0), [25.4, 50.8, 12.7])
    assert part["volume_mm3"] == pytest.approx(25.4 ** 3, rel=1e-9) and part["warnings"] == []
    sliced, _, _ = slice_and_place(client, part, 0.2)
    assert sliced["result"]["layer_count"] == 63        # 12.7 / 0.2 = 63.5 (63.4999 in floats): 63 of 0.2016 mm


def test_metre_glb_is_read_in_metres_with_y_up(client):
    part = upload(client, "case.glb", metre_glb((40.0, 30.0, 10.0)))
    assert part["units"] == "m" and part["frame"]["up"] == "+y"
    assert np.allclose(np.ptp(np.array(part["bounds"]), axis=0), [40.0, 30.0, 10.0], atol=1e-5)
    assert part["format"] == "ply" and part["source_format"] == "glb"     # the stored mesh is the part's frame
    slice_and_place(client, part, 1.0)


def test_metre_stl_warns_then_imports_with_units(client):
    guessed = upload(client, "plate.stl", metre_stl((40.0, 30.0, 10.0)))
    assert guessed["units"] == "mm" and "only 0.04 mm across" in guessed["warnings"][0]
    part = upload(client, "plate.stl", metre_stl((40.0, 30.0, 10.0)), units="m")
    assert part["units"] == "m" and part["frame"]["units_source"] == "upload" and part["warnings"] == []
    assert np.allclose(np.ptp(np.array(part["bounds"]), axis=0), [40.0, 30.0, 10.0], atol=1e-4)
    slice_and_place(client, part, 1.0)
    # and an orientation at upload: the 10 mm side up becomes the 40 mm side up
    turned = upload(client, "plate.stl", metre_stl((40.0, 30.0, 10.0)), units="m", up="+x")
    assert np.allclose(np.ptp(np.array(turned["bounds"]), axis=0), [10.0, 30.0, 40.0], atol=1e-4)
    bad = client.post("/api/v1/parts", files={"file": ("p.stl", metre_stl())}, data={"units": "furlong"}, headers=OP)
    assert bad.status_code == 422 and "units" in str(bad.json()["errors"][0]["loc"])


def test_open_teapot_is_repaired_or_refused_with_the_hole_size(client):
    data, closed_volume, opening = teapot_like()
    part = upload(client, "teapot.stl", data)
    assert part["watertight"] is False and part["volume_mm3"] is None
    sliced, _, _ = slice_and_place(client, part, 1.0)
    repairs = sliced["result"]["repairs"]
    assert any(r.startswith("filled holes: 1 (64 open edges") for r in repairs), repairs
    # closed flat, as designed (float32 STL)
    assert sliced["result"]["volume_mm3"] == pytest.approx(closed_volume, rel=1e-6)
    assert part["defects"]["holes"] == 1 and part["defects"]["open_edges"] == 64
    assert part["defects"]["largest_hole_mm"] == pytest.approx(opening, rel=1e-6)
    # a hole larger than allowed is refused at submission, not after queuing
    refused = client.post("/api/v1/jobs", json={"kind": "slice", "params": {
        "part_id": part["id"], "layer_mm": 1.0, "max_hole_mm": 100.0}}, headers=OP)
    assert refused.status_code == 422
    detail = refused.json()["detail"]
    assert "cannot be made watertight" in detail and f"{opening:.4g} mm around" in detail


def test_inconsistently_wound_two_bodies_get_no_false_volume_then_repair(client):
    data, true_volume = two_body_badly_wound()
    part = upload(client, "two.stl", data)
    assert part["watertight"] is False and part["volume_mm3"] is None          # trimesh alone says 3000 mm^3
    assert any("volume not reported" in w for w in part["warnings"])
    sliced, _, _ = slice_and_place(client, part, 1.0)
    assert sliced["result"]["volume_mm3"] == pytest.approx(true_volume, rel=1e-6)
    assert any("fixed winding and normals" in r for r in sliced["result"]["repairs"])


@pytest.mark.parametrize("layer_mm", [0.1, 0.2, 0.25])
def test_bolt_height_not_a_multiple_of_the_layer_slices_and_exports(client, layer_mm):
    part = upload(client, "bolt.stl", bolt(31.00026))
    height = part["bounds"][1][2] - part["bounds"][0][2]
    sliced, _, _ = slice_and_place(client, part, layer_mm)
    layers = sliced["result"]["layers"]
    assert len(layers) == round(height / layer_mm)
    assert max(abs(lay["thickness"] - layer_mm) for lay in layers) < layer_mm / (2 * len(layers)) + 1e-12
    assert [a["name"] for a in sliced["artifacts"]].count("layers.slc") == 1


def test_layers_that_would_vanish_on_the_slc_quantum_are_refused_at_submission(client):
    part = upload(client, "bolt.stl", bolt(31.00026))
    response = client.post("/api/v1/jobs", json={"kind": "slice", "params": {
        "part_id": part["id"], "layer_mm": 0.01, "slc_quantum_mm": 0.05}}, headers=OP)
    assert response.status_code == 422 and "quantum" in response.json()["detail"]
    assert math.isclose(response.json()["errors"][0]["value"], 0.01)
