"""The per-part cache on disk (app.parts.cache): round trips, corruption, eviction, and the
service's second compute job loading what the first one built (in process isolation)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from app.geometry.drape import drape_polyline
from app.geometry.edge_grid import cached_edge_grid, edge_grid
from app.parts.cache import MeshStore, PartCache, journal, mesh_key
from app.reference.s1 import s1_mesh, s1_traces
from tests.conftest import auth

OP = auth("operator")


def arrays(seed: int, n: int = 1000) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"x": rng.normal(size=(n, 3)), "i": rng.integers(0, 99, size=n, dtype=np.int32),
            "flag": rng.random(n) > 0.5, "empty": np.zeros((0, 2))}


def test_round_trip_is_exact_and_memory_mapped(tmp_path):
    cache = PartCache(tmp_path, 2 ** 24)
    stored = arrays(1)
    assert cache.store("k", "key-1", stored, {"note": "n"})
    loaded, meta = cache.load("k", "key-1")
    assert meta == {"note": "n"}
    for name, value in stored.items():
        assert loaded[name].dtype == value.dtype and np.array_equal(loaded[name], value)
    assert isinstance(loaded["x"], np.memmap)
    assert cache.load("k", "key-2") is None and cache.load("other", "key-1") is None
    assert cache.stats.hits == {"k": 1} and cache.stats.misses == {"k": 1, "other": 1}


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty"])
def test_a_partial_or_corrupt_file_is_a_miss_and_is_rebuilt(tmp_path, damage):
    cache = PartCache(tmp_path, 2 ** 24)
    cache.store("k", "key", arrays(2))
    path = cache.path("k", "key")
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[: len(data) - 100]
    elif damage == "flip":
        data[-50] ^= 0xFF  # inside the last array's bytes
    elif damage == "garbage":
        data[20:40] = b"x" * 20  # inside the JSON header
    else:
        data = bytearray()
    path.write_bytes(bytes(data))
    assert cache.load("k", "key") is None
    assert cache.stats.rejected == {"k": 1} and not path.exists()
    assert cache.store("k", "key", arrays(2))  # rebuilt
    assert np.array_equal(cache.load("k", "key")[0]["x"], arrays(2)["x"])


def test_eviction_keeps_the_bound_and_drops_the_least_recently_used(tmp_path):
    one = PartCache(tmp_path / "probe", 2 ** 30)
    one.store("k", "size", arrays(0))
    size = one.path("k", "size").stat().st_size
    cache = PartCache(tmp_path / "c", 3 * size + size // 2)  # room for three entries
    for i, key in enumerate(["a", "b", "c"]):
        cache.store("k", key, arrays(i))
        os.utime(cache.path("k", key), ns=(10**18 + i * 10**9,) * 2)  # a, b, c: oldest first
    assert cache.load("k", "a") is not None  # a is used again: b is now the oldest
    cache.store("k", "d", arrays(3))
    assert cache.bytes <= cache.max_bytes
    assert {key for key in "abcd" if cache.path("k", key).exists()} == {"a", "c", "d"}
    assert not cache.store("k", "huge", {"x": np.zeros(cache.max_bytes // 8 + 1)})  # alone over the bound
    assert not cache.path("k", "huge").exists() and cache.path("k", "d").exists()


def _hammer(root: str, seed: int, rounds: int, queue) -> None:  # type: ignore[no-untyped-def]
    """One process: store and load entries of a small store (others evict them meanwhile);
    puts the number of loads that came back wrong (not None and not the stored arrays)."""
    cache = PartCache(root, 5 * 40_000)  # room for about five of the ~33 kB entries
    wrong = 0
    for i in range(rounds):
        key = f"key-{(seed + i) % 8}"
        expected = arrays((seed + i) % 8, n=1500)
        cache.store("k", key, expected)
        for other in range(8):
            found = cache.load("k", f"key-{other}")
            if found is not None and not np.array_equal(found[0]["x"], arrays(other, n=1500)["x"]):
                wrong += 1
    queue.put(wrong)


def test_several_processes_share_the_store_without_locks(tmp_path):
    import multiprocessing

    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    workers = [context.Process(target=_hammer, args=(str(tmp_path), seed, 40, queue)) for seed in range(4)]
    for worker in workers:
        worker.start()
    results = [queue.get(timeout=120) for _ in workers]
    for worker in workers:
        worker.join(timeout=30)
        assert worker.exitcode == 0
    assert results == [0, 0, 0, 0]
    cache = PartCache(tmp_path, 5 * 40_000)
    assert cache.bytes <= cache.max_bytes + 40_000  # the bound (+ the one entry a writer keeps)
    assert not [p for p in cache.directory.glob("*/.tmp-*")]  # no temporary file left behind


def test_a_stored_edge_grid_drapes_exactly_like_a_fresh_one(tmp_path):
    cache = PartCache(tmp_path, 2 ** 28)
    store = MeshStore(cache)
    mesh = s1_mesh(grid_mm=1.0)
    xy = np.array([[5.0, 5.0], [30.0, 22.0], [55.0, 35.0]])  # across many facets of the S1 top
    fresh = drape_polyline(mesh, xy).points
    key = mesh_key("sha", np.eye(4))
    store.save_mesh("sha", mesh)
    assert store.persist(key, mesh) and not store.persist(key, mesh)  # once: nothing new the second time
    other = MeshStore(cache).load_mesh("sha")  # "another process"
    assert other is not mesh and np.array_equal(other.faces, mesh.faces)
    assert cached_edge_grid(other) is None
    assert MeshStore(cache).attach(key, other) == ["face_normals", "edge_grid"]
    grid = cached_edge_grid(other)
    assert grid is not None and edge_grid(other) is grid  # the core uses it, no rebuild
    assert np.array_equal(drape_polyline(other, xy).points, fresh)
    assert MeshStore(cache).attach(mesh_key("sha", 2 * np.eye(4)), other) == []  # another placement: a miss


def test_the_probe_programs_face_boxes_travel_with_the_mesh(tmp_path):
    from app.parts.cache import FACE_BOXES
    from app.probing import program, travel_height

    assert FACE_BOXES == travel_height.FACE_BOXES  # the key the probe program caches its boxes under
    mesh = s1_mesh(grid_mm=2.0)
    a, b = np.array([3.0, 4.0]), np.array([50.0, 30.0])
    top = program.segment_top_max(mesh, a, b, 0.1)
    MeshStore(PartCache(tmp_path, 2 ** 26)).persist("k", mesh)
    other = MeshStore(PartCache(tmp_path, 2 ** 26))
    copy = s1_mesh(grid_mm=2.0)  # the same part, parsed by another process
    assert other.attach("k", copy) == ["face_boxes"]
    lo, hi = copy._cache[FACE_BOXES]
    assert np.array_equal(lo, mesh._cache[FACE_BOXES][0]) and np.array_equal(hi, mesh._cache[FACE_BOXES][1])
    assert program.segment_top_max(copy, a, b, 0.1) == top


def test_a_derived_entry_of_another_mesh_is_refused(tmp_path):
    cache = PartCache(tmp_path, 2 ** 28)
    coarse, fine = s1_mesh(grid_mm=2.0), s1_mesh(grid_mm=1.0)
    edge_grid(coarse)
    MeshStore(cache).persist("k", coarse)
    assert MeshStore(cache).attach("k", fine) == [] and cached_edge_grid(fine) is None
    assert not cache.path("derived", "k").exists()


def _job(client, kind: str, params: dict, timeout: float = 120) -> dict:
    from tests.helpers.jobs import wait_for

    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=timeout)
    assert done["status"] == "succeeded", done["error"]
    return done


@pytest.fixture
def fresh_process_client(settings_factory):  # type: ignore[no-untyped-def]
    """A service whose compute processes each serve one job (the disk tier between processes)."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    settings = settings_factory(compute_recycle_jobs=1)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client, settings


