"""The scan_run job on a linuxcnc:// machine: the same job as on the mock, the sensor sampled
by the controller with its joints (sim/sensor.hal), against the simulated block's truth.

The nominal part is a 40 x 30 x 2 mm box; the simulator's block (the as-made part, probed
and scanned alike) is 20 um higher and tilted by 3 um/mm along x, so the deviation under a
trace at x is 0.02 + 0.003 x mm.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from hardware.linuxcnc import SimBlock, SimSensor
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import add_sim_machine, wait_until
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
OFFSET = (30.0, 5.0, -10.0)
TRUTH = SimBlock(40.0, 30.0, 2.02, 0.003)
TRACE_X = (10.0, 25.0)
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "probe_command": "G38.2",
           "travel_feed_mm_min": 6000.0, "probe_feed_mm_min": 300.0, "clearance_z": 2.0}


def _box_stl() -> bytes:
    box = trimesh.creation.box(extents=(40.0, 30.0, 2.0))
    box.apply_translation((20.0, 15.0, 1.0))
    return box.export(file_type="stl")


CALIBRATION = {"offset_mm": list(OFFSET), "scale": 1.0, "time_offset_s": 0.0, "slope_bias_mm": 0.0}


def _box_on_the_simulator(client, sim) -> tuple[dict, list[dict], str]:
    """(part, traces, machine id): the block under the simulated sensor, its two traces, and
    the simulator added as a machine."""
    sim.set_surface(TRUTH)
    sim.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0005))
    part = client.post("/api/v1/parts", files={"file": ("box.stl", _box_stl())}, headers=OP).json()
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=[
        {"name": f"line-{x:g}", "geometry": {"type": "line", "start": [x, 5.0], "end": [x, 25.0]}, "frame": "xy",
         "standoff_mm": 0.08} for x in TRACE_X], headers=OP).json()["items"]
    return part, traces, add_sim_machine(client, sim, PROFILE, OP)


def _submit_scan(client, sim, speed_mm_s: float, verify_count: int) -> tuple[str, str, list[str]]:
    """(job id, machine id, trace ids) of a scan_run of the two traces on the box."""
    _, traces, machine_id = _box_on_the_simulator(client, sim)
    calibration = CALIBRATION
    response = submit(client, "scan_run", {
        "machine_id": machine_id, "trace_ids": [t["id"] for t in traces], "calibration": calibration,
        "mode": "traces", "scan_speed_mm_s": speed_mm_s, "deviation_amplitude_mm": 0.15,
        "deviation_wavelength_mm": 20.0, "verify_count": verify_count})
    assert response.status_code == 202, response.text
    return response.json()["id"], machine_id, [t["id"] for t in traces]


def _check_against_truth(client, done: dict, trace_ids: list[str]) -> dict:
    """The job's fitted deviations and sampled surface against the block; returns the samples."""
    result = done["result"]
    for trace in result["traces"]:
        x = TRACE_X[trace_ids.index(trace["trace_id"])]
        assert trace["max_abs_deviation_mm"] == pytest.approx(0.02 + 0.003 * x, abs=0.003)
    artifact = next(a for a in done["artifacts"] if a["name"] == "samples.npz")
    data = dict(np.load(io.BytesIO(client.get(artifact["url"], headers=OP).content)))
    valid = data["valid"]
    assert len(valid) == result["samples"] > 100 and valid.mean() > 0.99
    x, y, z = data["x"][valid], data["y"][valid], data["z"][valid]
    error = z - np.array([TRUTH.top_z(a, b) for a, b in zip(x, y)])
    assert abs(np.median(error)) < 0.002 and np.percentile(np.abs(error), 95) < 0.006
    return data


def test_scan_run_on_linuxcnc_measures_the_simulated_block(client, lcnc_env):
    job_id, _, trace_ids = _submit_scan(client, lcnc_env, 50.0, 2)
    done = wait_for(client, job_id, timeout=180)
    assert done["status"] == "succeeded", done["error"]
    result = done["result"]
    assert result["verification"]["within"], result["verification"]  # probe touches on the same block
    data = _check_against_truth(client, done, trace_ids)
    steps = np.diff(data["t"][data["pass_index"] == 0]) / 0.001  # exposures at servo periods, most in each
    assert np.allclose(steps, np.round(steps)) and np.round(steps).min() >= 1 and np.median(np.round(steps)) == 1


def test_a_scan_run_whose_link_drops_waits_and_resumes_at_the_interrupted_pass(client, lcnc_env):
    """The linuxcncrsh session is cut while the second pass runs: the job becomes
    ``interrupted`` with one pass done; the operator's resume re-homes, keeps the first
    pass's samples, scans the second again and ends as an uninterrupted run would."""
    job_id, machine_id, trace_ids = _submit_scan(client, lcnc_env, 10.0, 1)
    machine = client.app.state.runtime.machines.get(machine_id)

    def second_pass_running() -> bool:
        state = client.get(f"/api/v1/jobs/{job_id}", headers=OP).json().get("program_state") or {}
        return state.get("executed") == 1 and machine.state == "printing"

    assert wait_until(second_pass_running, 60.0)
    machine.link.sever()
    assert wait_until(lambda: client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()["status"] != "running", 60.0)
    job = client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()
    assert job["status"] == "interrupted", job["error"]
    assert job["program_state"]["executed"] == 1 and job["program_state"]["reason"].startswith("LinkError")
    assert [a["name"] for a in job["artifacts"]] == ["pass.00000.npz"]  # the interrupted pass left nothing
    assert client.post(f"/api/v1/jobs/{job_id}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, job_id, timeout=180)
    assert done["status"] == "succeeded", done["error"]
    assert done["result"]["resumes"] == 1 and done["result"]["passes"] == 2
    data = _check_against_truth(client, done, trace_ids)
    assert sorted(set(data["pass_index"].tolist())) == [0, 1]


def test_a_closed_loop_measuring_by_scan_on_linuxcnc_needs_no_sensor_port(client, lcnc_env):
    """``closed_loop`` with ``measuring: scan`` on the simulator, without ``scan.sensor_port``
    (the controller samples the sensor): its scan_run child measures the block and the loop
    compensates every trace from that field."""
    part, traces, machine_id = _box_on_the_simulator(client, lcnc_env)
    calibration = CALIBRATION
    response = submit(client, "closed_loop", {
        "part_id": part["id"], "trace_ids": [t["id"] for t in traces], "machine_id": machine_id,
        "measuring": "scan", "scan": {"calibration": calibration, "mode": "traces", "scan_speed_mm_s": 50.0,
                                      "deviation_amplitude_mm": 0.15, "deviation_wavelength_mm": 20.0,
                                      "verify_count": 2}})
    assert response.status_code == 202, response.text
    loop = wait_for(client, response.json()["id"], timeout=300)
    assert loop["status"] == "succeeded", (loop["error"], (loop["result"] or {}).get("verdict"))
    rows = loop["result"]["traces"]
    scan = wait_for(client, rows[0]["scan_run"], timeout=5)
    assert scan["status"] == "succeeded" and scan["params"].get("sensor_port") is None
    for trace in scan["result"]["traces"]:
        x = TRACE_X[[t["id"] for t in traces].index(trace["trace_id"])]
        assert trace["max_abs_deviation_mm"] == pytest.approx(0.02 + 0.003 * x, abs=0.003)
