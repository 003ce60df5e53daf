"""Pure G-code host protocol codec: framing, command normalisation, digests, reply parsing.

No I/O and no threads: the link (``hardware.link``) and the mock firmware both use it.

* ``frame(5, "G1 X1")`` -> ``"N5 G1 X1*93"`` (Marlin line number + XOR checksum).
* ``normalize_command(line)`` -> the command without line number, checksum, comments and
  surrounding blanks, or None when nothing is left.
* ``commands_sha256(lines)`` -> ``CommandDigest(count, sha256)``: API.md's definition —
  every normalised non-empty command followed by ``"\\n"``, hashed with sha256.
* ``parse_reply(line, dialect)`` -> a typed event from ``hardware.events``.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from typing import NamedTuple

from .dialects import DEFAULT_DIALECT
from .dialects import dialect as dialect_rules
from .errors import InvalidConfig
from .events import (
    Alarm,
    Busy,
    Capability,
    Echo,
    Feedback,
    FirmwareErrorEvent,
    FirmwareInfo,
    Halted,
    HostAction,
    Message,
    Ok,
    PositionReport,
    ProbeReport,
    ReplyEvent,
    Resend,
    Setting,
    StartBanner,
    StatusReport,
    TemperatureReport,
    Unknown,
    Wait,
)

GRBL_ERRORS = {
    1: "Expected command letter", 2: "Bad number format", 3: "Invalid statement",
    4: "Negative value", 5: "Setting disabled", 6: "Step pulse too short",
    7: "EEPROM read fail", 8: "Not idle", 9: "G-code lock (alarm or jog state)",
    10: "Homing not enabled", 11: "Line overflow", 12: "Step rate too high",
    13: "Check door", 14: "Line length exceeded", 15: "Travel exceeded",
    16: "Invalid jog command", 17: "Setting disabled (laser mode)", 20: "Unsupported command",
    21: "Modal group violation", 22: "Undefined feed rate", 23: "Invalid G-code value",
    24: "Invalid G-code (two axis commands)", 25: "Repeated G-code word",
    26: "No axis words", 27: "Invalid line number", 28: "Value word missing",
    29: "Unsupported coordinate system", 30: "G53 invalid motion mode",
    31: "Unused axis words", 32: "No arc axis words", 33: "Invalid motion target",
    34: "Invalid arc radius", 35: "No arc offsets", 36: "Unused value words",
    37: "Tool length offset axis invalid", 38: "Tool number exceeds maximum",
}
GRBL_ALARMS = {
    1: "Hard limit triggered", 2: "Soft limit: target exceeds travel",
    3: "Reset while in motion", 4: "Probe fail: probe not in expected initial state",
    5: "Probe fail: probe did not contact the workpiece", 6: "Homing fail: reset during cycle",
    7: "Homing fail: safety door opened", 8: "Homing fail: pull-off did not clear switch",
    9: "Homing fail: limit switch not found", 10: "Homing fail: second switch not found",
}


class CommandDigest(NamedTuple):
    """Number of commands and the sha256 (hex) of ``cmd + "\\n"`` over all of them."""

    count: int  # type: ignore[assignment]  # the field, named as the API always did, hides tuple.count
    sha256: str


def check_dialect(dialect: str) -> str:
    """Return ``dialect`` if known, else raise ``UnknownDialect`` (an ``InvalidConfig``)
    naming the choices (``hardware.dialects``)."""
    return dialect_rules(dialect).name


def checksum(text: str) -> int:
    """XOR of all bytes of ``text`` (UTF-8), the Marlin/RepRap line checksum (0..255)."""
    value = 0
    for byte in text.encode("utf-8"):
        value ^= byte
    return value


def frame(line_no: int, command: str) -> str:
    """``N<line_no> <command>*<checksum>`` without terminator; ``command`` must already be
    normalised (no ``*``, no newline)."""
    if "\n" in command or "*" in command:
        raise InvalidConfig("command must be one line without '*'", field="command",
                            value=command[:60])
    body = f"N{line_no} {command}"
    return f"{body}*{checksum(body)}"


_PAREN_COMMENT = re.compile(r"\([^)]*\)")
_LINE_NUMBER = re.compile(r"^[Nn]-?\d+\s*")
_CHECKSUM = re.compile(r"\*\d*\s*$")


def normalize_command(line: str) -> str | None:
    """Strip a line to its command (see module docstring); None for blank/comment lines."""
    text = line.split(";", 1)[0]
    if "(" in text:
        text = _PAREN_COMMENT.sub("", text)
    if "*" in text:
        text = _CHECKSUM.sub("", text)
    text = text.strip()
    if text[:1] in ("N", "n"):
        text = _LINE_NUMBER.sub("", text, count=1)
    return text or None


_BLOCK_COMMENT = re.compile(r";[^\n]*")
_BLOCK_PAREN = re.compile(r"\([^)\n]*\)")
_BLOCK_CHECKSUM = re.compile(r"\*\d*[ \t]*$", re.MULTILINE)
_BLOCK_LEADING = re.compile(r"^[ \t]+", re.MULTILINE)
_BLOCK_TRAILING = re.compile(r"[ \t]+(?=\n|\Z)")
_BLOCK_LINE_NUMBER = re.compile(r"^[Nn]-?\d+[ \t]*", re.MULTILINE)
_BLOCK_BLANK_LINES = re.compile(r"\n\n+")
_BLOCK_LINE_STARTS = re.compile(r"\n[ \tNn]")
#: what :func:`normalize_block` reads: printable ASCII and tabs, lines ending in "\n"
_BLOCK_TEXT = re.compile(r"[\t\n\x20-\x7e]*")


def normalize_block(text: str) -> str | None:
    """:func:`normalize_command` of every line of ``text`` at once: the non-empty commands,
    each followed by ``"\\n"`` (``""`` when there are none); None unless ``text`` is
    printable ASCII and tabs with ``"\\n"`` line breaks (a caller then goes line by line).
    A last line without its ``"\\n"`` counts as a line."""
    if not _BLOCK_TEXT.fullmatch(text):
        return None
    if ";" in text:
        text = _BLOCK_COMMENT.sub("", text)
    if "(" in text:
        text = _BLOCK_PAREN.sub("", text)
    if "*" in text:
        text = _BLOCK_CHECKSUM.sub("", text)
    # a line that starts with a blank or a line number: one scan for all four (each two-character
    # ``in`` test is a scan of its own, 0.2 ms on a 300 kB program)
    starts = text[:1] in (" ", "\t", "N", "n") or _BLOCK_LINE_STARTS.search(text) is not None
    if starts and (text[:1] in (" ", "\t") or "\n " in text or "\n\t" in text):
        text = _BLOCK_LEADING.sub("", text)
    if text.endswith((" ", "\t")) or " \n" in text or "\t\n" in text:
        text = _BLOCK_TRAILING.sub("", text)
    if starts and (text[:1] in ("N", "n") or "\nN" in text or "\nn" in text):
        text = _BLOCK_LINE_NUMBER.sub("", text)
    text = _BLOCK_BLANK_LINES.sub("\n", text).lstrip("\n")
    return text if not text or text.endswith("\n") else text + "\n"


class CommandHasher:
    """Incremental ``commands_sha256``: ``update(command)`` with normalised commands."""

    __slots__ = ("_hash", "count")

    def __init__(self) -> None:
        self._hash = hashlib.sha256()
        self.count = 0

    def update(self, command: str) -> None:
        """Add one already-normalised command."""
        self._hash.update(command.encode("utf-8") + b"\n")
        self.count += 1

    def update_block(self, commands: str) -> None:
        """Add already-normalised commands, each followed by ``"\\n"`` (:func:`normalize_block`)."""
        self._hash.update(commands.encode("utf-8"))
        self.count += commands.count("\n")

    def digest(self) -> CommandDigest:
        """Current count and hex digest."""
        return CommandDigest(self.count, self._hash.hexdigest())


def normalized_commands(lines: Iterable[str]) -> list[str]:
    """The non-empty normalised commands of ``lines``, in order."""
    out = []
    for line in lines:
        command = normalize_command(line)
        if command is not None:
            out.append(command)
    return out


_COMMAND_START = re.compile(r"^[A-Za-z$%]")
_PRINTABLE = re.compile(r"^[\x20-\x7e\t]*$")


def validate_program(lines: Iterable[str], max_line_bytes: int = 256) -> list[str]:
    """The program's normalised commands, or ``InvalidConfig`` naming the first line that
    is not G-code (binary data, a word not starting with a letter, an over-long line)."""
    commands = []
    for number, line in enumerate(lines, start=1):
        command = normalize_command(line)
        if command is None:
            continue
        if not _PRINTABLE.match(command) or not _COMMAND_START.match(command) \
                or len(command) > max_line_bytes:
            raise InvalidConfig(f"line {number} is not a G-code command", field="program",
                                value=f"line {number}: {command[:40]!r}")
        commands.append(command)
    if not commands:
        raise InvalidConfig("the program contains no commands", field="program", value=None)
    return commands


def commands_sha256(lines: Iterable[str]) -> CommandDigest:
    """API.md's program digest over ``lines`` (raw G-code lines, comments allowed)."""
    hasher = CommandHasher()
    for line in lines:
        command = normalize_command(line)
        if command is not None:
            hasher.update(command)
    return hasher.digest()


