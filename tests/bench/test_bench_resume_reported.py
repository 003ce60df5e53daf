"""What a resume after a controller RESET repeats, located by the last real position the
controller reported while streaming (grbl ``?``, Marlin ``S000``; ten reports a second),
against the planner bound measured at the same cut in the same run (the reference: what the
resume repeated before position reports).  The mock runs in real time; a reset is pressed at
several moments of a program of 40 short moves (0.58 mm at 10 mm/s) and of one of five long
moves (6-8 mm at 20 mm/s).  Every row asserts the truth: nothing skipped, the executed stream
is the program with the repeats, and what ran twice is within the stated bound.

    .venv/bin/python -m pytest tests/bench/test_bench_resume_reported.py -s -o addopts="" -p no:cacheprovider
"""

from __future__ import annotations

import itertools

from hardware.mock import MockWorld, register_world, unregister_world
from hardware.resume import end_positions
from tests.hardware.test_resume_reported import PROFILES, long_moves, path_mm, reset_and_resume, short_moves

_names = itertools.count()


def _make_world(**options):
    name = f"bench-resume-{next(_names)}"
    world = register_world(name, MockWorld(**options))
    _made.append(name)
    return f"mock://{name}", world


_made: list[str] = []


def test_bench_resume_after_reset_by_reported_position():
    rows = []
    try:
        for dialect in ("grbl", "marlin"):
            for label, lines, cuts in (("40 short", short_moves(dialect), (0.4, 0.8, 1.2, 1.6, 2.0)),
                                       ("5 long", long_moves(dialect), (0.3, 0.6, 0.9, 1.2, 1.5))):
                for cut in cuts:
                    found, bound, ran, where, executed, expected, commands = reset_and_resume(
                        _make_world, dialect, lines, cut, realtime_reports=dialect == "marlin")
                    p = PROFILES[dialect]
                    ends = end_positions(commands, p.dispense_on, p.dispense_off)
                    assert found.basis == "reported position" and found.start <= ran and executed == expected
                    twice_mm = path_mm(ends, found.start, ran, where)
                    assert ran - found.start < found.repeat_bound_lines
                    assert twice_mm <= found.repeat_bound_mm + 0.01
                    first = next(k for k, e in enumerate(ends) if e is not None) + 1  # before it: not placeable
                    planner_mm = path_mm(ends, max(bound, first), ran, where)
                    rows.append((dialect, label, cut, ran, found.start, ran - found.start, found.repeat_bound_lines,
                                 twice_mm, found.repeat_bound_mm, bound, ran - bound, planner_mm))
    finally:
        for name in _made:
            unregister_world(name)
    print()
    print("| dialect | program | reset at s | completed | resume at | repeated lines | bound lines | "
          "repeated mm | bound mm | planner bound at | planner repeats | planner mm |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]:.1f} | {r[3]} | {r[4]} | {r[5]} | {r[6]} | {r[7]:.2f} | {r[8]:.2f} | "
              f"{r[9]} | {r[10]} | {r[11]:.2f} |")
    repeats = sum(r[5] for r in rows)
    planner = sum(r[10] for r in rows)
    print(f"repeated commands: {repeats} by reported position, {planner} by the planner bound "
          f"(ratio {repeats / max(planner, 1):.2f}); worst bound {max(r[6] for r in rows)} lines, "
          f"{max(r[8] for r in rows):.2f} mm")
