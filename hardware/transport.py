"""Opening a port by URL, with ``mock://`` made known to pyserial lazily.

    port = open_port("mock://bench?dialect=grbl", baudrate=115200, timeout=0.01)

``serial.serial_for_url`` imports ``<package>.protocol_<scheme>`` for each package named in
``serial.protocol_handler_packages``.  ``register_mock_scheme()`` only appends the name
``hardware.mock`` to that list (it imports nothing): the mock firmware is imported by
pyserial the first time a ``mock://`` URL is opened, never as a side effect of importing the
link.  ``open_port`` registers it when it is asked for a ``mock://`` URL; importing
``hardware.mock`` registers it too, so any client (printrun, a test's own
``serial.serial_for_url``) that uses the mock package can open ``mock://`` URLs.
"""

from __future__ import annotations

from typing import Any

import serial

from .port_url import PortUrl

MOCK_PACKAGE = "hardware.mock"


def register_mock_scheme() -> None:
    """Let ``serial.serial_for_url`` open ``mock://`` URLs (idempotent, imports nothing)."""
    if MOCK_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(MOCK_PACKAGE)


def open_port(url: str, **options: Any) -> serial.SerialBase:
    """``serial.serial_for_url(url, **options)``, registering ``mock://`` first when the
    URL asks for it.  pyserial's exceptions pass through unchanged."""
    if PortUrl.parse(url).is_mock:
        register_mock_scheme()
    return serial.serial_for_url(url, **options)
