"""pyserial protocol handler for ``head://NAME?options``: a port whose other end is the mock
head driver (:mod:`hardware.printhead.mock`).

The driver answers each LF-terminated command inside ``write()`` (its drops are timed by the
mock machine's clock, not the wall clock); ``read()`` returns what it answered
(:class:`hardware.mock.line_port.LineDevicePort`).  A command the driver cannot take (no
such machine) closes nothing: it raises ``serial.SerialException`` from ``write()``, as a
port whose device went away.
"""

from __future__ import annotations

from ..mock.line_port import LineDevicePort
from .mock import MockPrintHead, head_from_url


class Serial(LineDevicePort):
    """A serial port to a mock head driver."""

    terminator = b"\n"

    def _open_device(self, url: str) -> MockPrintHead:
        return head_from_url(url)

    def _answer(self, line: str) -> str | None:
        return self.head.handle(line)

    @property
    def head(self) -> MockPrintHead:
        device = self._device
        assert isinstance(device, MockPrintHead)
        return device
