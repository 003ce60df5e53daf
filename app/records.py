"""Reading and writing stored records, shared by the routers and the job kinds.

Lookups raise :class:`app.errors.NotFound` naming the id; meshes are parsed once per
process and cached by content hash.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from dataclasses import replace
from collections.abc import Callable
from typing import Any, BinaryIO, TypeVar

import numpy as np
import trimesh
from sqlmodel import SQLModel, Session, col

from app.blobs import BlobStore
from app.errors import ConformaError, NotFound
from app.geometry.slope import SlopePolicy, check_slope
from app.geometry.tolerance import Tolerance
from app.geometry.traces import TracePolyline, build_nominal_trace, build_nominal_traces
from app.jobs.results import ProbePlanResult
from app.mesh_intake import intake, parse_mesh
from app.models import Artifact, Job, Machine, Part, Trace, new_id, utcnow

T = TypeVar("T", bound=SQLModel)
_LABELS = {Part: "part", Trace: "trace", Job: "job", Machine: "machine"}


def get_or_404(session: Session, model: type[T], record_id: str, *, field: str | None = None) -> T:
    """The record with ``record_id`` or a NotFound that names it."""
    record = session.get(model, record_id)
    if record is None:
        label = _LABELS.get(model, model.__name__.lower())
        raise NotFound(f"{label} {record_id!r} does not exist", field=field or f"{label}_id", value=record_id)
    return record


class ByteLru:
    """A thread-safe least-recently-used map bounded by the BYTES its values hold.

    ``put(key, value, nbytes)``; ``get(key)`` (None when absent) marks it used;
    ``resize(key, nbytes)`` re-states an entry's size (e.g. after derived structures were
    built on it).  Entries are dropped oldest first while the total exceeds ``max_bytes``;
    the newest entry always stays, even alone over the bound.
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict[Any, tuple[Any, int]] = OrderedDict()
        self._lock = threading.Lock()

    @property
    def bytes(self) -> int:
        with self._lock:
            return sum(n for _, n in self._items.values())

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Any) -> bool:
        return key in self._items

    def get(self, key: Any) -> Any:
        with self._lock:
            item = self._items.get(key)
            if item is None:
                return None
            self._items.move_to_end(key)
            return item[0]

    def put(self, key: Any, value: Any, nbytes: int) -> None:
        with self._lock:
            self._items[key] = (value, int(nbytes))
            self._items.move_to_end(key)
            self._evict()

    def resize(self, key: Any, nbytes: int) -> None:
        with self._lock:
            if key in self._items:
                self._items[key] = (self._items[key][0], int(nbytes))
                self._evict()

    def _evict(self) -> None:
        total = sum(n for _, n in self._items.values())
        while total > self.max_bytes and len(self._items) > 1:
            _, (_, n) = self._items.popitem(last=False)
            total -= n


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

    ``store`` (optional, :class:`app.part_cache.MeshStore`): a disk tier shared by
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
                from app.part_cache import mesh_key

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


class BackedLru(ByteLru):
    """A :class:`ByteLru` over an optional disk tier ``backing`` (an object with
    ``load(key) -> (value, nbytes) | None`` and ``store(key, value)``, e.g.
    :class:`app.part_cache.FieldFitStore`): a miss in memory asks the backing; a put writes
    through to it.  Without a backing it is a plain ByteLru."""

    def __init__(self, max_bytes: int, backing: Any = None) -> None:
        super().__init__(max_bytes)
        self.backing = backing

    def get(self, key: Any) -> Any:
        value = super().get(key)
        if value is None and self.backing is not None:
            loaded = self.backing.load(key)
            if loaded is not None:
                super().put(key, loaded[0], loaded[1])
                value = loaded[0]
        return value

    def put(self, key: Any, value: Any, nbytes: int) -> None:
        super().put(key, value, nbytes)
        if self.backing is not None:
            self.backing.store(key, value)


FIELD_FITS = BackedLru(64 * 2 ** 20)
"""Fitted fields of field-plan probe runs by (run id, sigma): fitted once per process, and
once per service when a compute process gives it a disk tier (``FIELD_FITS.backing``)."""


def add_artifact(
    session: Session,
    blobs: BlobStore,
    job_id: str,
    name: str,
    data: bytes,
    media_type: str,
    meta: dict[str, Any] | None = None,
) -> Artifact:
    """Store ``data`` content-addressed and list it as artifact ``name`` of ``job_id``."""
    sha = blobs.put(session, data)
    existing = session.query(Artifact).filter(col(Artifact.job_id) == job_id, col(Artifact.name) == name).one_or_none()
    if existing is not None:  # a retried attempt rewrites its artifact
        existing.sha256, existing.bytes, existing.media_type, existing.meta = sha, len(data), media_type, meta or {}
        session.add(existing)
        return existing
    artifact = Artifact(
        job_id=job_id, name=name, media_type=media_type, bytes=len(data), sha256=sha,
        meta=meta or {}, created_at=utcnow(),
    )
    session.add(artifact)
    return artifact


