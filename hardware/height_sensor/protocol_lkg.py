"""pyserial protocol handler for ``lkg://NAME?options``: a port whose other end is the mock
LK-G controller (:mod:`hardware.height_sensor.mock`).

The controller answers each CR-terminated command inside ``write()`` (the mock machine's
clock, not the wall clock, times its samples); ``read()`` returns what it answered
(:class:`hardware.mock.line_port.LineDevicePort`).  An unplugged controller answers nothing.
"""

from __future__ import annotations

from ..mock.line_port import LineDevicePort
from .mock import MockHeightSensor, sensor_from_url


class Serial(LineDevicePort):
    """A serial port to a mock LK-G controller."""

    terminator = b"\r"

    def _open_device(self, url: str) -> MockHeightSensor:
        return sensor_from_url(url)

    def _answer(self, line: str) -> str | None:
        return self.sensor.handle(line)

    @property
    def sensor(self) -> MockHeightSensor:
        device = self._device
        assert isinstance(device, MockHeightSensor)
        return device
