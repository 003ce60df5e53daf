"""The mock print head on the LinuxCNC simulator: a jetting bench driven by LinuxCNC.

A real jetting bench on LinuxCNC wires it like this: the head driver takes its bitmaps over
its own link (``head_port``: serial, USB or Ethernet) and fires on the scan axis' position
(the axis encoder split to the driver's encoder input, or LinuxCNC's HAL echoing the joint
position as quadrature, e.g. ``encoder``/``stepgen`` in quadrature mode); LinuxCNC moves the
carriage, switches the UV lamp with a motion digital output (``M64 P3`` / ``M65 P3``) and
samples the height sensor with the joints.  The host never times a drop.

On the simulator :class:`SimHeadBridge` plays the driver's encoder input and the lamp's
wiring: it follows the simulator's HAL from the controller's side (``hal_watch.py``: the
joints' ``pos-fb``, the lamp's ``motion.digital-out-NN`` and the servo clock every 0.5 ms) and
feeds a :class:`hardware.mock.world.MockWorld` named ``name``: the carriage's segments on the
controller's servo clock (``conforma:clock``, ms of servo time; its
:class:`~hardware.mock.timeline.MotionTimeline`) and the lamp (``motion.digital-out-03``,
``sim/sensor.hal``) as the world's output ``P3``.  The servo clock, not the moment the watcher
read a sample, times them, and the lamp's edges come from HAL's count of its on-time
(``conforma:lamp-ms``): a busy host reads the watcher's samples tens of ms apart, and a 0.3 s
exposure read 0.1 s short would not cure.
The mock head ``head://name?cure=P<n>`` rides on that world exactly as on the mock machine
(:mod:`hardware.printhead.mock`: it fires each drop when its nozzle crosses its row, cures the
ink when the lamp was on long enough).  Before each of the head's commands the bridge catches
up with HAL (:func:`hardware.printhead.mock.follow_world`).
After each cure it writes the head's field (the ink's heights above the bed) to the
simulator's sensor map (:attr:`SimController.sensor_map`), which the simulated height sensor
adds to the part under its spot (``sensor_hal.py``).

    with SimHeadBridge(sim, "bench") as bridge:     # head://bench?cure=P3&... rides on it
        ...                                            # a jetting_run on the simulator
        bridge.head.field.heights()                    # the truth

The positions are the motors' (the frame the simulated part and sensor live in); a drop's x
is the joint position where its nozzle crossed its row.
"""

from __future__ import annotations

import io
import os
import threading
import time
from typing import TYPE_CHECKING

import numpy as np

from ..mock.timeline import MotionTimeline
from ..mock.world import MockWorld, register_world, unregister_world
from ..printhead.mock import MockPrintHead, follow_world, get_head

if TYPE_CHECKING:
    from .hal_watcher import HalWatch
    from .sim import SimController

__all__ = ["SimHeadBridge"]

LAMP_OUTPUT = 3      # the motion digital output sim/sensor.hal counts the on-time of
FOLLOW_S = 0.002     # how often the bridge takes the watcher's new samples
CATCH_UP_S = 5.0     # the longest a head command waits for HAL to be followed up to its call


