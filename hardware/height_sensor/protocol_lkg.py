"""pyserial protocol handler for ``lkg://NAME?options``: a port whose other end is the mock
LK-G controller (:mod:`hardware.height_sensor.mock`).

The controller answers each CR-terminated command inside ``write()`` (the mock machine's
clock, not the wall clock, times its samples); ``read()`` returns what it answered.
"""

from __future__ import annotations

import threading

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from ..errors import InvalidConfig
from .mock import MockHeightSensor, sensor_from_url


class Serial(SerialBase):
    """A serial port to a mock LK-G controller."""

    def open(self) -> None:
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        try:
            self._sensor: MockHeightSensor = sensor_from_url(self.portstr)
        except InvalidConfig as exc:
            raise SerialException(str(exc)) from exc
        self._rx = bytearray()
        self._out = bytearray()
        self._cond = threading.Condition()
        self.is_open = True

    def from_url(self, url: str) -> str:  # pyserial hook; options are read in open()
        return url

    def _reconfigure_port(self, *args: object, **kwargs: object) -> None:
        """Nothing to configure on the mock."""

    def close(self) -> None:
        self.is_open = False

    @property
    def sensor(self) -> MockHeightSensor:
        return self._sensor

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        with self._cond:
            return len(self._out)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        with self._cond:
            if not self._out and self._timeout:
                self._cond.wait(self._timeout)
            data = bytes(self._out[:size])
            del self._out[:size]
            return data

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        with self._cond:
            self._rx += bytes(data)
            while (end := self._rx.find(b"\r")) >= 0:
                line = self._rx[:end].decode("ascii", "replace")
                del self._rx[:end + 1]
                reply = self._sensor.handle(line)
                if reply is not None:
                    self._out += reply.encode("ascii") + b"\r"
            self._cond.notify_all()
        return len(data)

    def reset_input_buffer(self) -> None:
        with self._cond:
            self._out.clear()

    def reset_output_buffer(self) -> None:
        """Nothing is buffered on the host side."""
