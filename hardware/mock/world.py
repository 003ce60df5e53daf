"""The mock printer's world: configuration, fault plan, transcript, deposition log, registry.

A ``MockWorld`` outlives connections: the firmware state (position, line number, planner,
transcript) lives here, so closing and reopening ``mock://NAME`` talks to the same
"machine" again, like re-plugging a USB cable.

URL form (every option optional)::

    mock://NAME?dialect=marlin&time_scale=0&seed=1&probe_noise_mm=0.01
        &checksum_rate=0.01&drop_ok_rate=0&duplicate_ok_rate=0&resend_rate=0
        &garbage_rate=0&busy_rate=0&slow_rate=0&line_number_rate=0
        &disconnect_at_line=500&reset_at_line=900
        &advanced_ok=1&latency_ms=1&rx_buffer=128&command_buffer=4&planner_blocks=16&segment_buffer=6
        &homing=0&homing_fails=0&fresh_eeprom=0&boot_s=0.5&line_numbers=0   (grbl)
        &stylus_radius_mm=0.5&pretravel_mm=0.015&pretravel_sd_mm=0.002
        &pretravel_lobing_mm=0.003&drift_mm_per_min=0.001&touchoff_sd_mm=0.001
        &tool1=12.3,-4.1,-8.7,0.8&pad=100,10,5,20&sphere=120,10,12,25.4   (probe physics)

The probe physics options (see ``hardware.mock.physics`` and ``artifacts``) all default to
today's ideal probe: a point that reads the surface exactly, no pre-travel, no drift, no
tools beyond T0 and no reference artifacts.

``NAME`` selects a world registered with ``register_world``; an unknown name creates (and
registers) a fresh world from the options.  Options given for an existing world update
it (the dialect must match).  Malformed options raise ``InvalidConfig``.

Fault semantics (per received command line, probabilities 0..1, deterministic by seed):
``checksum_rate`` damages one character on the wire; ``drop_ok_rate``/``duplicate_ok_rate``
lose / repeat the ``ok``; ``resend_rate`` emits a spurious ``Resend:`` for a line already
accepted (Marlin); ``garbage_rate`` puts a line of random bytes before a reply;
``busy_rate`` emits a burst of ``echo:busy: processing`` (Marlin); ``slow_rate`` makes the
command take 2.5 s (times ``time_scale``); ``line_number_rate`` damages a numbered line's
``N`` word on the wire (Marlin answers "Line Number is not Last Line Number+1").  ``disconnect_at_line=N`` drops the
link right after the firmware executed its N-th recorded command (before its ``ok``): Marlin keeps
running and keeps its line number; grbl resets (Arduino boards reset on re-enumeration)
and loses its receive buffer.  ``reset_at_line=N`` restarts the controller instead of
executing its N-th command (it is not executed; queued commands are lost; grbl's
bootloader then ignores input for 1 s, or until the port is reopened with time_scale 0).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, cast
from urllib.parse import parse_qsl

from ..dialects import DEFAULT_DIALECT, DIALECTS, dialect
from ..errors import InvalidConfig
from ..port_url import PortUrl
from ..protocol import CommandDigest, CommandHasher
from .artifacts import (
    PHYSICS_LIMITS,
    MockPad,
    MockSphere,
    MockTool,
    check_physics_value,
    merge_tools,
    parse_artifact_option,
    tool_number,
)
from .timeline import MotionTimeline

if TYPE_CHECKING:
    import trimesh

    from .firmware import FirmwareCore

#: Host queries that do not change the machine; the transcript leaves them out so the
#: executed digest compares directly with the program's ``commands_sha256``.
HOST_QUERIES = frozenset({"M105", "M110", "M114", "M115", "M119", "M503", "$I", "$$", "$#",
                          "$G", "$N", "$X", "S000", "M154"})


@dataclass
class FaultConfig:
    """Fault injection plan (see module docstring)."""

    checksum_rate: float = 0.0
    drop_ok_rate: float = 0.0
    duplicate_ok_rate: float = 0.0
    resend_rate: float = 0.0
    garbage_rate: float = 0.0
    busy_rate: float = 0.0
    slow_rate: float = 0.0
    line_number_rate: float = 0.0
    disconnect_at_line: int | None = None
    reset_at_line: int | None = None
    seed: int = 0

    @classmethod
    def uniform(cls, rate: float, seed: int = 0) -> FaultConfig:
        """Every probabilistic fault class at ``rate``."""
        return cls(rate, rate, rate, rate, rate, rate, rate, seed=seed)


@dataclass(frozen=True)
class TruePlacement:
    """The as-made part's TRUE rigid offset on the mock's bed (what registration must find;
    hardware never imports app, so this is not app.geometry's Placement): rotation ``rz_deg``
    about the Z axis through the origin, then translation (dx, dy, dz) in mm."""

    dx: float = 0.0
    dy: float = 0.0
    dz: float = 0.0
    rz_deg: float = 0.0


@dataclass(frozen=True)
class DepositedMove:
    """One move made with the dispenser on: start/end (x, y, z) in mm, feed in mm/min."""

    start: tuple[float, float, float]
    end: tuple[float, float, float]
    feed_mm_min: float


class Transcript:
    """Commands the firmware executed, in order (host queries in ``HOST_QUERIES`` left out).

    ``executed_count``/``executed_sha256`` follow API.md's ``commands_sha256``; ``commands``
    keeps the texts when ``keep`` is true (tests), or stays empty (long soaks)."""

    def __init__(self, keep: bool = True) -> None:
        self.keep = keep
        self.commands: list[str] = []
        self._hasher = CommandHasher()

    def record(self, command: str) -> None:
        """Add one executed (normalised) command."""
        self._hasher.update(command)
        if self.keep:
            self.commands.append(command)

    def truncate(self, count: int) -> None:
        """Keep only the first ``count`` commands (a controller reset lost the rest before
        they moved).  Needs ``keep``; without the texts the digest cannot be rebuilt."""
        if count >= self.executed_count:
            return
        if not self.keep:
            raise RuntimeError("cannot truncate a transcript that keeps no commands")
        kept = self.commands[:count]
        self.reset()
        for command in kept:
            self.record(command)

    def reset(self) -> None:
        """Forget everything recorded so far."""
        self.commands = []
        self._hasher = CommandHasher()

    @property
    def executed_count(self) -> int:
        return self._hasher.count

    @property
    def executed_sha256(self) -> str:
        return self._hasher.digest().sha256

    def digest(self) -> CommandDigest:
        return self._hasher.digest()


@dataclass
class MockStats:
    """Counters the firmware keeps: planner underruns (the planner ran dry between moves
    while the host was streaming), receive-buffer overflows, faults injected per class."""

    underruns: int = 0
    starved_s: float = 0.0
    rx_overflows: int = 0
    blocks: int = 0
    lines_received: int = 0
    faults: dict[str, int] = field(default_factory=dict)
    #: the machine clock: modelled seconds of motion (length / feed, probing moves up to
    #: the trigger) and dwell since the world was made, whatever ``time_scale`` is
    machine_time_s: float = 0.0
    #: probing moves that drove a nozzle (T>=1) into the part (it does not trigger there)
    collisions: int = 0
    touches: int = 0
    #: emergency stops the firmware has taken (grbl soft reset, Marlin kill) and the executed
    #: command count at the last one: what ran before the stop reached the firmware
    stops: int = 0
    executed_at_stop: int = -1


@dataclass
class MockWorld:
    """Everything the mock printer is: part, placement, noise, dialect, timing, faults."""

    true_part: trimesh.Trimesh | None = None  # trimesh.Trimesh of the as-made part, or None (flat bed)
    placement: TruePlacement = field(default_factory=TruePlacement)
    probe_noise_mm: float = 0.0
    # dust (x, y, dz) mm: the first touch within DUST_RADIUS_MM of (x, y) reads dz high
    # (a chip or dust under the stylus, gone after that touch: a touch again reads the part)
    probe_dust: tuple[tuple[float, float, float], ...] = ()
    dust_gone: set[int] = field(default_factory=set)
    seed: int = 0
    dialect: str = DEFAULT_DIALECT
    time_scale: float = 0.0
    faults: FaultConfig = field(default_factory=FaultConfig)
    # the dispenser's on/off commands (a profile's); None: the dialect's (``Dialect.dispense``:
    # Marlin's fan ``M106 S255``/``M107``, grbl's flood coolant ``M8``/``M9``)
    dispense_on: str | None = None
    dispense_off: str | None = None
    advanced_ok: bool = True
    latency_ms: float = 1.0
    rx_buffer: int = 128
    command_buffer: int = 4
    planner_blocks: int = 16
    # grbl's stepper segment buffer (SEGMENT_BUFFER_SIZE, 6 on the 328P; one ring slot stays
    # free) of SEGMENT_S segments: a planner block is released once all its segments are
    # prepared, before they move.  None: the dialect's (grbl 6; Marlin 0, its stepper runs the
    # block in place in the planner ring)
    segment_buffer: int | None = None
    bed_z: float = 0.0
    probe_z_min: float = -20.0
    rapid_feed_mm_min: float = 6000.0
    keep_transcript: bool = True
    # grbl: homing enabled ($22, boots in Alarm), a failing homing cycle, a fresh EEPROM
    # (boot error:7), bootloader time before the banner (model s), line-number reports (Ln:)
    homing: bool = False
    homing_fails: bool = False
    fresh_eeprom: bool = False
    boot_s: float = 0.5
    # a grbl board's EEPROM settings and whether the next boot finds it fresh (kept across reconnects)
    grbl_eeprom: dict[int, str] | None = field(default=None, init=False, repr=False, compare=False)
    grbl_eeprom_fresh: bool = field(default=False, init=False, repr=False, compare=False)
    line_numbers: bool = False
    # Marlin: REALTIME_REPORTING_COMMANDS (needs EMERGENCY_PARSER; off in Marlin's default
    # configuration): "S000" answered on arrival with the real stepper position
    realtime_reports: bool = False
    # probe physics (hardware.mock.physics): ball stylus of T0, pre-travel (mean, scatter,
    # 3-lobed direction dependence), Z drift, nozzle touch-off scatter, tools, artifacts
    stylus_radius_mm: float = 0.0
    pretravel_mm: float = 0.0
    pretravel_sd_mm: float = 0.0
    pretravel_lobing_mm: float = 0.0
    drift_mm_per_min: float = 0.0
    touchoff_sd_mm: float = 0.0
    tools: tuple[MockTool, ...] = ()      # T1..Tn
    pad: MockPad | None = None
    sphere: MockSphere | None = None

    def __post_init__(self) -> None:
        if self.dialect not in DIALECTS:
            raise InvalidConfig(f"unknown dialect {self.dialect!r}", field="dialect",
                                value=str(self.dialect)[:40])
        for name in PHYSICS_LIMITS:
            setattr(self, name, check_physics_value(name, getattr(self, name), name))
        self.tools = tuple(self.tools)
        if len(self.tools) > 8 or not all(isinstance(t, MockTool) for t in self.tools):
            raise InvalidConfig("tools must be at most 8 MockTool values", field="tools",
                                value=len(self.tools))
        if self.pad is not None and not isinstance(self.pad, MockPad):
            raise InvalidConfig("pad must be a MockPad", field="pad", value=str(self.pad)[:40])
        if self.sphere is not None and not isinstance(self.sphere, MockSphere):
            raise InvalidConfig("sphere must be a MockSphere", field="sphere",
                                value=str(self.sphere)[:40])
        self.lock = threading.RLock()
        self.cond = threading.Condition(self.lock)
        self.transcript = Transcript(self.keep_transcript)
        self.deposition_log: list[DepositedMove] = []
        self.stats = MockStats()
        self.firmware: FirmwareCore | None = None  # created by the first connection (hardware.mock.firmware)
        # the carriage's path on the machine clock, kept while a device shares the position
        # stream (hardware.mock.timeline; the mock height sensor sets it)
        self.timeline: MotionTimeline | None = None
        # what lies on the bed besides the part and the artifacts (the mock printhead's jetted
        # material: objects with ``top(xy (n, 2)) -> (height above bed_z (n,), on (n,))``), and
        # the process outputs the program switched (``M42 P<pin> S<v>``: key "P<pin>"), each
        # change told to the listeners as (key, value, machine-clock s)
        self.surfaces: list[Any] = []
        self.outputs: dict[str, float] = {}
        self.output_listeners: list[Callable[[str, float, float], None]] = []

    def set_output(self, key: str, value: float) -> None:
        """The firmware switched output ``key`` to ``value`` (now on the machine clock)."""
        self.outputs[key] = float(value)
        for listener in list(self.output_listeners):
            listener(key, float(value), self.stats.machine_time_s)

    @property
    def segments(self) -> int:
        """Stepper segment buffer size (see ``segment_buffer``; 0: none)."""
        if self.segment_buffer is not None:
            return self.segment_buffer
        return dialect(self.dialect).stepper_queue

    @property
    def dispense_commands(self) -> tuple[str, str]:
        """The dispenser's (on, off) commands: the world's, else its dialect's."""
        default = dialect(self.dialect).dispense
        return (self.dispense_on or default[0], self.dispense_off or default[1])

    def dispenser_switch(self, command: str, head: str, params: dict[str, float]) -> bool | None:
        """True (on) or False (off) when the normalised ``command`` (first word ``head``,
        words ``params``) switches the dispenser's output, else None.  A command matches
        its on/off line exactly or by first word; the on word with an explicit ``S0`` sets
        the output's duty to 0, which is off (Marlin ``M106 S0``, grbl ``M3 S0``, ``M42 ... S0``)."""
        on, off = self.dispense_commands
        if command == on or head == on.split(" ")[0]:
            return command == on or params.get("S") != 0.0
        if command == off or head == off.split(" ")[0]:
            return False
        return None

    @property
    def position(self) -> tuple[float, float, float]:
        """Planned tool position (mm); (0, 0, 0) before the first connection."""
        fw = self.firmware
        if fw is None:
            return (0.0, 0.0, 0.0)
        x, y, z = fw.position
        return x, y, z

    @property
    def active_tool(self) -> int:
        """The selected tool: 0 = the touch probe, k >= 1 = ``tools[k - 1]``."""
        fw = self.firmware
        return int(getattr(fw, "active_tool", 0)) if fw is not None else 0

    def reset_controller(self) -> tuple[float, float, float] | None:
        """The controller restarts now (a reset button, a brown-out, a watchdog): what was
        planned and not yet moved is lost, the position is the power-on origin and the
        banner goes to the host (grbl's bootloader then ignores input for about a second).
        Returns where the tool really was (mm), the truth a test compares with."""
        with self.cond:
            firmware = self.firmware
            if firmware is None:
                return None
            now = 0.0 if self.time_scale == 0 else time.monotonic()
            x, y, z = (float(v) for v in firmware.machine_position(now))
            firmware.hard_reset(now)
            self.cond.notify_all()
            return x, y, z

    def drift_mm(self) -> float:
        """Z drift now (mm): actual tool Z = commanded Z + this (machine clock based)."""
        return self.drift_mm_per_min * self.stats.machine_time_s / 60.0

    @property
    def executed_count(self) -> int:
        return self.transcript.executed_count

    @property
    def executed_sha256(self) -> str:
        return self.transcript.executed_sha256


_REGISTRY: dict[str, MockWorld] = {}
_REGISTRY_LOCK = threading.Lock()

_FAULT_KEYS = {f.name: f.type for f in fields(FaultConfig)}
_WORLD_KEYS = {"dialect": str, "time_scale": float, "seed": int, "probe_noise_mm": float,
               "advanced_ok": bool, "latency_ms": float, "rx_buffer": int,
               "command_buffer": int, "planner_blocks": int, "segment_buffer": int, "bed_z": float,
               "probe_z_min": float, "dispense_on": str, "dispense_off": str,
               "keep_transcript": bool, "homing": bool, "homing_fails": bool,
               "fresh_eeprom": bool, "boot_s": float, "line_numbers": bool,
               "realtime_reports": bool}


def register_world(name: str, world: MockWorld) -> MockWorld:
    """Make ``world`` reachable as ``mock://name`` (replacing any previous one)."""
    if not name or "/" in name or "?" in name:
        raise InvalidConfig(f"invalid mock world name {name!r}", field="name", value=name)
    with _REGISTRY_LOCK:
        _REGISTRY[name] = world
    return world


def get_world(name: str) -> MockWorld:
    """The world registered under ``name`` (``KeyError`` when there is none)."""
    with _REGISTRY_LOCK:
        return _REGISTRY[name]


def unregister_world(name: str) -> None:
    """Forget ``name`` (no error when absent)."""
    with _REGISTRY_LOCK:
        _REGISTRY.pop(name, None)


def _convert(key: str, text: str, kind: object) -> Any:
    try:
        if kind in (bool, "bool"):
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError(text)
        if kind in (int, "int", "int | None"):
            return int(text)
        if kind in (float, "float"):
            value = float(text)
            if value != value or value in (float("inf"), float("-inf")):
                raise ValueError(text)
            return value
        return text
    except ValueError:
        raise InvalidConfig(f"mock option {key}={text!r} is not a valid {getattr(kind, '__name__', kind)}",
                            field=f"port.{key}", value=text[:40]) from None


def parse_mock_options(query: str) -> dict[str, object]:
    """Typed options from a ``mock://`` query string; ``InvalidConfig`` when malformed."""
    options: dict[str, object] = {}
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise InvalidConfig(f"malformed mock options {query!r}", field="port",
                            value=query[:80]) from None
    for key, text in pairs:
        artifact = parse_artifact_option(key, text)
        if artifact is not None:
            options[key] = artifact
            continue
        if key in PHYSICS_LIMITS:
            value = _convert(key, text, float)
            options[key] = check_physics_value(key, value, f"port.{key}")
            continue
        if key in _FAULT_KEYS:
            value = _convert(key, text, _FAULT_KEYS[key])
        elif key in _WORLD_KEYS:
            value = _convert(key, text, _WORLD_KEYS[key])
        else:
            raise InvalidConfig(f"unknown mock option {key!r}", field=f"port.{key}", value=text[:40])
        if key.endswith("_rate") and not 0.0 <= value <= 1.0:
            raise InvalidConfig(f"mock option {key} must be within 0..1", field=f"port.{key}",
                                value=value)
        if key in ("time_scale", "latency_ms", "probe_noise_mm", "boot_s") and value < 0:
            raise InvalidConfig(f"mock option {key} must be >= 0", field=f"port.{key}", value=value)
        if key in ("rx_buffer", "command_buffer", "planner_blocks") and value < 1 \
                or key == "segment_buffer" and value < 0:
            raise InvalidConfig(f"mock option {key} must be >= 1", field=f"port.{key}", value=value)
        if key == "dialect" and value not in DIALECTS:
            raise InvalidConfig(f"unknown dialect {value!r}; expected one of {', '.join(DIALECTS)}",
                                field="dialect", value=str(value)[:40])
        options[key] = value
    return options


def world_from_url(url: str) -> MockWorld:
    """Resolve ``mock://NAME?options`` to a (possibly new, then registered) world."""
    parts = PortUrl.parse(url)
    if parts.scheme != "mock":
        raise InvalidConfig(f"not a mock URL: {url!r}", field="port", value=url[:80])
    name = parts.name
    options = parse_mock_options(parts.query)
    with _REGISTRY_LOCK:
        world = _REGISTRY.get(name)
        if world is None:
            world = MockWorld(dialect=str(options.get("dialect", DEFAULT_DIALECT)))
            _REGISTRY[name] = world
    if "dialect" in options and options["dialect"] != world.dialect:
        raise InvalidConfig(f"mock world {name!r} speaks {world.dialect}, not {options['dialect']}",
                            field="dialect", value=options["dialect"])
    # tool<k>: a MockTool
    tools = {n: cast(MockTool, v) for k, v in options.items() if (n := tool_number(k)) is not None}
    if tools:
        world.tools = merge_tools(world.tools, tools)
    for key, value in options.items():
        if tool_number(key) is not None:
            continue
        if key in _FAULT_KEYS:
            setattr(world.faults, key, value)
            if key == "seed":  # one seed for the fault plan and the physics' noise and scatter
                world.seed = int(value)  # type: ignore[call-overload]
        elif key == "keep_transcript":
            world.transcript.keep = bool(value)
        else:
            setattr(world, key, value)
    return world
