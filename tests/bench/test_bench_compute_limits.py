"""Bench: the bombs' peak memory, measured, against the cost model's prediction.

Run: .venv/bin/python -m pytest tests/bench/test_bench_compute_limits.py -s -o addopts="" -q

Each case runs in a fresh process (peak RSS ``VmHWM`` minus the RSS before the work,
so one case never hides another) and grows the work by 4x per step, printing measured / predicted ratios and
the growth against the first step measured in the same run:

* the surface-fit bad-point test over 2,500 .. 40,000 points (was quadratic: ~4 GB at 40,000;
  now per k-d-tree tile: memory flat, time linear);
* surface_fit jobs' core on grids 50 .. 200 with a net of half and of all the grid, against
  ``app.jobs.kinds.surface_fit._estimate`` (and below 2x the upload limit);
* the surface least-squares solve alone, old (SuperLU on the N-unknown normal equations: 468
  MiB / 61 s at a 200 x 200 net) against new (tensor-product grid solve; banded Cholesky with a
  penalty), same knots;
* toolpath hilbert_merged at line widths 0.4 .. 0.1 mm on a 40 mm square (fill cells x4 per
  step), against ``app.jobs.kinds.toolpath._estimate``;
* the 0.8 MB NPZ holding 800 MiB: refused by its header, peak growth near zero.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest

from app.jobs.kinds.surface_fit import SurfaceFitJobParams
from app.jobs.kinds.surface_fit import _estimate as surface_fit_estimate
from app.jobs.kinds.toolpath import ToolpathJobParams
from app.jobs.kinds.toolpath import _estimate as toolpath_estimate

ROOT = Path(__file__).resolve().parents[2]
UPLOAD_LIMIT_MB = 200.0

_PRELUDE = """
import json, resource, time
import numpy as np
def status_kib(key):
    return int(next(l for l in open("/proc/self/status") if l.startswith(key)).split()[1])
base = status_kib("VmRSS:")  # KiB, now (ru_maxrss would carry the forking parent's peak across exec)
started = time.perf_counter()
"""
_REPORT = """
print(json.dumps({"peak_mb": (status_kib("VmHWM:") - base) / 1024,
                  "s": time.perf_counter() - started}))
"""


def measure(body: str, setup: str = "") -> dict:
    code = textwrap.dedent(setup) + _PRELUDE + textwrap.dedent(body) + _REPORT
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_bad_point_test_memory_is_flat_and_time_linear_in_points():
    print("\nbad-point test (scattered points, 5 spikes)")
    first = None
    for n in (2_500, 10_000, 40_000):
        got = measure("find_bad_points(pts)", setup=f"""
            import numpy as np
            from app.reconstruction.surface_fit.preprocess import find_bad_points
            rng = np.random.default_rng(0)
            xy = rng.uniform(0, 40, ({n}, 2))
            z = 5 + 0.1 * np.sin(xy[:, 0] / 5) * np.cos(xy[:, 1] / 7) + rng.normal(0, 0.001, {n})
            z[:5] += 0.5
            pts = np.column_stack([xy, z])
        """)
        first = first or got
        print(f"  {n:>6} points: peak +{got['peak_mb']:7.1f} MiB ({got['peak_mb'] / max(first['peak_mb'], 1):5.2f}x),"
              f" {got['s']:6.1f} s ({got['s'] / first['s']:5.2f}x)  [global dense fit at 40,000: ~4,200 MiB]")
        assert got["peak_mb"] < 2 * UPLOAD_LIMIT_MB


@pytest.mark.parametrize("net_of_grid", [0.5, 1.0])
def test_surface_fit_peak_memory_against_the_cost_model(net_of_grid):
    print(f"\nsurface_fit core (job defaults, bad points removed), grid n x n, net {net_of_grid:g} n")
    for n in (50, 100, 200):
        m = int(n * net_of_grid)
        params = SurfaceFitJobParams(part_id="p", region={"x": [0, 40], "y": [0, 40]}, grid=[n, n],
                                     control_points=[m, m])
        predicted = surface_fit_estimate(params, None)
        got = measure(f"fit = fit_surface(HeightGrid(x, x, z), SurfaceFitParams(control_points=({m}, {m})))",
                      setup=f"""
            import numpy as np
            from app.reconstruction.surface_fit import SurfaceFitParams, fit_surface
            from app.reconstruction.surface_fit.grid import HeightGrid
            x = np.linspace(0, 40, {n})
            xx, yy = np.meshgrid(x, x, indexing="ij")
            z = 5 + 0.1 * np.sin(xx / 5) * np.cos(yy / 7)
        """)
        print(f"  n={n:>3}: peak +{got['peak_mb']:7.1f} MiB, predicted {predicted.memory_mb:7.1f} MiB "
              f"(measured/predicted {got['peak_mb'] / predicted.memory_mb:4.2f}); {got['s']:6.1f} s, predicted "
              f"{predicted.time_s:6.1f} s")
        assert got["peak_mb"] <= predicted.memory_mb  # the model is an upper bound
        assert got["peak_mb"] < 2 * UPLOAD_LIMIT_MB  # bounded below 2x the upload limit


_SOLVE_SETUP = """
    import numpy as np
    import scipy.sparse as sp
    from scipy.interpolate import BSpline
    from app.geometry import fitting as F
    n, m, smoothing = {n}, {m}, {smoothing}
    x = np.linspace(0, 40, n)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    grid = np.stack([xx, yy, 5 + 0.1 * np.sin(xx / 5) * np.cos(yy / 7)], axis=-1)
    u = F.grid_parameters(grid, 0, F.DEFAULT_TOLERANCE, "grid")
    t = F.grid_knots(u, m, 3)
    uu, vv = np.meshgrid(u, u, indexing="ij")
    bu, bv = BSpline.design_matrix(u, t, 3), BSpline.design_matrix(u, t, 3)
