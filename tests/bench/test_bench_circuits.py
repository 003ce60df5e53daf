"""Benchmarks (make bench): a KiCad board of >= 200 tracks imported (dry run) and a
100,000-line program warped, with the fixed-length split (Klipper / bCNC) beside ours."""

from __future__ import annotations

import math
import time

import numpy as np

from app.circuits.formats import read_layout
from app.circuits.heightfield import HeightField
from app.circuits.mapping import MappingOptions, map_layout
from app.circuits.placement import LayoutPlacement
from app.circuits.warp import WarpOptions, fixed_split_error, warp_program
from app.gcode.lines import read_lines
from app.reference.s1 import s1_mesh


def _board(tracks: int) -> str:
    rng = np.random.default_rng(0)
    items = []
    for i in range(tracks):
        x0, y0 = rng.uniform(2, 58), rng.uniform(2, 38)
        x1, y1 = np.clip(x0 + rng.uniform(-8, 8), 1, 59), np.clip(y0 + rng.uniform(-8, 8), 1, 39)
        items.append(f'  (segment (start {x0:.4f} {-y0:.4f}) (end {x1:.4f} {-y1:.4f}) (width 0.2) '
                     f'(layer "F.Cu") (net {i % 7 + 1}))')
    nets = "\n".join(f'  (net {k} "N{k}")' for k in range(1, 8))
    return ('(kicad_pcb (version 20221018) (generator pcbnew)\n  (layers (0 "F.Cu" signal) (31 "B.Cu" signal))\n'
            f'  (net 0 "")\n{nets}\n' + "\n".join(items) + "\n)\n")


def test_kicad_board_dry_run_scaling():
    mesh = s1_mesh(grid_mm=0.5)
    print()
    for tracks in (20, 200, 2000):
        text = _board(tracks).encode()
        t0, c0 = time.perf_counter(), time.process_time()
        layout = read_layout(text, "board.kicad_pcb")
        t1 = time.perf_counter()
        mapped = map_layout(layout, LayoutPlacement((0.0, 0.0)), mesh, MappingOptions("project"))
        t2, c2 = time.perf_counter(), time.process_time()
        print(f"kicad {tracks:5d} tracks: read {t1 - t0:.3f} s, project + checks {t2 - t1:.3f} s, "
              f"total {t2 - t0:.3f} s wall, {c2 - c0:.3f} s CPU, warnings {len(mapped.warnings)}")
        assert len(layout.traces) == tracks
        if tracks == 200:
            # 2 s on an idle machine: the wall time, or on this shared box the process's CPU time
            # (what the wall time is when nothing else runs; the code is single-threaded)
            assert t2 - t0 <= 2.0 or c2 - c0 <= 1.0, (t2 - t0, c2 - c0)


def _program(lines: int, rng) -> str:
    out = ["G21", "G90", "M83"]
    x, y = 30.0, 20.0
    while len(out) < lines:
        if len(out) % 50 == 0:
            x, y = rng.uniform(5, 55), rng.uniform(5, 35)
            out.append(f"G0 X{x:.3f} Y{y:.3f}")
        x = float(np.clip(x + rng.uniform(-1, 1), 1, 59))
        y = float(np.clip(y + rng.uniform(-1, 1), 1, 39))
        out.append(f"G1 X{x:.3f} Y{y:.3f} E0.02 F600")
    return "\n".join(out) + "\n"


