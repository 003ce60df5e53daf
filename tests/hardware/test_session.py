"""The reply session driven directly: no port, no thread, no clock (every time is given).

Reply lines come from the corpus of real Marlin / grbl replies (``data/replies_*.tsv``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hardware.dialects import GRBL, MARLIN
from hardware.errors import FirmwareError, FirmwareReset, LinkError, ProtocolError
from hardware.events import Alarm, Busy, Echo, FirmwareErrorEvent
from hardware.protocol import frame
from hardware.session import ReplySession
from hardware.session_types import Complete, Halt, Position, Write

DATA = Path(__file__).parent / "data"
INFORMATIONAL = {"Echo", "Unknown", "Capability", "HostAction", "TemperatureReport", "FirmwareInfo",
                 "Busy", "Wait", "Setting", "Message", "ProbeReport", "PositionReport"}


def corpus(dialect: str) -> list[tuple[str, str]]:
    """(event type, raw line) of every reply in the dialect's corpus."""
    rows = []
    for line in (DATA / f"replies_{dialect}.tsv").read_text().splitlines():
        if line and not line.startswith("#"):
            kind, _, raw = line.split("\t", 2)
            rows.append((kind, raw))
    return rows


def line(dialect: str, pattern: str, **numbers: int) -> str:
    """The first corpus line matching ``pattern``, its numbers replaced (``last=3`` puts 3
    after ``Last Line:``; ``resend=2`` after ``Resend:``)."""
    raw = next(r for _, r in corpus(dialect) if re.search(pattern, r))
    if "last" in numbers:
        raw = re.sub(r"Last Line: \d+", f"Last Line: {numbers['last']}", raw)
    if "resend" in numbers:
        raw = re.sub(r"(Resend:\s*)\d+", rf"\g<1>{numbers['resend']}", raw)
    return raw


def okn(number: int) -> str:
    """Marlin's ADVANCED_OK acknowledgement of line ``number`` (the corpus form)."""
    return line("marlin", r"^ok N1 P15 B3$").replace("N1", f"N{number}")


def kinds(actions: list) -> list[str]:
    return [type(a).__name__ for a in actions]


def completes(actions: list) -> list[tuple[str, str]]:
    return [(a.command.command, a.status) for a in actions if isinstance(a, Complete)]


def writes(actions: list) -> list[tuple[bytes, str]]:
    return [(a.data, a.reason) for a in actions if isinstance(a, Write)]


def marlin(**options: float) -> ReplySession:
    return ReplySession(MARLIN, now=0.0, **options)


def grbl(**options: float) -> ReplySession:
    return ReplySession(GRBL, now=0.0, **options)


def send(session: ReplySession, *texts: str, now: float = 0.0) -> list:
    commands = []
    for text in texts:
        assert session.window_open(session.rules.line_bytes(text), now)
        command, actions = session.submit(text, now)
        assert writes(actions) == [(command.data, "command")]
        commands.append(command)
    return commands


# ------------------------------------------------------------------ Marlin
def test_marlin_lines_are_numbered_and_ok_n_acknowledges_every_earlier_line():
    s = marlin()
    one, two, three = send(s, "G1 X1", "G1 X2", "G1 X3")
    assert one.data == (frame(1, "G1 X1") + "\n").encode() and three.line_no == 3
    actions = s.feed(okn(2), 0.1)
    assert kinds(actions)[0] == "Observed"
    assert completes(actions) == [("G1 X1", "ok"), ("G1 X2", "ok")]
    assert list(s.outstanding) == [three] and s.n_ok and one.seq == 1 and two.seq == 2
    assert s.last_acked_line() == 2


def test_marlin_window_counts_command_slots_and_rx_bytes():
    s = marlin(command_buffer=2, rx_buffer=64)
    send(s, "G1 X1", "G1 X2")
    assert not s.window_open(s.rules.line_bytes("G1 X3"), 0.0)  # two slots taken
    s.feed(okn(1), 0.1)
    assert s.window_open(s.rules.line_bytes("G1 X3"), 0.1)
    assert not s.window_open(60, 0.1)  # bytes: 60 more would overflow 64


def test_marlin_checksum_mismatch_then_resend_replays_one_line_at_a_time():
    s = marlin()
    send(s, "G1 X1", "G1 X2", "G1 X3", "G1 X4")
    error = s.feed(line("marlin", r"checksum mismatch", last=1), 0.1)
    assert completes(error) == [] and writes(error) == []  # the Resend that follows does the work
    actions = s.feed(line("marlin", r"^Resend: \d+$", resend=2), 0.1)
    assert writes(actions) == [(s.history[2].data, "resend")]
    assert not s.window_open(10, 0.1)  # no new line while recovering
    assert s.stats["resends"] == 1 and s.history[2].resends == 1


def test_marlin_resend_without_advanced_ok_completes_the_accepted_lines():
    s = marlin()
    send(s, "G1 X1", "G1 X2", "G1 X3")
    s.feed(line("marlin", r"checksum mismatch", last=1), 0.1)
    actions = s.feed("Resend: 2", 0.1)  # no ok N seen: line 1 accepted is all we learn
    assert completes(actions) == [("G1 X1", "ok")]
    assert writes(actions) == [(s.history[2].data, "resend")]


