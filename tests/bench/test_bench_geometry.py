"""Geometry benchmarks: interpolation speed vs geomdl, draping on a 1M-face mesh.

Run: .venv/bin/python -m pytest tests/bench/test_bench_geometry.py -s -o addopts="" -q
Times are medians of repeated runs on a shared, noisy machine; ratios are against a
reference measured in the same process.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import trimesh
from geomdl import fitting as gfit

from app.geometry.cl_points import cl_points
from app.geometry.drape import drape_polyline, top_surface_z
from app.geometry.edge_grid import edge_grid
from app.geometry.fitting import interpolate_curve
from app.geometry.shapes import trace_curve


def median_time(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def measured_points(n: int, seed: int = 0) -> np.ndarray:
    """A smooth 3-D trace sampled unevenly (like probe points)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, n) + rng.uniform(0, 0.5 / n, n)
    return np.column_stack([32 * t, 3 * np.sin(5 * t), 2 + 0.5 * np.cos(7 * t)])


def height_field(n_side: int) -> trimesh.Trimesh:
    x, y = np.linspace(0, 40, n_side), np.linspace(0, 60, n_side)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    z = 5 + np.sin(xx / 5) * np.cos(yy / 9) + 0.02 * xx
    idx = np.arange(n_side * n_side).reshape(n_side, n_side)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return trimesh.Trimesh(np.column_stack([xx.ravel(), yy.ravel(), z.ravel()]), faces, process=False)


def row(name: str, seconds: float, note: str = "") -> None:
    print(f"  {name:<52} {seconds * 1e3:>10.3f} ms  {note}")


def test_bench_interpolation() -> None:
    print("\ncubic interpolation (A9.1, chord length, averaged knots)")
    p500, p5000 = measured_points(500), measured_points(5000)
    interpolate_curve(p5000)  # warm-up
    ours_500 = median_time(lambda: interpolate_curve(p500), 50)
    ours_5000 = median_time(lambda: interpolate_curve(p5000), 30)
    listed = p500.tolist()
    t0 = time.perf_counter()
    ref = gfit.interpolate_curve(listed, 3)
    geomdl_500 = time.perf_counter() - t0
    assert np.abs(np.array(ref.ctrlpts) - interpolate_curve(p500).control_points).max() < 1e-9
    ratio = geomdl_500 / ours_500
    row("conforma interpolate_curve, 500 points", ours_500)
    row("geomdl.fitting.interpolate_curve, 500 points (1 run)", geomdl_500, f"ratio {ratio:,.0f}x")
    row("conforma interpolate_curve, 5000 points", ours_5000, "goal <= 5 ms")
    assert ours_5000 <= 5e-3
    assert ratio >= 1000


def test_bench_draping() -> None:
    print("\ndraping onto a 1M-face height-field mesh")
    t0 = time.perf_counter()
    mesh = height_field(709)  # 708 * 708 * 2 faces
    assert len(mesh.faces) >= 1_000_000
    row(f"build mesh ({len(mesh.faces):,} faces)", time.perf_counter() - t0)
    rng = np.random.default_rng(1)
    xy = rng.uniform([0.1, 0.1], [39.9, 59.9], (10_000, 2))
    t0 = time.perf_counter()
    top_surface_z(mesh, xy[:10])
    row("first ray query (embree BVH build, once per mesh)", time.perf_counter() - t0)
    ours = median_time(lambda: top_surface_z(mesh, xy), 7)
    direction = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    origins = np.column_stack([xy, np.full(len(xy), 20.0)])
    ref = median_time(lambda: mesh.ray.intersects_location(origins, direction, multiple_hits=False), 7)
    row("top_surface_z, 10,000 points", ours, "goal <= 200 ms")
    row("reference: trimesh embree intersects_location", ref, f"ratio {ref / ours:.2f}x")
    top = top_surface_z(mesh, xy)
    assert top.hit.all()
    t0 = time.perf_counter()
    edge_grid(mesh)
    row("edge grid for exact draping (once per mesh)", time.perf_counter() - t0)
    arc = trace_curve({"type": "arc", "center": [60, 30], "radius": 40, "start_deg": 150, "end_deg": 210})
    poly = cl_points(arc, 0.001).points
    dense = np.column_stack([np.linspace(2, 38, 10_000), 30 + 20 * np.sin(np.linspace(0, 6, 10_000))])
    d_arc = median_time(lambda: drape_polyline(mesh, poly), 5)
    d_dense = median_time(lambda: drape_polyline(mesh, dense), 3)
    n_arc = len(drape_polyline(mesh, poly).points)
    n_dense = len(drape_polyline(mesh, dense).points)
    row(f"drape_polyline R40 arc ({len(poly)} CL pts -> {n_arc} exact pts)", d_arc)
    row(f"drape_polyline 10,000-point polyline (-> {n_dense} pts)", d_dense)
    assert ours <= 0.2
