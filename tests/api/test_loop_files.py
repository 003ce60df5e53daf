"""A closed loop has files of its own: a summary of every trace's figures
(JSON and CSV, the same rows as the result) and one whole-part program that dispenses
exactly what each trace's compensated program dispenses, in the machine's dialect, with
travel between traces at a safe height."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from app.gcode.reader import ReadOptions, read_program
from app.gcode.writer import own_dispense
from app.reference.s1 import as_made, s1_mesh
from tests.conftest import auth
from tests.e2e.test_closed_loop import _mock_setup
from tests.helpers.jobs import wait_for

OP = auth("operator")


@pytest.fixture(scope="module")
def meshes():
    truth = as_made(seed=11, amplitude_mm=0.15)
    return s1_mesh(grid_mm=0.3).export(file_type="stl"), truth.mesh(grid_mm=0.3).export(file_type="stl")


def _artifact(client, job_id: str, name: str) -> bytes:  # type: ignore[no-untyped-def]
    response = client.get(f"/api/v1/jobs/{job_id}/artifacts/{name}", headers=OP)
    assert response.status_code == 200, (name, response.text)
    return response.content


def test_a_closed_loop_lists_its_summary_and_a_whole_part_program(client, meshes):
    part, traces, machine = _mock_setup(client, *meshes, "files", {"dz": 0.03}, seed=3)
    response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [t["id"] for t in traces], "machine_id": machine["id"],
        "probe": {"method": "deviation"}, "sigma_mm": 0.001, "evaluate": True}}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=300)
    assert done["status"] == "succeeded", done["error"]
    listed = {a["name"]: a for a in client.get(f"/api/v1/jobs/{done['id']}/artifacts", headers=OP).json()}
    assert {"loop_summary.json", "loop_summary.csv", "whole_part.gcode"} <= set(listed)

    # the summary: one row per trace, the same figures as the loop's result table (µm)
    rows = json.loads(_artifact(client, done["id"], "loop_summary.json"))["traces"]
    table = done["result"]["table"]
    assert [r["trace_id"] for r in rows] == [t["id"] for t in traces]
    for row, line in zip(rows, table):
        assert row["standoff_max_before_um"] == pytest.approx(line["standoff_max_before_um"], abs=0.01)
        assert row["standoff_max_after_um"] == pytest.approx(line["standoff_max_after_um"], abs=0.01)
        assert row["standoff_max_after_um"] < row["standoff_max_before_um"]
    parsed = list(csv.DictReader(io.StringIO(_artifact(client, done["id"], "loop_summary.csv").decode())))
    assert [r["trace_id"] for r in parsed] == [r["trace_id"] for r in rows]
    assert [float(r["standoff_max_after_um"]) for r in parsed] == [r["standoff_max_after_um"] for r in rows]

    # the whole-part program dispenses exactly each compensated program's path, in the loop's order
    whole = _artifact(client, done["id"], "whole_part.gcode").decode()
    on, off = own_dispense("marlin")  # the mock machine's profile names none: its dialect's
    options = ReadOptions(dispense_on=on, dispense_off=off)
    info = done["result"]["files"]["whole_part"]
    assert (info["dialect"] == "marlin"
            and info["lines"] == len(whole.splitlines()) == listed["whole_part.gcode"]["meta"]["lines"])
    assert info["time_s"] > 0 and sorted(info["order"]) == sorted(t["id"] for t in traces)
    by_trace = {e["trace_id"]: e["compensate"] for e in done["result"]["traces"]}

    def dispensed(text: str) -> np.ndarray:
        program = read_program(text, options)
        return np.hstack([program.start[program.dispense, :3], program.end[program.dispense, :3]])

    expected = np.vstack([dispensed(_artifact(client, by_trace[t], "print.gcode").decode()) for t in info["order"]])
    got = dispensed(whole)
    assert got.shape == expected.shape and np.allclose(got, expected, atol=1e-4)
    program = read_program(whole, options)
    jumps = ~program.dispense & (np.linalg.norm(program.end[:, :2] - program.start[:, :2], axis=1) > 1.0)
    assert jumps.any() and np.all(program.start[jumps, 2] >= info["safe_z_mm"] - 1e-6)
    assert info["safe_z_mm"] > program.end[program.dispense, 2].max()
    assert "M2" not in whole.splitlines()  # Marlin: no grbl program end

    # what the machines page's Print confirmation reads: lines and the estimated time
    summary = client.get(f"/api/v1/jobs/{done['id']}/artifacts/whole_part.gcode/summary", headers=OP)
    assert summary.status_code == 200, summary.text
    assert summary.json()["lines"] == info["lines"] and summary.json()["time_s"] == pytest.approx(info["time_s"])
    refused = client.get(f"/api/v1/jobs/{done['id']}/artifacts/loop_summary.json/summary", headers=OP)
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"][-1] == "name"

    # the loop's 3-D scene: one deviation ribbon per trace (none duplicated by its compensate
    # step), and every program coloured by its standoff error over the rebuilt surface: the
    # nominal programs far off (>= 50 um somewhere), the compensated ones within 10 um (their
    # chord error plus the nominal polyline's own sampling between its points)
    from app.viewer.deviation_map import scene_legends
    from app.viewer.loaders import load_focus

    scene = load_focus(client.app.state.runtime, job_id=done["id"])
    assert len([s for s in scene.scalar_surfaces if s.signed]) == len(traces)
    errors = {role: np.concatenate([t.standoff_error_mm[np.isfinite(t.standoff_error_mm)]
                                    for t in scene.toolpaths if t.role == role and t.standoff_error_mm is not None])
              for role in ("nominal", "compensated")}
    assert np.abs(errors["compensated"]).max() < 0.010 and np.abs(errors["nominal"]).max() >= 0.050
    [legend] = scene_legends(scene)
    assert legend.hi_um == pytest.approx(max(abs(legend.data_min_um), legend.data_max_um))
