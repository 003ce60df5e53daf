"""An emergency stop is sent until the controller reports it: linuxcncrsh can read the stop's
line with another session's words (one ``strtok`` for every session's thread) and answer, or
do, something else.  A scripted server plays linuxcncrsh (no simulator needed); the stop's
timing at a real controller is tested in ``test_machine.py``."""

from __future__ import annotations

import pytest

from hardware.errors import LinkError
from hardware.linuxcnc.stop_session import ESTOP_TRIES
from tests.helpers.scripted_rsh import ScriptedRsh, printing_machine


class _Controller:
    """linuxcncrsh whose first ``broken`` stop lines go wrong as ``how`` says; ``estop`` is what
    the controller reports."""

    def __init__(self, how: str, broken: int) -> None:
        self.how, self.broken, self.estop = how, broken, "OFF"

    def __call__(self, line: str, connection: int) -> str | None:
        if line == "set estop on":
            if self.broken > 0:
                self.broken -= 1
                return {"nak": "SET ESTOP NAK", "other": "SET JOINT_POS NAK",
                        "ignored": "SET ESTOP ACK"}[self.how]
            self.estop = "ON"
        if line == "get estop":
            return f"ESTOP {self.estop}"
        return None


@pytest.mark.parametrize("how", ["nak", "other", "ignored"])
def test_a_stop_the_controller_did_not_take_is_sent_again_until_it_reports_it(how):
    controller = _Controller(how, broken=1)
    server = ScriptedRsh(controller)
    machine = printing_machine(server)
    machine.stop()
    assert controller.estop == "ON"
    assert server.lines("set estop on") == ["set estop on"] * 2
    assert machine.state == "error"
    sent = machine.console.since(direction="sent", contains="estop").entries
    assert [entry.text for entry in sent] == ["set estop on"] * 2  # the operator sees both


def test_a_stop_never_reported_is_a_link_error_and_the_machine_stays_in_error():
    controller = _Controller("ignored", broken=ESTOP_TRIES)
    server = ScriptedRsh(controller)
    machine = printing_machine(server)
    with pytest.raises(LinkError, match="did not report the emergency stop") as failed:
        machine.stop()
    assert failed.value.field == "port"
    assert len(server.lines("set estop on")) == ESTOP_TRIES
    assert machine.state == "error"
