"""Parsed part meshes, cached per process by content hash and bounded by the bytes they
hold with what jobs build on them (ray structure, edge grid)."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import trimesh

from app.parts.intake import parse_mesh
from app.parts.lru import ByteLru
from app.platform.blobs import BlobStore
from app.platform.models import Part

MESH_CACHE_BYTES = 2 ** 30  # default bound of a process's mesh cache
EMBREE_BYTES_PER_FACE = 160  # embree BVH + its float32 copy of the triangles (measured ~120-160)


def _nbytes(value: Any) -> int:
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, tuple):  # NamedTuples of arrays (the edge grid)
        return sum(_nbytes(v) for v in value)
    return 0


def mesh_bytes(mesh: trimesh.Trimesh) -> int:
    """Memory (bytes) a parsed mesh holds with what has been built on it: vertex and face
    arrays, trimesh's cached arrays (normals, edges, ...), the edge grid, and the ray
    intersector (estimated per face once built)."""
    total = int(mesh.vertices.nbytes + mesh.faces.nbytes)
    cache = getattr(mesh, "_cache", None)
    values = dict(getattr(cache, "cache", {}) or {})
    total += sum(_nbytes(v) for v in values.values())
    ray_cache = getattr(getattr(getattr(mesh, "ray", None), "_cache", None), "cache", None) or {}
    if ray_cache.get("_scene") is not None:  # embree's scene, built on the first ray query
        total += EMBREE_BYTES_PER_FACE * len(mesh.faces)
    return total


class MeshCache:
    """Parsed meshes by sha256, with what jobs build on them (the ray-casting structure and
    the edge grid live on the trimesh object), bounded by BYTES (least recently used out).

    A job that needs the part placed in machine coordinates gets a cached placed copy
    (:meth:`placed`), so its ray structure is built once per part and placement too.
    ``max_bytes``: the bound (default ``MESH_CACHE_BYTES``, 1 GiB); each access re-measures
    the entry, since structures are built lazily after it was stored.

    ``store`` (optional, :class:`app.parts.cache.MeshStore`): a disk tier shared by
    processes: a parsed mesh is read from it instead of parsing, what was built on a mesh
    (face normals, edge grid) is attached from it, and :meth:`persist` writes it back.
    """

    def __init__(self, blobs: BlobStore, max_bytes: int | None = None, store: Any = None) -> None:
        self.blobs = blobs
        self.store = store
        self._items = ByteLru(MESH_CACHE_BYTES if max_bytes is None else max_bytes)
        self._parse_lock = threading.Lock()
        self._keys: dict[Any, str] = {}  # memory key -> disk key, for persist()
        # lookups answered from memory or not, by mesh (parsed) and placed copy
        self.counts = {"mesh_hits": 0, "mesh_misses": 0, "placed_hits": 0, "placed_misses": 0}

    @property
    def max_bytes(self) -> int:
        return self._items.max_bytes

    @property
    def bytes(self) -> int:
        """Bytes held now (re-measured)."""
        for key in list(self._items._items):
            mesh = self._items._items.get(key, (None, 0))[0]
            if mesh is not None:
                self._items.resize(key, mesh_bytes(mesh))
        return self._items.bytes

    def put(self, sha256: str, mesh: trimesh.Trimesh) -> None:
        self._items.put(sha256, mesh, mesh_bytes(mesh))

    def parts(self) -> set[str]:
        """The sha256 of every part held (parsed, or placed)."""
        return {key if isinstance(key, str) else key[0] for key in list(self._items._items)}

    def _count(self, name: str) -> None:
        self.counts[name] = self.counts.get(name, 0) + 1

    def cached(self, key: Any) -> trimesh.Trimesh | None:
        """The cached mesh under ``key`` (a sha256, or (sha256, placement matrix bytes)) or None."""
        mesh = self._items.get(key)
        if mesh is not None:
            self._items.resize(key, mesh_bytes(mesh))
        return mesh

    def mesh(self, part: Part) -> trimesh.Trimesh:
        cached = self.cached(part.sha256)
        if cached is not None:
            self._count("mesh_hits")
            return cached
        with self._parse_lock:  # one parse per part, even when jobs ask at once
            cached = self._items.get(part.sha256)
            if cached is not None:
                self._count("mesh_hits")
                return cached
            self._count("mesh_misses")
            mesh = self.store.load_mesh(part.sha256) if self.store is not None else None
            if mesh is None:
                mesh = parse_mesh(self.blobs.read(part.sha256), part.format, max_unzipped_bytes=2**40)
                if self.store is not None:
                    self.store.save_mesh(part.sha256, mesh)
            if self.store is not None:
                self._keys[part.sha256] = part.sha256
                self.store.attach(part.sha256, mesh)
            self.put(part.sha256, mesh)
        return mesh

    def placed(self, part: Part, placement: Any) -> trimesh.Trimesh:
        """The part's mesh moved by ``placement`` (anything with ``matrix()`` -> 4 x 4; the
        mesh itself for None), cached per part and placement."""
        mesh = self.mesh(part)
        if placement is None:
            return mesh
        matrix = placement.matrix()
        key = (part.sha256, np.asarray(matrix, dtype=float).round(12).tobytes())
        cached = self.cached(key)
        self._count("placed_misses" if cached is None else "placed_hits")
        if cached is None:
            cached = mesh.copy()
            cached.apply_transform(matrix)
            if self.store is not None:
                from app.parts.cache import mesh_key

                self._keys[key] = mesh_key(part.sha256, matrix)
                self.store.attach(self._keys[key], cached)
            self._items.put(key, cached, mesh_bytes(cached))
        return cached

    def persist(self) -> int:
        """Write what jobs built on the held meshes to ``store`` (when it has more than
        the stored entry); returns the number of entries written."""
        if self.store is None:
            return 0
        written = 0
        for key, disk_key in list(self._keys.items()):
            mesh = self._items.get(key)
            if mesh is not None:
                written += bool(self.store.persist(disk_key, mesh))
        return written
