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
  file the controller ran and on the motor positions sampled from HAL (``HalWatch``)
  while its dispense output was on; also when the link drops mid-probe-run or mid-print
  and the operator resumes the interrupted step.

The simulator homes to switches (Z up to 30 mm first), so homing never drives the probe
into a placed part and a resume's re-homing comes back to the same frame; homing in place
(before) could put the new origin inside the part ("Probe tripped during homing motion").
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
import trimesh

from hardware.linuxcnc import SimBlock
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import SURFACE_SLOPE_X, SURFACE_Z, add_sim_machine, wait_until
from tests.helpers.jobs import wait_for

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
    return add_sim_machine(client, sim, PROFILE, OP)


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


# sampled at the controller (HAL, hardware.linuxcnc.HalWatch): the motors' positions (the
# simulated part is fixed in motor coordinates) and the dispense output M64/M65 P0 drives
# (and the probe input, to count touches)
WATCHED = ["joint.0.motor-pos-fb", "joint.1.motor-pos-fb", "joint.2.motor-pos-fb", "motion.digital-out-00",
           "motion.probe-input"]


def _start_loop(client, sim, truth: SimBlock) -> tuple[str, str]:
    """Upload the block, add and home the machine, place ``truth`` on the simulator and
    submit the closed loop (probe -> reconstruct -> compensate -> print); returns (machine, loop) ids."""
    part = upload_block(client)
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json={
        "name": "top line", "geometry": {"type": "line", "start": [3.0, 7.0], "end": [17.0, 7.0]},
        "frame": "xy", "standoff_mm": STANDOFF}, headers=OP)
    assert trace.status_code == 201, trace.text
    machine_id = add_machine(client, sim)
    sim.set_surface(truth)
    response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [trace.json()["id"]], "machine_id": machine_id,
        "probe": {"method": "uniform", "count": 5, "placement": {**TRUE, "dz": 0.0}},
        "reconstruct_method": "deviation", "print": True}}, headers=OP)
    assert response.status_code == 202, response.text
    return machine_id, response.json()["id"]


def _check_printed(client, sim, truth: SimBlock, loop: dict, samples: list, elapsed: float, label: str) -> None:
    """The loop succeeded and the controller held the nozzle at the standoff above the
    simulator's surface: on the program file it ran last and on every HAL sample taken
    while the dispense output was on (away from the trace's ends)."""
    assert loop["status"] == "succeeded", loop["error"]
    kinds = [j["kind"] for j in client.get(f"/api/v1/jobs?parent_id={loop['id']}", headers=OP).json()["items"]]
    assert {"probe_plan", "probe_run", "reconstruct", "compensate", "print"} <= set(kinds), kinds
    # the program the controller ran last (probing is MDI): the whole program, or a resume's tail
    files = sorted((sim.workdir / "programs").glob("conforma-*.ngc"), key=lambda p: p.stat().st_mtime)
    points = np.array(_dispensed_points(files[-1].read_text())[0])
    assert len(points) >= 2
    error = points[:, 2] - np.array([truth.top_z(x, y) for x, y, _ in points]) - STANDOFF
    nominal = HEIGHT + SLOPE * np.array([truth.part_uv(x, y)[0] for x, y, _ in points])  # placed without dz
    off = nominal - np.array([truth.top_z(x, y) for x, y, _ in points])
    x_lo, x_hi = points[:, 0].min() + 0.2, points[:, 0].max() - 0.2
    on_path = np.array([v[:3] for _, v in samples if v[3] == 1 and x_lo < v[0] < x_hi])
    assert len(on_path) >= 10, f"only {len(on_path)} HAL samples with the dispense output on"
    sampled = on_path[:, 2] - np.array([truth.top_z(x, y) for x, y, _ in on_path]) - STANDOFF
    print(f"{label} on LinuxCNC in {elapsed:.1f} s: program standoff error {error.min() * 1e3:.2f}.."
          f"{error.max() * 1e3:.2f} um over {len(points)} points; {len(on_path)} HAL samples with the dispenser on "
          f"{sampled.min() * 1e3:.2f}..{sampled.max() * 1e3:.2f} um; the uncompensated program would be "
          f"{off.min() * 1e3:.1f}..{off.max() * 1e3:.1f} um off")
    assert off.min() < -0.05  # the premise: uncompensated, the nozzle would be >= 50 um low
    # compensated: within the probes' trip lateness (they read up to LATE_MM low, so the
    # program sits up to that much low), the 2 um chord / fit allowance and, for the HAL
    # samples, the homing latch's 2 um repeatability (a resume re-homes)
    assert -LATE_MM - 0.002 <= error.min() and error.max() <= 0.002, error
    assert -LATE_MM - 0.004 <= sampled.min() and sampled.max() <= 0.004, sampled


