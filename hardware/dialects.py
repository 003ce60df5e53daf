"""Firmware dialects as data: one frozen record per host protocol, and ``dialect(name)``.

Everything in which the Marlin and grbl hosts differ is a field here; the link, the reply
session, the machine and the mock read fields instead of branching on the name, so a new
firmware (RepRapFirmware, a LinuxCNC serial front end...) is one more record::

    rules = dialect("grbl")
    rules.estop_bytes          # b"\\x18"  (soft reset, real-time, bypasses every queue)
    rules.line_bytes("G1 X1")  # 6: what the line takes in the controller's RX buffer
    dialect("smoothie")        # UnknownDialect (an InvalidConfig, field "dialect")

Comments are the same in both (``;`` to the end of the line and ``( )``) and never reach the
wire: ``hardware.protocol.normalize_command`` strips them before a line is framed.

Pure: no I/O.  Byte counts are bytes on the wire; times are not kept here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

from .errors import InvalidConfig

DEFAULT_DIALECT: Final = "marlin"  # the hardware's default (Link.open, Machine, the mock world)


class UnknownDialect(InvalidConfig):
    """A dialect name that is not in :data:`DIALECTS` (field ``dialect``)."""


@dataclass(frozen=True)
class Dialect:
    """What differs between firmware families on the serial host protocol.

    Identification and boot
      ``identify_command`` (``M115`` / ``$I``); ``boot_banner``: opening the port resets
      the board and the host waits for its banner and asks a status (grbl), else it waits
      for the boot chatter to go quiet (Marlin); ``banner_words``: exact reply texts that
      are a start banner (Marlin ``start``; grbl's ``Grbl 1.1h ['$' for help]`` is parsed
      by pattern whatever the dialect); ``build_info``: the identify reply carries
      ``[OPT:..,blocks,rx_bytes]`` (grbl).
    Commands
      ``home_command``, ``homing_disabled_error`` (grbl ``error:5`` when ``$22=0``),
      ``homing_setting`` (the ``$$`` line that says homing is enabled, None: always),
      ``wait_moves`` (``M400`` / ``G4 P0``), ``probe_command`` (the default probing
      word), ``probe_reports_contact`` (``G38.2`` answers with the contact point,
      grbl ``[PRB:...]``; Marlin's ``G38.2`` prints nothing and the host reads ``M114 D``),
      ``unlock_command`` (after an alarm: grbl ``$X``), ``lock_error`` (the code a locked
      controller answers G-code with: grbl ``error:9``, alarm or jog), ``unknown_error``
      (the code of a command the firmware does not have: grbl ``error:20``; Marlin answers
      ``echo:Unknown command`` and ``ok``, None), ``position_by_status`` (where the
      tool is: a real-time status report, else ``M114``), ``jog_locks_gcode`` (G-code
      while jogging is ``error:9``), ``feed_hold``/``cycle_start`` real-time bytes.
    Position reports while streaming (``hardware.reports``)
      ``position_request``: bytes that ask for the real position; ``request_queued``: the
      request also enters the command queue (Marlin ``S000``: answered at once, then
      acknowledged by a plain ``ok``; its bytes count in the RX window until then), False
      for a real-time byte (grbl ``?``, always available).
    Safety
      ``estop_bytes``: written under the link's lock, never queued (Marlin ``M112`` via
      its emergency parser, grbl soft reset 0x18).  ``estop_keeps``: command words whose
      outputs the firmware's emergency stop leaves as they were until the board resets.
      Marlin's ``kill()`` (MarlinCore.cpp) runs ``thermalManager.disable_all_heaters()`` and
      ``cutter.kill()`` (a spindle/laser on ``M3``/``M4``), then ``minkill()``: ``cli()``
      and a loop waiting for a reset; fans (``M106``/``M107``: ``zero_fan_speeds()`` is
      only called when an SD print is aborted) and ``M42`` pins keep their level, hardware
      PWM keeps running.  grbl's ``0x18`` runs ``mc_reset()``: ``spindle_stop();
      coolant_stop();`` (motion_control.c), so nothing is kept.
    Framing and flow control
      ``line_numbers``: ``N<n> cmd*<xor>`` with ``M110`` (Marlin), which also makes
      resend requests, ``ok N`` (ADVANCED_OK) and line-number resynchronisation after a
      reconnect possible; ``line_overhead`` bytes a framed line adds on the wire (the
      ``N..*..`` frame + newline, bounded); ``window``: ``slots`` (Marlin: BUFSIZE
      command slots and the RX bytes) or ``bytes`` (grbl character counting);
      ``ok_after_error``: a rejected command still gets its ``ok`` (Marlin), else the
      ``error:N`` is the command's one answer (grbl); ``parser_marker``: the command
      whose ``[GC:..]`` answer proves every earlier line was answered (grbl ``$G``),
      used as the stall poke; None: a stall replays unacknowledged numbered lines;
      ``announced_resets``: the firmware announces resets it is about to make (grbl
      ``$C`` leaving check mode, homing alarms) and the link waits for the banner.
    Resume
      ``resets_on_connect``: opening the port resets the controller and flushes its
      buffers, so a resumed program restarts from the planner bound (grbl).
      ``stepper_queue``: moves the stepper may still hold after the planner released their
      blocks (acknowledged, not moved, and not counted by ``[OPT:]`` or ``Bf:``): grbl 1.1's
      SEGMENT_BUFFER_SIZE, 6 on the 328P, each segment possibly the last of another short
      block; Marlin 0 (its stepper runs a block in place in the planner ring and discards
      it only when done, so BLOCK_BUFFER_SIZE counts everything).  A reset loses up to the
      planner's blocks plus this many acknowledged moves.
    Liveness (what proves the firmware alive; ``hardware.session``)
      ``idle_silent``: an idle firmware sends nothing unless asked, so silence while the
      host owes nothing is no evidence and the liveness window opens when the host begins
      to wait (Marlin: ``host_keepalive()`` prints only while ``busy_state != NOT_BUSY``,
      ``wait`` only with the opt-in ``NO_TIMEOUTS``, temperatures only after ``M155``;
      grbl: nothing unsolicited).  ``alive_replies``: the reply kinds
      (``hardware.events`` class names) that prove it alive and restart the window (never
      ``Unknown``: noise and echoes).  ``busy_replies``: kinds that say a command still runs
      (Marlin ``echo:busy: processing``/``paused for user``): no stall poke while they come,
      every ``keepalive_s`` (Marlin ``HOST_KEEPALIVE_INTERVAL``, 2 s by default; None: the
      firmware has none).  ``life_query``: real-time bytes the firmware answers in any
      state (grbl ``?``: the serial ISR sets ``EXEC_STATUS_REPORT``, served in every
      ``protocol_execute_realtime()``, also while dwelling, homing or in Alarm), which a
      stall poke asks first; None: none (Marlin's ``M105``/``M114`` queue behind a
      blocking command).
    Dispenser
      ``dispense``: the dispenser on/off commands a machine of this dialect gets when made
      without a profile, and the output the mock firmware's dispenser is wired to unless its
      world names others.  The same pair as the G-code writer's own table
      (``app.gcode.writer.DIALECTS``, which every service default derives from; ``hardware``
      may not import ``app``, so a test holds the two equal): Marlin's fan at full duty,
      ``M106 S255``/``M107``; grbl's flood coolant ``M8``/``M9``, a plain digital pin (grbl
      has no fan word, ``M106`` is its ``error:20``; its spindle ``M3`` drives PWM at the
      modal S, 0 after reset, so a bare ``M3`` switches nothing).
    """

    name: str
    identify_command: str
    boot_banner: bool
    banner_words: tuple[str, ...]
    build_info: bool
    home_command: str
    homing_disabled_error: int | None
    homing_setting: str | None
    wait_moves: str
    probe_command: str
    probe_reports_contact: bool
    unlock_command: str | None
    lock_error: int | None
    unknown_error: int | None
    position_by_status: bool
    jog_locks_gcode: bool
    feed_hold: bytes | None
    cycle_start: bytes | None
    position_request: bytes
    request_queued: bool
    estop_bytes: bytes
    estop_keeps: tuple[str, ...]
    line_numbers: bool
    line_overhead: int
    window: Literal["slots", "bytes"]
    ok_after_error: bool
    parser_marker: str | None
    announced_resets: bool
    resets_on_connect: bool
    stepper_queue: int
    idle_silent: bool
    alive_replies: tuple[str, ...]
    busy_replies: tuple[str, ...]
    keepalive_s: float | None
    life_query: bytes | None
    dispense: tuple[str, str]

    def proves_alive(self, kind: str) -> bool:
        """True when a reply of kind ``kind`` (an event class name) proves the firmware alive."""
        return kind in self.alive_replies

    def says_busy(self, kind: str) -> bool:
        """True when a reply of kind ``kind`` says the command in hand still runs."""
        return kind in self.busy_replies

    def line_bytes(self, text: str) -> int:
        """Bytes a normalised command ``text`` occupies in the controller's RX buffer
        (the framed line and its newline; for numbered dialects an upper bound)."""
        return len(text) + self.line_overhead

    def keeps_through_estop(self, command: str) -> bool:
        """True when the output ``command`` switches keeps its level through this
        firmware's emergency stop (its first word is in ``estop_keeps``)."""
        word = command.strip().upper().split(" ")[0] if command.strip() else ""
        return word in self.estop_keeps

    def is_banner_word(self, text: str) -> bool:
        """True when the stripped reply ``text`` is this dialect's start banner word."""
        return text in self.banner_words


