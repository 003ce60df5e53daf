"""The reply session's liveness rule and its resynchronisation after a reset, driven directly
(no port, no thread; every time is given).

* An idle grbl or Marlin says nothing unless asked: silence before the host sends the next
  command is no evidence of a dead link, so the liveness window starts when the host begins
  to wait, and a truly silent firmware still fails the link one window later.
* What proves a firmware alive is dialect data (``Dialect.alive_replies``, ``busy_replies``,
  ``keepalive_s``, ``life_query``, ``idle_silent``): Marlin's ``busy:`` keepalives every 2 s
  keep a long command alive and hold the stall poke back; ``wait`` lines and temperature
  auto-reports prove it alive; grbl is poked with ``?``, which it answers in any state; noise
  proves nothing.
* grbl flushes its receive buffer when it resets (``serial_reset_read_buffer``); a ``$G``
  marker a stall poke sent just before is never answered, and the replies that follow belong
  to the commands sent after the reset.
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from hardware import events
from hardware.dialects import DIALECTS, GRBL, MARLIN
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


def halted(actions: list) -> bool:
    return any(isinstance(a, Halt) for a in actions)


def writes(actions: list) -> list[bytes]:
    return [a.data for a in actions if isinstance(a, Write)]


@pytest.mark.parametrize("rules", list(DIALECTS.values()), ids=list(DIALECTS))
def test_every_reply_kind_named_as_a_sign_of_life_is_a_reply_event(rules):
    for kind in (*rules.alive_replies, *rules.busy_replies):
        assert issubclass(getattr(events, kind), events.ReplyEvent), kind
    assert "Unknown" not in rules.alive_replies and set(rules.busy_replies) <= set(rules.alive_replies)


def test_marlin_busy_keepalives_keep_a_long_command_alive_and_hold_the_poke_back():
    """G28 for a minute: Marlin prints ``echo:busy: processing`` every keepalive_s (2 s) and
    nothing else; a 30 s window never fails and the host never pokes while they come."""
    session = ReplySession(MARLIN, now=0.0, timeout_s=30.0, poke_s=2.5)
    command, _ = session.submit("G28", 0.0)
    t, sent = 0.0, []
    while t < 60.0:
        t += MARLIN.keepalive_s
        actions = session.feed("echo:busy: processing", t) + session.timeout(t + 0.5)
        assert not halted(actions), t
        sent += writes(actions)
    assert sent == [] and session.stats["pokes"] == 0
    session.feed("ok N1 P15 B3", 60.5)
    assert command.status == "ok"
    # the keepalives stop (a dead board): the link fails one window after the last one
    session.submit("G28", 61.0)
    session.feed("echo:busy: processing", 62.0)
    assert not halted(session.timeout(91.9)) and halted(session.timeout(92.1))


@pytest.mark.parametrize("line", ["wait", "T:25.00 /0.00 B:24.90 /0.00 @:0 B@:0", "echo:Unknown command"])
def test_marlin_wait_lines_and_temperature_reports_prove_it_alive_but_do_not_hold_the_poke(line):
    session = ReplySession(MARLIN, now=0.0, timeout_s=3.0, poke_s=0.5)
    session.submit("G1 X1 F100", 0.0)
    for t in (1.0, 2.0, 3.0, 4.0, 5.0):
        session.feed(line, t)
        assert not halted(session.timeout(t + 0.1)), t
    assert session.silent_s(5.1) == pytest.approx(0.1)
    assert session.stats["pokes"] >= 1  # alive, but the command's answer is owed: it is poked


def test_noise_proves_nothing():
    session = ReplySession(MARLIN, now=0.0, timeout_s=3.0, poke_s=0.5)
    session.submit("G1 X1 F100", 0.0)
    for t in (1.0, 2.0, 3.0):
        session.feed("\x00\xff garbage", t)
    assert halted(session.timeout(3.1))


def test_a_stalled_grbl_is_asked_its_status_which_it_answers_in_any_state():
    session = ReplySession(GRBL, now=0.0, timeout_s=3.0, poke_s=0.5)
    dwell, _ = session.submit("G4 P10", 0.0)     # a dwell: grbl says nothing until it ends
    poke = writes(session.timeout(0.6))
    assert poke[0] == GRBL.life_query
    for t in (1.0, 2.0, 3.0, 4.0, 5.0):   # each poke's answer restarts the window
        session.feed("<Idle|MPos:0.000,0.000,0.000|FS:0,0>", t)
        assert not halted(session.timeout(t + 0.5)), t
    session.feed("ok", 10.0)              # the dwell's answer, then the poke's $G marker's
    session.feed("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", 10.01)
    session.feed("ok", 10.02)
    assert session.fatal is None and dwell.status == "ok" and not session.outstanding


def test_the_session_reads_liveness_from_the_dialect():
    """The same reply sequences under changed dialect data: a firmware that chatters while
    idle (not ``idle_silent``) is judged from its last reply, and a reply kind that is not a
    sign of life for the dialect does not keep the link alive."""
    chatty = replace(MARLIN, idle_silent=False)
    session = ReplySession(chatty, now=0.0, timeout_s=30.0)
    session.submit("G1 X1 F100", 35.0)   # 35 s without a word from a firmware that should chatter
    assert halted(session.timeout(35.1))
    deaf = replace(MARLIN, alive_replies=("Ok",), busy_replies=())
    session = ReplySession(deaf, now=0.0, timeout_s=3.0, poke_s=0.5)
    session.submit("G28", 0.0)
    for t in (1.0, 2.0, 3.0):
        session.feed("echo:busy: processing", t)
    assert halted(session.timeout(3.1))


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
