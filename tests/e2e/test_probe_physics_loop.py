"""Probe physics end to end, through the API: a mock machine with real probe physics — a 0.5 mm
stylus ball, 15 um +- 2 um pre-travel, Z drift of 1 um/min, 1 um probe noise, a nozzle T1
whose true offset (12.3, -4.1, -8.7) mm the machine knows only as (12, -4, -8.5), a
reference pad and datum sphere ~0.3 mm off their nominal places — is calibrated
(calibrate_probe, calibrate_nozzle) and then runs the closed loop with evaluation on S1's
as-made part (the same loop on a held-out as-made part, another seed and amplitude never
used while tuning, is tests/bench/test_bench_probe_physics_loop.py: the same path and the
same assertions on other numbers): every compensated trace, printed by the nozzle and measured on the mock's
deposition log at the nozzle's TRUE tip, holds its standoff within 10 um max and its
top-view path within 10 um of the design.  The uncompensated (nominal) programs printed
by the same nozzle miss by far more.  On the same machine a wide nozzle (2 mm body) is
refused on the sloped S1 top with the trace, the place and the depth named.
"""

from __future__ import annotations

import numpy as np
import pytest

from app.reference.s1 import as_made, centred_placement, s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
TRACES = (0, 3, 6)  # one line, one R40 arc, one NURBS
TRUE_T1 = (12.3, -4.1, -8.7)
NOMINAL_T1 = (12.0, -4.0, -8.5)
T1_DIAMETER_MM = 0.3
PAD_TRUE, PAD_NOMINAL = (85.0, 10.0, 3.0), (85.25, 9.8, 3.2)
SPHERE_TRUE, SPHERE_NOMINAL = (85.0, 30.0, 8.0), (84.8, 30.25, 8.2)
SPHERE_D = 8.0
PHYSICS = {"stylus_radius_mm": 0.5, "pretravel_mm": 0.015, "pretravel_sd_mm": 0.002, "drift_mm_per_min": 0.001,
           "tools": [{"offset_mm": list(TRUE_T1), "outer_diameter_mm": T1_DIAMETER_MM},
                     {"offset_mm": [-10.0, 5.0, -9.0], "outer_diameter_mm": 2.0}],
           "pad": {"centre_mm": list(PAD_TRUE), "size_mm": 10.0},
           "sphere": {"centre_mm": list(SPHERE_TRUE), "diameter_mm": SPHERE_D}}
PROFILE = {"clearance_z": 25.0,
           "tools": {"probe": {"ball_radius_mm": 0.5},
                     "nozzles": [{"tool": 1, "name": "fine", "outer_diameter_mm": T1_DIAMETER_MM,
                                  "offset_mm": list(NOMINAL_T1)},
                                 {"tool": 2, "name": "wide", "outer_diameter_mm": 2.0,
                                  "offset_mm": [-10.0, 5.0, -9.0]}]},
           "reference": {"pad": {"centre_mm": list(PAD_NOMINAL), "size_mm": 10.0},
                         "sphere": {"centre_mm": list(SPHERE_NOMINAL), "diameter_mm": SPHERE_D}}}


def true_part_stl(seed: int, amplitude_mm: float) -> bytes:
    """An as-made S1 in its own frame (the mock places it)."""
    return as_made(seed=seed, amplitude_mm=amplitude_mm, placement=centred_placement()).mesh(grid_mm=0.3).export(
        file_type="stl")


def job(client, kind: str, params: dict, timeout: float = 300) -> dict:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=timeout)
    assert done["status"] == "succeeded", (kind, done["error"])
    return done


def calibrated_machine(client, true_stl: bytes, name: str, seed: int, physics: dict | None = None,
                       placement: dict | None = None, profile: dict | None = None) -> tuple[dict, dict, dict]:
    """A physics mock holding ``true_stl`` (+20 um in z), calibrated with the default procedure:
    (machine, probe job, nozzle job)."""
    real = client.post("/api/v1/parts", files={"file": (f"{name}.stl", true_stl)}, headers=OP).json()
    machine = client.post("/api/v1/machines", json={
        "name": name, "port": "mock://", "dialect": "marlin", "profile": {**PROFILE, **(profile or {})},
        "mock": {"true_part_id": real["id"], "placement": placement or {"dz": 0.02}, "probe_noise_mm": 0.001,
                 "faults": {"seed": seed}, "physics": physics or PHYSICS}}, headers=OP)
    assert machine.status_code == 201, machine.text
    machine = machine.json()
    probe = job(client, "calibrate_probe", {"machine_id": machine["id"]})
    nozzle = job(client, "calibrate_nozzle", {"machine_id": machine["id"], "tool": 1})
    return machine, probe, nozzle


