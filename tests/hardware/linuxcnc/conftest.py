"""The LinuxCNC simulator for these tests: at most one instance per test process, started on demand.

``lcnc_xyz`` / ``lcnc_trt`` give a running :class:`hardware.linuxcnc.SimController` of the
three-axis or the five-axis (xyzac-trt) config.  One manager per test process owns the
only instance: asking for the other config shuts the running one down first.  A simulator
serves every module that asks for its config (a start costs 7 s on a quiet box and over a
minute beside a busy xdist worker): the first time a module asks for it, it is reset
(:meth:`SimController.reset`) and its :meth:`~SimController.snapshot` must equal the one
taken right after its start, else it is restarted; so no module inherits another's
surface, e-stop, tool, units, homing or dispense output.  It is shut down as soon as the
next test is not a LinuxCNC test (or at the end of the session): no idle simulator uses
CPU beside the rest of the suite.  The tests that need the five-axis config run after the
three-axis ones (tests/conftest.py), so the config switches once.  As root each simulator
runs in namespaces of its own (:mod:`hardware.linuxcnc.sim_namespace`) and the modules form
two groups on two workers, each with its simulator (tests/conftest.py); elsewhere the
simulator's file lock keeps a second test process from starting another LinuxCNC meanwhile.  Without
LinuxCNC the tests skip, except under ``CI=true`` where they fail (CI installs
``linuxcnc-uspace``).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import pytest

from hardware.errors import LinkError
from hardware.linuxcnc import SimController, SimUnavailable, linuxcnc_available
from hardware.linuxcnc.hal_command import HAL_PREFIX_VAR
from hardware.machine_types import MachineProfile
from tests.helpers.real_components import missing

PROFILE = MachineProfile(dispense_on="M64 P0", dispense_off="M65 P0", probe_command="G38.2",
                         travel_feed_mm_min=6000.0, probe_feed_mm_min=300.0, clearance_z=3.0,
                         probe_z_min=-10.0)
# the simulated probe surface of sim/*.ini ([CONFORMA] SURFACE_Z, SURFACE_SLOPE_X)
SURFACE_Z, SURFACE_SLOPE_X = -2.0, 0.01
TRT_PIVOT = (5.0, -3.0, -20.0)  # the five-axis simulator's xyzac-trt rot-point (mm)
HERE = Path(__file__).resolve().parent
RESET_SETTLE_S = 10.0  # how long a reset simulator may take to report its start-up state


class _OneSimulator:
    """Starts the requested config, stopping any other first (one LinuxCNC per host), and
    resets it for each new module that asks for it (see the module docstring).  ``starts``
    and ``resets`` count what it did (``SimController.startup_s`` is the last start)."""

    def __init__(self) -> None:
        self.sim: SimController | None = None
        self.start_state: dict[str, float | str] = {}
        self.module: str | None = None   # the module the simulator last served
        self.starts = 0
        self.resets = 0

    def get(self, config: str, module: str) -> SimController:
        sim = self.sim
        if sim is not None and sim.config == config and sim.running:
            if module != self.module:
                self._reset(sim)
            if self.sim is not None:
                self.module = module
                return self.sim
        self._start(config)
        self.module = module
        assert self.sim is not None
        return self.sim

    def _start(self, config: str) -> None:
        self.close()
        if not linuxcnc_available():
            missing("LinuxCNC", "not installed (apt-get install linuxcnc-uspace)")
        sim = SimController(config, pivot_mm=TRT_PIVOT)
        try:
            sim.start()
            self.start_state = sim.snapshot()
        except SimUnavailable as exc:
            sim.stop()
            pytest.fail(f"the LinuxCNC simulator did not start: {exc}")
        self.sim = sim
        self.starts += 1

    def _reset(self, sim: SimController) -> None:
        """Reset ``sim``; restart it when its state still differs from the start-up state."""
        try:
            sim.reset()
            # the controller's status follows its commands a few task cycles late (longer
            # on a loaded host): poll the snapshot until it matches, at most RESET_SETTLE_S
            deadline = time.monotonic() + RESET_SETTLE_S
            while (state := sim.snapshot()) != self.start_state and time.monotonic() < deadline:
                time.sleep(0.1)
        except (SimUnavailable, LinkError) as exc:  # e.g. a linuxcncrsh that stopped answering
            state = {"reset failed": str(exc)}
        if state == self.start_state:
            self.resets += 1
            return
        differs = {k: (state.get(k), self.start_state.get(k)) for k in {*state, *self.start_state}
                   if state.get(k) != self.start_state.get(k)}
        warnings.warn(f"the LinuxCNC simulator's reset left {differs} (now, start-up): restarted", stacklevel=2)
        self.close()

    def close(self) -> None:
        if self.sim is not None:
            self.sim.stop()
            self.sim = None
            self.module = None


_MANAGER = _OneSimulator()


@pytest.fixture(scope="session")
def _one_simulator():
    yield _MANAGER
    _MANAGER.close()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None):
    """Stop the simulator once the next test (if any) is not one of this directory's."""
    yield
    if nextitem is None or HERE not in nextitem.path.resolve().parents:
        _MANAGER.close()


@pytest.fixture
def lcnc_xyz(_one_simulator, request) -> SimController:
    return _one_simulator.get("xyz", request.module.__name__)


@pytest.fixture
def lcnc_trt(_one_simulator, request) -> SimController:
    return _one_simulator.get("xyzac-trt", request.module.__name__)


def service_finds(sim: SimController, monkeypatch) -> SimController:
    """The service finds the simulator's passwords and program directory in its environment."""
    monkeypatch.setenv("CONFORMA_LINUXCNC_CONNECTPW", sim.connect_pw)
    monkeypatch.setenv("CONFORMA_LINUXCNC_ENABLEPW", sim.enable_pw)
    monkeypatch.setenv("CONFORMA_LINUXCNC_PROGRAMS", str(sim.workdir / "programs"))
    prefix = (sim.hal_env or {}).get(HAL_PREFIX_VAR)
    if prefix is not None:  # the simulator in namespaces of its own: its HAL reached through them
        monkeypatch.setenv(HAL_PREFIX_VAR, prefix)
    return sim


@pytest.fixture
def lcnc_env(lcnc_xyz, monkeypatch):
    """The three-axis simulator, found by the service (:func:`service_finds`)."""
    return service_finds(lcnc_xyz, monkeypatch)


@pytest.fixture
def machine(lcnc_xyz):
    """A connected, homed three-axis LinuxCNC machine at its home position (0, 0, 30) in mm;
    disconnected afterwards.  Homed when the controller's joints are not (a module's first
    test: the simulator's reset un-homes them), else sent home the way homing goes (Z up
    first, then X Y; 3 s of homing a test saved)."""
    m = lcnc_xyz.machine(PROFILE)
    m.connect()
    if m.homed:
        m.send("G21")  # a previous test may have left inches
        m.move(z=30.0)
        m.move(x=0.0, y=0.0)
    else:
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

