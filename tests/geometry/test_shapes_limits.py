"""Trace size limits: refused before any sampling, naming the field; the estimate of the
tool-location points matches the analytic count of a circle."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from app.geometry.cl_points import cl_points
from app.geometry.errors import GeometryError
from app.geometry.shapes import trace_curve
from app.geometry.shapes_limits import (
    MAX_CL_POINTS,
    MAX_LENGTH_MM,
    MAX_POINTS,
    _lengths_and_needs,
    curves_clearly_within_limits,
    estimated_cl_points,
)
from app.geometry.tolerance import Tolerance
from app.reference.boards import board_traces, dome_part


@pytest.mark.parametrize(("geometry", "field"), [
    ({"type": "arc", "center": [0, 0], "radius": 1e9, "start_deg": 0, "end_deg": 90}, "geometry.radius"),
    ({"type": "arc", "center": [0, 0], "radius": 1e5, "start_deg": 0, "end_deg": 360}, "geometry"),
    ({"type": "polyline", "points": [[i * 0.01, 0.0] for i in range(MAX_POINTS + 1)]}, "geometry.points"),
    ({"type": "line", "start": [0, 0], "end": [2e6, 0]}, "geometry.control_points.1"),
    # 477 turns of a 1 mm circle: 3 m long, but ~335,000 points at a 0.01 um chord
    ({"type": "nurbs", "degree": 3, "control_points": [[math.cos(t), math.sin(t)] for t in
                                                       np.linspace(0, 3000, 9000)]}, "geometry"),
])
def test_oversized_traces_are_refused_at_once_naming_the_field(geometry, field):
    started = time.perf_counter()
    with pytest.raises(GeometryError) as refused:
        trace_curve(geometry, tolerance=Tolerance(chord_mm=1e-5))
    assert refused.value.field == field
    assert time.perf_counter() - started < 5.0  # generous for a loaded machine; was 20-78 s


@pytest.mark.parametrize("radius", [1.0, 30.0, 500.0])
def test_the_sampling_estimate_matches_the_chordal_count_of_a_circle(radius):
    chord = 0.001
    curve = trace_curve({"type": "arc", "center": [0, 0], "radius": radius, "start_deg": 0, "end_deg": 360})
    analytic = 2 * math.pi * math.sqrt(radius / (8 * chord))  # segments of sagitta = chord
    estimate = estimated_cl_points(curve, chord)
    assert analytic <= estimate <= analytic + 6  # + one point per knot span
    assert cl_points(curve, chord).points.shape[0] <= 1.5 * estimate


def test_a_batch_of_curves_passes_the_limits_exactly_when_each_does_with_a_margin():
    chord = Tolerance().chord_mm
    board = [trace_curve(g, check_size=False) for g in board_traces(dome_part(), 120)]
    curved = [c for c in board if c.degree > 1]
    length, needed = _lengths_and_needs(curved, chord)
    np.testing.assert_allclose(length, [c.length for c in curved], rtol=1e-12)
    np.testing.assert_allclose(needed, [estimated_cl_points(c, chord) for c in curved], rtol=1e-12)
    assert curves_clearly_within_limits(board, chord, 1e-6)
    # at a finer chord: a circle whose sampling needs just over the limit, one under it; a line
    # just under the length limit, one at it; a line shorter than the minimum length
    chord = 1e-7
    radius = (MAX_CL_POINTS / (2 * math.pi)) ** 2 * 8 * chord
    circle = {"type": "arc", "center": [0, 0], "start_deg": 0, "end_deg": 360}
    for geometry, passes in [({**circle, "radius": radius * 1.01}, False), ({**circle, "radius": radius * 0.9}, True),
                             ({"type": "line", "start": [0, 0], "end": [MAX_LENGTH_MM * 0.99, 0]}, True),
                             ({"type": "line", "start": [0, 0], "end": [MAX_LENGTH_MM, 0]}, False),
                             ({"type": "line", "start": [0, 0], "end": [5e-4, 0]}, False)]:
        curve = trace_curve(geometry, check_size=False)
        assert curves_clearly_within_limits([*board[:5], curve], chord, 1e-3) is passes, geometry
        if not passes:  # the curve itself is refused or within the margin of a limit
            figures = (curve.length, estimated_cl_points(curve, chord))
            assert (figures[0] >= MAX_LENGTH_MM * (1 - 1e-6) or figures[1] >= MAX_CL_POINTS * (1 - 1e-6)
                    or figures[0] <= 1e-3 * (1 + 1e-6))
