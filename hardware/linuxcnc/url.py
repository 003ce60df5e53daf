"""``linuxcnc://host:port`` machine addresses.

    linuxcnc://127.0.0.1:5007
    linuxcnc://127.0.0.1:5007?programs=/srv/ngc          # where program files are written
    linuxcnc://127.0.0.1:5007?joints=5                   # joints home() waits for

Passwords are never part of a stored URL: they come from the constructor, else from the
environment (``CONFORMA_LINUXCNC_CONNECTPW`` / ``CONFORMA_LINUXCNC_ENABLEPW``), else
linuxcncrsh's defaults (``EMC`` / ``EMCTOO``).  ``programs`` is a directory the controller
can read under the same path (the controller's own disk, or a shared mount): linuxcncrsh
opens programs by path and cannot receive a file.  Default: the machine's ``program_dir``
argument (the service passes its ``CONFORMA_LINUXCNC_PROGRAMS`` setting), else that variable,
else ``<tmp>/conforma-linuxcnc`` (the service's API accepts ``linuxcnc://host:port`` and
``?joints=N`` only, so an API caller cannot pick a directory to write to).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass

from ..errors import InvalidConfig
from ..port_url import PortUrl

__all__ = ["LinuxCNCAddress", "parse_url"]

_OPTIONS = {"programs", "joints"}


@dataclass(frozen=True)
class LinuxCNCAddress:
    """Where linuxcncrsh listens and where program files go."""

    host: str
    port: int
    program_dir: str
    joints: int | None = None


def parse_url(url: str, program_dir: str | None = None) -> LinuxCNCAddress:
    """Parse ``linuxcnc://host:port[?programs=DIR&joints=N]`` (``InvalidConfig`` naming the
    part); ``program_dir`` is the default of ``programs``.  linuxcncrsh reports 6 joints
    whatever the machine has: without ``joints``, homing counts as done when the homed flags
    stay unchanged for half a second."""
    parts = PortUrl.parse(url)
    if parts.scheme != "linuxcnc":
        raise InvalidConfig("expected a linuxcnc://host:port URL", field="port", value=url)
    port = parts.port
    if not parts.host or port is None or not 0 < port < 65536:
        raise InvalidConfig("linuxcnc:// needs host:port", field="port", value=url)
    query = parts.options
    unknown = sorted(set(query) - _OPTIONS)
    if unknown:
        raise InvalidConfig(f"unknown linuxcnc:// option {unknown[0]!r}", field="port", value=url)
    default_dir = (program_dir or os.environ.get("CONFORMA_LINUXCNC_PROGRAMS")
                   or os.path.join(tempfile.gettempdir(), "conforma-linuxcnc"))
    program_dir = query.get("programs", [default_dir])[0]
    if not os.path.isabs(program_dir):
        raise InvalidConfig("programs must be an absolute directory", field="port", value=url)
    joints = query.get("joints", [None])[0]
    if joints is not None and not (joints.isdigit() and 1 <= int(joints) <= 9):
        raise InvalidConfig("joints must be 1..9", field="port", value=url)
    return LinuxCNCAddress(parts.host, port, program_dir, None if joints is None else int(joints))


def passwords(connect_pw: str | None, enable_pw: str | None) -> tuple[str, str]:
    """(connect, enable) passwords: arguments, else environment, else LinuxCNC defaults."""
    connect = connect_pw or os.environ.get("CONFORMA_LINUXCNC_CONNECTPW") or "EMC"
    enable = enable_pw or os.environ.get("CONFORMA_LINUXCNC_ENABLEPW") or "EMCTOO"
    for name, value in (("connect_pw", connect), ("enable_pw", enable)):
        if any(c.isspace() for c in value):
            raise InvalidConfig(f"{name} must not contain whitespace", field=name)
    return connect, enable
