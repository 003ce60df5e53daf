"""Program warp: every printing move at its standoff on the surface, the proved chord bound
holding on every emitted piece (checked densely against the analytic surface), travel lifted,
extrusion conserved, moves outside the measured region refused naming the line."""

from __future__ import annotations

import numpy as np
import pytest

from app.circuits.errors import WarpError
from app.circuits.heightfield import HeightField
from app.circuits.warp import WarpOptions, fixed_split_error, warp_program
from app.gcode.lines import read_lines


def h(x, y):
    """A cubic surface: the bicubic interpolating spline reproduces it exactly."""
    return 3.0 + 0.002 * x**2 - 0.0004 * x * y + 0.0001 * y**3 / 10


@pytest.fixture(scope="module")
def surface() -> HeightField:
    x, y = np.linspace(0, 60, 13), np.linspace(0, 40, 9)
    X, Y = np.meshgrid(x, y, indexing="ij")
    return HeightField(x, y, h(X, Y))


PROGRAM = """; a mecode-like program
G21
G91
M83
G0 X5 Y5
G1 Z0.2
M106
G1 X40 Y10 E1.0 F600
G1 X5 Y20 E0.5
M107
G0 X-30 Y-10
G1 X20 Y0 E0.4
"""


def _moves(text):
    pos, out = np.zeros(3), []
    for ln in read_lines(text):
        if ln.codes("G") and ln.codes("G")[0] in (0.0, 1.0):
            new = pos.copy()
            for i, ax in enumerate("XYZ"):
                if ln.get(ax) is not None:
                    new[i] = ln.get(ax)
            out.append((ln.codes("G")[0], pos.copy(), new.copy(), ln.get("E")))
            pos = new
    return out


def test_printing_moves_lie_at_the_standoff_within_the_proved_bound(surface):
    result = warp_program(PROGRAM, surface, WarpOptions(standoff_mm=0.1, chord_error_mm=0.002))
    assert result.printing_moves == 3 and result.max_chord_bound_mm <= 0.002
    moves = _moves(result.text)
    printing = [m for m in moves if m[0] == 1.0 and m[3] is not None]
    assert sum(m[3] for m in printing) == pytest.approx(1.9, abs=1e-4)   # extrusion conserved
    worst = 0.0
    for _, a, b, _ in printing:
        assert b[2] == pytest.approx(h(b[0], b[1]) + 0.1, abs=1e-4)     # 4 decimals written
        t = np.linspace(0, 1, 51)
        p = a[None, :] + t[:, None] * (b - a)[None, :]
        worst = max(worst, np.abs(p[:, 2] - (h(p[:, 0], p[:, 1]) + 0.1)).max())
    assert worst <= 0.002 + 1e-4
    travel = [m for m in moves if m[0] == 0.0 and (m[1][:2] != m[2][:2]).any()]
    assert all(m[2][2] >= surface.z.max() + 2.0 - 1e-9 for m in travel[1:])   # lifted after the first print


def test_a_move_outside_the_probed_area_is_refused_naming_its_line(surface):
    program = PROGRAM + "G1 X50 Y0 E0.1\n"
    with pytest.raises(WarpError, match="line 13"):
        warp_program(program, surface, WarpOptions(standoff_mm=0.1))
    allowed = warp_program(program, surface, WarpOptions(standoff_mm=0.1, allow_outside=True))
    assert allowed.printing_moves == 4


