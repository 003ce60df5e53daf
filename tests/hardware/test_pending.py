"""PendingCommand / CommandResult: waiting, failures and error results."""

from __future__ import annotations

import threading

import pytest

from hardware.errors import FirmwareError, LinkError
from hardware.events import FirmwareErrorEvent, Ok, PositionReport
from hardware.pending import PendingCommand


def test_result_carries_replies_payload_and_timing():
    pending = PendingCommand(None, "M114", 7, b"N7 M114*1\n")
    report = PositionReport({"X": 1.0}, raw="X:1.00")
    pending.replies += [report, Ok(raw="ok N7 P15 B3")]
    threading.Timer(0.05, pending.finish, args=("ok",)).start()
    result = pending.result(2)
    assert result.payload is report and result.line_no == 7
    assert result.reply_lines == ("X:1.00", "ok N7 P15 B3")
    assert result.t_done >= result.t_sent and result.status == "ok"


def test_error_result_raises_unless_unchecked():
    pending = PendingCommand(None, "G5 X1", None, b"G5 X1\n")
    error = FirmwareErrorEvent("Unsupported command", 20, raw="error:20")
    pending.finish("error", error)
    with pytest.raises(FirmwareError) as info:
        pending.result(1)
    assert info.value.code == 20 and info.value.command == "G5 X1"
    assert pending.result(1, check=False).error is error


def test_failure_and_timeout():
    pending = PendingCommand(None, "G1 X1", 1, b"")
    with pytest.raises(LinkError):
        pending.result(0.01)
    pending.fail(LinkError("gone"))
    with pytest.raises(LinkError, match="gone"):
        pending.result(1)
