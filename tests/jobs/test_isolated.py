"""A function on user input in a bounded child: its memory limit, its time limit, its
cancellation (a client that went away) and its errors, each ending the child at once."""

from __future__ import annotations

import os
import time

import pytest

from app.domain.errors import Cancelled, InvalidInput, TooLarge
from app.runtime.isolated import call_isolated

MIB = 2 ** 20


def _allocate(mb: int) -> int:
    return len(bytearray(mb * MIB))


def _sleep_then_pid(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def _refuse(value: int) -> None:
    raise InvalidInput("no", field="files", value=value)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_the_answer_comes_from_another_process():
    assert call_isolated(_sleep_then_pid, 0.0, memory_bytes=64 * MIB, time_s=30, what="t") != os.getpid()
    assert call_isolated(_allocate, 32, memory_bytes=256 * MIB, time_s=30, what="t") == 32 * MIB


def test_past_its_memory_it_is_a_413_and_this_process_never_holds_it():
    with pytest.raises(TooLarge, match="256 MiB"):
        call_isolated(_allocate, 2048, memory_bytes=256 * MIB, time_s=30, what="the import")


def test_past_its_time_it_is_killed():
    started = time.monotonic()
    with pytest.raises(TooLarge, match="longer than 0.5 s"):
        call_isolated(_sleep_then_pid, 60.0, memory_bytes=64 * MIB, time_s=0.5, what="the import")
    assert time.monotonic() - started < 5.0


def _write_pid_then_sleep(path: str, seconds: float) -> None:
    with open(path, "w") as out:
        out.write(str(os.getpid()))
    time.sleep(seconds)


def test_a_cancel_kills_the_child_within_a_poll(tmp_path):
    pid_file = tmp_path / "pid"
    started = time.monotonic()
    with pytest.raises(Cancelled):
        call_isolated(_write_pid_then_sleep, str(pid_file), 60.0, memory_bytes=64 * MIB, time_s=60, what="t",
                      cancelled=lambda: pid_file.exists() and time.monotonic() - started > 0.3)
    assert time.monotonic() - started < 2.0
    assert not _alive(int(pid_file.read_text()))


def test_its_errors_are_raised_here_with_field_and_value():
    with pytest.raises(InvalidInput) as raised:
        call_isolated(_refuse, 7, memory_bytes=64 * MIB, time_s=30, what="t")
    assert (raised.value.field, raised.value.value) == ("files", 7)