# ----------------------------------------------------------------------------- replies
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)"
_ADV_OK = re.compile(r"^(?:N(\d+)\s+)?P(\d+)\s+B(\d+)$")
_RESEND = re.compile(r"^(?:Resend|rs)[:\s]\s*N?:?\s*(\d+)", re.IGNORECASE)
_LAST_LINE = re.compile(r"Last Line:\s*(-?\d+)")
_GRBL_ERROR = re.compile(r"^error:\s*(\d+)\s*$", re.IGNORECASE)
_ALARM = re.compile(r"^ALARM:\s*(\d+)\s*$")
_BED = re.compile(rf"^Bed\s+X:\s*({_NUM})\s+Y:\s*({_NUM})\s+Z:\s*({_NUM})")
_PRB = re.compile(rf"^\[PRB:({_NUM}),({_NUM}),({_NUM})(?::([01]))?\]$")
_AXIS = re.compile(rf"([A-Z][A-Z0-9]?):\s*({_NUM})")
_TEMP = re.compile(rf"(T\d*|B|C|P|L|R|@|B@|@\d+):\s*({_NUM})(?:\s*/\s*({_NUM}))?")
_SETTING = re.compile(r"^\$(N?\d+)=(.*)$")
_NOISE = re.compile("[\x00-\x08\x0b-\x1f\x7f\ufffd]")
_GRBL_BANNER = re.compile(r"^Grbl\s+\S+\s+\[.*\]")


