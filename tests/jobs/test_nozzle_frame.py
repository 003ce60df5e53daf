"""compensate writes for a nozzle: ``T<tool>`` first, every coordinate the
carriage's = tip - the nozzle's CALIBRATED offset (the latest calibrate_nozzle job), the
nominal offset only when asked (ablation) or allowed (uncalibrated, with a warning), and
the nozzle body's clearance against the real surface — refused (422) when it would touch.

The part is a plane tilted along x (z = 5 + 0.2 x), so the flat-ended body of outer
diameter D over a tip at standoff s has the analytic clearance s - (D / 2) * 0.2.
"""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest
from sqlmodel import Session

from app.gcode.reader import read_program
from app.jobs.results.models import PrintResult
from app.platform.models import Job
from app.reference.s1 import height_field_mesh
from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.jobs.test_program_results import round_trips

OP = auth("operator")
SLOPE = 0.2
STANDOFF = 0.1
NOMINAL_T1 = (12.0, -4.0, -8.5)
CALIBRATED_T1 = (12.3, -4.1, -8.7)
TOOLS = {"nozzles": [{"tool": 1, "name": "fine", "outer_diameter_mm": 0.4, "offset_mm": list(NOMINAL_T1)},
                     {"tool": 2, "name": "wide", "outer_diameter_mm": 1.5, "offset_mm": [-10.0, 5.0, -9.0]}]}


def _wedge(xy: np.ndarray) -> np.ndarray:
    return 5.0 + SLOPE * xy[:, 0]


@pytest.fixture(scope="module")
def wedge_stl() -> bytes:
    return height_field_mesh(_wedge, grid_mm=1.0).export(file_type="stl")


def _job(client, kind: str, params: dict, timeout: float = 60) -> dict:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    return wait_for(client, response.json()["id"], timeout=timeout)


@pytest.fixture
def rebuilt(client, wedge_stl):
    """A wedge part, a trace along y at x = 20 (level along the path, sloped across it), a
    mock machine with two nozzles holding the part 20 um high, and a succeeded reconstruct."""
    part = client.post("/api/v1/parts", files={"file": ("wedge.stl", wedge_stl)}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json={
        "name": "across-the-slope", "geometry": {"type": "line", "start": [20.0, 5.0], "end": [20.0, 35.0]},
        "frame": "xy", "standoff_mm": STANDOFF}, headers=OP).json()
    machine = client.post("/api/v1/machines", json={
        "name": "two-nozzles", "port": "mock://", "dialect": "marlin", "profile": {"tools": TOOLS},
        "mock": {"true_part_id": part["id"], "placement": {"dz": 0.02}}}, headers=OP).json()
    plan = _job(client, "probe_plan", {"trace_id": trace["id"], "method": "uniform", "count": 8})
    run = _job(client, "probe_run", {"plan_job_id": plan["id"], "machine_id": machine["id"]})
    assert run["status"] == "succeeded", run["error"]
    recon = _job(client, "reconstruct", {"trace_id": trace["id"], "probe_run_job_id": run["id"],
                                         "method": "interpolate"})
    assert recon["status"] == "succeeded", recon["error"]
    return trace, machine, recon


def _calibrate(client, machine_id: str, tool: int, offset: tuple[float, float, float]) -> str:
    """Store a succeeded calibrate_nozzle job as the calibration job stores it (its
    measurement on the mock is tests/e2e/test_probe_physics_loop.py's)."""
    job = Job(id=f"job_cal{tool}x{abs(hash(offset)) % 10**6}", kind="calibrate_nozzle", status="succeeded",
              params={"machine_id": machine_id, "tool": tool}, queue="machine", machine_id=machine_id,
              result={"tool": tool, "offset_mm": list(offset), "std_mm": [0.001, 0.001, 0.001],
                      "outer_diameter_mm": 0.4, "touches": 7, "agreement": {"previous_job_id": None}},
              created_at=datetime.now(UTC), finished_at=datetime.now(UTC))
    job_id = job.id
    with Session(client.app.state.runtime.engine) as session:
        session.add(job)
        session.commit()
    return job_id


def _compensate(client, trace: dict, machine: dict, recon: dict, **extra) -> dict:
    return _job(client, "compensate", {"trace_id": trace["id"], "reconstruct_job_id": recon["id"],
                                       "machine_id": machine["id"], **extra})


