"""The FDM writer's piece loop and its blocks of layers write exactly what one ``ProgramBuilder.move`` per move writes.

The writer formats a piece's moves itself (plain floats, one f-string per line) instead of
calling :meth:`ProgramBuilder.move` per move; the reference below is that per-move loop as it
was written before, kept here so that the two are compared byte for byte on real parts,
every fill pattern, both modes, negative coordinates and repeated/near-zero moves.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from app.gcode.fdm import FdmParams, _end, _start, bead_area_mm2, write_fdm_layers
from app.gcode.reader import Program, read_program
from app.gcode.writer import GcodeError, ProgramBuilder
from app.geometry.tolerance import LENGTH_EPS_MM
from app.slicing import SliceParams, slice_mesh
from app.slicing.toolpath import LayerStats, LayerToolpath, PathPiece, ToolpathParams, plan_toolpath
from tests.helpers.real_parts import cad_part


def _reference(layers, tpp: ToolpathParams, params: FdmParams) -> str:
    """write_fdm_layers with one ProgramBuilder.move per move (the reference)."""
    b = ProgramBuilder(params.dialect, "toolpath", params.job_id)
    rules = b.dialect
    on, off = rules.dispense
    on, off = params.dispense_on or on, params.dispense_off or off
    fil_area = math.pi * (tpp.filament_mm / 2) ** 2
    _start(b, tpp, params, rules)
    decimals = b.decimals
    b.comment("process")
    e, retracted, extruded, pos, travel, z = 0.0, False, False, None, tpp.travel_feed_mm_s * 60.0, 0.0
    for lay in layers:
        z = lay.z
        h = tpp.layer_height_mm or lay.thickness
        b.raw(f";LAYER:{lay.index}")
        b.move(z=z + params.z_lift_mm, feed_mm_min=travel)
        for piece in lay.pieces:
            start = piece.points[0]
            dist = math.inf if pos is None else math.hypot(*(start - pos))
            if params.mode == "extrude" and extruded and dist > params.min_travel_for_retract_mm \
                    and params.retract_mm > 0:
                e -= params.retract_mm
                b.move(e=e, feed_mm_min=params.retract_feed_mm_s * 60.0)
                retracted = True
            if dist > LENGTH_EPS_MM:
                b.move(x=start[0], y=start[1], feed_mm_min=travel)
            if params.z_lift_mm:
                b.move(z=z, feed_mm_min=travel)
            if retracted:
                e += params.retract_mm
                b.move(e=e, feed_mm_min=params.retract_feed_mm_s * 60.0)
                retracted = False
            b.comment(f"TYPE:{piece.kind}")
            if params.mode == "dispense":
                b.raw(on)
            feed = piece.feed_mm_s * 60.0
            e_per_mm = bead_area_mm2(piece.width_mm or tpp.line_width_mm, h) / fil_area
            first = True
            written = (round(float(start[0]), decimals), round(float(start[1]), decimals))
            for a, c in zip(piece.points[:-1], piece.points[1:]):
                seg = math.hypot(*(c - a))
                if seg <= LENGTH_EPS_MM:
                    continue
                if params.mode == "extrude":
                    e += seg * e_per_mm
                target = (round(float(c[0]), decimals), round(float(c[1]), decimals))
                if target == written:
                    continue
                written = target
                if params.mode == "extrude":
                    extruded = True
                    b.move(x=c[0], y=c[1], feed_mm_min=feed if first else None, e=e)
                else:
                    b.move(x=c[0], y=c[1], feed_mm_min=feed if first else None)
                first = False
            if params.mode == "dispense":
                b.raw(off)
            pos = piece.points[-1]
            if params.z_lift_mm:
                b.move(z=z + params.z_lift_mm, feed_mm_min=travel)
    _end(b, params, z, off, rules)
    return b.text()


@pytest.fixture(scope="module")
def cad():
    mesh = cad_part(refine=1)
    mesh.apply_translation([-30.0, 40.0, 0.0] - mesh.bounds[0])   # crosses x = 0: signs and -0.0000
    return slice_mesh(mesh, SliceParams(layer_mm=1.0))


@pytest.mark.parametrize("pattern, fdm", [
    ("raster", FdmParams()), ("lines", FdmParams(z_lift_mm=0.3)), ("zone", FdmParams(mode="dispense")),
    ("contour", FdmParams(retract_mm=0.0)), ("hilbert", FdmParams(mode="dispense", dialect="grbl")),
])
def test_the_piece_loop_writes_the_per_move_bytes(cad, pattern, fdm):
    toolpath = plan_toolpath(cad, ToolpathParams(pattern=pattern))
    assert write_fdm_layers(toolpath.layers, toolpath.params, fdm) == _reference(toolpath.layers, toolpath.params, fdm)


def _layer(points: np.ndarray) -> LayerToolpath:
    return LayerToolpath(0, 0.2, 0.2, (PathPiece("infill", points, 40.0),), LayerStats(0.0, 0.0, 0, 0, 0.0))


def test_repeated_tiny_and_signed_moves_are_written_alike():
    rng = np.random.default_rng(3)
    steps = rng.choice([0.0, 1e-7, 4e-5, 6e-5, 0.3, -0.3], size=(400, 2))   # repeats, sub-resolution, real
    points = np.cumsum(np.vstack([[-0.00004, 0.00004], steps]), axis=0)
    layers = [_layer(points)]
    tpp = ToolpathParams()
    for fdm in (FdmParams(), FdmParams(mode="dispense")):
        assert write_fdm_layers(layers, tpp, fdm) == _reference(layers, tpp, fdm)
    assert "-0.0000" not in write_fdm_layers(layers, tpp)


def test_a_non_finite_point_is_refused_naming_its_axis():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [np.nan, 1.0]])
    with pytest.raises(GcodeError) as info:
        write_fdm_layers([_layer(points)], ToolpathParams())
    assert info.value.field == "x"


@pytest.mark.parametrize("block_points", [1, 400])
def test_layers_written_in_blocks_of_any_size_write_and_record_alike(cad, monkeypatch, block_points):
    """Each layer a block of its own, or a few layers per block: the bytes of the per-move
    reference and the record of what the reader reads (layers included) either way."""
    import app.gcode.fdm as fdm

    toolpath = plan_toolpath(cad, ToolpathParams())
    for params in (FdmParams(), FdmParams(z_lift_mm=0.3, min_travel_for_retract_mm=0.0)):
        monkeypatch.setattr(fdm, "BLOCK_POINTS", block_points)
        text, recorded = fdm.write_fdm_program(toolpath.layers, toolpath.params, params)
        assert text == _reference(toolpath.layers, toolpath.params, params)
        read = read_program(text)
        for f in dataclasses.fields(Program):
            a, b = getattr(recorded, f.name), getattr(read, f.name)
            assert np.array_equal(a, b) if isinstance(b, np.ndarray) else a == b, f.name
        assert set(read.layer.tolist()) == {-1, *range(len(toolpath.layers))}   # -1: homing, before any tag


def test_a_non_finite_point_after_finite_layers_is_refused_naming_its_axis():
    good = _layer(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]))
    bad = LayerToolpath(1, 0.4, 0.2, (PathPiece("infill", np.array([[0.0, 0.0], [1.0, np.inf]]), 40.0),),
                        LayerStats(0.0, 0.0, 0, 0, 0.0))
    with pytest.raises(GcodeError) as info:
        write_fdm_layers([good, good, bad], ToolpathParams())
    assert info.value.field == "y"
