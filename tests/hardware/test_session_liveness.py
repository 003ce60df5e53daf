"""The reply session's liveness rule and its resynchronisation after a reset, driven directly
(no port, no thread; every time is given).

* An idle grbl or Marlin says nothing unless asked: silence before the host sends the next
  command is no evidence of a dead link, so the liveness window starts when the host begins
  to wait, and a truly silent firmware still fails the link one window later.
* grbl flushes its receive buffer when it resets (``serial_reset_read_buffer``); a ``$G``
  marker a stall poke sent just before is never answered, and the replies that follow belong
  to the commands sent after the reset.
"""

from __future__ import annotations

import pytest

from hardware.dialects import GRBL, MARLIN
from hardware.errors import LinkError
from hardware.session import ReplySession
from hardware.session_types import Complete, Halt, Write

BANNER = "Grbl 1.1h ['$' for help]"


def completes(actions: list) -> list[tuple[str, str]]:
    return [(a.command.command, a.status) for a in actions if isinstance(a, Complete)]


@pytest.mark.parametrize("rules", [GRBL, MARLIN], ids=["grbl", "marlin"])
def test_an_idle_link_is_not_a_dead_link(rules):
    session = ReplySession(rules, now=0.0, timeout_s=30.0)
    assert session.timeout(35.0) == []  # idle for 35 s: nothing owed, nothing to judge
    command, _ = session.submit("G1 X1 F100", 35.0)
    for t in (35.01, 36.0, 40.0):  # the firmware is working on it: within the window
        assert not any(isinstance(a, Halt) for a in session.timeout(t)), t
    assert session.fatal is None and session.silent_s(40.0) == pytest.approx(5.0)
    session.feed("ok" if not rules.line_numbers else "ok N1 P15 B3", 40.5)
    assert command.status == "ok"


@pytest.mark.parametrize("rules", [GRBL, MARLIN], ids=["grbl", "marlin"])
def test_a_silent_firmware_still_fails_one_window_after_the_host_began_to_wait(rules):
    session = ReplySession(rules, now=0.0, timeout_s=3.0, poke_s=0.5)
    session.submit("G1 X1 F100", 100.0)
    halts = [a for t in (101.0, 102.0, 103.5) for a in session.timeout(t) if isinstance(a, Halt)]
    assert len(halts) == 1 and isinstance(halts[0].error, LinkError)


def test_a_marker_flushed_by_a_homing_reset_is_never_counted():
    """``$22=1`` and no switch in reach: ``$H`` gets ALARM:9 and its ok, grbl resets itself
    (the stall poke's ``$G`` in its receive buffer is flushed), boots in Alarm, and the next
    ``G1 X1 F100`` is refused with ``error:9``: that is its answer, not a lost ok."""
    s = ReplySession(GRBL, now=0.0, poke_s=2.5)
    home, _ = s.submit("$H", 0.0)
    poke = s.timeout(3.0)  # homing takes long and says nothing: a stall poke
    assert [w.data for w in poke if isinstance(w, Write)] == [b"?", b"$G\n"]
    s.feed("<Home|MPos:0.000,0.000,0.000|FS:0,0>", 3.01)
    s.feed("ALARM:9", 4.0)
    done = s.feed("ok", 4.0)
    assert completes(done) == [("$H", "error")]
    for text in ("", BANNER, "[MSG:'$H'|'$X' to unlock]"):
        s.feed(text, 4.1)
    assert not s.outstanding  # the marker was flushed with grbl's receive buffer
    move, _ = s.submit("G1 X1 F100", 5.0)
    answer = s.feed("error:9", 5.01)
    assert completes(answer) == [("G1 X1 F100", "error")]
    assert move.error_event is None and move.status == "error" and s.stats["assumed_ok"] == 0
    assert s.fatal is None


def test_after_a_probe_alarm_and_unlock_replies_stay_in_order():
    """ALARM:5 (no contact) keeps grbl running (no reset): the next lines are refused with
    error:9 until ``$X``; each answer belongs to its own command."""
    s = ReplySession(GRBL, now=0.0, poke_s=2.5)
    probe, _ = s.submit("G38.2 Z-10 F100", 0.0)
    s.feed("ALARM:5", 0.5)
    s.feed("[PRB:0.000,0.000,-10.000:0]", 0.5)
    assert completes(s.feed("ok", 0.5)) == [("G38.2 Z-10 F100", "error")]
    for text, reply in (("G0 Z5", "error:9"), ("$X", "[MSG:Caution: Unlocked]"), ("G0 Z5", "ok")):
        s.submit(text, 1.0)
        if reply != "ok" and not reply.startswith("error"):
            s.feed(reply, 1.01)
            reply = "ok"
        assert completes(s.feed(reply, 1.02)) == [(text, "error" if reply.startswith("error") else "ok")]
