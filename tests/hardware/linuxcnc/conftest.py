"""The LinuxCNC simulator for these tests: at most one instance, started on demand.

``lcnc_xyz`` / ``lcnc_trt`` give a running :class:`hardware.linuxcnc.SimController` of the
three-axis or the five-axis (xyzac-trt) config.  One session-scoped manager owns the only
instance: asking for the other config shuts the running one down first, and the end of
each test module (and of the session) shuts it down.  The simulator's file lock keeps a
second test process from starting another LinuxCNC meanwhile.  Without LinuxCNC the tests skip, except under ``CI=true`` where
they fail (CI installs ``linuxcnc-uspace``).
"""

from __future__ import annotations


import time

import pytest

from hardware.linuxcnc import SimController, SimUnavailable, linuxcnc_available
from hardware.machine_types import MachineProfile

from tests.real_components import missing
PROFILE = MachineProfile(dispense_on="M64 P0", dispense_off="M65 P0", probe_command="G38.2",
                         travel_feed_mm_min=6000.0, probe_feed_mm_min=300.0, clearance_z=3.0,
                         probe_z_min=-10.0)
# the simulated probe surface of sim/*.ini ([CONFORMA] SURFACE_Z, SURFACE_SLOPE_X)
SURFACE_Z, SURFACE_SLOPE_X = -2.0, 0.01
TRT_PIVOT = (5.0, -3.0, -20.0)  # the five-axis simulator's xyzac-trt rot-point (mm)


class _OneSimulator:
    """Starts the requested config, stopping any other first (one LinuxCNC per host)."""

    def __init__(self) -> None:
        self.sim: SimController | None = None

    def get(self, config: str) -> SimController:
        if self.sim is not None and self.sim.config == config and self.sim.running:
            return self.sim
        self.close()
        if not linuxcnc_available():
            missing("LinuxCNC", "not installed (apt-get install linuxcnc-uspace)")
        sim = SimController(config, pivot_mm=TRT_PIVOT)
        try:
            sim.start()
        except SimUnavailable as exc:
            pytest.fail(f"the LinuxCNC simulator did not start: {exc}")
        self.sim = sim
        return sim

    def close(self) -> None:
        if self.sim is not None:
            self.sim.stop()
            self.sim = None


@pytest.fixture(scope="session")
def _one_simulator():
    manager = _OneSimulator()
    yield manager
    manager.close()


@pytest.fixture(scope="module", autouse=True)
def _stop_after_module(_one_simulator):
    """No simulator keeps running (and using CPU) once a module's tests are done."""
    yield
    _one_simulator.close()


@pytest.fixture
def lcnc_xyz(_one_simulator) -> SimController:
    return _one_simulator.get("xyz")


@pytest.fixture
def lcnc_trt(_one_simulator) -> SimController:
    return _one_simulator.get("xyzac-trt")


@pytest.fixture
def lcnc_env(lcnc_xyz, monkeypatch):
    """The service finds the simulator's passwords and program directory in its environment."""
    monkeypatch.setenv("CONFORMA_LINUXCNC_CONNECTPW", lcnc_xyz.connect_pw)
    monkeypatch.setenv("CONFORMA_LINUXCNC_ENABLEPW", lcnc_xyz.enable_pw)
    monkeypatch.setenv("CONFORMA_LINUXCNC_PROGRAMS", str(lcnc_xyz.workdir / "programs"))
    return lcnc_xyz


@pytest.fixture
def machine(lcnc_xyz):
    """A connected, homed three-axis LinuxCNC machine; disconnected afterwards."""
    m = lcnc_xyz.machine(PROFILE)
    m.connect()
    m.home()
    yield m
    if m.state != "disconnected":
        m.disconnect()


def wait_until(predicate, timeout_s: float = 5.0) -> bool:
    """True as soon as ``predicate()`` holds (polled every 10 ms), False after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def add_sim_machine(client, sim: SimController, profile: dict, headers: dict) -> str:
    """A three-axis ``linuxcnc://`` machine on ``sim`` through the API, connected and homed
    (the simulator homes Z up to its switch at 30 mm, above any surface: sim/home.hal)."""
    body = {"name": "lcnc", "port": f"linuxcnc://127.0.0.1:{sim.port}?joints=3", "dialect": "linuxcnc",
            "profile": profile}
    response = client.post("/api/v1/machines", json=body, headers=headers)
    assert response.status_code == 201, response.text
    machine_id = response.json()["id"]
    assert client.post(f"/api/v1/machines/{machine_id}/connect", headers=headers).json()["state"] == "idle"
    homed = client.post(f"/api/v1/machines/{machine_id}/home", headers=headers)
    assert homed.status_code == 200 and homed.json()["position"] == pytest.approx([0, 0, 30], abs=1e-6), homed.text
    return machine_id

