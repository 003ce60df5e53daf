"""calibrate_probe / calibrate_nozzle through the API on a mock machine with probe physics:
the recovered ball radius, pre-travel and nozzle offset against the mock's truth, the
repeatability of a calibration, a re-check that disagrees, the machine left retracted at T0."""

from __future__ import annotations

import numpy as np

from hardware.mock import MockTool, get_world
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
# the mock's truth (hidden from the machine) ...
BALL_MM, PRETRAVEL_MM = 0.5, 0.015
TOOL1_MM = (12.3, -4.1, -8.7)
SPHERE_MM, SPHERE_D_MM = (60.3, 40.2, 10.25), 10.0
PAD_MM = (20.2, 40.3, 4.8)
# ... and what the machine's profile knows (nominal places ~0.3 mm off)
PROFILE = {
    "tools": {"probe": {"ball_radius_mm": 0.5},
              "nozzles": [{"tool": 1, "name": "silver", "outer_diameter_mm": 0.8, "offset_mm": [12.0, -4.0, -8.5]}]},
    "reference": {"pad": {"centre_mm": [20.0, 40.0, 5.0], "size_mm": 20.0},
                  "sphere": {"centre_mm": [60.0, 40.0, 10.0], "diameter_mm": SPHERE_D_MM}},
}
PHYSICS = (f"stylus_radius_mm={BALL_MM}&pretravel_mm={PRETRAVEL_MM}&pretravel_sd_mm=0.002"
           f"&tool1={','.join(map(str, TOOL1_MM))},0.8&pad={','.join(map(str, PAD_MM))},20"
           f"&sphere={','.join(map(str, SPHERE_MM))},{SPHERE_D_MM}")


def physics_machine(client, profile: dict | None = None, physics: str = PHYSICS, seed: int = 0) -> dict:
    """A registered mock machine with probe physics and 1 um probe noise."""
    body = {"name": "calib", "port": f"mock://?{physics}", "dialect": "marlin",
            "profile": PROFILE if profile is None else profile,
            "mock": {"probe_noise_mm": 0.001, "faults": {"seed": seed}}}
    response = client.post("/api/v1/machines", json=body, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()


def calibrate(client, kind: str, params: dict) -> dict:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=180)
    assert job["status"] == "succeeded", job["error"]
    return job


def calibration(client, machine: dict) -> dict:
    response = client.get(f"/api/v1/machines/{machine['id']}/calibration", headers=auth("viewer"))
    assert response.status_code == 200, response.text
    return response.json()


def test_calibration_recovers_the_truth_repeats_and_flags_what_changed(client):
    machine = physics_machine(client)
    mid = machine["id"]
    probe1 = calibrate(client, "calibrate_probe", {"machine_id": mid})["result"]
    assert abs(probe1["ball_radius_mm"] - BALL_MM) <= 0.003, probe1["ball_radius_mm"]
    assert abs(probe1["pretravel"]["p0_mm"] - PRETRAVEL_MM) <= 0.003, probe1["pretravel"]
    assert np.allclose(probe1["sphere_centre_mm"], SPHERE_MM, atol=0.005)  # the ball-centre frame = machine's
    assert probe1["agreement"] == {"previous_job_id": None, "differences_mm": {}, "disagrees": []}
    world = get_world(mid)
    assert world.active_tool == 0 and world.stats.collisions == 0

    nozzle1_job = calibrate(client, "calibrate_nozzle", {"machine_id": mid, "tool": 1})
    nozzle1 = nozzle1_job["result"]
    assert np.allclose(nozzle1["offset_mm"], TOOL1_MM, atol=0.005), nozzle1["offset_mm"]
    assert np.allclose(nozzle1["nominal_difference_mm"], np.subtract(nozzle1["offset_mm"], [12.0, -4.0, -8.5]))
    # left retracted with the probe selected
    assert world.active_tool == 0 and world.stats.collisions == 0
    assert world.position[2] >= PROFILE["reference"]["sphere"]["centre_mm"][2] + SPHERE_D_MM / 2 + 2

    # the procedure's own 1-sigma (from the touches' scatter and number): small enough that two runs differing
    # by 2 um is a > 5-sigma event (tests/bench/test_bench_calibration_repeat.py: 20 runs, the noise model)
    assert probe1["std"]["ball_radius_mm"] <= 0.00025 and probe1["std"]["p0_mm"] <= 0.0003, probe1["std"]
    assert probe1["std"]["p0_minus_radius_mm"] <= 0.0002, probe1["std"]
    assert max(nozzle1["std_mm"]) <= 0.0003, nozzle1["std_mm"]
    assert np.abs(np.subtract(nozzle1["offset_mm"], TOOL1_MM)).max() <= 0.001, nozzle1["offset_mm"]

    # repeatability: a second run agrees with the first within 1 um (the Show line: 2 um)
    probe2_job = calibrate(client, "calibrate_probe", {"machine_id": mid})
    probe2 = probe2_job["result"]
    assert abs(probe2["ball_radius_mm"] - probe1["ball_radius_mm"]) <= 0.001
    assert abs(probe2["pretravel"]["p0_mm"] - probe1["pretravel"]["p0_mm"]) <= 0.001
    assert probe2["agreement"]["previous_job_id"] and probe2["agreement"]["disagrees"] == []
    # the nozzle was calibrated against the first probe calibration: flagged until re-done
    flags = calibration(client, machine)["flags"]
    assert any("T1 was calibrated against probe calibration" in f for f in flags), flags
    nozzle2 = calibrate(client, "calibrate_nozzle", {"machine_id": mid, "tool": 1})["result"]
    assert np.abs(np.subtract(nozzle2["offset_mm"], nozzle1["offset_mm"])).max() <= 0.001
    assert nozzle2["agreement"]["disagrees"] == [] and nozzle2["probe_job_id"] == probe2_job["id"]
    summary = calibration(client, machine)
    assert summary["flags"] == [], summary["flags"]
    assert summary["probe"]["job_id"] == probe2_job["id"] and not summary["probe"]["stale"]
    assert summary["nozzles"][0]["calibrated"] and summary["nozzles"][0]["offset_std_um"][0] > 0

    # a needle change moved the tip by 20 um in x: the re-check disagrees and says so
    world.tools = (MockTool((TOOL1_MM[0] + 0.02, TOOL1_MM[1], TOOL1_MM[2]), 0.8),)
    nozzle3 = calibrate(client, "calibrate_nozzle", {"machine_id": mid, "tool": 1})["result"]
    assert abs(nozzle3["offset_mm"][0] - (TOOL1_MM[0] + 0.02)) <= 0.005
    assert nozzle3["agreement"]["disagrees"] == ["offset_x_mm"], nozzle3["agreement"]
    assert abs(nozzle3["agreement"]["differences_mm"]["offset_x_mm"] - 0.02) <= 0.004
    flags = calibration(client, machine)["flags"]
    assert any("re-check disagrees" in f and "offset_x_mm" in f for f in flags), flags
    assert world.active_tool == 0 and world.stats.collisions == 0


