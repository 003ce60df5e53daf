"""The simulator's jetting pieces without LinuxCNC: the sensor component's surface (the sphere,
the jetted ink map, the latency's position lookup) and :class:`SimHeadBridge` fed from a
scripted HAL watcher (the carriage crossing a swath, the lamp on for the dose)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from hardware.linuxcnc import sensor_hal
from hardware.linuxcnc.sim_head import SimHeadBridge
from hardware.printhead import PrintHead
from hardware.printhead.mock import unregister_head

FLAT = {"u-gain0": 1.0, "u-gain1": 0.0, "u-offset": 0.0, "v-gain0": 0.0, "v-gain1": 1.0, "v-offset": 0.0,
        "u-min": -1e9, "u-max": 1e9, "v-min": -1e9, "v-max": 1e9, "top-z": -1.0, "top-slope": 0.0, "bed-z": -1e9,
        "sphere-x": 10.0, "sphere-y": 0.0, "sphere-z": 0.0, "sphere-r": 5.0}


def test_the_sensor_sees_the_sphere_above_the_plane_with_its_tilt():
    points = np.array([[[10.0, 0.0]], [[13.0, 0.0]], [[20.0, 0.0]]])
    heights, cos_tilt = sensor_hal.block_heights(FLAT, points)
    assert heights[:, 0] == pytest.approx([5.0, 4.0, -1.0])
    assert cos_tilt == pytest.approx([1.0, 0.8, 1.0])


def test_the_latency_looks_up_where_the_carriage_was():
    history = [(100.0, 0.0, 0.0, 5.0), (101.0, 0.1, 0.0, 5.0), (102.0, 0.2, 0.0, 5.0)]
    assert sensor_hal.position_at(history, 101.5) == pytest.approx((0.15, 0.0, 5.0))
    assert sensor_hal.position_at(history, 90.0) == pytest.approx((0.0, 0.0, 5.0))  # held at the first read


class _ServoPins(dict):
    """A component's pins as a servo thread writes them (``sim/sensor.hal``): each period sets
    the started count, then the joints one by one, then the finished count; ``stall_in`` reads
    pass mid-period (a preempted servo thread)."""

    def __init__(self, stall_in: int) -> None:
        super().__init__({"tick": 7.0, "tick-started": 7.0, "x": 7.0, "y": 7.0, "z": 7.0})
        self.reads, self.stall_in = 0, stall_in

    def __getitem__(self, pin: str) -> float:
        self.reads += 1
        if self.reads == 2:  # a period starts after the first read: x written, y and z not yet
            self.update({"tick-started": 8.0, "x": 8.0})
        if self.reads == 2 + self.stall_in:
            self.update({"y": 8.0, "z": 8.0, "tick": 8.0})
        return dict.__getitem__(self, pin)


def test_the_sensor_keeps_only_joints_read_within_one_servo_period():
    p: dict = {}
    pins = _ServoPins(stall_in=30)
    assert sensor_hal.read_joints(pins, p, time.monotonic() + 5.0) == 8.0
    assert (p["x"], p["y"], p["z"]) == (8.0, 8.0, 8.0)  # never x of period 8 with y of period 7
    p = {}
    assert sensor_hal.read_joints(_ServoPins(stall_in=10**9), p, time.monotonic() + 0.01) is None


def test_the_ink_map_is_read_again_when_its_file_changes(tmp_path: Path):
    path = tmp_path / "map.npz"
    ink = sensor_hal.InkMap(path)
    ink.refresh(1.0)
    assert ink.at(np.array([[[0.0, 0.0]]]))[0, 0] == 0.0  # no file: no ink
    np.savez(path, heights=np.array([[0.001, 0.002], [0.003, 0.004]]), origin=np.array([5.0, 5.0]), pitch=0.1)
    ink.refresh(2.0)
    points = np.array([[[5.0, 5.0], [5.1, 5.0], [5.1, 5.1], [7.0, 7.0]]])
    assert ink.at(points)[0] == pytest.approx([0.001, 0.002, 0.004, 0.0])


class _Watch:
    """A scripted hal_watch: (t_ns, [x, y, z, lamp, clock, lamp_ms]) rows; the test sets where the
    carriage is (:meth:`at`), and from then on, as HAL's servo thread does, the watcher keeps
    sampling that state every ``TICK_S`` until closed (a head command waits for a sample newer than itself:
    ``SimHeadBridge.catch_up``).  ``lamp_ms`` counts the lamp's on-time as ``sim/sensor.hal`` does,
    also while :attr:`paused` (a busy host's watcher that reads nothing)."""

    TICK_S = 0.002

    def __init__(self) -> None:
        self.samples: list[tuple[int, list[float]]] = []
        self.clock = 0.0
        self.lamp_ms = 0.0
        self.paused = False
        self.starved = False  # the ticker thread not scheduled: no sample, no count, until at()
        self._t0_ns = time.monotonic_ns()
        self._state: list[float] | None = None   # nothing to sample before the first at()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker = threading.Thread(target=self._tick, daemon=True)
        self._ticker.start()

    def _count(self) -> int:
        """Count the lamp's on-time up to now at the state held since the last count (the
        lock held); the time now (ns)."""
        now = time.monotonic_ns()
        clock = (now - self._t0_ns) / 1e6  # ms, as conforma:clock counts 1 ms servo periods
        if self._state is not None:
            self.lamp_ms += self._state[3] * (clock - self.clock)
        self.clock = clock
        return now

    def _sample(self) -> None:
        with self._lock:
            now = self._count()
            if self._state is not None and not self.paused:
                self.samples.append((now, [*self._state, self.clock, self.lamp_ms]))

    def _tick(self) -> None:
        while not self._stop.wait(self.TICK_S):
            if not self.starved:
                self._sample()

    def at(self, x: float, y: float, lamp: float = 0.0) -> None:
        """The carriage and lamp change now: the time since the last sample is counted at the
        state before (HAL counts each servo period at that period's lamp; a busy host's
        ticker may not have sampled for tens of ms)."""
        with self._lock:
            self._count()
            self._state = [x, y, 5.0, lamp]
        self._sample()

    def close(self) -> None:
        self._stop.set()
        self._ticker.join()


class _Sim:
    def __init__(self, workdir: Path) -> None:
        self.sensor_map = workdir / "sensor_map.npz"
        self.watcher = _Watch()

    def watch(self, names, period_s, max_s):
        return self.watcher


@pytest.mark.parametrize("starved", [False, True])
def test_the_bridge_fires_a_swath_on_the_followed_joints_and_maps_the_cured_ink(tmp_path: Path, starved):
    """``starved``: the watcher's ticker is not scheduled while the lamp is on, so the off
    edge's sample is the first after the on edge's (the lamp's count must hold the dose)."""
    sim = _Sim(tmp_path)
    bridge = SimHeadBridge(sim, "bridgetest")  # type: ignore[arg-type]
    head = PrintHead("head://bridgetest?nozzles=4&rows=1&row_gap_um=0&offset=0,0&field=0,0,40,40&cure=P3&cure_s=0.05"
                     "&spread=0&drop_noise=0")
    watch = sim.watcher
    try:
        head.connect()
        watch.at(1.0, 0.5)
        bits = np.zeros((5, 4), dtype=bool)
        bits[2, :] = True                                    # row 2 at y = 1 + 2 pitches: four drops
        pitch = 25.4 / 300
        head.load(bits, 1.0, 0)
        head.arm()
        for y in np.linspace(0.5, 1.0 + 6 * pitch, 40):     # the carriage crosses every row
            watch.at(1.0, float(y))
        assert head.status().rows_done == 5
        assert head.disarm() == 4
        watch.at(1.0, 1.6, lamp=1.0)
        watch.starved = starved
        time.sleep(0.1)                                      # the lamp on for twice the dose (the clock runs on)
        watch.at(1.0, 1.6, lamp=0.0)
        watch.starved = False
        deadline = time.monotonic() + 5
        while (bridge.maps_written == 0 or bridge.head.cures == 0) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert bridge.head.cures == 1 and bridge.head.field.drops == 4
        with np.load(sim.sensor_map) as data:
            assert data["heights"].sum() > 0 and np.allclose(data["heights"], bridge.head.field.heights())
            assert float(data["pitch"]) == pytest.approx(pitch)
    finally:
        head.close()
        bridge.close()
        unregister_head("bridgetest")
    assert not sim.sensor_map.exists()


@pytest.mark.parametrize("late, exposure_s, cures", [("on", 0.12, 1), ("off", 0.04, 0)])
def test_the_lamps_edges_read_late_by_a_busy_host_keep_their_servo_times(tmp_path: Path, late, exposure_s, cures):
    """The watcher reads nothing for 0.1 s around one of the lamp's edges: a 0.12 s exposure
    seen on 0.1 s late still cures (dose 0.1 s), a 0.04 s one seen off 0.1 s late does not."""
    sim = _Sim(tmp_path)
    bridge = SimHeadBridge(sim, "lamptest")  # type: ignore[arg-type]
    head = PrintHead("head://lamptest?nozzles=4&rows=1&offset=0,0&field=0,0,40,40&cure=P3&cure_s=0.1")
    watch = sim.watcher
    try:
        head.connect()
        watch.at(1.0, 0.5)
        head.status()                                        # the head rides on the world from here
        watch.paused = late == "on"
        watch.at(1.0, 0.5, lamp=1.0)
        if late == "on":
            time.sleep(0.1)
            watch.paused = False
            time.sleep(exposure_s - 0.1)
        else:
            time.sleep(exposure_s)
            watch.paused = True
        watch.at(1.0, 0.5, lamp=0.0)
        time.sleep(0.1 if late == "off" else 0.0)
        watch.paused = False
        watch.at(1.0, 0.5)
        head.status()                                        # caught up with a sample after the off edge
        dose_s = watch.lamp_ms * 1e-3                        # the lamp's true on-time (the sleeps may overrun)
        assert bridge.head.cures == int(dose_s >= 0.1) and (cures == 0 or dose_s >= 0.12)
    finally:
        head.close()
        bridge.close()
        unregister_head("lamptest")