def test_marlin_resend_swallows_the_plain_ok_and_continues_after_ok_n():
    s = marlin()
    send(s, "M110 N0")
    s.feed(okn(1), 0.05)  # the firmware speaks ADVANCED_OK
    send(s, "G1 X1", "G1 X2", "G1 X3")  # lines 2, 3, 4
    s.feed(line("marlin", r"checksum mismatch", last=2), 0.1)
    first = s.feed("Resend: 3", 0.1)
    assert completes(first) == [] and writes(first) == [(s.history[3].data, "resend")]
    swallowed = s.feed("ok", 0.11)
    assert completes(swallowed) == [] and writes(swallowed) == []
    actions = s.feed(okn(3), 0.12)  # line 3 (replayed) done: line 4 goes next
    assert completes(actions) == [("G1 X1", "ok"), ("G1 X2", "ok")]
    assert writes(actions) == [(s.history[4].data, "resend")]
    done = s.feed(okn(4), 0.13)
    assert completes(done) == [("G1 X3", "ok")] and s.window_open(10, 0.13)


def test_marlin_repeated_resend_for_a_line_in_flight_is_ignored():
    s = marlin()
    send(s, "G1 X1", "G1 X2", "G1 X3")
    s.feed("Resend: 1", 0.1)
    again = s.feed("Resend: 1", 0.1)  # line 2 arrived damaged too: same request
    assert writes(again) == [] and s.stats["ignored_resends"] == 1


def test_marlin_resend_beyond_the_history_halts_the_session():
    s = marlin(history=16)
    for k in range(20):
        send(s, f"G1 X{k}")
        s.feed(okn(k + 1), 0.01 * k)
    pending = send(s, "G1 Y1")
    actions = s.feed("Resend: 2", 1.0)
    halts = [a for a in actions if isinstance(a, Halt)]
    assert len(halts) == 1 and isinstance(halts[0].error, ProtocolError)
    assert halts[0].commands == tuple(pending) and s.fatal is halts[0].error
    assert s.feed(okn(21), 1.1) == [] and s.timeout(99.0) == []  # a dead session never acts


def test_marlin_command_error_keeps_the_command_until_its_ok():
    s = marlin()
    send(s, "G1 E5")
    error = s.feed(line("marlin", r"Cold extrusion"), 0.1)
    assert completes(error) == []
    actions = s.feed(okn(1), 0.2)
    done = [a for a in actions if isinstance(a, Complete)]
    assert [(d.status, type(d.error)) for d in done] == [("error", FirmwareErrorEvent)]


def test_marlin_busy_and_echo_lines_are_life_and_belong_to_the_head():
    s = marlin(poke_s=2.5)
    (command,) = send(s, "G28")
    for t in (2.0, 4.0, 6.0):
        actions = s.feed(line("marlin", r"^echo:busy: processing$"), t)
        assert completes(actions) == []
        assert s.timeout(t + 1.0) == []  # a keepalive one second ago: no poke
    s.feed(line("marlin", r"^echo:Home XYZ first$"), 6.5)
    assert [type(e) for e in command.replies] == [Busy, Busy, Busy, Echo]
    assert s.stats["pokes"] == 0


def test_marlin_stall_replays_the_unanswered_lines_then_times_out():
    s = marlin(poke_s=0.5, timeout_s=3.0)
    send(s, "G1 X1", "G1 X2")
    assert s.timeout(0.4) == []
    poke = s.timeout(0.6)
    assert writes(poke) == [(s.history[1].data, "resend")] and s.stats["pokes"] == 1
    halt = s.timeout(3.1)
    assert isinstance(halt[-1], Halt) and isinstance(halt[-1].error, LinkError)


def test_marlin_halt_reply_fails_everything_in_flight():
    s = marlin()
    commands = send(s, "G1 X1", "G1 X2")
    actions = s.feed(line("marlin", r"^!!$"), 0.1)
    halt = actions[-1]
    assert isinstance(halt, Halt) and isinstance(halt.error, FirmwareError)
    assert halt.commands == tuple(commands) and not s.outstanding


def test_marlin_restart_banner_with_commands_in_flight_is_a_reset():
    s = marlin()
    send(s, "G1 X1", "G1 X2")
    s.feed(okn(1), 0.1)
    actions = s.feed(line("marlin", r"^start$"), 0.2)
    assert isinstance(actions[-1], Halt) and isinstance(actions[-1].error, FirmwareReset)
    assert actions[-1].error.last_line == 1


