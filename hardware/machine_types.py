"""Value types of ``hardware.machine``: profile, identity, probe result, stream report, the
last position reported while streaming."""

from __future__ import annotations

from dataclasses import dataclass, field

from .dialects import MARLIN
from .errors import InvalidConfig

STATES = ("disconnected", "idle", "busy", "printing", "paused", "error")


@dataclass(frozen=True)
class MachineProfile:
    """Machine-specific commands and motion defaults (mm, mm/min).

    ``dispense_on``/``dispense_off`` default to Marlin's (``hardware.dialects``' table, the
    default dialect); a ``Machine`` made without a profile gets its own dialect's.
    """

    dispense_on: str = MARLIN.dispense[0]
    dispense_off: str = MARLIN.dispense[1]
    probe_feed_mm_min: float = 100.0
    travel_feed_mm_min: float = 3000.0
    clearance_z: float = 5.0
    probe_z_min: float = -10.0
    probe_command: str | None = None   # "G30" | "G38.2"; None: G30 (marlin), G38.2 (grbl)
    home_command: str | None = None    # None: "G28" (marlin), "$H" (grbl)
    # commands that switch every other process output off (spindle, high voltage, heaters),
    # sent with dispense_off wherever the machine makes its outputs safe (``safe_off``)
    outputs_off: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.probe_command not in (None, "G30", "G38.2"):
            raise InvalidConfig("probe_command must be G30 or G38.2", field="profile.probe_command",
                                value=self.probe_command)
        for name in ("probe_feed_mm_min", "travel_feed_mm_min"):
            if not getattr(self, name) > 0:
                raise InvalidConfig(f"{name} must be > 0", field=f"profile.{name}",
                                    value=getattr(self, name))
        if not self.dispense_on.strip() or not self.dispense_off.strip():
            raise InvalidConfig("dispense commands must not be empty", field="profile.dispense_on")
        object.__setattr__(self, "outputs_off", tuple(self.outputs_off))
        for k, command in enumerate(self.outputs_off):
            if not isinstance(command, str) or not command.strip():
                raise InvalidConfig("outputs_off commands must not be empty", field=f"profile.outputs_off.{k}",
                                    value=command)

    @property
    def safe_off(self) -> tuple[str, ...]:
        """Every process output off: ``dispense_off`` then ``outputs_off``."""
        return (self.dispense_off, *self.outputs_off)


@dataclass(frozen=True)
class Identity:
    """Who answered: firmware name, M115/``$I`` fields, capabilities, start banner."""

    dialect: str
    firmware: str
    fields: dict[str, str]
    capabilities: dict[str, bool]
    banner: tuple[str, ...]
    reset_detected: bool


@dataclass(frozen=True)
class ProbeResult:
    """A measured surface point (mm, machine coordinates)."""

    x: float
    y: float
    z: float


@dataclass(frozen=True)
class StreamReport:
    """Outcome of ``stream``: commands known executed (index of the next one), total,
    where it started, whether it was cancelled, elapsed seconds, link counters."""

    executed: int
    total: int
    start_line: int
    cancelled: bool
    elapsed_s: float
    link_stats: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class ReportEvidence:
    """The last real position the controller reported while streaming (``hardware.reports``):
    ``position`` (mm, work frame), commands ``[0, acked_index)`` acknowledged when it arrived,
    ``asked_at`` (host time at or before it was made) and
    ``stopped_at`` (host time the controller surely stopped moving: the reset seen on the
    link; None when the link died without one: the reconnect stops it at the latest) and
    ``origin``, the reported position of the tool standing still before the first command
    (None: unknown, or a resumed stream whose start point the modal replay set)."""

    position: tuple[float, float, float]
    acked_index: int
    asked_at: float
    stopped_at: float | None
    origin: tuple[float, float, float] | None = None  # where the tool stood (still) before the stream
