"""The closed loop through the API with the mock printer (the acceptance case).

S1 reference part, as-made with +-0.15 mm machining error and a 0.03 mm placement offset
in z, 1 um probe noise: every compensated trace holds its standoff within 10 um along the
whole printed length (measured on what the mock really deposited), while the nominal
programs are off by >= 100 um (on the worst trace; >= 50 um on each).

With an XY + rotation placement (dx 0.2, dy -0.15, rz 0.3 deg about the machine origin,
dz 0.03) and ``registration``: the printed path lies within 10 um (top view) of the
designed trace moved by the TRUE placement, still at its standoff within 10 um; the same
loop without registration prints the designed trace where the part is not (XY error of
the order of the offset).
"""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.placement import Placement, apply_placement
from app.reference.s1 import as_made, centred_placement, s1_mesh, s1_traces
from app.viewer.loaders import load_focus
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
TRACES = (0, 3, 6)  # one line, one R40 arc, one NURBS


@pytest.fixture(scope="module")
def meshes():
    truth = as_made(seed=11, amplitude_mm=0.15)
    return s1_mesh(grid_mm=0.3).export(file_type="stl"), truth.mesh(grid_mm=0.3).export(file_type="stl")


def _mock_setup(client, nominal_stl: bytes, true_stl: bytes, name: str, placement: dict,
                seed: int) -> tuple[dict, list[dict], dict]:
    """Upload the nominal and the as-made part, import the TRACES on the nominal and add a
    mock Marlin machine holding the as-made part at ``placement``: (part, traces, machine)."""
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", nominal_stl)}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("s1-as-made.stl", true_stl)}, headers=OP).json()
    refs = [s1_traces()[i] for i in TRACES]
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=[t.to_api() for t in refs],
                         headers=OP).json()["items"]
    machine = client.post("/api/v1/machines", json={
        "name": name, "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "placement": placement, "probe_noise_mm": 0.001,
                 "faults": {"seed": seed}}}, headers=OP).json()
    return part, traces, machine


def test_compensated_traces_hold_their_standoff_on_the_real_part(client, meshes):
    nominal_stl, true_stl = meshes
    part, traces, machine = _mock_setup(client, nominal_stl, true_stl, "sim", {"dz": 0.03}, seed=5)
    response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [t["id"] for t in traces], "machine_id": machine["id"],
        "probe": {"method": "deviation"}, "sigma_mm": 0.001, "evaluate": True}}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=240)
    assert done["status"] == "succeeded", done["error"]
    table = done["result"]["table"]
    assert len(table) == len(TRACES)
    for row in table:
        assert row["standoff_max_after_um"] <= 10.0, row
        assert row["standoff_max_before_um"] >= 50.0, row  # where the +-0.15 mm error field peaks varies
        assert row["width_std_after_um"] < row["width_std_before_um"]
    assert max(row["standoff_max_before_um"] for row in table) >= 100.0
    children = client.get(f"/api/v1/jobs?parent_id={done['id']}&limit=100", headers=OP).json()
    kinds = sorted(j["kind"] for j in children["items"])
    assert kinds.count("probe_run") == len(TRACES) and kinds.count("print") == 2 * len(TRACES)
    assert all(j["status"] == "succeeded" for j in children["items"])
    # the 3-D view of the loop shows every trace's probes and programs, none overwriting another
    scene = load_focus(client.app.state.runtime, job_id=done["id"])
    runs = [j for j in children["items"] if j["kind"] == "probe_run"]
    measured = [p for p in scene.probes if p.measured is not None and p.name.startswith("probe_run:")]
    assert len(measured) == len(TRACES)
    assert sum(len(p.measured) for p in measured) == sum(len(run["result"]["points"]) for run in runs)
    names = [item.name for key in ("polylines", "probes", "toolpaths") for item in getattr(scene, key)]
    assert len(names) == len(set(names))
    assert sum(t.name.startswith("compensate:") for t in scene.toolpaths) == 2 * len(TRACES)

    # the run report: one page with the part, every trace, its compensated program's hash
    # and the deposited standoff before / after, as the jobs recorded them
    report = client.get(f"/api/v1/jobs/{done['id']}/report", headers=OP)
    assert report.status_code == 200 and report.headers["content-type"].startswith("text/html")
    page = report.text
    assert part["sha256"] in page and machine["id"] in page
    for trace in traces:
        assert trace["name"] in page
    for child in children["items"]:
        assert child["id"] in page
        if child["kind"] == "compensate":
            program = next(a for a in child["artifacts"] if a["name"] == "print.gcode")
            assert program["meta"]["commands_sha256"] in page
    for row in table:
        assert f"<td class=\"n\">{row['standoff_max_after_um']}</td>" in page
    assert page.count("<svg") == len(TRACES)          # one deviation plot per trace
    download = client.get(f"/api/v1/jobs/{done['id']}/report?download=true", headers=OP)
    assert download.headers["content-disposition"] == f'attachment; filename="run-report-{done["id"]}.html"'
    compensate = next(j for j in children["items"] if j["kind"] == "compensate")
    refused = client.get(f"/api/v1/jobs/{compensate['id']}/report", headers=OP)
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"][-1] == "job_id"
    run = next(j for j in children["items"] if j["kind"] == "probe_run")     # a probe run has its own report:
    own = client.get(f"/api/v1/jobs/{run['id']}/report", headers=OP).text    # its plan, and what was made from it
    assert run["params"]["plan_job_id"] in own and own.count("<svg") == 1
    assert client.get("/api/v1/jobs/job_missing/report", headers=OP).status_code == 404


