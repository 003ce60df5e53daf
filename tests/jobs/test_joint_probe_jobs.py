"""Part-level (joint) probing through the API: one probe_plan for several traces of the S1
part, one probe run, per-trace reconstruction with the other traces' probes as context,
and the closed loop with ``joint_probing`` on a mock machine holding an as-made part."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import update

from app.geometry.nurbs import NurbsCurve
from app.geometry.placement import Placement, apply_placement
from app.geometry.traces import as_trace_polyline
from app.platform.models import Job
from app.probing import segment_top_max
from app.reference.s1 import as_made, s1_mesh, s1_traces
from app.viewer.gcode_paths import parse_toolpath
from app.viewer.loaders import load_focus
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
TRACES = (5, 6, 7)  # S1 traces 6-8: one R40 arc and two NURBS, 4 mm apart
PROCESS = {"deviation_amplitude_mm": 0.15, "deviation_wavelength_mm": 15.0}


@pytest.fixture(scope="module")
def meshes():
    nominal = s1_mesh(grid_mm=0.5)
    return nominal, nominal.export(file_type="stl"), as_made(seed=4, amplitude_mm=0.15).mesh(
        grid_mm=0.5).export(file_type="stl")


@pytest.fixture
def setup(client, meshes):
    """(part, its traces TRACES, one more trace of it, a trace of another part, mock machine)."""
    _, stl, true_stl = meshes
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", stl)}, headers=OP).json()
    other_part = client.post("/api/v1/parts", files={"file": ("s1b.stl", stl)}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", true_stl)}, headers=OP).json()
    refs = [s1_traces()[i].to_api() for i in (*TRACES, 0)]
    *traces, spare = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=refs,
                                 headers=OP).json()["items"]
    foreign = client.post(f"/api/v1/parts/{other_part['id']}/traces", json=s1_traces()[8].to_api(),
                          headers=OP).json()
    machine = client.post("/api/v1/machines", json={
        "name": "m", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "probe_noise_mm": 0.001}}, headers=OP).json()
    return part, traces, spare, foreign, machine


def job(client, kind: str, params: dict, timeout: float = 60) -> dict:
    response = submit(client, kind, params)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=timeout)
    assert done["status"] == "succeeded", done["error"]
    return done


def joint_plan(client, traces, count: int = 6) -> dict:
    return job(client, "probe_plan", {"trace_ids": [t["id"] for t in traces], "method": "kriging",
                                      "count": count, **PROCESS})


def refused(response, loc: list[str]) -> dict:
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["errors"][0]["loc"][:len(loc)] == loc, body
    return body


def test_joint_kriging_plan_partitions_the_points_on_their_traces_with_one_safe_program(client, setup, meshes):
    _part, traces, *_ = setup
    plan = joint_plan(client, traces)
    result = plan["result"]
    entries = result["traces"]
    assert [e["trace_id"] for e in entries] == [t["id"] for t in traces]
    assert [e["count"] for e in entries] == [6, 6, 6]
    assert [e["first"] for e in entries] == [0, 6, 12]
    points = np.array(result["points"])
    assert result["count"] == len(points) == len(result["records"]) == 18
    assert [r["index"] for r in result["records"]] == list(range(18))
    assert result["s_mm"] == [s for e in entries for s in e["s_mm"]]
    for entry, trace in zip(entries, traces):
        path = as_trace_polyline(np.array(trace["nominal"]["points"]))
        own = points[entry["first"]:entry["first"] + entry["count"]]
        s = np.array(entry["s_mm"])
        assert np.all(np.diff(s) > 0) and 0 <= s[0] and s[-1] <= path.length_mm + 1e-9
        assert np.allclose(path.at(s), own, atol=1e-6)  # every point lies on its own trace
        assert entry["trace_length_mm"] == pytest.approx(trace["length_mm"])
        assert 0 < entry["predicted_sd_mm"] < 0.15
    # one program, one probe per point, travel level and clear of the part between all points
    gcode = client.get(plan["artifacts"][0]["url"], headers=OP).text
    assert gcode.count("G38.2") == 18
    moves = parse_toolpath(gcode)
    assert np.allclose(moves.starts[0][:2], moves.ends[0][:2])  # straight up first
    mesh = meshes[0]
    xy_moves = [(a, b) for a, b in zip(moves.starts, moves.ends) if np.linalg.norm(b[:2] - a[:2]) > 1e-9]
    assert len(xy_moves) == 18  # to the first point, then one between consecutive points
    for a, b in xy_moves:
        assert a[2] == b[2]
        assert a[2] >= segment_top_max(mesh, a[:2], b[:2], 0.25) + 2.0 - 1e-4  # G-code keeps 4 decimals
    # the viewer shows every trace with its own planned probes
    scene = load_focus(client.app.state.runtime, job_id=plan["id"])
    assert [line.name for line in scene.polylines] == [t["name"] for t in traces]
    assert [len(p.planned) for p in scene.probes] == [6, 6, 6]


def test_other_methods_plan_per_trace_in_one_program_with_every_trace_placed(client, setup):
    _part, traces, *_ = setup
    placed = {"dx": 0.2, "dy": -0.15, "dz": 0.03, "rz_deg": 0.3}
    plan = job(client, "probe_plan", {"trace_ids": [t["id"] for t in traces[:2]], "method": "uniform", "count": 5,
                                      "placement": placed})
    entries, points = plan["result"]["traces"], np.array(plan["result"]["points"])
    assert [(e["count"], e["first"]) for e in entries] == [(5, 0), (5, 5)] and plan["result"]["count"] == 10
    assert plan["result"]["placement"]["dx"] == pytest.approx(0.2)
    for entry, trace in zip(entries, traces):  # uniform: even arc length, ends included
        path = as_trace_polyline(np.array(trace["nominal"]["points"]))
        assert np.allclose(entry["s_mm"], np.linspace(0.0, path.length_mm, 5), atol=1e-6)
        assert entry["predicted_sd_mm"] is None
        at = apply_placement(path.at(np.array(entry["s_mm"])), Placement.from_deg(**placed))
        assert np.allclose(points[entry["first"]:entry["first"] + 5], at, atol=1e-6)  # in machine coordinates


def worst_height_error(rebuilt: dict, truth) -> float:
    """Largest |reconstructed - true| height (mm) along a reconstruct job's curve."""
    curve = NurbsCurve.from_dict(rebuilt["result"]["curve"])
    lo, hi = curve.domain
    pts = curve.evaluate(np.linspace(lo, hi, 600))
    return float(np.abs(pts[:, 2] - truth.true_height(pts[:, :2])).max())