def _marlin_error(raw: str, message: str) -> FirmwareErrorEvent:
    lowered = message.lower()
    last = _LAST_LINE.search(message)
    last_line = int(last.group(1)) if last else None
    if "checksum mismatch" in lowered:
        kind = "checksum"
    elif "line number is not" in lowered:
        kind = "line_number"
    elif "no checksum" in lowered:
        kind = "no_checksum"
    elif "no line number" in lowered:
        kind = "no_line_number"
    elif any(s in lowered for s in ("probing failed", "failed to reach target",
                                     "probe deployment failed", "probe stow failed")):
        kind = "probe"
    elif any(s in lowered for s in ("halted", "kill", "stopped", "stop called")):
        kind = "halted"
    else:
        kind = "command"
    return FirmwareErrorEvent(message, None, last_line, kind, raw=raw)


def _parse_ok(raw: str, text: str) -> ReplyEvent:
    extra = text[2:].strip()
    match = _ADV_OK.match(extra)
    if match:
        line = int(match.group(1)) if match.group(1) else None
        return Ok(extra, line, int(match.group(2)), int(match.group(3)), raw=raw)
    return Ok(extra, raw=raw)


def _parse_axes(text: str) -> dict[str, float]:
    return {name: float(value) for name, value in _AXIS.findall(text)}


def _parse_position(raw: str, text: str) -> ReplyEvent:
    head, _, tail = text.partition("Count")
    axes = _parse_axes(head)
    counts = _parse_axes(tail) if tail else {}
    return PositionReport(axes, counts, raw=raw)


def _parse_temperature(raw: str, text: str) -> ReplyEvent:
    current: dict[str, float] = {}
    target: dict[str, float] = {}
    for name, value, goal in _TEMP.findall(text):
        current[name] = float(value)
        if goal:
            target[name] = float(goal)
    return TemperatureReport(current, target, raw=raw)


def _triple(text: str) -> tuple[float, ...] | None:
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        return None


def _parse_status(raw: str, text: str) -> ReplyEvent:
    body = text[1:-1]
    if "|" in body:
        parts = body.split("|")
        fields = {key: value for key, _, value in (part.partition(":") for part in parts[1:])}
    else:  # grbl 0.9: <Idle,MPos:0.000,0.000,0.000,WPos:0.000,0.000,0.000>
        parts = body.split(",", 1)
        fields = {key: value.rstrip(",") for key, value in
                  re.findall(r"(\w+):([-\d.,]+?)(?=,\w+:|$)", parts[1] if len(parts) > 1 else "")}
    state = parts[0]
    mpos = _triple(fields["MPos"]) if "MPos" in fields else None
    wpos = _triple(fields["WPos"]) if "WPos" in fields else None
    return StatusReport(state, mpos, wpos, fields, raw=raw)


