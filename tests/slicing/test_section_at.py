"""A section with one outer boundary is taken whole, without decomposing it: the same islands."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.slicing.layers import section_at
from app.slicing.mesh_prep import prepare_mesh
from app.slicing.rings import Island, oriented
from tests.helpers.real_parts import cad_part, thin_tube


def _decomposed(solid, z: float) -> tuple[Island, ...]:
    """Every section decomposed into its islands (the outer ring: the largest of each)."""
    islands = []
    for part in solid.slice(float(z)).decompose():
        polys = [np.asarray(p, dtype=np.float64) for p in part.to_polygons()]
        if not polys:
            continue
        areas = [abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(np.roll(p[:, 0], -1), p[:, 1])))
                 for p in polys]
        k = int(np.argmax(areas))
        islands.append(Island(oriented(polys[k], ccw=True),
                              tuple(oriented(p, ccw=False) for i, p in enumerate(polys) if i != k)))
    islands.sort(key=lambda i: (float(i.outer[:, 1].min()), float(i.outer[:, 0].min())))
    return tuple(islands)


def _two_towers() -> trimesh.Trimesh:
    a, b = trimesh.creation.box((10.0, 10.0, 8.0)), trimesh.creation.annulus(2.0, 4.0, 8.0)
    b.apply_translation([20.0, 0.0, 0.0])
    return trimesh.util.concatenate([a, b])


@pytest.mark.parametrize("make", [thin_tube, lambda: cad_part(refine=1), _two_towers],
                         ids=["tube", "cad part", "two towers"])
def test_sections_equal_their_decomposition_island_for_island(make):
    prepared = prepare_mesh(make())
    several = 0
    for z in np.linspace(prepared.z_min + 0.01, prepared.z_max - 0.01, 60):
        ours, reference = section_at(prepared.solid, z), _decomposed(prepared.solid, z)
        assert len(ours) == len(reference) > 0
        several += len(ours) > 1
        for a, b in zip(ours, reference):
            assert len(a.holes) == len(b.holes)
            for ra, rb in zip(a.rings(), b.rings()):
                assert np.array_equal(ra, rb)
    if make is _two_towers:
        assert several == 60  # the several-island path is exercised too
