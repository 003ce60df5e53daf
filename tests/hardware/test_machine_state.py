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
from hardware.machine_state import MachineState


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
