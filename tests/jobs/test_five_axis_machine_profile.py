"""five_axis jobs that take their program settings from a LinuxCNC machine's profile."""

from __future__ import annotations

import numpy as np

from app.geometry.nurbs_surface import NurbsSurface
from tests.helpers.gcode_words import g1_rows
from tests.jobs.test_five_axis_jobs import (
    ARC,
    OP,
    add_trace,
    artifact,
    assert_normal_and_standoff,
    cap_stl,
    run_job,
    submit,
    upload,
)

__all__ = ["cap_stl"]  # the module-scoped part fixture, shared
PIVOT = [1.0, 2.0, -12.0]
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "program_end": "M2", "pivot_mm": PIVOT,
           "five_axis_post": "linuxcnc_xyzac_trt", "probe_command": "G38.2"}


def test_machine_profile_sets_post_pivot_dispense_and_end(client, cap_stl):
    machine = client.post("/api/v1/machines", headers=OP, json={
        "name": "trt", "port": "linuxcnc://127.0.0.1:5007?joints=5", "dialect": "linuxcnc", "profile": PROFILE})
    assert machine.status_code == 201, machine.text
    part = upload(client, cap_stl)
    trace = add_trace(client, part["id"], ARC)
    job = run_job(client, "five_axis", {"part_id": part["id"], "trace_id": trace["id"],
                                        "machine_id": machine.json()["id"], "pivot": [9.0, 9.0, 9.0]})
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["post"] == "linuxcnc_xyzac_trt" and job["result"]["pivot"] == PIVOT
    text = artifact(client, job, "five_axis.gcode")[1].text
    lines = text.splitlines()
    assert lines[-1] == "M2" and "M428" in lines and "M64 P0" in lines and "M65 P0" in lines
    assert "setp xyzac-trt-kins.x-rot-point 1" in text and "G64 P0.001" in lines
    # TCP: the program's X Y Z are already workpiece tips; A, C turn the nozzle to the normal
    rows = np.array(g1_rows(text))
    a, c = np.radians(rows[:, 3]), np.radians(rows[:, 4])
    axes = np.stack([np.sin(a) * np.sin(c), np.sin(a) * np.cos(c), np.cos(a)], -1)
    surface = NurbsSurface.from_dict(job["result"]["surface"])
    assert_normal_and_standoff(surface, rows[:, :3], axes)


def test_unknown_machine_is_refused(client, cap_stl):
    part = upload(client, cap_stl)
    trace = add_trace(client, part["id"], ARC)
    response = submit(client, "five_axis", {"part_id": part["id"], "trace_id": trace["id"], "machine_id": "mach_x"})
    problem = response.json()
    assert response.status_code == 422 and problem["errors"][0]["loc"] == ["params", "machine_id"]
    assert problem["errors"][0]["value"] == "mach_x"
