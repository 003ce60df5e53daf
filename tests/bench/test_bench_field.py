"""Bench: the field planner on whole boards.

Run: .venv/bin/python -m pytest tests/bench/test_bench_field.py -s -o addopts="" -q

Boards of 9, 81, 300 and 1000 traces (lines, arcs and free cubic curves in turn; on S1 the
9-trace board is the seed's nine traces) on the S1 part (60 x 40 mm) and on a 150 x 100 mm
doubly curved part (:mod:`app.reference.boards`); process told to the planners: A = 0.15 mm
peak, lambda >= 15 mm, placement tolerances at their defaults; 1 um probe noise; target 5 um
with coverage 4 (3 is the default: over 20 parts x 1000 traces the worst point reaches
3.3-3.7 sd; measured with 3.5: worst 5.27 um on the 150 x 100 mm part) and compensation chord error 1 um
(``chord_error_mm``, default 2 um).  Truth: held-out as-made parts, seeds 300..319 (never used while the planner was
designed or tuned; tuning used seeds 100..110, 200..210, 2, 7, 8).

Measured per board: field plan time (wall and CPU s) and peak traced memory; stations vs the
field's degrees of freedom at the target (``dof``: the Karhunen-Loeve truncation dimension over
the area within lambda/4 of a trace, :mod:`app.probing.field_dof`) and vs the Nyquist rule of
thumb A / (lambda/2)^2 + 6;
worst reconstruction error over every trace point (every 0.1 mm) on all 20 held-out parts;
on COMPENSATED_PARTS of them the full reconstruct + compensate of every trace (timed on the
first) and the worst standoff error along the emitted print path (its points and three points
inside every segment) against the true surface.  One comparison table against the seed's
uniform and adaptive methods and today's per-trace kriging (each trace planned and rebuilt on
its own) on the boards of up to BASELINE_MAX traces, on BASELINE_PARTS held-out parts.  The
per-part cache: two "jobs" (drape a trace: ray casting + edge grid) on a 1.3M-face part.
"""

from __future__ import annotations

import hashlib
import math
import time
import tracemalloc
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from app.compensation.standoff import CompensationParams, compensate_trace
from app.geometry.tolerance import Tolerance
from app.geometry.traces import build_nominal_trace
from app.parts.meshes import MeshCache, mesh_bytes
from app.platform.blobs import BlobStore
from app.probing.deviation_prior import Sites, path_gradient
from app.probing.field import plan_field
from app.probing.selection import PlanParams, plan_probes
from app.reconstruction.field import fit_field, trace_reconstruction
from app.reconstruction.preprocess import ReconstructionError
from app.reconstruction.reconstruct import ReconstructParams, reconstruct
from app.reference.boards import as_made_board, board_path, board_traces, dome_part, s1_part
from app.reference.s1 import s1_mesh, s1_traces

LIMIT_MM = 0.005
SIGMA_MM = 0.001
SIZES = (9, 81, 300, 1000)
HOLDOUT = tuple(range(300, 320))
# full compensation of every trace on this many of the held-out parts (time budget: ~10 min on 2 cores)
COMPENSATED_PARTS = {"S1": {9: 20, 81: 20, 300: 3, 1000: 2}, "dome": {9: 20, 81: 20, 300: 2, 1000: 1}}
BASELINE_MAX = 300
BASELINE_PARTS = 3
PROCESS = dict(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)
COVERAGE = 4.0  # the max over a whole board spans far more points than one trace: 4 sd, not 3
PARAMS = PlanParams(coverage=COVERAGE, **PROCESS)
PRIOR = PARAMS.prior()
REC = ReconstructParams(prior=PRIOR)
STANDOFF_MM = 0.1
CHORD_MM = 0.001  # compensate's chord_error_mm (default 2 um): the print polyline within 1 um of the curve
JOINT_MIN_PER_TRACE = 4  # today's joint planner gives every trace the same count, at least min_count = 4


def measure(stations_xy: np.ndarray, made, seed: int) -> np.ndarray:
    """True heights (n,) at the stations + 1 um noise (seeded per part)."""
    return made.true_height(stations_xy) + np.random.default_rng(10_000 + seed).normal(0, SIGMA_MM, len(stations_xy))


def board_truth_error(fit, paths, made) -> np.ndarray:
    """Worst |reconstructed - true| height (T,) mm per trace over its points (every 0.1 mm)."""
    pts = [p.points[::2] for p in paths]
    xy = np.concatenate([q[:, :2] for q in pts])
    grad = np.concatenate([path_gradient(p, p.s[::2]) for p in paths])
    z = np.concatenate([q[:, 2] for q in pts])
    err = np.abs(z + fit.machining(xy) + fit.placement(Sites(xy, grad)) - made.true_height(xy))
    out = np.zeros(len(paths))
    np.maximum.at(out, np.repeat(np.arange(len(paths)), [len(q) for q in pts]), err)
    return out


