"""Typed reply events: what one line from the firmware means (see ``protocol.parse_reply``).

All events are small frozen dataclasses; every one keeps the raw line in ``raw``.
Positions are in mm as the firmware printed them (machine coordinates for grbl
``[PRB:...]``/``MPos``; the *planned* position for Marlin ``M114``)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class ReplyEvent:
    """Base class; ``raw`` is the line as received (without the line terminator)."""

    raw: str = field(default="", kw_only=True)


@dataclass(frozen=True)
class Ok(ReplyEvent):
    """``ok`` — the command was processed.  Marlin ``ADVANCED_OK`` adds the acknowledged
    line number ``line`` (``N``), free planner blocks ``planner_free`` (``P``) and free
    command-buffer slots ``buffer_free`` (``B``); anything else after ``ok`` is ``extra``."""

    extra: str = ""
    line: int | None = None
    planner_free: int | None = None
    buffer_free: int | None = None


@dataclass(frozen=True)
class Resend(ReplyEvent):
    """``Resend: n`` / ``rs n`` — the firmware wants line ``n`` (and all after it) again."""

    line: int


@dataclass(frozen=True)
class FirmwareErrorEvent(ReplyEvent):
    """``Error:...`` (Marlin), ``error:N`` (grbl) or ``!! msg`` (Klipper).

    ``kind`` is one of ``checksum``, ``line_number``, ``no_checksum``, ``no_line_number``
    (transmission errors, a ``Resend`` follows), ``probe`` (probing failed), ``halted``
    (the firmware stopped itself) or ``command`` (anything else).  ``code`` is grbl's error
    number; ``last_line`` Marlin's ``Last Line:`` value."""

    message: str
    code: int | None = None
    last_line: int | None = None
    kind: str = "command"

    @property
    def is_transmission(self) -> bool:
        """True for errors caused by a damaged or misnumbered line (answered by a resend)."""
        return self.kind in ("checksum", "line_number", "no_checksum", "no_line_number")


@dataclass(frozen=True)
class Busy(ReplyEvent):
    """``echo:busy: processing`` — a keepalive: the firmware is alive but still working."""

    reason: str


@dataclass(frozen=True)
class Wait(ReplyEvent):
    """``wait`` — Repetier-style idle keepalive (the firmware's queue is empty)."""


@dataclass(frozen=True)
class Halted(ReplyEvent):
    """``!!`` — the firmware halted (kill); it needs a reset."""

    text: str = "!!"


@dataclass(frozen=True)
class Alarm(ReplyEvent):
    """grbl ``ALARM:n`` (1.1) or ``ALARM: text`` (0.9); ``code`` is None for the text form."""

    code: int | None
    message: str


@dataclass(frozen=True)
class ProbeReport(ReplyEvent):
    """A probe result: Marlin ``Bed X: .. Y: .. Z: ..`` or grbl ``[PRB:x,y,z:1]``."""

    x: float
    y: float
    z: float
    triggered: bool = True


@dataclass(frozen=True)
class PositionReport(ReplyEvent):
    """Marlin ``M114`` (``X:.. Y:.. Z:.. E:.. Count X:..``): ``axes`` in mm, ``counts`` in
    steps (empty when absent)."""

    axes: dict[str, float]
    counts: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class StatusReport(ReplyEvent):
    """grbl real-time status ``<Idle|MPos:..|FS:..>`` (1.1) or ``<Idle,MPos:..,WPos:..>`` (0.9).

    ``mpos``/``wpos`` are (x, y, z) or None; ``fields`` keeps every field as text."""

    state: str
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    fields: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class TemperatureReport(ReplyEvent):
    """``T:21.5 /0.0 B:21.2 /0.0 @:0 B@:0``: ``current``/``target`` per heater name."""

    current: dict[str, float]
    target: dict[str, float]


@dataclass(frozen=True)
class FirmwareInfo(ReplyEvent):
    """``FIRMWARE_NAME:Marlin ... PROTOCOL_VERSION:1.0 ...`` (M115) or grbl ``[VER:..]``."""

    fields: dict[str, str]

    @property
    def name(self) -> str:
        """Firmware name (first word of ``FIRMWARE_NAME`` or ``VER``)."""
        return (self.fields.get("FIRMWARE_NAME") or self.fields.get("VER") or "").split(" ")[0]


@dataclass(frozen=True)
class Capability(ReplyEvent):
    """``Cap:NAME:0|1`` lines after ``M115``."""

    name: str
    enabled: bool


@dataclass(frozen=True)
class Feedback(ReplyEvent):
    """grbl bracketed feedback other than probe/messages: ``[GC:..]``, ``[OPT:..]``,
    ``[G54:..]``, ``[TLO:..]``, ``[HLP:..]``, ``[echo:..]``."""

    tag: str
    value: str


@dataclass(frozen=True)
class Message(ReplyEvent):
    """grbl ``[MSG:text]`` (or 0.9 ``[text]``)."""

    text: str


@dataclass(frozen=True)
class Setting(ReplyEvent):
    """grbl ``$n=value`` setting lines and ``$Nn=`` startup lines."""

    key: str
    value: str


@dataclass(frozen=True)
class HostAction(ReplyEvent):
    """Marlin ``//action:name args`` host action commands."""

    action: str


@dataclass(frozen=True)
class Echo(ReplyEvent):
    """``echo:text`` (Marlin informational line, e.g. ``Unknown command``)."""

    text: str


@dataclass(frozen=True)
class StartBanner(ReplyEvent):
    """The controller (re)started: Marlin ``start`` or grbl ``Grbl 1.1h ['$' for help]``."""

    firmware: str
    text: str


@dataclass(frozen=True)
class Unknown(ReplyEvent):
    """Anything else (noise, firmware chatter we do not interpret)."""

    text: str
