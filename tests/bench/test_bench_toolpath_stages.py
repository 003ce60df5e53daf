"""Where the toolpath job's CPU goes, stage by stage, on the small real parts.

Run: .venv/bin/python -m pytest tests/bench/test_bench_toolpath_stages.py -s -o addopts="" -q

The stages of the toolpath job's body (:func:`app.jobs.kinds.toolpath.run`) at the defaults,
each timed by ``time.process_time`` in this process: reading the slice's ``layers.npz``
(``from_binary``; parsing its ``layers.json`` instead, ``from_json``, is timed beside it), planning (``iter_toolpath``),
writing G-code while recording its moves (``write_fdm_program``), the time estimate and the meta (``commands_sha256``,
bounds); beside them what the job no longer does: reading ``print.gcode`` back (``read_program``), which must
give exactly the recorded moves.
"""

from __future__ import annotations

import time

import numpy as np
import trimesh

from app.gcode.estimator import estimate_program
from app.gcode.fdm import FdmParams, write_fdm_program
from app.gcode.reader import read_program
from app.jobs.gcode_meta import gcode_meta
from app.slicing import SliceParams, slice_mesh
from app.slicing.export import from_json, to_json
from app.slicing.export_binary import from_binary, to_binary
from app.slicing.toolpath import ToolpathParams, iter_toolpath
from tests.helpers.real_parts import cad_part, thin_tube

PARTS = {"cube 20 mm": lambda: trimesh.creation.box((20.0, 20.0, 20.0)),
         "cad part 13k faces": lambda: cad_part(refine=1), "tube, 0.305 mm wall": thin_tube}


def _lap(clock: list[float]) -> float:
    """CPU seconds since the last entry of ``clock`` (appended)."""
    clock.append(time.process_time())
    return clock[-1] - clock[-2]


def test_bench_toolpath_job_stages():
    rows = []
    for name, make in PARTS.items():
        mesh = make()
        mesh.apply_translation([100.0, 100.0, 0.0] - (mesh.bounds[0] + mesh.bounds[1]) * [0.5, 0.5, 0.0]
                               - [0.0, 0.0, mesh.bounds[0][2]])
        layers_ = slice_mesh(mesh, SliceParams(layer_mm=0.2))
        text, data = to_json(layers_), to_binary(layers_)
        clock = [time.process_time()]
        from_json(text)
        t_text = _lap(clock)
        sliced = from_binary(data)
        t_json = _lap(clock)
        layers = list(iter_toolpath(sliced, ToolpathParams()))
        t_plan = _lap(clock)
        gcode, program = write_fdm_program(layers, ToolpathParams(), FdmParams())
        t_write = _lap(clock)
        estimate = estimate_program(program)
        t_estimate = _lap(clock)
        meta = gcode_meta(gcode, program)
        t_meta = _lap(clock)
        read = read_program(gcode)
        t_read = _lap(clock)
        assert np.array_equal(read.end, program.end) and np.array_equal(read.feed_mm_s, program.feed_mm_s)
        assert estimate_program(read).total_s == estimate.total_s
        job = t_json + t_plan + t_write + t_estimate + t_meta
        rows.append([name, meta["lines"], t_json, t_text, t_plan, t_write, t_estimate, t_meta, job, t_read])
    print("\ntoolpath job stages, CPU s (defaults: 0.2 mm layers, 1 perimeter, 100 % raster)")
    print("part | lines | layers.npz | layers.json (not done) | plan | write + record | estimate | meta | job total | "
          "read back (not done)")
    for row in rows:
        print(" | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row))
