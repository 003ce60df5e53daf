"""The state both machine backends keep (``hardware.machine_state.MachineState``): one
operation at a time, errors that stick until a reconnect, and an emergency stop that never
waits for the operation holding the machine."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pytest

from hardware.errors import MachineBusy, MachineStateError
from hardware.linuxcnc import LinuxCNCMachine
from hardware.machine import Machine as SerialMachine
from hardware.machine_state import InterruptedProgram, MachineState


@dataclass
class FakeLink:
    """A link that is only healthy or not (what ``MachineState`` reads of a link)."""

    healthy: bool = True


def connected_state(error_when_lost: tuple[str, ...] = ("idle", "busy")) -> MachineState[FakeLink]:
    state: MachineState[FakeLink] = MachineState(error_when_lost=error_when_lost)
    state.link = FakeLink()
    state.connecting()
    state.current = "idle"
    return state


def test_a_disconnected_machine_refuses_every_operation_and_every_stop() -> None:
    state: MachineState[FakeLink] = MachineState()
    assert state.state == "disconnected"
    with pytest.raises(MachineStateError, match="not connected"):
        state.claim("busy")
    with pytest.raises(MachineStateError, match="nothing to stop"):
        state.require_stoppable()
    with pytest.raises(MachineStateError, match="not connected"):
        state.stopping()
    assert not state.estopped and not state.cancel_requested


def test_a_second_operation_is_busy_until_the_first_releases() -> None:
    state = connected_state()
    state.claim("printing")
    with pytest.raises(MachineBusy) as busy:
        state.claim("busy")
    assert busy.value.value == "printing" and state.state == "printing"
    state.release("idle")
    state.claim("busy")
    assert state.state == "busy"


def test_the_emergency_stop_claims_nothing_while_an_operation_holds_the_machine() -> None:
    state = connected_state()
    state.claim("printing")  # an operation holds the machine (the lock stays held)
    stopped: list[FakeLink] = []
    stopper = threading.Thread(target=lambda: stopped.append(state.stopping()))
    stopper.start()
    stopper.join(timeout=2.0)
    assert not stopper.is_alive() and stopped == [state.link]  # it did not wait for the lock
    assert state.estopped and state.cancel_requested and state.hold.locked()
    state.release(state.fail_state())  # the operation ends: in error, not idle
    assert state.state == "error"
    with pytest.raises(MachineStateError, match="error state"):
        state.claim("busy")  # nothing runs until the next connect
    state.connecting()
    assert not state.estopped


@pytest.mark.parametrize(("error_when_lost", "shown"), [(("idle", "busy"), "printing"),
                                                        (("idle", "busy", "printing", "paused"), "error")])
def test_a_lost_link_is_an_error_in_the_states_the_backend_names(error_when_lost, shown) -> None:
    state = connected_state(error_when_lost)
    state.claim("printing")
    assert state.link is not None
    state.link.healthy = False
    assert state.state == shown and state.link_lost and state.fail_state() == "error"
    state.release(state.fail_state())
    assert state.state == "error"


def test_pause_resume_and_cancel_name_the_state_that_refuses_them() -> None:
    state = connected_state()
    with pytest.raises(MachineStateError, match="cannot pause while idle"):
        state.require(("printing",), "cannot pause")
    state.claim("printing")
    state.progress = (3, 10)
    state.require(("printing", "paused"), "no program to cancel")
    assert state.running_program() == {"state": "printing", "line": 3, "total": 10}
    state.release()
    assert state.running_program() is None


@pytest.mark.parametrize("machine", [SerialMachine("mock://state-shared", "grbl"),
                                     LinuxCNCMachine("linuxcnc://127.0.0.1:5007")], ids=["serial", "linuxcnc"])
def test_both_backends_refuse_pause_and_stop_alike_before_connecting(machine) -> None:
    with pytest.raises(MachineStateError) as paused:
        machine.pause()
    assert paused.value.message == "cannot pause while disconnected"
    with pytest.raises(MachineStateError) as stopped:
        machine.stop()
    assert stopped.value.message == "nothing to stop: machine is disconnected"
    with pytest.raises(MachineStateError, match="not connected"):
        machine.emergency_stop()
    assert not machine.estopped and machine.state == "disconnected"


def test_an_interrupted_record_tells_the_resume_alone_unless_lines_in_flight_wait_for_their_numbers() -> None:
    # 3 acknowledged, 2 more sent numbered 12 and 13; the planner bound says only 2 moved
    sent = InterruptedProgram(8, 3, 11, [(12, 3), (13, 4)], reset=False, moved_index=2)
    assert sent.known_resume() is None  # the controller must say which of lines 12, 13 it took
    assert sent.known_resume(resets_on_connect=True) == 2  # a reset: from the first not known moved
    sent.reset = True
    assert sent.known_resume() == 2
    assert InterruptedProgram(8, 3, 11, [], reset=False, moved_index=2).known_resume() == 3  # nothing in flight
    assert InterruptedProgram(8, 3, None, [], reset=True).known_resume() == 3  # no bound on what moved
    # taken over by a new process: the later commands were numbered on from the last acknowledged
    numbered = InterruptedProgram.adopted(6, 3, 11)
    assert numbered.inflight == [(12, 3), (13, 4), (14, 5)] and not numbered.reset
    assert numbered.known_resume() is None
    unnumbered = InterruptedProgram.adopted(6, 3, None)
    assert unnumbered == InterruptedProgram(6, 3, None, [], reset=True)
    assert unnumbered.known_resume() == 3


def test_a_program_that_starts_forgets_the_interrupted_one() -> None:
    state = connected_state()
    state.interrupted = InterruptedProgram(10, 4, None, [], reset=True)
    state.cancel_requested = True
    assert state.program_status() == {"state": "interrupted", "line": 4, "total": 10, "resume_line": 4}
    assert state.program_status(located=5) == {"state": "interrupted", "line": 4, "total": 10, "resume_line": 5}
    state.claim("printing")
    state.program_started(4, 10)
    assert state.interrupted is None and not state.cancel_requested and state.progress == (4, 10)
    assert state.program_status() == {"state": "printing", "line": 4, "total": 10}


@pytest.mark.parametrize("machine", [SerialMachine("mock://state-adopt", "grbl"),
                                     LinuxCNCMachine("linuxcnc://127.0.0.1:5007")], ids=["serial", "linuxcnc"])
def test_both_backends_keep_an_adopted_program_in_their_machine_state_alike(machine) -> None:
    """A new process takes over what an earlier one recorded (``adopt_interrupted``, as the
    service does on a resume after a restart): the same record type in the same place, the
    same status, and a resume refused until connected."""
    assert machine.interrupted_program is None and machine.program_status() is None
    machine.adopt_interrupted(12, 5, None)
    gap = machine.interrupted_program
    assert gap is machine.machine_state.interrupted
    assert gap == InterruptedProgram(12, 5, None, [], reset=True)
    assert machine.program_status() == {"state": "interrupted", "line": 5, "total": 12, "resume_line": 5}
    assert machine.status()["program"] == machine.program_status()
    with pytest.raises(MachineStateError, match="connect before resuming"):
        machine.resume_line()
