"""Each simulator in namespaces of its own, so that several run on one host at once.

LinuxCNC allows one instance per host: HAL and NML live in System V shared memory under fixed
keys, the launcher keeps ``/tmp/linuxcnc.lock`` and ends other instances' processes *by
name* (``pidof``), and the NML server listens on TCP port 5005.  Started through
``unshare`` with its own IPC, PID and mount namespaces (a private ``/tmp``, the run's
directory bound back at its own path) and an NML file whose server port is free, a
simulator shares none of these with another; HAL commands reach it through
``nsenter --target <pid> --ipc`` (:mod:`hardware.linuxcnc.hal_command`).  Creating
namespaces needs root (CAP_SYS_ADMIN; tried once) and util-linux's ``unshare`` / ``nsenter``; elsewhere
simulators run in the host's namespaces, one at a time (``SimController``'s file lock).
``CONFORMA_SIM_SHARED_NAMESPACES=1`` keeps them there.
"""

from __future__ import annotations

import functools
import os
import re
import shutil
import subprocess
from pathlib import Path

__all__ = ["SYSTEM_NML", "isolation_available", "launch_command", "nsenter_prefix", "write_nml"]

SYSTEM_NML = Path("/usr/share/linuxcnc/linuxcnc.nml")  # the launcher's default NML file
NML_TCP = re.compile(r"\bTCP=\d+")

# run in the new namespaces (bash: $1 the run's directory, $2 the INI file): the run's
# directory opened before /tmp is replaced, then bound back at its own path
_INSIDE = ('exec 3<"$1" && mount -t tmpfs -o mode=1777 conforma-sim /tmp && '
           'case "$1" in /tmp/*) mkdir -p "$1" && mount --no-canonicalize --bind /proc/self/fd/3 "$1";; esac && '
           'exec 3<&- && cd "$1" && exec linuxcnc "$2"')


def isolation_available() -> bool:
    """True when simulators can each run in namespaces of their own (see the module docstring)."""
    if os.environ.get("CONFORMA_SIM_SHARED_NAMESPACES") == "1":
        return False
    return os.geteuid() == 0 and _namespaces_permitted()


@functools.cache
def _namespaces_permitted() -> bool:
    """``unshare`` and ``nsenter`` exist and the kernel lets this process create the namespaces
    (root in a container without CAP_SYS_ADMIN may not): tried once per process."""
    if shutil.which("unshare") is None or shutil.which("nsenter") is None:
        return False
    try:
        done = subprocess.run(["unshare", "--ipc", "--pid", "--mount", "--fork", "--mount-proc", "true"],
                              capture_output=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return done.returncode == 0


def launch_command(workdir: Path, ini: str) -> list[str]:
    """The command that starts ``linuxcnc <ini>`` in ``workdir`` in new IPC, PID and mount
    namespaces (``--kill-child``: the namespace ends with the ``unshare`` process)."""
    return ["unshare", "--ipc", "--pid", "--mount", "--fork", "--mount-proc", "--kill-child",
            "bash", "-c", _INSIDE, "conforma-sim", str(workdir), ini]


def nsenter_prefix(pid: int) -> str:
    """The ``CONFORMA_LINUXCNC_HAL_PREFIX`` that enters the IPC namespace of ``pid`` (the
    ``unshare`` process, which holds the simulator's namespace)."""
    return f"nsenter --target {pid} --ipc"


def write_nml(path: Path, port: int) -> None:
    """LinuxCNC's default NML file with its server's TCP port changed to ``port``."""
    path.write_text(NML_TCP.sub(f"TCP={port}", SYSTEM_NML.read_text()))