@pytest.mark.parametrize("count", [5, 6])
def test_context_recovers_the_as_made_part_better_than_each_trace_alone(client, setup, count):
    _part, traces, *_ = setup
    plan = joint_plan(client, traces, count)["result"]
    for seed in (3, 11):
        truth = as_made(seed=seed, amplitude_mm=0.15)
        measured = []
        for entry in plan["traces"]:
            xy = np.array(plan["points"])[entry["first"]:entry["first"] + entry["count"], :2]
            measured.append(np.column_stack([xy, truth.true_height(xy)]).tolist())
        alone, joint = [], []
        for i, trace in enumerate(traces):
            base = {"trace_id": trace["id"], "points": measured[i], "method": "kriging", "sigma_mm": 0.001, **PROCESS}
            context = [{"trace_id": t["id"], "points": measured[j]} for j, t in enumerate(traces) if j != i]
            alone.append(worst_height_error(job(client, "reconstruct", base), truth))
            joint.append(worst_height_error(job(client, "reconstruct", {**base, "context": context}), truth))
        # the same few probes per trace: the part's other probes cut the worst error (the bench
        # shows 6-7 joint probes per trace meet 5 um where 8 are needed per trace)
        assert max(joint) < 0.6 * max(alone), (seed, joint, alone)
        assert max(joint) < 0.015, (seed, joint)


