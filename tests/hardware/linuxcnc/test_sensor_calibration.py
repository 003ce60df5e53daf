"""``calibrate_sensor`` through the API on a ``linuxcnc://`` machine: the simulator's height
sensor (``sim/sensor.hal``), sampled by the controller with its joints, no sensor port.

The simulated sensor's truth (never used by the job: it gets only the nominal offset and the
profile's pad and sphere) is an offset 0.1-0.2 mm off the nominal, a 2.5 ms latency between
the value and its exposure stamp, a 0.4 % scale error and a tilt bias.  The pad is a 20 x 20
mm block whose -x edge the time offset is found on; the datum sphere stands on the bed beside
it (the probe trips on both, the sensor sees both).  The job's recovered time offset must be
within 1 ms of the latency (or, on a host so loaded that the simulated sensor delivers few
values, within three of the sd the job states), the offset within 5 um of the truth (z: the probe's trip lateness,
two servo periods at the probe feed, 2 um, is inside it), the scale within 0.1 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from hardware.linuxcnc import SimBlock, SimSensor, SimSphere
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import SURFACE_SLOPE_X, SURFACE_Z, add_sim_machine
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
NOMINAL = (30.0, 5.0, -10.0)
TRUTH = SimSensor(offset_mm=(30.13, 4.88, -10.07), noise_mm=0.0005, acceptance_deg=40.0, scale_error=0.004,
                  slope_bias_mm=0.002, latency_ms=2.5)
PAD = SimBlock(20.0, 20.0, 2.0, dx=40.0, dy=0.0, dz=-3.0)    # top z = -1 over x 40..60, y 0..20
SPHERE_MM, SPHERE_R_MM = (90.0, 10.0, -1.0), 5.0
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "probe_command": "G38.2",
           "travel_feed_mm_min": 6000.0, "probe_feed_mm_min": 60.0,
           "reference": {"pad": {"centre_mm": [50.0, 10.0, -1.0], "size_mm": 20.0},
                         "sphere": {"centre_mm": list(SPHERE_MM), "diameter_mm": 2 * SPHERE_R_MM}}}


@pytest.fixture
def reference_artifacts(lcnc_env):
    lcnc_env.set_surface(PAD)
    lcnc_env.set_surface(SimSphere(SPHERE_MM, SPHERE_R_MM))
    lcnc_env.set_sensor(TRUTH)
    yield lcnc_env
    lcnc_env.set_surface(SimSphere.none())
    lcnc_env.set_surface(SimBlock.plane(SURFACE_Z, SURFACE_SLOPE_X))
    lcnc_env.set_sensor(SimSensor())


def test_calibrate_sensor_on_linuxcnc_recovers_the_simulated_sensors_truth(client, reference_artifacts):
    machine_id = add_sim_machine(client, reference_artifacts, PROFILE, OP)
    response = submit(client, "calibrate_sensor", {"machine_id": machine_id, "nominal_offset_mm": list(NOMINAL),
                                                   "range_mm": 5.0})
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=300)
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    offset_error = np.asarray(result["offset_mm"]) - np.asarray(TRUTH.offset_mm)
    print(f"calibrate_sensor on LinuxCNC: time offset {result['time_offset_s'] * 1e3:.3f} ms (truth "
          f"{TRUTH.latency_ms} ms), offset error {np.round(offset_error * 1e3, 2).tolist()} um, scale "
          f"{result['scale']:.5f} (truth {1 + TRUTH.scale_error}), tilt bias {result['slope_bias_mm'] * 1e3:.2f} um "
          f"(truth {TRUTH.slope_bias_mm * 1e3} um)")
    # within 1 ms whenever the component delivers its values densely; on a host loaded so far
    # that it delivers few (the edge then falls between values tens of ms apart), within three
    # of the job's own stated sd
    tau_error, tau_sd = abs(result["time_offset_s"] - TRUTH.latency_ms * 1e-3), result["sd"]["time_offset_s"]
    print(f"time offset error {tau_error * 1e3:.3f} ms, the job's sd {tau_sd * 1e3:.3f} ms")
    assert tau_error < max(1e-3, 3 * tau_sd)
    # 5 um; on a host so loaded that the time offset is off by tens of ms, the sphere raster's
    # lines shift by that times its speed and the lateral offset is off by more: within three
    # of the job's own stated sd then
    sd = result["sd"]
    print(f"lateral offset sd stated by the job {sd['o_x'] * 1e3:.2f}, {sd['o_y'] * 1e3:.2f} um")
    assert abs(offset_error[0]) < max(0.005, 3 * sd["o_x"]) and abs(offset_error[1]) < max(0.005, 3 * sd["o_y"])
    assert abs(offset_error[2]) < 0.005
    assert result["scale"] == pytest.approx(1 + TRUTH.scale_error, abs=1e-3)
    assert result["sensor_port"] is None and result["references"]["source"].startswith("pad touched once")
    stored = client.get(f"/api/v1/machines/{machine_id}/calibration", headers=OP).json()["sensor"]
    assert stored["time_offset_s"] == result["time_offset_s"]


def test_a_serial_machine_without_the_sensors_port_is_refused(client):
    plain = client.post("/api/v1/machines", json={"name": "plain", "port": "mock://", "dialect": "marlin",
                                                  "profile": PROFILE}, headers=OP).json()
    response = submit(client, "calibrate_sensor", {"machine_id": plain["id"], "nominal_offset_mm": list(NOMINAL)})
    assert response.status_code == 422 and response.json()["errors"][0]["loc"] == ["params", "sensor_port"]
