"""Bench: a post's program (tape marks, an O-number, N-words, comments) warped through the
API onto a surface fit of S1.

Run: .venv/bin/python -m pytest tests/bench/test_bench_warp_jobs.py -o addopts="" -q

The default suite covers this path in parts: the warp job on a surface fit through the API
(tests/jobs/test_circuit_jobs.py::test_warp_program_on_a_surface_fit_and_outside_it) and the
reading and warping of posts' programs (tests/circuits/test_warp_posts.py,
tests/circuits/test_gcode_scan.py); this run puts the two together.
"""

from __future__ import annotations

from tests.jobs.test_circuit_jobs import MESH, _upload, surface_fit_of_s1
from tests.jobs.test_five_axis_jobs import run_job


def test_a_posts_program_is_warped_through_the_api(client):
    """A post's program uploads and its warp job succeeds."""
    fit = surface_fit_of_s1(client, MESH.export(file_type="stl"))
    # what posts write around a program: tape marks, a program number, line numbers, comments
    post = _upload(client, "%\nO1001\n(ISOLATION)\nN10 G90 G94 G17 G21\nN20 G0 Z5.\nN30 M3 S1000\n"
                           "N40 X10. Y10.\nN50 G1 Z-0.05 F60.\nN60 X20. F150.\nN70 G0 Z5.\nN80 M5\n%\n")
    warped = run_job(client, "warp_program", {"program_id": post["id"], "surface_fit_job_id": fit["id"]})
    assert warped["status"] == "succeeded", warped["error"]
