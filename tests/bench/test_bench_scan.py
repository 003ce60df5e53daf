"""Bench: the 1000-trace board from part on the bed to a verified compensated program,
touch-only against scanning with the laser height sensor, at the same verified bound.

Run: .venv/bin/python -m pytest tests/bench/test_bench_scan.py -s -o addopts="" -q

The 150 x 100 mm dome (:func:`app.reference.boards.dome_part`) with SCAN_BENCH_TRACES traces
(default 1000); the as-made part (seed 11, +-0.15 mm, shortest wavelength 15 mm; the mock
holds it as a 0.5 mm mesh, 0.03 mm high); target 5 um at coverage 4 for both.

* touch-only: the field planner's stations (:func:`app.probing.field.plan_field`), touched
  (the truth + 1 um noise), fitted (learned prior, outliers) and checked as the loop does;
* scan: the mock LK-G (2 kHz, 0.5 um noise, 30 um spot, a seeded time offset, scale error,
  tilt bias and offset never used to tune anything) calibrated on the pad and the sphere,
  then the scan plan (:func:`app.probing.scan_plan.plan_scans`, the cheaper of trace passes
  and rasters per tile) driven on the mock machine, the samples block-averaged, the field fitted by the
  inducing-point solve (:mod:`app.reconstruction.scan_field`) and checked at 5
  verification touches; every trace reconstructed and compensated.

Machine time by the cost model (:mod:`app.probing.scan_cost`: 100 mm/s travel and scan,
1000 mm/s^2, probing 100 mm/min from 1 mm above, 2 mm hops) for both; the mock's own clock
(constant speed, no ramps) beside it; the sensor's data transfer at 115200 baud apart.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import replace

import numpy as np
import pytest

from app.compensation.standoff import CompensationParams, compensate_trace
from app.jobs.sensor_runs import CalibrationSetup, SerialScanner, calibrate_sensor, run_pass
from app.probing.deviation_prior import DeviationPrior, Sites, path_sites
from app.probing.field import plan_field
from app.probing.scan_cost import MotionCost, touch_order, touch_time
from app.probing.scan_plan import plan_to_target
from app.probing.selection import PlanParams
from app.reconstruction.field import trace_reconstruction
from app.reconstruction.field_trust import checked_field
from app.reconstruction.reconstruct import ReconstructParams
from app.reconstruction.scan_field import fit_scan_field, verify_touches
from app.reconstruction.scan_samples import block_average, pass_deviations
from app.reference.boards import as_made_board, board_path, board_traces, dome_part
from hardware.height_sensor import HeightSensor
from hardware.height_sensor.mock import unregister_sensor
from hardware.machine import Machine
from hardware.mock import MockPad, MockSphere, MockWorld, TruePlacement, register_world, unregister_world
from tests.bench.test_bench_board_api import true_part

TRACES = int(os.environ.get("SCAN_BENCH_TRACES", "1000"))
TARGET, COVERAGE = 0.005, 4.0
PAD, SPHERE = (190.0, 20.0, 4.0), (190.0, 70.0, 12.0)
NOMINAL_OFFSET = (30.0, 5.0, -10.0)
RATE = 2000.0
VERIFY = 5
BLOCK = 5  # samples averaged per fitted point (noise / sqrt(5), 0.25 mm along a pass at 100 mm/s)
DZ = 0.03


def _verification_sites(fit, paths, count):
    """The trace points (spread) where the fitted field is least certain."""
    sites = [path_sites(p, np.linspace(0, p.length_mm, 5)) for p in paths]
    owner = np.concatenate([np.full(5, i) for i in range(len(paths))])
    allsites = Sites(np.concatenate([s.xy for s in sites]), np.concatenate([s.grad for s in sites]))
    sd = fit.posterior.sd(allsites)
    picked: list[int] = []
    for _ in range(count):
        far = np.ones(len(sd), bool) if not picked else \
            np.min(np.linalg.norm(allsites.xy[:, None] - allsites.xy[picked][None], axis=2), axis=1) > 15.0
        picked.append(int(np.argmax(np.where(far, sd, -1))))
    return allsites.take(np.array(picked)), owner[picked]


@pytest.mark.timeout(3600)
def test_scan_against_touches_on_the_1000_trace_board():
    part = dome_part()
    made = as_made_board(part, 11)
    truth = lambda xy: part.height(xy) + made.machining_error(xy) + DZ  # noqa: E731
    paths = [board_path(part, g, 0.05) for g in board_traces(part, TRACES)]
    cost = MotionCost()
    params = PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0, coverage=COVERAGE,
                        target_error_mm=TARGET)
    rng = np.random.default_rng(11)

    # ---------------------------------------------------------------- touch-only
    c0 = time.process_time()
    plan = plan_field(paths, params)
    measured = np.column_stack([plan.xy, truth(plan.xy) + rng.normal(0, 0.001, len(plan.xy))])
    stations = Sites(plan.xy, plan.grad)
    check = checked_field(params.prior(), stations, plan.z, measured, plan.center, plan.trace, plan.s_mm,
                          np.zeros(len(plan.z), bool), COVERAGE, TARGET, learn=True)
    touch_cpu = time.process_time() - c0
    touch_bound = COVERAGE * float(plan.max_sd_mm)

    # ---------------------------------------------------------------- scan on the mock
    seed = np.random.default_rng(2026)
    true_offset = np.asarray(NOMINAL_OFFSET) + seed.uniform(-0.2, 0.2, 3)
    tau, scale_error, bias = seed.uniform(0.5e-3, 4e-3), seed.uniform(-0.005, 0.005), seed.uniform(0, 0.003)
    world = register_world("scanbench", MockWorld(true_part=true_part().mesh(grid_mm=0.5),
                                                  placement=TruePlacement(dz=DZ), pad=MockPad(PAD, 20.0),
                                                  sphere=MockSphere(SPHERE, 25.4)))
    machine = Machine("mock://scanbench")
    machine.connect()
    machine.home()
    sensor = HeightSensor(f"lkg://scanbench?offset={','.join(f'{v:.6f}' for v in true_offset)}"
                          f"&time_offset_ms={tau * 1e3:.6f}&scale_error={scale_error:.6f}&slope_bias_mm={bias:.6f}"
                          f"&noise_mm=0.0005&spot_mm=0.03&rate_hz={RATE}&seed=7", rate_hz=RATE)
    sensor.connect()
    try:
        t_cal = world.stats.machine_time_s
        calibration, _ = calibrate_sensor(machine, SerialScanner(machine, sensor), CalibrationSetup(
            PAD, 20.0, SPHERE, 12.7, NOMINAL_OFFSET, 5.0, travel_z=40.0))
        cal_clock = world.stats.machine_time_s - t_cal
        allp = np.concatenate([p.points[:, :2] for p in paths])
        lo, hi = allp.min(axis=0) - 1.0, allp.max(axis=0) + 1.0
        c1 = time.process_time()
        prior = DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.0005)
        targeted = plan_to_target(paths, part.height, part.gradient, (lo[0], lo[1], hi[0], hi[1]), cost, prior,
                                  COVERAGE, TARGET, RATE, (7.5, 6.5, 6.0, 5.0, 4.0), block=BLOCK)
        scan = targeted.plan
        plan_cpu = time.process_time() - c1
        t0, bytes0 = world.stats.machine_time_s, sensor.bytes_received
        xy_all, dz_all = [], []
        for p in scan.passes:
            w = p.carriage(calibration.offset_mm)
            data = run_pass(machine, sensor, w, cost.scan_mm_s, 40.0 if p.hop else None)
            xy, dz = pass_deviations(w, cost.scan_mm_s, data.values, RATE, calibration, part.height,
                                     lambda q: part.gradient(q))
            xy, dz = block_average(xy, dz, BLOCK)
            xy_all.append(xy)
            dz_all.append(dz)
        scan_clock = world.stats.machine_time_s - t0
        transfer_s = (sensor.bytes_received - bytes0) * 10 / 115200
        xy, dz = np.concatenate(xy_all), np.concatenate(dz_all)
        c2 = time.process_time()
        prior = replace(prior, sigma_mm=prior.sigma_mm / math.sqrt(BLOCK))
        center = (lo + hi) / 2
        fit = fit_scan_field(prior, Sites(xy, part.gradient(xy)), dz, center, part.gradient)
        fit_cpu = time.process_time() - c2
        vsites, vtrace = _verification_sites(fit, paths, VERIFY)
        order = touch_order(vsites.xy, scan.passes[-1].spot[-1, :2])  # a short tour, as scan_run touches them
        vsites, vtrace = vsites.take(order), vtrace[order]
        touched = []
        for (x, y), z_nom in zip(vsites.xy, part.height(vsites.xy)):
            touched.append(machine.probe(float(x), float(y), z_start=float(z_nom) + 2.0, z_min=float(z_nom) - 2.0).z)
        verification = verify_touches(fit, vsites, np.array(touched) - part.height(vsites.xy), vtrace, COVERAGE,
                                      params.probe_sigma_mm)
        trace_sd = [float(fit.posterior.sd(path_sites(p, np.linspace(0, p.length_mm, 9))).max()) for p in paths]
        scan_bound = COVERAGE * max(trace_sd)
        errors = []
        c3 = time.process_time()
        for i, path in enumerate(paths):
            rec = trace_reconstruction(fit, path, i, ReconstructParams(prior=prior))
            s = np.linspace(0, path.length_mm, 41)
            errors.append(float(np.abs(rec.height_at_s(s) - truth(path.at(s)[:, :2])).max()))
            compensate_trace(rec, CompensationParams(standoff_mm=0.1))
        compensate_cpu = time.process_time() - c3
    finally:
        sensor.close()
        unregister_sensor("scanbench")
        unregister_world("scanbench")
    scan_s = scan.machine_s + touch_time(cost, vsites.xy)
    touch_s = touch_time(cost, plan.xy) + touch_time(cost, vsites.xy)  # the same verification touches
    touch_errors = []
    for i, path in enumerate(paths[:200]):
        rec = trace_reconstruction(check.fit, path, i, ReconstructParams(prior=params.prior()))
        s = np.linspace(0, path.length_mm, 41)
        touch_errors.append(float(np.abs(rec.height_at_s(s) - truth(path.at(s)[:, :2])).max()))
    print(f"\nboard: {TRACES} traces on the 150 x 100 mm dome; target {TARGET * 1e3:g} um at coverage {COVERAGE:g}")
    print(f"calibration: tau {calibration.time_offset_s * 1e3:.3f} ms (true {tau * 1e3:.3f}), offset error "
          f"{np.round((np.asarray(calibration.offset_mm) - true_offset) * 1e3, 2).tolist()} um, scale error "
          f"{(calibration.scale - 1 - scale_error):+.1e}; mock clock {cal_clock:.1f} s (per machine setup)")
    print(f"touch-only: {len(plan.xy)} stations + {VERIFY} verification: {touch_s:.0f} s machine time; bound "
          f"{touch_bound * 1e3:.2f} um; max error (200 traces) {max(touch_errors) * 1e3:.2f} um; CPU {touch_cpu:.1f} s")
    print(f"scan plans tried: {targeted.tried}")
    print(f"scan: spacing {targeted.spacing_mm:g} mm, predicted bound {targeted.bound_mm * 1e3:.2f} um; "
          f"{len(scan.passes)} passes ({scan.tiles}), {scan.length_mm:.0f} mm: {scan.machine_s:.1f} s "
          f"(+ {VERIFY} verification touches: {scan_s:.1f} s; mock clock {scan_clock:.1f} s; data transfer at "
          f"115200 baud {transfer_s:.1f} s); {len(dz)} averaged samples; bound {scan_bound * 1e3:.2f} um; max error "
          f"{max(errors) * 1e3:.2f} um; verification max |r| {verification.max_abs_residual_mm * 1e3:.2f} um "
          f"(within: {bool(verification.within.all())}); CPU plan {plan_cpu:.1f} s, fit {fit_cpu:.1f} s, "
          f"reconstruct+compensate {compensate_cpu:.1f} s")
    print(f"ratio touch / scan machine time: {touch_s / scan_s:.1f}x "
          f"({touch_s / (scan_s + transfer_s):.1f}x with the sensor's data transfer at 115200 baud)")
    assert abs(calibration.time_offset_s - tau) < 1e-3
    assert scan_bound <= TARGET and touch_bound <= TARGET
    assert verification.within.all() and verification.max_abs_residual_mm <= scan_bound
    assert max(errors) <= scan_bound
    # the goal is 10x; measured 11.6x (423 s / 36.5 s) with the default cost model
    assert touch_s / scan_s >= 10.0
