"""Measured peak memory of the slice and toolpath job bodies against their cost models.

:func:`measure_jobs` runs, in a fresh process, the jobs' own ``run`` functions on a part
(a stand-in context: the mesh given, artifacts counted and let go, as the blob store does)
and reports each job's peak growth of resident memory (``VmHWM``) and of address space
(``VmPeak``, what ``RLIMIT_AS`` limits) above the process before that job, with the cost
model's prediction (``_estimate`` of each kind, on the same facts the API gives it).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

_BODY = """
import gc, io, json, sys
from types import SimpleNamespace
import numpy as np, trimesh

def kib(key):
    return int(next(l for l in open("/proc/self/status") if l.startswith(key)).split()[1])

def reset_peak():  # VmHWM back to the current RSS (Linux >= 4.0)
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")

from app.jobs.kinds import slice as slice_kind, toolpath as toolpath_kind
import tests.helpers.real_parts as parts

mesh = eval(sys.argv[1], vars(parts))
data = mesh.export(file_type="stl")
del mesh
artifacts = {}

class Ctx:
    job_id = "t"
    session = None
    def progress(self, *a, **k): pass
    def mesh(self, part_id): return trimesh.load(io.BytesIO(data), file_type="stl")
    def artifact(self, name, blob, media, meta=None):
        artifacts[name] = blob if name in ("layers.json", "layers.npz") else len(blob)
    def artifacts(self, items):
        for name, blob, media, meta in items:
            self.artifact(name, blob, media, meta)
    def artifact_batch(self, max_bytes=64 * 2**20):
        from app.runtime.context import ArtifactBatch
        return ArtifactBatch(self, max_bytes)
    def job(self, job_id, **k): return SimpleNamespace(id=job_id)
    def require_succeeded(self, job_id, kind, field): pass
    def artifact_bytes(self, job_id, name): return artifacts[name]

import threading
top = [0]
def sample():  # VmPeak cannot be reset: the address space's peak is sampled (started once: its arena too)
    while True:
        top[0] = max(top[0], kib("VmSize:"))
        threading.Event().wait(0.005)
threading.Thread(target=sample, daemon=True).start()

import ctypes
libc = ctypes.CDLL("libc.so.6")

def measured(fn):
    gc.collect()
    libc.malloc_trim(0)  # the heap an earlier job freed goes back to the system: growth is measured from there
    reset_peak()
    rss, vm = kib("VmRSS:"), kib("VmSize:")
    top[0] = vm
    result = fn()
    top[0] = max(top[0], kib("VmSize:"))
    return result, (kib("VmHWM:") - rss) / 1024, (top[0] - vm) / 1024

sp = slice_kind.SliceJobParams(part_id="p", **json.loads(sys.argv[2]))
probe = trimesh.load(io.BytesIO(data), file_type="stl")
part = SimpleNamespace(bounds=probe.bounds.tolist(), faces=len(probe.faces))
del probe
slice_cost = slice_kind._estimate(sp, SimpleNamespace(find_part=lambda _id: part))
sliced, s_rss, s_vm = measured(lambda: slice_kind.run(Ctx(), sp))
job = SimpleNamespace(id="s", kind="slice", status="succeeded", params={"part_id": "p"}, result=sliced,
                      artifacts={"layers.json": len(artifacts["layers.json"])})
del sliced
tp = toolpath_kind.ToolpathJobParams(slice_job_id="s", **json.loads(sys.argv[3]))
lookup = {"s": job, "p": part}
tool_cost = toolpath_kind._estimate(tp, SimpleNamespace(find_job=lookup.get, find_part=lookup.get,
                                                        layers_json_bytes=len(artifacts["layers.json"])))
toolpath, t_rss, t_vm = measured(lambda: toolpath_kind.run(Ctx(), tp))
print(json.dumps({"faces": part.faces, "layers": job.result["layer_count"],
                  "lines": toolpath["program"]["lines"],
                  "slice": {"rss_mb": s_rss, "vm_mb": s_vm, "estimate_mb": slice_cost.memory_mb},
                  "toolpath": {"rss_mb": t_rss, "vm_mb": t_vm, "estimate_mb": tool_cost.memory_mb}}))
"""


def measure_jobs(part: str, slice_params: dict | None = None, toolpath_params: dict | None = None) -> dict:
    """Slice then toolpath ``part`` (an expression over :mod:`tests.helpers.real_parts`, e.g.
    ``"thin_tube()"``) in a fresh process; returns faces, layers, program lines and per job
    ``rss_mb``, ``vm_mb`` (peak growth, MiB) and ``estimate_mb`` (the cost model's)."""
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(_BODY), part, json.dumps(slice_params or {}),
                          json.dumps(toolpath_params or {})], cwd=ROOT, capture_output=True, text=True, timeout=3600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])
