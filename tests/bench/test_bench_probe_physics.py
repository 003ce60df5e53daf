"""Bench: what each probe-physics correction buys, through the API on the mock.

Run: .venv/bin/python -m pytest tests/bench/test_bench_probe_physics.py -s -o addopts="" -q
(also part of ``make bench``).

The machine of tests/e2e/test_probe_physics_loop.py (0.5 mm ball, 15 +- 2 um pre-travel,
1 um/min Z drift, 1 um noise, nozzle T1 at (12.3, -4.1, -8.7) known as (12, -4, -8.5)),
S1 as made (seed 11, +-0.15 mm), three traces.  The loop's probe runs touch down with
G38.2 at a slow feed (PROBE_FEED; the profile's ``probe_command``: Marlin's G30 would use
its own speed) at PROBES uniform stations per trace, so that a run lasts about ten
minutes of machine time and the drift between probing a point and printing over it
matters.  After one calibration (calibrate_probe, calibrate_nozzle) the
closed loop with evaluation runs once with every correction and once with each switched
off: the stylus radius, the pre-travel, the calibrated nozzle offset (nominal instead),
the drift (no pad re-touches, no pad touch before printing).  Each row: the standoff error
along what the nozzle really deposited (max and rms over the traces, um) and the top-view
error of the printed path (max, um).
"""

from __future__ import annotations

import numpy as np

from tests.e2e.test_probe_physics_loop import calibrated_machine, closed_loop, nominal_part, true_part_stl

PROBE_FEED = 10.0  # mm/min: slow touches (~1 mm each) ...
PROBES = 48        # ... and many, so that a probe run lasts ~10 min of machine time
GOAL_UM = 10.0
ROWS = (("all corrections", {}),
        ("without radius compensation", {"radius": False}),
        ("without pre-travel correction", {"pretravel": False}),
        ("without offset calibration (nominal)", {"offsets": False}),
        ("without drift correction", {"drift": False}))


def _row(loop: dict) -> dict[str, float]:
    table = loop["result"]["table"]
    rms = [row["standoff_rms_after_um"] for row in table]
    return {"standoff_max_um": max(row["standoff_max_after_um"] for row in table),
            "standoff_rms_um": float(np.sqrt(np.mean(np.square(rms)))),
            "xy_max_um": max(row["xy_max_after_um"] for row in table)}


def test_bench_probe_physics_ablation(client):
    part, traces = nominal_part(client)
    machine, probe, nozzle = calibrated_machine(client, true_part_stl(seed=11, amplitude_mm=0.15), "bench", seed=3,
                                                profile={"probe_command": "G38.2"})
    results = {}
    for name, corrections in ROWS:
        loop = closed_loop(client, part, traces, machine, corrections=corrections,
                           probe={"method": "uniform", "count": PROBES, "probe_feed_mm_min": PROBE_FEED})
        results[name] = _row(loop)
    print(f"\ncalibration: ball radius {probe['result']['ball_radius_mm'] * 1000:.1f} um, pre-travel "
          f"{probe['result']['pretravel']['p0_mm'] * 1000:.1f} um, T1 offset "
          f"{[round(v, 4) for v in nozzle['result']['offset_mm']]} mm")
    print(f"{'loop':40s} {'standoff max um':>16s} {'standoff rms um':>16s} {'XY max um':>10s}")
    for name, row in results.items():
        print(f"{name:40s} {row['standoff_max_um']:16.1f} {row['standoff_rms_um']:16.1f} {row['xy_max_um']:10.1f}")
    full = results["all corrections"]
    assert full["standoff_max_um"] <= GOAL_UM and full["xy_max_um"] <= GOAL_UM, full
    for name, row in results.items():
        if name != "all corrections":
            worse = row["standoff_max_um"] > full["standoff_max_um"] or row["xy_max_um"] > full["xy_max_um"]
            assert worse, (name, row, full)
