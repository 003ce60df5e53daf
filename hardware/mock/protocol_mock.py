"""pyserial protocol handler for ``mock://NAME?options`` (see ``hardware.mock.world``).

pyserial's ``serial_for_url`` imports ``<package>.protocol_mock`` for every package in
``serial.protocol_handler_packages`` (``hardware.mock`` registers itself) and uses its
``Serial`` class.  The port behaves like a USB serial device: reads honour ``timeout``;
after a disconnect the bytes the device already sent stay readable, then reads and writes
raise ``serial.SerialException`` — exactly what a real port does.

Time: with ``time_scale == 0`` the firmware runs inside ``write()`` (deterministic, as
fast as possible); otherwise a daemon thread per world drives it in real time.
"""

from __future__ import annotations

import threading
import time
from collections import deque

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from .firmware import FirmwareCore
from .grbl import GrblFirmware
from .marlin import MarlinFirmware
from .world import MockWorld, world_from_url


def _clock(world: MockWorld) -> float:
    return 0.0 if world.time_scale == 0 else time.monotonic()


def _drive(world: MockWorld, firmware: FirmwareCore) -> None:
    """Real-time driver thread: advance the firmware whenever something is due."""
    with world.cond:
        while world.firmware is firmware:
            now = time.monotonic()
            due = firmware.advance(now)
            world.cond.notify_all()
            timeout = None if due is None else max(due - time.monotonic(), 0.0)
            if timeout is None or timeout > 0:
                world.cond.wait(timeout if timeout is not None else 0.5)


FIRMWARES = {"marlin": MarlinFirmware, "grbl": GrblFirmware}  # the mock firmware per dialect


def _firmware_for(world: MockWorld, baudrate: int) -> tuple[FirmwareCore, bool]:
    if world.firmware is not None:
        return world.firmware, False
    kind = FIRMWARES[world.dialect]
    firmware = kind(world, baudrate)
    world.firmware = firmware
    if world.time_scale > 0:
        threading.Thread(target=_drive, args=(world, firmware), daemon=True,
                         name="mock-firmware").start()
    return firmware, True


class Serial(SerialBase):
    """A serial port whose other end is the mock firmware of a ``MockWorld``."""

    is_open: bool  # set by SerialBase.__init__ and by open/close

    def open(self) -> None:
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        world = world_from_url(self.portstr)
        self._world = world
        self._out: deque[tuple[float, bytes]] = deque()
        self._out_bytes = 0
        self._dead = False
        with world.cond:
            firmware, first = _firmware_for(world, self._baudrate or 115200)
            old = firmware.port
            if old is not None and old is not self:
                old.mark_dead()
            firmware.port = self
            self._firmware = firmware
            now = _clock(world)
            firmware.on_attach(now, first)
            firmware.advance(now)
            world.cond.notify_all()
        self.is_open = True

    def from_url(self, url: str) -> str:  # pyserial hook; options are read in open()
        return url

    def _reconfigure_port(self, *args: object, **kwargs: object) -> None:
        """Baud rate etc. are fixed when the firmware is created."""

    def close(self) -> None:
        if not self.is_open:
            return
        with self._world.cond:
            if self._firmware.port is self:
                self._firmware.port = None
            self._dead = True
            self._world.cond.notify_all()
        self.is_open = False

    # called by the firmware with the world lock held
    def deliver(self, ready_at: float, data: bytes) -> None:
        self._out.append((ready_at, data))
        self._out_bytes += len(data)

    def mark_dead(self) -> None:
        self._dead = True

    @property
    def world(self) -> MockWorld:
        return self._world

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        with self._world.cond:
            if self._world.time_scale == 0:
                count = self._out_bytes
            else:
                now = _clock(self._world)
                count = sum(len(d) for t, d in self._out if t <= now)
            if not count and self._dead:
                raise SerialException("device disconnected")
            return count

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        world = self._world
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        buf = bytearray()
        with world.cond:
            while len(buf) < size:
                now = _clock(world)
                while self._out and self._out[0][0] <= now and len(buf) < size:
                    ready, data = self._out.popleft()
                    take = size - len(buf)
                    if len(data) > take:
                        self._out.appendleft((ready, data[take:]))
                        data = data[:take]
                    buf += data
                    self._out_bytes -= len(data)
                if len(buf) >= size:
                    break
                if self._dead and not self._out:
                    if buf:
                        break
                    raise SerialException("device disconnected")
                wait = None
                if deadline is not None:
                    wait = deadline - time.monotonic()
                    if wait <= 0:
                        break
                if self._out and world.time_scale > 0:
                    gap = max(self._out[0][0] - time.monotonic(), 0.0005)
                    wait = gap if wait is None else min(wait, gap)
                world.cond.wait(wait)
        return bytes(buf)

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(data)
        world = self._world
        with world.cond:
            if self._dead:
                raise SerialException("device disconnected")
            firmware = self._firmware
            now = _clock(world)
            firmware.receive(data, now)
            if world.time_scale == 0:
                firmware.advance(now)
            world.cond.notify_all()
        return len(data)

    def reset_input_buffer(self) -> None:
        with self._world.cond:
            self._out.clear()
            self._out_bytes = 0

    def reset_output_buffer(self) -> None:
        """Nothing is buffered on the host side."""

    def cancel_read(self) -> None:
        with self._world.cond:
            self._world.cond.notify_all()
