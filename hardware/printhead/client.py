"""The host side of a piezo print-head driver (:mod:`hardware.printhead.hdp`).

    head = PrintHead("head://bench")          # or "/dev/ttyUSB2", "socket://host:port"
    head.connect()                            # ID: nozzles, rows, dpi, row gap
    head.load(bits, y0_mm=12.0, first_nozzle=0)  # (rows, count) bool bitmap of one swath
    head.arm()                                # fire it as the nozzles cross its rows
    ...                                       # move the carriage along the swath
    head.status().rows_done; head.disarm()    # drops fired

One command at a time, each answered before the next.  A refused command (``ER``) raises
:class:`HeadRejected` naming the command and the reason; a silent or garbled link raises
:class:`hardware.errors.LinkError` / :class:`hardware.errors.ProtocolError`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import serial

from ..errors import FirmwareError, InvalidConfig, LinkError, ProtocolError
from . import hdp

SCHEME_PACKAGE = "hardware.printhead"
MM_PER_INCH = 25.4


class HeadRejected(FirmwareError):
    """The driver answered ``ER``: the command, its code and what it means."""


@dataclass(frozen=True)
class HeadInfo:
    """What ``ID`` says: nozzle ``n`` at ``n * pitch_mm`` along +x in row ``n % rows``."""

    model: str
    nozzles: int
    rows: int
    dpi: float
    row_gap_um: float

    @property
    def pitch_mm(self) -> float:
        return MM_PER_INCH / self.dpi


@dataclass(frozen=True)
class HeadStatus:
    """``ST``: armed, bitmap rows every nozzle row crossed, the swath's rows, drops fired."""

    armed: bool
    rows_done: int
    rows: int
    fired: int


def register_scheme() -> None:
    """Let ``serial.serial_for_url`` open ``head://`` URLs (idempotent)."""
    if SCHEME_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(SCHEME_PACKAGE)


class PrintHead:
    """A head driver on ``url`` (see module docstring)."""

    def __init__(self, url: str, baudrate: int = 115200, timeout_s: float = 5.0) -> None:
        if not url:
            raise InvalidConfig("the head's port is empty", field="head_port", value=url)
        self.url = url
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.port: serial.SerialBase | None = None
        self.info: HeadInfo | None = None

    def connect(self) -> HeadInfo:
        """Open the link and identify the head."""
        if self.url.startswith("head://"):
            register_scheme()
        try:
            self.port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.timeout_s)
        except (serial.SerialException, ValueError) as exc:
            raise LinkError(f"cannot open the head at {self.url!r}: {exc}", field="head_port",
                            value=self.url) from exc
        fields = self.command("ID")
        try:
            self.info = HeadInfo(fields[0], int(fields[1]), int(fields[2]), float(fields[3]), float(fields[4]))
        except (IndexError, ValueError) as exc:
            raise ProtocolError(f"bad ID response {fields!r}", field="head_port") from exc
        return self.info

    def close(self) -> None:
        if self.port is not None:
            self.port.close()
            self.port = None

    def command(self, text: str) -> list[str]:
        """Send one command; its response's fields after the echoed header."""
        port = self.port
        if port is None:
            raise LinkError("the head is not connected", field="head_port", value=self.url)
        try:
            port.write(text.encode("ascii") + hdp.LF)
            line = self._read_line(port)
        except serial.SerialException as exc:
            raise LinkError(f"head link failed: {exc}", field="head_port", value=self.url) from exc
        parts = line.strip().split(",")
        header, fields = parts[0], parts[1:]
        command = text.split(",", 1)[0].strip().upper()
        if header == "ER":
            raise HeadRejected(f"the head refused {command}: {hdp.error_text(fields)}", command=command,
                               code=int(fields[1]) if len(fields) > 1 and fields[1].isdigit() else None)
        if header != command:
            raise ProtocolError(f"the head answered {line[:40]!r} to {command!r}", field="head_port",
                                value=line[:40])
        return fields

    def _read_line(self, port: serial.SerialBase) -> str:
        buf = bytearray()
        deadline = time.monotonic() + self.timeout_s
        while not buf.endswith(hdp.LF):
            chunk = port.read(max(1, port.in_waiting))
            if chunk:
                buf += chunk
            elif time.monotonic() > deadline:
                raise LinkError("the head did not answer", field="head_port", value=self.url)
        return buf[:-1].decode("ascii", "replace")

    def load(self, bits: np.ndarray, y0_mm: float, first_nozzle: int) -> int:
        """Load one swath: ``bits`` (rows, count) bool, row i at scan position y0 + i * pitch,
        column c on nozzle first_nozzle + c.  Returns the drops the head counted."""
        b = np.asarray(bits, dtype=bool)
        if b.ndim != 2 or b.shape[0] < 1 or b.shape[1] < 1:
            raise InvalidConfig("a swath bitmap is (rows, nozzles) with both >= 1", field="bits",
                                value=list(b.shape))
        text, crc = hdp.pack_bitmap(b)
        fields = self.command(f"LOAD,{y0_mm:.5f},{b.shape[0]},{first_nozzle},{b.shape[1]},{crc},{text}")
        drops = int(fields[0])
        if drops != int(b.sum()):
            raise ProtocolError(f"the head counted {drops} drops in a swath of {int(b.sum())}", field="head_port",
                                value=drops)
        return drops

    def arm(self) -> None:
        self.command("ARM")

    def status(self) -> HeadStatus:
        fields = self.command("ST")
        try:
            return HeadStatus(fields[0] == "1", int(fields[1]), int(fields[2]), int(fields[3]))
        except (IndexError, ValueError) as exc:
            raise ProtocolError(f"bad ST response {fields!r}", field="head_port") from exc

    def disarm(self) -> int:
        """Disarm and forget the swath; the drops it fired."""
        return int(self.command("DA")[0])
