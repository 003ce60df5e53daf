"""jetting_run through the API on the mock machine: each drop fired once, the measured maps
against the mock's truth, an interrupted run resumed by the operator, a pause held."""

from __future__ import annotations

import io
import threading
import time

import numpy as np
import pytest

from app.jetting import DropParams, JettingParams, PlantParams, TargetSpec, simulate, surface_metrics
from hardware.height_sensor.mock import sensor_from_url
from hardware.mock import get_world
from tests.helpers.jetting_rig import OP, jetting_rig
from tests.helpers.jobs import submit, wait_for

SMALL = {"target": {"size_mm": 1.5, "hole_mm": 0.5}, "layers": 4}


def measured(client, job, layer):
    artifact = next(a for a in job["artifacts"] if a["name"] == f"measured_{layer:04d}.npz")
    return np.load(io.BytesIO(client.get(artifact["url"], headers=OP).content))


def test_a_run_jets_each_drop_once_and_measures_what_the_mock_holds(client):
    rig = jetting_rig(client, "nozzles=16&spread=0.05&seed=3")  # a 16-nozzle head: two swaths per layer
    try:
        response = submit(client, "jetting_run", rig.params(**SMALL))
        assert response.status_code == 202, response.text
        done = wait_for(client, response.json()["id"], timeout=120)
        assert done["status"] == "succeeded", done["error"]
        head = rig.head
    finally:
        rig.close()
    result = done["result"]
    layers = result["layers"]
    assert [r["layer"] for r in layers] == [1, 2, 3, 4]
    assert all(r["fired"] == r["drops"] > 0 for r in layers)
    assert head.field.drops == sum(r["drops"] for r in layers) and head.cures == 4
    assert all(r["valid_fraction"] > 0.99 and r["filled_cells"] == 0 for r in layers)
    shape, pitch = tuple(result["grid"]["shape"]), result["grid"]["pitch_mm"]
    assert shape[1] > 16
    for layer in (1, 4):
        data = measured(client, done, layer)
        truth = rig.truth(shape, pitch, layer)
        error = data["filled"] - truth
        assert np.abs(error).mean() < 0.3e-3 and np.abs(error).max() < 1.5e-3  # 0.2 um per cell
        assert data["pattern"].any() and data["mask"].shape == shape
    report = client.get(f"/api/v1/jobs/{done['id']}/report", headers=OP)
    assert report.status_code == 200 and "Droplet layers" in report.text
    sha = next(a["sha256"] for a in done["artifacts"] if a["name"] == "measured_0004.npz")
    assert sha[:16] in report.text
    # the same loop in simulation with the same head (16 nozzles, 5 % spread, its seed): the
    # machine's true part matches the simulated one
    sim = simulate(JettingParams(layers=4, target=TargetSpec(size_mm=1.5, hole_mm=0.5),
                                 plant=PlantParams(nozzle_spread=0.05, n_nozzles=16, seed=3)))
    assert sim.target.shape == shape
    true = surface_metrics(rig.truth(shape, pitch), sim.target, 4 * 0.8 * DropParams().layer_mm)
    assert true.mean_height_um == pytest.approx(sim.final.metrics.mean_height_um, rel=0.03)
    assert true.sa_um == pytest.approx(sim.final.metrics.sa_um, rel=0.3)


def test_a_lost_sensor_interrupts_the_run_and_the_operators_resume_finishes_it(client):
    rig = jetting_rig(client, "seed=5")
    world = get_world(rig.machine_id)
    cures = []

    def unplug_after_second_cure(key, value, _t):
        if key == "P6" and value == 0:
            cures.append(1)
            if len(cures) == 2:
                sensor_from_url(rig.sensor_url).unplugged = True

    world.output_listeners.append(unplug_after_second_cure)
    try:
        job = submit(client, "jetting_run", rig.params(**SMALL)).json()
        stopped = wait_for(client, job["id"], states=("interrupted", "failed", "succeeded"), timeout=120)
        assert stopped["status"] == "interrupted", stopped
        state = stopped["program_state"]
        assert state["printed"] == 2 and state["executed"] == 1 and state["phase"] == "scan"
        drops_before = rig.head.field.drops
        time.sleep(0.3)
        assert rig.head.field.drops == drops_before  # nothing dispenses while it waits
        world.output_listeners.remove(unplug_after_second_cure)
        sensor_from_url(rig.sensor_url).unplugged = False
        assert client.post(f"/api/v1/jobs/{job['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
        done = wait_for(client, job["id"], timeout=120)
        head = rig.head
    finally:
        rig.close()
    assert done["status"] == "succeeded", done["error"]
    layers = done["result"]["layers"]
    assert [r["layer"] for r in layers] == [1, 2, 3, 4] and done["result"]["resumes"] == 1
    assert head.field.drops == sum(r["drops"] for r in layers)  # layer 2 printed once, not again


def test_an_operators_pause_holds_the_run_and_each_drop_still_fires_once(client):
    rig = jetting_rig(client, "seed=2")
    paused = threading.Event()
    try:
        job = submit(client, "jetting_run", rig.params(**SMALL)).json()
        deadline = time.monotonic() + 60
        while not paused.is_set() and time.monotonic() < deadline:
            if client.post(f"/api/v1/machines/{rig.machine_id}/pause", headers=OP).status_code == 200:
                paused.set()
        assert paused.is_set()
        drops = rig.head.field.drops
        time.sleep(0.5)
        record = client.get(f"/api/v1/jobs/{job['id']}", headers=OP).json()
        machine = client.get(f"/api/v1/machines/{rig.machine_id}", headers=OP).json()
        assert record["status"] == "running" and machine["state"] == "paused"
        assert rig.head.field.drops == drops
        assert client.post(f"/api/v1/machines/{rig.machine_id}/resume", headers=OP).status_code == 200
        done = wait_for(client, job["id"], timeout=120)
        head = rig.head
    finally:
        rig.close()
    assert done["status"] == "succeeded", done["error"]
    assert head.field.drops == sum(r["drops"] for r in done["result"]["layers"])