def test_marlin_s000_position_report_is_consumed_and_marked():
    s = marlin()
    send(s, "M110 N0")
    s.feed(okn(1), 0.05)  # S000 is used with ADVANCED_OK only (its plain ok stays apart)
    s.reports.realtime = True
    s.reports.interval_s = 0.1
    (command,) = send(s, "G1 X50")
    asked = s.poll_reports(1.0)
    assert writes(asked) == [(b"S000\n", "report")] and s.reports.rt_pending == 1
    s.feed(line("marlin", r"^X:50\.00 Y:50\.00"), 1.01)
    consumed = s.feed("S_XYZ:5", 1.02)
    marks = [a.mark for a in consumed if isinstance(a, Position)]
    assert [m.position for m in marks] == [(50.0, 50.0, 15.0)] and marks[0].moving is True
    assert marks[0].asked_at == 1.0 and command.replies == []  # not the command's answer
    s.feed("ok", 1.03)  # the S000 line's own plain ok
    assert s.reports.rt_pending == 0 and command in s.outstanding


# ------------------------------------------------------------------ grbl
def test_grbl_counts_characters_in_the_rx_buffer():
    s = grbl(rx_buffer=20)
    send(s, "G1 X1 Y1", "G1 X2")  # 9 + 6 bytes
    assert not s.window_open(s.rules.line_bytes("G1 X3"), 0.0)  # 15 + 6 > 19
    assert writes(s.feed("ok", 0.1)) == [] and s.window_open(s.rules.line_bytes("G1 X3"), 0.1)


def test_grbl_error_is_the_answer_of_the_oldest_line():
    s = grbl()
    send(s, "G5 X1", "G1 X1")
    actions = s.feed(line("grbl", r"^error:20$"), 0.1)
    (done,) = [a for a in actions if isinstance(a, Complete)]
    assert done.command.command == "G5 X1" and done.status == "error" and done.error.code == 20
    assert completes(s.feed("ok", 0.2)) == [("G1 X1", "ok")]


def test_grbl_probe_alarm_fails_the_probe_when_its_ok_comes():
    s = grbl()
    send(s, "G38.2 Z-5 F100")
    assert completes(s.feed(line("grbl", r"^ALARM:4$"), 0.1)) == []
    actions = s.feed("ok", 0.2)
    (done,) = [a for a in actions if isinstance(a, Complete)]
    assert done.status == "error" and isinstance(done.error, Alarm) and done.error.code == 4


def test_grbl_status_report_is_a_position_and_a_completion_mark():
    s = grbl()
    send(s, "G1 X1")
    s.feed("ok", 0.1)
    actions = s.feed(line("grbl", r"^<Run\|MPos:10\.000,20\.000"), 0.2)
    marks = [a.mark for a in actions if isinstance(a, Position)]
    assert [m.position for m in marks] == [(10.0, 20.0, -1.0)] and marks[0].moving is True
    assert s.status_marks[-1][1:] == (1, 0.2) and s.status_seq == 1


def test_grbl_lost_ok_is_settled_by_the_parser_state_marker():
    s = grbl(poke_s=0.5)
    send(s, "G1 X1", "G1 X2")
    poke = s.timeout(0.6)
    assert writes(poke) == [(b"?", "poke"), (b"$G\n", "command")]
    settled = s.feed(line("grbl", r"^\[GC:G0 G54"), 0.7)
    assert completes(settled) == [("G1 X1", "assumed"), ("G1 X2", "assumed")]
    assert s.stats["assumed_ok"] == 2
    assert completes(s.feed("ok", 0.8)) == [("$G", "ok")]


def test_grbl_announced_reset_waits_for_its_banner():
    s = grbl()
    send(s, "$C")
    s.feed(line("grbl", r"^\[MSG:Disabled\]$"), 0.1)
    s.feed("ok", 0.1)
    assert s.awaiting_reset(0.2) and not s.window_open(5, 0.2)
    banner = s.feed(line("grbl", r"^Grbl 1\.1h"), 0.3)
    assert not any(isinstance(a, Halt) for a in banner) and s.window_open(5, 0.3)


def test_grbl_unannounced_banner_after_answers_is_a_restart():
    s = grbl()
    send(s, "G1 X1", "G1 X2")
    s.feed("ok", 0.1)
    actions = s.feed(line("grbl", r"^Grbl 1\.1f"), 0.2)
    assert isinstance(actions[-1], Halt) and isinstance(actions[-1].error, FirmwareReset)


# ------------------------------------------------------------------ the whole corpus
@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_informational_corpus_lines_never_complete_halt_or_write(dialect):
    rules = MARLIN if dialect == "marlin" else GRBL
    rows = [(k, r) for k, r in corpus(dialect) if k in INFORMATIONAL]
    assert len(rows) > 60
    for kind, raw in rows:
        s = ReplySession(rules, now=0.0)
        (command,) = send(s, "M115")
        actions = s.feed(raw, 0.1)
        assert kinds(actions) in ([], ["Observed"]), (raw, actions)
        assert list(s.outstanding) == [command] and s.fatal is None, raw
        if raw.strip() and kind != "Unknown":
            assert command.replies, raw  # it belongs to the command in flight


def test_emergency_halt_then_nothing_is_written():
    s = marlin()
    commands = send(s, "G1 X1")
    halt = s.halt(FirmwareError("emergency stop"), 0.5)
    assert halt == [Halt(tuple(commands), s.fatal)] and s.failed_at == 0.5
    assert writes(s.poll_reports(1.0)) == [] and writes(s.ask_status(1.0)) == []
