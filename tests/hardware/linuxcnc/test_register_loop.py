"""``register`` and ``closed_loop`` through the API on a ``linuxcnc://`` machine (Conforma's
three-axis LinuxCNC simulator).

The simulator's probe touches a placed block (``hardware.linuxcnc.SimBlock``, HAL in
``sim/probe.hal``): footprint 20 x 14 mm, top the tilted plane z = 1 + 0.01 u (part frame),
bed at its bottom.  The part Conforma is given is that block's nominal mesh; the
simulator places it with a known rigid placement, so the truth of every job is known:

* ``register`` must recover the placement within 3 sigma of the std it reports (dz also
  within the simulator's trip lateness, see ``LATE_MM``);
* ``closed_loop`` (probe -> reconstruct -> compensate -> print) must make the controller
  hold the nozzle at the standoff above the simulator's surface: checked on the program
  file the controller ran and on joint positions sampled from the controller while it ran.
"""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest
import trimesh

from hardware.linuxcnc import SimBlock
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import SURFACE_SLOPE_X, SURFACE_Z
from tests.jobs.test_jobs_api import wait_for

OP = auth("operator")
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "probe_command": "G38.2",
           "travel_feed_mm_min": 6000.0, "probe_feed_mm_min": 300.0}
LENGTH, WIDTH, HEIGHT, SLOPE = 20.0, 14.0, 2.0, 0.01
TRUE = {"dx": 0.4, "dy": -0.3, "dz": 0.05, "rz_deg": 0.5}
PROBE_FEED = 300.0  # mm/min
# the simulator sees the trip at most two 1 ms servo periods late (sampling + its one-period
# feedback lag): every touch reads up to this much below the surface (10 um at 300 mm/min)
LATE_MM = 2 * PROBE_FEED / 60 * 0.001


def block_mesh() -> trimesh.Trimesh:
    """The part: the block's nominal mesh (part frame, bottom at z = 0, tilted top)."""
    mesh = trimesh.creation.box(extents=[LENGTH, WIDTH, 4.0])
    mesh.apply_translation([LENGTH / 2, WIDTH / 2, 2.0])
    v = mesh.vertices.copy()
    top = v[:, 2] > 3.0
    v[top, 2] = HEIGHT + SLOPE * v[top, 0]
    v[~top, 2] = 0.0
    return trimesh.Trimesh(v, mesh.faces, process=True)


def add_machine(client, sim) -> str:
    body = {"name": "lcnc", "port": f"linuxcnc://127.0.0.1:{sim.port}?joints=3", "dialect": "linuxcnc",
            "profile": PROFILE}
    response = client.post("/api/v1/machines", json=body, headers=OP)
    assert response.status_code == 201, response.text
    machine_id = response.json()["id"]
    assert client.post(f"/api/v1/machines/{machine_id}/connect", headers=OP).json()["state"] == "idle"
    homed = client.post(f"/api/v1/machines/{machine_id}/home", headers=OP)
    assert homed.status_code == 200 and homed.json()["position"] == pytest.approx([0, 0, 0], abs=1e-6), homed.text
    return machine_id


def upload_block(client) -> dict:
    stl = block_mesh().export(file_type="stl")
    part = client.post("/api/v1/parts", files={"file": ("block.stl", stl)}, data={"units": "mm"}, headers=OP)
    assert part.status_code == 201, part.text
    return part.json()


@pytest.fixture
def placed_block(lcnc_env):
    block = SimBlock(LENGTH, WIDTH, HEIGHT, SLOPE, **TRUE)
    lcnc_env.set_surface(block)
    yield lcnc_env, block
    lcnc_env.set_surface(SimBlock.plane(SURFACE_Z, SURFACE_SLOPE_X))


def test_register_recovers_the_simulators_placement(client, placed_block):
    sim, block = placed_block
    part = upload_block(client)
    machine_id = add_machine(client, sim)
    started = time.monotonic()
    response = client.post("/api/v1/jobs", json={"kind": "register", "params": {
        "part_id": part["id"], "machine_id": machine_id, "count": 4, "sigma_mm": 0.003,
        "resolution_mm": 0.002, "clearance_mm": 0.5, "overtravel_mm": 0.5, "margin_mm": 1.0, "search_mm": 0.8,
        "probe_feed_mm_min": PROBE_FEED}}, headers=OP)
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=120)
    elapsed = time.monotonic() - started
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    est, std = result["placement"], result["std"]
    print(f"register on LinuxCNC: {result['probe_count']} touches in {elapsed:.1f} s; "
          f"estimate {est}; std {std}; truth {TRUE}")
    assert result["unobservable"] == []
    for key in ("dx", "dy"):
        assert abs(est[key] - TRUE[key]) <= 3 * std[f"{key}_mm"], (key, est[key], std)
    assert abs(est["rz_deg"] - TRUE["rz_deg"]) <= 3 * std["rz_deg"], (est, std)
    # every z touch reads 0..LATE_MM low: dz is biased low by at most that
    assert -LATE_MM - 3 * std["dz_mm"] <= est["dz"] - TRUE["dz"] <= 3 * std["dz_mm"], (est, std)
    assert max(std["dx_mm"], std["dy_mm"], std["dz_mm"]) < 0.01 and std["rz_deg"] < 0.05


