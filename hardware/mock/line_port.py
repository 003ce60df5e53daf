"""A pyserial port whose other end is a mock device answering one line at a time.

The device answers each terminated command inside ``write()`` (a mock's time is the mock
machine's clock, not the wall clock); ``read()`` returns what it answered.  Subclasses
name the device (:meth:`LineDevicePort._open_device`, from the port's URL), the
terminator and how a line is answered (:meth:`LineDevicePort._answer`; None: no reply).
A device that cannot take a command (it went away) raises ``serial.SerialException``
from ``write()``, as a port whose device was unplugged.
"""

from __future__ import annotations

import threading

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from ..errors import InvalidConfig


class LineDevicePort(SerialBase):
    """A serial port to a mock line-protocol device (see the module docstring)."""

    terminator = b"\n"
    is_open: bool  # set by SerialBase.__init__ and by open/close

    def _open_device(self, url: str) -> object:
        """The device the port's URL names (InvalidConfig if there is none)."""
        raise NotImplementedError

    def _answer(self, line: str) -> str | None:
        """The device's reply to one command line (without its terminator)."""
        raise NotImplementedError

    def open(self) -> None:
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        try:
            self._device = self._open_device(self.portstr)
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
            while (end := self._rx.find(self.terminator)) >= 0:
                line = self._rx[:end].decode("ascii", "replace")
                del self._rx[:end + len(self.terminator)]
                try:
                    reply = self._answer(line)
                except InvalidConfig as exc:
                    raise SerialException(str(exc)) from exc
                if reply is not None:
                    self._out += reply.encode("ascii") + self.terminator
            self._cond.notify_all()
        return len(data)

    def reset_input_buffer(self) -> None:
        with self._cond:
            self._out.clear()

    def reset_output_buffer(self) -> None:
        """Nothing is buffered on the host side."""
