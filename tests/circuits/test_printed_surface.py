"""The measured surface of a circuit program and what each printed item records of it, on a
plane with a known deviation: analytic heights, sd, bounds and clearances."""

from __future__ import annotations

import numpy as np
import pytest

from app.circuits.strokes import fill_tip_strokes
from app.circuits.surface import MeasuredSurface, PrintedPoints


def _plane() -> MeasuredSurface:
    """z = 0.1 x (slope (0.1, 0)) + deviation 0.002 y, sd 0.001 (1 + x / 10); bound 3 sd."""
    def nominal(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return 0.1 * xy[:, 0], np.tile([0.1, 0.0], (len(xy), 1))

    def deviation(xy: np.ndarray, slope: np.ndarray, sd: bool) -> tuple[np.ndarray, np.ndarray | None]:
        assert np.allclose(slope, [0.1, 0.0])
        return 0.002 * xy[:, 1], 0.001 * (1 + xy[:, 0] / 10) if sd else None

    return MeasuredSurface(nominal, deviation, coverage=3.0)


def test_fills_sit_on_the_measured_surface_and_report_their_sd_and_bound():
    surface = _plane()
    square = np.array([[0, 0], [4, 0], [4, 2], [0, 2], [0, 0]], float)

    def drape(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([xy, 0.1 * xy[:, 0]])

    strokes = fill_tip_strokes(square, [], 0.2, drape, lambda xy: surface.at(xy)[0], 0.08)
    printed = PrintedPoints(surface)
    for s in strokes:
        assert s[:, 2] == pytest.approx(0.1 * s[:, 0] + 0.002 * s[:, 1] + 0.08, abs=1e-12)
        printed.add("pad 1", "pad", s, 0.08)
    row = printed.as_dict()["items"]["pad 1"]
    worst_x = max(float(s[:, 0].max()) for s in strokes)                 # 4 - half a line
    assert worst_x == pytest.approx(3.9)
    assert row["sd_mm"] == pytest.approx(0.001 * (1 + worst_x / 10))
    assert row["bound_mm"] == pytest.approx(3 * row["sd_mm"])
    assert row["clearance_min_mm"] == pytest.approx(0.08)
    assert printed.below(0.002) == [] and printed.as_dict()["bound_over_standoff"] == []


def test_a_point_below_the_surface_or_its_standoff_is_named():
    printed = PrintedPoints(_plane())
    printed.add("ok", "trace", np.array([[1.0, 1.0, 0.1 + 0.002 + 0.079]]), 0.08)        # 1 um low: tolerated
    printed.add("low", "trace", np.array([[2.0, 0.0, 0.2 + 0.07]]), 0.08)               # 10 um low
    printed.add("under", "area", np.array([[0.0, 5.0, 0.01 - 0.001]]), 0.003)           # 1 um under the surface
    below = dict((n, c) for n, c, _ in printed.below(0.002))
    assert set(below) == {"low", "under"}
    assert below["low"] == pytest.approx(0.07) and below["under"] == pytest.approx(-0.001)
    assert printed.as_dict()["bound_over_standoff"] == ["under"]        # its bound 3 x 1 um reaches its 3 um standoff


def test_the_sd_is_judged_every_step_along_a_stroke_and_at_its_end():
    plane = _plane()
    judged: list[np.ndarray] = []

    def deviation(xy: np.ndarray, slope: np.ndarray, sd: bool) -> tuple[np.ndarray, np.ndarray | None]:
        if sd:
            judged.append(xy.copy())
        return plane.deviation(xy, slope, sd)

    printed = PrintedPoints(MeasuredSurface(plane.nominal, deviation, coverage=3.0, sd_step_mm=1.0))
    x = np.arange(0.0, 4.0, 0.25)                                     # 0 .. 3.75 mm, 16 points
    printed.add("trace", "trace", np.column_stack([x, np.zeros_like(x), 0.1 * x + 0.05]), 0.05)
    printed.add("trace", "trace", np.column_stack([x, np.ones_like(x), 0.1 * x + 0.052]), 0.05)   # 1 mm over
    assert printed.as_dict()["items"]["trace"]["sd_mm"] == pytest.approx(0.001 * 1.375)
    (at,) = judged                                                    # both strokes judged in one evaluation
    assert at[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 3.75] * 2 and at[:, 1].tolist() == [0.0] * 5 + [1.0] * 5
    assert printed.as_dict()["items"]["trace"]["clearance_min_mm"] == pytest.approx(0.05)
