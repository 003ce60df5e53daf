"""``calibrate_probe`` through the API on a ``linuxcnc://`` machine (Conforma's three-axis
LinuxCNC simulator), against a simulated reference sphere and pad whose truth is known.

The simulator's probe input (``sim/probe.hal``) trips where the tip, which stands for the
probe ball's centre, comes within R = sphere radius + ball radius of the sphere's centre
(``hardware.linuxcnc.SimSphere``), or below the pad (the start-up plane, made level).  The
machine profile knows the sphere and pad at nominal places ~0.3 mm off.  The simulator
has no pre-travel of its own except its trip lateness: it sees the contact up to two 1 ms
servo periods late (sampling + one period of feedback lag), 10 um at 300 mm/min, along
the motion.  So the job must find the true sphere centre, the true ball radius, a
pre-travel within that lateness and the pad height less it.
"""

from __future__ import annotations

import numpy as np
import pytest

from hardware.linuxcnc import SimBlock, SimSphere
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import SURFACE_SLOPE_X, SURFACE_Z, add_sim_machine
from tests.helpers.jobs import wait_for

OP = auth("operator")
BALL_MM, SPHERE_D_MM = 0.5, 10.0
SPHERE_MM = (30.3, 20.2, 3.1)   # the truth ...
PAD_Z_MM = -1.05
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "probe_command": "G38.2",
           "travel_feed_mm_min": 6000.0, "probe_feed_mm_min": 300.0,
           "tools": {"probe": {"ball_radius_mm": BALL_MM}, "nozzles": []},
           "reference": {"pad": {"centre_mm": [-20.0, 10.0, -1.0], "size_mm": 20.0},   # ... and the nominal places
                         "sphere": {"centre_mm": [30.0, 20.0, 3.0], "diameter_mm": SPHERE_D_MM}}}
LATE_MM = 2 * 300.0 / 60 * 0.001


@pytest.fixture
def reference_sphere(lcnc_env):
    lcnc_env.set_surface(SimBlock.plane(PAD_Z_MM, 0.0))
    lcnc_env.set_surface(SimSphere(SPHERE_MM, SPHERE_D_MM / 2 + BALL_MM))
    yield lcnc_env
    lcnc_env.set_surface(SimSphere.none())
    lcnc_env.set_surface(SimBlock.plane(SURFACE_Z, SURFACE_SLOPE_X))


def test_calibrate_probe_on_linuxcnc_finds_the_simulated_sphere_ball_and_pad(client, reference_sphere):
    sim = reference_sphere
    machine_id = add_sim_machine(client, sim, PROFILE, OP)
    response = client.post("/api/v1/jobs", json={"kind": "calibrate_probe", "params": {
        "machine_id": machine_id, "cap_rings_deg": [0, 60], "per_ring": 3, "equator": 7, "pad_touches": 3}},
        headers=OP)
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=240)
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    centre, radius, p0 = result["sphere_centre_mm"], result["ball_radius_mm"], result["pretravel"]["p0_mm"]
    print(f"calibrate_probe on LinuxCNC: {len(result['readings'])} touches; centre {np.round(centre, 4).tolist()} "
          f"(truth {list(SPHERE_MM)}), ball radius {radius:.4f} (truth {BALL_MM}), pre-travel p0 {p0 * 1e3:.1f} um, "
          f"pad {result['pad_reading_z_mm']:.4f} (truth {PAD_Z_MM}), rms {result['residual_rms_mm'] * 1e3:.2f} um")
    assert np.allclose(centre, SPHERE_MM, atol=0.003), centre
    assert abs(radius - BALL_MM) <= 0.003, radius
    assert -0.002 <= p0 <= LATE_MM + 0.002, p0   # the simulator's trip lateness is its only pre-travel
    assert -LATE_MM - 0.002 <= result["pad_reading_z_mm"] - PAD_Z_MM <= 0.002, result["pad_reading_z_mm"]