def test_the_second_compute_job_on_a_part_loads_what_the_first_built(fresh_process_client):
    client, settings = fresh_process_client
    assert settings.compute_isolation == "process" and settings.cache_mb > 0
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=1.0).export(file_type="stl"))},
                       headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[4].to_api(), headers=OP).json()
    params = {"trace_id": trace["id"], "method": "uniform", "count": 8}
    first = _job(client, "probe_plan", params)
    second = _job(client, "probe_plan", params)
    entries = {e["job_id"]: e for e in journal(settings.data_dir / "part-cache")}
    one, two = entries[first["id"]], entries[second["id"]]
    assert one["misses"].get("mesh") == 1 and one["writes"].get("mesh") == 1 and not one["hits"]
    assert two["hits"].get("mesh") == 1 and not two["misses"].get("mesh") and not two["writes"].get("mesh")
    assert one["writes"].get("derived") == 1 and two["hits"].get("derived") == 1  # face boxes, normals
    assert first["result"]["points"] == second["result"]["points"]  # same answer from the cached mesh
    assert one["pid"] != two["pid"]  # two processes


def test_a_probe_runs_field_is_fitted_once_for_the_service(fresh_process_client):
    client, settings = fresh_process_client
    from app.reference.s1 import as_made
    from tests.jobs.test_field_probe_jobs import PROCESS, board

    truth = as_made(seed=11, amplitude_mm=0.15)
    setup = board(client, (s1_mesh(grid_mm=0.6), truth.mesh(grid_mm=0.6).export(file_type="stl")))
    plan = _job(client, "probe_plan", {"trace_ids": setup["trace_ids"], "count": 12, **PROCESS})
    run = _job(client, "probe_run", {"plan_job_id": plan["id"], "machine_id": setup["machine_id"]})

    def rebuild(index: int) -> dict:
        return _job(client, "reconstruct", {"trace_id": setup["trace_ids"][index], "probe_run_job_id": run["id"],
                                            "method": "field"})

    first, other, again = rebuild(0), rebuild(1), rebuild(0)
    entries = {e["job_id"]: e for e in journal(settings.data_dir / "part-cache")}
    assert entries[first["id"]]["misses"].get("field") == 1 and entries[first["id"]]["writes"].get("field") == 1
    for done in (other, again):
        assert entries[done["id"]]["hits"].get("field") == 1 and not entries[done["id"]]["writes"].get("field")
    assert again["result"] == first["result"]  # the stored fit is the fit: same reconstruction