PLACED = {"dx": 0.2, "dy": -0.15, "dz": 0.03, "rz_deg": 0.3}


def test_registration_puts_the_print_on_the_part_where_it_really_sits(client, meshes):
    nominal_stl = meshes[0]
    true_stl = as_made(seed=11, amplitude_mm=0.15, placement=centred_placement()).mesh(grid_mm=0.3).export(
        file_type="stl")  # as made, in the part frame: the mock applies the placement
    part, traces, machine = _mock_setup(client, nominal_stl, true_stl, "placed", PLACED, seed=7)
    base = {"part_id": part["id"], "trace_ids": [t["id"] for t in traces], "machine_id": machine["id"],
            "probe": {"method": "deviation"}, "sigma_mm": 0.001, "evaluate": True}
    runs = {}
    for registration in (True, False):
        response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
            **base, "registration": registration}}, headers=OP)
        assert response.status_code == 202, response.text
        runs[registration] = wait_for(client, response.json()["id"], timeout=240)
        assert runs[registration]["status"] == "succeeded", runs[registration]["error"]
    registered, unregistered = runs[True]["result"], runs[False]["result"]
    # the estimated transform and its uncertainty are reported
    reg = registered["registration"]
    est, std = reg["placement"], reg["std"]
    for key in ("dx", "dy"):
        assert abs(est[key] - PLACED[key]) <= 3 * std[f"{key}_mm"] + 0.001, (key, est, std)
    assert abs(est["rz_deg"] - PLACED["rz_deg"]) <= 3 * std["rz_deg"] + 0.001
    assert abs(est["dz"] - PLACED["dz"]) <= 0.15 + 3 * std["dz_mm"]  # the top's machining error biases dz
    assert reg["unobservable"] == [] and reg["probe_count"] > 20
    # with registration: on the truly placed design in XY, at the standoff in Z
    for row in registered["table"]:
        assert row["xy_max_after_um"] <= 10.0 and row["xy_max_before_um"] <= 10.0, row
        assert row["standoff_max_after_um"] <= 10.0, row
        assert row["standoff_max_before_um"] >= 50.0, row
    # without: the designed trace printed where the part is not, off by about the offset
    truth = Placement.from_deg(**PLACED)
    for row, trace in zip(unregistered["table"], traces):
        nominal = np.array(trace["nominal"]["points"])
        moved_um = 1000 * np.linalg.norm(apply_placement(nominal, truth)[:, :2] - nominal[:, :2], axis=1)
        assert 150.0 <= row["xy_max_after_um"] <= moved_um.max() + 5.0, (row, moved_um.max())
        assert row["xy_max_after_um"] > 15 * max(r["xy_max_after_um"] for r in registered["table"])
    children = client.get(f"/api/v1/jobs?parent_id={runs[True]['id']}&limit=100", headers=OP).json()["items"]
    plans = [j for j in children if j["kind"] == "probe_plan"]
    assert [j["kind"] for j in children].count("register") == 1
    assert all(j["params"]["registration_job_id"] == reg["job_id"] for j in plans)


def test_closed_loop_bad_input(client, meshes):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", meshes[0])}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[0].to_api(), headers=OP).json()
    real_machine = client.post("/api/v1/machines", json={"name": "r", "port": "socket://127.0.0.1:9"},
                               headers=OP).json()
    base = {"part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": real_machine["id"]}
    no_truth = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {**base, "evaluate": True}},
                           headers=OP)
    assert no_truth.status_code == 422 and no_truth.json()["errors"][0]["loc"] == ["params", "evaluate"]
    wrong_trace = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {**base, "trace_ids": ["t_x"]}},
                              headers=OP)
    assert wrong_trace.status_code == 422 and "trace_ids" in wrong_trace.json()["errors"][0]["loc"]
    bad_probe = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        **base, "probe": {"method": "psychic"}}}, headers=OP)
    assert bad_probe.status_code == 422
    bad_register = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        **base, "registration": True, "registration_params": {"mode": "psychic"}}}, headers=OP)
    assert bad_register.status_code == 422
    assert bad_register.json()["errors"][0]["loc"][:2] == ["params", "registration_params"]
    two_placements = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        **base, "registration": True, "probe": {"placement": {"dx": 0.1}}}}, headers=OP)
    assert two_placements.status_code == 422 and "registration" in two_placements.json()["detail"]
    assert client.get("/api/v1/jobs?kind=closed_loop", headers=OP).json()["total"] == 0