def test_reconstruct_from_a_joint_probe_run(client, setup):
    part, traces, spare, foreign, machine = setup
    plan = joint_plan(client, traces)
    run = job(client, "probe_run", {"plan_job_id": plan["id"], "machine_id": machine["id"]})
    rows = run["result"]["points"]
    assert [r["index"] for r in rows] == list(range(18))
    truth = as_made(seed=4, amplitude_mm=0.15)
    measured = np.array([r["measured"] for r in rows])
    assert np.abs(measured[:, 2] - truth.true_height(measured[:, :2])).max() < 0.02  # the mock's mesh + noise
    own = {e["trace_id"]: measured[e["first"]:e["first"] + e["count"]].tolist() for e in plan["result"]["traces"]}
    middle = traces[1]["id"]
    common = {"trace_id": middle, "method": "kriging", "sigma_mm": 0.001, **PROCESS}
    from_run = job(client, "reconstruct", {**common, "probe_run_job_id": run["id"]})
    assert from_run["result"]["points_used"] == 6
    # the same as giving the trace's own range as points and every other range as context
    explicit = job(client, "reconstruct", {**common, "points": own[middle], "context": [
        {"trace_id": t, "points": pts} for t, pts in own.items() if t != middle]})
    assert from_run["result"]["curve"] == explicit["result"]["curve"]
    alone = job(client, "reconstruct", {**common, "points": own[middle]})
    assert alone["result"]["curve"] != from_run["result"]["curve"]
    # other methods use the trace's own range only
    deviation = job(client, "reconstruct", {**common, "method": "deviation", "probe_run_job_id": run["id"]})
    assert deviation["result"]["points_used"] == 6
    assert np.allclose(np.array(deviation["result"]["deviation"]["samples"])[:, 0],
                       plan["result"]["traces"][1]["s_mm"], atol=0.01)
    # compensate rebuilds the joint reconstruction from the stored parameters
    compensated = job(client, "compensate", {"trace_id": middle, "reconstruct_job_id": from_run["id"], "hold_mm": 0.5})
    assert compensated["result"]["segments"] > 0
    # the viewer: a joint run shows every trace; its reconstruction only the trace's own probes
    runtime = client.app.state.runtime
    scene = load_focus(runtime, job_id=run["id"])
    assert [len(p.measured) for p in scene.probes] == [6, 6, 6] and len(scene.plots) == 3
    scene = load_focus(runtime, job_id=from_run["id"])
    assert [len(p.measured) for p in scene.probes] == [6]
    assert np.allclose(scene.probes[0].measured, own[middle])

    before = client.get("/api/v1/jobs?kind=reconstruct", headers=OP).json()["total"]
    not_probed = submit(client, "reconstruct", {**common, "trace_id": spare["id"], "probe_run_job_id": run["id"]})
    assert "not one of the traces" in refused(not_probed, ["params", "trace_id"])["detail"]
    base = {"trace_id": middle, "points": own[middle], "method": "kriging"}
    context = [{"trace_id": traces[0]["id"], "points": own[traces[0]["id"]]}]
    refused(submit(client, "reconstruct", {**base, "method": "interpolate", "context": context}),
            ["params", "context"])
    refused(submit(client, "reconstruct", {**common, "probe_run_job_id": run["id"], "context": context}),
            ["params", "context"])
    refused(submit(client, "reconstruct", {**base, "context": [{"trace_id": foreign["id"], "points": own[middle]}]}),
            ["params", "context", "0", "trace_id"])
    refused(submit(client, "reconstruct", {**base, "context": [{"trace_id": middle, "points": own[middle]}]}),
            ["params", "context", "0", "trace_id"])
    missing = refused(submit(client, "reconstruct", {**base, "context": [
        *context, {"trace_id": "trace_missing", "points": own[middle]}]}), ["params", "context", "1", "trace_id"])
    assert missing["errors"][0]["value"] == "trace_missing"
    far = (np.array(own[traces[0]["id"]]) + [30.0, 0.0, 0.0]).tolist()
    body = refused(submit(client, "reconstruct", {**base, "context": [
        *context, {"trace_id": traces[2]["id"], "points": far}]}), ["params", "context", "1", "points[0]"])
    assert "from the trace" in body["detail"]
    nan = client.post("/api/v1/jobs", content=(
        '{"kind": "reconstruct", "params": {"trace_id": "%s", "method": "kriging", "points": %s, '
        '"context": [{"trace_id": "%s", "points": [[1, 2, NaN]]}]}}' % (middle, own[middle], traces[0]["id"])).encode(),
        headers={**OP, "content-type": "application/json"})
    assert nan.status_code == 422, nan.text
    refused(submit(client, "reconstruct", {**base, "context": [{"trace_id": traces[0]["id"], "points": []}]}),
            ["params", "context", "0", "points"])
    assert client.get("/api/v1/jobs?kind=reconstruct", headers=OP).json()["total"] == before


def test_joint_plan_bad_input_is_refused_at_submission(client, setup):
    _part, traces, spare, foreign, _ = setup
    ids = [t["id"] for t in traces]
    body = refused(submit(client, "probe_plan", {"trace_ids": [*ids, ids[1]]}), ["params", "trace_ids", "3"])
    assert "twice" in body["detail"]
    body = refused(submit(client, "probe_plan", {"trace_ids": [ids[0], foreign["id"]]}), ["params", "trace_ids", "1"])
    assert foreign["id"] in body["detail"]
    refused(submit(client, "probe_plan", {"trace_ids": [ids[0], "trace_nope"]}), ["params", "trace_ids", "1"])
    both = refused(submit(client, "probe_plan", {"trace_id": spare["id"], "trace_ids": ids}), ["params"])
    assert "exactly one" in both["detail"]
    assert "exactly one" in refused(submit(client, "probe_plan", {"method": "kriging"}), ["params"])["detail"]
    refused(submit(client, "probe_plan", {"trace_ids": []}), ["params", "trace_ids"])
    assert client.get("/api/v1/jobs?kind=probe_plan", headers=OP).json()["total"] == 0


@pytest.fixture(scope="module")
def loop_meshes():
    truth = as_made(seed=11, amplitude_mm=0.15)
    return s1_mesh(grid_mm=0.3).export(file_type="stl"), truth.mesh(grid_mm=0.3).export(file_type="stl")


