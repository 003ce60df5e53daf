"""The console ring: sequence numbers, paging with ``after``, filters and what it forgot."""

from __future__ import annotations

import threading

import pytest

from hardware.console_log import MAX_TEXT, ConsoleLog


def test_pages_return_exactly_what_came_after_and_count_what_the_ring_forgot():
    log = ConsoleLog(capacity=5)
    for i in range(1, 4):
        log.record("sent", f"G1 X{i}")
    first = log.since(0)
    assert [e.seq for e in first.entries] == [1, 2, 3] and first.last_seq == 3 and first.dropped == 0
    assert log.since(first.last_seq).entries == [] and log.since(first.last_seq).last_seq == 3
    for i in range(4, 10):
        log.record("received", "ok")
    later = log.since(first.last_seq)
    assert [e.seq for e in later.entries] == [5, 6, 7, 8, 9]  # the ring holds 5 lines
    assert later.dropped == 1                                  # line 4 came and went unread
    assert log.since(9).dropped == 0 and log.since(0).dropped == 4


def test_filters_by_direction_and_text_still_advance_the_cursor():
    log = ConsoleLog()
    log.record("sent", "N1 M114*35")
    log.record("received", "X:1.00 Y:2.00 Z:3.00 E:0.00 Count X:80 Y:160 Z:1200")
    log.record("received", "ok N1")
    replies = log.since(0, direction="received")
    assert [e.text for e in replies.entries] == ["X:1.00 Y:2.00 Z:3.00 E:0.00 Count X:80 Y:160 Z:1200", "ok N1"]
    assert replies.last_seq == 3
    assert [e.seq for e in log.since(0, contains="m114").entries] == [1]
    assert log.since(0, contains="nothing like this").last_seq == 3  # looked at, none matched
    assert [e.seq for e in log.since(0, limit=2).entries] == [1, 2] and log.since(0, limit=2).last_seq == 2


def test_wire_bytes_become_lines_and_realtime_bytes_stay_readable():
    log = ConsoleLog()
    log.record_bytes("sent", b"N2 G1 X1*99\nN3 G1 X2*98\n")
    log.record_bytes("sent", b"\x18")
    log.record_bytes("received", b"x" * (MAX_TEXT + 50))
    texts = [e.text for e in log.since(0).entries]
    assert texts[:2] == ["N2 G1 X1*99", "N3 G1 X2*98"]
    assert texts[2] == repr("\x18") and len(texts[3]) == MAX_TEXT


def test_concurrent_writers_never_reuse_a_sequence_number():
    log = ConsoleLog(capacity=10_000)

    def write() -> None:
        for _ in range(1000):
            log.record("sent", "G1")
    threads = [threading.Thread(target=write) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    seqs = [e.seq for e in log.since(0, limit=10_000).entries]
    assert seqs == list(range(1, 4001))


def test_a_ring_needs_room_for_one_line():
    with pytest.raises(ValueError, match="capacity"):
        ConsoleLog(capacity=0)
