"""Scene building against a real viser server: nodes, batching, precision, sliders, toggles."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from app.viewer.gcode_paths import ToolpathSegments
from app.viewer.registry import SceneRegistry
from app.viewer.scene_data import (
    AxisGlyphs,
    DeviationPlot,
    FocusScene,
    HeightStack,
    LayerStack,
    Polyline,
    ProbeSet,
    Toolpath,
)
from app.viewer.scenes import DrawParams, SceneBuilder, height_surface


def segments(n: int, dispense_every: int = 2, seed: int = 0) -> ToolpathSegments:
    rng = np.random.default_rng(seed)
    pts = np.cumsum(rng.normal(size=(n + 1, 3)), axis=0)
    return ToolpathSegments(pts[:-1], pts[1:], np.arange(n) % dispense_every == 0, np.zeros(n, np.int64),
                            np.zeros(n), np.zeros(n))


def handles(builder: SceneBuilder) -> dict:
    return {name: h for name, (_g, h) in builder._handles.items()}


def test_toolpaths_are_batched_into_two_screen_unit_nodes(viser_server):
    builder = SceneBuilder(viser_server, SceneRegistry())
    seg = segments(20_000, dispense_every=3)
    builder.draw(FocusScene({"job_id": "j"}, "t", toolpaths=(Toolpath("path", seg, "compensated"),)))
    nodes = handles(builder)
    assert set(nodes) == {"/focus/toolpaths/path/dispense", "/focus/toolpaths/path/travel"}
    dispense, travel = nodes["/focus/toolpaths/path/dispense"], nodes["/focus/toolpaths/path/travel"]
    assert dispense.thickness_units == "screen" and travel.thickness_units == "screen"
    assert len(dispense.points) == seg.dispense.sum() and len(travel.points) == (~seg.dispense).sum()
    assert np.allclose(dispense.points[:, 0], seg.starts[seg.dispense], atol=1e-4)
    assert np.allclose(travel.points[:, 1], seg.ends[~seg.dispense], atol=1e-4)
    assert not np.array_equal(dispense.colors, travel.colors)  # dispense vs travel colours


def test_very_large_toolpaths_split_into_few_nodes(viser_server):
    registry = SceneRegistry()
    builder = SceneBuilder(viser_server, registry, params=DrawParams(max_segments_per_node=1000))
    seg = segments(5000, dispense_every=1)  # 5000 dispense moves
    builder.draw(FocusScene({}, "t", toolpaths=(Toolpath("big", seg),)))
    nodes = registry.snapshot()["nodes"]
    assert len(nodes) == 5
    assert sum(n["count"] for n in nodes.values()) == 5000


def test_probe_points_are_float32_and_coloured_by_deviation(viser_server):
    builder = SceneBuilder(viser_server, SceneRegistry())
    planned = np.array([[200.0, 150.0, 10.0], [200.01, 150.0, 10.0]])
    measured = planned + [0, 0, 0.03]
    builder.draw(FocusScene({}, "t", probes=(ProbeSet("p", planned, measured, np.array([0.03, -0.03])),)))
    nodes = handles(builder)
    planned_node, measured_node = nodes["/focus/probes/p/planned"], nodes["/focus/probes/p/measured"]
    assert planned_node.precision == "float32" and measured_node.precision == "float32"
    # float16 would round 200.01 to 200.0; float32 keeps 10 um near 200 mm
    assert np.allclose(planned_node.points, planned, atol=2e-5)
    assert measured_node.colors[0, 0] > measured_node.colors[0, 2]  # above nominal: red
    assert measured_node.colors[1, 2] > measured_node.colors[1, 0]  # below nominal: blue


def test_layer_slider_swaps_the_current_layer_node(viser_server):
    registry = SceneRegistry()
    builder = SceneBuilder(viser_server, registry)
    layers = tuple(np.full((k + 1, 2, 3), float(k)) for k in range(5))
    builder.draw(FocusScene({}, "t", layers=(LayerStack("slices", tuple(f"L{k}" for k in range(5)), layers),)))
    nodes = registry.snapshot()["nodes"]
    assert nodes["/focus/layers/slices/all"]["count"] == 15
    assert nodes["/focus/layers/slices/current"]["count"] == 5  # the top layer first
    assert builder.show_layer("slices", 1) == 1
    current = handles(builder)["/focus/layers/slices/current"]
    assert len(current.points) == 2 and np.all(current.points == 1.0)
    assert registry.snapshot()["nodes"]["/focus/layers/slices/current"]["label"] == "L1"
    assert builder.show_layer("slices", 99) == 4  # clipped


def test_height_map_is_a_coloured_surface_with_a_slider(viser_server):
    registry = SceneRegistry()
    builder = SceneBuilder(viser_server, registry)
    heights = np.stack([np.full((6, 4), 0.01 * k) for k in range(3)])
    builder.draw(FocusScene({}, "t", heights=(HeightStack("h", heights, 0.1, ("a", "b", "c")),)))
    node = registry.snapshot()["nodes"]["/focus/heights/h"]
    assert node["count"] == 2 * 5 * 3 and node["label"] == "c"
    assert node["height_range_mm"] == pytest.approx([0.0, 0.02])
    assert builder.show_height("h", 0) == 0
    assert registry.snapshot()["nodes"]["/focus/heights/h"]["label"] == "a"


def test_height_surface_geometry():
    h = np.arange(12, dtype=float).reshape(3, 4)
    mesh = height_surface(h, 0.5, (10.0, 20.0), 0.0, 11.0)
    assert len(mesh.vertices) == 12 and len(mesh.faces) == 2 * 2 * 3
    assert np.allclose(mesh.vertices[5], [10.0 + 1.5 * 0.5, 20.0 + 1.5 * 0.5, 5.0])
    # z = 2 x + 8 y (+ const) over a 1.5 x 1.0 mm footprint: area = 1.5 * sqrt(1 + 2^2 + 8^2)
    assert np.isclose(mesh.area, 1.5 * np.sqrt(69.0))
    colours = mesh.visual.vertex_colors
    assert colours[0, :3].tolist() == [48, 18, 59] and colours[-1, :3].tolist() == [250, 240, 30]


def test_group_toggles_hide_and_show_nodes(viser_server):
    registry = SceneRegistry()
    builder = SceneBuilder(viser_server, registry)
    builder.draw(FocusScene({}, "t", polylines=(Polyline("a", np.eye(3)), Polyline("b", np.eye(3), "reconstructed")),
                            toolpaths=(Toolpath("p", segments(10)),)))
    builder.set_group_visible("toolpaths", False)
    snap = registry.snapshot()
    assert snap["groups"] == {"curves": True, "toolpaths": False, "traces": True}
    assert all(not h.visible for n, h in handles(builder).items() if "/toolpaths/" in n)
    assert all(h.visible for n, h in handles(builder).items() if "/toolpaths/" not in n)
    # a new scene keeps the operator's choice
    builder.draw(FocusScene({}, "t", toolpaths=(Toolpath("q", segments(10)),)))
    assert all(not h.visible for h in handles(builder).values())


def test_viewer_show_registers_plots_and_aims_the_camera(viewer):
    s = np.linspace(0, 30, 7)
    scene = FocusScene({"job_id": "job_1"}, "reconstruct job_1",
                       polylines=(Polyline("t", np.array([[0, 0, 0], [30, 0, 6.0]])),),
                       axes=(AxisGlyphs("nozzle", np.zeros((3, 3)), np.tile([0, 0, 1.0], (3, 1)), 2.0),),
                       plots=(DeviationPlot("t", "t: dz", s, 0.01 * np.sin(s)),))
    snap = viewer.show(scene)
    assert snap["focus"] == {"job_id": "job_1"}
    assert snap["plots"]["deviation/t"]["x"] == pytest.approx(s.tolist())
    assert snap["plots"]["deviation/t"]["y"] == pytest.approx((0.01 * np.sin(s)).tolist())
    assert snap["nodes"]["/focus/axes/nozzle"]["count"] == 3
    assert np.allclose(viewer.view().camera[0], [15, 0, 3])  # each view aims its own browsers' cameras
    second = viewer.show(FocusScene({"part_id": "p"}, "part"))
    assert second["generation"] == snap["generation"] + 1 and second["nodes"] == {} and second["plots"] == {}


def test_nothing_in_the_viewer_can_reach_a_machine():
    """The viewer imports neither the hardware package nor the machines API/service."""
    forbidden = ("hardware", "app.machines.live", "app.api.routes.machines", "serial")
    for path in Path("app/viewer").glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not any(n == f or n.startswith(f + ".") for n in names for f in forbidden), (path, names)
