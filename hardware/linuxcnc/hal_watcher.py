"""Watching the simulator's HAL pins from the host: ``hal_watch.py`` (run under the system
Python, which has LinuxCNC's ``hal`` module) prints a pin's value each time it changes, stamped
on the host's monotonic clock; :class:`HalWatch` collects them.  And the error every part of
the simulator raises when LinuxCNC is missing or does not come up."""

from __future__ import annotations

import shutil
import subprocess
import threading
from pathlib import Path

from ..errors import HardwareError
from .hal_command import hal_command


class SimUnavailable(HardwareError):
    """LinuxCNC is not installed, or the simulator did not come up."""

    status = 503


class HalWatch:
    """A running ``hal_watch.py`` (see :meth:`SimController.watch`): ``samples`` is the
    list of ``(t_ns, values)`` it printed, ``t_ns`` on the host's CLOCK_MONOTONIC (the
    clock of ``time.monotonic_ns()``), one entry each time a value changed."""

    SCRIPT = Path(__file__).with_name("hal_watch.py")

    def __init__(self, names: list[str], env: dict[str, str] | None, period_s: float, max_s: float) -> None:
        self.names = list(names)
        self.samples: list[tuple[int, list[float]]] = []
        self._ready = threading.Event()
        python = shutil.which("python3", path="/usr/bin:/bin") or "python3"
        command = hal_command([python, str(self.SCRIPT), repr(period_s), repr(max_s), *self.names], env)
        self._process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(15.0):
            self.close()
            raise SimUnavailable("hal_watch did not start: "
                                 f"{self._process.stderr.read()[:300] if self._process.stderr else ''}",
                                 field="hal_watch")

    def _read(self) -> None:
        assert self._process.stdout is not None
        for line in self._process.stdout:
            if line.startswith("ready"):
                self._ready.set()
                continue
            words = line.split()
            self.samples.append((int(words[0]), [float(w) for w in words[1:]]))
        self._ready.set()

    def first(self, name: str, predicate, after_ns: int = 0) -> int | None:
        """The time (ns) of the first sample at or after ``after_ns`` whose ``name`` value
        satisfies ``predicate`` (None if none)."""
        k = self.names.index(name)
        for t_ns, values in list(self.samples):
            if t_ns >= after_ns and predicate(values[k]):
                return t_ns
        return None

    def ended(self) -> str | None:
        """Why the sampler stopped early (its exit code and the end of its stderr), or None
        while it runs: a test that saw no change says whether it was watching."""
        code = self._process.poll()
        if code is None:
            return None
        err = self._process.stderr.read()[-300:] if self._process.stderr else ""
        return f"hal_watch exited with {code}: {err.strip()}"

    def close(self) -> None:
        """Stop the sampler (SIGTERM to the process this object started) and collect the rest."""
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(5)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait(5)
        self._reader.join(5)

    def __enter__(self) -> HalWatch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
