"""Bench: probes needed for max height error <= 5 um on the S1 reference part.

Run: .venv/bin/python -m pytest tests/bench/test_bench_probing.py -s -o addopts="" -q

Simulation: as-made S1 parts (smooth machining error 0.15 mm peak, wavelengths >= 15 mm,
seeded random placement), probing = true height at the planned xy + N(0, 1 um).  Error =
max |reconstructed height - true height| along the trace (every 0.05 mm), worst case over
parts x noise draws.  "Needed" = smallest probe count from which every larger count tried
meets 5 um.  Methods: the seed's adaptive chord-height rule + inverse cubic interpolation
(seed), uniform + interpolation (seed baseline), our deviation planner + deviation model,
our kriging planner + kriging model (both told the process: A = 0.15 mm peak, lambda >= 15
mm, placement tolerances at their defaults); "uniform+dev" (even stations, deviation
model) shows how much comes from the model alone; "kriging joint" plans the nine traces
of the part together (:func:`app.probing.joint.plan_joint`, the same count on every trace)
and reconstructs each trace from all of the part's probes (``reconstruct(...,
context=...)``).  The goal: our best planner needs <= 0.5 x the probes of the
better seed method, per trace type.
"""

from __future__ import annotations

import time

import numpy as np

from app.probing.joint import plan_joint
from app.probing.selection import PlanParams, plan_probes
from app.reconstruction.reconstruct import ReconstructParams, reconstruct
from app.reference.s1 import as_made, nominal_path, s1_traces

LIMIT_MM = 0.005
SIGMA_MM = 0.001
PARTS = [as_made(seed) for seed in (11, 12)]
NOISE_DRAWS = 2
COUNTS = list(range(4, 31)) + [35, 40, 50, 60]
CHORD_ERRORS = np.geomspace(0.5, 2e-4, 36)
PROCESS = dict(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)
REC_PARAMS = {"kriging": ReconstructParams(prior=PlanParams(**PROCESS).prior())}
JOINT = "kriging joint (ours)"
OURS = ("deviation (ours)", "kriging (ours)", JOINT)


def worst_error(path, truths, plan, rmethod, parts=PARTS):
    err = 0.0
    for p_i, part in enumerate(parts):
        for d in range(NOISE_DRAWS):
            rng = np.random.default_rng(1000 * p_i + d)
            pts = plan.points.copy()
            pts[:, 2] = part.true_height(pts[:, :2]) + rng.normal(0.0, SIGMA_MM, len(pts))
            rec = reconstruct(path, pts, rmethod, sigma_mm=SIGMA_MM,
                              params=REC_PARAMS.get(rmethod))
            err = max(err, float(np.abs(rec.height_at_s(path.s) - truths[p_i]).max()))
    return err


def joint_errors(paths, truths, plans, parts=PARTS):
    """Worst error (9,) mm per trace when every trace is rebuilt from all the part's probes."""
    worst = np.zeros(len(paths))
    for p_i, part in enumerate(parts):
        for d in range(NOISE_DRAWS):
            rng = np.random.default_rng(1000 * p_i + d)
            measured = []
            for plan in plans:
                pts = plan.points.copy()
                pts[:, 2] = part.true_height(pts[:, :2]) + rng.normal(0.0, SIGMA_MM, len(pts))
                measured.append(pts)
            for i, path in enumerate(paths):
                context = [(paths[j], measured[j]) for j in range(len(paths)) if j != i]
                rec = reconstruct(path, measured[i], "kriging", sigma_mm=SIGMA_MM,
                                  params=REC_PARAMS["kriging"], context=context)
                err = float(np.abs(rec.height_at_s(path.s) - truths[i][p_i]).max())
                worst[i] = max(worst[i], err)
    return worst


def sweep_joint(paths, truths, parts=PARTS):
    """Per trace [(count, worst error)] for the joint planner over COUNTS."""
    res = [[] for _ in paths]
    for n in COUNTS:
        errs = joint_errors(paths, truths, plan_joint(paths, PlanParams(count=n, **PROCESS)), parts)
        for i, e in enumerate(errs):
            res[i].append((n, float(e)))
        if n >= 12 and all(all(e <= LIMIT_MM for _, e in r[-4:]) for r in res):
            break
    return res


def needed(results):
    """Smallest count c such that every tried count >= c meets the limit (None if none)."""
    ok = None
    for count, err in sorted(results, reverse=True):
        if err > LIMIT_MM:
            break
        ok = count
    return ok


