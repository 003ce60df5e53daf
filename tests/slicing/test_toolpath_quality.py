"""Toolpath quality: paths simplified to the machine's resolution (no repeated, zero-length or
sub-resolution moves, shape kept within the resolution), thin walls printed with one bead."""

from __future__ import annotations

import dataclasses
import math
import re

import manifold3d
import numpy as np
import pytest
import shapely

from app.gcode.fdm import FdmParams, bead_area_mm2, write_fdm_gcode
from app.slicing import SliceParams, slice_mesh
from app.slicing.toolpath import RESOLUTION_MM, ToolpathParams, plan_toolpath, simplify_paths
from tests.helpers.real_parts import cad_part, thin_tube
from tests.slicing.conftest import to_trimesh

MOVE = re.compile(r"^G1 X(-?[\d.]+) Y(-?[\d.]+)(?: F[\d.]+)?(?: E(-?[\d.]+))?$")


def xy_moves(gcode: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The process section's X Y moves: (m, 2) targets, (m,) bool extruding, the lines."""
    lines = [line for line in gcode.split("; process", 1)[1].splitlines() if MOVE.match(line)]
    targets = np.array([[float(v) for v in MOVE.match(line).groups()[:2]] for line in lines])
    extruding = np.array([MOVE.match(line).group(3) is not None for line in lines])
    return targets, extruding, lines


@pytest.fixture(scope="module")
def fine_part():
    """A real-shaped CAD part refined (53,568 faces: contours of ~0.02-0.1 mm segments, many
    sliced across facet corners), three layers of it."""
    sliced = slice_mesh(cad_part(refine=2), SliceParams(layer_mm=0.2))
    return dataclasses.replace(sliced, layers=sliced.layers[40:43])


def test_no_repeated_zero_length_or_sub_resolution_moves(fine_part):
    params = ToolpathParams(perimeters=2, infill=0.3)
    gcode = write_fdm_gcode(plan_toolpath(fine_part, params), FdmParams(retract_mm=0.0))
    targets, extruding, lines = xy_moves(gcode)
    assert len(lines) > 500
    assert not any(a == b for a, b in zip(lines, lines[1:]))  # no line repeats the one before
    step = np.hypot(*np.diff(targets, axis=0).T)
    assert step.min() > 0  # no zero-length move
    printed = step[extruding[1:]]
    assert printed.min() >= RESOLUTION_MM - 1e-4  # none shorter than the resolution (4 decimals written)


def test_simplified_perimeters_stay_within_the_resolution_of_the_section(fine_part):
    layer = fine_part.layers[0]
    rings = [np.vstack([r, r[:1]]) for island in layer.islands for r in island.rings()]
    simple = simplify_paths(rings, RESOLUTION_MM)
    assert len(simple) == len(rings)
    assert sum(len(r) for r in simple) < 0.8 * sum(len(r) for r in rings)  # vertices dropped...
    for ring, kept in zip(rings, simple):  # ...but the shape kept
        assert np.allclose(kept[0], kept[-1])
        assert shapely.hausdorff_distance(shapely.LineString(ring), shapely.LineString(kept)) <= RESOLUTION_MM + 1e-9


def test_a_wall_thinner_than_one_bead_is_printed_as_one_bead_of_its_width():
    wall, radius = 0.305, 10.0
    sliced = slice_mesh(thin_tube(wall, radius, height_mm=2.0), SliceParams(layer_mm=0.2))
    toolpath = plan_toolpath(sliced, ToolpathParams())
    middle = 2 * math.pi * (radius - wall / 2) * math.cos(math.pi / 128)  # the 128-gon's mid line
    assert len(toolpath.layers) == 10
    for layer in toolpath.layers:
        assert [p.kind for p in layer.pieces] == ["thin_wall"]
        assert layer.stats.path_mm == pytest.approx(middle, rel=2e-3)
        assert layer.pieces[0].width_mm == pytest.approx(wall, abs=2e-3)
    gcode = write_fdm_gcode(toolpath, FdmParams(retract_mm=0.0))
    e_last = float(re.findall(r" E(-?[\d.]+)", gcode)[-1])
    filament = math.pi * (1.75 / 2) ** 2
    assert e_last == pytest.approx(toolpath.totals.path_mm * bead_area_mm2(wall, 0.2) / filament, rel=5e-3)


def test_a_thin_rib_is_one_open_bead_along_it_beside_a_block_with_perimeters():
    block = manifold3d.Manifold.cube((10.0, 10.0, 1.0))
    rib = manifold3d.Manifold.cube((20.0, 0.3, 1.0)).translate((15.0, 4.85, 0.0))
    sliced = slice_mesh(to_trimesh(block + rib), SliceParams(layer_mm=0.5))
    layer = plan_toolpath(sliced, ToolpathParams(perimeters=1, infill=0.2)).layers[0]
    walls = [p for p in layer.pieces if p.kind == "thin_wall"]
    assert len(walls) == 1
    points = walls[0].points
    assert not np.allclose(points[0], points[-1])  # open: along the rib, not round it
    assert np.hypot(*np.diff(points, axis=0).T).sum() == pytest.approx(20.0, abs=0.31)
    assert np.allclose(points[:, 1], 5.0, atol=1e-3) and walls[0].width_mm == pytest.approx(0.3, abs=2e-3)
    assert {p.kind for p in layer.pieces} == {"perimeter", "thin_wall", "infill"}


def test_a_wall_thinner_than_a_quarter_nozzle_is_left_out():
    sliced = slice_mesh(thin_tube(0.08, 10.0, height_mm=0.4), SliceParams(layer_mm=0.2))
    assert plan_toolpath(sliced, ToolpathParams()).totals.path_mm == 0.0
