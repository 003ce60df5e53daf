"""Mock firmware core shared by the Marlin and grbl personalities.

A discrete-event model of a controller, driven by ``advance(now)``:

* the wire: bytes written by the host arrive one by one at the baud rate (10 bits per
  byte) plus a link latency; they land in an RX buffer of ``rx_buffer`` bytes (overflowing
  bytes are lost, as on a UART without flow control);
* the command path (dialect specific, see ``marlin.py``/``grbl.py``) takes complete lines
  out of RX, checks them and executes them one by one;
* commands run as generators that yield what they wait for: a time, a free planner block,
  or an empty planner (``M400``); moves become planner blocks of constant speed
  (``length / feed``); the "stepper" retires blocks at their end time;
* replies leave through the same kind of wire (baud + latency) into the port's buffer.

Times are real seconds, every modelled duration times ``time_scale`` (1: real time, 0: all instantaneous).
"""

from __future__ import annotations

import math
import random
import re
from collections import deque
from collections.abc import Callable, Generator
from typing import Any

import numpy as np

from ..protocol import normalize_command
from .physics import ProbePhysics, Touch
from .surface import PlacedSurface
from .world import HOST_QUERIES, DepositedMove, MockTool, MockWorld

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
KEEPALIVE_S = 2.0
SLOW_S = 2.5
UNDERRUN_WINDOW_S = 0.2
SEGMENT_S = 0.01  # grbl's step segment: DT_SEGMENT, 1 / ACCELERATION_TICKS_PER_SECOND (100) s

Wait = tuple  # ("until", t) | ("slot",) | ("drain",)


def split_words(command: str) -> tuple[str, dict[str, float]]:
    """``"G1 X1 Y2"`` -> ``("G1", {"X": 1.0, "Y": 2.0})``; the head is upper-cased."""
    words = _WORD.findall(command)
    if not words or not command.lstrip()[:1].isalpha():
        return command.strip().upper(), {}
    letter, number = words[0]
    head = f"{letter.upper()}{number.lstrip('+')}"
    if "." in head:
        head = head.rstrip("0").rstrip(".") if head.split(".")[1].strip("0") == "" else head
    params = {}
    for letter, number in words[1:]:
        params[letter.upper()] = float(number)
    return head, params