def sweep(path, truths, method, rmethod, parts=PARTS):
    res = []
    if method == "adaptive":
        seen = set()
        for e in CHORD_ERRORS:
            plan = plan_probes(path, "adaptive", PlanParams(chord_error_mm=float(e)))
            if plan.count < 4 or plan.count in seen:
                continue
            seen.add(plan.count)
            res.append((plan.count, worst_error(path, truths, plan, rmethod, parts)))
    else:
        for n in COUNTS:
            plan = plan_probes(path, method, PlanParams(count=n, **PROCESS))
            res.append((n, worst_error(path, truths, plan, rmethod, parts)))
            if len(res) >= 4 and all(r[1] <= LIMIT_MM for r in res[-4:]) and n >= 12:
                break  # converged: the rest of the sweep stays under the limit
    return res


def timed(path, method, rmethod, params, part, reps=5):
    plan = plan_probes(path, method, params)
    pts = plan.points.copy()
    pts[:, 2] = part.true_height(pts[:, :2])
    t0 = time.perf_counter()
    for _ in range(reps):
        plan = plan_probes(path, method, params)
        reconstruct(path, pts, rmethod, sigma_mm=SIGMA_MM, params=REC_PARAMS.get(rmethod))
    return (time.perf_counter() - t0) / reps * 1000


def test_probe_count_for_5um():
    methods = [("seed adaptive", "adaptive", "interpolate"),
               ("seed uniform", "uniform", "interpolate"),
               ("deviation (ours)", "deviation", "deviation"),
               ("kriging (ours)", "kriging", "kriging"),
               ("uniform+dev", "uniform", "deviation")]
    need = {}
    times = {}
    auto = {}
    for trace in s1_traces():
        path = nominal_path(trace, 0.05)
        truths = [part.true_height(path.points[:, :2]) for part in PARTS]
        for label, method, rmethod in methods:
            n = needed(sweep(path, truths, method, rmethod))
            need.setdefault((trace.kind, label), []).append(n)
            params = (PlanParams(chord_error_mm=0.005) if method == "adaptive"
                      else PlanParams(count=n or 30, **PROCESS))
            times.setdefault(label, []).append(timed(path, method, rmethod, params, PARTS[0]))
        for planner in ("deviation", "kriging"):
            plan = plan_probes(path, planner, PlanParams(**PROCESS))
            auto.setdefault((planner, trace.kind), []).append(
                (plan.count, worst_error(path, truths, plan, planner)))

    paths = [nominal_path(trace, 0.05) for trace in s1_traces()]
    all_truths = [[part.true_height(path.points[:, :2]) for part in PARTS] for path in paths]
    for trace, res in zip(s1_traces(), sweep_joint(paths, all_truths)):
        need.setdefault((trace.kind, JOINT), []).append(needed(res))
    t0 = time.perf_counter()
    plans = plan_joint(paths, PlanParams(**PROCESS))
    joint_plan_ms = (time.perf_counter() - t0) * 1000
    for trace, plan, err in zip(s1_traces(), plans, joint_errors(paths, all_truths, plans)):
        auto.setdefault(("joint", trace.kind), []).append((plan.count, float(err)))
    methods.append((JOINT, "kriging", "kriging"))

    print("\n\nProbes needed for max height error <= 5 um (worst trace of each type; "
          f"{len(PARTS)} as-made parts x {NOISE_DRAWS} noise draws, sigma 1 um)")
    head = f"{'trace type':<10}" + "".join(f"{lab:>18}" for lab, _, _ in methods)
    print(head + f"{'best ours / seed':>18}")
    ratios = {}
    for kind in ("line", "arc", "nurbs"):
        row = {}
        for label, _, _ in methods:
            vals = need[(kind, label)]
            row[label] = None if None in vals else max(vals)
        best_seed = min(v for k, v in row.items() if k.startswith("seed") and v is not None)
        ratios[kind] = min(row[k] for k in OURS if row[k] is not None) / best_seed
        print(f"{kind:<10}" + "".join(f"{str(row[lab]):>18}" for lab, _, _ in methods)
              + f"{ratios[kind]:>18.2f}")
    print("\nPer trace (1..9):")
    for label, _, _ in methods:
        per = [v for kind in ("line", "arc", "nurbs") for v in need[(kind, label)]]
        print(f"  {label:<18}" + " ".join(f"{str(v):>4}" for v in per))
    print("\nOur planners with their own count (A = 0.15 mm, lambda = 15 mm; per trace):")
    for (planner, kind), vals in auto.items():
        print(f"  {planner:<9} {kind:<6} counts {[c for c, _ in vals]}  max error um "
              f"{[round(e * 1000, 2) for _, e in vals]}")
    print("\nplan + reconstruct per trace, ms (median over the 9 traces; at the needed count):")
    for label, vals in times.items():
        print(f"  {label:<18} {np.median(vals):8.1f}")
    print(f"  joint plan of all nine traces (own count): {joint_plan_ms:.0f} ms")
    assert all(e <= LIMIT_MM for vals in auto.values() for _, e in vals)
    for kind, r in ratios.items():
        assert r <= 0.5, f"{kind}: ours needs {r:.2f} x the probes of the best seed method"
