"""The slicer-style program preview: move types, layers, dispense on/off, layer height and
time (against the estimator and the toolpath planner), and drawing up to layer k only."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.gcode.estimator import estimate_gcode
from app.gcode.fdm import FdmParams, write_fdm_gcode
from app.slicing import SliceParams, slice_mesh
from app.slicing.toolpath import ToolpathParams, plan_toolpath
from app.viewer.headless import HeadlessTarget
from app.viewer.layer_preview import PreviewError, line_tags, program_preview
from app.viewer.preview_draw import DISPENSE_OFF, DISPENSE_ON, MOVE_COLORS
from app.viewer.registry import SceneRegistry
from app.viewer.scene_data import FocusScene
from app.viewer.scenes import SceneBuilder

# two layers 0.3 mm apart, each: travel, dispense on, a perimeter square side pair, infill, off
HAND = """G21
G90
G1 Z5 F600
;LAYER:0
G0 X0 Y0 Z0.3
; TYPE:perimeter
M106 S255
G1 X10 Y0 F1200
G1 X10 Y10
; TYPE:infill
G1 X0 Y10
M107
G0 X20 Y20
;LAYER:1
G0 X0 Y0 Z0.6
; TYPE:perimeter
M106 S255
G1 X10 Y0
M107
"""


def test_moves_are_typed_layered_and_timed_as_the_estimator_times_them():
    p = program_preview(HAND)
    assert p.kinds == ("infill", "perimeter", "travel")
    assert p.counts() == {"infill": 1, "perimeter": 3, "travel": 4}
    assert [lay.index for lay in p.layers] == [0, 1]
    assert [lay.z_mm for lay in p.layers] == pytest.approx([0.3, 0.6])
    assert [lay.height_mm for lay in p.layers] == pytest.approx([0.3, 0.3])          # floor_z 0
    assert [lay.dispense_mm for lay in p.layers] == pytest.approx([30.0, 10.0])
    assert [lay.time_s for lay in p.layers] == pytest.approx(estimate_gcode(HAND).layer_times, rel=1e-12)
    assert p.on_points.tolist() == [[0, 0, 0.3], [0, 0, 0.6]] and p.on_layer.tolist() == [0, 1]
    assert p.off_points.tolist() == [[0, 10, 0.3], [10, 0, 0.6]] and p.off_layer.tolist() == [0, 1]
    assert p.layer.tolist() == [0, 0, 0, 0, 0, 0, 1, 1]   # the start section's lift goes with layer 0
    assert program_preview(HAND, floor_z=0.1).layers[0].height_mm == pytest.approx(0.2)


def test_circuit_program_strokes_are_typed_by_their_comment_and_one_layer():
    text = "G21\nG90\n; trace T1 net GND\nG0 X0 Y0 Z1\nG1 Z0.1 F100\nM106\nG1 X5 F300\nM107\nG0 Z1\n" \
           "; pad P1\nG0 X7 Y0\nG1 Z0.1\nM106\nG1 X7.5\nM107\n"
    vocab, codes = line_tags(text)
    assert vocab == ("trace", "pad") and codes.tolist()[:4] == [-1, -1, 0, 0] and codes[-1] == 1
    p = program_preview(text)
    assert p.counts() == {"pad": 1, "trace": 1, "travel": 5}
    assert len(p.layers) == 1 and p.layers[0].z_mm == pytest.approx(0.1)
    assert len(p.on_points) == len(p.off_points) == 2


def test_a_program_without_moves_is_refused():
    with pytest.raises(PreviewError):
        program_preview("G21\nM106\nM107\n")


@pytest.fixture(scope="module")
def planned():
    res = slice_mesh(trimesh.creation.box((12, 8, 0.6)), SliceParams(layer_mm=0.2))
    return plan_toolpath(res, ToolpathParams(pattern="raster", perimeters=1))


@pytest.mark.parametrize("mode", ["extrude", "dispense"])
def test_the_fdm_writers_programs_preview_with_the_planners_layers(planned, mode):
    text = write_fdm_gcode(planned, FdmParams(mode=mode))
    first = planned.layers[0]
    p = program_preview(text, floor_z=first.z - first.thickness)
    assert set(p.kinds) == {"perimeter", "infill", "travel"}
    assert [lay.z_mm for lay in p.layers] == pytest.approx([lay.z for lay in planned.layers])
    assert [lay.height_mm for lay in p.layers] == pytest.approx([lay.thickness for lay in planned.layers])
    assert [lay.dispense_mm for lay in p.layers] == pytest.approx([lay.stats.path_mm for lay in planned.layers],
                                                                  rel=1e-3)
    pieces = sum(len(lay.pieces) for lay in planned.layers)
    if mode == "dispense":       # one on and one off per piece
        assert len(p.on_points) == len(p.off_points) == pieces


def test_the_slider_draws_layers_up_to_k_and_nothing_above():
    registry = SceneRegistry()
    builder = SceneBuilder(HeadlessTarget(), registry)
    preview = program_preview(HAND, name="hand")
    builder.draw(FocusScene({"job_id": "j"}, "t", previews=(preview,)))
    nodes = registry.snapshot()["nodes"]
    assert nodes["/focus/preview/hand/perimeter"]["count"] == 3                    # every layer at first
    assert nodes["/focus/preview/hand/dispense_on"]["count"] == 2
    assert registry.snapshot()["previews"]["hand"]["layer"] == 1
    builder.show_preview_layer("hand", 0)
    shot = registry.snapshot()
    nodes = shot["nodes"]
    assert nodes["/focus/preview/hand/perimeter"]["count"] == 2
    assert nodes["/focus/preview/hand/dispense_on"]["count"] == 1
    drawn = builder._handles["/focus/preview/hand/perimeter"][1].points
    assert np.asarray(drawn)[:, :, 2].max() == pytest.approx(0.3)                # no point of layer 1
    assert shot["sliders"]["hand"]["value"] == 0
    legend = {row["type"]: row for row in shot["previews"]["hand"]["legend"]}
    assert legend["perimeter"]["color"] == "#%02x%02x%02x" % MOVE_COLORS["perimeter"]
    assert legend["perimeter"]["shown"] == 2 and legend["perimeter"]["moves"] == 3
    assert legend["dispense_on"]["color"] == "#%02x%02x%02x" % DISPENSE_ON
    assert legend["dispense_off"]["color"] == "#%02x%02x%02x" % DISPENSE_OFF
    assert builder.show_preview_layer("hand", 99) == 1                            # clipped


def test_the_head_is_one_node_where_it_is_told():
    registry = SceneRegistry()
    builder = SceneBuilder(HeadlessTarget(), registry)
    builder.draw(FocusScene({"job_id": "j"}, "t", previews=(program_preview(HAND, name="hand"),)))
    builder.show_head((1.0, 2.0, 3.0), line=7)
    builder.show_head((4.0, 5.0, 6.0), line=9)
    heads = [n for n in registry.snapshot()["nodes"] if n.startswith("/focus/head")]
    assert heads == ["/focus/head"]
    node = registry.snapshot()["nodes"]["/focus/head"]
    assert node["position_mm"] == [4.0, 5.0, 6.0] and node["line"] == 9
    assert builder._handles["/focus/head"][1].position == (4.0, 5.0, 6.0)
