"""The dry run's 3-D preview scene: warnings beyond the first few are counted, not listed, and
a pour with a hole is drawn on the part's surface (a box top at z = 1) with the hole open."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.viewer.circuit_preview import LIFT_MM, NOTES_SHOWN, circuit_preview_scene


def test_the_preview_lists_the_first_warnings_and_counts_the_rest():
    mesh = trimesh.creation.box(extents=[40, 40, 2])                     # top at z = 1
    square = [[-5, -5], [5, -5], [5, 5], [-5, 5]]
    hole = [[-1, -1], [1, -1], [1, 1], [-1, 1]]
    warnings = [{"kind": "spacing", "message": f"warning {i}", "traces": []} for i in range(NOTES_SHOWN + 13)]
    scene = circuit_preview_scene("part_x", mesh, {"import_id": "cimp_x", "traces": [], "pads": [],
                                                   "areas": [{"exterior_xy_mm": square, "holes_xy_mm": [hole]}],
                                                   "warnings": warnings})
    listed = [n for n in scene.notes if n.startswith("spacing: ")]
    assert listed == [f"spacing: warning {i}" for i in range(NOTES_SHOWN)]
    assert scene.notes[-1].startswith("... and 13 more warnings")
    (pour,) = scene.scalar_surfaces
    assert np.allclose(pour.vertices[:, 2], 1.0 + LIFT_MM)                # on the surface, not under it
    tri = pour.vertices[pour.faces][:, :, :2]
    area = 0.5 * np.abs(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])).sum()
    assert area == pytest.approx(100.0 - 4.0, abs=1e-6)                   # the hole stays open