def standoff_error(path_points: np.ndarray, made) -> float:
    """Worst |tip z - standoff - true z| (mm) along a print polyline (k, 3): its points and
    three points inside every segment."""
    t = np.array([0.0, 0.25, 0.5, 0.75])
    a, b = path_points[:-1], path_points[1:]
    pts = (a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]).reshape(-1, 3)
    pts = np.concatenate([pts, path_points[-1:]])
    return float(np.abs(pts[:, 2] - STANDOFF_MM - made.true_height(pts[:, :2])).max())


def field_board(part, n: int) -> dict:
    paths = [board_path(part, g, 0.05) for g in board_traces(part, n)]
    t0, c0 = time.perf_counter(), time.process_time()
    plan = plan_field(paths, PARAMS)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = 0
    if n == max(SIZES):  # memory where it is asked: the largest board
        tracemalloc.start()
        plan_field(paths, PARAMS)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    t0 = time.perf_counter()
    exchanged = plan_field(paths, replace(PARAMS, exchange=True))   # opt-in: counted and timed, not flown
    exchange_wall = time.perf_counter() - t0
    rec_err = np.zeros(len(paths))
    comp_err = np.zeros(len(paths))
    comp_time = None
    for k, seed in enumerate(HOLDOUT):
        made = as_made_board(part, seed)
        measured = plan.points.copy()
        measured[:, 2] = measure(plan.xy, made, seed)
        t0, c0 = time.perf_counter(), time.process_time()
        fit = fit_field(PRIOR, plan.sites, plan.z, measured, plan.center, plan.trace, plan.s_mm)
        if k < COMPENSATED_PARTS[part.name][n]:  # what the reconstruct and compensate jobs of every trace do
            for i, path in enumerate(paths):
                printed = compensate_trace(trace_reconstruction(fit, path, i, REC),
                                           CompensationParams(standoff_mm=STANDOFF_MM, chord_error_mm=CHORD_MM))
                comp_err[i] = max(comp_err[i], standoff_error(printed.points, made))
            if k == 0:
                comp_time = (time.perf_counter() - t0, time.process_time() - c0)
        rec_err = np.maximum(rec_err, board_truth_error(fit, paths, made))
    return {"paths": paths, "plan": plan, "wall": wall, "cpu": cpu, "peak": peak, "rec_err": rec_err,
            "exchanged": exchanged, "exchange_wall": exchange_wall,
            "comp_err": comp_err, "comp_time": comp_time}


def baseline(paths, part, method: str) -> tuple[int, float, float]:
    """(probes, worst error mm over BASELINE_PARTS parts, plan time s) of a per-trace method,
    each trace rebuilt from its own probes (uniform/adaptive: the seed's interpolation; kriging:
    its own model; inf when some trace could not be rebuilt).  uniform uses the per-trace
    kriging counts."""
    t0 = time.perf_counter()
    if method == "adaptive":
        plans = [plan_probes(p, "adaptive", PlanParams(chord_error_mm=0.005)) for p in paths]
    elif method == "kriging":
        plans = [plan_probes(p, "kriging", PARAMS) for p in paths]
    else:
        counts = [plan_probes(p, "kriging", PARAMS).count for p in paths]
        t0 = time.perf_counter()
        plans = [plan_probes(p, "uniform", PlanParams(count=max(4, c))) for p, c in zip(paths, counts)]
    plan_time = time.perf_counter() - t0
    rmethod = "kriging" if method == "kriging" else "interpolate"
    worst = 0.0
    for seed in HOLDOUT[:BASELINE_PARTS]:
        made = as_made_board(part, seed)
        for path, plan in zip(paths, plans):
            pts = plan.points.copy()
            pts[:, 2] = measure(pts[:, :2], made, seed)
            try:
                rec = reconstruct(path, pts, rmethod, sigma_mm=SIGMA_MM, params=REC)
            except ReconstructionError:  # too few points kept (adaptive on a short trace): no program
                worst = math.inf
                continue
            worst = max(worst, float(np.abs(rec.height_at_s(path.s) - made.true_height(path.points[:, :2])).max()))
    return sum(p.count for p in plans), worst, plan_time