def test_closed_loop_prints_at_the_standoff_above_the_simulated_surface(client, lcnc_env):
    truth = SimBlock(LENGTH, WIDTH, HEIGHT, TRUE_SLOPE, **TRUE)
    started = time.monotonic()
    try:
        with lcnc_env.watch(WATCHED) as watch:
            _, loop_id = _start_loop(client, lcnc_env, truth)
            loop = wait_for(client, loop_id, timeout=180)
    finally:
        lcnc_env.set_surface(SimBlock.plane(SURFACE_Z, SURFACE_SLOPE_X))
    _check_printed(client, lcnc_env, truth, loop, watch.samples, time.monotonic() - started, "closed loop")


def _wait_child(client, loop_id: str, kind: str, states: tuple[str, ...], timeout_s: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for job in client.get(f"/api/v1/jobs?parent_id={loop_id}", headers=OP).json()["items"]:
            if job["kind"] == kind and job["status"] in states:
                return job
        time.sleep(0.05)
    raise AssertionError(f"no {kind} child of {loop_id} became {states} in {timeout_s} s")


@pytest.mark.parametrize("cut_during", ["probe_run", "print"])
def test_a_closed_loop_whose_link_drops_waits_for_the_operator_and_resumes_to_the_right_result(
        client, lcnc_env, cut_during):
    """The linuxcncrsh session is cut mid-probe-run (after two touches) or mid-print (a third
    of the program done): the step becomes ``interrupted``, the controller aborts and
    nothing moves (HAL) until the operator resumes the step; the loop then completes and
    prints at the standoff, as uninterrupted."""
    truth = SimBlock(LENGTH, WIDTH, HEIGHT, TRUE_SLOPE, **TRUE)
    observer = lcnc_env.session()
    started = time.monotonic()
    try:
        with lcnc_env.watch(WATCHED) as watch:
            machine_id, loop_id = _start_loop(client, lcnc_env, truth)
            machine = client.app.state.runtime.machines.get(machine_id)
            _wait_child(client, loop_id, cut_during, ("running",))
            if cut_during == "print":
                assert wait_until(lambda: machine.state == "printing" and machine.progress
                             and machine.progress[0] >= max(1, machine.progress[1] // 3), 60.0)
            else:  # two touches made: each probe descends, touches, retracts
                assert wait_until(lambda: _touches(watch) >= 2 and machine.state == "busy", 60.0)
            machine.link.sever()
            child = _wait_child(client, loop_id, cut_during, ("interrupted", "failed", "succeeded"))
            assert child["status"] == "interrupted", child["error"]
            assert child["program_state"]["reason"].startswith("LinkError")
            assert client.get(f"/api/v1/jobs/{loop_id}", headers=OP).json()["status"] == "running"  # it waits
            assert wait_until(lambda: observer.get("program_status") == "IDLE", 60.0)
            time.sleep(0.3)  # the abort's deceleration
            frozen, count = watch.samples[-1], len(watch.samples)
            time.sleep(1.0)  # nobody resumed: nothing moves, the dispenser stays as it was left
            assert len(watch.samples) == count and frozen[1][3] == 0, watch.samples[count - 1:]
            assert client.post(f"/api/v1/jobs/{child['id']}/resume", json={"confirm": True},
                               headers=OP).status_code == 202
            loop = wait_for(client, loop_id, timeout=180)
    finally:
        observer.close()
        lcnc_env.set_surface(SimBlock.plane(SURFACE_Z, SURFACE_SLOPE_X))
    resumed = client.get(f"/api/v1/jobs/{child['id']}", headers=OP).json()
    assert resumed["status"] == "succeeded" and resumed["result"]["resumes"] == 1, resumed
    _check_printed(client, lcnc_env, truth, loop, watch.samples, time.monotonic() - started,
                   f"closed loop cut during {cut_during}, resumed")



def _touches(watch) -> int:
    """Rising edges of the probe input so far."""
    values = [v[4] for _, v in list(watch.samples)]
    return sum(1 for a, b in zip(values, values[1:]) if a == 0 and b == 1)
