"""Bench: the laser height sensor on Conforma's three-axis LinuxCNC simulator (sim/sensor.hal).

Run: .venv/bin/python -m pytest tests/bench/test_bench_linuxcnc_scan.py -s -o addopts="" -q

Prints three figures, each against the simulated block's truth (:class:`SimBlock.top_z`):

* ``time offset``: what is left of the sensor's time offset once ``HalScan`` pairs each
  value with the joints of its exposure, from passes across the block's 2 mm edge in both
  directions (:func:`app.calibration.sensor.fit_time_offset` on the paired positions),
  50 mm/s; beside it how late the values reached the sampler (the HAL component's
  scheduling: median, 95th percentile, max) and the share of servo periods with a new value;
* ``samples``: a scan_run job (mode ``traces``, two 20 mm line traces, 50 mm/s, 0.5 um
  noise) through the API on a ``linuxcnc://`` machine: sample count, valid fraction, the
  sampled surface minus the truth (median, 95th percentile, max), the fitted deviation at
  each trace against the truth, the verification touches' residuals, the job's wall time;
* ``dropouts``: the valid fraction over a 31 degree top (acceptance 25 degrees) and a 17 degree one.

Asserted: the default tests' bounds.  Runs only where LinuxCNC is installed (it fails
under CI=true without it); it takes the simulator lock.
"""

from __future__ import annotations

import io
import os
import time

import numpy as np
import pytest

from app.calibration.sensor import EdgePass, fit_time_offset
from hardware.linuxcnc import SimBlock, SimController, SimSensor, linuxcnc_available
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import PROFILE, add_sim_machine, service_finds
from tests.hardware.linuxcnc.test_height_sensor import _scan
from tests.hardware.linuxcnc.test_scan_run import PROFILE as API_PROFILE
from tests.hardware.linuxcnc.test_scan_run import TRACE_X, _box_stl
from tests.helpers.jobs import submit, wait_for
from tests.helpers.real_components import missing

pytestmark = pytest.mark.timeout(900)
OP = auth("operator")
OFFSET = (30.0, 5.0, -10.0)
EDGE_PASSES = 4
EDGE_SPEED = 50.0


def _time_offset(sim: SimController, machine) -> tuple[float, float, np.ndarray, float]:
    """(tau s, sd s, every value's lag s, values per servo period) from passes across the
    block's u = 0 edge at x = 10 (the spot's x)."""
    block = SimBlock(40.0, 30.0, 2.0, 0.0, dx=10.0, dy=-5.0)
    sim.set_surface(block)
    sim.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0005))
    passes, lags, shares = [], [], []
    for k in range(2 * EDGE_PASSES):
        a, b = (-26.0, -14.0) if k % 2 == 0 else (-14.0, -26.0)
        samples = _scan(machine, sim, (a, 3.0, 12.0), (b, 3.0, 12.0), EDGE_SPEED)
        passes.append(EdgePass(samples.xyz[:, 0], samples.reading, 1 if k % 2 == 0 else -1, EDGE_SPEED))
        lags.append(samples.lag_s)
        shares.append(len(samples.t) / (1 + round(samples.t[-1] / samples.period_s)))
    # the zero at z = 2: the bed reads -2 mm, the top 0; the edge is where -1 mm is crossed
    tau, _, sd = fit_time_offset(passes, -1.0)
    return tau, sd, np.concatenate(lags), float(np.mean(shares))


def _dropouts(sim: SimController, machine, slope: float) -> float:
    block = SimBlock(6.0, 30.0, 1.0, slope, dx=10.0, dy=-5.0, dz=0.1)
    sim.set_surface(block)
    sim.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0005))
    samples = _scan(machine, sim, (-21.0, 3.0, 11.5), (-15.0, 3.0, 11.5), 20.0)
    u = samples.xyz[:, 0] + OFFSET[0] - block.dx
    top = (u > 0.2) & (u < block.length_mm - 0.2)
    return float(np.isfinite(samples.reading[top]).mean())


