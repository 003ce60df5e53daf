"""Bench: the sequential field planner's CPU on a whole board, in the core (no service).

Run: .venv/bin/python -m pytest tests/bench/test_bench_sequential_board.py -s -o addopts="" -q
(``SEQUENTIAL_BOARD_TRACES``, default 1000).

The 150 x 100 mm dome (:func:`app.reference.boards.dome_part`) with that many traces
(:func:`app.reference.boards.board_traces`), an as-made part (seed 11, +-0.15 mm, shortest
wavelength 15 mm) touched with 1 um probe noise (seeded), the process told to the planner
(A 0.15 mm, lambda 15 mm, target 5 um); :func:`app.reconstruction.field_sequential.plan_sequential`
timed with the process CPU clock (its BLAS threads included): pilot, rounds, verification.
Printed: CPU and wall s, the stations per round, why the rounds ended, the touches, the
run's bound and the load average (the box is shared: trust CPU over wall); then the prior
the verdict learned from the stations and the sum of the traces' bounds, every digit (two
builds of the planner compared: the same numbers to rounding)."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from app.probing.selection import PlanParams
from app.reconstruction.field_learning import NAMES
from app.reconstruction.field_sequential import plan_sequential
from app.reference.boards import as_made_board, board_path, board_traces, dome_part

TRACES = int(os.environ.get("SEQUENTIAL_BOARD_TRACES", "1000"))


@pytest.mark.timeout(7200)
def test_sequential_planner_cpu_on_a_board():
    part = dome_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, TRACES)]
    made = as_made_board(part, 11)
    rng = np.random.default_rng(5)

    def measure(xy: np.ndarray) -> np.ndarray:
        return made.machining_error(xy) + rng.normal(0.0, 0.001, len(xy))
    c0, t0 = time.process_time(), time.perf_counter()
    result = plan_sequential(paths, PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0), measure)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    print(f"\n{TRACES} traces: plan_sequential CPU {cpu:.1f} s, wall {wall:.1f} s; rounds {result.rounds}, stopped "
          f"{result.stopped!r}, touches {result.touches}, run's bound {result.check.bound_mm * 1e3:.2f} um; "
          f"load average {os.getloadavg()[0]:.1f}")
    learned = result.check.learned or {}
    print("learned from the stations: " + ", ".join(f"{k} {learned[k]['value']!r}" for k in NAMES if k in learned)
          + f"; trace bounds sum {sum(result.trace_bounds_mm)!r} mm")
    assert result.touches > 0 and np.isfinite(result.check.bound_mm)
