"""Where the controller's HAL is reached from.

``halcmd``, ``halsampler`` and LinuxCNC's Python modules (``hal``, ``linuxcnc``) talk to the
controller through System V shared memory, so they must run in the controller's IPC
namespace.  On a controller host that is the host's own.  Where LinuxCNC runs in other
namespaces (a container, or Conforma's simulators, each in its own so that several run on one
host), ``CONFORMA_LINUXCNC_HAL_PREFIX`` holds the command that enters them, as shell words
(``nsenter --target 4242 --ipc``, ``docker exec linuxcnc``); it is read from the environment
the HAL command runs with.

    subprocess.run(hal_command(["halcmd", "getp", "motion.digital-out-00"], env), env=env)
"""

from __future__ import annotations

import os
import shlex
from collections.abc import Mapping, Sequence

__all__ = ["HAL_PREFIX_VAR", "hal_command"]

HAL_PREFIX_VAR = "CONFORMA_LINUXCNC_HAL_PREFIX"


def hal_command(args: Sequence[str], env: Mapping[str, str] | None = None) -> list[str]:
    """``args`` prefixed by ``HAL_PREFIX_VAR`` of ``env`` (default: this process's
    environment) when it is set."""
    prefix = (os.environ if env is None else env).get(HAL_PREFIX_VAR, "")
    return [*shlex.split(prefix), *args]
