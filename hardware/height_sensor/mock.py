"""The mock LK-G controller: the command subset of :mod:`hardware.height_sensor.lkg` over a
``lkg://NAME?options`` pyserial URL, coupled to a mock machine.

The sensor shares the mock machine's world (``machine=<world name>``, default NAME: a mock
machine registered by the service under its id), so it reads the true part, the reference
artifacts and the carriage's position stream with its machine-clock times
(:class:`hardware.mock.timeline.MotionTimeline`, attached to the world when the sensor is
made).  Storage (``AS``) starts at the machine clock's present (start it with the machine
at rest, then move: the storage's sample k is stamped k / rate after the start); ``AP``
stops it; ``AO,1`` outputs one value per sampling cycle, computed from where the carriage
was ``time_offset_ms`` before each stamp.  ``M0``/``M1`` read the spot now.

URL options (all optional)::

    lkg://NAME?machine=NAME&offset=30,5,-10&range_mm=5&resolution_mm=0.0001&noise_mm=0.0005
        &spot_mm=0.03&rate_hz=2000&acceptance_deg=25&time_offset_ms=0&scale_error=0
        &slope_bias_mm=0&dropout_rate=0&dark=x,y,r;x,y,r&capacity=65536&seed=0

Options given for a registered sensor update it.  ``InvalidConfig`` names ``port.<option>``.
"""

from __future__ import annotations

import math
import threading
from dataclasses import fields
from typing import Any
from urllib.parse import parse_qsl

import numpy as np

from ..errors import InvalidConfig
from ..mock.timeline import MotionTimeline
from ..mock.url_options import url_numbers
from ..mock.world import MockWorld, get_world
from ..port_url import PortUrl
from . import lkg
from .optics import Scene, SensorOptics, readings

_FLOATS = {"range_mm", "resolution_mm", "noise_mm", "spot_mm", "rate_hz", "acceptance_deg", "time_offset_ms",
           "scale_error", "slope_bias_mm", "dropout_rate"}
_INTS = {"capacity", "seed"}


class MockHeightSensor:
    """One mock LK-G controller with one head (OUT1; OUT2 repeats it)."""

    def __init__(self, optics: SensorOptics, machine: str) -> None:
        self.optics = optics
        self.machine = machine
        self.communication = False
        self.storing = False
        self.start_s = 0.0
        self.stop_s: float | None = None
        self.stored: list[str] = []
        self.lock = threading.RLock()
        self._scene: tuple[object, Scene] | None = None
        self.unplugged = False  # a fault: the cable is out, nothing answers

    # ------------------------------------------------------------------ the machine
    def world(self) -> MockWorld:
        try:
            world = get_world(self.machine)
        except KeyError:
            raise InvalidConfig(f"no mock machine {self.machine!r} for the sensor", field="port.machine",
                                value=self.machine) from None
        if world.timeline is None:
            world.timeline = MotionTimeline()
        return world

    def scene(self, world: MockWorld) -> Scene:
        key = (id(world), id(world.true_part), world.placement, world.pad, world.sphere, world.bed_z)
        if self._scene is None or self._scene[0] != key:
            self._scene = (key, Scene(world))
        return self._scene[1]

    def _values(self, world: MockWorld, carriage: np.ndarray) -> list[str]:
        values = readings(self.optics, self.scene(world), carriage)
        return [lkg.format_value(None if math.isnan(v) else float(v), self.optics.range_mm) for v in values]

    def _sample_count(self, until_s: float) -> int:
        span = max(until_s - self.start_s, 0.0)
        return min(int(math.floor(span * self.optics.rate_hz + 1e-9)) + 1, int(self.optics.capacity))

    def _stored_until(self, world: MockWorld, until_s: float) -> list[str]:
        """The stored values up to ``until_s`` (machine clock), computed once per stop."""
        count = self._sample_count(until_s)
        if len(self.stored) < count:
            k = np.arange(len(self.stored), count)
            stamps = self.start_s + k / self.optics.rate_hz
            exposed = stamps - self.optics.time_offset_ms / 1000.0
            assert world.timeline is not None
            self.stored += self._values(world, world.timeline.positions(exposed))
        return self.stored[:count]

    # ------------------------------------------------------------------ commands
    def handle(self, line: str) -> str | None:
        """The response line (without CR) to one command line (None: unplugged, no answer)."""
        if self.unplugged:
            return None
        parts = [p.strip() for p in line.strip().split(",")]
        head = parts[0].upper()
        args = parts[1:]
        with self.lock:
            if head == "Q0":
                self.communication = True
                return "Q0"
            if head == "R0":
                self.communication = False
                return "R0"
            if head not in ("M0", "M1", "AQ", "AS", "AP", "AN", "AO"):
                return f"ER,{head[:2]},00"
            if self.communication:
                return f"ER,{head},01"
            world = self.world()
            with world.lock:
                now = world.stats.machine_time_s
                if head in ("M0", "M1"):
                    if args:
                        return f"ER,{head},21"
                    value = self._values(world, np.array([world.position]))[0]
                    return f"M1,{value}" if head == "M1" else f"M0,{value},{value}"
                if head == "AQ":
                    self.storing, self.stored, self.stop_s = False, [], None
                    return "AQ"
                if head == "AS":
                    if self.storing:
                        return "ER,AS,01"
                    self.storing, self.stored, self.start_s, self.stop_s = True, [], now, None
                    assert world.timeline is not None
                    world.timeline.anchor(now, world.position)
                    return "AS"
                if head == "AP":
                    if not self.storing:
                        return "ER,AP,01"
                    self._stored_until(world, now)
                    self.storing, self.stop_s = False, now
                    return "AP"
                until = now if self.storing else self.stop_s
                if head == "AN":
                    count = 0 if until is None else len(self._stored_until(world, until))
                    return f"AN,{int(self.storing)},{count}"
                if len(args) != 1:
                    return "ER,AO,21"
                if args[0] not in ("1", "01"):
                    return "ER,AO,22"
                values = [] if until is None else self._stored_until(world, until)
                return ",".join(["AO", *values])