def _program(client, job: dict, name: str) -> str:
    return client.get(f"/api/v1/jobs/{job['id']}/artifacts/{name}", headers=OP).text


def _assert_in_frame(client, job: dict, tool: int, offset: tuple[float, float, float]) -> None:
    """print.gcode selects T<tool> before any move and its printing moves are the result's
    tip points minus ``offset`` (to the program's 4 decimals)."""
    for name in ("print.gcode", "nominal.gcode"):
        text = _program(client, job, name)
        commands = [line.split(";")[0].strip() for line in text.splitlines() if line.split(";")[0].strip()]
        assert commands[:3] == ["G21", "G90", f"T{tool}"] and commands.count(f"T{tool}") == 1, commands[:4]
    program = read_program(_program(client, job, "print.gcode"))
    printed = program.end[program.dispense, :3]
    tips = np.asarray(job["result"]["points"])
    assert np.abs(printed + np.asarray(offset) - tips[1:]).max() <= 6e-5
    nominal = read_program(_program(client, job, "nominal.gcode"))
    assert nominal.end[nominal.dispense, 2].min() == pytest.approx(
        tips[:, 2].min() - offset[2] - 0.02, abs=0.01)  # the nominal is the CAD surface's (20 um lower)


def test_an_uncalibrated_nozzle_is_refused_unless_allowed(client, rebuilt):
    trace, machine, recon = rebuilt
    refused = client.post("/api/v1/jobs", json={"kind": "compensate", "params": {
        "trace_id": trace["id"], "reconstruct_job_id": recon["id"], "machine_id": machine["id"]}}, headers=OP)
    assert refused.status_code == 422, refused.text
    error = refused.json()["errors"][0]
    assert error["loc"] == ["params", "tool"] and "T1" in error["msg"] and "calibrate_nozzle" in error["msg"]
    allowed = _compensate(client, trace, machine, recon, allow_uncalibrated=True)
    assert allowed["status"] == "succeeded", allowed["error"]
    assert allowed["result"]["tool"]["offset_source"] == "nominal" and allowed["result"]["warnings"]
    _assert_in_frame(client, allowed, 1, NOMINAL_T1)
    missing = client.post("/api/v1/jobs", json={"kind": "compensate", "params": {
        "trace_id": trace["id"], "reconstruct_job_id": recon["id"], "machine_id": machine["id"], "tool": 5}},
        headers=OP)
    assert missing.status_code == 422 and missing.json()["errors"][0]["loc"] == ["params", "tool"]


def test_the_program_is_written_from_the_calibrated_offset(client, rebuilt):
    trace, machine, recon = rebuilt
    _calibrate(client, machine["id"], 1, NOMINAL_T1)            # an older calibration ...
    latest = _calibrate(client, machine["id"], 1, CALIBRATED_T1)  # ... and the current one
    done = _compensate(client, trace, machine, recon)
    assert done["status"] == "succeeded", done["error"]
    tool = done["result"]["tool"]
    assert tool["tool"] == 1 and tool["offset_source"] == "calibrated" and tool["calibration_job_id"] == latest
    assert tool["offset_mm"] == list(CALIBRATED_T1)
    _assert_in_frame(client, done, 1, CALIBRATED_T1)
    # the 3-D view draws the nozzle's tip, not the carriage the program moves
    from app.viewer.loaders import load_focus

    [drawn] = [t for t in load_focus(client.app.state.runtime, job_id=done["id"]).toolpaths if t.role == "compensated"]
    printed = drawn.segments.ends[drawn.segments.dispense]
    assert np.abs(printed - np.asarray(done["result"]["points"])[1:]).max() <= 6e-5
    # the tips stand at the standoff above the real (20 um high) plane, whatever the frame
    tips = np.asarray(done["result"]["points"])
    assert np.abs(tips[:, 2] - (_wedge(tips[:, :2]) + 0.02 + STANDOFF)).max() <= 0.002
    # clearance of the 0.4 mm body on the 0.2 slope: standoff - 0.2 * 0.2, analytic
    clearance = done["result"]["clearance"]
    assert clearance["min_mm"] == pytest.approx(STANDOFF - 0.2 * SLOPE, abs=0.002)
    assert 0.0 <= clearance["s_mm"] <= 30.0 and len(clearance["point_mm"]) == 3
    ablation = _compensate(client, trace, machine, recon, corrections={"offsets": False})
    assert ablation["result"]["tool"]["offset_source"] == "nominal"
    _assert_in_frame(client, ablation, 1, NOMINAL_T1)
    probe_frame = _compensate(client, trace, machine, recon, tool=0)
    assert "clearance" not in probe_frame["result"]
    _assert_in_frame(client, probe_frame, 0, (0.0, 0.0, 0.0))


