"""A session's echo and verbose flags hold after it opens, also when linuxcncrsh refused the
first ``set``.

linuxcncrsh (LinuxCNC 2.9) parses every session's line with one shared ``strtok``: while another
session talks, ``set echo off`` or ``set verbose on`` can be read with that session's words and
answered NAK, leaving the flag as it was.  Seen under load as a session that failed to open with
"LinuxCNC rejected 'set verbose on'".  A scripted server plays linuxcncrsh's side, with each
session's flags (no simulator needed)."""

from __future__ import annotations

import socket

import pytest

from hardware.errors import LinkError
from hardware.linuxcnc.rsh import RshSession
from tests.helpers.scripted_rsh import ScriptedRsh, in_turn


def _opened(server: ScriptedRsh) -> RshSession:
    return RshSession.open("127.0.0.1", server.port, "pw", timeout_s=5.0)


@pytest.mark.parametrize("flag, value", [("echo", "off"), ("verbose", "on")])
def test_a_flag_refused_once_is_set_again_and_every_later_reply_is_its_own(flag, value):
    server = ScriptedRsh(in_turn(f"set {flag}", f"SET {flag.upper()} NAK"))
    session = _opened(server)
    try:
        assert server.lines(f"set {flag}") == [f"set {flag} {value}"] * 2
        assert session.get("echo") == "OFF" and session.get("verbose") == "ON"
        session.set("mode", "mdi")  # answered by its own ACK, not by a copy of itself
        assert session.get("mode") == "OK"
    finally:
        session.close()


def test_a_flag_read_back_with_another_sessions_words_is_set_again():
    server = ScriptedRsh(in_turn("get verbose", "JOINT_POS 1.0 2.0 3.0", "VERBOSE ON"))
    session = _opened(server)
    try:
        assert server.lines("set verbose") == ["set verbose on"] * 2
        assert session.get("mode") == "OK"
    finally:
        session.close()


def test_a_flag_that_never_holds_is_a_link_error_naming_the_port():
    server = ScriptedRsh(in_turn("set verbose", *["SET VERBOSE NAK"] * 5))
    with pytest.raises(LinkError, match="did not keep 'set verbose on' in 5 tries") as failed:
        _opened(server)
    assert failed.value.field == "port"
    assert len(server.lines("set verbose")) == 5



def test_the_scripted_server_keeps_a_sessions_flags_as_linuxcncrsh_does():
    """Read on a raw socket, as any client would: no ``set`` before hello, no copy before
    hello, a copy of every line after it while echo is on, an ACK only when verbose."""
    server = ScriptedRsh(lambda line, _: None)
    with socket.create_connection(("127.0.0.1", server.port), timeout=5.0) as sock, \
            sock.makefile("rwb") as stream:
        def say(line: str) -> bytes:
            stream.write(line.encode() + b"\r\n")
            stream.flush()
            return stream.readline()

        assert say("set echo off") == b"SET NAK\r\n"
        assert say("get echo") == b"ECHO ON\r\n"
        assert say("hello pw me 1.0") == b"HELLO ACK EMCNETSVR 1.1\r\n"
        assert say("get verbose") == b"get verbose\r\n" and stream.readline() == b"VERBOSE OFF\r\n"
        assert say("set verbose on") == b"set verbose on\r\n" and stream.readline() == b"SET VERBOSE ACK\r\n"
        assert say("set echo off") == b"set echo off\r\n" and stream.readline() == b"SET ECHO ACK\r\n"
        assert say("get echo") == b"ECHO OFF\r\n"