def test_the_mesh_cache_of_a_new_process_gets_the_placed_meshs_grid(tmp_path):
    import hashlib
    from types import SimpleNamespace

    from app.parts.meshes import MeshCache
    from app.platform.blobs import BlobStore

    data = s1_mesh(grid_mm=2.0).export(file_type="stl")
    blobs = BlobStore(tmp_path / "blobs")
    sha = hashlib.sha256(data).hexdigest()
    blobs.path(sha).parent.mkdir(parents=True)
    blobs.path(sha).write_bytes(data)
    part = SimpleNamespace(sha256=sha, format="stl")
    matrix = np.eye(4)
    matrix[:3, 3] = [10.0, -5.0, 2.0]
    placement = SimpleNamespace(matrix=lambda: matrix)
    cache = PartCache(tmp_path / "cache", 2 ** 28)

    first = MeshCache(blobs, store=MeshStore(cache))
    grid = edge_grid(first.placed(part, placement))
    assert first.persist() == 1  # the placed mesh's normals + grid (nothing was built on the unplaced one)
    assert first.persist() == 0  # nothing new

    later = MeshCache(blobs, store=MeshStore(cache))  # the next job's process
    placed = later.placed(part, placement)
    assert cache.stats.hits["mesh"] == 1
    again = cached_edge_grid(placed)
    assert again is not None and all(np.array_equal(x, y) for x, y in zip(again, grid))
    assert np.array_equal(placed.vertices, first.placed(part, placement).vertices)
    assert cached_edge_grid(later.mesh(part)) is None  # the unplaced mesh has its own (absent) entry


def test_an_entry_written_by_another_software_version_is_rebuilt(tmp_path, monkeypatch):
    import app

    cache = PartCache(tmp_path, 2 ** 24)
    cache.store("k", "key", arrays(5))
    monkeypatch.setattr(app, "__version__", app.__version__ + ".next")
    assert cache.load("k", "key") is None and cache.stats.rejected == {"k": 1}
    assert cache.store("k", "key", arrays(5)) and cache.load("k", "key") is not None
