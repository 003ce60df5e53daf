"""Benchmark of droplet-jetting compensation (the jetting MPC method) on the published case.

Run: .venv/bin/python -m pytest tests/bench/test_bench_jetting.py -s -o addopts="" -q
(``JETTING_BENCH_SPREADS=0.02`` for one nozzle spread)

The seed's case: 10 mm square with a 4 mm square hole, 300 dpi, 60 um drops (6 pL),
200 layers, nozzle volume spread 2 % and 6 %, plant seeds 0-4. Open loop prints every
part cell each layer; the MPC (horizon 1, default settings: the edge-aware target) prints
0/1 patterns; the published MPC (flat reference, ``edge_lead`` 0) beside it. The early gain
(smallest Sa ratio from layer 80 on) on plant seeds 2-6, held out from the edge lead's
tuning (seeds 0 and 1). Goals: Sa >= 3x
lower than open loop on every seed (held-out seeds: at every layer from 80 on), >= 50 %
less edge collapse, controller <= 50 ms per layer (median, one core) at 300 dpi and <= 0.25 s at 600 dpi. Times are CPU
seconds of the controller's thread (the machine is shared); wall-clock medians are printed beside.
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from app.jetting import (
    ControllerParams,
    DropParams,
    JettingParams,
    PlantParams,
    TargetSpec,
    drop_kernel,
    simulate,
    surface_metrics,
    target_from_spec,
)
from app.jetting.controller import build_qp, mpc_layer
from app.jetting.flow import mobility_map
from app.jetting.plant import Plant
from app.jetting.qp import solve_fista, solve_lbfgsb

SEEDS = range(5)
TUNING_SEEDS = (0, 1)  # the edge lead (8 nominal layer heights over 4 rings) was chosen on these
HELD_OUT_SEEDS = range(2, 7)
FROM_LAYER = 80
SPREADS = tuple(float(s) for s in os.environ.get("JETTING_BENCH_SPREADS", "0.02,0.06").split(","))
LAYERS = 200


SEED_DROP, SEED_PART = DropParams(), TargetSpec()


def run(kind: str, spread: float, seed: int, layers: int = LAYERS, drop: DropParams = SEED_DROP,
        target: TargetSpec = SEED_PART, plant: dict | None = None, **ctrl):
    params = JettingParams(layers=layers, drop=drop, target=target,
                           plant=PlantParams(nozzle_spread=spread, seed=seed, **(plant or {})),
                           controller=ControllerParams(kind=kind, **ctrl))
    return simulate(params)


def med(values) -> float:
    return float(np.median(list(values)))


def compare(spread: float, seed: int, **ctrl) -> dict:
    ol = run("open_loop", spread, seed).final.metrics
    result = run("mpc", spread, seed, **ctrl)
    m = result.final.metrics
    return {
        "spread": spread, "seed": seed,
        "sa_ol": ol.sa_um, "sa_mpc": m.sa_um, "sa_ratio": ol.sa_um / m.sa_um,
        "sai_ol": ol.sa_interior_um, "sai_mpc": m.sa_interior_um,
        "ec_ol": ol.edge_collapse_um, "ec_mpc": m.edge_collapse_um,
        "ec_cut": 1.0 - m.edge_collapse_um / ol.edge_collapse_um,
        "ecr_cut": 1.0 - (m.edge_collapse_um / m.mean_height_um) / (ol.edge_collapse_um / ol.mean_height_um),
        "rmse_ol": ol.rmse_um, "rmse_mpc": m.rmse_um, "sz_ol": ol.sz_um, "sz_mpc": m.sz_um,
        "h_ol": ol.mean_height_um, "h_mpc": m.mean_height_um, "tgt_mpc": m.target_height_um,
        "cpu_ms": med(r.solve_cpu_ms for r in result.layers),
        "wall_ms": med(r.solve_ms for r in result.layers),
        "gap": med(r.integer_gap for r in result.layers),
    }


def print_rows(title: str, rows: list[dict]) -> None:
    print(f"\n{title}")
    print(" spread seed | Sa OL  Sa MPC  ratio | Sa_int OL  MPC | RMSE OL  MPC | Sz OL   MPC  |"
          " EC OL  EC MPC  cut | EC/h cut | h OL  h MPC (ref) | ctrl ms cpu/wall")
    for r in rows:
        print(f"  {r['spread']:.2f}  {r['seed']:3d}  | {r['sa_ol']:5.2f}  {r['sa_mpc']:5.2f}  {r['sa_ratio']:4.1f}x |"
              f"  {r['sai_ol']:5.2f}  {r['sai_mpc']:5.2f} | {r['rmse_ol']:5.2f}  {r['rmse_mpc']:5.2f} |"
              f" {r['sz_ol']:5.1f} {r['sz_mpc']:5.1f} | {r['ec_ol']:5.1f}  {r['ec_mpc']:5.1f}  "
              f"{100 * r['ec_cut']:3.0f}% |   {100 * r['ecr_cut']:3.0f}%   | {r['h_ol']:4.0f}  {r['h_mpc']:4.0f} "
              f"({r['tgt_mpc']:4.0f}) |  {r['cpu_ms']:5.1f} / {r['wall_ms']:5.1f}")


@pytest.mark.timeout(7200)
def test_bench_seed_case_open_loop_vs_mpc():
    rows = [compare(spread, seed) for spread in SPREADS for seed in SEEDS]
    print_rows("Seed case, MPC m=1, transport model, greedy 0/1 drops (um; h = mean part height)", rows)
    flat = [compare(spread, seed, edge_lead=0.0) for spread in SPREADS for seed in SEEDS]
    print_rows("Same, the published flat reference (edge_lead 0)", flat)
    seed_model = [compare(spread, seed, model="seed_diagonal", binarize="threshold", edge_lead=0.0)
                  for spread in SPREADS for seed in SEEDS]
    print_rows("Same, the seed's model as published: (I + Dg) B diagonal, relax-and-round, flat reference", seed_model)
    worst_ratio = min(r["sa_ratio"] for r in rows)
    worst_cut = min(r["ec_cut"] for r in rows)
    cpu = med(r["cpu_ms"] for r in rows)
    print(f"\nworst Sa ratio {worst_ratio:.2f}x (goal >= 3x, seed reports 3.1x); worst edge-collapse cut "
          f"{100 * worst_cut:.0f} % (goal >= 50 %, seed 43 %); controller median {cpu:.1f} ms CPU (goal <= 50)")
    assert worst_ratio >= 3.0
    assert worst_cut >= 0.5
    assert cpu <= 50.0


def early_gain(spread: float, seed: int, open_loop, **ctrl) -> tuple[float, int, object]:
    """The smallest Sa ratio open loop / MPC over layers FROM_LAYER..LAYERS, where, and the final metrics."""
    result = run("mpc", spread, seed, **ctrl)
    ratios = [o.metrics.sa_um / m.metrics.sa_um for o, m in zip(open_loop.layers, result.layers)][FROM_LAYER - 1:]
    k = int(np.argmin(ratios))
    return ratios[k], FROM_LAYER + k, result.final.metrics


@pytest.mark.timeout(7200)
def test_bench_early_gain_on_held_out_seeds():
    """The edge-aware target (default) against the published flat reference at the default
    fill 0.8, on plant seeds never used to tune it."""
    variants = {"edge-aware (default)": {}, "published, fill 0.8": {"edge_lead": 0.0}}
    print(f"\nEarly gain: smallest Sa open loop / MPC over layers {FROM_LAYER}-{LAYERS} (at layer), and at layer"
          f" {LAYERS}: Sa, edge collapse, mean height (um); seeds {list(HELD_OUT_SEEDS)} held out"
          f" (tuned on {list(TUNING_SEEDS)})")
    print(" spread seed | open loop Sa  EC    h   | " + " | ".join(f"{name:28s}" for name in variants))
    worst = {name: np.inf for name in variants}
    for spread in SPREADS:
        for seed in HELD_OUT_SEEDS:
            ol = run("open_loop", spread, seed)
            o = ol.final.metrics
            cells = []
            for name, ctrl in variants.items():
                ratio, at, m = early_gain(spread, seed, ol, **ctrl)
                worst[name] = min(worst[name], ratio)
                cells.append(f"{ratio:4.2f}x ({at:3d}) {m.sa_um:4.2f} {m.edge_collapse_um:4.1f} "
                             f"{m.mean_height_um:5.1f}")
            print(f"  {spread:.2f}  {seed:3d}  |  {o.sa_um:5.2f}  {o.edge_collapse_um:5.1f} {o.mean_height_um:5.1f} | "
                  + " | ".join(cells), flush=True)
    print("worst: " + ", ".join(f"{name} {value:.2f}x" for name, value in worst.items()) + " (goal >= 3x)")
    assert worst["edge-aware (default)"] >= 3.0


def test_bench_fista_vs_lbfgsb():
    """Objective gap and speed of the fast solver against the L-BFGS-B reference."""
    drop, ctrl = DropParams(), ControllerParams()
    kernel, flow = drop_kernel(drop), JettingParams().flow
    print("\nFISTA vs L-BFGS-B on measured states of a closed-loop run (300 dpi, 124 x 124 grid)")
    print(" layer  m | J fista        J lbfgsb       rel gap   | KKT fista  KKT lbfgsb | ms fista  ms lbfgsb  ratio")
    worst = 0.0
    for layer in (30, 60, 90, 120):
        result = run("mpc", 0.02, 0, layers=layer)
        target, heights = result.target, result.final_heights
        mobility = mobility_map(np.zeros(target.shape), flow)
        guess = result.patterns[-1].astype(float)
        for m in (1, 2):
            c = ControllerParams(horizon=m)
            qp = build_qp(heights, target, guess, kernel, drop, flow, mobility, c, layer)
            t0 = time.thread_time()
            fast = solve_fista(qp, max_iter=ctrl.max_iter, tol=ctrl.tol)
            t1 = time.thread_time()
            ref = solve_lbfgsb(qp)
            t2 = time.thread_time()
            gap = (fast.objective - ref.objective) / abs(ref.objective)
            worst = max(worst, gap)
            print(f"  {layer:4d} {m:2d} | {fast.objective:13.6g}  {ref.objective:13.6g}  {gap:+.1e} |"
                  f"  {fast.kkt_residual:.1e}    {ref.kkt_residual:.1e} | {1e3 * (t1 - t0):7.1f}  "
                  f"{1e3 * (t2 - t1):8.1f}  {(t2 - t1) / max(t1 - t0, 1e-9):5.1f}x")
    print(f"worst relative objective gap (FISTA at its default tolerance) {worst:.1e}")
    assert worst < 1e-4


def test_bench_binarization_methods():
    print("\nBinary drops from the relaxed QP (spread 2 %, seed 0): integer gap J(0/1) - J(relaxed), units t^2")
    print(" dpi layers method           | median gap | final Sa  Sa_int  EC   | ctrl ms cpu")
    for dpi, layers in ((300, LAYERS), (600, 40)):
        for method in ("threshold", "error_diffusion", "greedy"):
            result = run("mpc", 0.02, 0, layers=layers, drop=DropParams(dpi=dpi), binarize=method)
            m = result.final.metrics
            print(f" {dpi:3d} {layers:4d}  {method:15s}  | {med(r.integer_gap for r in result.layers):9.1f}  |"
                  f" {m.sa_um:6.2f}  {m.sa_interior_um:6.2f}  {m.edge_collapse_um:5.1f} |"
                  f" {med(r.solve_cpu_ms for r in result.layers):6.1f}")
        relaxed = relaxed_loop(0.02, 0, layers, DropParams(dpi=dpi))
        print(f" {dpi:3d} {layers:4d}  relaxed drops    |      0     | {relaxed.sa_um:6.2f}  "
              f"{relaxed.sa_interior_um:6.2f}  {relaxed.edge_collapse_um:5.1f} |  "
              "(fractional volumes: the bound 0/1 patterns chase)")


def relaxed_loop(spread: float, seed: int, layers: int, drop: DropParams):
    """The MPC closed loop applying the relaxed (fractional) first layer, as a greyscale head would."""
    params = JettingParams(layers=layers, drop=drop, plant=PlantParams(nozzle_spread=spread, seed=seed))
    target = target_from_spec(params.target, drop, params.margin_mm)
    kernel = drop_kernel(drop)
    plant = Plant(target.shape, kernel, params.flow, params.plant)
    mobility = mobility_map(np.zeros(target.shape), params.flow)
    guess = None
    for layer in range(layers):
        decision = mpc_layer(plant.measure(), target, kernel, drop, params.flow, mobility,
                             params.controller, layer, guess)
        guess = decision.relaxed[0]
        plant.print_layer(guess)
    return surface_metrics(plant.heights, target, layers * params.controller.fill * drop.layer_mm)


def test_bench_horizon_dead_nozzles_and_600_dpi():
    print("\nHorizon and dead nozzles (spread 2 %, seed 0)")
    for label, kwargs, plant in (("m=2", {"horizon": 2}, None),
                                 ("m=1, 3 dead nozzles", {}, {"dead_nozzles": (20, 60, 90)})):
        ol = run("open_loop", 0.02, 0, plant=plant).final.metrics
        res = run("mpc", 0.02, 0, plant=plant, **kwargs)
        m = res.final.metrics
        print(f"  {label:22s} Sa {ol.sa_um:5.2f} -> {m.sa_um:5.2f}  EC {ol.edge_collapse_um:5.1f} -> "
              f"{m.edge_collapse_um:5.1f}  ctrl {med(r.solve_cpu_ms for r in res.layers):5.1f} ms")
    print("\n600 dpi, seed case part (248 x 248 grid), 40 layers, default controller (greedy drops)")
    res = run("mpc", 0.02, 0, layers=40, drop=DropParams(dpi=600))
    cpu600 = med(r.solve_cpu_ms for r in res.layers)
    print(f"  controller {cpu600:6.1f} ms CPU median ({med(r.solve_ms for r in res.layers):6.1f} wall),"
          f" max {max(r.solve_cpu_ms for r in res.layers):6.1f} ms; goal <= 250 ms")
    big = run("mpc", 0.02, 0, layers=2, drop=DropParams(dpi=600), target=TargetSpec(size_mm=50, hole_mm=20))
    print(f"  50 mm part at 600 dpi ({big.target.shape[0]} x {big.target.shape[1]}): controller"
          f" {big.layers[-1].solve_cpu_ms / 1e3:.2f} s CPU per layer (layer 2)")
    assert cpu600 <= 250.0
