"""The calibration core against the mock printer's physics, through ``hardware.machine``.

The mock (``mock://`` URL with probe-physics options) knows the truth: ball radius, pre-travel
with lobing and scatter, noise, drift, the nozzle's offset and the true places of the pad and
sphere (off their nominal places).  The touches run the way the calibration jobs run them:
up to a travel height, across, down to the start, ``probe_toward`` the target.
"""

from __future__ import annotations

import itertools
from contextlib import contextmanager

import numpy as np
import pytest

from app.calibration import (
    fit_nozzle_offset,
    fit_qualification,
    hops,
    plan_nozzle_calibration,
    plan_qualification,
    plan_times,
)
from hardware.machine import Machine, MachineProfile
from hardware.mock import MockWorld, register_world, unregister_world
from hardware.mock.world import get_world

_names = itertools.count()
R, P0, SD, LOBE, NOISE, DRIFT = 0.5, 0.015, 0.002, 0.003, 0.001, 0.001
OFFSET, NOZZLE_D = (12.3, -4.1, -8.7), 0.8
SPHERE_TRUE, SPHERE_NOMINAL, SPHERE_D = (120.3, 10.2, 12.25), (120.0, 10.0, 12.0), 25.4
PAD_TRUE, PAD_NOMINAL = (100.0, 10.0, 5.2), (100.0, 10.0, 5.0)
TRAVEL_Z = 50.0


@contextmanager
def mock_machine(dialect: str = "marlin", seed: int = 3):
    """A connected ``Machine`` on a fresh mock world with the issue's physics (``.world_name`` set)."""
    name = f"core16-{next(_names)}"
    # the URL's seed= seeds the fault plan only; the physics' random draws follow the world's seed
    register_world(name, MockWorld(dialect=dialect, seed=seed))
    options = (f"dialect={dialect}&stylus_radius_mm={R}&pretravel_mm={P0}&pretravel_sd_mm={SD}"
               f"&pretravel_lobing_mm={LOBE}&probe_noise_mm={NOISE}&drift_mm_per_min={DRIFT}"
               f"&touchoff_sd_mm=0.0005&tool1={','.join(map(str, OFFSET))},{NOZZLE_D}"
               f"&pad={','.join(map(str, PAD_TRUE))},20&sphere={','.join(map(str, SPHERE_TRUE))},{SPHERE_D}")
    profile = MachineProfile() if dialect == "marlin" else MachineProfile(dispense_on="M8", dispense_off="M9")
    m = Machine(f"mock://{name}?{options}", dialect, profile, boot_wait_s=0.5, boot_quiet_s=0.01, poke_s=0.02,
                timeout_s=10)
    try:
        m.connect()
        m.world_name = name
        yield m
    finally:
        m.disconnect()
        unregister_world(name)


@pytest.fixture
def machine(request):
    with mock_machine(request.param) as m:
        yield m


def run(machine: Machine, touches, tools) -> tuple[np.ndarray, np.ndarray]:
    """Execute touches as the calibration jobs do; readings (n, 3) and the mock's clock (n,) s
    at each trigger."""
    world = get_world(machine.world_name)
    out, clock = [], []
    current, previous = None, None
    for touch, tool in zip(touches, tools, strict=True):
        x, y, z = touch.start_mm
        # a local touch after one of its kind hops near the artifact, else up to the travel height
        machine.move(z=max(previous.start_mm[2], z) if hops(previous, touch) else TRAVEL_Z)
        if tool != current:
            machine.select_tool(tool)
            current = tool
        machine.move(x=x, y=y)
        machine.move(z=z)
        hit = machine.probe_toward(touch.start_mm, touch.target_mm)
        out.append([hit.x, hit.y, hit.z])
        back = float(np.linalg.norm(np.subtract(out[-1], touch.start_mm))) / 3000.0 * 60.0
        clock.append(world.stats.machine_time_s - back)      # probe_toward ends back at the start
        previous = touch
    machine.move(z=TRAVEL_Z)
    machine.select_tool(0)
    return np.array(out), np.array(clock)


@pytest.mark.parametrize("machine", ["marlin", "grbl"], indirect=True)
def test_qualification_and_nozzle_offset_on_the_mock(machine):
    machine.move(z=TRAVEL_Z)
    start = machine.position()
    clock0 = get_world(machine.world_name).stats.machine_time_s
    touches = plan_qualification(SPHERE_NOMINAL, SPHERE_D, R, PAD_NOMINAL, per_ring=12, equator=24)
    readings, clock = run(machine, touches, [0] * len(touches))
    times = plan_times(touches, readings, travel_z=TRAVEL_Z, travel_feed=3000.0, probe_feed=100.0, start_mm=start)
    # the estimated trigger times are the mock's clock, to the readings' noise and 1 um reports
    # (~0.5 ms a touch at 100 mm/min, summed over the run; 0.05 s of 1 um/min drift is 1e-9 mm)
    assert times + clock0 == pytest.approx(clock, abs=0.05)
    times = times + clock0
    cal = fit_qualification(touches, readings, SPHERE_D, times_s=times)
    s = cal.std
    # 3 sigma plus the reports' 1 um quantisation
    assert abs(cal.ball_radius_mm - R) < 3 * s["ball_radius_mm"] + 0.0005
    assert abs(cal.pretravel.p0_mm - P0) < 3 * s["p0_mm"] + 0.0005
    assert abs(cal.pretravel.cos3_mm - LOBE) < 3 * s["cos3_mm"] + 0.0005
    assert abs(cal.pretravel.sin3_mm) < 3 * s["sin3_mm"] + 0.0005
    assert abs(cal.ball_radius_mm - R) < 0.003 and abs(cal.pretravel.p0_mm - P0) < 0.003
    e0 = DRIFT / 60 * times[0]          # the centre refers to the first touch's drift
    for k, axis in enumerate("xyz"):
        truth = SPHERE_TRUE[k] - (e0 if axis == "z" else 0.0)
        assert abs(cal.sphere_centre_mm[k] - truth) < 3 * s[f"centre_{axis}_mm"] + 0.001
    assert cal.drift_mm_per_min == pytest.approx(DRIFT, abs=3 * s["drift_mm_per_min"] + 1e-4)

    nozzle_plan = plan_nozzle_calibration(cal, (12.0, -4.0, -8.5), NOZZLE_D, SPHERE_D, PAD_NOMINAL,
                                          pad_touches=4, side_touches=2)
    nozzle_readings, _ = run(machine, nozzle_plan, [0 if t.kind == "pad" else 1 for t in nozzle_plan])
    nozzle = fit_nozzle_offset(1, nozzle_plan, nozzle_readings, cal, NOZZLE_D, SPHERE_D)
    error = np.subtract(nozzle.offset_mm, OFFSET)
    assert np.abs(error).max() < 0.003
    assert np.all(np.abs(error) < 3 * np.array(nozzle.std_mm) + 0.0005)
