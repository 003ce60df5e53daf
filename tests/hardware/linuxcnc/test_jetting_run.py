"""``jetting_run`` through the API on a ``linuxcnc://`` machine: LinuxCNC moves the carriage,
switches the UV lamp (``M64 P3`` / ``M65 P3``) and samples the height sensor with its joints
(no sensor port); the mock head rides on the simulator's joints (its encoder input) over its
own link (:class:`hardware.linuxcnc.sim_head.SimHeadBridge`) and its cured ink is what the
simulated sensor sees on the bed.  Checked against the head's truth (its field after each
cure), independently of the job's own figures."""

from __future__ import annotations

import io

import numpy as np
import pytest

from hardware.linuxcnc import SimBlock, SimSensor
from hardware.linuxcnc.sim_head import SimHeadBridge
from hardware.printhead.mock import unregister_head
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import SURFACE_SLOPE_X, SURFACE_Z, add_sim_machine, wait_until
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
SENSOR_OFFSET = (30.0, 5.0, -10.0)
HEAD_OFFSET = (20.0, -15.0)
ORIGIN = (5.0, 5.0)
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "probe_command": "G38.2",
           "travel_feed_mm_min": 6000.0, "probe_feed_mm_min": 300.0, "clearance_z": 2.0,
           "outputs_off": ["M65 P3"]}
SMALL = {"target": {"size_mm": 1.5, "hole_mm": 0.5}, "layers": 3}


@pytest.fixture
def bench(lcnc_env):
    """The simulator with a level bed at z = 0, its sensor (0.26 um noise) and the head's bridge."""
    lcnc_env.set_surface(SimBlock.plane(0.0, 0.0))
    lcnc_env.set_sensor(SimSensor(offset_mm=SENSOR_OFFSET, noise_mm=0.00026))
    bridge = SimHeadBridge(lcnc_env, "lcncjet")
    yield lcnc_env, bridge
    bridge.close()
    unregister_head("lcncjet")
    lcnc_env.set_surface(SimBlock.plane(SURFACE_Z, SURFACE_SLOPE_X))
    lcnc_env.set_sensor(SimSensor())


def jetting_params(machine_id: str, head_options: str, **kwargs) -> dict:
    head = (f"head://lcncjet?machine=lcncjet&offset={HEAD_OFFSET[0]},{HEAD_OFFSET[1]}&field=0,0,200,200&history=1"
            f"&cure=P3&{head_options}")
    return {"machine_id": machine_id, "head_port": head.rstrip("&"),
            "calibration": {"offset_mm": list(SENSOR_OFFSET), "scale": 1.0, "time_offset_s": 0.0},
            "origin_mm": list(ORIGIN), "head_offset_mm": list(HEAD_OFFSET), "cure_on": "M64 P3",
            "cure_off": "M65 P3", "scan_speed_mm_s": 20.0, **kwargs}


def head_truth(field, shape: tuple[int, int], pitch_mm: float, layer: int) -> np.ndarray:
    """The head's true heights (L, W) mm after ``layer`` cures on the job's grid cells."""
    heights = np.asarray(field.history[layer - 1], dtype=float)
    rows = np.rint((ORIGIN[1] + np.arange(shape[0]) * pitch_mm - field.origin[1]) / field.pitch).astype(int)
    cols = np.rint((ORIGIN[0] + np.arange(shape[1]) * pitch_mm - field.origin[0]) / field.pitch).astype(int)
    return heights[np.ix_(rows, cols)]


def measured(client, job: dict, layer: int) -> dict:
    artifact = next(a for a in job["artifacts"] if a["name"] == f"measured_{layer:04d}.npz")
    return dict(np.load(io.BytesIO(client.get(artifact["url"], headers=OP).content)))


def test_jetting_run_on_linuxcnc_fires_each_drop_once_and_measures_the_heads_truth(client, bench):
    sim, bridge = bench
    machine_id = add_sim_machine(client, sim, PROFILE, OP)
    response = submit(client, "jetting_run", jetting_params(machine_id, "nozzles=16&spread=0.05&seed=3", **SMALL))
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=600)
    assert done["status"] == "succeeded", done["error"]
    head = bridge.head
    layers = done["result"]["layers"]
    assert [r["layer"] for r in layers] == [1, 2, 3]
    assert all(r["fired"] == r["drops"] > 0 for r in layers)             # two swaths a layer, each drop once
    assert head.field.drops == sum(r["drops"] for r in layers) and head.cures == 3  # the lamp's dose each layer
    shape, pitch = tuple(done["result"]["grid"]["shape"]), done["result"]["grid"]["pitch_mm"]
    for layer in (1, 3):
        data = measured(client, done, layer)
        truth = head_truth(head.field, shape, pitch, layer)
        seen = np.isfinite(data["heights"])
        error = data["heights"][seen] - truth[seen]
        print(f"layer {layer}: {seen.mean():.3f} of the cells sampled, measured - truth: mean |e| "
              f"{np.abs(error).mean() * 1e3:.3f} um, max {np.abs(error).max() * 1e3:.2f} um")
        assert seen.mean() > 0.1 and np.abs(error).mean() < 0.5e-3 and np.abs(error).max() < 3e-3
    assert not sim.outputs()["dout"][3]                                  # the lamp is off


def test_a_jetting_run_whose_link_drops_waits_and_the_operators_resume_finishes_it(client, bench):
    """The linuxcncrsh session is cut during the second layer: the job is ``interrupted``, the
    lamp off; the operator's resume re-homes, cures, scans and finishes without printing a
    layer twice (every layer's drops fired once in all)."""
    sim, bridge = bench
    machine_id = add_sim_machine(client, sim, PROFILE, OP)
    job_id = submit(client, "jetting_run", jetting_params(machine_id, "seed=5", **SMALL)).json()["id"]
    machine = client.app.state.runtime.machines.get(machine_id)

    def second_layer_printing() -> bool:
        state = client.get(f"/api/v1/jobs/{job_id}", headers=OP).json().get("program_state") or {}
        return state.get("printed") == 2 and state.get("phase") == "print"

    assert wait_until(second_layer_printing, 300.0)
    machine.link.sever()
    assert wait_until(lambda: client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()["status"] != "running", 60.0)
    job = client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()
    assert job["status"] == "interrupted", job["error"]
    assert job["program_state"]["reason"].startswith("LinkError")
    assert not sim.outputs()["dout"][3]
    assert client.post(f"/api/v1/jobs/{job_id}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, job_id, timeout=600)
    assert done["status"] == "succeeded", done["error"]
    layers = done["result"]["layers"]
    assert [r["layer"] for r in layers] == [1, 2, 3] and done["result"]["resumes"] == 1
    printed = [r["drops"] for r in layers]
    assert bridge.head.field.drops <= sum(printed)  # nothing printed twice (the cut layer: at most its drops)