"""
_OLD_SOLVE = """
    design = F._row_kron(BSpline.design_matrix(uu.ravel(), t, 3), BSpline.design_matrix(vv.ravel(), t, 3)).tocsc()
    penalty = None
    if smoothing:
        du = sp.kron(F._second_difference(m), sp.eye(m))
        dv = sp.kron(sp.eye(m), F._second_difference(m))
        pen = (du.T @ du + dv.T @ dv).tocsc()
        penalty = smoothing * (design.multiply(design)).sum() / pen.diagonal().sum() * pen
    ctrl = F._solve_normal(design, grid.reshape(-1, 3), "grid", penalty)  # SuperLU: the dense-design reference
"""
_NEW_SOLVE = """
    if smoothing:
        design = F._row_kron(BSpline.design_matrix(uu.ravel(), t, 3), BSpline.design_matrix(vv.ravel(), t, 3))
        ctrl = F._solve_net(design, grid.reshape(-1, 3), m, m, smoothing, "grid")
    else:
        ctrl = F._solve_tensor_grid(bu, bv, grid, "grid")
"""


def test_surface_least_squares_solve_old_against_new():
    """The solve alone (same knots, same answer): the old sparse normal equations (SuperLU)
    against the tensor-product grid solve (no penalty) and the banded Cholesky (penalty)."""
    print("\nsurface least-squares solve, grid n x n, net m x m: old SuperLU -> new")
    for n, m, smoothing in ((100, 50, 0.0), (100, 100, 0.0), (200, 100, 0.0), (200, 200, 0.0),
                            (200, 200, 0.01)):
        setup = _SOLVE_SETUP.format(n=n, m=m, smoothing=smoothing)
        old = measure(_OLD_SOLVE, setup=setup)
        new = measure(_NEW_SOLVE, setup=setup)
        print(f"  n={n:>3} m={m:>3} penalty {smoothing:<4g}: peak +{old['peak_mb']:6.1f} -> +{new['peak_mb']:6.1f} "
              f"MiB, {old['s']:6.2f} -> {new['s']:6.2f} s ({'tensor grid' if not smoothing else 'banded Cholesky'})")
        assert new["peak_mb"] < old["peak_mb"] or new["peak_mb"] < 5


def test_toolpath_hilbert_merged_peak_memory_against_the_cost_model():
    print("\ntoolpath hilbert_merged on a 40 x 40 mm square, one layer")
    job = SimpleNamespace(id="s", kind="slice", status="succeeded", params={"part_id": "p"}, result={
        "mode": "uniform", "layer_count": 1, "z_min": 0.0, "z_max": 1.0, "bounds": [[0, 0, 0], [40, 40, 1]],
        "frame": "part", "volume_mm3": 1600.0, "repairs": [], "notes": [], "beam": {}, "slc": {}, "svg": {},
        "layers": []})
    part = SimpleNamespace(bounds=[[0, 0, 0], [40, 40, 1]])
    reads = SimpleNamespace(find_job=lambda _id: job, find_part=lambda _id: part)
    first = None
    for width in (0.4, 0.2, 0.1):
        params = ToolpathJobParams(slice_job_id="s", pattern="hilbert_merged", line_width_mm=width,
                                   nozzle_mm=min(width, 0.4))
        predicted = toolpath_estimate(params, reads)
        got = measure(f"plan_toolpath(sliced, ToolpathParams(pattern='hilbert_merged', line_width_mm={width}, "
                      f"nozzle_mm={min(width, 0.4)}))", setup="""
            import trimesh
            from app.slicing import SliceParams, ToolpathParams, plan_toolpath, slice_mesh
            mesh = trimesh.creation.box([40, 40, 1.0])
            mesh.apply_translation([20, 20, 0.5])
            sliced = slice_mesh(mesh, SliceParams(mode="uniform", layer_mm=1.0))
        """)
        first = first or got
        print(f"  line width {width:4.2f} mm: peak +{got['peak_mb']:7.1f} MiB "
              f"({got['peak_mb'] / max(first['peak_mb'], 1):5.1f}x), predicted {predicted.memory_mb:7.1f} MiB; "
              f"{got['s']:6.1f} s, predicted {predicted.time_s:6.1f} s")
        assert got["peak_mb"] <= predicted.memory_mb
    bomb = ToolpathJobParams(slice_job_id="s", pattern="hilbert_merged", line_width_mm=0.005, nozzle_mm=0.005)
    print(f"  line width 0.005 mm (the attack): predicted {toolpath_estimate(bomb, reads).memory_mb:,.0f} MiB "
          "-> 422 at submission")


def test_npz_bomb_is_refused_with_near_zero_growth(tmp_path):
    import io

    import numpy as np

    buffer = io.BytesIO()
    np.savez_compressed(buffer, heights=np.zeros(800 * 2**20 // 8))
    path = tmp_path / "bomb.npz"
    path.write_bytes(buffer.getvalue())
    got = measure("""
        try:
            inspect_npz(data, 200 * 2**20)
        except ArrayFileError as exc:
            refused = exc.field
        assert refused == "file"
    """, setup=f"""
        from pathlib import Path
        from app.platform.array_files import ArrayFileError, inspect_npz
        data = Path({str(path)!r}).read_bytes()
    """)
    print(f"\nNPZ bomb ({path.stat().st_size / 1e6:.2f} MB holding 800 MiB): refused, peak growth "
          f"+{got['peak_mb']:.1f} MiB")
    assert got["peak_mb"] < 2 * UPLOAD_LIMIT_MB


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(pytest.main([__file__, "-s", "-o", "addopts=", "-q"]))