MARLIN = Dialect(
    name="marlin", identify_command="M115", boot_banner=False, banner_words=("start",),
    build_info=False, home_command="G28", homing_disabled_error=None, homing_setting=None,
    wait_moves="M400", probe_command="G30", probe_reports_contact=False, unlock_command=None,
    lock_error=None, unknown_error=None, position_by_status=False, jog_locks_gcode=False, feed_hold=None,
    cycle_start=None, position_request=b"S000\n", request_queued=True, estop_bytes=b"M112\n",
    estop_keeps=("M106", "M107", "M42"),
    line_numbers=True, line_overhead=16, window="slots", ok_after_error=True,
    parser_marker=None, announced_resets=False, resets_on_connect=False, stepper_queue=0,
    idle_silent=True,
    alive_replies=("Ok", "Resend", "FirmwareErrorEvent", "Busy", "Wait", "Halted", "TemperatureReport",
                   "PositionReport", "ProbeReport", "FirmwareInfo", "Capability", "Echo", "Message", "Setting",
                   "HostAction", "StartBanner", "Alarm", "StatusReport", "Feedback"),
    busy_replies=("Busy",), keepalive_s=2.0, life_query=None,
    dispense=("M106 S255", "M107"))

GRBL = Dialect(
    name="grbl", identify_command="$I", boot_banner=True, banner_words=(),
    build_info=True, home_command="$H", homing_disabled_error=5, homing_setting="$22=1",
    wait_moves="G4 P0", probe_command="G38.2", probe_reports_contact=True, unlock_command="$X",
    lock_error=9, unknown_error=20, position_by_status=True, jog_locks_gcode=True, feed_hold=b"!", cycle_start=b"~",
    position_request=b"?", request_queued=False, estop_bytes=b"\x18", estop_keeps=(),
    line_numbers=False, line_overhead=1, window="bytes", ok_after_error=False,
    parser_marker="$G", announced_resets=True, resets_on_connect=True, stepper_queue=6,
    idle_silent=True,
    alive_replies=("Ok", "FirmwareErrorEvent", "Alarm", "StatusReport", "ProbeReport", "Feedback", "FirmwareInfo",
                   "Message", "Setting", "Echo", "StartBanner"),
    busy_replies=(), keepalive_s=None, life_query=b"?",
    dispense=("M8", "M9"))

# RepRapFirmware would be one more record here (M115, G28, M400, G30, M112, line numbers
# and checksums, "ok" without ADVANCED_OK); LinuxCNC is driven through its own Python
# interface (hardware.linuxcnc), not this serial host.
DIALECTS: dict[str, Dialect] = {d.name: d for d in (MARLIN, GRBL)}


def dialect(name: str) -> Dialect:
    """The record of dialect ``name``; ``UnknownDialect`` (field ``dialect``) naming the
    known ones otherwise."""
    found = DIALECTS.get(name) if isinstance(name, str) else None
    if found is None:
        raise UnknownDialect(f"unknown dialect {name!r}; expected one of {', '.join(DIALECTS)}",
                             field="dialect", value=str(name)[:40])
    return found


#: LinuxCNC's dispenser: digital output 0 (``motion.digital-out-00``), synchronised with motion
LINUXCNC_DISPENSE = ("M64 P0", "M65 P0")

