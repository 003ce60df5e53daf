"""``get`` under concurrent sessions: linuxcncrsh (2.9) can read a ``get``'s argument from
another session's line and answer for one joint (``JOINT_POS <n> <value>``, seen under load
as two joints read instead of three); a value shorter than ``VALUE_WORDS`` says is asked
again.  A scripted server plays linuxcncrsh (no simulator needed)."""

from __future__ import annotations

import pytest

from hardware.errors import FirmwareError
from hardware.linuxcnc.rsh import RshSession
from tests.helpers.scripted_rsh import ScriptedRsh, in_turn

ALL_JOINTS = "JOINT_POS " + " ".join(["1.000000", "2.000000", "5.000000"] + ["0.000000"] * 6)


def test_a_one_joint_answer_is_asked_again_when_every_joint_was_asked_for():
    server = ScriptedRsh(in_turn("get joint_pos", "JOINT_POS 20 0.145864", ALL_JOINTS))
    session = RshSession.open("127.0.0.1", server.port, "pw")
    try:
        assert session.get("joint_pos").split()[:3] == ["1.000000", "2.000000", "5.000000"]
        assert server.lines("get joint_pos") == ["get joint_pos"] * 2
    finally:
        session.close()


def test_a_value_that_stays_short_is_a_firmware_error_naming_the_request():
    server = ScriptedRsh(in_turn("get joint_pos", *["JOINT_POS 20 0.145864"] * 6))
    session = RshSession.open("127.0.0.1", server.port, "pw")
    try:
        with pytest.raises(FirmwareError, match="get joint_pos") as failed:
            session.get("joint_pos")
        assert failed.value.command == "get joint_pos"
    finally:
        session.close()
