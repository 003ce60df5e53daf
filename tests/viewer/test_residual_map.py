"""The verification residuals of a closed loop as a map on the part: each point on its trace's
nominal lifted by the measured deviation, its residual (measured - predicted) the value the
view colours on its own legend, flagged points ringed, flagged traces highlighted."""

from __future__ import annotations

import numpy as np

from app.viewer.deviation_map import scene_legends
from app.viewer.registry import SceneRegistry
from app.viewer.residual_map import residual_map
from app.viewer.scene_data import FocusScene, Polyline
from app.viewer.scenes import SceneBuilder
from tests.helpers.residuals import NOMINALS, VERDICT


def test_the_points_sit_on_their_traces_with_their_residuals():
    residuals = residual_map(VERDICT, ["t-ramp", "t-flat"], NOMINALS)
    assert residuals is not None
    # z: the nominal under the point (1 + 0.1 x on the ramp, 3 on the flat trace) + the measured deviation
    assert np.allclose(residuals.points, [[10, 5, 2.0 + 0.020], [30, 5, 4.0 - 0.010], [25, 20, 3.0 + 0.004]])
    assert np.allclose(residuals.residual_mm, [0.002, -0.006, -0.008])
    assert np.allclose(residuals.limit_mm, [0.006, 0.005, 0.010])
    assert residuals.flagged.tolist() == [False, True, True]        # outside its band; correction does not help
    assert residuals.trace_ids == ("t-ramp", "t-ramp", "t-flat")
    assert residual_map({"verification": []}, ["t-ramp"], NOMINALS) is None
    # a trace index the loop does not name: the nearest nominal gives the height
    other = residual_map({"verification": [{**VERDICT["verification"][2], "trace": 7}]}, ["t-ramp"], NOMINALS)
    assert other is not None and other.trace_ids == (None,) and np.isclose(other.points[0, 2], 3.004)


def test_the_view_draws_them_on_their_own_legend_and_rings_the_flagged(viser_server):
    residuals = residual_map(VERDICT, ["t-ramp", "t-flat"], NOMINALS)
    assert residuals is not None
    scene = FocusScene({"job_id": "loop"}, "loop", residuals=(residuals,),
                       polylines=(Polyline("flat worse than nominal", NOMINALS["t-flat"], role="flagged"),))
    legend = next(g for g in scene_legends(scene) if g.name.startswith("residual"))
    assert legend.unit == "µm" and np.isclose(legend.data_min_um, -8.0) and np.isclose(legend.data_max_um, 2.0)
    assert np.isclose(legend.lo_um, -8.0) and np.isclose(legend.hi_um, 8.0)          # symmetric about 0
    registry = SceneRegistry()
    builder = SceneBuilder(viser_server, registry)
    builder.draw(scene)
    nodes = {name: h for name, (_g, h) in builder._handles.items()}
    points = nodes["/focus/residuals/verification_residuals"]
    assert np.allclose(points.points, residuals.points, atol=1e-4)
    colors = np.asarray(points.colors, int)
    assert colors[2, 2] > colors[2, 0] and colors[0, 0] > colors[0, 2]   # -8 um blue, +2 um red-ish
    ring = nodes["/focus/residuals/verification_residuals/flagged"]
    assert np.allclose(ring.points, residuals.points[[1, 2]], atol=1e-4)
    snapshot = registry.snapshot()
    assert snapshot["nodes"]["/focus/residuals/verification_residuals"]["count"] == 3
    assert snapshot["nodes"]["/focus/traces/flat_worse_than_nominal"]["role"] == "flagged"
    assert any(g["name"].startswith("residual") for g in registry.legends())
