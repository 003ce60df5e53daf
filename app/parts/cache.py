"""Per-part precomputations that outlive the process: content-addressed cache files.

Compute jobs run each in a fresh child process, so what a job builds on a part (the parsed
mesh, its face normals, the edge grid of exact draping, a probe run's fitted field) would
be rebuilt by every job.  This store keeps such arrays as files under
``<data_dir>/part-cache/v<FORMAT_VERSION>/<kind>/<sha256 of the key>.arr`` and hands them
back memory-mapped (copy on write), so the next process pays a page-cache read instead of
the build.

* **Keyed by content.**  The key names what the arrays were derived from (a mesh's sha256,
  a placement matrix, a probe run id and sigma); the kind and ``FORMAT_VERSION`` are part
  of the path, so a change of layout never reads an old file.
* **Written atomically.**  A temporary file in the same directory, fsynced, renamed into
  place: readers see a whole file or none, never a partial one; no locks.  When two
  processes build the same entry, the last rename wins with identical content.
* **Checked when read.**  Magic, header, key, the software version that wrote it, total
  length and a CRC-32 of every array;
  anything wrong (truncated, corrupt, another key) is a miss, the file is removed and the
  caller rebuilds.
* **Bounded.**  After each write the directory is trimmed to ``max_bytes``, least
  recently used out (a hit touches the file's mtime).  A reader that has mapped a file
  keeps its pages when another process evicts it (POSIX unlink semantics).

File layout: ``MAGIC`` (8 bytes), header length (uint64 LE), the JSON header (arrays:
name, dtype, shape, offset, nbytes, crc32; key, kind, meta, total), then each array
C-contiguous at a 64-byte aligned offset.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import struct
import threading
import time
import zlib
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from app.platform.blobs import write_atomically
from app.probing.travel_height import FACE_BOXES

log = logging.getLogger("conforma.part_cache")
FORMAT_VERSION = 1
MAGIC = b"CFPCACHE"
SUFFIX = ".arr"
_ALIGN = 64


def _aligned(n: int) -> int:
    return (n + _ALIGN - 1) // _ALIGN * _ALIGN


def _software() -> str:
    """The software version: a parser or builder of another version may give other arrays."""
    import app

    return str(app.__version__)


def _crc(array: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(array).data.cast("B")) if array.nbytes else 0


class CacheStats:
    """What this process's store did (counters by kind; seconds spent loading/writing)."""

    def __init__(self) -> None:
        self.hits: dict[str, int] = {}
        self.misses: dict[str, int] = {}
        self.writes: dict[str, int] = {}
        self.rejected: dict[str, int] = {}
        self.load_s = 0.0
        self.write_s = 0.0
        self._lock = threading.Lock()

    def count(self, table: dict[str, int], kind: str) -> None:
        with self._lock:
            table[kind] = table.get(kind, 0) + 1

    def to_dict(self) -> dict[str, Any]:
        return {"hits": dict(self.hits), "misses": dict(self.misses), "writes": dict(self.writes),
                "rejected": dict(self.rejected), "load_s": round(self.load_s, 4), "write_s": round(self.write_s, 4)}


