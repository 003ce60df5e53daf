"""The cycle collector's pause around a bulk import: re-entrant across threads, and it
leaves the collector as it found it."""

from __future__ import annotations

import gc
import threading

from app.parts.traces import collection_paused


def test_the_collector_resumes_when_the_last_of_overlapping_pauses_ends():
    assert gc.isenabled()
    first_in, second_done, release = threading.Event(), threading.Event(), threading.Event()
    seen: list[bool] = []

    def first() -> None:
        with collection_paused():
            first_in.set()
            release.wait(5)
            seen.append(gc.isenabled())

    worker = threading.Thread(target=first)
    worker.start()
    assert first_in.wait(5)
    with collection_paused():
        assert not gc.isenabled()
    second_done.set()
    assert not gc.isenabled()  # the first pause still holds
    release.set()
    worker.join(5)
    assert seen == [False] and gc.isenabled()


def test_a_collector_disabled_before_stays_disabled():
    gc.disable()
    try:
        with collection_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()
