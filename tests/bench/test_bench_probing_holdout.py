"""Bench: the probe-count goal on 20 further as-made parts (held out from every design choice).

Run: .venv/bin/python -m pytest tests/bench/test_bench_probing_holdout.py -s -o addopts="" -q

The main probing bench (test_bench_probing.py) follows one protocol for every method: two
as-made parts x two noise draws.  Two parts are a small sample of the worst case, and the
joint planner's criterion was chosen among a few (see app/probing/joint.py), so this
bench repeats the comparison that matters for the goal — the better seed method (uniform
+ the seed's interpolation) against our best planner (kriging, joint over the part's nine
traces) — on seeds 21..40, which were used for nothing else.  Same measure: per trace the
smallest count from which every larger count tried keeps max |error| <= 5 um over all
parts x draws; per trace type the worst trace.
"""

from __future__ import annotations

from app.reference.s1 import as_made, nominal_path, s1_traces
from tests.bench.test_bench_probing import needed, sweep, sweep_joint

HOLDOUT = [as_made(seed) for seed in range(21, 41)]


def test_probe_count_goal_on_held_out_parts():
    traces = s1_traces()
    paths = [nominal_path(trace, 0.05) for trace in traces]
    truths = [[part.true_height(path.points[:, :2]) for part in HOLDOUT] for path in paths]
    seed = [needed(sweep(path, truth, "uniform", "interpolate", HOLDOUT))
            for path, truth in zip(paths, truths)]
    ours = [needed(res) for res in sweep_joint(paths, truths, HOLDOUT)]
    print(f"\n\nHeld-out parts (seeds 21..40, {len(HOLDOUT)} parts x 2 noise draws, sigma 1 um): "
          "probes needed for max error <= 5 um")
    print("  per trace (1..9)  seed uniform: " + " ".join(f"{v:>3}" for v in seed))
    print("                    kriging joint: " + " ".join(f"{v:>3}" for v in ours))
    ratios = {}
    for kind in ("line", "arc", "nurbs"):
        idx = [i for i, t in enumerate(traces) if t.kind == kind]
        worst_seed, worst_ours = max(seed[i] for i in idx), max(ours[i] for i in idx)
        ratios[kind] = worst_ours / worst_seed
        print(f"  {kind:<6} seed uniform {worst_seed:>3}  kriging joint {worst_ours:>3}  "
              f"ratio {ratios[kind]:.2f}")
    assert None not in seed and None not in ours
    for kind, r in ratios.items():
        assert r <= 0.5, f"{kind}: ours needs {r:.2f} x the probes of the better seed method"
