"""The firmware's own state (grbl Alarm, Hold, Check...) as machine state, on the grbl mock.

An alarm locks grbl until ``$X`` or ``$H``: the machine says so (never a stale ``Idle``),
refuses motion with a ``ControllerLocked`` naming the state, why and how to clear it, and
an unlock clears it.  A homing alarm resets grbl, which flushes the ``$G`` marker a stall
poke sent while homing: the next command still gets its own answer."""

from __future__ import annotations

import pytest

from hardware.errors import ControllerLocked, FirmwareError, MachineStateError
from hardware.machine import Machine, MachineProfile

GRBL = MachineProfile(dispense_on="M8", dispense_off="M9")


def grbl_machine(make_world, **world) -> tuple[Machine, object]:
    url, w = make_world(dialect="grbl", boot_s=0.05, **world)
    m = Machine(url, "grbl", GRBL, timeout_s=5, boot_wait_s=0.5, boot_quiet_s=0.02, poke_s=0.2)
    m.connect()
    return m, w


def test_a_probe_alarm_is_the_machine_state_until_unlocked(make_world):
    m, w = grbl_machine(make_world)
    m.move(z=5.0)
    assert m.status()["controller"] == "Idle"
    with pytest.raises(FirmwareError) as alarm:
        m.send("G38.2 Z4 F100")  # nothing between Z5 and Z4: ALARM:5
    assert alarm.value.code == 5
    status = m.status()
    assert status["controller"] == "Alarm", status  # never the Idle of the last report
    assert status["controller_state"]["reason"].startswith("ALARM:5")
    assert "$X" in status["controller_state"]["clear"]
    before = w.executed_count
    for attempt in (lambda: m.send("G1 X1 F100"), lambda: m.move(x=1.0), lambda: m.stream(["G1 X2 F100"]),
                    lambda: m.probe(1.0, 1.0)):
        with pytest.raises(ControllerLocked) as refused:
            attempt()
        assert "Alarm" in str(refused.value) and "ALARM:5" in str(refused.value) and "$X" in str(refused.value)
    assert w.executed_count == before and m.state == "idle"  # nothing ran, nothing is held
    assert m.send("$G").status == "ok"  # system commands still go through
    m.unlock()
    assert m.status()["controller"] == "Idle" and m.status()["controller_state"]["clear"] is None
    assert m.move(x=1.0)[0] == pytest.approx(1.0)
    m.disconnect()


def test_a_homing_alarm_keeps_replies_matched(make_world):
    """``$22=1`` with no switch in reach: ``$H`` fails with ALARM:9 while a stall poke's ``$G``
    waits in grbl's receive buffer; grbl resets (flushing it) and boots locked.  The next
    G-code's answer is its own ``error:9``, not an ``assumed`` ok."""
    m, _ = grbl_machine(make_world, time_scale=0.5, homing=True, homing_fails=True)
    with pytest.raises(FirmwareError) as failed:
        m.home()
    assert failed.value.code == 9 and m.link.stats["pokes"] >= 1  # a poke went out while homing
    answer = m.link.send("G1 X1 F100", 2.0, check=False)
    assert (answer.status, answer.reply_lines) == ("error", ("error:9",))
    assert m.link.stats["assumed_ok"] == 0
    assert m.status()["controller"] == "Alarm"
    with pytest.raises(ControllerLocked, match=r"\$X"):
        m.send("G1 X1 F100")
    m.disconnect()


def test_marlin_has_no_alarm_lock_to_clear(make_world):
    url, _ = make_world(dialect="marlin")
    m = Machine(url, "marlin", timeout_s=5, boot_wait_s=0.2, boot_quiet_s=0.02)
    m.connect()
    assert m.status()["controller"] is None
    with pytest.raises(MachineStateError, match="no alarm lock"):
        m.unlock()
    m.disconnect()