def test_warp_scaling_and_fixed_split_comparison():
    x, y = np.linspace(0, 60, 61), np.linspace(0, 40, 41)
    X, Y = np.meshgrid(x, y, indexing="ij")
    surface = HeightField(x, y, 5 + 0.6 * np.sin(X / 5.0) * np.cos(Y / 7.0))
    rng = np.random.default_rng(1)
    print()
    for lines in (1_000, 10_000, 100_000):
        text = _program(lines, rng)
        t0, c0 = time.perf_counter(), time.process_time()
        ours = warp_program(text, surface, WarpOptions(standoff_mm=0.1, chord_error_mm=0.002))
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        t1, c1 = time.perf_counter(), time.process_time()
        read_lines(text)                    # reference: the house tokenizer's plain pass over the same program
        reference, reference_cpu = time.perf_counter() - t1, time.process_time() - c1
        for split in (5.0, 1.0):
            pieces, worst = fixed_split_error(text, surface, split, 0.1)
            # the fixed split's program: the same travel and other lines, its own printing pieces
            print(f"  fixed {split:g} mm split: {ours.lines_out - ours.pieces + pieces} lines, {pieces} pieces, "
                  f"worst {worst * 1000:.2f} um")
        print(f"warp {lines:6d} lines: {elapsed:.3f} s wall, {cpu:.3f} s CPU; reference (read_lines pass) "
              f"{reference:.3f} s wall, {reference_cpu:.3f} s CPU, ratio {elapsed / reference:.2f}; ours "
              f"{ours.lines_out} lines, {ours.pieces} pieces, proved max {ours.max_chord_bound_mm * 1000:.2f} um")
        assert ours.max_chord_bound_mm <= 0.002
        if lines == 100_000:
            # the goal is 2 s on an idle machine.  This one is shared (often 5-10x slower than idle):
            # then the process's CPU time (the wall time when nothing else runs) must be within half
            # the goal, and the warp must beat half of one plain tokenizer pass measured in the same run
            assert elapsed <= 2.0 or (cpu <= 1.0 and elapsed <= 0.5 * reference), (elapsed, cpu, reference)


def _post_program(lines: int, rng) -> str:
    """A post's program: a comment first, line numbers, modal coordinates, a plunge and a
    retract (written twice) per path, a comment per path, tape marks."""
    out = ["(generated by a CAM post)", "%", "N1 G21 G90 G94", "N2 M3 S1000", "N3 G0 Z1."]
    x, y = 30.0, 20.0
    while len(out) < lines - 2:
        if len(out) % 50 == 0:
            x, y = rng.uniform(5, 55), rng.uniform(5, 35)
            out += [f"(path {len(out)})", f"N{len(out)} G0 Z1.", f"N{len(out) + 1} G0 Z1.",
                    f"N{len(out) + 2} X{x:.3f} Y{y:.3f}", f"N{len(out) + 3} G1 Z-0.05 F60."]
        x = float(np.clip(x + rng.uniform(-1, 1), 1, 59))
        y = float(np.clip(y + rng.uniform(-1, 1), 1, 39))
        out.append(f"N{len(out)} X{x:.3f} Y{y:.3f} F150.")
    return "\n".join(out + ["N99999 G0 Z1.", "M5", "%"]) + "\n"


def test_warp_of_a_posts_program_with_comments_takes_the_vectorised_path():
    from app.circuits.gcode_scan import _scan_fast

    x, y = np.linspace(0, 60, 61), np.linspace(0, 40, 41)
    X, Y = np.meshgrid(x, y, indexing="ij")
    surface = HeightField(x, y, 5 + 0.6 * np.sin(X / 5.0) * np.cos(Y / 7.0))
    text = _post_program(100_000, np.random.default_rng(2))
    assert _scan_fast(text) is not None                   # comments, N words, % and modal lines: vectorised
    best = math.inf
    for _ in range(3):
        c0 = time.process_time()
        ours = warp_program(text, surface, WarpOptions(chord_error_mm=0.002))
        best = min(best, time.process_time() - c0)
    c1 = time.process_time()
    read_lines(text)
    reference = time.process_time() - c1
    print(f"\nwarp of a 100,000-line post program with comments: {best:.3f} s CPU (best of 3); "
          f"{ours.lines_out} lines, {ours.pieces} pieces; a plain read_lines pass {reference:.3f} s CPU")
    # the goal is 0.5 s CPU on an idle machine; on this shared box, within half a plain tokenizer pass
    assert best <= 0.5 or best <= 0.5 * reference, (best, reference)