def test_a_nozzle_body_that_would_touch_the_part_is_refused(client, rebuilt):
    trace, machine, recon = rebuilt
    done = _compensate(client, trace, machine, recon, tool=2, allow_uncalibrated=True)
    assert done["status"] == "failed"
    error = done["error"]
    assert error["status"] == 422 and error["errors"][0]["loc"] == ["params", "tool"]
    # 1.5 mm body on the 0.2 slope at 0.1 mm standoff: its edge is 0.75 * 0.2 = 0.15 mm up the
    # slope, so it would sink 0.05 mm into the part
    by = error["errors"][0]["value"]["by_mm"]
    assert by == pytest.approx(0.75 * SLOPE - STANDOFF, abs=0.002)
    detail = error["detail"]
    assert f"trace {trace['name']} ({trace['id']})" in detail and "outer diameter 1.5 mm" in detail
    assert "s = " in detail and f"by {by:.4f} mm" in detail
    assert not any(a["name"] == "print.gcode"
                   for a in client.get(f"/api/v1/jobs/{done['id']}?include=result&include=artifacts", headers=OP)
                   .json().get("artifacts", []))


def test_a_print_on_a_calibrated_machine_is_shifted_by_the_drift_since_calibration(client):
    """10 min of dwell after the probe calibration at 10 um/min of drift: the print's pad touch
    finds the pad ~100 um lower, the program streamed is the artifact with every absolute Z
    shifted by that (what the firmware executed is exactly the shifted program), and what it
    deposits lands where the calibration's frame says — not 100 um off."""
    from hardware.mock import get_world
    from hardware.protocol import commands_sha256, normalized_commands
    from tests.e2e.test_probe_physics_loop import PHYSICS, PROFILE

    rate = 0.01  # mm/min
    machine = client.post("/api/v1/machines", json={
        "name": "drifting", "port": "mock://", "dialect": "marlin", "profile": PROFILE,
        "mock": {"probe_noise_mm": 0.001, "physics": {**PHYSICS, "drift_mm_per_min": rate}}}, headers=OP).json()
    probe = _job(client, "calibrate_probe", {"machine_id": machine["id"]}, timeout=300)
    assert probe["status"] == "succeeded", probe["error"]
    world = get_world(machine["id"])
    calibrated_by = world.stats.machine_time_s  # the calibration's pad reading refers to a time before this
    dwell = client.post("/api/v1/programs", files={"file": ("dwell.gcode", b"G4 S600\n")}, headers=OP).json()
    waited = _job(client, "print", {"machine_id": machine["id"], "program_id": dwell["id"], "drift_reference": False})
    assert waited["status"] == "succeeded" and "drift" not in waited["result"]
    assert round_trips(PrintResult, waited).drift is None
    text = "G21\nG90\nG0 Z20\nG0 X40 Y20\nG1 Z10 F300\nM106\nG1 X45 Z10.5\nM107\nG91\nG0 Z5\nG90\n"
    program = client.post("/api/v1/programs", files={"file": ("p.gcode", text.encode())}, headers=OP).json()
    start, deposits = world.stats.machine_time_s, len(world.deposition_log)
    done = _job(client, "print", {"machine_id": machine["id"], "program_id": program["id"]})
    assert done["status"] == "succeeded", done["error"]
    drift = done["result"]["drift"]
    assert round_trips(PrintResult, done).source_program is not None
    assert drift["probe_job_id"] == probe["id"]
    # the mock drifted rate x t since the calibration's pad reading (taken during the calibration)
    per_s = rate / 60
    assert -per_s * world.stats.machine_time_s - 0.004 <= drift["dz_mm"] <= -per_s * (start - calibrated_by) + 0.004
    assert drift["dz_mm"] < -0.09
    streamed = world.transcript.commands[-len(normalized_commands(text.splitlines())):]
    shifted = [f"G0 Z{20 + drift['dz_mm']:.4f}", "G0 X40 Y20", f"G1 Z{10 + drift['dz_mm']:.4f} F300", "M106",
               f"G1 X45 Z{10.5 + drift['dz_mm']:.4f}", "M107", "G91", "G0 Z5", "G90"]
    assert streamed == ["G21", "G90", *shifted]
    assert done["result"]["program"]["commands_sha256"] == commands_sha256(streamed).sha256
    assert done["result"]["source_program"]["commands_sha256"] == program["commands_sha256"]
    [move] = world.deposition_log[deposits:]
    # where the calibration's frame says (its drift then, at most per_s x calibrated_by); unshifted it
    # would land ~0.1 mm higher
    assert 10.5 - 0.004 <= move.end[2] <= 10.5 + per_s * calibrated_by + 0.004