def test_bench_linuxcnc_height_sensor(client, monkeypatch):
    if not linuxcnc_available():
        missing("LinuxCNC", "not installed (apt-get install linuxcnc-uspace)")
    with SimController("xyz") as sim:
        service_finds(sim, monkeypatch)
        machine = sim.machine(PROFILE)
        machine.connect()
        machine.home()
        tau, sd, lag, share = _time_offset(sim, machine)
        steep, mild = _dropouts(sim, machine, 0.6), _dropouts(sim, machine, 0.3)
        machine.disconnect()
        print(f"\ntime offset left after pairing: {tau * 1000:.3f} ms (sd {sd * 1000:.3f} ms, {2 * EDGE_PASSES} "
              f"edge passes at {EDGE_SPEED:g} mm/s; load average {os.getloadavg()[0]:.1f})")
        print(f"values reached the sampler late by median {np.median(lag) * 1000:.1f} ms, p95 "
              f"{np.percentile(lag, 95) * 1000:.1f} ms, max {lag.max() * 1000:.1f} ms; "
              f"{share:.2f} of the servo periods had a new value")
        print(f"dropouts: valid fraction over a 31 deg top {steep:.3f}, over a 17 deg top {mild:.3f} "
              "(acceptance 25 deg)")
        assert steep == 0.0 and mild == 1.0 and abs(tau) < 0.0005

        truth = SimBlock(40.0, 30.0, 2.02, 0.003)
        sim.set_surface(truth)
        sim.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0005))
        part = client.post("/api/v1/parts", files={"file": ("box.stl", _box_stl())}, headers=OP).json()
        traces = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=[
            {"name": f"line-{x:g}", "geometry": {"type": "line", "start": [x, 5.0], "end": [x, 25.0]},
             "frame": "xy", "standoff_mm": 0.08} for x in TRACE_X], headers=OP).json()["items"]
        machine_id = add_sim_machine(client, sim, API_PROFILE, OP)
        calibration = {"offset_mm": list(OFFSET), "scale": 1.0, "time_offset_s": 0.0, "slope_bias_mm": 0.0}
        started = time.monotonic()
        response = submit(client, "scan_run", {
            "machine_id": machine_id, "trace_ids": [t["id"] for t in traces], "calibration": calibration,
            "mode": "traces", "scan_speed_mm_s": 50.0, "deviation_amplitude_mm": 0.15,
            "deviation_wavelength_mm": 20.0, "verify_count": 2})
        done = wait_for(client, response.json()["id"], timeout=300)
        wall = time.monotonic() - started
        assert done["status"] == "succeeded", done["error"]
        result = done["result"]
        artifact = next(a for a in done["artifacts"] if a["name"] == "samples.npz")
        data = np.load(io.BytesIO(client.get(artifact["url"], headers=OP).content))
        valid = data["valid"]
        x, y, z = data["x"][valid], data["y"][valid], data["z"][valid]
        error = np.abs(z - np.array([truth.top_z(a, b) for a, b in zip(x, y)]))
        print(f"scan_run on linuxcnc://: {result['samples']} samples ({valid.mean():.4f} valid) in "
              f"{result['passes']} passes, job wall time {wall:.1f} s; |sampled surface - truth| median "
              f"{np.median(error) * 1000:.2f} um, p95 {np.percentile(error, 95) * 1000:.2f} um, "
              f"max {error.max() * 1000:.2f} um")
        ids = [t["id"] for t in traces]
        for trace in result["traces"]:
            x0 = TRACE_X[ids.index(trace["trace_id"])]
            true_dev = 0.02 + 0.003 * x0
            print(f"trace x={x0:g}: fitted max deviation {trace['max_abs_deviation_mm'] * 1000:.2f} um, truth "
                  f"{true_dev * 1000:.2f} um, error {(trace['max_abs_deviation_mm'] - true_dev) * 1000:+.2f} um, "
                  f"bound {trace['bound_mm'] * 1000:.2f} um")
        check = result["verification"]
        print(f"verification touches: residuals {[round(r * 1000, 2) for r in check['residual_mm']]} um, "
              f"limits {[round(r * 1000, 2) for r in check['limit_mm']]} um, within {check['within']}")
        assert check["within"] and np.percentile(error, 95) < 0.006
