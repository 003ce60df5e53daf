"""The host side of a height sensor: an LK-G controller over its own serial link.

    sensor = HeightSensor("lkg://bench", rate_hz=2000)   # or "/dev/ttyUSB1", "socket://host:port"
    sensor.connect()
    z = sensor.measure()                      # one value (mm) or None (no value)
    sensor.start_storage()                    # AQ, AS: sample k is stamped k / rate_hz
    ...                                       # move the machine
    values, valid = sensor.stop_storage()     # AP, AO,1: (n,) mm, (n,) bool

One command at a time, each answered before the next (the LK-G's rule).  A refused command
(``ER,<cmd>,<code>``) raises :class:`SensorRejected` naming the command and the reason; a
silent or garbled link raises :class:`hardware.errors.LinkError` /
:class:`hardware.errors.ProtocolError`.  The sampling cycle is the controller's setting:
the host is told it (``rate_hz``).
"""

from __future__ import annotations

import time

import numpy as np
import serial

from ..errors import FirmwareError, InvalidConfig, LinkError, ProtocolError
from . import lkg

SCHEME_PACKAGE = "hardware.height_sensor"


class SensorRejected(FirmwareError):
    """The controller answered ``ER``: the command, its code and what it means."""


def register_scheme() -> None:
    """Let ``serial.serial_for_url`` open ``lkg://`` URLs (idempotent)."""
    if SCHEME_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(SCHEME_PACKAGE)


class HeightSensor:
    """An LK-G controller on ``url`` (see module docstring); ``rate_hz``: its sampling rate."""

    def __init__(self, url: str, rate_hz: float, baudrate: int = 115200, timeout_s: float = 2.0) -> None:
        if not rate_hz > 0:
            raise InvalidConfig("rate_hz must be > 0", field="rate_hz", value=rate_hz)
        self.url = url
        self.rate_hz = float(rate_hz)
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.port: serial.SerialBase | None = None
        self.bytes_received = 0

    def connect(self) -> None:
        """Open the link and put the controller in general (measuring) mode."""
        if self.url.startswith("lkg://"):
            register_scheme()
        try:
            self.port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.timeout_s)
        except (serial.SerialException, ValueError) as exc:
            raise LinkError(f"cannot open the sensor at {self.url!r}: {exc}", field="sensor_port",
                            value=self.url) from exc
        self.command("R0")

    def close(self) -> None:
        if self.port is not None:
            self.port.close()
            self.port = None

    def __enter__(self) -> HeightSensor:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def command(self, text: str) -> list[str]:
        """Send one command; its response's fields after the echoed header."""
        port = self.port
        if port is None:
            raise LinkError("the sensor is not connected", field="sensor_port", value=self.url)
        try:
            port.write(text.encode("ascii") + lkg.CR)
            line = self._read_line(port)
        except serial.SerialException as exc:
            raise LinkError(f"sensor link failed: {exc}", field="sensor_port", value=self.url) from exc
        header, fields = lkg.split_response(line)
        if header == "ER":
            raise SensorRejected(f"the sensor refused {text!r}: {lkg.error_text(fields)}", command=text,
                                 code=int(fields[1]) if len(fields) > 1 and fields[1].isdigit() else None)
        if header != text.split(",")[0].strip().upper():
            raise ProtocolError(f"the sensor answered {line[:40]!r} to {text!r}", field="sensor_port",
                                value=line[:40])
        return fields

    def _read_line(self, port: serial.SerialBase) -> str:
        buf = bytearray()
        deadline = time.monotonic() + self.timeout_s
        while not buf.endswith(lkg.CR):
            chunk = port.read(max(1, port.in_waiting))
            if chunk:
                buf += chunk
            elif time.monotonic() > deadline:
                raise LinkError("the sensor did not answer", field="sensor_port", value=self.url)
        self.bytes_received += len(buf)
        return buf[:-1].decode("ascii", "replace")

    def measure(self) -> float | None:
        """OUT1 now (mm), None when the sensor has no value (alarm or over range)."""
        fields = self.command("M1")
        try:
            return lkg.parse_value(fields[0])
        except (IndexError, lkg.LkgFormatError) as exc:
            raise ProtocolError(f"bad M1 response {fields!r}", field="sensor_port") from exc

    def start_storage(self) -> None:
        """Clear the storage and start it (sample 0 is stamped now)."""
        self.command("AQ")
        self.command("AS")

    def stop_storage(self) -> tuple[np.ndarray, np.ndarray]:
        """Stop storing; the stored OUT1 values (n,) mm (NaN where none) and validity (n,)."""
        self.command("AP")
        fields = self.command("AO,1")
        try:
            values, valid = lkg.parse_values(fields)
        except lkg.LkgFormatError as exc:
            raise ProtocolError(f"bad stored value: {exc}", field="sensor_port") from exc
        return np.asarray(values, dtype=float), np.asarray(valid, dtype=bool)

    def stamps(self, count: int) -> np.ndarray:
        """Sample times (count,) s after the storage start."""
        out: np.ndarray = np.arange(count) / self.rate_hz
        return out
