"""The mock head driver: :mod:`hardware.printhead.hdp` over a ``head://NAME?options`` pyserial
URL, coupled to a mock machine's world like the mock height sensor.

The head rides on the carriage of the mock machine ``machine=<world name>`` (default NAME).
Armed, it fires its swath from the carriage's position stream on the machine clock
(:class:`hardware.mock.timeline.MotionTimeline`): bitmap row ``i`` of nozzle ``n`` fires when
that nozzle's row crosses ``y0 + i * pitch`` (a real driver's encoder trigger), once, at the
nozzle's x at that instant; so a pause, a feed hold or a pass in either direction fires each
drop exactly once.  Firing is settled whenever the host talks to the head and when the UV
lamp goes off.  A drop's volume is ``volume_pl * volume_bias * (1 + spread * N_n) * (1 +
drop_noise * N)`` (N_n: the nozzle's fixed draw, the first ``nozzles`` normal draws of the
seeded generator, as the simulation's plant draws its nozzles; 0 for a dead nozzle), and it
lands on the world's :class:`~hardware.printhead.ink.JettedField` (``field=x0,y0,cols,rows``:
cell [0, 0] centre and size in cells at the head's pitch), which the mock height sensor reads.

The UV lamp is the output ``cure`` of the machine (``P6``: Marlin ``M42 P6 S255`` / ``S0``;
``M8``: grbl's flood coolant ``M8``/``M9``); on for at least ``cure_s`` machine seconds, it
cures the liquid ink when it goes off (:meth:`JettedField.cure`).

URL options (all optional)::

    head://NAME?machine=NAME&nozzles=384&rows=2&dpi=300&row_gap_um=550&offset=20,-15
        &volume_pl=6&diameter_um=60&spread=0.02&drop_noise=0.01&volume_bias=1&dead=3,17
        &seed=0&cure=P6&cure_s=0.2&threshold_um=3&mobility=0.5&flow_steps=1
        &field=0,0,360,360&history=0

Options given for a registered head may only change ``dead`` (a nozzle failing mid-run) and
``machine``.  ``InvalidConfig`` names ``port.<option>``.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from urllib.parse import parse_qsl

import numpy as np

from ..errors import InvalidConfig
from ..mock.timeline import MotionTimeline
from ..mock.world import MockWorld, get_world
from ..port_url import PortUrl
from . import hdp
from .ink import MM3_PER_PL, InkModel, JettedField

MM_PER_INCH = 25.4


@dataclass(frozen=True)
class HeadSpec:
    """The mock head and its ink (module docstring)."""

    nozzles: int = 384
    rows: int = 2
    dpi: float = 300.0
    row_gap_um: float = 550.0
    offset_mm: tuple[float, float] = (20.0, -15.0)
    volume_pl: float = 6.0
    spread: float = 0.02
    drop_noise: float = 0.01
    volume_bias: float = 1.0
    dead: tuple[int, ...] = ()
    seed: int = 0
    cure: str = "P6"
    cure_s: float = 0.2
    ink: InkModel = field(default_factory=InkModel)
    field_cells: tuple[float, float, int, int] = (0.0, 0.0, 360, 360)
    history: bool = False

    def __post_init__(self) -> None:
        checks = [("nozzles", 1 <= self.nozzles <= 100_000), ("rows", 1 <= self.rows <= 16),
                  ("dpi", 0 < self.dpi <= 10_000), ("row_gap_um", self.row_gap_um >= 0),
                  ("volume_pl", self.volume_pl > 0), ("spread", 0 <= self.spread < 1),
                  ("drop_noise", 0 <= self.drop_noise < 1), ("volume_bias", self.volume_bias > 0),
                  ("cure_s", self.cure_s >= 0), ("dead", all(0 <= d < self.nozzles for d in self.dead))]
        for name, ok in checks:
            if not ok:
                raise InvalidConfig(f"head option {name} is out of range", field=f"port.{name}",
                                    value=str(getattr(self, name))[:60])

    @property
    def pitch_mm(self) -> float:
        return MM_PER_INCH / self.dpi


class MockPrintHead:
    """One mock head driver (module docstring)."""

    def __init__(self, spec: HeadSpec, machine: str) -> None:
        self.spec = spec
        self.machine = machine
        self.rng = np.random.default_rng(spec.seed)
        self.nozzle_factor = np.maximum(1.0 + spec.spread * self.rng.standard_normal(spec.nozzles), 0.0)
        x0, y0, cols, rows = spec.field_cells
        self.field = JettedField((x0, y0), spec.pitch_mm, (int(rows), int(cols)), spec.ink, spec.history)
        self.swath: tuple[float, int, np.ndarray] | None = None  # y0, first nozzle, (rows, count) bits
        self.armed = False
        self.crossed = np.zeros((0, 0), dtype=bool)  # (bitmap rows, nozzle rows) crossed since ARM
        self.fired = 0
        self.since = 0.0
        self.lamp_on_at: float | None = None
        self.cures = 0
        self.lock = threading.RLock()
        self._world_id: int | None = None

    # ------------------------------------------------------------------ the machine
    def world(self) -> MockWorld:
        """The machine's world, with this head's field and lamp attached to it."""
        try:
            world = get_world(self.machine)
        except KeyError:
            raise InvalidConfig(f"no mock machine {self.machine!r} for the head", field="port.machine",
                                value=self.machine) from None
        if self._world_id != id(world):
            with world.lock:
                if world.timeline is None:
                    world.timeline = MotionTimeline()
                world.surfaces.append(self.field)
                world.output_listeners.append(self.on_output)
            self._world_id = id(world)
        return world

    def on_output(self, key: str, value: float, t: float) -> None:
        """The lamp: on at ``value > 0``; going off after ``cure_s`` it cures the ink."""
        if key != self.spec.cure:
            return
        with self.lock:
            if value > 0 and self.lamp_on_at is None:
                self.lamp_on_at = t
            elif value <= 0 and self.lamp_on_at is not None:
                dose, self.lamp_on_at = t - self.lamp_on_at, None
                if dose >= self.spec.cure_s - 1e-9:
                    self.settle(get_world(self.machine), t)
                    self.field.cure()
                    self.cures += 1

    def settle(self, world: MockWorld, now: float) -> None:
        """Fire every drop whose nozzle crossed its bitmap row since the last settle."""
        if not self.armed or self.swath is None or world.timeline is None:
            self.since = now
            return
        y0, first, bits = self.swath
        spec, pitch = self.spec, self.spec.pitch_mm
        rows_y = y0 + np.arange(bits.shape[0]) * pitch
        nozzles = first + np.arange(bits.shape[1])
        for t0, t1, *ends in world.timeline.segments_since(self.since):
            p0, p1 = np.array(ends[:3]), np.array(ends[3:])
            if t0 < self.since:  # the part of the segment after the last settle
                p0 = p0 + (p1 - p0) * (self.since - t0) / (t1 - t0)
            dy = p1[1] - p0[1]
            if abs(dy) < 1e-12:
                continue
            for r in range(spec.rows):
                cols = np.flatnonzero(nozzles % spec.rows == r)
                f = (rows_y - (p0[1] + spec.offset_mm[1] + r * spec.row_gap_um * 1e-3)) / dy
                hit = np.flatnonzero((f >= 0.0) & (f <= 1.0) & ~self.crossed[:, r])
                if not len(hit) or not len(cols):
                    continue
                self.crossed[hit, r] = True
                on = bits[np.ix_(hit, cols)]
                if not on.any():
                    continue
                i, c = np.nonzero(on)
                n = nozzles[cols[c]]
                x = p0[0] + f[hit[i]] * (p1[0] - p0[0]) + spec.offset_mm[0] + n * pitch
                alive = (~np.isin(n, spec.dead)).astype(float)
                noise = np.maximum(1.0 + spec.drop_noise * self.rng.standard_normal(len(n)), 0.0)
                volume = spec.volume_pl * MM3_PER_PL * spec.volume_bias * self.nozzle_factor[n] * alive * noise
                self.field.land(x, rows_y[hit[i]], volume)
                self.fired += len(n)
        self.since = now

    # ------------------------------------------------------------------ commands
    def handle(self, line: str) -> str:
        """The response line (without LF) to one command line."""
        parts = [p.strip() for p in line.strip().split(",")]
        head, args = parts[0].upper(), parts[1:]
        if head not in ("ID", "LOAD", "ARM", "ST", "DA"):
            return f"ER,{head[:4]},00"
        spec = self.spec
        if head == "ID":
            return f"ID,MOCK-HEAD,{spec.nozzles},{spec.rows},{spec.dpi:g},{spec.row_gap_um:g}"
        world = self.world()
        follower = _FOLLOWERS.get(self.machine)
        if follower is not None:  # a world fed from a real controller: its clock catches up first
            follower()
        with world.lock, self.lock:
            now = world.stats.machine_time_s
            if head == "LOAD":
                return self._load(args)
            if head == "ARM":
                if self.swath is None or self.armed:
                    return "ER,ARM,01"
                self.armed, self.fired, self.since = True, 0, now
                self.crossed = np.zeros((self.swath[2].shape[0], spec.rows), dtype=bool)
                return "ARM"
            self.settle(world, now)
            if head == "ST":
                rows = 0 if self.swath is None else int(self.swath[2].shape[0])
                used = sorted({int(n) % spec.rows
                               for n in range(self.swath[1], self.swath[1] + self.swath[2].shape[1])}) \
                    if self.swath is not None else []
                done = int(self.crossed[:, used].all(axis=1).sum()) if self.armed and used else 0
                return f"ST,{int(self.armed)},{done},{rows},{self.fired}"
            fired = self.fired
            self.armed, self.swath = False, None
            return f"DA,{fired}"

    def _load(self, args: list[str]) -> str:
        if self.armed:
            return "ER,LOAD,01"
        if len(args) != 6:
            return "ER,LOAD,21"
        try:
            y0, rows, first, count = float(args[0]), int(args[1]), int(args[2]), int(args[3])
        except ValueError:
            return "ER,LOAD,22"
        if not math.isfinite(y0) or first < 0 or count < 1 or first + count > self.spec.nozzles:
            return "ER,LOAD,22"
        try:
            bits = hdp.unpack_bitmap(args[5], rows, count, args[4])
        except hdp.HdpFormatError as exc:
            return "ER,LOAD,23" if "checksum" in str(exc) else "ER,LOAD,22"
        self.swath = (y0, first, bits)
        return f"LOAD,{int(bits.sum())}"


_REGISTRY: dict[str, MockPrintHead] = {}
_LOCK = threading.Lock()
_FOLLOWERS: dict[str, Callable[[], None]] = {}


def follow_world(name: str, catch_up: Callable[[], None] | None) -> None:
    """The world ``name`` is fed from a controller (its carriage and outputs, e.g. the LinuxCNC
    simulator's HAL: :mod:`hardware.linuxcnc.sim_head`): a head on it calls ``catch_up()``
    before each command that reads the machine clock, which returns once the world holds the
    controller's state as of that call; None: forget it."""
    if catch_up is None:
        _FOLLOWERS.pop(name, None)
    else:
        _FOLLOWERS[name] = catch_up
_FLOATS = {"dpi", "row_gap_um", "volume_pl", "spread", "drop_noise", "volume_bias", "cure_s"}
_INTS = {"nozzles", "rows", "seed"}
_INK = {"diameter_um": "drop_diameter_um", "threshold_um": "threshold_um", "mobility": "mobility",
        "flow_steps": "flow_steps"}


def _number(key: str, text: str, kind: type) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise InvalidConfig(f"head option {key}={text!r} is not a number", field=f"port.{key}",
                            value=text[:40]) from None
    if not math.isfinite(value):
        raise InvalidConfig(f"head option {key} must be finite", field=f"port.{key}", value=text[:40])
    return float(value)


def _list(key: str, text: str, count: int | None, kind: type) -> list[float]:
    values = [_number(key, v, kind) for v in text.split(",") if v != ""]
    if count is not None and len(values) != count:
        raise InvalidConfig(f"head option {key}={text!r}: expected {count} comma-separated numbers",
                            field=f"port.{key}", value=text[:60])
    return values


def parse_options(query: str) -> dict[str, object]:
    """Typed options from a ``head://`` query string (``InvalidConfig`` when malformed)."""
    out: dict[str, object] = {}
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise InvalidConfig(f"malformed head options {query!r}", field="port", value=query[:80]) from None
    ink: dict[str, float] = {}
    for key, text in pairs:
        if key in ("machine", "cure"):
            out[key] = text
        elif key == "offset":
            out["offset_mm"] = tuple(_list(key, text, 2, float))
        elif key == "dead":
            out["dead"] = tuple(sorted({int(v) for v in _list(key, text, None, int)}))
        elif key == "field":
            x0, y0, cols, rows = _list(key, text, 4, float)
            out["field_cells"] = (x0, y0, int(cols), int(rows))
        elif key == "history":
            out["history"] = text.lower() in ("1", "true", "yes", "on")
        elif key in _FLOATS or key in _INTS:
            value = _number(key, text, int if key in _INTS else float)
            out[key] = int(value) if key in _INTS else value
        elif key in _INK:
            ink[_INK[key]] = _number(key, text, int if key == "flow_steps" else float)
        else:
            raise InvalidConfig(f"unknown head option {key!r}", field=f"port.{key}", value=text[:40])
    if ink:
        out["ink"] = InkModel(**{k: (int(v) if k == "flow_steps" else v) for k, v in ink.items()})  # type: ignore[arg-type]
    return out


def register_head(name: str, head: MockPrintHead) -> MockPrintHead:
    """Make ``head`` reachable as ``head://name``."""
    with _LOCK:
        _REGISTRY[name] = head
    return head


def unregister_head(name: str) -> None:
    """Forget ``head://name`` and take its field and lamp off the machine's world."""
    with _LOCK:
        head = _REGISTRY.pop(name, None)
    if head is None:
        return
    try:
        world = get_world(head.machine)
    except KeyError:
        return
    with world.lock:
        world.surfaces[:] = [s for s in world.surfaces if s is not head.field]
        world.output_listeners[:] = [f for f in world.output_listeners if getattr(f, "__self__", None) is not head]


def get_head(name: str) -> MockPrintHead:
    """The head registered as ``name`` (``KeyError`` when there is none)."""
    with _LOCK:
        return _REGISTRY[name]


def head_from_url(url: str) -> MockPrintHead:
    """Resolve ``head://NAME?options`` to a (possibly new, then registered) mock head."""
    parts = PortUrl.parse(url)
    if parts.scheme != "head":
        raise InvalidConfig(f"not a head URL: {url!r}", field="port", value=url[:80])
    name = parts.name
    options = parse_options(parts.query)
    machine = str(options.pop("machine", name))
    with _LOCK:
        head = _REGISTRY.get(name)
        if head is None:
            head = MockPrintHead(HeadSpec(**options), machine)  # type: ignore[arg-type]
            _REGISTRY[name] = head
            return head
    changed = {k for k, v in options.items() if getattr(head.spec, k) != v} - {"dead"}
    if changed:
        key = sorted(changed)[0]
        raise InvalidConfig(f"head {name!r} is in use: only dead nozzles may change, not {key}",
                            field=f"port.{key}", value=str(options[key])[:40])
    with head.lock:
        head.machine = machine
        if "dead" in options:
            head.spec = replace(head.spec, **{"dead": options["dead"]})  # type: ignore[arg-type]
    return head
