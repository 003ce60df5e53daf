"""app/slicing: pure slicing, beam offsets, exports and fill paths (seeds S4, S5).

Entry points for the job adapters::

    from app.slicing import slice_mesh, SliceParams, plan_toolpath, ToolpathParams
    result = slice_mesh(mesh, SliceParams(mode="cavity", l_min=0.02, l_max=0.04))
    slc = to_slc(result).data; cli = to_cli(result); js = to_json(result)
    toolpath = plan_toolpath(result, ToolpathParams(pattern="hilbert_merged"))
    gcode = app.gcode.fdm.write_fdm_gcode(toolpath, FdmParams(...))
"""

from app.slicing.errors import MeshError, SlicingError
from app.slicing.export import SlcOptions, layer_svg, to_cli, to_json, to_slc
from app.slicing.layers import Layer, SliceParams, SliceResult
from app.slicing.mesh_prep import place_on_bed, prepare_mesh
from app.slicing.offset import SEED_HAZ_TABLE, BeamWidthTable, compensate_beam
from app.slicing.slicer import slice_mesh
from app.slicing.toolpath import Toolpath, ToolpathParams, plan_toolpath

__all__ = ["MeshError", "SlicingError", "SlcOptions", "layer_svg", "to_cli", "to_json",
           "to_slc", "Layer", "SliceParams", "SliceResult", "slice_mesh", "place_on_bed",
           "prepare_mesh", "SEED_HAZ_TABLE", "BeamWidthTable", "compensate_beam", "Toolpath",
           "ToolpathParams", "plan_toolpath"]