def store_part(session: Session, blobs: BlobStore, meshes: MeshCache, data: bytes | BinaryIO, fmt: str, name: str,
               max_unzipped_bytes: int, units: str | None = None, up: str | None = None,
               rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Part:
    """Parse, check and store an uploaded mesh as a part in mm, +Z up (added to ``session``,
    not committed).  When units or orientation change the file, the converted mesh is
    stored (binary PLY) beside the uploaded file (``source_sha256``).  ``data``: bytes or an
    open binary file (read in chunks where the format allows: binary STL)."""
    taken = intake(data, fmt, max_unzipped_bytes=max_unzipped_bytes, units=units, up=up, rotate_deg=rotate_deg)
    summary = taken.summary
    source = blobs.put(session, data) if isinstance(data, bytes) else blobs.put_file(session, data)
    sha, stored_format = source, fmt
    if taken.canonical is not None:
        sha, stored_format = blobs.put(session, taken.canonical), "ply"
    part = Part(
        id=new_id("part"), name=name, format=stored_format, faces=summary.faces, vertices=summary.vertices,
        bounds=summary.bounds, watertight=summary.watertight, volume_mm3=summary.volume_mm3,
        area_mm2=summary.area_mm2, sha256=sha, created_at=utcnow(), units=taken.frame.units,
        frame=taken.frame.describe(), source_sha256=source, source_format=fmt, warnings=taken.warnings,
        defects=summary.defects,
    )
    session.add(part)
    meshes.put(sha, taken.mesh)
    return part


def build_trace(meshes: MeshCache, part: Part, body: Any, field_prefix: str = "") -> Trace:
    """Drape/snap a trace (an API ``TraceCreate``) onto its part and make the record (not added).

    Errors from the geometry core name their field under ``field_prefix`` (the index of a
    trace in a bulk import)."""
    geometry = body.geometry.model_dump()
    return _trace_record(part, body, geometry, field_prefix,
                         lambda: build_nominal_trace(meshes.mesh(part), geometry, body.frame, Tolerance()))


def build_traces(meshes: MeshCache, part: Part, bodies: list[Any]) -> list[Trace]:
    """:func:`build_trace` of each body (API ``TraceCreate``), errors named by index; top-view
    traces are draped all at once (:func:`app.geometry.traces.build_nominal_traces`, the same
    polylines), anything else (or a batch with an error) one by one."""
    geometries = [body.geometry.model_dump() for body in bodies]
    nominals = None
    if all(body.frame == "xy" for body in bodies):
        nominals = build_nominal_traces(meshes.mesh(part), geometries, Tolerance())
    if nominals is None:
        return [build_trace(meshes, part, body, field_prefix=str(i)) for i, body in enumerate(bodies)]
    return [_trace_record(part, body, geometry, str(i), lambda n=nominal: n)
            for i, (body, geometry, nominal) in enumerate(zip(bodies, geometries, nominals))]


class DrapedAhead:
    """Top-view trace geometries (API ``TraceGeometry`` dicts) draped all at once before their
    records are made one by one (a circuit import's traces and probe rings): :meth:`build` is
    :func:`build_trace` with the batch's polyline when the body's geometry is one of them
    (equal to draping it alone), else (a batch with an error, another frame) draped alone,
    which names the error."""

    def __init__(self, meshes: MeshCache, part: Part, geometries: list[dict[str, Any]]) -> None:
        nominals = build_nominal_traces(meshes.mesh(part), geometries, Tolerance()) if geometries else None
        self._nominal = {} if nominals is None else {_geometry_key(g): n for g, n in zip(geometries, nominals)}

    def build(self, meshes: MeshCache, part: Part, body: Any, field_prefix: str = "") -> Trace:
        geometry = body.geometry.model_dump()
        nominal = self._nominal.get(_geometry_key(geometry)) if body.frame == "xy" else None
        if nominal is None:
            return build_trace(meshes, part, body, field_prefix=field_prefix)
        return _trace_record(part, body, geometry, field_prefix, lambda: nominal)


def _geometry_key(geometry: dict[str, Any]) -> str:
    return json.dumps(geometry, sort_keys=True)


def _trace_record(part: Part, body: Any, geometry: dict[str, Any], field_prefix: str,
                  nominal_of: Callable[[], TracePolyline]) -> Trace:
    policy = SlopePolicy(warn_deg=min(body.slope_warn_deg, body.slope_max_deg), max_deg=body.slope_max_deg)
    try:
        nominal = nominal_of()
        slope = check_slope(nominal.points, nominal.normals, policy)
    except ConformaError as exc:
        if field_prefix and exc.field:
            exc.field = f"{field_prefix}.{exc.field}"
        raise
    return Trace(
        id=new_id("trace"), part_id=part.id, name=body.name, frame=body.frame, geometry=geometry,
        standoff_mm=body.standoff_mm, width_mm=body.width_mm, feed_mm_min=body.feed_mm_min,
        length_mm=float(nominal.length_mm), z_min=float(nominal.z_range[0]), z_max=float(nominal.z_range[1]),
        nominal=replace(nominal, slope=slope.to_json()).to_dict(),
        created_at=utcnow(),
    )


def joint_trace_ranges(plan: Job) -> dict[str, tuple[int, int]] | None:
    """{trace id: [first, stop) point indices} of a joint probe plan (``probe_plan`` with
    ``trace_ids``; the same indices hold in its probe runs); None for a one-trace plan and
    for a field plan (its stations are shared by the traces, see ``reconstruct`` method field)."""
    if not (plan.params or {}).get("trace_ids"):
        return None
    return ProbePlanResult.of(plan).joint_ranges()
