"""Driving a height sensor with a machine: scan passes and the sensor's calibration.

A pass: the carriage goes to the travel height, over the first waypoint, down to it; the
sensor's storage starts with the carriage at rest there; the waypoints stream at the scan
feed (then the dialect's wait for the moves); the storage stops and its values are read.
The carriage position of each sample comes from the commanded pass
(:func:`app.probing.scan_path.sample_positions`) and the calibrated time offset.

:func:`open_scanner` picks how a scan job reads the sensor from the machine's port: on a
``linuxcnc://`` machine the sensor is an analog input the controller samples with its
joints in the servo thread (:class:`hardware.linuxcnc.hal_scan.HalScan`, the controller
on this host), so each sample carries the carriage's measured position; on a serial
machine it is the LK-G sensor on its own link (``sensor_port``).

:func:`calibrate_sensor` runs the three procedures of :mod:`app.calibration.sensor`, with
either backend (still readings: a dwell sampled by the controller, or single measurements), on
the reference pad (its probe-measured top height) and the datum sphere (its qualified centre
and radius).  Machine and sensor errors pass through as hardware errors (the job kinds
translate them).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.calibration.sensor import (
    EdgePass,
    SensorCalibration,
    fit_scale_and_z,
    fit_sphere_scan,
    fit_time_offset,
    with_time_offset_sd,
)
from app.domain.errors import InvalidInput
from app.probing.scan_path import sample_positions
from app.reconstruction.scan_samples import exposure_positions
from hardware import backend
from hardware.errors import HardwareError
from hardware.height_sensor import HeightSensor
from hardware.machine import Machine
from hardware.port_url import PortUrl

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


@dataclass(frozen=True)
class PassData:
    """One executed pass: waypoints (m, 3), speed mm/s, readings (n,) mm (NaN: none)."""

    waypoints: np.ndarray
    speed_mm_s: float
    values: np.ndarray


def run_pass(machine: Machine, sensor: HeightSensor, waypoints: np.ndarray, speed_mm_s: float,
             travel_z: float | None = None) -> PassData:
    """Drive one pass (see module docstring); ``travel_z`` None: go straight to the start."""
    w = np.asarray(waypoints, dtype=float)
    if travel_z is not None:
        machine.move(z=max(travel_z, float(w[0, 2])))
        machine.move(x=float(w[0, 0]), y=float(w[0, 1]))
    machine.move(x=float(w[0, 0]), y=float(w[0, 1]), z=float(w[0, 2]))
    feed = speed_mm_s * 60.0
    lines = ["G90"] + [f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f} F{feed:.1f}" for x, y, z in w[1:]]
    sensor.start_storage()
    machine.stream(lines + [machine.rules.wait_moves])
    values, _ = sensor.stop_storage()
    return PassData(w, speed_mm_s, values)


@dataclass(frozen=True)
class ScannedPass:
    """One pass as a scan job uses it: the carriage (n, 3) mm where each reading was
    exposed (the calibrated time offset applied), the readings (n,) mm (NaN: none) and their
    stamps (n,) s after the pass's first sample."""

    carriage: np.ndarray
    values: np.ndarray
    stamps: np.ndarray


class SerialScanner:
    """The sensor on its own link (connected; closed by :meth:`close`); positions from the
    commanded pass at the sensor's rate."""

    def __init__(self, machine: Machine, sensor: HeightSensor) -> None:
        self.machine = machine
        self.sensor = sensor

    def run(self, waypoints: np.ndarray, speed_mm_s: float, travel_z: float | None,
            time_offset_s: float) -> ScannedPass:
        data = run_pass(self.machine, self.sensor, waypoints, speed_mm_s, travel_z)
        n = len(data.values)
        carriage = sample_positions(data.waypoints, speed_mm_s, n, self.sensor.rate_hz, time_offset_s)
        return ScannedPass(carriage, data.values, self.sensor.stamps(n))

    def still(self, count: int) -> np.ndarray:
        """``count`` readings (count,) mm (NaN: no value) with the carriage at rest."""
        return still_heights([self.sensor.measure() for _ in range(count)])

    def close(self) -> None:
        self.sensor.close()


