"""scan_run through the API: the mock LK-G on a mock machine holding an as-made S1 part."""

from __future__ import annotations

import io

import numpy as np
import pytest

from app.reference.s1 import as_made, s1_mesh, s1_traces
from hardware.height_sensor.mock import unregister_sensor
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
OFFSET = (30.05, 4.93, -10.08)
TAU_S = 0.0021
#: the mock sensor's true calibration (what the scans are given)
CALIBRATION = {"offset_mm": list(OFFSET), "scale": 1.0, "time_offset_s": TAU_S, "slope_bias_mm": 0.0}


def sensor_port(machine_id: str) -> str:
    """The mock LK-G on ``machine_id``'s world: the offset and time offset above, 0.5 um noise."""
    return (f"lkg://{machine_id}?offset={','.join(map(str, OFFSET))}&time_offset_ms={TAU_S * 1000}"
            "&noise_mm=0.0005&rate_hz=2000&seed=4")


def _part_traces_and_truth(client, meshes, indices: tuple[int, ...]) -> tuple[list[dict], dict]:
    """(traces, as-made part record): the reference part's traces ``indices`` on the nominal
    part, and the as-made part a mock machine holds as its truth."""
    nominal, true_stl, _ = meshes
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", nominal.export(file_type="stl"))},
                       headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", true_stl)}, headers=OP).json()
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import",
                         json=[s1_traces()[i].to_api() for i in indices], headers=OP).json()["items"]
    return traces, real


def _submit_scan(client, machine_id: str, traces: list[dict], mode: str = "traces"):
    """Submit a scan_run of ``traces`` with the mock sensor on ``machine_id`` and its true
    calibration; the response."""
    return submit(client, "scan_run", {
        "machine_id": machine_id, "trace_ids": [t["id"] for t in traces], "sensor_port": sensor_port(machine_id),
        "calibration": dict(CALIBRATION), "mode": mode, "deviation_amplitude_mm": 0.15,
        "deviation_wavelength_mm": 15.0, "verify_count": 3})


@pytest.fixture(scope="module")
def meshes():
    truth = as_made(seed=11, amplitude_mm=0.15)
    return s1_mesh(grid_mm=0.6), truth.mesh(grid_mm=0.6).export(file_type="stl"), truth


@pytest.mark.parametrize("mode", ["traces", "raster"])
def test_a_scan_run_records_samples_and_verifies_its_field(client, meshes, mode):
    truth = meshes[2]
    traces, real = _part_traces_and_truth(client, meshes, (0, 4))
    machine = client.post("/api/v1/machines", json={
        "name": "sim", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "probe_noise_mm": 0.001}}, headers=OP).json()
    try:
        response = _submit_scan(client, machine["id"], traces, mode)
        assert response.status_code == 202, response.text
        done = wait_for(client, response.json()["id"], timeout=120)
    finally:
        unregister_sensor(machine["id"])
    assert done["status"] == "succeeded", done["error"]
    result = done["result"]
    assert result["verification"]["within"], result["verification"]
    assert result["bound_mm"] <= 0.005
    assert result["tiles"][mode.removesuffix("s") if mode == "traces" else "raster"] >= 1
    artifact = next(a for a in done["artifacts"] if a["name"] == "samples.npz")
    data = np.load(io.BytesIO(client.get(artifact["url"], headers=OP).content))
    valid = data["valid"]
    assert valid.mean() > 0.9 and len(valid) == result["samples"]
    xy = np.column_stack([data["x"], data["y"]])[valid]
    on_part = (xy[:, 0] > 1) & (xy[:, 0] < 59) & (xy[:, 1] > 1) & (xy[:, 1] < 39)
    error = data["z"][valid][on_part] - truth.true_height(xy[on_part])
    assert np.abs(np.median(error)) < 0.002 and np.percentile(np.abs(error), 95) < 0.01  # the 0.6 mm mesh