class SimHeadBridge:
    """Feeds the world ``name`` from the simulator's HAL (see the module docstring)."""

    key = f"P{LAMP_OUTPUT}"  # the lamp as the world's output (``head://...&cure=P3``)

    def __init__(self, sim: SimController, name: str, max_s: float = 7200.0) -> None:
        self.sim = sim
        self.name = name
        self.world = register_world(name, MockWorld(keep_transcript=False))
        self.world.timeline = MotionTimeline()
        self.pins = ["joint.0.pos-fb", "joint.1.pos-fb", "joint.2.pos-fb", f"motion.digital-out-{LAMP_OUTPUT:02d}",
                     "conforma:clock", "conforma:lamp-ms"]
        self._done = 0          # watcher samples taken
        self._last_ns = 0       # the newest sample's time (monotonic ns)
        self._prev: tuple[float, tuple[float, float, float]] | None = None
        self._lamp: float | None = None
        self._read: tuple[float, float] | None = None  # the last sample's servo time (s) and lamp count (ms)
        self._cures: dict[int, int] = {}
        self.maps_written = 0
        self._clock0: float | None = None  # the servo clock's first count (ms)
        self._cond = threading.Condition()
        self._running = True
        self._watch: HalWatch = sim.watch(self.pins, 0.0005, max_s)
        self._thread = threading.Thread(target=self._follow, daemon=True, name=f"sim-head-{name}")
        self._thread.start()
        follow_world(name, self.catch_up)

    @property
    def head(self) -> MockPrintHead:
        """The mock head riding on this world (registered by its first ``head://`` open)."""
        return get_head(self.name)

    def catch_up(self) -> None:
        """Return once a HAL sample taken after this call has been followed (at most
        ``CATCH_UP_S``: a watcher that stopped leaves the world where it was)."""
        now = time.monotonic_ns()
        with self._cond:
            self._cond.wait_for(lambda: self._last_ns >= now or not self._running, CATCH_UP_S)

    def _follow(self) -> None:
        while self._running:
            samples = self._watch.samples
            if len(samples) > self._done:
                new = samples[self._done:]
                self._done += len(new)
                self._take(new)
            time.sleep(FOLLOW_S)

    def _take(self, samples: list[tuple[int, list[float]]]) -> None:
        world, timeline = self.world, self.world.timeline
        assert timeline is not None
        with world.lock:
            for _, values in samples:
                if self._clock0 is None:
                    self._clock0 = values[4]
                t = (values[4] - self._clock0) * 1e-3  # s of servo time since the first sample
                p = (values[0], values[1], values[2])
                if self._prev is not None and p != self._prev[1]:
                    timeline.add(self._prev[0], t, self._prev[1], p)
                if self._prev is None or p != self._prev[1] or t - self._prev[0] > 0.05:
                    self._prev = (t, p)
                if values[3] != self._lamp:
                    world.stats.machine_time_s = self._edge(t, values[5], values[3])
                    self._lamp = values[3]
                    world.set_output(self.key, values[3])
                world.stats.machine_time_s = t
                self._read = (t, values[5])
            self._write_map()
        with self._cond:
            self._last_ns = samples[-1][0]
            self._cond.notify_all()

    def _edge(self, t: float, lamp_ms: float, on: float) -> float:
        """The servo time (s) the lamp switched, seen at the sample (``t`` s, ``lamp_ms``):
        on, it has been on for the count's growth since the last read; off, it stayed on for
        that growth after the last read."""
        if self._read is None:
            return t
        grown = (lamp_ms - self._read[1]) * 1e-3
        return t - grown if on else self._read[0] + grown

    def _write_map(self) -> None:
        """The jetted fields' heights to the sensor map after a cure (atomically)."""
        for surface in self.world.surfaces:
            cures = getattr(surface, "cures", None)
            if cures is None or self._cures.get(id(surface), 0) == cures:  # uncured: nothing to show yet
                continue
            self._cures[id(surface)] = cures
            buf = io.BytesIO()
            np.savez(buf, heights=surface.heights(), origin=np.asarray(surface.origin, dtype=float),
                     pitch=np.float64(surface.pitch))
            target = self.sim.sensor_map
            partial = target.with_name(target.name + ".part")
            partial.write_bytes(buf.getvalue())
            os.replace(partial, target)
            self.maps_written += 1

    def close(self) -> None:
        """Stop following, forget the world and the map (the sensor sees the bare part again)."""
        follow_world(self.name, None)
        self._running = False
        with self._cond:
            self._cond.notify_all()
        self._thread.join(5)
        self._watch.close()
        unregister_world(self.name)
        self.sim.sensor_map.unlink(missing_ok=True)

    def __enter__(self) -> SimHeadBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
