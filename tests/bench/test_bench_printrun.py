"""Printrun's printcore streams 200, 2,000 and 20,000 lines to the mock Marlin over a
pseudo-terminal with 1 % of the lines damaged on the wire (0.5 % checksum, 0.5 % line
number): the executed stream must equal the program.  Reference in the same run: the same
program with no faults, so the ratio shows what the resends cost.

    make bench   # or: .venv/bin/python -m pytest tests/bench/test_bench_printrun.py -s -o addopts=""
"""

from __future__ import annotations

import itertools

from hardware.mock import MockWorld, register_world, unregister_world
from hardware.mock.expose import PtyBridge
from hardware.protocol import commands_sha256
from tests.hardware.mock.printrun_host import program, stream_with_printcore

_names = itertools.count()


def _run(lines: list[str], rate: float) -> tuple[float, dict[str, int], bool]:
    name = f"bench-printrun-{next(_names)}"
    world = register_world(name, MockWorld(dialect="marlin", keep_transcript=False))
    world.faults.checksum_rate = rate / 2
    world.faults.line_number_rate = rate / 2
    world.faults.seed = 20
    try:
        with PtyBridge(f"mock://{name}") as bridge:
            run = stream_with_printcore(bridge.path, lines, query_every_s=1.0, timeout_s=600)
        exact = world.transcript.digest() == commands_sha256(lines)
        return run.elapsed_s, dict(world.stats.faults), exact
    finally:
        unregister_world(name)


def test_printcore_resends_scale_and_stay_exact():
    print("\nlines   faults  faulty s  clean s  ratio  exact")
    for n in (200, 2000, 20000):
        lines = program(n)
        faulty_s, faults, exact = _run(lines, 0.01)
        clean_s, _, clean_exact = _run(lines, 0.0)
        damaged = faults.get("checksum", 0) + faults.get("line_number", 0)
        print(f"{n:6d}  {damaged:6d}  {faulty_s:8.2f}  {clean_s:7.2f}  {faulty_s / clean_s:5.2f}  {exact}")
        assert exact and clean_exact
        assert damaged >= n // 200
