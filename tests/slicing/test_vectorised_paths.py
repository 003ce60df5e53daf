"""The vectorised fill machinery against plain per-line / per-path references, and the
invariants of a real part's toolpath: every bead inside its section, no zero-length or
repeated move, the same paths whether a section's paths are made afresh or remembered."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import shapely

from app.slicing import SliceParams, slice_mesh
from app.slicing.export_binary import from_binary, to_binary
from app.slicing.fills import flat_intervals, region_geometry, scan_intervals
from app.slicing.path_memo import _geometry, normalised
from app.slicing.rings import Island, split_at
from app.slicing.toolpath import RESOLUTION_MM, ToolpathParams, iter_toolpath, layer_pieces, plan_toolpath, turns_of
from tests.helpers.real_parts import cad_part, thin_tube

W = 0.4


@pytest.fixture(scope="module")
def part_layers():
    """Eight layers of the CAD-like part (holes, a pocket, a boss and a dome: islands that
    split and merge), sliced once."""
    sliced = slice_mesh(cad_part(refine=1), SliceParams(layer_mm=0.2))
    return dataclasses.replace(sliced, layers=sliced.layers[::12][:8])


def _intervals_by_line(islands: tuple[Island, ...], pitch: float, angle: float):
    """The reference: each scan line intersected with every edge on its own."""
    c, s = math.cos(-angle), math.sin(-angle)
    rot = np.array([[c, -s], [s, c]])
    e = np.concatenate([np.stack([r @ rot.T, np.roll(r, -1, axis=0) @ rot.T], axis=1)
                        for isl in islands for r in isl.rings()])
    ys = scan_intervals(islands, pitch, angle).ys
    rows = []
    for y in ys:
        hit = (e[:, 0, 1] <= y) != (e[:, 1, 1] <= y)
        t = (y - e[hit, 0, 1]) / (e[hit, 1, 1] - e[hit, 0, 1])
        xs = np.sort(e[hit, 0, 0] + t * (e[hit, 1, 0] - e[hit, 0, 0]))
        rows.append(xs[: len(xs) // 2 * 2].reshape(-1, 2))
    return rows


def test_scan_intervals_match_line_by_line_intersection(part_layers):
    for layer in part_layers.layers:
        for angle in (0.0, 0.7, math.pi / 2):
            rows = scan_intervals(layer.islands, W, angle).rows
            reference = _intervals_by_line(layer.islands, W, angle)
            assert len(rows) == len(reference)
            for got, want in zip(rows, reference):
                assert got.shape == want.shape and np.allclose(got, want, atol=1e-12)
            flat = flat_intervals(layer.islands, W, angle)
            assert np.all(np.diff(flat.row) >= 0) and np.all(flat.x1 >= flat.x0)


def _turns_reference(points: np.ndarray, threshold: float) -> int:
    d = np.diff(points, axis=0)
    d = d[np.hypot(d[:, 0], d[:, 1]) > 1e-12]
    if len(points) > 2 and np.allclose(points[0], points[-1]) and len(d) > 1:
        d = np.vstack([d, d[:1]])
    if len(d) < 2:
        return 0
    ang = np.arctan2(d[:, 1], d[:, 0])
    return int(np.count_nonzero(np.abs((np.diff(ang) + np.pi) % (2 * np.pi) - np.pi) > threshold))


def test_turns_of_a_layer_are_the_sum_of_each_paths_turns(part_layers):
    thr = math.radians(10.0)
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0.0]])
    assert turns_of([square], thr) == 4  # three corners along it and the closing one
    assert turns_of([square[:4]], thr) == 2  # open: two corners
    assert turns_of([np.array([[0, 0], [1, 0], [1, 0], [2, 0.0]])], thr) == 0  # a repeated point is no turn
    pieces = [p.points for lay in plan_toolpath(part_layers, ToolpathParams(perimeters=2)).layers for p in lay.pieces]
    assert turns_of(pieces, thr) == sum(_turns_reference(p, thr) for p in pieces) > 100


def test_every_bead_of_a_real_part_stays_inside_its_section(part_layers):
    for layer, planned in zip(part_layers.layers, iter_toolpath(part_layers, ToolpathParams(perimeters=2))):
        region = region_geometry(layer.islands)
        # a bead's centre line half a bead inside, but for what simplifying to the resolution moves it
        inner = region.buffer(-W / 2 + RESOLUTION_MM + 1e-6)
        lines = np.array([shapely.LineString(p.points) for p in planned.pieces])
        assert len(planned.pieces) > 0
        assert shapely.covers(inner, lines).all(), layer.index
        steps = np.concatenate([np.hypot(*np.diff(p.points, axis=0).T) for p in planned.pieces])
        assert steps.min() > 0  # no zero-length move inside a piece


def test_remembered_paths_are_the_paths_made_afresh(part_layers):
    layers = list(iter_toolpath(part_layers, ToolpathParams()))
    pos = np.zeros(2)
    for layer, planned in zip(part_layers.layers, layers):
        fresh, pos = layer_pieces(normalised(layer.islands), layer.index, pos, ToolpathParams())
        assert [p.kind for p in fresh] == [p.kind for p in planned.pieces]
        for a, b in zip(fresh, planned.pieces):
            assert a.points.shape == b.points.shape and np.allclose(a.points, b.points, rtol=0, atol=1e-9)


def test_a_tube_makes_its_shell_once_for_every_infill_angle_and_plans_as_made_afresh(monkeypatch):
    """The perimeters and thin walls do not turn with the infill: one section at four angles
    (0, 90, 180, 270 degrees) has four sets of paths but one shell, and each layer's pieces
    are the ones made afresh."""
    from app.slicing import toolpath

    sliced = slice_mesh(thin_tube(height_mm=3.0), SliceParams(layer_mm=0.2))
    made: list[int] = []
    shell = toolpath.layer_shell
    monkeypatch.setattr(toolpath, "layer_shell", lambda islands, params: made.append(1) or shell(islands, params))
    planned = list(toolpath.iter_toolpath(sliced, ToolpathParams()))
    sections = {_geometry(normalised(lay.islands)) for lay in sliced.layers}
    assert len(made) == len(sections) < len(sliced.layers)
    monkeypatch.undo()
    pos = np.zeros(2)
    for layer, layer_planned in zip(sliced.layers, planned):
        fresh, pos = layer_pieces(normalised(layer.islands), layer.index, pos, ToolpathParams())
        assert [(p.kind, p.width_mm) for p in fresh] == [(p.kind, p.width_mm) for p in layer_planned.pieces]
        assert all(np.array_equal(a.points, b.points) for a, b in zip(fresh, layer_planned.pieces))


def test_a_prismatic_stretch_shares_one_section_and_normalising_keeps_the_region():
    box = Island(np.array([[0, 0], [5, 0], [10, 0], [10, 3.3], [10, 10], [0, 10], [0, 4.0]]))
    other = Island(np.array([[10, 0], [10, 7.1], [10, 10], [0, 10], [0, 0], [2.5, 0.0]]))
    a, b = normalised((box,))[0], normalised((other,))[0]
    assert len(a.outer) == 4 and len(b.outer) == 4
    assert a.area == pytest.approx(100.0) and b.area == pytest.approx(100.0)
    assert sorted(map(tuple, a.outer)) == sorted(map(tuple, b.outer))
    triangle = Island(np.array([[0, 0], [1, 0], [0, 1.0]]))
    assert np.array_equal(normalised((triangle,))[0].outer, triangle.outer)  # nothing to drop


def test_a_prismatic_part_read_back_from_layers_npz_is_one_section_and_plans_as_sliced():
    """The toolpath job reads layers.npz (6 decimals): rounding moves a straight wall's vertices
    off its line by a micrometre, and a layer's thickness in its last bits; neither makes a
    tube's repeated section a new one, nor changes what is planned."""
    sliced = slice_mesh(thin_tube(height_mm=6.0), SliceParams(layer_mm=0.2))
    read = from_binary(to_binary(sliced))
    middle = read.layers[1:-1]
    assert len({_geometry(normalised(lay.islands)) for lay in middle}) == 1
    for a, b in zip(iter_toolpath(sliced), iter_toolpath(read)):
        assert a.stats.path_mm == pytest.approx(b.stats.path_mm, rel=1e-9, abs=1e-6)
        assert a.stats.time_s == pytest.approx(b.stats.time_s, rel=1e-9)
        assert [p.points.shape for p in a.pieces] == [p.points.shape for p in b.pieces]


def test_split_at_is_numpy_split():
    rng = np.random.default_rng(5)
    for n in (0, 1, 7, 50):
        values = rng.uniform(-1, 1, (n, 2))
        for _ in range(20):
            cuts = np.sort(rng.integers(0, n + 1, rng.integers(0, 6)))
            mine, numpy_s = split_at(values, cuts), np.split(values, cuts)
            assert len(mine) == len(numpy_s)
            assert all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(mine, numpy_s))
