"""FDM / dispense G-code: sections, E bookkeeping, dialects, determinism, time agreement."""

from __future__ import annotations

import math
import re

import pytest
import trimesh

from app.gcode.estimator import estimate_gcode
from app.gcode.fdm import FdmParams, write_fdm_gcode
from app.gcode.writer import GcodeError
from app.slicing.layers import SliceParams, slice_mesh
from app.slicing.toolpath import ToolpathParams, plan_toolpath


@pytest.fixture(scope="module")
def toolpath():
    res = slice_mesh(trimesh.creation.box((12, 8, 0.6)), SliceParams(layer_mm=0.2))
    return plan_toolpath(res, ToolpathParams(pattern="raster", perimeters=1))


def test_extrusion_e_matches_path_volume(toolpath):
    g = write_fdm_gcode(toolpath, FdmParams(retract_mm=0.0))
    e_values = [float(m) for m in re.findall(r" E(-?[\d.]+)", g)]
    area = math.pi * (1.75 / 2) ** 2
    expect = toolpath.totals.path_mm * 0.4 * 0.2 / area
    assert e_values[-1] == pytest.approx(expect, rel=1e-4)
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
