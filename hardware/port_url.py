"""A port as one typed value, parsed once: what a machine, a sensor or a print head is
reached by.

    port = PortUrl.parse("linuxcnc://127.0.0.1:5007?joints=5")
    port.scheme, port.host, port.port, port.options     # 'linuxcnc', '127.0.0.1', 5007, {'joints': ['5']}
    PortUrl.parse("/dev/ttyUSB0").scheme                 # '' (a device path)
    PortUrl.parse("mock://bench?dialect=grbl").name      # 'bench'

Schemes in use: ``mock://NAME`` (the mock firmware), ``linuxcnc://host:port`` (linuxcncrsh),
``socket://host:port`` (a serial bridge), ``loop://`` (pyserial's loopback), ``lkg://NAME``
and ``head://NAME`` (the mock sensor and print head); a device path (``/dev/...``, ``COM3``)
has none.  Parsing never fails: whether a port is acceptable is its user's decision (the
service's ``physical_port``, ``hardware.linuxcnc.url.parse_url``), which reads these fields.
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

__all__ = ["PortUrl", "TCP_SCHEMES"]

#: schemes whose port is a TCP controller at ``host:port``
TCP_SCHEMES = ("socket", "linuxcnc")


@dataclass(frozen=True)
class PortUrl:
    """A parsed port URL (``urllib.parse.urlsplit`` read once)."""

    text: str  # the URL as given
    scheme: str  # lower-case; "" for a device path
    netloc: str  # as given (a mock device's name keeps its case)
    host: str  # lower-case host name, "" when there is none
    port: int | None  # TCP port number; None when absent or not a number
    path: str
    query: str  # the raw query string (each device parses its own options strictly)

    @classmethod
    def parse(cls, text: str) -> PortUrl:
        """The fields of ``text`` (never raises)."""
        parts = urlsplit(text)
        try:
            number = parts.port
        except ValueError:  # not a number, or out of 0..65535
            number = None
        return cls(text, parts.scheme, parts.netloc, parts.hostname or "", number, parts.path, parts.query)

    @property
    def name(self) -> str:
        """A mock device's name: ``mock://NAME`` -> ``NAME`` (``default`` when empty)."""
        return (self.netloc + self.path).strip("/") or "default"

    @property
    def options(self) -> dict[str, list[str]]:
        """The query's options, each with every value given (blank values kept)."""
        return parse_qs(self.query, keep_blank_values=True)

    @property
    def is_mock(self) -> bool:
        """A ``mock://`` port (the mock firmware)."""
        return self.scheme == "mock"

    @property
    def is_tcp(self) -> bool:
        """A TCP controller (``socket://`` or ``linuxcnc://``)."""
        return self.scheme in TCP_SCHEMES

    def __str__(self) -> str:
        return self.text