def test_arcs_are_split_within_their_chord_and_warped(surface):
    # a CW half circle about (30, 20), radius 10, by I/J; then a CCW quarter by R; extruding
    program = "G21\nG90\nM83\nG0 X20 Y20\nG2 X40 Y20 I10 J0 E2.0 F600\nG3 X30 Y30 R10 E1.0\n"
    result = warp_program(program, surface, WarpOptions(standoff_mm=0.1, arc_chord_mm=0.001))
    moves = [m for m in _moves(result.text) if m[0] == 1.0 and m[3] is not None]
    assert sum(m[3] for m in moves) == pytest.approx(3.0, abs=1e-4)
    ends = np.array([m[2] for m in moves])
    first = ends[np.linalg.norm(ends[:, :2] - [40, 20], axis=1).argmin() + 1:]
    half = ends[: len(ends) - len(first)]
    # the half circle passes above the centre (CW from the left end): y >= 20; every vertex on the circle
    assert half[:, 1].min() >= 20 - 1e-6 and half[:, 1].max() == pytest.approx(30, abs=0.01)
    np.testing.assert_allclose(np.hypot(half[:, 0] - 30, half[:, 1] - 20), 10, atol=1e-4)
    # the R arc from (40, 20) to (30, 30), CCW, shorter: centre (30, 20)
    np.testing.assert_allclose(np.hypot(first[:, 0] - 30, first[:, 1] - 20), 10, atol=1e-4)
    np.testing.assert_allclose(ends[:, 2], h(ends[:, 0], ends[:, 1]) + 0.1, atol=1e-4)
    # chords of the arc: sagitta <= arc_chord_mm, so vertices are at most 2 * sqrt(2 r d) apart
    gaps = np.linalg.norm(np.diff(ends[:, :2], axis=0), axis=1)
    assert gaps.max() <= 2 * np.sqrt(2 * 10 * 0.001) + 1e-6


def test_arcs_outside_the_xy_plane_are_refused_naming_the_line(surface):
    with pytest.raises(WarpError, match="line 2: G18"):
        warp_program("G1 X10 Y10\nG18\nG2 X20 Y10 I5 K0 E1\n", surface)


def test_fixed_length_split_leaves_a_larger_error_than_ours(surface):
    pieces, worst = fixed_split_error(PROGRAM, surface, split_mm=5.0, standoff_mm=0.1)
    ours = warp_program(PROGRAM, surface, WarpOptions(standoff_mm=0.1, chord_error_mm=0.002))
    assert worst > 0.002 >= ours.max_chord_bound_mm
    assert pieces > 0


def test_curvature_bound_is_an_upper_bound(surface):
    rng = np.random.default_rng(0)
    x0, y0 = rng.uniform(0, 60, 200), rng.uniform(0, 40, 200)
    x1, y1 = rng.uniform(0, 60, 200), rng.uniform(0, 40, 200)
    bound = surface.curvature_bound(x0, y0, x1, y1)
    t = np.linspace(0, 1, 201)
    for k in range(200):
        d = np.array([x1[k] - x0[k], y1[k] - y0[k]])
        L = np.linalg.norm(d)
        s = t * L
        z = h(x0[k] + t * d[0], y0[k] + t * d[1])
        second = np.gradient(np.gradient(z, s), s)[2:-2]
        assert np.abs(second).max() <= bound[k] * (1 + 1e-6) + 1e-9


def test_arc_chords_beyond_the_programs_budget_are_refused_before_they_are_made(surface):
    import time
    import tracemalloc

    circles = "G21\nG90\nG0 X30 Y20\n" + "G2 X30 Y20 I5 J0 E1 F600\n" * 4      # 4 full circles, ~120 bytes
    opts = WarpOptions(standoff_mm=0.1, arc_chord_mm=1e-12)
    c0 = time.process_time()
    with pytest.raises(WarpError, match="line 6: the arcs need more than") as err:
        warp_program(circles, surface, opts)
    cpu = time.process_time() - c0
    assert err.value.field == "arc_chord_mm" and err.value.value["line"] == 6      # the third circle
    tracemalloc.start()
    with pytest.raises(WarpError):
        warp_program(circles, surface, opts)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert cpu < 1.0 and peak < 50e6, (cpu, peak)
    # at a sensible sagitta the same circles are warped
    assert warp_program(circles, surface, WarpOptions(standoff_mm=0.1, arc_chord_mm=1e-3)).printing_moves > 4
