"""warp_program through the API: a program warped onto a surface_fit of the S1 part lies at
its standoff above that surface; a move outside the fitted region is refused at submission
(422 naming the line and the coordinates) unless allowed."""

from __future__ import annotations

import numpy as np
import pytest

from app.gcode.lines import read_lines
from app.geometry.drape import top_surface_z
from app.geometry.nurbs_surface import NurbsSurface
from app.jobs.results.program import WarpProgramResult
from app.reference.s1 import s1_mesh
from tests.conftest import auth
from tests.jobs.test_five_axis_jobs import artifact, run_job, submit
from tests.jobs.test_program_results import round_trips

OP = auth("operator")


MESH = s1_mesh(grid_mm=1.0)


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return MESH.export(file_type="stl")


def _upload(client, text: str) -> dict:
    response = client.post("/api/v1/programs", files={"file": ("p.gcode", text.encode())}, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()


def surface_fit_of_s1(client, s1_stl: bytes) -> dict:  # type: ignore[no-untyped-def]
    """A succeeded surface_fit job of S1's top (x 5..55, y 5..35 mm, 21 x 13 grid)."""
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()
    fit = run_job(client, "surface_fit", {"part_id": part["id"], "region": {"x": [5, 55], "y": [5, 35]},
                                          "grid": [21, 13]})
    assert fit["status"] == "succeeded", fit["error"]
    return fit


def test_warp_program_on_a_surface_fit_and_outside_it(client, s1_stl):
    """One warp job on a surface fit: every printing point 0.1 mm above the fitted NURBS and
    within 0.05 mm of the part's top, the height model chosen by cross-validation; a move
    outside the fit refused at submission naming line and point, and run when allowed; a
    line the warp does not model (G43) refused at submission.  A post's program (tape marks,
    O-number, N-words) warped through the API is tests/bench/test_bench_warp_jobs.py (its
    reading and warping: tests/circuits/test_warp_posts.py, tests/circuits/test_gcode_scan.py)."""
    fit = surface_fit_of_s1(client, s1_stl)
    program = _upload(client, "G21\nG90\nG0 X10 Y10\nM106\nG1 X50 Y12 F600\nG1 X50 Y30\nM107\nG0 X10 Y30\n"
                              "M106\nG1 X30 Y20\nM107\n")
    job = run_job(client, "warp_program", {"program_id": program["id"], "surface_fit_job_id": fit["id"],
                                           "standoff_mm": 0.1})
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    assert result["printing_moves"] == 3 and result["max_chord_bound_mm"] <= 0.002
    assert round_trips(WarpProgramResult, job).fixed_split.split_mm == 5.0
    # the fitted surface sampled on a grid of its parameters (x and y along them): the grid's own
    # bicubic and Clough-Tocher compared by leaving grid rows out, the better one used
    model = result["height_model"]
    assert model["cv"] == "leave_one_row_out" and model["cv_max_mm"] > 0, model
    assert model["alternatives"][model["kind"]] == min(model["alternatives"].values())
    print("height model", model)
    assert result["fixed_split"]["pieces"] > 0
    _, response = artifact(client, job, "warped.gcode")
    dispensing, tips = False, []
    for ln in read_lines(response.text):
        dispensing = True if 106.0 in ln.m else False if 107.0 in ln.m else dispensing
        if dispensing and ln.get("X") is not None and ln.get("Z") is not None:
            tips.append([ln.get("X"), ln.get("Y"), ln.get("Z") - 0.1])
    # every printing point lies 0.1 mm above the fitted surface (its NURBS, inverted independently)
    fitted = NurbsSurface.from_dict(fit["result"]["surface"])
    assert len(tips) > 20 and fitted.invert(np.array(tips)).distance.max() <= 0.002
    # and near the part's top (the fit of its faceted top, least squares on a 21 x 13 grid)
    tips = np.array(tips)
    assert np.abs(tips[:, 2] - top_surface_z(MESH, tips[:, :2]).z).max() <= 0.05

    outside = _upload(client, "G21\nG90\nG0 X10 Y10\nM106\nG1 X58 Y12 F600\nM107\n")
    refused = submit(client, "warp_program", {"program_id": outside["id"], "surface_fit_job_id": fit["id"],
                                              "standoff_mm": 0.1})
    assert refused.status_code == 422, refused.text             # at submission: no job is queued
    problem = refused.json()
    assert "line 5" in problem["detail"] and "x=58.0000, y=12.0000" in problem["detail"]
    error = problem["errors"][0]
    assert error["loc"] == ["params", "program_id"] and error["value"]["line"] == 5
    assert error["value"]["to_xy"] == [58.0, 12.0]
    allowed = run_job(client, "warp_program", {"program_id": outside["id"], "surface_fit_job_id": fit["id"],
                                               "standoff_mm": 0.1, "allow_outside": True})
    assert allowed["status"] == "succeeded", allowed["error"]
    both = submit(client, "warp_program", {"program_id": program["id"], "surface_fit_job_id": fit["id"],
                                           "probe_run_job_id": fit["id"]})
    assert both.status_code == 422
    wrong = submit(client, "warp_program", {"program_id": program["id"], "probe_run_job_id": fit["id"]})
    assert wrong.status_code == 422 and "probe_run" in wrong.json()["detail"]

    # a line the warp does not model: refused at submission, naming it
    offset = _upload(client, "G21\nG90\nG43 H1 Z15\nG0 X10 Y10\n")
    refused = submit(client, "warp_program", {"program_id": offset["id"], "surface_fit_job_id": fit["id"]})
    assert refused.status_code == 422 and "line 3: G43" in refused.json()["detail"]
    assert refused.json()["errors"][0]["value"] == {"line": 3, "text": "G43 H1 Z15"}


def test_arc_chords_are_bounded_before_they_are_expanded(client):
    """Four full circles in 130 bytes: uploaded with their exact bounds in milliseconds; a chord
    sagitta below the floor is refused by the schema,
    and at the floor a radius whose chords exceed the program's budget is refused at submission,
    in milliseconds (the chords are counted, never made)."""
    import time

    circles = "G21\nG90\nG0 X10 Y10\n" + "G2 X10 Y10 I1000000 J0 F600\n" * 4
    cpu = time.process_time()
    program = _upload(client, circles)
    assert time.process_time() - cpu < 1.0         # the upload's bounds: each circle's exact extent, no chords
    assert program["bounds"] == [[10.0, -999_990.0, 0.0], [2_000_010.0, 1_000_010.0, 0.0]]
    probe = {"program_id": program["id"], "probe_run_job_id": "job_none"}
    tiny = submit(client, "warp_program", {**probe, "arc_chord_mm": 1e-12})
    assert tiny.status_code == 422 and tiny.json()["errors"][0]["loc"][-1] == "arc_chord_mm"
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", MESH.export(file_type="stl"))}, headers=OP).json()
    fit = run_job(client, "surface_fit", {"part_id": part["id"], "region": {"x": [5, 55], "y": [5, 35]},
                                          "grid": [9, 7]})
    t0 = time.perf_counter()
    big = submit(client, "warp_program", {"program_id": program["id"], "surface_fit_job_id": fit["id"],
                                          "arc_chord_mm": 1e-4})
    elapsed = time.perf_counter() - t0
    assert big.status_code == 422, big.text
    assert big.json()["errors"][0]["loc"] == ["params", "arc_chord_mm"] and "line 4" in big.json()["detail"]
    assert elapsed < 1.0


def test_a_program_too_big_to_check_at_submission_is_checked_by_its_job(client):
    """Arcs within the program's chord budget but beyond what a request reads (500 circles of
    50 chords each): accepted in well under a second of CPU, and the job itself refuses the
    moves that leave the measured region, naming the line."""
    import time

    from tests.helpers.jobs import wait_for

    text = "G21\nG90\nG0 X100 Y10\nM106\n" + "G2 X100 Y10 I0.5 J0 F600\n" * 500
    program = _upload(client, text)
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", MESH.export(file_type="stl"))}, headers=OP).json()
    fit = run_job(client, "surface_fit", {"part_id": part["id"], "region": {"x": [5, 55], "y": [5, 35]},
                                          "grid": [9, 7]})
    cpu = time.process_time()
    accepted = submit(client, "warp_program", {"program_id": program["id"], "surface_fit_job_id": fit["id"],
                                               "arc_chord_mm": 0.001})
    assert time.process_time() - cpu < 1.0
    assert accepted.status_code == 202, accepted.text
    job = wait_for(client, accepted.json()["id"], timeout=120)
    assert job["status"] == "failed"
    assert "line 5" in str(job["error"]) and "leaves the measured region" in str(job["error"]), job["error"]