def test_a_malformed_calibration_is_refused_at_submission(client):
    machine = client.post("/api/v1/machines", json={"name": "sim", "port": "mock://", "dialect": "marlin"},
                          headers=OP).json()
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=1.0).export(file_type="stl"))},
                       headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[0].to_api(), headers=OP).json()
    response = submit(client, "scan_run", {"machine_id": machine["id"], "trace_ids": [trace["id"]],
                                           "sensor_port": "lkg://x", "calibration": {"scale": 1.0}})
    assert response.status_code == 422 and "calibration" in response.text


def test_a_dropped_link_interrupts_the_scan_and_a_resume_keeps_the_stored_passes(client, meshes):
    traces, real = _part_traces_and_truth(client, meshes, (0, 2, 4, 6))
    machine = client.post("/api/v1/machines", json={
        "name": "flaky", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "probe_noise_mm": 0.001, "faults": {"disconnect_at_line": 30}}},
        headers=OP).json()
    try:
        response = _submit_scan(client, machine["id"], traces)
        assert response.status_code == 202, response.text
        job_id = response.json()["id"]
        stopped = wait_for(client, job_id, states=("interrupted", "succeeded", "failed"), timeout=120)
        assert stopped["status"] == "interrupted", (stopped["status"], stopped["error"])
        state = stopped["program_state"]
        assert 0 < state["passes_done"] < state["total"] == 4
        kept = {a["name"]: a["sha256"] for a in stopped["artifacts"] if a["name"].startswith("pass.")}
        assert len(kept) == state["passes_done"]
        assert client.post(f"/api/v1/jobs/{job_id}/resume", json={"confirm": True}, headers=OP).status_code == 202
        done = wait_for(client, job_id, timeout=120)
    finally:
        unregister_sensor(machine["id"])
    assert done["status"] == "succeeded", done["error"]
    result = done["result"]
    assert result["resumes"] == 1 and result["passes"] == 4 and result["verification"]["within"]
    passes = {a["name"]: a["sha256"] for a in done["artifacts"] if a["name"].startswith("pass.")}
    assert len(passes) == 4 and all(passes[name] == sha for name, sha in kept.items())  # not scanned again
    assert result["valid"] > 0.9 * result["samples"] and result["bound_mm"] <= 0.005


def test_with_a_calibrated_ball_stylus_the_touches_are_corrected_as_a_probe_runs_are(client, meshes):
    """A 0.5 mm ball with 15 um pre-travel reads ~0.49 mm high on the part: calibrated
    (calibrate_probe), the scan's gap and verification touches are corrected and agree with
    the sensor's field."""
    traces, real = _part_traces_and_truth(client, meshes, (0, 4))
    physics = "stylus_radius_mm=0.5&pretravel_mm=0.015&pad=150,10,3,20&sphere=110,12,12,10"
    profile = {"tools": {"probe": {"ball_radius_mm": 0.5}},
               "reference": {"pad": {"centre_mm": [150.0, 10.0, 3.0], "size_mm": 20.0},
                             "sphere": {"centre_mm": [110.0, 12.0, 12.0], "diameter_mm": 10.0}}}
    machine = client.post("/api/v1/machines", json={
        "name": "stylus", "port": f"mock://?{physics}", "dialect": "marlin", "profile": profile,
        "mock": {"true_part_id": real["id"], "probe_noise_mm": 0.001}}, headers=OP).json()
    qualified = wait_for(client, submit(client, "calibrate_probe", {"machine_id": machine["id"], "per_ring": 4,
                                                                    "equator": 8}).json()["id"], timeout=180)
    assert qualified["status"] == "succeeded", qualified["error"]
    try:
        response = _submit_scan(client, machine["id"], traces)
        done = wait_for(client, response.json()["id"], timeout=120)
    finally:
        unregister_sensor(machine["id"])
    assert done["status"] == "succeeded", done["error"]
    verification = done["result"]["verification"]
    assert verification["within"] and verification["max_abs_residual_mm"] < 0.005, verification