def _parse_bracket(raw: str, text: str) -> ReplyEvent:
    match = _PRB.match(text)
    if match:
        x, y, z, flag = match.groups()
        return ProbeReport(float(x), float(y), float(z), flag != "0", raw=raw)
    body = text[1:-1]
    tag, sep, value = body.partition(":")
    if sep and tag.isalnum() and tag.upper() == tag or tag == "echo":
        if tag == "MSG":
            return Message(value, raw=raw)
        if tag == "VER":
            return FirmwareInfo({"VER": value}, raw=raw)
        return Feedback(tag, value, raw=raw)
    return Message(body, raw=raw)


def _parse_m115(raw: str, text: str) -> ReplyEvent:
    keys = list(re.finditer(r"([A-Z_]+):", text))
    fields = {}
    for i, key in enumerate(keys):
        end = keys[i + 1].start() if i + 1 < len(keys) else len(text)
        fields[key.group(1)] = text[key.end():end].strip()
    return FirmwareInfo(fields, raw=raw)


# one flat dispatch over cases; splitting it hides their order
def parse_reply(line: str, dialect: str = DEFAULT_DIALECT) -> ReplyEvent:  # noqa: C901
    """Parse one reply line (terminator optional) into a typed event.

    Both dialects' forms are recognised whatever ``dialect`` says (grbl error texts are
    looked up for ``error:N``); ``dialect`` is validated (``InvalidConfig`` if unknown) and
    decides ambiguous words (``start`` is a banner only for Marlin: ``banner_words``)."""
    rules = dialect_rules(dialect)
    raw = line.rstrip("\r\n")
    text = raw.strip()
    if not text:
        return Unknown("", raw=raw)
    if _NOISE.search(text):  # line noise: control bytes or undecodable bytes
        return Unknown(text, raw=raw)
    if text == "ok" or text.startswith("ok ") or text.startswith("ok:"):
        return _parse_ok(raw, text.replace("ok:", "ok ", 1))
    head = text[0]
    if head in "Rr" and (resend := _RESEND.match(text)):
        return Resend(int(resend.group(1)), raw=raw)
    if text.startswith(("Error:", "ERROR:", "error:", "Error ")):
        match = _GRBL_ERROR.match(text)
        if match:
            code = int(match.group(1))
            return FirmwareErrorEvent(GRBL_ERRORS.get(code, f"error {code}"), code, None,
                                      "command", raw=raw)
        return _marlin_error(raw, text.split(":", 1)[1].strip() if ":" in text else text[6:])
    if text.startswith("!!"):
        rest = text[2:].strip()
        if not rest:
            return Halted(text, raw=raw)
        return FirmwareErrorEvent(rest, None, None, "command", raw=raw)
    if text.startswith("ALARM:"):
        match = _ALARM.match(text)
        if match:
            code = int(match.group(1))
            return Alarm(code, GRBL_ALARMS.get(code, f"alarm {code}"), raw=raw)
        return Alarm(None, text[6:].strip(), raw=raw)
    if "busy:" in text and text.replace("echo:", "").startswith("busy:"):
        return Busy(text.split("busy:", 1)[1].strip(), raw=raw)
    if text == "wait":
        return Wait(raw=raw)
    if head == "B" and text.startswith("Bed"):
        match = _BED.match(text)
        if match:
            x, y, z = (float(v) for v in match.groups())
            return ProbeReport(x, y, z, raw=raw)
    if head == "<" and text.endswith(">"):
        return _parse_status(raw, text)
    if head == "[" and text.endswith("]"):
        return _parse_bracket(raw, text)
    if head == "$" and (setting := _SETTING.match(text)):
        key, value = setting.groups()
        return Setting(key, value, raw=raw)
    if text.startswith("FIRMWARE_NAME:"):
        return _parse_m115(raw, text)
    if text.startswith("Cap:"):
        name, _, flag = text[4:].rpartition(":")
        return Capability(name, flag.strip() == "1", raw=raw)
    if text.startswith("//action:"):
        return HostAction(text[9:].strip(), raw=raw)
    if text.startswith("echo:"):
        return Echo(text[5:].strip(), raw=raw)
    if rules.is_banner_word(text):
        return StartBanner(rules.name, text, raw=raw)
    if _GRBL_BANNER.match(text):
        return StartBanner("grbl", text, raw=raw)
    if text.startswith(("T:", "T0:", "B:")) and _TEMP.match(text):
        return _parse_temperature(raw, text)
    if text.startswith("X:") and _AXIS.match(text):
        return _parse_position(raw, text)
    return Unknown(text, raw=raw)


def dwell_budget_s(commands: Iterable[str]) -> float:
    """Seconds of grbl ``G4`` dwell among ``commands`` (P is seconds; an unreadable P: 60)."""
    total = 0.0
    for command in commands:
        words = command.upper().replace(" ", "")
        if words.startswith("G4P"):
            try:
                total += float(words[3:])
            except ValueError:
                total += 60.0
    return total
