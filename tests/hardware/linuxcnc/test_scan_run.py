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
from tests.hardware.linuxcnc.conftest import add_sim_machine
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


def test_scan_run_on_linuxcnc_measures_the_simulated_block(client, lcnc_env):
    lcnc_env.set_surface(TRUTH)
    lcnc_env.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0005))
    part = client.post("/api/v1/parts", files={"file": ("box.stl", _box_stl())}, headers=OP).json()
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=[
        {"name": f"line-{x:g}", "geometry": {"type": "line", "start": [x, 5.0], "end": [x, 25.0]}, "frame": "xy",
         "standoff_mm": 0.08} for x in TRACE_X], headers=OP).json()["items"]
    machine_id = add_sim_machine(client, lcnc_env, PROFILE, OP)
    calibration = {"offset_mm": list(OFFSET), "scale": 1.0, "time_offset_s": 0.001, "slope_bias_mm": 0.0}
    response = submit(client, "scan_run", {
        "machine_id": machine_id, "trace_ids": [t["id"] for t in traces], "calibration": calibration,
        "mode": "traces", "scan_speed_mm_s": 50.0, "deviation_amplitude_mm": 0.15,
        "deviation_wavelength_mm": 20.0, "verify_count": 2})
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=180)
    assert done["status"] == "succeeded", done["error"]
    result = done["result"]
    assert result["verification"]["within"], result["verification"]  # probe touches on the same block
    for trace in result["traces"]:
        x = TRACE_X[[t["id"] for t in traces].index(trace["trace_id"])]
        assert trace["max_abs_deviation_mm"] == pytest.approx(0.02 + 0.003 * x, abs=0.003)
    artifact = next(a for a in done["artifacts"] if a["name"] == "samples.npz")
    data = np.load(io.BytesIO(client.get(artifact["url"], headers=OP).content))
    valid = data["valid"]
    assert len(valid) == result["samples"] > 500 and valid.mean() > 0.99
    assert np.allclose(np.diff(data["t"][data["pass_index"] == 0]), 0.001)  # one sample per servo period
    x, y, z = data["x"][valid], data["y"][valid], data["z"][valid]
    error = z - np.array([TRUTH.top_z(a, b) for a, b in zip(x, y)])
    assert abs(np.median(error)) < 0.002 and np.percentile(np.abs(error), 95) < 0.006
