"""Machine: probing against the true part, streaming, pause/resume/cancel, stop, resume
after disconnects and resets."""

from __future__ import annotations

import math
import random
import threading
import time

import numpy as np
import pytest
import trimesh

from hardware.errors import InvalidConfig, LinkError, MachineBusy, MachineStateError, ProbeFailed
from hardware.machine import Machine, MachineProfile
from hardware.mock import FaultConfig, TruePlacement
from hardware.protocol import normalized_commands
from tests.helpers.machines import executed_before_the_cut

GRBL_PROFILE = MachineProfile(dispense_on="M8", dispense_off="M9")


def _machine(url: str, dialect: str, **kwargs) -> Machine:
    profile = GRBL_PROFILE if dialect == "grbl" else MachineProfile()
    kwargs.setdefault("timeout_s", 10)
    return Machine(url, dialect, profile, boot_wait_s=0.5, boot_quiet_s=0.01, poke_s=0.02,
                   **kwargs)


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_probe_run_within_three_sigma_of_the_true_part(make_world, dialect):
    radius, sigma = 30.0, 0.01
    dome = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    dome.apply_translation((0.0, 0.0, -20.0))  # a shallow cap above the bed
    placement = TruePlacement(dx=1.5, dy=-0.7, dz=0.3, rz_deg=12.0)
    url, world = make_world(dialect=dialect, true_part=dome, placement=placement,
                            probe_noise_mm=sigma, seed=4, homing=dialect == "grbl")
    machine = _machine(url, dialect)
    machine.connect()
    machine.home()
    sag = radius - np.linalg.norm(dome.triangles_center - (0.0, 0.0, -20.0), axis=1).min()
    residuals = []
    for x in np.linspace(-10, 10, 4):
        for y in np.linspace(-10, 10, 4):
            point = machine.probe(float(x), float(y), z_start=15.0, z_min=-5.0)
            assert (point.x, point.y) == pytest.approx((x, y), abs=1e-3)
            # analytic truth: sphere centre (0, 0, -20) moved by the placement
            cx, cy, cz = 1.5, -0.7, -20.0 + 0.3
            height = math.sqrt(radius**2 - (x - cx) ** 2 - (y - cy) ** 2)
            truth = cz + height
            slack = sag * radius / height + 0.001  # facet sag + 3-decimal reporting
            residual = point.z - truth
            assert -3 * sigma - slack <= residual <= 3 * sigma + 0.001
            residuals.append(residual)
    assert 0.4 * sigma < np.std(residuals) < 1.6 * sigma  # the noise is really there
    assert machine.state == "idle"
    machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_probe_miss_raises_and_leaves_machine_safe(make_world, dialect):
    url, world = make_world(dialect=dialect)
    machine = _machine(url, dialect)
    machine.connect()
    with pytest.raises(ProbeFailed) as info:
        machine.probe(10.0, 10.0, z_start=5.0, z_min=1.0)  # the bed (z=0) is out of reach
    assert (info.value.x, info.value.y) == (10.0, 10.0)
    assert machine.state == "idle"
    assert machine.position()[2] == pytest.approx(5.0)  # retracted, and unlocked (grbl)
    assert machine.move(1.0, 2.0, 3.0) == pytest.approx((1.0, 2.0, 3.0))
    with pytest.raises(InvalidConfig):
        machine.probe(0.0, 0.0, z_start=1.0, z_min=2.0)
    machine.disconnect()


def _trial(make_world, rng: random.Random, trial: int) -> None:
    dialect = rng.choice(["marlin", "grbl"])
    window = rng.choice(["windowed", "pingpong"])
    kind = rng.choice(["disconnect_at_line", "reset_at_line"])
    program = ["G21", "G90"] + [f"G1 X{i * 0.5:.1f} Y{rng.randrange(50)} F3000" for i in range(38)]
    at = rng.randrange(1, len(program) + 1)
    # the fault comes at program command ``at``: the controller runs the program's safe_off first
    cut = at + len((GRBL_PROFILE if dialect == "grbl" else MachineProfile()).safe_off)
    url, world = make_world(dialect=dialect, faults=FaultConfig(seed=trial, **{kind: cut}))
    machine = _machine(url, dialect, window=window)
    machine.connect()
    world.transcript.reset()
    with pytest.raises(LinkError):
        machine.stream(program)
    assert machine.state == "error"
    machine.connect()
    ran, safe, reconnect = executed_before_the_cut(world, machine)
    start = machine.resume_line()
    case = (dialect, window, kind, at, start, ran)
    assert start <= ran, case  # never skips a command that did not run
    # "ok" = planned: after a reset what the controller can hold (planner blocks and stepper
    # segments) of acknowledged moves may not have run, so that many may run twice; a
    # Marlin that kept running is exact
    if dialect == "marlin" and kind == "disconnect_at_line":
        assert start == ran, case
    assert ran - start <= machine.held_moves + 2, case
    report = machine.stream(program, start_line=start)
    assert report.executed == report.total == len(program)
    commands = normalized_commands(program)
    expected = safe + commands[:ran] + reconnect + machine.last_preamble + commands[start:]
    assert world.transcript.commands == expected, case
    if start:  # units and distance mode restored before continuing; the feed once a move set it
        assert machine.last_preamble[1:3] == ["G21", "G90"]
        assert ("G1 F3000" in machine.last_preamble) == any(" F3000" in c for c in program[:start]), case
    machine.disconnect()


