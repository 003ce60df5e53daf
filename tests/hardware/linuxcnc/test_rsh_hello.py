"""The linuxcncrsh hello: a reply meant for another session, or a NAK while another session
talks, is not a refused password.

linuxcncrsh (LinuxCNC 2.9) parses every session's line with one shared ``strtok``, so while
sessions talk at once a line can be read with another session's words; seen under load as a
connect refused with the right password.  A scripted server plays linuxcncrsh's side (no
simulator needed)."""

from __future__ import annotations

import pytest

from hardware.errors import LinkError
from hardware.linuxcnc.rsh import RshSession
from tests.helpers.scripted_rsh import ScriptedRsh, in_turn


def test_another_sessions_reply_is_answered_by_a_second_hello():
    server = ScriptedRsh(in_turn("hello", "ESTOP OFF", "HELLO ACK EMCNETSVR 1.1"))
    session = RshSession.open("127.0.0.1", server.port, "pw", timeout_s=5.0)
    try:
        assert session.server == "EMCNETSVR 1.1"
        assert server.lines("hello") == ["hello pw conforma 1.0"] * 2
    finally:
        session.close()


def test_a_nak_while_another_session_talks_is_answered_by_a_second_hello():
    server = ScriptedRsh(in_turn("hello", "HELLO NAK", "HELLO ACK EMCNETSVR 1.1"))
    session = RshSession.open("127.0.0.1", server.port, "pw", timeout_s=5.0)
    try:
        assert session.server == "EMCNETSVR 1.1"
        assert len(server.lines("hello")) == 2
    finally:
        session.close()


def test_a_wrong_password_is_refused_after_three_naks_naming_the_field():
    server = ScriptedRsh(in_turn("hello", "HELLO NAK", "ESTOP OFF", "HELLO NAK", "HELLO NAK", "HELLO NAK",
                                 "HELLO ACK EMCNETSVR 1.1"))
    with pytest.raises(LinkError, match="refused the connect password") as refused:
        RshSession.open("127.0.0.1", server.port, "wrong", timeout_s=5.0)
    assert refused.value.field == "connect_pw"
    assert len(server.lines("hello")) == 5  # three NAKs in a row


def test_a_server_that_never_says_hello_is_a_link_error_with_its_answer():
    server = ScriptedRsh(in_turn("hello", *["JOINT_HOMED YES"] * 6))
    with pytest.raises(LinkError, match="JOINT_HOMED YES") as failed:
        RshSession.open("127.0.0.1", server.port, "pw", timeout_s=5.0)
    assert failed.value.field == "port"