def test_a_shifted_print_interrupted_mid_program_resumes_the_same_shifted_program(client):
    """The link drops mid-program: the operator's resume does not touch the pad again; it
    streams on from the resume point with the shift recorded before the interruption, so
    the firmware executed the SHIFTED program exactly once around the re-homing."""
    from hardware.mock import get_world
    from hardware.protocol import normalized_commands
    from tests.e2e.test_probe_physics_loop import PHYSICS, PROFILE

    machine = client.post("/api/v1/machines", json={
        "name": "dropping", "port": "mock://", "dialect": "marlin", "profile": PROFILE,
        "mock": {"physics": {**PHYSICS, "drift_mm_per_min": 0.01}}}, headers=OP).json()
    assert _job(client, "calibrate_probe", {"machine_id": machine["id"]}, timeout=300)["status"] == "succeeded"
    text = "G21\nG90\n" + "".join(f"G1 X{40 + (i % 20) * 0.5:.2f} Y{20 + (i // 20) * 0.5:.2f} Z{12 + i * 0.001:.4f} "
                                  f"F3000\n" for i in range(200))
    program = client.post("/api/v1/programs", files={"file": ("p.gcode", text.encode())}, headers=OP).json()
    world = get_world(machine["id"])
    base = world.transcript.executed_count
    world.faults.disconnect_at_line = base + 120  # the pad touch, then about a hundred program lines
    response = client.post("/api/v1/jobs", json={"kind": "print", "params": {
        "machine_id": machine["id"], "program_id": program["id"]}}, headers=OP)
    interrupted = wait_for(client, response.json()["id"], states=("interrupted", "succeeded", "failed"), timeout=120)
    assert interrupted["status"] == "interrupted", interrupted
    recorded = interrupted["program_state"]["drift"]
    assert recorded["dz_mm"] < 0
    touches = world.stats.machine_time_s
    assert client.post(f"/api/v1/jobs/{interrupted['id']}/resume", json={"confirm": True},
                       headers=OP).status_code == 202
    done = wait_for(client, interrupted["id"], timeout=120)
    assert done["status"] == "succeeded", done["error"]
    assert done["result"]["drift"] == recorded and world.stats.machine_time_s > touches
    start, preamble = done["result"]["start_line"], done["result"]["resume_preamble"]
    dz = recorded["dz_mm"]
    shifted = normalized_commands([line.replace(f"Z{z}", f"Z{float(z) + dz:.4f}")
                                   if (z := line.split("Z")[-1].split()[0])
                                   and line.startswith("G1") else line for line in text.splitlines()])
    executed = world.transcript.commands[base:]
    assert executed[-(len(shifted) - start + len(preamble)):] == preamble + shifted[start:]
    before = executed[:-(len(shifted) - start + len(preamble))]
    # the Marlin kept running through the dropped link: the reconnect's safe_off follows what it accepted
    profile = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()["profile"]
    safe = normalized_commands([profile["dispense_off"], *profile.get("outputs_off", [])])
    assert before[-len(safe):] == safe
    before = before[:-len(safe)]
    assert before[-start:] == shifted[:start] and "G38.2" not in " ".join(executed[-(len(shifted) - start):])