@pytest.mark.timeout(1800)
@pytest.mark.parametrize("part", [s1_part(), dome_part()], ids=["S1", "dome"])
def test_field_planner_on_boards(part):
    rows, table = [], []
    for n in SIZES:
        r = field_board(part, n)
        plan = r["plan"]
        rows.append((n, r))
        table.append((n, "field (ours)", plan.count, float(max(r["rec_err"].max(), r["comp_err"].max())), r["wall"]))
        if n <= BASELINE_MAX:
            for method, label in (("uniform", "seed uniform"), ("adaptive", "seed adaptive"),
                                  ("kriging", "kriging per trace")):
                count, err, secs = baseline(r["paths"], part, method)
                table.append((n, label, count, err, secs))
    print(f"\n\nField planner on {part.name} ({part.size[0]:.0f} x {part.size[1]:.0f} mm), "
          f"held-out parts {HOLDOUT[0]}..{HOLDOUT[-1]}, sigma 1 um, target 5 um (coverage {COVERAGE})")
    print(f"{'traces':>6} {'stations':>8} {'dof':>6} {'st/dof':>6} {'nyquist':>7} {'st/nyq':>6} {'plan s':>7} "
          f"{'cpu s':>6} {'peak MiB':>8} "
          f"{'max sd um':>9} {'rec err um':>10} {'comp err um':>11} {'parts comp':>10} {'rec+comp s':>10} {'cpu s':>6} "
          f"{'exchange: stations':>18} {'plan s':>6}")
    for n, r in rows:
        plan = r["plan"]
        print(f"{n:>6} {plan.count:>8} {plan.dof:>6.0f} {plan.count / plan.dof:>6.2f} {plan.nyquist_dof:>7.1f} "
              f"{plan.count / plan.nyquist_dof:>6.2f} {r['wall']:>7.2f} "
              f"{r['cpu']:>6.2f} {r['peak'] / 2**20:>8.1f} {plan.max_sd_mm * 1e3:>9.2f} "
              f"{r['rec_err'].max() * 1e3:>10.2f} {r['comp_err'].max() * 1e3:>11.2f} "
              f"{COMPENSATED_PARTS[part.name][n]:>10} {r['comp_time'][0]:>10.2f} {r['comp_time'][1]:>6.2f} "
              f"{r['exchanged'].count:>18} {r['exchange_wall']:>6.2f}")
    print(f"\nComparison (probes / worst error over {BASELINE_PARTS} held-out parts for the per-trace methods, "
          f"{len(HOLDOUT)} for the field / plan time s):")
    print(f"{'traces':>6} {'method':<18} {'probes':>7} {'err um':>8} {'plan s':>8}")
    for n, label, count, err, secs in table:
        print(f"{n:>6} {label:<18} {count:>7} {err * 1e3:>8.2f} {secs:>8.2f}")
    by_n = dict(rows)
    joint_floor = JOINT_MIN_PER_TRACE * 81
    print(f"\n81 traces: field {by_n[81]['plan'].count} stations vs today's joint planner >= {joint_floor} "
          f"(same count on every trace, >= min_count 4): ratio <= {by_n[81]['plan'].count / joint_floor:.2f}")
    for n, r in rows:
        assert r["rec_err"].max() <= LIMIT_MM, (n, r["rec_err"].max())
        assert r["comp_err"].max() <= LIMIT_MM, (n, r["comp_err"].max())
        assert r["peak"] <= 2 ** 30
        assert r["plan"].count <= 1.5 * r["plan"].dof, (n, r["plan"].count, r["plan"].dof)
        assert r["exchanged"].count <= r["plan"].count and r["exchanged"].max_sd_mm <= LIMIT_MM / COVERAGE * (1 + 1e-9)
    # CPU seconds of this process: the 2 cores are shared by several sessions (wall printed too)
    assert by_n[1000]["cpu"] <= 5.0 and by_n[1000]["comp_time"][1] <= 10.0
    if part.name == "S1":
        assert by_n[81]["plan"].count <= joint_floor / 3


def test_per_part_cache_skips_the_ray_structure_and_edge_grid_on_the_second_job(tmp_path):
    mesh = s1_mesh(grid_mm=0.06)
    data = mesh.export(file_type="stl")
    blobs = BlobStore(tmp_path)
    sha = hashlib.sha256(data).hexdigest()
    blobs.path(sha).parent.mkdir(parents=True, exist_ok=True)
    blobs.path(sha).write_bytes(data)
    cache = MeshCache(blobs)
    part = SimpleNamespace(sha256=sha, format="stl")
    geometry = s1_traces()[4].geometry

    def job() -> float:
        t0 = time.perf_counter()
        build_nominal_trace(cache.mesh(part), geometry, "xy", Tolerance())
        return time.perf_counter() - t0

    first, second = job(), job()
    held = cache.bytes
    print(f"\n\nPer-part cache, {len(mesh.faces):,} faces: first job {first:.2f} s (parse + ray structure + "
          f"edge grid), second {second:.3f} s ({first / second:.0f}x); the cached part holds {held / 2**20:.0f} MiB "
          f"(bound {cache.max_bytes / 2**20:.0f} MiB)")
    assert second < 0.25 * first and held == mesh_bytes(cache.mesh(part))
