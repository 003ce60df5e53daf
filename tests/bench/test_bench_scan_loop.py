"""Bench: the closed loop measuring by scanning on held-out as-made parts, every trace
checked against the mock's truth.

Run: .venv/bin/python -m pytest tests/bench/test_bench_scan_loop.py -s -o addopts="" -q

SCAN_LOOP_SEEDS as-made reference parts (default 8, seeds 61-68: used nowhere else, nothing was
tuned on them), all nine traces, through the API (:mod:`tests.helpers.scan_loop`): a mock
machine with the reference pad and sphere, a mock LK-G with an offset, time offset, scale
error and tilt bias drawn from the seed, dropping out beyond 10 degrees of tilt (the steep
flanks of the wavy top) and in a dark spot of 2 mm radius over the arcs; the sensor
calibrated by ``calibrate_sensor``, then ``closed_loop`` measuring scan (mixed plan, 4 mm
raster spacing where rastered, coverage 4, target 5 um, up to 20 gap touches, 4
verification touches).  Each trace's rebuilt height is compared with the as-made part's
analytic top every 0.2 mm.

The claim checked: a loop that ends verified has every trace within its bound.  Printed:
per part the verdict, the dropouts, the gap touches, the worst trace's error and bound, and
the scan's machine time by the cost model.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from hardware.height_sensor.mock import unregister_sensor
from tests.helpers.jobs import wait_for
from tests.helpers.scan_loop import calibrate, scan_bed, scan_loop, trace_errors

SEEDS = [61 + i for i in range(int(os.environ.get("SCAN_LOOP_SEEDS", "8")))]
SCAN = {"mode": "mixed", "spacing_mm": 4.0, "deviation_amplitude_mm": 0.15, "deviation_wavelength_mm": 15.0,
        "verify_count": 4, "coverage": 4.0, "target_error_mm": 0.005, "gap_touches": 20}
DARK = "22,20,2"


@pytest.mark.timeout(7200)
def test_scanning_loops_on_held_out_parts(client):
    rows = []
    for seed in SEEDS:
        bed = scan_bed(client, seed, tuple(range(9)), acceptance_deg=10.0, dark=DARK)
        try:
            calibration = calibrate(client, bed)
            done = scan_loop(client, bed, SCAN, timeout=1200)
        finally:
            unregister_sensor(bed.machine["id"])
        assert done["status"] in ("succeeded", "needs_attention"), done["error"]
        scan = wait_for(client, done["result"]["traces"][0]["scan_run"], timeout=5)["result"]
        errors = trace_errors(client, bed, done, points=201)
        worst = max(errors, key=lambda eb: eb[0] / eb[1])
        machine_s = sum(scan["machine_s"].values())
        rows.append((seed, done["status"], done["result"]["verdict"]["verified"], errors))
        print(f"\nseed {seed}: {done['status']}; {done['result']['verdict']['verified']}; "
              f"tau error {(calibration['time_offset_s'] - bed.hidden['tau']) * 1e3:+.3f} ms, offset error "
              f"{np.round((np.asarray(calibration['offset_mm']) - bed.hidden['offset']) * 1e3, 2).tolist()} um; "
              f"samples {scan['valid']}/{scan['samples']} valid ({1 - scan['valid'] / scan['samples']:.1%} dropped), "
              f"gap touches {scan['gap_touches']}; worst trace |error| {worst[0] * 1e3:.2f} um / bound "
              f"{worst[1] * 1e3:.2f} um; traces within bound {sum(e <= b for e, b in errors)}/{len(errors)}; "
              f"machine time {machine_s:.1f} s (scan {scan['machine_s']['scan']:.1f}, links "
              f"{scan['machine_s']['links']:.1f}, gap touches {scan['machine_s']['gap_touches']:.1f}, verification "
              f"{scan['machine_s']['verification']:.1f})")
    verified = [r for r in rows if r[1] == "succeeded"]
    print(f"\n{len(verified)}/{len(rows)} loops verified; in them "
          f"{sum(e <= b for r in verified for e, b in r[3])}/{sum(len(r[3]) for r in verified)} traces within their "
          "bound")
    for seed, _status, line, errors in verified:
        assert all(e <= b for e, b in errors), (seed, line, errors)
    assert len(verified) >= len(rows) // 2