class FirmwareCore:
    """State and timing common to both dialects (see module docstring)."""

    dialect = "base"
    hard_reset: Callable[[float], None]  # MockWorld.reset_controller: grbl's mock defines it, Marlin's does not
    # disconnect_at_line fires when the N-th command is recorded (Marlin); grbl's receive path fires it itself
    DISCONNECT_WHEN_RECORDED = False

    def __init__(self, world: MockWorld, baudrate: int) -> None:
        self.world = world
        self.scale = float(world.time_scale)
        self.byte_s = 10.0 / float(baudrate) * self.scale
        self.latency_s = world.latency_ms / 1000.0 * self.scale
        self.faults = world.faults
        self.rng = random.Random(world.faults.seed)
        self.noise = np.random.default_rng(world.seed)
        self.surface = PlacedSurface(world.true_part, world.placement, world.bed_z)
        self.physics = ProbePhysics(world, self.surface, self.noise)
        self.port: Any = None
        self.wire: deque[tuple[float, bytes]] = deque()
        self.wire_free_at = 0.0
        self.out_free_at = 0.0
        self.fired: set[str] = set()
        self.now = 0.0
        self.cold_start()

    # ------------------------------------------------------------------ state
    def cold_start(self) -> None:
        """Power-on state: empty buffers, position unknown (0, 0, 0), not homed."""
        self.rx = bytearray()
        self.queue: deque[tuple[int | None, str]] = deque()
        self.current: Generator[Wait, None, None] | None = None
        self.waiting: Wait | None = None
        self.keepalive_at = float("inf")
        self.auto_report_s = 0.0  # Marlin M154: position auto-report interval (0: off)
        self.auto_report_at = float("inf")
        self.planner: deque[float] = deque()  # end times of planned blocks
        # per planned block: (transcript index of its command, N word, start time, start, end)
        self.blocks: deque[tuple[int, int | None, float, tuple, tuple]] = deque()
        self.held_since: float | None = None  # feed hold: the planner is frozen
        self.motion_end = 0.0
        self.position = [0.0, 0.0, 0.0]
        self.absolute = True
        self.inches = False
        self.line_n: int | None = None  # N word of the command being planned
        self.feed = 1000.0
        self.dispensing = False
        self.homed = False
        self.halted = False
        self.active_tool = 0  # T0: the touch probe; k >= 1: world.tools[k - 1]

    # ------------------------------------------------------------------ I/O
    def receive(self, data: bytes, now: float) -> None:
        """Bytes written by the host at ``now``; real-time bytes are handled at once."""
        data = self.realtime(data, now)
        if not data:
            return
        if self.scale == 0.0:
            self.wire.append((now, data))
        else:
            start = max(now + self.latency_s, self.wire_free_at)
            self.wire_free_at = start + len(data) * self.byte_s
            self.wire.append((self.wire_free_at, data))

    def realtime(self, data: bytes, now: float) -> bytes:
        """Dialect hook: consume real-time bytes, return the rest."""
        return data

    def emit(self, line: str, now: float) -> None:
        """Send one reply line (subject to the garbage fault)."""
        port = self.port
        if port is None:
            return
        if self.faults.garbage_rate and self.rng.random() < self.faults.garbage_rate:
            self.count_fault("garbage")
            noise = b"\xfe" + bytes(self.rng.choice(b"\x00\x07\x1b\xfe\xff!#%&o k")
                                     for _ in range(6))
            self._send(port, noise + b"\n", now)
        self._send(port, line.encode("utf-8") + b"\n", now)

    def _send(self, port: Any, data: bytes, now: float) -> None:
        if self.scale == 0.0:
            port.deliver(0.0, data)
            return
        start = max(now + self.latency_s, self.out_free_at)
        self.out_free_at = start + len(data) * self.byte_s
        port.deliver(self.out_free_at, data)

    def count_fault(self, name: str) -> None:
        faults = self.world.stats.faults
        faults[name] = faults.get(name, 0) + 1

    def chance(self, rate: float, name: str) -> bool:
        """True with probability ``rate`` (and counts the injected fault)."""
        if rate and self.rng.random() < rate:
            self.count_fault(name)
            return True
        return False

    # ------------------------------------------------------------------ event loop
    def advance(self, now: float) -> float | None:
        """Run everything due at ``now``; return the next time something happens by
        itself (None: nothing until the host sends more)."""
        self.now = now
        while True:
            progressed = False
            while self.wire and self.wire[0][0] <= now:
                _, data = self.wire.popleft()
                room = self.world.rx_buffer - len(self.rx)
                if len(data) > room:
                    self.world.stats.rx_overflows += 1
                    data = data[:max(room, 0)]
                self.rx += data
                progressed = True
            while self.planner and self.planner[0] <= now and self.held_since is None:
                self.planner.popleft()
                self.blocks.popleft()
            if self.current is not None:
                if self._ready(self.waiting, now):
                    progressed = True
                    self._step(now)
                elif self.keepalive_at <= now:
                    self.keepalive(now)
                    self.keepalive_at = now + KEEPALIVE_S * self.scale
            if not self.halted:
                progressed = self.pump(now) or progressed
            if self.auto_report_at <= now and not self.halted:
                self.auto_report(now)
                self.auto_report_at = now + self.auto_report_s * self.scale
            if not progressed:
                return self._next_time()

    def _ready(self, waiting: Wait | None, now: float) -> bool:
        if waiting is None:
            return True
        if waiting[0] == "until":
            return waiting[1] <= now
        if waiting[0] == "slot":
            return self.planner_room(now)
        return not self.planner  # "drain"

    def _next_time(self) -> float | None:
        times = [self.auto_report_at] if self.auto_report_at != float("inf") else []
        if self.wire:
            times.append(self.wire[0][0])
        if self.current is not None:
            if self.waiting and self.waiting[0] == "until":
                times.append(self.waiting[1])
            elif self.planner and self.held_since is None:
                times.append(self.planner[0])
                if self.waiting and self.waiting[0] == "slot" and self.world.segments:
                    times.append(self.now + SEGMENT_S * self.scale)  # a block may leave at a segment
            if self.keepalive_at != float("inf"):
                times.append(self.keepalive_at)
        return min(times) if times else None

    def start(self, line_no: int | None, command: str, now: float) -> None:
        """Begin executing ``command`` (already checked)."""
        self.current = self.run(line_no, command, now)
        self.waiting = None
        self.keepalive_at = now + KEEPALIVE_S * self.scale if self.scale else float("inf")
        self._step(now)

    def _step(self, now: float) -> None:
        assert self.current is not None, "a command was started"  # callers set it just before
        try:
            self.waiting = self.current.send(None)
        except StopIteration:
            self.current = None
            self.waiting = None
            self.keepalive_at = float("inf")

    def record(self, command: str, now: float) -> None:
        """Put an executed command into the transcript; fire ``disconnect_at_line``."""
        head = command.split(" ", 1)[0].upper()
        if head in HOST_QUERIES:
            return
        transcript = self.world.transcript
        transcript.record(command)
        if self.DISCONNECT_WHEN_RECORDED and self.faults.disconnect_at_line == transcript.executed_count \
                and "disconnect" not in self.fired:
            self.fired.add("disconnect")
            self.disconnect(now)

    def due(self, fault: str, command: str) -> bool:
        """True (once) when ``command`` would be the recorded command number
        ``<fault>_at_line`` names (``fault``: "reset" or "disconnect")."""
        target = getattr(self.faults, f"{fault}_at_line")
        if target is None or fault in self.fired:
            return False
        if command.split(" ", 1)[0].upper() in HOST_QUERIES:
            return False
        if self.world.transcript.executed_count + 1 >= target:
            self.fired.add(fault)
            return True
        return False

    def disconnect(self, now: float) -> None:
        """The USB link drops: the port dies (what it already received stays readable)."""
        port, self.port = self.port, None
        self.wire.clear()
        if port is not None:
            port.mark_dead()

    # ------------------------------------------------------------------ motion
    def plan_move(self, target: list[float], feed_mm_min: float, now: float
                  ) -> Generator[Wait, None, None]:
        """Wait for a free planner block, then plan a straight move to ``target``."""
        if not self.planner_room(self.clock()):
            yield ("slot",)
        start = tuple(self.position)
        length = math.dist(target, start)
        drift_before = self.world.drift_mm()
        if length > 0:
            self.advance_clock(length / max(feed_mm_min, 1e-9) * 60.0, (start, tuple(target)))
        if length > 0 and (self.dispensing or self.active_tool):
            tip_start, tip_end = self.tip_path(start, tuple(target), drift_before)
            if self.dispensing:
                self.world.deposition_log.append(DepositedMove(tip_start, tip_end, feed_mm_min))
            if self.tool_spec() is not None:
                self.physics.nozzle_move(tip_start, tip_end)
        self.position = list(target)
        if length == 0.0:
            return
        duration = length / max(feed_mm_min, 1e-9) * 60.0 * self.scale
        self.world.stats.blocks += 1
        if self.scale:
            now = self.clock()
            if not self.planner and self.motion_end < now:
                gap = now - self.motion_end
                if gap < UNDERRUN_WINDOW_S and self.motion_end > 0:
                    self.world.stats.underruns += 1
                    self.world.stats.starved_s += gap
            begin = max(now, self.motion_end)
            self.motion_end = begin + duration
            self.planner.append(self.motion_end)
            self.blocks.append((self.world.transcript.executed_count, self.line_n, begin, start,
                                tuple(target)))

    def advance_clock(self, seconds: float, path: tuple | None = None) -> None:
        """Machine clock += ``seconds`` (modelled); a ``world.timeline`` gets ``path`` (start, end)."""
        self.world.stats.machine_time_s += max(float(seconds), 0.0)
        if self.world.timeline is not None:  # a device shares the position stream (default: standing)
            self.world.timeline.advance(self.world.stats.machine_time_s, seconds, path or (self.position,) * 2)

    def tip_path(self, start: tuple, end: tuple, drift_before: float) -> tuple[tuple, tuple]:
        """Where the active tool's tip really went: carriage + tool offset + Z drift (the
        drift at the start and at the end of the move); T0 without drift: the carriage."""
        spec = self.tool_spec()
        drift_after = self.world.drift_mm()
        if spec is None and drift_before == 0.0 and drift_after == 0.0:
            return start, end
        offset = spec.offset_mm if spec is not None else (0.0, 0.0, 0.0)
        a = tuple(float(v + o) for v, o in zip(start, offset))
        b = tuple(float(v + o) for v, o in zip(end, offset))
        return (a[0], a[1], a[2] + drift_before), (b[0], b[1], b[2] + drift_after)

    def tool_spec(self) -> MockTool | None:
        """The active nozzle's ``MockTool`` (None for T0 or a tool the world lacks)."""
        tools = self.world.tools
        return tools[self.active_tool - 1] if 1 <= self.active_tool <= len(tools) else None

    def touch(self, start: tuple, target: tuple, feed_mm_min: float) -> Touch:
        """A probing move with the active tool (see ``hardware.mock.physics``); advances
        the machine clock by the travel up to the trigger (or the whole move)."""
        tool = self.active_tool
        if tool != 0 and self.tool_spec() is None:  # a tool the mock does not know: touches nothing
            length = math.dist(start, target)
            self.advance_clock(length / max(feed_mm_min, 1e-9) * 60.0)
            return Touch("miss", tuple(target), length, None)
        result = self.physics.touch(start, target, tool)
        self.advance_clock(result.travel_mm / max(feed_mm_min, 1e-9) * 60.0, (start, result.reading))
        return result

    def hold(self, now: float) -> None:
        """Feed hold: planned motion stops where it is (deceleration not modelled)."""
        if self.held_since is None:
            self.held_since = now

    def cycle_start(self, now: float) -> None:
        """Resume after a feed hold: every planned block moves later by the hold time."""
        if self.held_since is None:
            return
        shift = max(now - self.held_since, 0.0)
        self.held_since = None
        self.planner = deque(t + shift for t in self.planner)
        self.blocks = deque((i, n, t + shift, a, b) for i, n, t, a, b in self.blocks)
        self.motion_end += shift

    def _running(self, now: float) -> int | None:
        """Index (in ``blocks``) of the block moving at ``now`` (the driver may not have
        retired the finished ones yet), or None when every planned block has ended."""
        t = self.held_since if self.held_since is not None else now
        for i, end_at in enumerate(self.planner):
            if end_at > t:
                return i
        return None

    def machine_position(self, now: float) -> tuple[float, float, float]:
        """Where the tool really is (mm) at ``now``: inside the block moving then, not the
        planned end (also between two advances of the event loop)."""
        i = self._running(now) if self.blocks else None
        if i is None:
            return self.position[0], self.position[1], self.position[2]
        _, _, begin, start, end = self.blocks[i]
        t = self.held_since if self.held_since is not None else now
        span = self.planner[i] - begin
        f = 1.0 if span <= 0 else min(max((t - begin) / span, 0.0), 1.0)
        return tuple(a + (b - a) * f for a, b in zip(start, end))

    def moving(self) -> bool:
        """True while planned motion remains (also while held)."""
        return bool(self.planner)

    def done_count(self, now: float | None = None) -> int:
        """Recorded commands whose motion is complete (at ``now``; default: the event
        loop's time): the ones before the running block."""
        i = self._running(self.now if now is None else now) if self.blocks else None
        return self.blocks[i][0] if i is not None else self.world.transcript.executed_count

    def lose_planned_motion(self, now: float | None = None) -> None:
        """A reset or power loss: planned but unexecuted commands never ran, so the
        transcript ends at the last command whose motion completed (when it keeps texts)."""
        if self.world.transcript.keep:
            self.world.transcript.truncate(self.done_count(now))

    def planner_room(self, now: float) -> bool:
        """True when the planner has a free block at ``now``: blocks whose segments all sit
        in the stepper's segment buffer (``world.segments``) no longer take one."""
        return len(self.planner) - self.segmented(now) < self.block_capacity()

    def segmented(self, now: float) -> int:
        """Planned blocks (from the oldest) the planner has released at ``now``: ended, or
        every segment prepared in the stepper's segment buffer (grbl ``st_prep_buffer``:
        it keeps ``segments - 1`` segments of ``SEGMENT_S`` ready, the executing one
        included; a block's last segment ends with the block, so a short block is one)."""
        slots = self.world.segments - 1
        if slots <= 0 or not self.planner:
            return 0
        t = self.held_since if self.held_since is not None else now
        step = SEGMENT_S * self.scale
        released, used = 0, 0
        for (_, _, begin, _, _), end in zip(self.blocks, self.planner):
            if end <= t:
                released += 1  # moved already (the event loop retires it next)
                continue
            first = begin if begin >= t else begin + math.floor((t - begin) / step) * step
            used += max(1, math.ceil((end - first) / step - 1e-9)) if step > 0 else 1
            if used > slots:
                break
            released += 1
        return released

    def block_capacity(self) -> int:
        """Planner blocks that can hold motion at once (grbl keeps one ring slot free)."""
        return self.world.planner_blocks

    def clock(self) -> float:
        """Current time (generators resume later than they started)."""
        return self.now

    def target_of(self, params: dict[str, float]) -> list[float]:
        """Move target from X/Y/Z words (absolute or relative mode)."""
        target = list(self.position)
        unit = 25.4 if self.inches else 1.0
        for i, axis in enumerate("XYZ"):
            if axis in params:
                value = params[axis] * unit
                target[i] = value if self.absolute else target[i] + value
        return target

    def dwell(self, seconds: float, now: float) -> Generator[Wait, None, None]:
        """Wait ``seconds`` of model time (nothing when time_scale is 0)."""
        if seconds > 0 and self.scale:
            yield ("until", self.clock() + seconds * self.scale)

    def select_tool(self, number: int) -> bool:
        """``T<number>``: True when the tool exists (0, or 1..len(world.tools))."""
        if 0 <= number <= len(self.world.tools):
            self.active_tool = number
            return True
        return False

    def run_shared(self, command: str, head: str, params: dict[str, float]
                   ) -> Generator[Wait, None, bool]:
        """Run a command both dialects treat alike (the world's dispense on/off commands,
        G20, G21, G90, G91, G92); False, doing nothing, for any other command."""
        switch = self.world.dispenser_switch(command, head, params)
        if switch is not None:
            yield ("drain",)
            self.dispensing = switch
        elif head in ("G20", "G21"):
            self.inches = head == "G20"
        elif head == "G90":
            self.absolute = True
        elif head == "G91":
            self.absolute = False
        elif head == "G92":
            yield ("drain",)
            for i, axis in enumerate("XYZ"):
                if axis in params:
                    self.position[i] = params[axis]
        else:
            return False
        return True

    # ------------------------------------------------------------------ dialect hooks
    def pump(self, now: float) -> bool:
        raise NotImplementedError

    def run(self, line_no: int | None, command: str, now: float) -> Generator[Wait, None, None]:
        raise NotImplementedError

    def keepalive(self, now: float) -> None:
        """Dialect hook: what to print while a command runs long."""

    def auto_report(self, now: float) -> None:
        """Dialect hook: a periodic report (Marlin ``M154``)."""

    def banner(self, now: float) -> None:
        raise NotImplementedError

    def on_attach(self, now: float, first: bool) -> None:
        """A port opened: boot on the first open, reset when the dialect resets on open."""
        if first:
            self.banner(now)

    def take_line(self) -> bytes | None:
        """Remove one complete line (without terminator) from RX, or None."""
        index = self.rx.find(b"\n")
        if index < 0:
            return None
        line = bytes(self.rx[:index])
        del self.rx[:index + 1]
        return line.rstrip(b"\r")


def normalized(text: str) -> str | None:
    """Normalised command text (comments and blanks removed)."""
    return normalize_command(text)