def loop_setup(client, loop_meshes) -> dict:
    """Closed-loop parameters on the nominal part with TRACES, a mock holding the as-made part
    (placed 0.03 mm high, 1 um probe noise), as in tests/e2e/test_closed_loop.py."""
    nominal_stl, true_stl = loop_meshes
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", nominal_stl)}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", true_stl)}, headers=OP).json()
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import",
                         json=[s1_traces()[i].to_api() for i in TRACES], headers=OP).json()["items"]
    machine = client.post("/api/v1/machines", json={
        "name": "sim", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "placement": {"dz": 0.03}, "probe_noise_mm": 0.001,
                 "faults": {"seed": 5}}}, headers=OP).json()
    return {"part_id": part["id"], "trace_ids": [t["id"] for t in traces], "machine_id": machine["id"],
            "sigma_mm": 0.001, "joint_probing": True}


def assert_standoff_held(client, done: dict) -> None:
    """The e2e closed loop's thresholds, and one shared plan and probe run."""
    entries, table = done["result"]["traces"], done["result"]["table"]
    assert len(table) == len(entries) == len(TRACES)
    for row in table:
        assert row["standoff_max_after_um"] <= 10.0, row
        assert row["standoff_max_before_um"] >= 50.0, row
        assert row["width_std_after_um"] < row["width_std_before_um"]
    assert len({e["probe_plan"] for e in entries}) == 1 and len({e["probe_run"] for e in entries}) == 1
    plan = client.get(f"/api/v1/jobs/{entries[0]['probe_plan']}?include=result&include=artifacts", headers=OP).json()
    assert plan["params"]["trace_ids"] == [e["trace_id"] for e in entries] and plan["params"]["dialect"] == "marlin"
    counts = [e["count"] for e in plan["result"]["traces"]]
    assert [e["probes"] for e in entries] == [row["probes"] for row in table] == counts
    children = client.get(f"/api/v1/jobs?parent_id={done['id']}&limit=100", headers=OP).json()["items"]
    kinds = sorted(j["kind"] for j in children)
    assert kinds.count("probe_plan") == 1 and kinds.count("probe_run") == 1
    assert kinds.count("reconstruct") == kinds.count("compensate") == len(TRACES)
    assert kinds.count("print") == 2 * len(TRACES)
    assert all(j["status"] == "succeeded" for j in children)


def test_closed_loop_with_joint_probing_holds_the_standoff(client, loop_meshes):
    """As tests/e2e/test_closed_loop.py (deviation planner and model), with one plan and one
    probe run for all traces; a retried loop reuses its children."""
    params = {**loop_setup(client, loop_meshes), "probe": {"method": "deviation"}}
    done = job(client, "closed_loop", {**params, "evaluate": True}, timeout=240)
    assert_standoff_held(client, done)

    # a retried loop (its worker died) reuses the finished children instead of probing again
    again = job(client, "closed_loop", params)
    before = client.get(f"/api/v1/jobs?parent_id={again['id']}", headers=OP).json()["total"]
    assert before == 2 + 2 * len(TRACES)
    runtime = client.app.state.runtime
    with runtime.engine.begin() as conn:
        conn.execute(update(Job).where(Job.id == again["id"]).values(status="queued", result=None, finished_at=None))
    runtime.enqueue(again["id"], "workflow")
    retried = wait_for(client, again["id"])
    assert retried["status"] == "succeeded" and retried["attempts"] == 2
    assert client.get(f"/api/v1/jobs?parent_id={again['id']}", headers=OP).json()["total"] == before
    assert retried["result"]["traces"] == again["result"]["traces"]


def test_closed_loop_with_joint_kriging_probing_holds_the_standoff(client, loop_meshes):
    params = {**loop_setup(client, loop_meshes), "probe": {"method": "kriging", **PROCESS},
              "reconstruct_method": "kriging"}  # no hold_mm: a kriging model covers the trace ends
    response = submit(client, "closed_loop", {**params, "evaluate": True})
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=240)
    assert done["status"] == "succeeded", done["error"]["detail"]
    assert_standoff_held(client, done)


def test_closed_loop_joint_probing_refuses_a_repeated_trace(client, loop_meshes):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", loop_meshes[0])}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[0].to_api(), headers=OP).json()
    machine = client.post("/api/v1/machines", json={"name": "m", "port": "mock://"}, headers=OP).json()
    base = {"part_id": part["id"], "trace_ids": [trace["id"], trace["id"]], "machine_id": machine["id"],
            "joint_probing": True}
    body = refused(submit(client, "closed_loop", base), ["params", "trace_ids", "1"])
    assert "twice" in body["detail"]
    refused(submit(client, "closed_loop", {**base, "trace_ids": [trace["id"]], "probe": {"trace_ids": ["x"]}}),
            ["params", "probe"])
    assert client.get("/api/v1/jobs?kind=closed_loop", headers=OP).json()["total"] == 0
