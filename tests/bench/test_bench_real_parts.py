"""Real-shaped meshes end to end: intake, repair + manifold build, slicing, exports; beside
PrusaSlicer on the same STL when it is installed; and an upload's peak memory.

The part is CAD-like and closed (a block with a boss, a dome, a pocket and four through
holes: manifold3d booleans), refined 1, 3 and 10 times per edge: 13,392, 120,528 and
1,339,200 faces (the work grows ~10 x and ~100 x).  Not a height field.

Run: .venv/bin/python -m pytest tests/bench/test_bench_real_parts.py -s -o addopts="" -q
"""

from __future__ import annotations

import resource
import shutil
import subprocess
import time

import pytest

from app.parts.intake import intake
from app.slicing import SliceParams, slice_mesh
from app.slicing.export import to_cli, to_json, to_slc
from app.slicing.mesh_prep import prepare_mesh
from tests.bench.test_bench_slicing import _table
from tests.helpers.real_parts import cad_part
from tests.helpers.upload_memory import measure_upload

LAYER_MM = 0.2
STAGES = ("intake (read STL, merge, check)", "repair check + manifold build", "slice", "SLC", "CLI", "JSON")


def _stages(path) -> tuple[dict[str, float], float, int]:
    """Wall time per stage (s), CPU time of the whole (s), layer count."""
    times: dict[str, float] = {}
    cpu0 = time.process_time()

    def timed(name, fn, *args):
        t0 = time.perf_counter()
        out = fn(*args)
        times[name] = time.perf_counter() - t0
        return out

    with open(path, "rb") as handle:
        mesh = timed(STAGES[0], lambda: intake(handle, "stl", max_unzipped_bytes=1 << 30).mesh)
    prepared = timed(STAGES[1], prepare_mesh, mesh)
    result = timed(STAGES[2], slice_mesh, prepared, SliceParams(layer_mm=LAYER_MM))
    timed(STAGES[3], to_slc, result)
    timed(STAGES[4], to_cli, result)
    timed(STAGES[5], to_json, result)
    return times, time.process_time() - cpu0, len(result.layers)


def _prusaslicer(path, out) -> tuple[float, float] | None:
    """(wall s, CPU s) of PrusaSlicer exporting G-code at the same layer height, or None."""
    exe = shutil.which("prusa-slicer")
    if exe is None:
        return None
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([exe, "--export-gcode", "--layer-height", str(LAYER_MM), "--first-layer-height",
                           str(LAYER_MM), "--output", str(out), str(path)], capture_output=True, text=True,
                          timeout=1800)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def test_bench_real_part_end_to_end(tmp_path):
    rows, largest = [], None
    for refine in (1, 3, 10):
        mesh = cad_part(refine)
        path = tmp_path / f"part_{refine}.stl"
        path.write_bytes(mesh.export(file_type="stl"))
        times, cpu, layers = _stages(path)
        total = sum(times.values())
        rows.append([f"{len(mesh.faces):,}", layers, *[times[s] for s in STAGES], total, cpu])
        largest = (path, total, cpu, len(mesh.faces))
    _table(f"real-shaped part end to end, {LAYER_MM} mm layers (wall s; CPU s of the whole)",
           ["faces", "layers", *STAGES, "total", "CPU"], rows)
    path, total, cpu, faces = largest
    reference = _prusaslicer(path, tmp_path / "prusa.gcode")
    if reference is None:
        print("  PrusaSlicer is not installed (apt-get install prusa-slicer): no reference time")
    else:
        wall, ref_cpu = reference
        _table(f"{faces:,} faces: ours (mesh -> layers + SLC/CLI/JSON) vs PrusaSlicer (mesh -> G-code)",
               ["", "wall s", "CPU s", "x PrusaSlicer (wall)", "x PrusaSlicer (CPU)"],
               [["ours", total, cpu, total / wall, cpu / ref_cpu], ["PrusaSlicer 2.5", wall, ref_cpu, 1.0, 1.0]])
        assert total <= 2.0 * wall, f"goal: within 2 x PrusaSlicer; {total:.1f} s vs {wall:.1f} s"
    peak = measure_upload(path, tmp_path / "data")
    _table("upload of the largest STL to a real server", ["file MiB", "peak RSS growth MiB", "x file"],
           [[peak.file_bytes / 2**20, peak.growth_bytes / 2**20, peak.ratio]])
    assert peak.ratio <= 4.0
    assert peak.part["faces"] == faces and peak.part["watertight"] is True
    assert peak.part["volume_mm3"] == pytest.approx(cad_part(1).volume, rel=1e-6)