class PartCache:
    """Content-addressed array files under ``root``, bounded by ``max_bytes`` (LRU)."""

    def __init__(self, root: Path, max_bytes: int) -> None:
        self.root = Path(root)
        self.max_bytes = int(max_bytes)
        self.stats = CacheStats()

    # paths -------------------------------------------------------------------------
    @property
    def directory(self) -> Path:
        return self.root / f"v{FORMAT_VERSION}"

    def path(self, kind: str, key: str) -> Path:
        """The file of ``(kind, key)`` (kind: a short name; key: any string)."""
        return self.directory / kind / (hashlib.sha256(key.encode()).hexdigest() + SUFFIX)

    def files(self) -> list[Path]:
        """Every finished cache file (temporary files excluded)."""
        if not self.directory.exists():
            return []
        return [p for p in self.directory.glob(f"*/*{SUFFIX}") if not p.name.startswith(".")]

    @property
    def bytes(self) -> int:
        total = 0
        for p in self.files():
            try:
                total += p.stat().st_size
            except FileNotFoundError:
                pass
        return total

    # read --------------------------------------------------------------------------
    def load(self, kind: str, key: str) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
        """(arrays memory-mapped copy-on-write, meta) of ``(kind, key)``, or None (a miss).

        A file that fails any check is removed (unless another process replaced it
        meanwhile) and reported as a miss."""
        t0 = time.perf_counter()
        path = self.path(kind, key)
        found = None
        try:
            with open(path, "rb") as handle:  # one open file: header and arrays of the same inode
                try:
                    found = self._read(handle, kind, key)
                except (OSError, ValueError, KeyError, TypeError, struct.error) as exc:
                    log.warning("part cache: ignoring %s (%s: %s); it will be rebuilt", path, type(exc).__name__, exc)
                    self.stats.count(self.stats.rejected, kind)
                    self._unlink_if_same(path, os.fstat(handle.fileno()).st_ino)
        except FileNotFoundError:
            pass
        self.stats.load_s += time.perf_counter() - t0
        self.stats.count(self.stats.misses if found is None else self.stats.hits, kind)
        if found is not None:
            try:
                os.utime(path)  # least recently used goes first
            except OSError:
                pass
        return found

    @staticmethod
    def _unlink_if_same(path: Path, inode: int) -> None:
        try:
            if os.stat(path).st_ino == inode:
                path.unlink(missing_ok=True)
        except FileNotFoundError:
            pass

    def _read(self, handle: Any, kind: str, key: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        size = os.fstat(handle.fileno()).st_size
        head = handle.read(16)
        if len(head) < 16 or head[:8] != MAGIC:
            raise ValueError("not a part cache file")
        (header_len,) = struct.unpack("<Q", head[8:])
        if header_len > min(size, 2 ** 24):
            raise ValueError(f"header length {header_len} beyond the file")
        header = json.loads(handle.read(header_len))
        if header["version"] != FORMAT_VERSION or header["kind"] != kind or header["key"] != key:
            raise ValueError("another version, kind or key")
        if header.get("software") != _software():
            raise ValueError(f"written by Conforma {header.get('software')!r}, this is {_software()!r}")
        if header["total"] != size:
            raise ValueError(f"file is {size} bytes, its header says {header['total']} (partial)")
        arrays: dict[str, np.ndarray] = {}
        for item in header["arrays"]:
            dtype, shape = np.dtype(item["dtype"]), tuple(item["shape"])
            if item["nbytes"] == 0:
                arrays[item["name"]] = np.zeros(shape, dtype=dtype)
                continue
            if item["offset"] + item["nbytes"] > size or dtype.itemsize * int(np.prod(shape)) != item["nbytes"]:
                raise ValueError(f"array {item['name']!r} does not fit the file")
            array = np.memmap(handle, dtype=dtype, mode="c", offset=item["offset"], shape=shape)
            if _crc(array) != item["crc32"]:
                raise ValueError(f"array {item['name']!r} fails its checksum (corrupt)")
            arrays[item["name"]] = array
        return arrays, header.get("meta", {})

    # write -------------------------------------------------------------------------
    def store(self, kind: str, key: str, arrays: dict[str, np.ndarray], meta: dict[str, Any] | None = None) -> bool:
        """Write ``arrays`` (name -> array) as ``(kind, key)`` atomically, then trim the
        store to its bound.  False (logged) when the entry alone exceeds the bound or the
        disk refuses; the caller goes on without the cache."""
        t0 = time.perf_counter()
        items: list[dict[str, Any]] = []
        offset = 0
        prepared = {name: np.ascontiguousarray(a) for name, a in arrays.items()}
        for name, array in prepared.items():
            if array.dtype.hasobject:
                raise TypeError(f"array {name!r} holds Python objects")
            items.append({"name": name, "dtype": array.dtype.str, "shape": list(array.shape),
                          "nbytes": int(array.nbytes), "crc32": _crc(array), "offset": 0})
        header: dict[str, Any] = {"version": FORMAT_VERSION, "software": _software(), "kind": kind, "key": key,
                                  "meta": meta or {},
                                  "arrays": items, "total": 0}
        text, start = b"", -1
        while _aligned(16 + len(text)) != start:  # offsets change the header's length: settle
            start = offset = _aligned(16 + len(text))
            for item in items:
                item["offset"] = offset
                offset = _aligned(offset + item["nbytes"])
            header["total"] = offset
            text = json.dumps(header).encode()
        if offset > self.max_bytes:
            log.info("part cache: %s entry of %d bytes exceeds the bound %d; not stored", kind, offset, self.max_bytes)
            return False
        target = self.path(kind, key)
        try:
            def write(handle: BinaryIO) -> None:
                handle.write(MAGIC + struct.pack("<Q", len(text)) + text)
                for item, array in zip(items, prepared.values()):
                    handle.seek(item["offset"])
                    handle.write(array.data.cast("B") if array.nbytes else b"")
                handle.truncate(offset)

            write_atomically(target, write)
        except OSError as exc:
            log.warning("part cache: could not write %s: %s", target, exc)
            return False
        self.stats.write_s += time.perf_counter() - t0
        self.stats.count(self.stats.writes, kind)
        self.evict(keep=target)
        return True

    def evict(self, keep: Path | None = None) -> list[Path]:
        """Remove least recently used files until the store holds <= ``max_bytes``;
        ``keep`` (the entry just written) goes last.  Returns the removed paths."""
        entries = []
        for p in self.files():
            try:
                st = p.stat()
            except FileNotFoundError:
                continue
            entries.append((p == keep, st.st_mtime_ns, st.st_size, p))
        entries.sort(key=lambda e: (e[0], e[1]))
        total = sum(e[2] for e in entries)
        removed = []
        for _, _, size, p in entries:
            if total <= self.max_bytes:
                break
            p.unlink(missing_ok=True)
            total -= size
            removed.append(p)
        return removed


# ---------------------------------------------------------------------------------------
# What the service stores: a part's parsed mesh, what jobs build on a (placed) mesh, and
# the fitted field of a probe run.  Each adapter turns core objects into arrays and back.

def mesh_key(sha256: str, matrix: np.ndarray | None = None) -> str:
    """The cache key of a part's mesh (its file's sha256), placed by ``matrix`` (4 x 4) or not."""
    if matrix is None:
        return sha256
    return f"{sha256}@{hashlib.sha256(np.asarray(matrix, dtype=float).round(12).tobytes()).hexdigest()[:32]}"




class MeshStore:
    """Meshes and their per-mesh precomputations in a :class:`PartCache`.

    * ``"mesh"``: a part's parsed vertices (V, 3) float64 mm and faces (F, 3) int64,
      keyed by the file's sha256 (parsing + merging a 1M-face STL costs seconds);
    * ``"derived"``: per (placed) mesh, what jobs built on it: face normals (F, 3), the
      faces' top-view boxes of the probe program's travel check (F, 2) x 2
      (:mod:`app.probing.travel_height`) and the edge grid of exact draping
      (:mod:`app.geometry.edge_grid`), attached to the next process's mesh before the
      core asks for them.

    The ray-casting structure (embree's BVH) is not stored: embree cannot serialise it,
    and its numpy preparation (float32 vertices, int32 faces) is a small part of its build.
    """

    def __init__(self, cache: PartCache) -> None:
        self.cache = cache
        self._have: dict[str, frozenset[str]] = {}  # derived arrays already on disk, by key
        self._lock = threading.Lock()

    def load_mesh(self, sha256: str) -> Any:
        import trimesh

        found = self.cache.load("mesh", sha256)
        if found is None:
            return None
        arrays, _ = found
        vertices, faces = arrays["vertices"], arrays["faces"]
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3 or (
                len(faces) and (int(faces.min()) < 0 or int(faces.max()) >= len(vertices))):
            self.cache.path("mesh", sha256).unlink(missing_ok=True)
            return None
        return trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)

    def save_mesh(self, sha256: str, mesh: Any) -> None:
        self.cache.store("mesh", sha256, {"vertices": np.asarray(mesh.vertices, dtype=float),
                                          "faces": np.asarray(mesh.faces, dtype=np.int64)})

    def attach(self, key: str, mesh: Any) -> list[str]:
        """Give ``mesh`` what was stored under ``key``; returns the names attached."""
        from app.geometry.edge_grid import attach_edge_grid, edge_grid_from_arrays

        found = self.cache.load("derived", key)
        if found is None:
            return []
        arrays, meta = found
        attached: list[str] = []
        try:
            if meta.get("faces") != len(mesh.faces) or meta.get("vertices") != len(mesh.vertices):
                raise ValueError("stored for another mesh")
            if "face_normals" in arrays:
                if arrays["face_normals"].shape != mesh.faces.shape:
                    raise ValueError("face normals of another shape")
                mesh._cache["face_normals"] = arrays["face_normals"]
                attached.append("face_normals")
            if "box_lo" in arrays:
                if arrays["box_lo"].shape != (len(mesh.faces), 2) or arrays["box_hi"].shape != (len(mesh.faces), 2):
                    raise ValueError("face boxes of another shape")
                mesh._cache[FACE_BOXES] = (arrays["box_lo"], arrays["box_hi"])
                attached.append("face_boxes")
            if "a" in arrays:
                attach_edge_grid(mesh, edge_grid_from_arrays(arrays))
                attached.append("edge_grid")
        except (ValueError, KeyError, IndexError) as exc:
            log.warning("part cache: derived entry %s does not fit its mesh (%s); rebuilding", key, exc)
            self.cache.path("derived", key).unlink(missing_ok=True)
            return []
        with self._lock:
            self._have[key] = frozenset(attached)
        return attached

    def persist(self, key: str, mesh: Any) -> bool:
        """Store what jobs built on ``mesh`` when it is more than what is stored already."""
        from app.geometry.edge_grid import cached_edge_grid, edge_grid_arrays

        arrays: dict[str, np.ndarray] = {}
        normals = mesh._cache["face_normals"]
        if normals is not None and np.shape(normals) == mesh.faces.shape:
            arrays["face_normals"] = np.asarray(normals)
        boxes = mesh._cache[FACE_BOXES]
        if isinstance(boxes, tuple) and len(boxes) == 2:
            arrays["box_lo"], arrays["box_hi"] = np.asarray(boxes[0]), np.asarray(boxes[1])
        grid = cached_edge_grid(mesh)
        if grid is not None:
            arrays.update(edge_grid_arrays(grid))
        names = frozenset(name for name, array in (("face_normals", "face_normals"), ("face_boxes", "box_lo"),
                                                   ("edge_grid", "a")) if array in arrays)
        with self._lock:
            if not names or names <= self._have.get(key, frozenset()):
                return False
        done = self.cache.store("derived", key, arrays,
                                {"faces": len(mesh.faces), "vertices": len(mesh.vertices)})
        if done:
            with self._lock:
                self._have[key] = names
        return done


