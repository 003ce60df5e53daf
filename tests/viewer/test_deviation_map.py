"""The 3-D view's readability: the part in a colour that contrasts with the white
grid, the rebuilt deviation as a colour ribbon on the part, programs coloured by their
standoff error, and legends whose ends are the data's — all read from the scene drawn
into a real viser server."""

from __future__ import annotations

import numpy as np
import pytest

from app.viewer.colors import PALETTE, deviation_colors
from app.viewer.deviation_map import deviation_ribbon, ribbon_surface, scene_legends, standoff_errors
from app.viewer.gcode_paths import ToolpathSegments
from app.viewer.gui import legend_html
from app.viewer.registry import SceneRegistry
from app.viewer.scene_data import FocusScene, ProbeSet, ScalarSurface, Toolpath
from app.viewer.scenes import SceneBuilder, scalar_surface_mesh

STANDOFF = 0.08


def nominal_trace(n: int = 200) -> np.ndarray:
    """A sloped straight trace: x 0..40 mm, z = 2 + 0.1 x."""
    x = np.linspace(0.0, 40.0, n)
    return np.column_stack([x, np.full(n, 5.0), 2.0 + 0.1 * x])


def arc_length(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def deviation(s: np.ndarray) -> np.ndarray:
    return 0.06 * np.sin(s / 6.0) + 0.01


def luminance(rgb: tuple[int, int, int]) -> float:
    c = np.asarray(rgb, float) / 255.0
    lin = np.where(c <= 0.03928, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return float(lin @ [0.2126, 0.7152, 0.0722])


def test_the_part_contrasts_with_the_white_grid():
    ratio = (1.0 + 0.05) / (luminance(PALETTE.mesh) + 0.05)
    assert ratio >= 3.0  # WCAG 1.4.11, graphical objects (the old pale grey gave 1.9)


def test_ribbon_vertices_carry_the_deviation_and_colours_rise_with_it():
    nominal = nominal_trace()
    s = arc_length(nominal)
    vertices, faces, values = deviation_ribbon(nominal, deviation(s), width_mm=2.0, lift_mm=0.01)
    assert len(vertices) == 2 * len(nominal) and len(faces) == 2 * (len(nominal) - 1)
    assert np.allclose(values[0::2], deviation(s)) and np.allclose(values[1::2], deviation(s))
    # both edges 1 mm off the trace in the top view, 10 um above it
    assert np.allclose(np.abs(vertices[0::2, 1] - 5.0), 1.0) and np.allclose(vertices[0::2, 2], nominal[:, 2] + 0.01)
    surface = ScalarSurface("dev", vertices, faces, values, values.min(), values.max(), signed=True)
    limit = float(np.abs(values).max())
    colors = np.asarray(scalar_surface_mesh(surface, limit).visual.vertex_colors)[:, :3].astype(int)
    order = np.argsort(values)
    warmth = colors[order, 0] - colors[order, 2]  # red minus blue
    # monotone (to the uint8 rounding of each channel), from blue (below nominal) to red (above)
    assert np.all(np.diff(warmth) >= -1) and warmth[-1] - warmth[0] > 200
    assert warmth[-1] > 100 and warmth[0] < -50 and np.corrcoef(values[order], warmth)[0, 1] > 0.98
    zero = scalar_surface_mesh(ScalarSurface("z", vertices, faces, np.zeros(len(values)), 0, 0, signed=True), limit)
    assert np.all(np.asarray(zero.visual.vertex_colors)[:, :3] >= 240)  # zero deviation is white


def test_standoff_errors_of_nominal_and_compensated_programs():
    nominal = nominal_trace()
    s = arc_length(nominal)
    samples_s = np.linspace(0, s[-1], 400)
    dz = deviation(samples_s)
    x = np.linspace(0.0, 40.0, 120)
    pts = np.column_stack([x, np.full(len(x), 5.0), 2.0 + 0.1 * x])
    real = pts.copy()
    real[:, 2] += deviation(arc_length(pts))
    n = len(pts) - 1
    dispense = np.ones(n, bool)
    dispense[:3] = False  # travel moves carry no error
    nominal_program = standoff_errors(pts[:-1] + [0, 0, STANDOFF], pts[1:] + [0, 0, STANDOFF], dispense, nominal,
                                      samples_s, dz, STANDOFF)
    compensated = standoff_errors(real[:-1] + [0, 0, STANDOFF], real[1:] + [0, 0, STANDOFF], dispense, nominal,
                                  samples_s, dz, STANDOFF)
    assert np.isnan(nominal_program[:3]).all() and np.isnan(compensated[:3]).all()
    mid_s = 0.5 * (arc_length(pts)[:-1] + arc_length(pts)[1:])
    # the nominal program is off by minus the deviation (to the chord's sagitta of a 1/6 mm^-1 sine)
    assert np.allclose(nominal_program[3:], -deviation(mid_s)[3:], atol=2e-4)
    assert np.abs(compensated[3:]).max() < 2e-4  # the compensated one only by its chord error


def _draw(viser_server, scene: FocusScene) -> tuple[SceneBuilder, SceneRegistry]:
    registry = SceneRegistry()
    builder = SceneBuilder(viser_server, registry)
    builder.draw(scene)
    return builder, registry


def test_one_shared_scale_and_legends_that_match_the_data(viser_server):
    nominal = nominal_trace()
    samples_s = np.linspace(0, arc_length(nominal)[-1], 300)
    dz = deviation(samples_s)
    ribbon = ribbon_surface("t1 deviation", nominal, samples_s, dz, 2.0, 0.01)
    pts = nominal[::10] + [0, 0, STANDOFF]
    seg = ToolpathSegments(pts[:-1], pts[1:], np.ones(len(pts) - 1, bool), np.zeros(len(pts) - 1, np.int64),
                           np.zeros(len(pts) - 1), np.zeros(len(pts) - 1))
    errors = standoff_errors(seg.starts, seg.ends, seg.dispense, nominal, samples_s, dz, STANDOFF)
    probes = ProbeSet("run", measured=nominal[::40] + [0, 0, 0.001], deviation_mm=np.full(5, 0.001))
    sd = ScalarSurface("posterior sd", nominal[:3] + [0, 0, 1], np.array([[0, 1, 2]]), np.array([0.001, 0.002, 0.003]),
                       0.0, 0.003)
    scene = FocusScene({"job_id": "j"}, "t", nominal[:3], np.array([[0, 1, 2]]), probes=(probes,),
                       toolpaths=(Toolpath("nominal", seg, "nominal", errors),), scalar_surfaces=(ribbon, sd))
    builder, registry = _draw(viser_server, scene)
    legends = {legend["name"]: legend for legend in registry.snapshot()["legends"]}
    signed = legends["signed"]
    every = np.concatenate([ribbon.values, errors, probes.deviation_mm]) * 1000
    limit = np.abs(every).max()
    assert signed["unit"] == "µm" and signed["lo"] == pytest.approx(-limit) and signed["hi"] == pytest.approx(limit)
    assert signed["data_min"] == pytest.approx(every.min()) and signed["data_max"] == pytest.approx(every.max())
    assert signed["items"] == 3
    assert legends["map:posterior sd"]["lo"] == 0 and legends["map:posterior sd"]["hi"] == pytest.approx(3.0)
    assert legends["map:posterior sd"]["data_max"] == pytest.approx(3.0)
    handles = {name: h for name, (_g, h) in builder._handles.items()}
    dispense = handles["/focus/toolpaths/nominal/dispense"]
    expected = deviation_colors(errors, limit / 1000)
    assert np.array_equal(np.asarray(dispense.colors)[:, 0], expected)  # each move in its error's colour
    measured = handles["/focus/probes/run/measured"]
    # the probes' 1 um deviation is pale on the shared scale (not full red as on its own)
    assert np.all(np.asarray(measured.colors)[:, 2] > 200)
    nodes = registry.snapshot()["nodes"]
    assert nodes["/focus/fields/t1_deviation"]["group"] == "deviation"
    assert nodes["/focus/toolpaths/nominal/dispense"]["colored_by"] == "standoff_error"
    html = legend_html(signed)
    assert "µm" in html and f"{-limit:.3g}" in html and f"{limit:.3g}" in html and "linear-gradient" in html


def test_scene_without_signed_values_has_no_signed_legend():
    scene = FocusScene({}, "t", probes=(ProbeSet("plan", planned=np.zeros((3, 3))),))
    assert scene_legends(scene) == []