def test_resume_after_disconnect_or_reset_in_100_random_trials(make_world):
    rng = random.Random(2024)
    for trial in range(100):
        _trial(make_world, rng, trial)


def test_pause_resume_and_cancel_from_another_thread(make_world):
    url, world = make_world(dialect="marlin")
    machine = _machine(url, "marlin")
    machine.connect()
    world.transcript.reset()
    program = [f"G1 X{i}" for i in range(60)]
    seen: dict[str, object] = {}

    def controller() -> None:
        machine.pause()
        seen["state"] = machine.state
        frozen = world.transcript.executed_count
        time.sleep(0.1)
        seen["frozen"] = world.transcript.executed_count == frozen
        with pytest.raises(MachineBusy):
            machine.move(1, 1, 1)
        machine.resume()

    def on_progress(executed: int, total: int) -> None:
        if executed == 10:
            thread = threading.Thread(target=controller)
            thread.start()
            seen["thread"] = thread
        if executed == 40:
            machine.cancel()

    report = machine.stream(program, on_progress=on_progress)
    seen["thread"].join(5)
    assert seen["state"] == "paused" and seen["frozen"] is True
    assert report.cancelled and 40 <= report.executed < 60
    # the program's safe_off, then its commands up to the cancel
    assert world.transcript.commands == normalized_commands([*machine.profile.safe_off, *program[:report.executed]])
    assert machine.state == "idle"
    with pytest.raises(MachineStateError):
        machine.pause()


def test_a_pause_after_the_last_line_went_out_holds_the_program_until_resumed(make_world):
    url, world = make_world(dialect="marlin")
    machine = _machine(url, "marlin")
    machine.connect()
    program = [f"G1 X{i}" for i in range(5)]
    done = threading.Event()

    def on_progress(executed: int, total: int) -> None:
        if executed == total:  # every line sent and answered
            machine.pause()

    def run() -> None:
        machine.stream(program, on_progress=on_progress)
        done.set()

    thread = threading.Thread(target=run)
    thread.start()
    time.sleep(0.3)
    assert not done.is_set() and machine.state == "paused"
    machine.resume()
    thread.join(5)
    assert done.is_set() and machine.state == "idle"


def test_stop_while_idle_or_disconnected_is_a_clear_error(make_world):
    url, world = make_world(dialect="grbl")
    machine = _machine(url, "grbl")
    with pytest.raises(MachineStateError):
        machine.stop()
    machine.connect()
    connected = list(world.transcript.commands)
    assert connected == normalized_commands(machine.profile.safe_off)  # the connect's safe_off
    with pytest.raises(MachineStateError) as info:
        machine.stop()
    assert "idle" in info.value.message and machine.state == "idle"
    assert world.transcript.commands == connected and world.stats.stops == 0  # nothing was sent


def test_emergency_stop_during_a_program(make_world):
    url, world = make_world(dialect="marlin", time_scale=1.0)
    machine = _machine(url, "marlin")
    machine.connect()
    errors = []

    def run() -> None:
        try:
            machine.stream(["G4 P3000", "G1 X10 F600", "G1 X20"])
        except Exception as exc:
            errors.append(exc)

    thread = threading.Thread(target=run)
    thread.start()
    time.sleep(0.2)
    assert machine.state == "printing"
    machine.stop()
    thread.join(2)
    assert not thread.is_alive() and errors and machine.state == "error"
    assert world.firmware.halted
    machine.connect()  # reopening resets the halted controller
    assert machine.state == "idle" and not world.firmware.halted


def test_bad_input(make_world):
    with pytest.raises(InvalidConfig):
        Machine("mock://x", "klipper")
    with pytest.raises(InvalidConfig):
        MachineProfile(probe_command="G29")
    machine = Machine("/dev/ttyCONFORMA_NONE", "marlin")
    with pytest.raises(LinkError):
        machine.connect()
    assert machine.state == "disconnected"
    with pytest.raises(MachineStateError):
        machine.home()
    url, _ = make_world(dialect="marlin")
    machine = _machine(url, "marlin")
    machine.connect()
    with pytest.raises(InvalidConfig):
        machine.stream(["G1 X1"], start_line=5)
    with pytest.raises(InvalidConfig) as info:  # a non-G-code artifact
        machine.stream(["G21", "\x00\x01binary"])
    assert info.value.field == "program" and machine.state == "idle"
    with pytest.raises(MachineStateError):
        machine.resume_line()