class HalScanner:
    """A LinuxCNC machine's sensor sampled with its joints (see the module docstring)."""

    def __init__(self, machine: Any) -> None:
        from hardware.linuxcnc.hal_scan import HalScan

        host = machine.address.host
        if host not in LOCAL_HOSTS:
            raise InvalidInput(f"scanning on a LinuxCNC machine samples its HAL on this host; {host!r} is another",
                               field="machine.port", value=machine.url)
        self.machine = machine
        self.scan = HalScan(hal_prefix=machine.hal_prefix)

    def run(self, waypoints: np.ndarray, speed_mm_s: float, travel_z: float | None,
            time_offset_s: float) -> ScannedPass:
        w = np.asarray(waypoints, dtype=float)
        if travel_z is not None:
            self.machine.move(z=max(travel_z, float(w[0, 2])))
            self.machine.move(x=float(w[0, 0]), y=float(w[0, 1]))
        self.machine.move(x=float(w[0, 0]), y=float(w[0, 1]), z=float(w[0, 2]))
        feed = speed_mm_s * 60.0
        self.scan.start()
        try:
            self.machine.stream(["G90"] + [f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f} F{feed:.1f}" for x, y, z in w[1:]])
        except BaseException:
            with contextlib.suppress(HardwareError):  # the pass's own failure is the one reported
                self.scan.stop()
            raise
        samples = self.scan.stop()
        return ScannedPass(exposure_positions(samples.t, samples.xyz, time_offset_s), samples.reading, samples.t)

    def still(self, count: int) -> np.ndarray:
        """The readings (n,) mm (NaN: no value) of ``count`` servo periods (a dwell) with the
        carriage at rest."""
        self.scan.start()
        try:
            self.machine.stream([f"G4 P{max(count, 1) * self.scan.period_s:.4f}"])
        except BaseException:
            with contextlib.suppress(HardwareError):
                self.scan.stop()
            raise
        return self.scan.stop().reading

    def close(self) -> None:
        """Nothing stays open between passes."""


def sensor_port_needed(machine_port: str) -> bool:
    """False for a ``linuxcnc://`` machine (its controller samples the sensor with its joints:
    no link of its own), True for every other machine (the LK-G sensor on ``sensor_port``)."""
    return PortUrl.parse(machine_port).scheme != "linuxcnc"


def require_sensor_port(machine_id: str, machine_port: str, sensor_port: str | None, field: str) -> None:
    """422 naming ``field`` when the machine reads its sensor over a link of its own and
    ``sensor_port`` is not given (nothing to check on a ``linuxcnc://`` machine)."""
    if not sensor_port and sensor_port_needed(machine_port):
        raise InvalidInput(f"machine {machine_id!r} reads the height sensor over the sensor's own link: give "
                           f"{field} (lkg://NAME for the mock, /dev/ttyUSB1, socket://host:port); only a "
                           "linuxcnc:// machine samples it itself", field=field, value=sensor_port)


def open_scanner(machine: Any, sensor_port: str | None, rate_hz: float) -> SerialScanner | HalScanner:
    """The scan backend for ``machine`` (see the module docstring)."""
    if getattr(machine, "dialect", None) == "linuxcnc":
        return HalScanner(machine)
    if not sensor_port:
        raise InvalidInput("a scan on a serial machine needs the sensor's link", field="params.sensor_port",
                           value=sensor_port)
    sensor = HeightSensor(sensor_port, rate_hz)
    sensor.connect()
    return SerialScanner(machine, sensor)


@dataclass(frozen=True)
class CalibrationSetup:
    """Where the artifacts are (probe frame, mm) and how to scan them.

    pad_centre (3,): the pad's top centre (z measured by the probe); pad_size; sphere_centre
    (3,) and sphere_radius from the probe qualification; nominal_offset (3,) the sensor's
    offset as mounted (known to a few 0.1 mm); range_mm: the head's half range."""

    pad_centre: tuple[float, float, float]
    pad_size: float
    sphere_centre: tuple[float, float, float]
    sphere_radius: float
    nominal_offset: tuple[float, float, float]
    range_mm: float
    travel_z: float
    edge_speed_mm_s: float = 20.0
    edge_passes: int = 4
    still_heights: int = 9
    still_readings: int = 5
    sphere_lines: int = 9
    sphere_speed_mm_s: float = 10.0


def calibrate_sensor(machine: backend.Machine, scanner: SerialScanner | HalScanner,
                     setup: CalibrationSetup) -> tuple[SensorCalibration, dict]:
    """The sensor's calibration and a report of each procedure (module docstring); the
    sensor read by ``scanner`` (:func:`open_scanner`: its own link, or a LinuxCNC
    controller sampling it with the joints)."""
    o = np.asarray(setup.nominal_offset, dtype=float)
    pad = np.asarray(setup.pad_centre, dtype=float)
    # 1. scale and z offset: still over the pad's centre at heights across the range
    machine.move(z=setup.travel_z)
    heights = pad[2] - o[2] - np.linspace(-0.7, 0.7, setup.still_heights) * setup.range_mm
    still = []
    for z in heights:
        machine.move(x=float(pad[0] - o[0]), y=float(pad[1] - o[1]), z=float(z))
        values = scanner.still(setup.still_readings)
        still.append(np.nanmean(values) if np.isfinite(values).any() else np.nan)
    scale, oz, sd_oz = fit_scale_and_z(heights, np.array(still), float(pad[2]))
    # 2. time offset: across the pad's -x edge both ways, the zero 0.4 range below its top
    edge_x = pad[0] - setup.pad_size / 2
    z = pad[2] - oz - 0.4 * setup.range_mm
    y = pad[1] - o[1]
    passes: list[EdgePass] = []
    level = 0.4 * setup.range_mm * scale - 0.5 * min(0.4 * setup.range_mm, 1.0) * scale
    for k in range(2 * setup.edge_passes):
        direction = 1 if k % 2 == 0 else -1
        a, b = edge_x - o[0] - 3.0 * direction, edge_x - o[0] + 3.0 * direction
        data = scanner.run(np.array([[a, y, z], [b, y, z]]), setup.edge_speed_mm_s,
                           setup.travel_z if k == 0 else None, 0.0)
        passes.append(EdgePass(data.carriage[:, 0], data.values, direction, setup.edge_speed_mm_s))
    tau, _, sd_tau = fit_time_offset(passes, level)
    # 3. lateral offset and tilt bias: a serpentine raster over the sphere's cap
    c = np.asarray(setup.sphere_centre, dtype=float)
    r = setup.sphere_radius
    z = c[2] + r - oz - 0.05 * r
    carriage, hs, along = [], [], []
    machine.move(z=setup.travel_z)
    for i, dy in enumerate(np.linspace(-0.35, 0.35, setup.sphere_lines) * r):
        sign = 1 if i % 2 == 0 else -1
        w = np.array([[c[0] - o[0] - sign * 0.45 * r, c[1] - o[1] + dy, z],
                      [c[0] - o[0] + sign * 0.45 * r, c[1] - o[1] + dy, z]])
        data = scanner.run(w, setup.sphere_speed_mm_s, setup.travel_z if i == 0 else None, tau)
        carriage.append(data.carriage)
        hs.append(data.carriage[:, 2] + oz + data.values / scale)
        along.append(np.full(len(data.carriage), float(sign)))
    machine.move(z=setup.travel_z)
    raster, raster_h = np.concatenate(carriage), np.concatenate(hs)
    sphere = with_time_offset_sd(fit_sphere_scan(raster, raster_h, c.tolist(), r, o[:2].tolist()), raster, raster_h,
                                 np.concatenate(along), setup.sphere_speed_mm_s, sd_tau, c.tolist(), r)
    calibration = SensorCalibration((sphere["o_x"], sphere["o_y"], oz), scale, tau, sphere["b"],
                                    {"o_x": sphere["sd_o_x"], "o_y": sphere["sd_o_y"], "o_z": sd_oz,
                                     "time_offset_s": sd_tau, "slope_bias_mm": sphere["sd_b"]})
    report = {"still": {"heights_mm": heights.tolist(), "readings_mm": [float(v) for v in still]},
              "edge_passes": len(passes), "sphere": sphere}
    return calibration, report


def still_heights(values: Sequence[float | None]) -> np.ndarray:
    """Readings as an array (n,) mm with NaN for no value."""
    return np.array([np.nan if v is None else v for v in values], dtype=float)
