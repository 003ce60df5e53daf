"""Which process owns the machines of a data directory.

The process that runs the ``machine`` queue owns the serial ports and the mock worlds;
two such processes on one data directory would claim each other's machine jobs (and a
mock machine's world lives in one process only).  ``conforma serve`` takes this lock for
its lifetime; ``conforma demo`` takes it when free, else it hands its jobs to the server
that holds it.  An advisory ``flock`` is released by the kernel when its holder dies.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

LOCK_NAME = "machine-owner.lock"


class MachineOwnerLock:
    """A non-blocking exclusive lock on ``data_dir/machine-owner.lock``."""

    def __init__(self, data_dir: Path) -> None:
        data_dir.mkdir(parents=True, exist_ok=True)
        self.path = data_dir / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> bool:
        """Take the lock; False when another live process holds it."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return True

    def holder_pid(self) -> int | None:
        """The pid the holder wrote (None if unknown)."""
        try:
            return int(self.path.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return None

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None