_REGISTRY: dict[str, MockHeightSensor] = {}
_LOCK = threading.Lock()


def parse_options(query: str) -> dict[str, Any]:
    """Typed options from a ``lkg://`` query string (``InvalidConfig`` when malformed)."""
    out: dict[str, Any] = {}  # each key's value typed as SensorOptics' field of that name
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise InvalidConfig(f"malformed sensor options {query!r}", field="port", value=query[:80]) from None
    for key, text in pairs:
        if key == "machine":
            out[key] = text
        elif key == "offset":
            out["offset_mm"] = url_numbers(key, text, 3, "sensor")
        elif key == "dark":
            out["dark_spots"] = tuple(url_numbers(key, spot, 3, "sensor") for spot in text.split(";") if spot)
        elif key in _FLOATS or key in _INTS:
            try:
                value: float = int(text) if key in _INTS else float(text)
            except ValueError:
                raise InvalidConfig(f"sensor option {key}={text!r} is not a number", field=f"port.{key}",
                                    value=text[:40]) from None
            if not math.isfinite(value):
                raise InvalidConfig(f"sensor option {key} must be finite", field=f"port.{key}", value=text[:40])
            out[key] = value
        else:
            raise InvalidConfig(f"unknown sensor option {key!r}", field=f"port.{key}", value=text[:40])
    return out


def register_sensor(name: str, sensor: MockHeightSensor) -> MockHeightSensor:
    """Make ``sensor`` reachable as ``lkg://name``."""
    with _LOCK:
        _REGISTRY[name] = sensor
    return sensor


def unregister_sensor(name: str) -> None:
    with _LOCK:
        _REGISTRY.pop(name, None)


def sensor_from_url(url: str) -> MockHeightSensor:
    """Resolve ``lkg://NAME?options`` to a (possibly new, then registered) mock sensor."""
    parts = PortUrl.parse(url)
    if parts.scheme != "lkg":
        raise InvalidConfig(f"not a sensor URL: {url!r}", field="port", value=url[:80])
    name = parts.name
    options = parse_options(parts.query)
    machine = str(options.pop("machine", name))
    known = {f.name for f in fields(SensorOptics) if f.init}
    with _LOCK:
        sensor = _REGISTRY.get(name)
        if sensor is None:
            sensor = MockHeightSensor(SensorOptics(**{k: v for k, v in options.items() if k in known}), machine)
            _REGISTRY[name] = sensor
            return sensor
    with sensor.lock:
        sensor.machine = machine
        merged = {f.name: getattr(sensor.optics, f.name) for f in fields(SensorOptics) if f.init}
        merged.update(options)
        sensor.optics = SensorOptics(**merged)
    return sensor
