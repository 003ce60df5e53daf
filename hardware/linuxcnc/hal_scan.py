"""Sample a LinuxCNC controller's height sensor with its joints, in the servo thread.

The controller's HAL has a ``sampler`` whose channels are ``x y z exposed reading valid clock
exposed`` and a signal that switches the sensor and the sampler on.  ``clock`` counts servo
periods; ``exposed`` is the count at which the value in ``reading`` was measured, sampled
twice, before and after ``reading`` and ``valid``.  On Conforma's simulator
(``sim/sensor.hal``) the sensor's HAL component stamps each value with the count it read the
joints at, however late the scheduler ran it; it runs beside the servo thread, so it sets
``exposed`` to -1 before it writes a value and to the count after: a row whose two reads of
``exposed`` differ (or are -1) was sampled while a value was being written and is dropped (a
sequence lock: under load the sampler can be held between two channels for a whole write, and
the row would pair one value with another's count).  On a machine whose sensor is an analog
input sampled in the servo thread, both ``exposed`` channels are the clock itself and the
sensor's own latency is the calibrated time offset.  :class:`HalScan` runs ``halsampler``
(LinuxCNC's reader of the sampler's FIFO) on this host while a scan pass runs:

    scan = HalScan()                # halcmd / halsampler of the controller on this host
    scan.start()                    # halsampler attached, then ``sets conforma:sensor-on 1``
    machine.stream(pass_lines)      # the carriage moves; every servo period is one row
    samples = scan.stop()           # ``sets ... 0``, the FIFO drained, halsampler ended
    samples.t, samples.xyz, samples.reading   # (n,) s, (n, 3) mm, (n,) mm (NaN: no value)

Each row's value is paired with the joints of the row it was exposed in: ``t`` and ``xyz``
are the exposure's (a gap in the sampler's sequence numbers means the FIFO overran, which is
an error).  A value exposed before the first row (the sensor not yet awake) and repeats of
one exposure (the sensor had nothing new) are dropped; ``lag_s`` is how late each value
reached the sampler.  The HAL must be on this host (``halcmd`` reaches the
controller's shared memory; in another namespace through ``CONFORMA_LINUXCNC_HAL_PREFIX``,
:mod:`hardware.linuxcnc.hal_command`): a ``linuxcnc://`` machine elsewhere cannot be scanned
this way.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import threading
import time
from dataclasses import dataclass

import numpy as np

from ..errors import HardwareError
from .hal_command import HAL_PREFIX_VAR, hal_command

__all__ = ["HalScan", "HalScanError", "HalSamples", "servo_period_s"]

SENSOR_ON = "conforma:sensor-on"
CHANNELS = 8  # x y z exposed reading valid clock exposed


class HalScanError(HardwareError):
    """halsampler / halcmd failed, or samples were lost."""

    status = 503


@dataclass(frozen=True)
class HalSamples:
    """One sampled pass: t (n,) s of each exposure from the first row, xyz (n, 3) mm (the
    joints' feedback at the exposure), reading (n,) mm (NaN where the sensor had no value),
    lag_s (n,) s from the exposure to the row that sampled the value, period_s the servo period."""

    t: np.ndarray
    xyz: np.ndarray
    reading: np.ndarray
    lag_s: np.ndarray
    period_s: float


def _halcmd(args: list[str], env: dict[str, str] | None, timeout_s: float = 10.0) -> str:
    done = subprocess.run(hal_command(["halcmd", *args], env), capture_output=True, text=True, timeout=timeout_s,
                          env=env)
    if done.returncode != 0:
        raise HalScanError(f"halcmd {' '.join(args)} failed: {done.stderr.strip()[:200]}", field="halcmd",
                           value=args[0])
    return done.stdout


def servo_period_s(env: dict[str, str] | None = None) -> float:
    """The servo thread's period (s), from ``halcmd show thread servo-thread``."""
    for line in _halcmd(["show", "thread", "servo-thread"], env).splitlines():
        words = line.split()
        if "servo-thread" in words and words[0].isdigit():
            return int(words[0]) * 1e-9
    raise HalScanError("no servo-thread in the controller's HAL", field="halcmd", value="servo-thread")


def parse_rows(lines: list[str], period_s: float) -> HalSamples:
    """``halsampler -t`` lines (``seq x y z exposed reading valid clock exposed``) -> samples
    (see the module docstring); a gap in the sequence (FIFO overrun) raises ``HalScanError``."""
    lines = [line for line in lines if line.strip()]
    while lines and lines[0].strip() == "overrun":  # halsampler counts from 0: the sampler's
        lines = lines[1:]                             # numbers went on since its last session
    overruns = sum(line.strip() == "overrun" for line in lines)
    if overruns:
        raise HalScanError(f"the sampler's FIFO overran {overruns} times (samples lost)", field="sampler",
                           value=overruns)
    rows = np.array([[float(w) for w in line.split()] for line in lines], dtype=float)
    if len(rows) == 0 or rows.shape[1] != CHANNELS + 1:
        raise HalScanError(f"the sampler gave no rows of {CHANNELS} channels", field="sampler", value=len(rows))
    seq = rows[:, 0]
    if np.any(np.diff(seq) != 1):
        raise HalScanError("samples were lost (a gap in the sampler's sequence)", field="sampler",
                           value=int(np.count_nonzero(np.diff(seq) != 1)))
    whole = np.flatnonzero((rows[:, 4] == rows[:, 8]) & (rows[:, 8] >= 0))  # not sampled mid-write
    at = np.rint(rows[whole, 8] - rows[0, 7]).astype(int)  # the row each value was exposed in
    keep = (at >= 0) & (at <= whole)
    keep[1:] &= at[1:] != at[:-1]  # a repeat: nothing new since the previous whole row
    exposed, sampled = at[keep], rows[whole[keep]]
    reading = np.where(sampled[:, 6] > 0.5, sampled[:, 5], np.nan)
    return HalSamples(exposed * period_s, rows[exposed, 1:4], reading, (sampled[:, 7] - sampled[:, 8]) * period_s,
                      period_s)


class HalScan:
    """One sampling session at a time (see the module docstring); ``env``: the controller's
    environment for ``halcmd`` (the simulator's, :attr:`SimController.hal_env`); ``hal_prefix``:
    the command that enters the controller's namespace (:mod:`hardware.linuxcnc.hal_command`)."""

    def __init__(self, env: dict[str, str] | None = None, signal: str = SENSOR_ON, channel: int = 0,
                 hal_prefix: str | None = None) -> None:
        if shutil.which("halsampler") is None or shutil.which("halcmd") is None:
            raise HalScanError("halcmd / halsampler are not on this host (LinuxCNC not installed)",
                               field="halsampler")
        if hal_prefix is not None:  # else the environment's HAL_PREFIX_VAR, if any
            env = {**(os.environ if env is None else env), HAL_PREFIX_VAR: hal_prefix}
        self.env = env
        self.signal = signal
        self.channel = channel
        self.period_s = servo_period_s(env)
        self._process: subprocess.Popen | None = None
        self._lines: list[str] = []
        self._reader: threading.Thread | None = None

    def start(self) -> None:
        """Attach halsampler to the FIFO, then switch the sensor and the sampler on."""
        if self._process is not None:
            raise HalScanError("a sampling session is already running", field="sampler")
        _halcmd(["sets", self.signal, "0"], self.env)
        self._lines = []
        command = ["halsampler", "-t", "-c", str(self.channel)]
        if shutil.which("stdbuf"):
            command = ["stdbuf", "-oL", *command]  # rows reach us as they are read, not at exit
        self._process = subprocess.Popen(hal_command(command, self.env), stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, text=True, env=self.env)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        try:
            _halcmd(["sets", self.signal, "1"], self.env)
        except HalScanError:
            self._end()
            raise

    def _read(self) -> None:
        assert self._process is not None and self._process.stdout is not None
        for line in self._process.stdout:
            self._lines.append(line)

    def stop(self, drain_timeout_s: float = 10.0) -> HalSamples:
        """Switch off, wait until halsampler emptied the FIFO and its rows arrived, end it."""
        if self._process is None:
            raise HalScanError("no sampling session is running", field="sampler")
        try:
            _halcmd(["sets", self.signal, "0"], self.env)
            deadline = time.monotonic() + drain_timeout_s
            count, still_since = -1, time.monotonic()
            while time.monotonic() < deadline:
                depth = int(_halcmd(["getp", f"sampler.{self.channel}.curr-depth"], self.env).split()[0])
                if len(self._lines) != count:
                    count, still_since = len(self._lines), time.monotonic()
                elif depth == 0 and time.monotonic() - still_since > 0.1:
                    break
                time.sleep(0.02)
            else:
                raise HalScanError("halsampler did not drain the sampler's FIFO in time", field="halsampler")
        finally:
            self._end()
        return parse_rows(self._lines, self.period_s)

    def _end(self) -> None:
        process, self._process = self._process, None
        if process is None:
            return
        if process.poll() is None:
            process.terminate()
            try:
                process.wait(5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(5)
        if self._reader is not None:
            self._reader.join(5)
