"""What an operator reads about a G-code program before printing it and on its result page:
its line count, the estimated run time, and for five-axis programs the A/C angles
and the nozzle tip's speed along the path (workpiece coordinates).

Read through the one G-code reader (:mod:`app.gcode.reader`).  Three-axis programs are
timed by :func:`app.gcode.estimator.estimate_gcode`.  Five-axis programs (A or C words) are
timed line by line: ``G93`` inverse time gives each feed line 1 / F minutes; ``G94`` gives
length / F at the tip (``tcp``) or along the machine's linear axes; rapids are not counted
(a five-axis program's rapids are its approach and retract).  Lengths mm, angles degrees,
times s, speeds mm/s.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.gcode.estimator import estimate_gcode
from app.gcode.lines import read_lines
from app.gcode.reader import ReadOptions, arc_chord_budget, read_program

MAX_POINTS = 600
RAPID = 0


def _inverse_time_lines(text: str) -> set[int]:
    """1-based numbers of the lines read while G93 (inverse time) is active."""
    active, lines = False, set()
    for line in read_lines(text, strict=False):
        for code in line.g:
            if code == 93:
                active = True
            elif code == 94:
                active = False
        if active:
            lines.add(line.number)
    return lines


def _thin(n: int, limit: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, limit)).round().astype(int)) if n else np.zeros(0, int)


def rotary_profile(text: str, pivot_mm: Any = (0.0, 0.0, 0.0), tcp: bool = False,
                   max_points: int = MAX_POINTS, options: ReadOptions | None = None) -> dict[str, Any] | None:
    """Along the feed moves of a five-axis program: s_mm (cumulative tip path), a_deg, c_deg,
    tip_speed_mm_s (each (k,), k <= ``max_points``) and time_s (every feed line); None for a
    program without A/C motion.  ``tcp``: X Y Z are already the tip in workpiece coordinates
    (LinuxCNC TCP mode); otherwise machine coordinates about ``pivot_mm``.  With the
    program's dispense commands in ``options``, only the dispensing moves count (the path,
    not the approach)."""
    from app.five_axis.kinematics import machine_to_workpiece

    program = read_program(text, options or ReadOptions())
    if program.count == 0 or not np.any(np.abs(program.rotary) > 1e-12):
        return None
    feed = program.motion != RAPID
    feed &= ~program.home
    every_feed = feed.copy()
    if (feed & program.dispense).any():
        feed &= program.dispense
    if not feed.any():
        return None
    ends, starts = program.end[:, :3], program.start[:, :3]
    rot = np.radians(program.rotary)
    before = np.vstack([np.zeros((1, 2)), rot[:-1]])
    if tcp:
        tip_end, tip_start = ends, starts
    else:
        pivot = np.asarray(pivot_mm, float)
        tip_end = machine_to_workpiece(ends, rot[:, 0], rot[:, 1], pivot)
        tip_start = machine_to_workpiece(starts, before[:, 0], before[:, 1], pivot)
    step = np.linalg.norm(tip_end - tip_start, axis=1)
    inverse = np.isin(program.line, sorted(_inverse_time_lines(text)))
    rate = np.maximum(program.feed_mm_s, 1e-12)  # the reader's F / 60
    linear = np.linalg.norm(ends - starts, axis=1)
    dt = np.where(inverse, 1.0 / rate, (step if tcp else linear) / rate)
    idx = np.flatnonzero(feed)
    s = np.cumsum(step[idx])
    speed = np.divide(step[idx], dt[idx], out=np.zeros(len(idx)), where=dt[idx] > 0)
    keep = _thin(len(idx), max_points)
    return {"s_mm": s[keep].tolist(), "a_deg": program.rotary[idx[keep], 0].tolist(),
            "c_deg": program.rotary[idx[keep], 1].tolist(), "tip_speed_mm_s": speed[keep].tolist(),
            "time_s": float(dt[every_feed].sum()), "points": int(len(idx)),
            "tip_speed_max_mm_s": float(speed.max()) if len(speed) else 0.0}


def program_summary(text: str, pivot_mm: Any = (0.0, 0.0, 0.0), tcp: bool = False,
                    dispense_on: str | None = None, dispense_off: str | None = None,
                    max_arc_chords: int | None = None) -> dict[str, Any]:
    """``{lines, time_s, timing, rotary}`` of a G-code text (see the module doc);
    ``time_s`` of a five-axis program counts every feed line, its profile the dispensing ones.
    Its arcs may need at most ``max_arc_chords`` chords (default: the budget of the text's
    size, :func:`app.gcode.reader.arc_chord_budget`), counted before any is made
    (:class:`app.gcode.reader.ArcBudgetError` naming the line beyond it)."""
    lines = len(text.splitlines())
    options = ReadOptions(dispense_on=dispense_on, dispense_off=dispense_off, max_arc_chords=max_arc_chords)
    rotary = rotary_profile(text, pivot_mm, tcp, options=options)
    if rotary is not None:
        time_s, timing = rotary["time_s"], "five-axis feed lines (G93 inverse time / G94 feed), rapids not counted"
    else:
        time_s = estimate_gcode(text, max_arc_chords=max_arc_chords).total_s
        timing = "app.gcode.estimator (trapezoids, junction deviation)"
    return {"lines": lines, "time_s": float(time_s),
            "timing": timing, "rotary": rotary}


def program_summary_file(path: str, pivot_mm: Any = (0.0, 0.0, 0.0), tcp: bool = False,
                         dispense_on: str | None = None, dispense_off: str | None = None) -> dict[str, Any]:
    """:func:`program_summary` of the program stored at ``path`` (UTF-8, undecodable bytes
    replaced), with the arc budget of its size: what a bounded child process computes for
    a program too large to summarise in a request (:func:`app.runtime.isolated.call_isolated`)."""
    with open(path, "rb") as handle:
        data = handle.read()
    text = data.decode("utf-8", errors="replace")
    return program_summary(text, pivot_mm, tcp, dispense_on, dispense_off, arc_chord_budget(len(data)))
