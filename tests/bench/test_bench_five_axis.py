"""Benchmark: surface fit accuracy (goal: <= 10 um from a noisy 20 x 20 grid) and
the five-axis planner (feed fluctuation, normal and standoff errors, time).

Run: .venv/bin/python -m pytest tests/bench/test_bench_five_axis.py -s -o addopts="" -q
"""

from __future__ import annotations

import time

import numpy as np

from app.five_axis import FiveAxisParams, plan_five_axis
from app.five_axis.trace import trace_over_xy
from app.geometry.nurbs_surface import NurbsSurface
from app.probing.grid import ProbeRegion, plan_probe_grid
from app.reconstruction.surface_fit import SurfaceFitParams, fit_surface, grid_from_plan

NOISE_MM = 0.005
SEEDS = range(5)
GOAL_MM = 0.010


def _sphere(x, y):
    return np.sqrt(50.0**2 - x**2 - y**2)


def _cylinder(x, y):
    return np.sqrt(30.0**2 - x**2)


def _saddle(x, y):
    return (x**2 - y**2) / 200.0


def _true_error(kind: str, p: np.ndarray) -> np.ndarray:
    """Distance of points (k,3) from the analytic surface (normal distance)."""
    if kind == "sphere":
        return np.abs(np.linalg.norm(p, axis=1) - 50.0)
    if kind == "cylinder":
        return np.abs(np.hypot(p[:, 0], p[:, 2]) - 30.0)
    grad = np.hypot(p[:, 0] / 100.0, p[:, 1] / 100.0)
    return np.abs(p[:, 2] - _saddle(p[:, 0], p[:, 1])) / np.sqrt(1 + grad**2)


def _max_error(kind: str, surface: NurbsSurface) -> float:
    (u0, u1), (v0, v1) = surface.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, 81), np.linspace(v0, v1, 81), indexing="ij")
    return float(_true_error(kind, surface.evaluate(uu.ravel(), vv.ravel())).max())


CASES = [
    ("interpolate", "none"),  # reference: the plain interpolating fit
    ("interpolate", "moving_average"),
    ("interpolate", "five_point_cubic"),
    ("interpolate", "spline"),
    ("least_squares", "none"),
    ("least_squares", "five_point_cubic"),
    ("least_squares", "spline"),
]


def test_bench_surface_fit() -> None:
    plan = plan_probe_grid(ProbeRegion(-20, 20, -20, 20), 20, 20)
    x, y = plan.points_xy.T
    print(f"\nsurface fit, 20 x 20 grid over 40 x 40 mm, noise {NOISE_MM * 1e3:.0f} um, "
          f"max over {len(SEEDS)} seeds; ratio = error / plain interpolation")
    print(f"{'surface':9s} {'method':14s} {'smoothing':17s} {'max err um':>10s} "
          f"{'ratio':>6s} {'rms res um':>10s} {'net':>7s} {'ms':>6s}")
    worst_default = 0.0
    for kind, fn in (("sphere", _sphere), ("cylinder", _cylinder), ("saddle", _saddle)):
        reference = None
        for method, smoothing in CASES:
            errs, rms, t_total = [], [], 0.0
            for seed in SEEDS:
                rng = np.random.default_rng(seed)
                grid = grid_from_plan(plan, fn(x, y) + rng.normal(0, NOISE_MM, x.size))
                t0 = time.perf_counter()
                fit = fit_surface(grid, SurfaceFitParams(method=method, smoothing=smoothing))
                t_total += time.perf_counter() - t0
                errs.append(_max_error(kind, fit.surface))
                rms.append(fit.residual_rms_mm)
            err = max(errs)
            reference = reference or err
            if (method, smoothing) == ("least_squares", "none"):
                worst_default = max(worst_default, err)
            print(f"{kind:9s} {method:14s} {smoothing:17s} {err * 1e3:10.2f} "
                  f"{err / reference:6.2f} {np.mean(rms) * 1e3:10.2f} "
                  f"{'x'.join(map(str, fit.control_points)):>7s} "
                  f"{t_total / len(SEEDS) * 1e3:6.1f}")
    print(f"default (least squares, GCV net): worst max error {worst_default * 1e3:.2f} um "
          f"(goal <= {GOAL_MM * 1e3:.0f} um)")
    assert worst_default <= GOAL_MM


def test_bench_five_axis_plan() -> None:
    plan = plan_probe_grid(ProbeRegion(-20, 20, -20, 20), 20, 20)
    x, y = plan.points_xy.T
    rng = np.random.default_rng(0)
    surface = fit_surface(grid_from_plan(plan, _sphere(x, y) + rng.normal(0, NOISE_MM, x.size)),
                          SurfaceFitParams()).surface
    t = np.linspace(0, 2 * np.pi, 80)
    trace = trace_over_xy(surface, np.column_stack([3 + 12 * np.cos(t), 8 * np.sin(2 * t)]))
    print(f"\nfive-axis plan on a fitted R50 sphere, figure-eight trace "
          f"{trace.length:.1f} mm, h = 0.5 mm")
    print(f"{'feed mm/min':>11s} {'T ms':>5s} {'periods':>8s} {'fluct 2nd %':>12s} "
          f"{'fluct 1st %':>12s} {'1st/2nd':>8s} {'normal deg':>10s} {'standoff um':>11s} "
          f"{'nominal deg':>11s} {'lines':>6s} {'s':>6s}")
    for feed, period in ((600.0, 0.001), (3000.0, 0.001), (3000.0, 0.004)):
        t0 = time.perf_counter()
        path = plan_five_axis(surface, trace, FiveAxisParams(
            feed_mm_min=feed, period_s=period, segment_mm=0.5, pivot=(0, 0, -30)))
        elapsed = time.perf_counter() - t0
        f2, f1 = path.feed.max_rel, path.feed_first_order.max_rel
        print(f"{feed:11.0f} {period * 1e3:5.1f} {path.figures.servo_periods:8d} {100 * f2:12.2e} "
              f"{100 * f1:12.2e} {f1 / f2:8.1f} {path.figures.max_normal_error_deg:10.2e} "
              f"{path.figures.max_standoff_error_mm * 1e3:11.2e} "
              f"{path.figures.nominal_max_normal_error_deg:11.2f} {path.u.size:6d} {elapsed:6.2f}")
        assert f2 < 1e-3 and f2 < f1
        assert path.figures.max_normal_error_deg < 0.05 and path.figures.max_standoff_error_mm < 1e-3
