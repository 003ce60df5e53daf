"""Benchmark: droplet jetting on the LinuxCNC simulator (``jetting_run``) against the simulation.

Run: CI=true .venv/bin/python -m pytest tests/bench/test_bench_linuxcnc_jetting.py -s -o addopts="" -q
(``LINUXCNC_JETTING_LAYERS``, default 30).

A 3 mm square with a 1 mm hole at 300 dpi (6 pL drops of 60 um, the MPC with horizon 1, its
reference rising 0.75 nominal layer heights a layer), jetted by the mock head (384 nozzles,
2 % volume spread, seed 1) riding on the simulator's joints, cured by LinuxCNC's ``M64 P3``
lamp output and scanned by the simulator's HAL height sensor (sampled every 1 ms servo period,
0.26 um noise, 20 mm/s raster), against the simulation of the same head and the simulated open
loop.  Metrics on the head's TRUE heights after each cure (the machine) and on the simulation's
plant (the simulation).
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from app.jetting import (
    ControllerParams,
    JettingParams,
    PlantParams,
    TargetSpec,
    simulate,
    surface_metrics,
    target_from_spec,
)
from hardware.linuxcnc import SimBlock, SimController, SimSensor, linuxcnc_available
from hardware.linuxcnc.sim_head import SimHeadBridge
from hardware.printhead.mock import unregister_head
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import add_sim_machine, service_finds
from tests.hardware.linuxcnc.test_jetting_run import PROFILE, SENSOR_OFFSET, head_truth, jetting_params
from tests.helpers.jobs import submit, wait_for
from tests.helpers.real_components import missing

OP = auth("operator")
LAYERS = int(os.environ.get("LINUXCNC_JETTING_LAYERS", "30"))
SPREAD, SEED, FILL = 0.02, 1, 0.75
TARGET = TargetSpec(size_mm=3.0, hole_mm=1.0)


def sim_curve(kind: str) -> list:
    params = JettingParams(layers=LAYERS, target=TARGET, plant=PlantParams(nozzle_spread=SPREAD, seed=SEED),
                           controller=ControllerParams(kind=kind, fill=FILL))
    return [r.metrics for r in simulate(params).layers]


@pytest.mark.timeout(7200)
def test_bench_linuxcnc_jetting_against_the_simulation(client, monkeypatch):
    if not linuxcnc_available():
        missing("LinuxCNC", "not installed (apt-get install linuxcnc-uspace)")
    with SimController("xyz") as sim:
        service_finds(sim, monkeypatch)
        machine, elapsed, layers, fired_once = _machine_run(client, sim)
    _report(machine, elapsed, layers, fired_once)


def _machine_run(client, sim: SimController) -> tuple[list, float, list, bool]:
    """(the true heights' metrics after each cure, wall s, the job's layers, each drop fired once)."""
    sim.set_surface(SimBlock.plane(0.0, 0.0))
    sim.set_sensor(SimSensor(offset_mm=SENSOR_OFFSET, noise_mm=0.00026))
    bridge = SimHeadBridge(sim, "lcncjet")
    try:
        machine_id = add_sim_machine(client, sim, PROFILE, OP)
        response = submit(client, "jetting_run", jetting_params(
            machine_id, f"spread={SPREAD}&seed={SEED}", target={"size_mm": TARGET.size_mm, "hole_mm": TARGET.hole_mm},
            layers=LAYERS, controller="mpc", fill=FILL))
        assert response.status_code == 202, response.text
        started = time.monotonic()
        done = wait_for(client, response.json()["id"], timeout=7000)
        elapsed = time.monotonic() - started
        assert done["status"] == "succeeded", done["error"]
        params = JettingParams()
        target = target_from_spec(TARGET, params.drop, params.margin_mm)
        step = params.drop.layer_mm * FILL
        machine = [surface_metrics(head_truth(bridge.head.field, target.shape, target.pitch_mm, k), target, k * step)
                   for k in range(1, LAYERS + 1)]
        layers = done["result"]["layers"]
        fired_once = all(r["fired"] == r["drops"] for r in layers) and \
            bridge.head.field.drops == sum(r["drops"] for r in layers)
    finally:
        bridge.close()
        unregister_head("lcncjet")
    return machine, elapsed, layers, fired_once


def _report(machine: list, elapsed: float, layers: list, fired_once: bool) -> None:
    params = JettingParams()
    target = target_from_spec(TARGET, params.drop, params.margin_mm)
    mpc, ol = sim_curve("mpc"), sim_curve("open_loop")
    print(f"\nDroplet jetting on the LinuxCNC simulator, {LAYERS} layers, {target.shape} cells at 300 dpi, spread "
          f"{SPREAD}, seed {SEED}: {elapsed:.0f} s wall ({elapsed / LAYERS:.1f} s/layer), each drop fired once: "
          f"{fired_once}; valid samples {np.mean([r['valid_fraction'] for r in layers]):.3f}, cells filled from the "
          f"model {sum(r['filled_cells'] for r in layers)}")
    print(" layer | Sa MPC LinuxCNC  sim   | edge collapse MPC LinuxCNC  sim | Sa open loop sim")
    for k in sorted({5, 10, 20, LAYERS} & set(range(1, LAYERS + 1))):
        m, s, o = machine[k - 1], mpc[k - 1], ol[k - 1]
        print(f"  {k:4d} |   {m.sa_um:6.3f}   {s.sa_um:6.3f}   |   {m.edge_collapse_um:6.2f}   "
              f"{s.edge_collapse_um:6.2f}         |  {o.sa_um:6.3f}")
    assert fired_once
    final_m, final_s, final_o = machine[-1], mpc[-1], ol[-1]
    assert abs(final_m.sa_um / final_s.sa_um - 1) <= 0.25
    assert final_m.sa_um < final_o.sa_um
