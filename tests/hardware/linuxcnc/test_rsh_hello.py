"""The linuxcncrsh hello: a reply meant for another session is not a refused password.

linuxcncrsh now and then hands one session's reply to another while sessions talk at once;
seen under load as a connect refused with the right password.  A scripted server on loopback
plays linuxcncrsh's side of the hello (no simulator needed)."""

from __future__ import annotations

import contextlib
import socket
import threading

import pytest

from hardware.errors import LinkError
from hardware.linuxcnc.rsh import RshSession


def _serve(replies_to_hello: list[str]) -> tuple[int, list[str]]:
    """A one-connection server answering each hello with the next of ``replies_to_hello``,
    every other line with its echo (as ``set echo off`` is answered) or ``VERBOSE ACK``;
    returns its port and the lines it received."""
    listener = socket.create_server(("127.0.0.1", 0))
    received: list[str] = []

    def run() -> None:
        conn, _ = listener.accept()
        listener.close()
        replies = iter(replies_to_hello)
        with conn, conn.makefile("rwb") as stream, contextlib.suppress(ConnectionError):
            for raw in stream:  # until the client closes (a reset when it closes unread)
                line = raw.decode().strip()
                received.append(line)
                if line.startswith("hello"):
                    answer = next(replies)
                elif line.startswith("set verbose"):
                    answer = "SET VERBOSE ACK"
                else:
                    answer = line
                stream.write(answer.encode() + b"\r\n")
                stream.flush()

    threading.Thread(target=run, daemon=True).start()
    return listener.getsockname()[1], received


def test_another_sessions_reply_is_answered_by_a_second_hello():
    port, received = _serve(["ESTOP OFF", "HELLO ACK EMCNETSVR 1.1"])
    session = RshSession.open("127.0.0.1", port, "pw", timeout_s=5.0)
    try:
        assert session.server == "EMCNETSVR 1.1"
        assert [line for line in received if line.startswith("hello")] == ["hello pw conforma 1.0"] * 2
    finally:
        session.close()


def test_a_nak_while_another_session_talks_is_answered_by_a_second_hello():
    port, received = _serve(["HELLO NAK", "HELLO ACK EMCNETSVR 1.1"])
    session = RshSession.open("127.0.0.1", port, "pw", timeout_s=5.0)
    try:
        assert session.server == "EMCNETSVR 1.1"
        assert sum(line.startswith("hello") for line in received) == 2
    finally:
        session.close()


def test_a_wrong_password_is_refused_after_three_naks_naming_the_field():
    port, received = _serve(["HELLO NAK", "ESTOP OFF", "HELLO NAK", "HELLO NAK", "HELLO NAK",
                             "HELLO ACK EMCNETSVR 1.1"])
    with pytest.raises(LinkError, match="refused the connect password") as refused:
        RshSession.open("127.0.0.1", port, "wrong", timeout_s=5.0)
    assert refused.value.field == "connect_pw"
    assert sum(line.startswith("hello") for line in received) == 5   # three NAKs in a row


def test_a_server_that_never_says_hello_is_a_link_error_with_its_answer():
    port, _ = _serve(["JOINT_HOMED YES"] * 6)
    with pytest.raises(LinkError, match="JOINT_HOMED YES") as failed:
        RshSession.open("127.0.0.1", port, "pw", timeout_s=5.0)
    assert failed.value.field == "port"