class FieldFitStore:
    """Fitted fields (:class:`app.reconstruction.field.FieldFit`) by (probe run id, sigma)."""

    def __init__(self, cache: PartCache) -> None:
        self.cache = cache

    @staticmethod
    def _key(key: Any) -> str:
        return json.dumps(list(key) if isinstance(key, tuple) else key)

    def load(self, key: Any) -> tuple[Any, int] | None:
        """(fit, bytes) or None."""
        from dataclasses import fields

        from app.probing.deviation_prior import DeviationPosterior, DeviationPrior, Sites
        from app.reconstruction.field import FieldFit, fit_bytes

        found = self.cache.load("field", self._key(key))
        if found is None:
            return None
        a, meta = found
        try:
            names = {f.name for f in fields(DeviationPrior)}
            prior = DeviationPrior(**{k: v for k, v in meta["prior"].items() if k in names})
            stations = Sites(np.asarray(a["xy"]), np.asarray(a["grad"]))
            kept = np.asarray(a["kept"], dtype=bool)
            factor = (np.asarray(a["factor"]), bool(meta["lower"]))
            if factor[0].shape != (int(kept.sum()),) * 2 or a["alpha"].shape != (int(kept.sum()),):
                raise ValueError("factor and kept stations disagree")
            posterior = DeviationPosterior(prior, np.asarray(a["center"]), stations.take(np.flatnonzero(kept)),
                                           np.asarray(a["alpha"]), factor)
            fit = FieldFit(posterior, stations, np.asarray(a["dz"]), kept, tuple(int(i) for i in a["outliers"]),
                           np.asarray(a["trace"]), np.asarray(a["s_mm"]))
        except (KeyError, TypeError, ValueError) as exc:
            log.warning("part cache: field entry %s unusable (%s); refitting", key, exc)
            self.cache.path("field", self._key(key)).unlink(missing_ok=True)
            return None
        if meta.get("check") is not None:  # a checked field (app.reconstruction.field_trust)
            from app.reconstruction.field_trust import FieldCheck, Verification

            c = meta["check"]
            check = FieldCheck(fit, c["learned"], None if c["verification"] is None else
                               Verification.from_arrays(c["verification"]), float(c["coverage"]), float(c["target_mm"]))
            return (check, meta.get("refinement")), fit_bytes(fit)
        if meta.get("pair"):  # (fit, its normal-iteration report): see reconstruct's field rebuild
            return (fit, meta.get("refinement")), fit_bytes(fit)
        return fit, fit_bytes(fit)

    def store(self, key: Any, value: Any) -> bool:
        """Store a fitted field, or a (fit, refinement report or None) pair."""
        from dataclasses import asdict

        pair = isinstance(value, tuple)
        fit, refinement = value if pair else (value, None)
        check = None
        if hasattr(fit, "fit"):  # a checked field: its fit's arrays, the check's figures in the meta
            v = fit.verification
            check = {"learned": fit.learned, "verification": None if v is None else v.arrays(),
                     "coverage": fit.coverage, "target_mm": fit.target_mm}
            fit = fit.fit
        post = fit.posterior
        return self.cache.store("field", self._key(key), {
            "xy": fit.stations.xy, "grad": fit.stations.grad, "dz": fit.dz, "kept": fit.kept,
            "outliers": np.asarray(fit.outliers, dtype=np.int64), "trace": np.asarray(fit.trace, dtype=np.int64),
            "s_mm": fit.s_mm, "center": post.center, "alpha": post.alpha, "factor": post.factor[0],
        }, {"prior": asdict(post.prior), "lower": bool(post.factor[1]), "pair": pair,
            "refinement": json.loads(json.dumps(refinement, default=float)),
            "check": json.loads(json.dumps(check, default=float))})


