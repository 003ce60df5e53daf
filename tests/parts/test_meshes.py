"""The per-process caches of app/parts/lru.py and app/parts/meshes.py (bounded by bytes, and
what they keep) and the traces app/parts/traces.py builds draped in one batch (the same as one
by one)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import trimesh

from app.geometry.edge_grid import edge_grid
from app.geometry.placement import Placement
from app.parts.lru import ByteLru
from app.parts.meshes import MeshCache, mesh_bytes
from app.platform.blobs import BlobStore


def test_byte_lru_drops_the_least_recently_used_until_under_the_bound():
    lru = ByteLru(100)
    lru.put("a", 1, 40)
    lru.put("b", 2, 40)
    assert lru.get("a") == 1  # a is now the most recent
    lru.put("c", 3, 40)  # 120 > 100: b goes
    assert "b" not in lru and lru.get("a") == 1 and lru.get("c") == 3 and lru.bytes == 80
    lru.get("a")
    lru.resize("a", 90)  # a (just used) grew, e.g. structures built on it: c, the oldest now, goes
    assert "c" not in lru and lru.bytes == 90
    lru.put("huge", 4, 500)  # the newest stays even alone over the bound
    assert list(lru._items) == ["huge"]


def test_mesh_bytes_count_what_is_built_on_the_mesh():
    mesh = trimesh.creation.icosphere(subdivisions=4)
    bare = mesh_bytes(mesh)
    assert bare >= mesh.vertices.nbytes + mesh.faces.nbytes
    grid = edge_grid(mesh)
    with_grid = mesh_bytes(mesh)
    assert with_grid >= bare + grid.a.nbytes + grid.b.nbytes + grid.edges.nbytes
    mesh.ray.intersects_first(np.array([[0.0, 0.0, 5.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert mesh_bytes(mesh) >= with_grid + 100 * len(mesh.faces)


def test_mesh_cache_is_bounded_by_bytes_and_keeps_placed_meshes_with_their_ray_structure(tmp_path):
    one = trimesh.creation.icosphere(subdivisions=3)
    cache = MeshCache(BlobStore(tmp_path), max_bytes=int(2.5 * mesh_bytes(one)))
    part = SimpleNamespace(sha256="a" * 64, format="stl")
    cache.put(part.sha256, one)
    assert cache.mesh(part) is one
    placement = Placement.from_deg(dx=0.2, dy=-0.1, dz=0.03, rz_deg=0.3)
    placed = cache.placed(part, placement)
    assert placed is not one and cache.placed(part, placement) is placed  # one copy per placement
    assert np.allclose(placed.vertices, trimesh.transform_points(one.vertices, placement.matrix()))
    ray = placed.ray
    assert cache.placed(part, placement).ray is ray  # built once, kept with the cached copy
    assert cache.placed(part, None) is one
    # a third mesh does not fit in 2.5 meshes' bytes: the least recently used (the placed copy) goes
    cache.put("b" * 64, trimesh.creation.icosphere(subdivisions=3))
    assert cache.cached(part.sha256) is one and len(cache._items) == 2
    assert cache.bytes <= cache.max_bytes


def test_traces_draped_ahead_are_the_traces_built_one_by_one():
    import pytest

    from app.api.schemas import TraceCreate
    from app.geometry.drape import OffSurfaceError
    from app.parts.traces import DrapedAhead, build_trace
    from app.reference.boards import board_traces, dome_part

    dome = dome_part()
    mesh = dome.mesh(grid_mm=1.0)
    meshes, part = SimpleNamespace(mesh=lambda _part: mesh), SimpleNamespace(id="part_x")
    bodies = [TraceCreate(name=f"t{i}", geometry=g, frame="xy") for i, g in enumerate(board_traces(dome, 30))]
    ahead = DrapedAhead(meshes, part, [b.geometry.model_dump() for b in bodies])   # type: ignore[arg-type]
    assert len(ahead._nominal) == 30                                             # the batch was draped
    for body in bodies:
        batched, alone = ahead.build(meshes, part, body), build_trace(meshes, part, body)  # type: ignore[arg-type]
        assert batched.nominal == alone.nominal and batched.length_mm == alone.length_mm
    # a batch with a trace off the part drapes one by one: the good ones alike, the bad one named
    off = TraceCreate(name="off", geometry={"type": "polyline", "points": [[10, 10], [400, 10]]}, frame="xy")
    ahead = DrapedAhead(meshes, part, [b.geometry.model_dump() for b in (*bodies[:3], off)])  # type: ignore[arg-type]
    assert ahead._nominal == {}
    assert ahead.build(meshes, part, bodies[0]).nominal == build_trace(meshes, part, bodies[0]).nominal  # type: ignore[arg-type]
    with pytest.raises(OffSurfaceError, match="leaves the part|not over the part"):
        ahead.build(meshes, part, off, field_prefix="traces.3")                  # type: ignore[arg-type]