# closed loop: the simulator's block top deviates from the part's nominal one (slope 0.012
# instead of 0.01: a machining error of 40 um over the block) and the loop is told the
# placement without dz (50 um), so an uncompensated program would be 56..90 um off
TRUE_SLOPE = 0.012
STANDOFF = 0.1
_WORD = re.compile(r"([XYZ])(-?[\d.]+)")


def _dispensed_points(text: str) -> tuple[list[tuple[float, float, float]], set[int]]:
    """The start and the X Y Z targets of the moves made with the dispenser on (M64 P0 ..
    M65 P0), and those moves' line numbers in the file (1-based)."""
    points, lines, on, here = [], set(), False, {"X": None, "Y": None, "Z": None}
    for number, line in enumerate(text.splitlines(), start=1):
        if line.startswith("M64 P0"):
            on = True
            points.append(tuple(here.values()))  # where the printing starts
        elif line.startswith("M65 P0"):
            on = False
        elif line.startswith(("G0", "G1")):
            here.update({k: float(v) for k, v in _WORD.findall(line)})
            if on:
                points.append(tuple(here.values()))
                lines.add(number)
    return points, lines


def _sample_joints(sim, stop: threading.Event, samples: list) -> None:
    observer = sim.session()
    try:
        while not stop.is_set():
            line = observer.get("program_line")
            joints = [float(v) for v in observer.get("joint_pos").split()[:3]]
            if observer.get("program_line") == line:
                samples.append((int(float(line or 0)), joints))
    finally:
        observer.close()


@pytest.mark.xfail(strict=False, reason="known defect (stop 22 note, issue 18): after the register test the "
                   "simulator's probe can be tripped when the loop homes ('Probe tripped during homing motion'); "
                   "passes when run alone")
def test_closed_loop_prints_at_the_standoff_above_the_simulated_surface(client, lcnc_env):
    truth = SimBlock(LENGTH, WIDTH, HEIGHT, TRUE_SLOPE, **TRUE)
    stop, samples = threading.Event(), []
    sampler = threading.Thread(target=_sample_joints, args=(lcnc_env, stop, samples))
    try:
        part = upload_block(client)
        trace = client.post(f"/api/v1/parts/{part['id']}/traces", json={
            "name": "top line", "geometry": {"type": "line", "start": [3.0, 7.0], "end": [17.0, 7.0]},
            "frame": "xy", "standoff_mm": STANDOFF}, headers=OP)
        assert trace.status_code == 201, trace.text
        machine_id = add_machine(client, lcnc_env)  # homed above whatever surface an earlier test left
        lcnc_env.set_surface(truth)
        placement = {**TRUE, "dz": 0.0}
        started = time.monotonic()
        sampler.start()
        response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
            "part_id": part["id"], "trace_ids": [trace.json()["id"]], "machine_id": machine_id,
            "probe": {"method": "uniform", "count": 5, "placement": placement},
            "reconstruct_method": "deviation", "print": True}}, headers=OP)
        assert response.status_code == 202, response.text
        loop = wait_for(client, response.json()["id"], timeout=120)
    finally:
        stop.set()
        if sampler.is_alive():
            sampler.join(10)
        lcnc_env.set_surface(SimBlock.plane(SURFACE_Z, SURFACE_SLOPE_X))
    elapsed = time.monotonic() - started
    assert loop["status"] == "succeeded", loop["error"]
    kinds = [j["kind"] for j in client.get(f"/api/v1/jobs?parent_id={loop['id']}", headers=OP).json()["items"]]
    assert {"probe_plan", "probe_run", "reconstruct", "compensate", "print"} <= set(kinds), kinds
    # the program the controller ran: the only program file (probing is MDI)
    files = sorted((lcnc_env.workdir / "programs").glob("conforma-*.ngc"), key=lambda p: p.stat().st_mtime)
    text = files[-1].read_text()
    dispensed, printing_lines = _dispensed_points(text)
    points = np.array(dispensed)
    assert len(points) >= 2
    top = np.array([truth.top_z(x, y) for x, y, _ in points])
    error = points[:, 2] - top - STANDOFF
    nominal = HEIGHT + SLOPE * np.array([truth.part_uv(x, y)[0] for x, y, _ in points])  # placed without dz
    off = nominal + STANDOFF - top - STANDOFF
    # the joints the controller sampled on the printing moves, away from their ends
    x_lo, x_hi = points[:, 0].min() + 0.2, points[:, 0].max() - 0.2
    on_path = np.array([j for line, j in samples if line in printing_lines and x_lo < j[0] < x_hi])
    assert len(on_path) >= 10, f"only {len(on_path)} joint samples on the printing moves"
    sampled = on_path[:, 2] - np.array([truth.top_z(x, y) for x, y, _ in on_path]) - STANDOFF
    print(f"closed loop on LinuxCNC in {elapsed:.1f} s: program standoff error {error.min() * 1e3:.2f}.."
          f"{error.max() * 1e3:.2f} um over {len(points)} points; {len(on_path)} joint samples "
          f"{sampled.min() * 1e3:.2f}..{sampled.max() * 1e3:.2f} um; the uncompensated program would be "
          f"{off.min() * 1e3:.1f}..{off.max() * 1e3:.1f} um off")
    assert off.min() < -0.05  # the premise: uncompensated, the nozzle would be >= 50 um low
    # compensated: within the probes' trip lateness (they read up to LATE_MM low, so the
    # program sits up to that much low) and the 2 um chord / fit allowance
    for values in (error, sampled):
        assert -LATE_MM - 0.002 <= values.min() and values.max() <= 0.002, values