def part_cache_for(settings: Any) -> PartCache | None:
    """The store of ``settings`` (``<data_dir>/part-cache``, ``CONFORMA_CACHE_MB``); None when 0."""
    if settings.cache_mb <= 0:
        return None
    return PartCache(settings.data_dir / "part-cache", int(settings.cache_mb * 2 ** 20))


JOURNAL = "journal.jsonl"
JOURNAL_MAX_BYTES = 2 ** 20


def record_job(cache: PartCache, job_id: str, kind: str, memory: dict[str, Any] | None = None) -> None:
    """Append what this process's store did for job ``job_id`` to ``<root>/journal.jsonl``
    (one JSON line; the file is rotated to ``journal.1.jsonl`` past 1 MiB).  ``memory``:
    what the process's in-memory cache did (``mesh_hits`` ..., ``process_job``: the how
    many-th job of the process, ``held``: the parts it held when the job started)."""
    path = cache.root / JOURNAL
    line = json.dumps({"job_id": job_id, "kind": kind, "pid": os.getpid(), **cache.stats.to_dict(),
                       "memory": memory or {}}) + "\n"
    try:
        cache.root.mkdir(parents=True, exist_ok=True)
        if path.exists() and path.stat().st_size > JOURNAL_MAX_BYTES:
            os.replace(path, cache.root / "journal.1.jsonl")
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line.encode())
        finally:
            os.close(fd)
    except OSError as exc:
        log.warning("part cache: could not write the journal: %s", exc)


def journal(cache_root: Path) -> list[dict[str, Any]]:
    """The journal's entries, oldest first (what tests and benchmarks read)."""
    entries = []
    for name in ("journal.1.jsonl", JOURNAL):
        path = Path(cache_root) / name
        if path.exists():
            entries += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return entries
