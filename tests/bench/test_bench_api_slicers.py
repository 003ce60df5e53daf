"""Slice + toolpath through the HTTP API beside PrusaSlicer and CuraEngine, in the same run.

Run: make bench (or .venv/bin/python -m pytest tests/bench/test_bench_api_slicers.py -s -o addopts="" -q)

Each real-shaped part (:mod:`tests.helpers.real_parts`) is uploaded to a ``conforma serve`` process
at its defaults (compute jobs in its pool processes, default limits; its compute processes warmed
up by a first slice), sliced and filled at the defaults (0.2 mm layers, one
perimeter, 100 % raster infill), then given to PrusaSlicer (``prusa-slicer``, Debian) and
CuraEngine (``cura-engine``, with the ``cura`` package's definition files) with the same layer
height, perimeters and infill and no skins, skirt or brim.  CPU seconds are compared (the box
may be loaded; wall times are printed too): ours is the whole service tree's (the server, the
fork server and the compute processes), theirs the CLI's; the client (this process, httpx) is
not counted.  ``BENCH_IN_PROCESS=1`` serves the app inside this process instead (Starlette's
``TestClient``, the service's lease and reaper period), as this bench did before: its figure
then also holds the test client's own work on each request (~1.4 ms a request for
``/api/v1/health``).  Jobs are polled as a client polls them (the status every 0.2 s, the
result once); the service's idle work (its reaper, its consumers' 1 s fallback poll, the
client's status polls) grows with the wall time, so a loaded box inflates our CPU seconds a
little.  ``BENCH_REPEAT=N`` runs each part N times (each a new upload) and each CLI N times
and prints the medians and each run's ratio to CuraEngine's.  CPU seconds: the service tree's
from its threads' run times in nanoseconds, a CLI's from ``getrusage`` of the waited-for
process (microseconds; ``/proc/<pid>/stat`` and GNU time count hundredths, as large as a
small part's differences).  Peak memory: the compute
processes' largest resident peak, the CLI's maximum RSS.  ``BENCH_LARGE=1`` adds the 1.34M-face part, ``BENCH_QUICK=1``
leaves the 300 mm plate out, ``BENCH_PARTS=cube,tube`` keeps the parts whose names start so.

The tools are installed by ``make bench-tools`` (``apt-get install prusa-slicer cura-engine``,
the ``cura`` package's definitions extracted to ``CURA_RESOURCES``); without them this bench
fails and says so, it never skips.
"""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import statistics
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.conftest import auth
from tests.e2e.test_serve import env_for, free_port, start, stop, wait_healthy
from tests.helpers.cputime import tree_cpu_and_peak
from tests.helpers.processes import process_tree
from tests.helpers.real_parts import cad_part, large_plate, thin_tube

OP = auth("operator")
KEY = OP["Authorization"].removeprefix("Bearer ")
CURA_RESOURCES = Path(os.environ.get("CURA_RESOURCES", "/usr/share/cura/resources"))
PARTS = {
    "cube 20 mm": "trimesh.creation.box((20.0, 20.0, 20.0))",
    "cad part 13k faces": "cad_part(refine=1)",
    "tube, 0.305 mm wall": "thin_tube()",
    "plate 300 mm, 69k faces": "large_plate()",
}
if os.environ.get("BENCH_QUICK"):  # the small parts only
    del PARTS["plate 300 mm, 69k faces"]
if os.environ.get("BENCH_LARGE"):
    PARTS["cad part 1.34M faces"] = "cad_part(refine=10)"
if os.environ.get("BENCH_PARTS"):  # e.g. "cube,tube": the parts whose names start so
    PARTS = {k: v for k, v in PARTS.items() if k.startswith(tuple(os.environ["BENCH_PARTS"].split(",")))}
REPEAT = int(os.environ.get("BENCH_REPEAT", "1"))  # runs of each part (and of each CLI): the medians are printed


def _timed(cmd: list[str], env: dict | None = None) -> tuple[float, float, float, subprocess.CompletedProcess]:
    """(CPU s, max RSS MiB, wall s, the run) of ``cmd`` under GNU time; the CPU seconds from
    this process's waited-for children (``getrusage``: microseconds, not GNU time's hundredths)."""
    started = time.perf_counter()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    run = subprocess.run(["/usr/bin/time", "-f", "@@%U %S %M", *cmd], capture_output=True, text=True, timeout=3600,
                         env=env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter() - started
    rss_kib = run.stderr.rsplit("@@", 1)[1].split()[2]
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return cpu, int(rss_kib) / 1024, wall, run


def _tree_cpu(root: int) -> float:
    """CPU s of process ``root``'s tree (``root`` and every descendant) from each live thread's
    run time in nanoseconds (``/proc/<pid>/task/<tid>/schedstat``; ``/proc/<pid>/stat`` counts
    10 ms ticks, as large as a small part's differences; a thread that ended is not counted:
    the service's threads live as long as it does)."""
    total = 0
    for pid in process_tree(root):
        try:
            tasks = os.listdir(f"/proc/{pid}/task")
        except OSError:
            continue
        for tid in tasks:
            try:
                total += int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])
            except (OSError, IndexError, ValueError):
                pass
    return total / 1e9


