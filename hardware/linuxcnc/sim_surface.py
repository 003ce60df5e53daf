"""The simulated probe surface of Conforma's LinuxCNC simulators (``sim/probe.hal``).

A :class:`SimBlock` is a block placed on the bed: in its own (part) frame its footprint is
``0 <= u <= length_mm``, ``0 <= v <= width_mm``, its bottom is at z = 0 and its top is the
plane ``z = height_mm + slope_x * u``.  It sits on the machine with the rigid placement
Conforma's ``register`` job reports: rotation ``rz_deg`` about the vertical axis through
the machine origin, then (dx, dy, dz).  The probe touches the block's top inside its
footprint and the bed (z = dz, the block's bottom) outside it.

    block = SimBlock(20, 14, 1.0, 0.01, dx=0.4, dy=-0.3, dz=0.05, rz_deg=0.5)
    sim.set_surface(block)        # halcmd setp ... on the running simulator
    block.top_z(x, y)             # the truth (machine coordinates, mm)

``SimBlock.plane(z0, slope_x)`` is the start-up surface: the endless plane
z = z0 + slope_x * x.

A :class:`SimSphere` is a reference sphere beside it (``calibrate_probe``): the probe
trips where the tip, which stands for the ball's centre, is within ``radius_mm`` (the
sphere's radius plus the ball's) of ``centre_mm``.  ``SimSphere.none()`` removes it.

    sim.set_surface(SimSphere((30.3, 20.2, 3.1), 5.0 + 0.5))

The three-axis simulator's laser height sensor (``sim/sensor.hal``) sees the same block:
``SimBlock.sensor_setp_values()`` are its surface pins.  A :class:`SimSensor` is its
optics (the fields of :class:`hardware.height_sensor.optics.SensorOptics` the component
has; the defaults are ``sensor.hal``'s start-up values):

    sim.set_sensor(SimSensor(offset_mm=(30, 5, -10), noise_mm=0.0005))

``latency_ms``: the sensor's value lags its exposure stamp by this much (the time offset a
calibration must recover; the clock counts milliseconds on the simulator).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["SimBlock", "SimSensor", "SimSphere"]

_ENDLESS = 1e9


@dataclass(frozen=True)
class SimBlock:
    """A placed block (mm, degrees); see the module docstring."""

    length_mm: float
    width_mm: float
    height_mm: float
    slope_x: float = 0.0
    dx: float = 0.0
    dy: float = 0.0
    dz: float = 0.0
    rz_deg: float = 0.0
    endless: bool = False

    @classmethod
    def plane(cls, z0: float, slope_x: float) -> SimBlock:
        """The endless plane z = z0 + slope_x * x (the simulators' start-up surface)."""
        return cls(0.0, 0.0, z0, slope_x, endless=True)

    def part_uv(self, x: float, y: float) -> tuple[float, float]:
        """Machine (x, y) -> part-frame (u, v): the inverse of the placement."""
        c, s = math.cos(math.radians(self.rz_deg)), math.sin(math.radians(self.rz_deg))
        return c * (x - self.dx) + s * (y - self.dy), -s * (x - self.dx) + c * (y - self.dy)

    def inside(self, x: float, y: float) -> bool:
        """True when machine (x, y) is over the block's footprint."""
        if self.endless:
            return True
        u, v = self.part_uv(x, y)
        return 0.0 < u < self.length_mm and 0.0 < v < self.width_mm

    def top_z(self, x: float, y: float) -> float:
        """The surface height the probe touches at machine (x, y), mm."""
        u, _ = self.part_uv(x, y)
        if not self.inside(x, y):
            return self.dz
        return self.dz + self.height_mm + self.slope_x * u

    def setp_values(self) -> dict[str, float]:
        """HAL pin/parameter values of ``sim/probe.hal`` for this surface."""
        c, s = math.cos(math.radians(self.rz_deg)), math.sin(math.radians(self.rz_deg))
        u_max, v_max = (_ENDLESS, _ENDLESS) if self.endless else (self.length_mm, self.width_mm)
        low = -_ENDLESS if self.endless else 0.0
        return {"conforma-u.gain0": c, "conforma-u.gain1": s,
                "conforma-u.offset": -(c * self.dx + s * self.dy),
                "conforma-v.gain0": -s, "conforma-v.gain1": c,
                "conforma-v.offset": s * self.dx - c * self.dy,
                "conforma-inside-u.min": low, "conforma-inside-u.max": u_max,
                "conforma-inside-v.min": low, "conforma-inside-v.max": v_max,
                "conforma-surface.gain0": self.slope_x,
                "conforma-surface.offset": self.dz + self.height_mm,
                "conforma-bed.in1": -_ENDLESS if self.endless else self.dz}

    def sensor_setp_values(self) -> dict[str, float]:
        """HAL pin values of ``sim/sensor.hal``'s component for this surface (the same
        placement; outside the footprint it sees the bed at dz)."""
        probe = self.setp_values()
        names = {"u.gain0": "u-gain0", "u.gain1": "u-gain1", "u.offset": "u-offset", "v.gain0": "v-gain0",
                 "v.gain1": "v-gain1", "v.offset": "v-offset", "inside-u.min": "u-min", "inside-u.max": "u-max",
                 "inside-v.min": "v-min", "inside-v.max": "v-max", "surface.gain0": "top-slope",
                 "surface.offset": "top-z", "bed.in1": "bed-z"}
        return {f"conforma-sensor.{pin}": probe[f"conforma-{key}"] for key, pin in names.items()}


@dataclass(frozen=True)
class SimSphere:
    """A reference sphere of the simulated probe (mm); see the module docstring.  The height
    sensor sees the sphere itself, radius ``radius_mm - ball_radius_mm``."""

    centre_mm: tuple[float, float, float]
    radius_mm: float
    ball_radius_mm: float = 0.0

    @classmethod
    def none(cls) -> SimSphere:
        """No sphere (the start-up state)."""
        return cls((0.0, 0.0, 0.0), 0.0)

    def setp_values(self) -> dict[str, float]:
        """HAL values of ``sim/probe.hal``'s sphere for this one."""
        cx, cy, cz = (float(v) for v in self.centre_mm)
        return {"conforma-dx.offset": -cx, "conforma-dy.offset": -cy, "conforma-dz.offset": -cz,
                "conforma-sphere.in1": float(self.radius_mm) ** 2}

    def sensor_setp_values(self) -> dict[str, float]:
        """HAL pin values of ``sim/sensor.hal``'s sphere (the sphere without the ball)."""
        cx, cy, cz = (float(v) for v in self.centre_mm)
        return {"conforma-sensor.sphere-x": cx, "conforma-sensor.sphere-y": cy, "conforma-sensor.sphere-z": cz,
                "conforma-sensor.sphere-r": max(float(self.radius_mm) - float(self.ball_radius_mm), 0.0)}


@dataclass(frozen=True)
class SimSensor:
    """The simulated height sensor's optics (mm, degrees); see the module docstring."""

    offset_mm: tuple[float, float, float] = (30.0, 5.0, -10.0)
    range_mm: float = 5.0
    noise_mm: float = 0.0005
    resolution_mm: float = 0.0001
    spot_mm: float = 0.03
    acceptance_deg: float = 25.0
    scale_error: float = 0.0
    slope_bias_mm: float = 0.0
    dropout_rate: float = 0.0
    latency_ms: float = 0.0

    def setp_values(self) -> dict[str, float]:
        """HAL pin values of ``sim/sensor.hal``'s component for these optics."""
        ox, oy, oz = (float(v) for v in self.offset_mm)
        values = {"offset-x": ox, "offset-y": oy, "offset-z": oz, "range": self.range_mm, "noise": self.noise_mm,
                  "resolution": self.resolution_mm, "spot": self.spot_mm, "acceptance-deg": self.acceptance_deg,
                  "scale-error": self.scale_error, "slope-bias": self.slope_bias_mm,
                  "dropout-rate": self.dropout_rate, "latency-ms": self.latency_ms}
        return {f"conforma-sensor.{k}": float(v) for k, v in values.items()}
