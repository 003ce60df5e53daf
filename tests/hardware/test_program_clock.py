"""The program clock: elapsed wall time, held time left out of the rate, time left."""

from __future__ import annotations

import pytest

from hardware import program_clock
from hardware.program_clock import MIN_LINES, ProgramClock


class FakeTime:
    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now

    def time(self) -> float:
        return 1.7e9 + self.now


@pytest.fixture
def clock_time(monkeypatch):
    fake = FakeTime()
    monkeypatch.setattr(program_clock.time, "monotonic", fake.monotonic)
    monkeypatch.setattr(program_clock.time, "time", fake.time)
    return fake


def test_time_left_is_the_running_line_rate_times_the_lines_left(clock_time):
    clock = ProgramClock()
    assert clock.elapsed_s() is None and clock.eta_s(0, 100) is None
    clock.start(start_line=0)
    clock_time.now += 10.0
    assert clock.eta_s(MIN_LINES, 1000) == pytest.approx(10.0 / MIN_LINES * (1000 - MIN_LINES))
    clock.pause()
    clock_time.now += 50.0                              # held: the wall clock runs, the rate does not change
    assert clock.elapsed_s() == pytest.approx(60.0) and clock.running_s() == pytest.approx(10.0)
    assert clock.eta_s(MIN_LINES, 1000) == pytest.approx(10.0 / MIN_LINES * (1000 - MIN_LINES))
    clock.resume()
    clock_time.now += 10.0
    assert clock.running_s() == pytest.approx(20.0)
    assert clock.eta_s(2 * MIN_LINES, 2 * MIN_LINES) == 0.0


def test_no_estimate_from_too_few_lines_and_a_resume_counts_its_own_lines(clock_time):
    clock = ProgramClock()
    clock.start(start_line=500)                         # a resumed program: lines before 500 ran earlier
    clock_time.now += 0.5
    assert clock.eta_s(505, 1000) is None               # 5 lines in 0.5 s mean little
    clock_time.now += 4.5
    assert clock.eta_s(550, 1000) == pytest.approx(5.0 / 50 * 450)


def test_a_plan_weights_the_time_left_by_each_command_s_planned_duration(clock_time):
    clock = ProgramClock()
    plan = [0.0, 10.0] + [10.0 + 0.1 * k for k in range(1, 101)]  # one 10 s move, then 100 moves of 0.1 s
    clock.expect(plan)
    clock.start(0)
    clock_time.now += 24.0                                       # the machine runs at half the planned speed
    assert clock.eta_s(51, 101) == pytest.approx(24.0 * (20.0 - 15.0) / 15.0)  # 8 s, where the line rate says 23.5
    clock.start(0)                                               # the plan was for one program only
    clock_time.now += 24.0
    assert clock.eta_s(51, 101) == pytest.approx(24.0 / 51 * 50)


def test_a_plan_that_does_not_fit_the_program_is_not_used(clock_time):
    clock = ProgramClock()
    clock.expect([0.0, 1.0, 2.0])
    clock.start(0)
    clock_time.now += 30.0
    assert clock.eta_s(30, 60) == pytest.approx(30.0)