def nominal_part(client) -> tuple[dict, list[dict]]:
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=0.3).export(file_type="stl"))},
                       headers=OP).json()
    refs = [s1_traces()[i] for i in TRACES]
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=[t.to_api() for t in refs],
                         headers=OP).json()["items"]
    return part, traces


def closed_loop(client, part: dict, traces: list[dict], machine: dict, **extra) -> dict:
    return job(client, "closed_loop", {
        "part_id": part["id"], "trace_ids": [t["id"] for t in traces], "machine_id": machine["id"],
        "probe": {"method": "deviation"}, "sigma_mm": 0.001, "evaluate": True, **extra}, timeout=900)


def _children(client, loop: dict) -> list[dict]:
    return client.get(f"/api/v1/jobs?parent_id={loop['id']}&limit=100", headers=OP).json()["items"]


def calibrated_loop_holds_standoff_and_path(client, true_stl: bytes, name: str, seed: int):  # type: ignore[no-untyped-def]
    """Calibrate a physics mock holding ``true_stl``, run the evaluated closed loop on S1's
    traces and assert what it must hold: the hidden truth recovered by the calibration, every
    compensated trace within 10 um of its standoff and path, the nominal programs >= 30 um
    off, each print's drift shift read from the pad, every probe run on that calibration.
    Returns (traces, children of the loop)."""
    part, traces = nominal_part(client)
    machine, probe, nozzle = calibrated_machine(client, true_stl, name, seed=seed)
    # the calibration found the mock's hidden truth
    assert probe["result"]["ball_radius_mm"] == pytest.approx(0.5, abs=0.003)
    assert probe["result"]["pretravel"]["p0_mm"] == pytest.approx(0.015, abs=0.003)
    assert np.abs(np.asarray(nozzle["result"]["offset_mm"]) - TRUE_T1).max() <= 0.005
    loop = closed_loop(client, part, traces, machine)
    table = loop["result"]["table"]
    assert len(table) == len(TRACES)
    print("\n" + "\n".join(f"{r['name']}: standoff max {r['standoff_max_after_um']} um (nominal "
                            f"{r['standoff_max_before_um']}), xy max {r['xy_max_after_um']} um" for r in table))
    for row in table:
        assert row["standoff_max_after_um"] <= 10.0, row
        assert row["xy_max_after_um"] <= 10.0, row
        # the nominal program at the calibrated offset misses by the part's machining error
        assert row["standoff_max_before_um"] >= 30.0, row
    children = _children(client, loop)
    for comp in (j for j in children if j["kind"] == "compensate"):
        tool = comp["result"]["tool"]
        assert (tool["tool"] == 1 and tool["offset_source"] == "calibrated"
                and tool["calibration_job_id"] == nozzle["id"])
        assert comp["result"]["clearance"]["min_mm"] > 0.0
    prints = [j for j in children if j["kind"] == "print"]
    assert len(prints) == 2 * len(TRACES)
    for run in prints:  # each print touched the pad and shifted its Z by the drift since calibration
        drift = run["result"]["drift"]
        assert drift["probe_job_id"] == probe["id"] and abs(drift["dz_mm"]) < 0.02
        assert drift["dz_mm"] == pytest.approx(drift["pad_reading_z_mm"] - probe["result"]["pad_reading_z_mm"])
        assert run["result"]["program"]["commands"] == run["result"]["source_program"]["commands"]
    runs = [j for j in children if j["kind"] == "probe_run"]
    assert all(r["result"]["calibration"]["probe_job_id"] == probe["id"] for r in runs)
    return traces, children


def test_after_calibration_every_trace_holds_its_standoff_and_path(client):
    """On S1's as-made part: everything :func:`calibrated_loop_holds_standoff_and_path`
    asserts, and a wide nozzle on the same machine refused on the slopes, named."""
    traces, children = calibrated_loop_holds_standoff_and_path(
        client, true_part_stl(seed=11, amplitude_mm=0.15), "s1", seed=5)
    # a wide nozzle on the same machine: its 2 mm body would touch S1's slopes; refused, named
    comp = next(j for j in children if j["kind"] == "compensate")
    trace = next(t for t in traces if t["id"] == comp["params"]["trace_id"])
    response = client.post("/api/v1/jobs", json={"kind": "compensate", "params": {
        **comp["params"], "tool": 2, "allow_uncalibrated": True}}, headers=OP)
    assert response.status_code == 202, response.text
    refused = wait_for(client, response.json()["id"], timeout=120)
    assert refused["status"] == "failed" and refused["error"]["status"] == 422
    error = refused["error"]["errors"][0]
    assert error["loc"] == ["params", "tool"] and error["value"]["trace_id"] == trace["id"]
    assert error["value"]["by_mm"] > 0.0
    assert f"trace {trace['name']}" in refused["error"]["detail"] and "s = " in refused["error"]["detail"]
