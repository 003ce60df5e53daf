"""Bench: the per-part cache on disk ("per-part precomputation paid once").

Run: .venv/bin/python -m pytest tests/bench/test_bench_part_cache.py -s -o addopts="" -q

Compute jobs run each in a fresh child process, so what one job builds on a part is lost
with its process unless it is stored: :mod:`app.parts.cache` keeps the parsed mesh, its face
normals and its edge grid as memory-mapped files keyed by the mesh's sha256.

1. In process, on the 1.34M-face S1 part: each precomputation built from scratch vs loaded
   from the store (what a child process does on a hit), and embree's ray structure split
   into its numpy preparation and the BVH build (which embree cannot serialise).
2. Through the service (process isolation, the default): two successive ``probe_plan`` jobs
   on the same part; each job's wall time (started -> finished) and what its process's
   store did (the journal).
"""

from __future__ import annotations

import time
from datetime import datetime

import numpy as np

from app.geometry.edge_grid import edge_grid
from app.parts.cache import MeshStore, PartCache, journal
from app.parts.intake import parse_mesh
from app.reference.s1 import s1_mesh, s1_traces
from tests.conftest import auth

OP = auth("operator")
GRID_MM = 0.06  # S1 at 0.06 mm: 1,344,002 faces


def _timed(fn):  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    value = fn()
    return value, time.perf_counter() - t0


def test_precomputations_built_vs_loaded_from_the_store(tmp_path):
    data = s1_mesh(grid_mm=GRID_MM).export(file_type="stl")
    mesh, t_parse = _timed(lambda: parse_mesh(data, "stl", max_unzipped_bytes=2 ** 40))
    _, t_normals = _timed(lambda: mesh.face_normals)
    _, t_grid = _timed(lambda: edge_grid(mesh))
    # embree: trimesh's numpy preparation (float64 copy, shift, scale, float32 / int32) ...
    def prep():  # type: ignore[no-untyped-def]
        v = np.array(mesh.vertices, dtype=np.float64)
        return ((v - v.min(axis=0)) * (100.0 / mesh.scale)).astype(np.float32), mesh.faces.astype(np.int32)
    _, t_prep = _timed(prep)
    # ... and the whole structure: scene + BVH build on the first query
    _, t_ray = _timed(lambda: mesh.ray.intersects_first([[30.0, 20.0, 100.0]], [[0.0, 0.0, -1.0]]))
    cache = PartCache(tmp_path, 2 ** 31)
    store = MeshStore(cache)
    _, t_save = _timed(lambda: (store.save_mesh("sha", mesh), store.persist("sha", mesh)))
    other = MeshStore(cache)  # another process
    loaded, t_load_mesh = _timed(lambda: other.load_mesh("sha"))
    names, t_attach = _timed(lambda: other.attach("sha", loaded))
    assert names == ["face_normals", "edge_grid"]
    _, t_grid_again = _timed(lambda: edge_grid(loaded))
    built = t_parse + t_normals + t_grid
    load = t_load_mesh + t_attach + t_grid_again
    print(f"\n\nPer-part store, S1 at {GRID_MM} mm, {len(mesh.faces):,} faces, {cache.bytes / 2**20:.0f} MiB on disk:")
    print("| precomputation | built | loaded |\n|---|---|---|")
    print(f"| parse + merge the STL | {t_parse:.2f} s | {t_load_mesh:.3f} s (mesh file) |")
    print(f"| face normals + edge grid | {t_normals:.2f} + {t_grid:.2f} s | {t_attach + t_grid_again:.3f} s |")
    print(f"| total stored | {built:.2f} s | {load:.3f} s ({built / load:.0f}x) |")
    print(f"| ray structure (not stored) | {t_ray:.2f} s, of which numpy preparation {t_prep:.3f} s | - |")
    print(f"(writing both entries: {t_save:.2f} s, once)")
    assert load < 0.25 * built


def _seconds(job: dict) -> float:
    return (datetime.fromisoformat(job["finished_at"]) - datetime.fromisoformat(job["started_at"])).total_seconds()


def test_the_second_job_on_a_1m_face_part_loads_the_precomputation(client, settings):
    from tests.helpers.jobs import wait_for

    data = s1_mesh(grid_mm=GRID_MM).export(file_type="stl")
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", data)}, headers=OP)
    assert part.status_code == 201, part.text
    trace = client.post(f"/api/v1/parts/{part.json()['id']}/traces", json=s1_traces()[4].to_api(), headers=OP)
    assert trace.status_code == 201, trace.text
    params = {"trace_id": trace.json()["id"], "method": "uniform", "count": 8}
    done = []
    for _ in range(2):
        response = client.post("/api/v1/jobs", json={"kind": "probe_plan", "params": params}, headers=OP)
        job = wait_for(client, response.json()["id"], timeout=600)
        assert job["status"] == "succeeded", job["error"]
        done.append(job)
    entries = {e["job_id"]: e for e in journal(settings.data_dir / "part-cache")}
    first, second = (entries[j["id"]] for j in done)
    t1, t2 = _seconds(done[0]), _seconds(done[1])
    print(f"\n\nTwo probe_plan jobs on the {GRID_MM} mm S1 part (1,344,002 faces), each in its own process:")
    print(f"first {t1:.2f} s (cache: {first}),\nsecond {t2:.2f} s (cache: {second});\n"
          f"second / first = {t2 / t1:.2f}, saved {t1 - t2:.2f} s")
    assert second["hits"].get("mesh") == 1 and not second["misses"].get("mesh")
    assert t2 < t1