def _wait(client, job_id: str, timeout: float = 3600.0) -> dict:
    """The finished job with its result: polled as a client polls (the status alone, every
    0.2 s), then read once whole."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()["status"] in ("succeeded", "failed", "cancelled"):
            return client.get(f"/api/v1/jobs/{job_id}?include=result&include=artifacts", headers=OP).json()
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} did not finish in {timeout} s")


@pytest.fixture(scope="module")
def tools():
    missing = [name for name in ("prusa-slicer", "CuraEngine") if shutil.which(name) is None]
    if not (CURA_RESOURCES / "definitions/fdmprinter.def.json").exists():
        missing.append(f"Cura's definitions in {CURA_RESOURCES} (CURA_RESOURCES)")
    if not Path("/usr/bin/time").exists():
        missing.append("/usr/bin/time (GNU time)")
    if missing:
        pytest.fail(f"the reference slicers are missing: {', '.join(missing)}; run `make bench-tools` (apt-get "
                    "install prusa-slicer cura-engine, Cura's definitions extracted)")


def _ours(client, service: int, data: bytes) -> tuple[float, float, float, dict]:  # type: ignore[no-untyped-def]
    """(CPU s of the service tree, wall s, its compute peak MiB, the toolpath job's result) of
    uploading the STL ``data``, slicing it and filling it at the defaults."""
    cpu0 = _tree_cpu(service)
    started = time.perf_counter()
    response = client.post("/api/v1/parts", files={"file": ("part.stl", data)}, headers=OP)
    assert response.status_code == 201, response.text
    sliced = client.post("/api/v1/jobs", json={"kind": "slice", "params": {
        "part_id": response.json()["id"], "layer_mm": 0.2}}, headers=OP)
    assert sliced.status_code == 202, sliced.text
    slice_job = _wait(client, sliced.json()["id"])
    assert slice_job["status"] == "succeeded", slice_job["error"]
    volume = {"x": [0, 400], "y": [0, 400], "z": [0, 400]}
    filled = client.post("/api/v1/jobs", json={"kind": "toolpath", "params": {
        "slice_job_id": slice_job["id"], "volume_mm": volume}}, headers=OP)
    assert filled.status_code == 202, filled.text
    tool_job = _wait(client, filled.json()["id"])
    assert tool_job["status"] == "succeeded", tool_job["error"]
    wall = time.perf_counter() - started
    cpu = _tree_cpu(service)
    _, peak = tree_cpu_and_peak(service)
    result = client.get(f"/api/v1/jobs/{tool_job['id']}?include=result&include=artifacts", headers=OP).json()["result"]
    return cpu - cpu0, wall, peak, result


def _prusa(stl: Path, tmp_path: Path) -> tuple[float, float]:
    """(CPU s, max RSS MiB) of PrusaSlicer on ``stl`` at the bench's settings."""
    prusa = _timed(["prusa-slicer", "--export-gcode", "--layer-height", "0.2", "--first-layer-height", "0.2",
                    "--perimeters", "1", "--fill-density", "100%", "--fill-pattern", "rectilinear",
                    "--top-solid-layers", "0", "--bottom-solid-layers", "0", "--skirts", "0",
                    "--bed-shape", "0x0,400x0,400x400,0x400", "--max-print-height", "400",
                    "-o", str(tmp_path / "prusa.gcode"), str(stl)])
    assert prusa[3].returncode == 0, prusa[3].stderr[-500:]
    return prusa[0], prusa[1]


def _cura(stl: Path, tmp_path: Path) -> tuple[float, float]:
    """(CPU s, max RSS MiB) of CuraEngine on ``stl`` at the bench's settings."""
    env = dict(os.environ, CURA_ENGINE_SEARCH_PATH=f"{CURA_RESOURCES}/definitions:{CURA_RESOURCES}/extruders")
    cmd = ["CuraEngine", "slice", "-j", str(CURA_RESOURCES / "definitions/fdmprinter.def.json")]
    for setting in ("layer_height=0.2", "layer_height_0=0.2", "wall_line_count=1", "infill_sparse_density=100",
                    "infill_pattern=lines", "top_layers=0", "bottom_layers=0", "adhesion_type=none",
                    "machine_width=400", "machine_depth=400", "machine_height=400"):
        cmd += ["-s", setting]
    cura = _timed([*cmd, "-l", str(stl), "-o", str(tmp_path / "cura.gcode")], env)
    assert cura[3].returncode == 0, cura[3].stderr[-500:]
    return cura[0], cura[1]


@contextlib.contextmanager
def _service(settings_factory, tmp_path: Path) -> Iterator[tuple[object, int]]:
    """(a client of the service, the pid whose process tree is the service)."""
    if os.environ.get("BENCH_IN_PROCESS"):
        from fastapi.testclient import TestClient

        from app.main import create_app

        # the service's own lease and reaper period (the test apps' reaper runs every 0.2 s)
        settings = settings_factory(lease_s=30.0, reaper_interval_s=1.0, compute_isolation="process")
        with TestClient(create_app(settings), raise_server_exceptions=False) as client:
            yield client, os.getpid()
        return
    port = free_port()
    proc = start(["serve", "--port", str(port)], env_for(tmp_path / "data", CONFORMA_API_KEYS=f"{KEY}:operator",
                                                         CONFORMA_LOG_LEVEL="warning"), tmp_path / "serve.log")
    try:
        base = f"http://127.0.0.1:{port}"
        wait_healthy(base, proc, timeout=120, log=tmp_path / "serve.log")
        with httpx.Client(base_url=base, timeout=600) as client:
            yield client, proc.pid
    finally:
        stop(proc)


@pytest.mark.timeout(7200)  # the 300 mm plate and the reference slicers take minutes on a loaded box
def test_bench_slice_and_toolpath_through_the_api_against_prusaslicer_and_curaengine(tools, settings_factory,
                                                                                       tmp_path):
    import trimesh  # noqa: F401  (the part expressions use it)

    rows = []
    with _service(settings_factory, tmp_path) as (client, service):
        # warm: the fork server and compute processes start (imports: seconds of CPU) before any figure
        warm = client.post("/api/v1/parts", files={"file": ("warm.stl", trimesh.creation.box((5.0, 5.0, 1.0))
                                                            .export(file_type="stl"))}, headers=OP).json()
        warm_slice = client.post("/api/v1/jobs", json={"kind": "slice", "params": {"part_id": warm["id"]}},
                                 headers=OP).json()
        assert _wait(client, warm_slice["id"])["status"] == "succeeded"
        for name, expression in PARTS.items():
            mesh = eval(expression, {"trimesh": trimesh, "cad_part": cad_part, "large_plate": large_plate,
                                     "thin_tube": thin_tube})
            mesh.apply_translation([100.0, 100.0, 0.0] - (mesh.bounds[0] + mesh.bounds[1]) * [0.5, 0.5, 0.0]
                                   - [0.0, 0.0, mesh.bounds[0][2]])
            stl = tmp_path / "part.stl"
            mesh.export(stl)
            runs = []
            for rep in range(REPEAT):  # each a new part: the binary STL's free header told apart
                data = f"conforma bench {name} {rep}".encode().ljust(80) + stl.read_bytes()[80:]
                ours_cpu, ours_wall, ours_peak, result = _ours(client, service, data)
                runs.append((ours_cpu, ours_wall, ours_peak, _prusa(stl, tmp_path), _cura(stl, tmp_path)))
            ours, prusa, cura = (statistics.median(r[0] for r in runs), statistics.median(r[3][0] for r in runs),
                                 statistics.median(r[4][0] for r in runs))
            each = [r[0] / r[4][0] for r in runs]
            rows.append([name, f"{len(mesh.faces):,}", result["program"]["lines"], f"{result['path_mm']:,.0f}",
                         ours, statistics.median(r[1] for r in runs), max(r[2] for r in runs), prusa,
                         max(r[3][1] for r in runs), cura, max(r[4][1] for r in runs), ours / prusa, ours / cura,
                         f"{min(each):.2f}-{max(each):.2f}"])
    header = ["part", "faces", "our lines", "our path mm", "ours CPU s", "ours wall s", "compute peak MiB",
              "Prusa CPU s", "Prusa MiB", "Cura CPU s", "Cura MiB", "CPU x Prusa", "CPU x Cura", "each run x Cura"]
    print(f"\nslice + toolpath through the API ({'in process' if os.environ.get('BENCH_IN_PROCESS') else 'served'}, "
          "0.2 mm layers, 1 perimeter, 100 % raster infill, no skins) "
          f"beside PrusaSlicer 2.5 and CuraEngine 4.13, same run; medians of {REPEAT} run(s) each")
    print(" | ".join(header))
    for row in rows:
        print(" | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row))