def test_a_failed_nozzle_touch_fails_the_job_and_leaves_the_machine_retracted_at_t0(client):
    machine = physics_machine(client)
    calibrate(client, "calibrate_probe", {"machine_id": machine["id"], "per_ring": 4, "equator": 8})
    world = get_world(machine["id"])
    world.tools = (MockTool((TOOL1_MM[0], TOOL1_MM[1], TOOL1_MM[2] + 3.0), 0.8),)  # 3 mm shorter than nominal
    response = client.post("/api/v1/jobs", json={"kind": "calibrate_nozzle",
                                                 "params": {"machine_id": machine["id"], "tool": 1}}, headers=OP)
    job = wait_for(client, response.json()["id"], timeout=120)
    assert job["status"] == "failed" and job["error"]["status"] == 422, job
    assert "touched nothing" in job["error"]["detail"] or "no surface" in job["error"]["detail"], job["error"]
    sphere_top = PROFILE["reference"]["sphere"]["centre_mm"][2] + SPHERE_D_MM / 2
    assert world.active_tool == 0 and world.position[2] >= sphere_top + 2 and world.stats.collisions == 0


def test_a_dropped_link_interrupts_the_calibration_and_the_operator_resumes_it(client):
    machine = physics_machine(client, seed=3)
    body = {"name": "flaky", "port": f"mock://?{PHYSICS}", "profile": PROFILE,
            "mock": {"probe_noise_mm": 0.001, "faults": {"disconnect_at_line": 120}}}
    flaky = client.post("/api/v1/machines", json=body, headers=OP).json()
    params = {"per_ring": 4, "equator": 8, "pad_touches": 3}
    run = client.post("/api/v1/jobs", json={"kind": "calibrate_probe", "params": {"machine_id": flaky["id"], **params}},
                      headers=OP).json()
    interrupted = wait_for(client, run["id"], states=("interrupted", "succeeded", "failed"), timeout=120)
    assert interrupted["status"] == "interrupted", interrupted
    state = interrupted["program_state"]
    assert 0 < state["executed"] < 13 and len(state["stages"]["locate"]) == state["executed"]
    assert client.post(f"/api/v1/jobs/{run['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
    resumed = wait_for(client, run["id"], timeout=120)
    assert resumed["status"] == "succeeded", resumed["error"]
    reference = calibrate(client, "calibrate_probe", {"machine_id": machine["id"], **params})["result"]
    assert len(resumed["result"]["readings"]) == len(reference["readings"]) == resumed["result"]["touches"]
    assert abs(resumed["result"]["ball_radius_mm"] - BALL_MM) <= 0.005
    assert get_world(flaky["id"]).active_tool == 0


def test_a_slow_z_drift_during_the_calibration_does_not_bias_it(client):
    """1 um/min of Z drift over a qualification of minutes (machine time): fitted out."""
    machine = physics_machine(client, physics=f"{PHYSICS}&drift_mm_per_min=0.001")
    client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP)
    clock = get_world(machine["id"]).stats.machine_time_s
    # a lighter procedure than the default (the drift, not the repeatability, is the point here)
    probe = calibrate(client, "calibrate_probe", {"machine_id": machine["id"], "per_ring": 24, "equator": 48})["result"]
    elapsed = get_world(machine["id"]).stats.machine_time_s - clock
    last = probe["readings"][-1]["t_s"]  # the touches' estimated machine times follow the mock's clock
    assert last > 150 and last <= elapsed <= last + 30, (last, elapsed)  # minutes: several um of drift
    assert abs(probe["ball_radius_mm"] - BALL_MM) <= 0.003 and abs(probe["pretravel"]["p0_mm"] - PRETRAVEL_MM) <= 0.003
    assert abs(probe["drift_mm_per_min"] - 0.001) <= 0.0003, probe["drift_mm_per_min"]
    nozzle = calibrate(client, "calibrate_nozzle", {"machine_id": machine["id"], "tool": 1, "pad_touches": 24,
                                                    "side_touches": 2})["result"]
    assert np.allclose(nozzle["offset_mm"], TOOL1_MM, atol=0.005), nozzle["offset_mm"]
