"""FDM / dispense G-code: sections, E bookkeeping, dialects, determinism, time agreement."""

from __future__ import annotations

import math
import re

import pytest
import trimesh

from app.gcode.estimator import estimate_gcode
from app.gcode.fdm import FdmParams, write_fdm_gcode
from app.gcode.writer import GcodeError
from app.slicing import SliceParams, slice_mesh
from app.slicing.toolpath import ToolpathParams, plan_toolpath


@pytest.fixture(scope="module")
def toolpath():
    res = slice_mesh(trimesh.creation.box((12, 8, 0.6)), SliceParams(layer_mm=0.2))
    return plan_toolpath(res, ToolpathParams(pattern="raster", perimeters=1))


def test_extrusion_e_matches_path_volume(toolpath):
    g = write_fdm_gcode(toolpath, FdmParams(retract_mm=0.0))
    e_values = [float(m) for m in re.findall(r" E(-?[\d.]+)", g)]
    area = math.pi * (1.75 / 2) ** 2
    bead = (0.4 - 0.2) * 0.2 + math.pi * 0.2 ** 2 / 4       # stadium: 0.0714 mm^2, PrusaSlicer's Flow model
    expect = toolpath.totals.path_mm * bead / area
    assert e_values[-1] == pytest.approx(expect, rel=1e-4)
    assert bead / (0.4 * 0.2) == pytest.approx(0.8927, abs=1e-4)  # the rectangle gave 12 % more


def test_no_retract_before_anything_was_extruded(toolpath):
    g = write_fdm_gcode(toolpath, FdmParams(retract_mm=0.8))
    e_values = [float(m) for m in re.findall(r" E(-?[\d.]+)", g.split("; process", 1)[1])]
    assert e_values[0] > 0                                      # the first E move extrudes
    assert min(e_values) >= 0 and any(b < a for a, b in zip(e_values, e_values[1:]))   # later retracts exist
    for section in ("; start", "; process", "; end"):
        assert section in g
    assert g.count(";LAYER:") == len(toolpath.layers)
    assert write_fdm_gcode(toolpath) == write_fdm_gcode(toolpath)     # byte-identical


def test_time_of_gcode_matches_toolpath_statistics(toolpath):
    g = write_fdm_gcode(toolpath, FdmParams(retract_mm=0.0, home=False))
    est = estimate_gcode(g, toolpath.params.limits)
    assert est.print_s == pytest.approx(sum(
        lay.stats.time_s for lay in toolpath.layers), rel=0.1)
    assert len(est.layer_times) == len(toolpath.layers)


def test_dispense_mode_switches_per_piece(toolpath):
    g = write_fdm_gcode(toolpath, FdmParams(dialect="grbl", mode="dispense"))
    pieces = sum(len(lay.pieces) for lay in toolpath.layers)
    assert g.count("\nM8\n") == pieces and g.count("\nM9\n") == pieces + 1
    assert " E" not in g and g.rstrip().endswith("M2")
    with pytest.raises(GcodeError):
        write_fdm_gcode(toolpath, FdmParams(dialect="grbl", mode="extrude"))


def test_linuxcnc_dispenses_with_the_commands_it_is_given(toolpath):
    """LinuxCNC has no dispenser words of its own (numbered outputs): a dispense program names them."""
    with pytest.raises(GcodeError) as caught:
        write_fdm_gcode(toolpath, FdmParams(dialect="linuxcnc", mode="dispense"))
    assert caught.value.field == "dispense_on" and "linuxcnc" in caught.value.message
    g = write_fdm_gcode(toolpath, FdmParams(dialect="linuxcnc", mode="dispense", dispense_on="M64 P0",
                                            dispense_off="M65 P0"))
    pieces = sum(len(lay.pieces) for lay in toolpath.layers)
    assert g.count("\nM64 P0\n") == pieces and g.count("\nM65 P0\n") == pieces + 1 and "M106" not in g
