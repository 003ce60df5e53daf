"""The writer's own record of a program equals what the reader reads from its text.

:func:`app.gcode.fdm.write_fdm_program` and ``ProgramBuilder(record=True)`` follow every
line as they write it; the toolpath job takes its time estimate, bounds and meta from that
record instead of reading ``print.gcode`` back.  The independent reference is
:func:`app.gcode.reader.read_program` / :func:`app.gcode.estimator.estimate_gcode` on the
written text: every field must be equal, exactly, on real parts, every fill pattern, both
modes, z lift and raw lines that switch the reader to relative moves.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from app.gcode.estimator import MachineLimits, estimate_gcode, estimate_program
from app.gcode.fdm import FdmParams, write_fdm_layers, write_fdm_program
from app.gcode.reader import Program, read_program
from app.gcode.writer import GcodeError, ProgramBuilder
from app.jobs.gcode_meta import gcode_meta
from app.slicing import SliceParams, slice_mesh
from app.slicing.toolpath import ToolpathParams, plan_toolpath
from tests.helpers.real_parts import cad_part, thin_tube


def _assert_same(recorded: Program, read: Program) -> None:
    for f in dataclasses.fields(Program):
        a, b = getattr(recorded, f.name), getattr(read, f.name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape, f.name
            assert np.array_equal(a, b), f"{f.name}: first difference at {np.argwhere(a != b)[:1].tolist()}"
        else:
            assert a == b, f.name


@pytest.fixture(scope="module")
def parts():
    cad = cad_part(refine=1)
    cad.apply_translation([40.0, 60.0, 0.0] - cad.bounds[0])
    tube = thin_tube()
    tube.apply_translation([100.0, 100.0, 0.0] - tube.bounds[0])
    box = trimesh.creation.box((12.0, 7.0, 3.0))
    box.apply_translation([-3.0, 5.0, 0.0] - box.bounds[0])   # negative x: signs, -0.0000
    return {"cad": slice_mesh(cad, SliceParams(layer_mm=1.0)), "tube": slice_mesh(tube, SliceParams(layer_mm=1.5)),
            "box": slice_mesh(box, SliceParams(layer_mm=0.3))}


CASES = [
    ("cad", "raster", FdmParams()),
    ("cad", "lines", FdmParams(retract_mm=0.0)),
    ("box", "contour", FdmParams(mode="dispense")),
    ("cad", "zone", FdmParams(mode="dispense", dialect="grbl", z_lift_mm=0.4)),
    ("tube", "raster", FdmParams(z_lift_mm=0.2, min_travel_for_retract_mm=0.0)),
    ("box", "hilbert", FdmParams(home=False)),
    ("box", "raster", FdmParams(mode="dispense", dispense_on="G91", dispense_off="G90")),  # relative moves
    ("box", "lines", FdmParams(mode="dispense", dispense_on="M64 P0", dispense_off="M65 P0")),
]


@pytest.mark.parametrize("part, pattern, fdm", CASES)
def test_the_written_record_is_what_the_reader_reads(parts, part, pattern, fdm):
    toolpath = plan_toolpath(parts[part], ToolpathParams(pattern=pattern))
    text, recorded = write_fdm_program(toolpath.layers, toolpath.params, fdm)
    assert text == write_fdm_layers(toolpath.layers, toolpath.params, fdm)   # recording changes nothing written
    read = read_program(text)
    assert read.count > 10
    _assert_same(recorded, read)
    limits = MachineLimits(accel_mm_s2=800.0, junction_deviation_mm=0.02)
    ours, reference = estimate_program(recorded, limits), estimate_gcode(text, limits)
    assert ours.total_s == reference.total_s and ours.layer_times == reference.layer_times
    assert np.array_equal(ours.block_times, reference.block_times)
    assert gcode_meta(text, recorded) == gcode_meta(text)


def test_a_builder_records_probes_rapids_extra_axes_and_raw_lines():
    b = ProgramBuilder("linuxcnc", "x", record=True)
    b.rapid(x=1.23456, y=-0.00001).move(z=-2.0, feed_mm_min=300.0).probe("g38", z=-5.0, feed_mm_min=60.0)
    b.raw("G92 X0 Y0").move(x=4.0, y=2.0, c=30.0, feed_mm_min=900.0).raw("G4 P0.5").raw("G28")
    b.comment("LAYER:3").move(x=-1.0, e=0.7).raw("M83").move(e=0.2).raw("G20").move(x=1.0).wait_for_moves().end()
    _assert_same(b.program(), read_program(b.text()))


def test_a_builder_without_record_has_no_program():
    with pytest.raises(GcodeError):
        ProgramBuilder("marlin", "x").program()


def test_a_block_with_layer_tags_records_each_move_in_its_layer():
    b = ProgramBuilder("marlin", "x", record=True)
    nan = np.nan
    lines = [";LAYER:-2", "G1 X1.0000 Y2.0000 F600.0", "; TYPE:infill", ";LAYER:7", "G1 Z0.2000",
             "G1 X3.0000 Y2.0000 E0.5000", ";LAYER:3", "G1 X3.0000 Y4.0000 E1.0000"]
    rows = np.array([[nan] * 5, [1.0, 2.0, nan, nan, 600.0], [nan] * 5, [nan] * 5, [nan, nan, 0.2, nan, nan],
                     [3.0, 2.0, nan, 0.5, nan], [nan] * 5, [3.0, 4.0, nan, 1.0, nan]])
    b.extend_block(lines, rows)
    recorded, read = b.program(), read_program(b.text())
    assert read.layer.tolist() == [-2, 7, 7, 3]
    _assert_same(recorded, read)
    assert b.bounds() is None   # a layer tag is a raw line: the builder follows no bounds after it
