"""Request/response models of machines and programs (mm, mm/min, degrees)."""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, field_validator, model_validator

from app.api.schemas import Finite, Strict, UtcDatetime
from app.five_axis.post import PostName
from app.gcode.writer import DEFAULT_DIALECT, DialectName
from app.machines.dispenser import described, machine_dispense
from app.machines.materials import DispenseProfile

MaterialName = Annotated[str, Field(min_length=1, max_length=80)]
MAX_MATERIAL_PROFILES = 32

_PORT = re.compile(r"^(mock://[^\s]*|socket://[A-Za-z0-9.\-]+:\d{1,5}|/dev/[A-Za-z0-9_./\-]+|COM\d+|loop://[^\s]*"
                   r"|linuxcnc://[A-Za-z0-9.\-]+:\d{1,5}(\?joints=\d)?)$")
Rate = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]


class TravelVolume(Strict):
    """Travel limits, mm: [min, max] per axis (toolpath jobs place parts inside them)."""

    x: Annotated[list[Finite], Field(min_length=2, max_length=2)]
    y: Annotated[list[Finite], Field(min_length=2, max_length=2)]
    z: Annotated[list[Finite], Field(min_length=2, max_length=2)]

    @field_validator("x", "y", "z")
    @classmethod
    def _ordered(cls, value: list[float]) -> list[float]:
        if not value[1] > value[0] or max(abs(v) for v in value) > 10_000:
            raise ValueError("expected [min, max] with min < max within +-10000 mm")
        return value


Coordinate = Annotated[float, Field(allow_inf_nan=False, ge=-10_000, le=10_000)]
Point3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]


class ProbeTool(Strict):
    """The touch probe, tool T0: its stylus ball and its (definitional) zero offset."""

    ball_radius_mm: Finite = Field(0.0, ge=0, le=10, description="nominal stylus ball radius, mm")
    offset_mm: Point3 = Field(default_factory=lambda: [0.0, 0.0, 0.0],
                              description="T0's offset: [0, 0, 0] (machine coordinates are the ball centre's)")

    @field_validator("offset_mm")
    @classmethod
    def _zero(cls, value: list[float]) -> list[float]:
        if any(v != 0 for v in value):
            raise ValueError("the probe (T0) defines the machine frame: its offset must be [0, 0, 0]")
        return value


class NozzleTool(Strict):
    """A dispensing nozzle T<tool>: tip = carriage + offset (nominal until calibrated)."""

    tool: int = Field(ge=1, le=8, description="tool number (T1..T8)")
    name: str = Field("", max_length=80)
    outer_diameter_mm: Finite = Field(gt=0, le=20, description="outer diameter of the nozzle body, mm")
    offset_mm: Point3 = Field(description="nominal [x, y, z] offset of the tip from the probe's ball centre, mm")
    dispense_on: str | None = Field(None, min_length=1, max_length=80, description="default: the profile's")
    dispense_off: str | None = Field(None, min_length=1, max_length=80, description="default: the profile's")

    @field_validator("offset_mm")
    @classmethod
    def _reach(cls, value: list[float]) -> list[float]:
        if max(abs(v) for v in value) > 500:
            raise ValueError("a tool offset is within +-500 mm of the probe")
        return value


class Tools(Strict):
    probe: ProbeTool = Field(default_factory=ProbeTool)
    nozzles: list[NozzleTool] = Field(default_factory=list, max_length=8)

    @field_validator("nozzles")
    @classmethod
    def _unique(cls, value: list[NozzleTool]) -> list[NozzleTool]:
        numbers = [n.tool for n in value]
        if len(set(numbers)) != len(numbers):
            raise ValueError(f"tool numbers must be unique, got {numbers}")
        return value


class ReferencePad(Strict):
    """A flat conductive contact pad: square, top face at centre_mm's z (nominal place)."""

    centre_mm: Point3
    size_mm: Finite = Field(gt=0, le=200, description="side of the square top face, mm")


class ReferenceSphere(Strict):
    """The datum sphere on its stem (nominal place)."""

    centre_mm: Point3
    diameter_mm: Finite = Field(gt=0, le=100)


class Reference(Strict):
    """Reference artifacts on the table (nominal places, machine coordinates, mm)."""

    pad: ReferencePad | None = None
    sphere: ReferenceSphere | None = None


class Profile(Strict):
    dispense_on: str | None = Field(None, min_length=1, max_length=80, description=(
        f"G-code that starts dispensing; default: the dialect's ({described(0)})"))
    dispense_off: str | None = Field(None, min_length=1, max_length=80, description=(
        f"G-code that stops dispensing; default: the dialect's ({described(1)})"))
    outputs_off: list[Annotated[str, Field(min_length=1, max_length=80)]] = Field(
        default_factory=list, max_length=16,
        description="G-code that switches every other process output off (spindle, high voltage, heaters), sent "
                    "after dispense_off wherever the machine makes its outputs safe (LinuxCNC: connect, home, "
                    "each program's start, disconnect)")
    probe_feed_mm_min: Finite = Field(100.0, gt=0, le=10_000)
    travel_feed_mm_min: Finite = Field(3000.0, gt=0, le=100_000)
    print_feed_mm_min: Finite = Field(300.0, gt=0, le=100_000)
    clearance_z: Finite = Field(5.0, gt=-1000, le=1000, description="safe Z for travel, mm")
    probe_z_min: Finite = Field(-10.0, gt=-1000, le=1000, description="lowest Z a probe may reach, mm")
    probe_command: Literal["G30", "G38.2"] | None = None
    volume_mm: TravelVolume | None = Field(None, description="the machine's travel limits (real-parts: programs "
                                           "from a part in its own frame are placed inside and refused beyond)")
    program_end: str | None = Field(None, min_length=1, max_length=40, pattern=r"^[A-Za-z0-9 .\-]+$",
                                    description="program end, e.g. M2 (LinuxCNC); default: the dialect's")
    pivot_mm: list[Finite] | None = Field(None, min_length=3, max_length=3,
                                          description="five-axis table pivot [x, y, z] mm (LinuxCNC xyzac-trt "
                                          "x/y/z-rot-point); five_axis jobs with machine_id use it")
    five_axis_post: PostName = Field(
        "conforma", description="how five_axis jobs with machine_id write X Y Z A C (see docs/five-axis.md)")
    tools: Tools | None = Field(None, description="T0 = the touch probe, T1..T8 = nozzles (nominal offsets)")
    reference: Reference | None = Field(None, description="reference pad and sphere for the calibration jobs")
    calibration_max_age_h: Finite = Field(24.0, gt=0, le=24 * 365,
                                          description="a calibration older than this is flagged stale")
    dispense: DispenseProfile | None = Field(None, description="the material this machine dispenses: pressure, "
                                             "on/off delays, standoff, speed (app.machines.materials); print jobs "
                                             "apply its delays and record it")
    dispense_by_material: dict[MaterialName, DispenseProfile] = Field(
        default_factory=dict, max_length=MAX_MATERIAL_PROFILES,
        description="this machine's own profile of each material it has dispensed, by preset name: set whenever "
        "profile.dispense is saved for a material; choosing that material again (PATCH {material}, a print's "
        "material) takes the machine's own, not the preset's starting point")


class MockPlacement(Strict):
    dx: Finite = Field(0.0, ge=-100, le=100)
    dy: Finite = Field(0.0, ge=-100, le=100)
    dz: Finite = Field(0.0, ge=-100, le=100)
    rz_deg: Finite = Field(0.0, ge=-180, le=180)


class MockFaults(Strict):
    checksum_rate: Rate = 0.0
    drop_ok_rate: Rate = 0.0
    duplicate_ok_rate: Rate = 0.0
    resend_rate: Rate = 0.0
    garbage_rate: Rate = 0.0
    busy_rate: Rate = 0.0
    slow_rate: Rate = 0.0
    disconnect_at_line: int | None = Field(None, ge=1)
    reset_at_line: int | None = Field(None, ge=1)
    seed: int = Field(0, ge=0, le=2**31)


Coord = Annotated[float, Field(ge=-10_000, le=10_000, allow_inf_nan=False)]


class MockToolSettings(Strict):
    """A nozzle T1..Tn of the mock: its tip is at carriage + offset_mm."""

    offset_mm: list[Coord] = Field(min_length=3, max_length=3, description="[x, y, z] tip - carriage, mm")
    outer_diameter_mm: Finite = Field(gt=0, le=50, description="the nozzle body's outer diameter, mm")


class MockPadSettings(Strict):
    """The conductive reference pad: a square block, top face centred at centre_mm."""

    centre_mm: list[Coord] = Field(min_length=3, max_length=3, description="[x, y, z top] mm")
    size_mm: Finite = Field(gt=0, le=500)


class MockSphereSettings(Strict):
    """The conductive datum sphere (on a thin stem)."""

    centre_mm: list[Coord] = Field(min_length=3, max_length=3, description="[x, y, z] mm")
    diameter_mm: Finite = Field(gt=0, le=500)


class MockPhysics(Strict):
    """The mock's probe physics (hidden truth; defaults = the ideal point probe)."""

    stylus_radius_mm: Finite = Field(0.0, ge=0, le=10, description="T0's ball radius, mm")
    pretravel_mm: Finite = Field(0.0, ge=0, le=5, description="mean trigger pre-travel, mm")
    pretravel_sd_mm: Finite = Field(0.0, ge=0, le=1, description="pre-travel scatter per touch, mm")
    pretravel_lobing_mm: Finite = Field(0.0, ge=0, le=1, description="amplitude of sin(theta) cos(3 phi), mm")
    drift_mm_per_min: Finite = Field(0.0, ge=0, le=1, description="Z drift per minute of machine time, mm")
    touchoff_sd_mm: Finite = Field(0.0, ge=0, le=1, description="nozzle touch-off scatter, mm")
    tools: list[MockToolSettings] = Field(default_factory=list, max_length=8, description="T1..Tn")
    pad: MockPadSettings | None = None
    sphere: MockSphereSettings | None = None


class MockSettings(Strict):
    true_part_id: str | None = Field(None, description="the as-made part the mock probes against")
    placement: MockPlacement = Field(default_factory=MockPlacement)
    probe_noise_mm: Finite = Field(0.0, ge=0, le=1)
    probe_dust: list[tuple[Coord, Coord, Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)]]] = Field(
        default_factory=list, max_length=100, description="dust [x, y, dz] mm: the first touch within 0.5 mm of "
        "(x, y) reads dz high (gone after that touch: a touch again reads the part)")
    time_scale: Finite = Field(0.0, ge=0, le=10, description="1 = real time, 0 = as fast as possible")
    faults: MockFaults = Field(default_factory=MockFaults)
    physics: MockPhysics | None = Field(None, description="probe physics (ball stylus, pre-travel, drift, tools, "
                                        "reference pad and sphere); none: the ideal probe")


class MachineCreate(Strict):
    name: str = Field(min_length=1, max_length=200)
    port: str = Field(description='"mock://", "socket://host:port" or a device such as "/dev/ttyUSB0"')
    baudrate: int = Field(115200, ge=300, le=4_000_000)
    dialect: DialectName = DEFAULT_DIALECT
    profile: Profile = Field(default_factory=Profile)
    mock: MockSettings | None = None

    @field_validator("port")
    @classmethod
    def _port(cls, value: str) -> str:
        if not _PORT.match(value):
            raise ValueError("expected mock://..., socket://host:port, linuxcnc://host:port or a serial device path")
        return value

    @model_validator(mode="after")
    def _dialect_dispense(self) -> MachineCreate:
        """A profile that names no dispenser gets its dialect's (``machine_dispense``)."""
        on, off = machine_dispense(self.dialect)
        if self.profile.dispense_on is None:
            self.profile.dispense_on = on
        if self.profile.dispense_off is None:
            self.profile.dispense_off = off
        return self


class StopOut(BaseModel):
    """The answer to an emergency stop (the machine's full record: GET /machines/{id})."""

    id: str
    state: str
    stop_sent: bool
    elapsed_ms: float = Field(description="time from the request to the stop byte written")
    position: list[float] | None = None
    program: None = None


class ProgramState(BaseModel):
    """The program on a machine: running (``printing``/``paused``: ``line`` commands of
    ``total`` acknowledged) or ``interrupted`` (stopped on a lost link or a dead process:
    ``line`` commands known processed, ``resume_line`` the command a resume starts at when
    known before reconnecting; the job ``job_id`` holds the machine until an operator
    resumes or abandons it, ``waits`` says so and ``message`` how)."""

    job_id: str | None
    line: int | None
    total: int | None
    state: Literal["printing", "paused", "interrupted"] = "printing"
    resume_line: int | None = None
    waits: str | None = Field(None, description="what the holding job waits for (\"resume or abandon\")")
    message: str | None = Field(None, description="for the operator: where it stopped and how to resume or abandon it")
    started_at: UtcDatetime | None = Field(None, description="when the running program started streaming")
    elapsed_s: float | None = Field(None, description="wall seconds since the start, pauses included")
    eta_s: float | None = Field(None, description="seconds left at the line rate so far (running seconds per "
                                "executed line times the lines left; null for the first lines); a program whose "
                                "remaining moves are slower finishes later")


class ControllerOut(BaseModel):
    """The firmware's own state (grbl): ``state`` (Idle, Run, Hold, Jog, Alarm, Door, Check,
    Home, Sleep), ``detail`` as reported (``Hold:0``), ``reason`` (the alarm, e.g. ``ALARM:5
    Probe fail...``) and ``clear``: how an operator clears a state that refuses motion."""

    state: str
    detail: str
    reason: str | None = None
    clear: str | None = None


class MachineOut(BaseModel):
    id: str
    name: str
    port: str
    baudrate: int
    dialect: str
    profile: dict[str, Any]
    mock: dict[str, Any] | None = Field(
        None, description="mock settings plus, once connected, executed_commands, executed_sha256 "
        "(API.md's commands_sha256 over what the firmware executed) and deposited_moves")
    created_at: UtcDatetime
    state: Literal["disconnected", "idle", "busy", "printing", "paused", "error"]
    homed: bool | None = Field(None, description="homed since this connection: the host's record for Marlin and "
                               "grbl (a successful Home or the home command from the console; cleared by a "
                               "reconnect, an emergency stop or an alarm), the controller's own report for "
                               "LinuxCNC; null while disconnected")
    position: list[float] | None
    program: ProgramState | None
    held_by: str | None = Field(None, description="the machine job that holds the machine (queued, running or "
                                "interrupted); Print, Home and manual control are 409 naming it until it ends")
    firmware: str | None = None
    outputs: dict[str, Any] | None = Field(
        None, description="the last time the profile's safe_off was sent (safe_off: connect, disconnect, program, "
        "emergency stop), whether it was (sent) and why not (why: e.g. a grbl in Alarm, whose reset switched its "
        "outputs off, or a Marlin emergency stop, which leaves fan outputs on until the reconnect resets it)")
    controller: ControllerOut | None = Field(
        None, description="the firmware's own state when it reports one (grbl); an Alarm, Hold, Door or "
        "Check refuses motion (409) until cleared as ``clear`` says")


class PrintRequest(Strict):
    program_id: str | None = None
    job_id: str | None = None
    artifact: str | None = Field(None, description="artifact name of job_id, e.g. print.gcode")
    dispense: DispenseProfile | None = Field(None, description="this print's dispense profile (default: the "
                                             "machine's profile.dispense)")
    material: str | None = Field(None, max_length=80, description="this print's dispense profile: a preset's "
                                 "(GET /materials)")


class ProgramOut(BaseModel):
    id: str
    name: str
    lines: int
    commands: int
    commands_sha256: str
    bounds: list[list[float]] | None
    sha256: str
    created_at: UtcDatetime


class JogRequest(BaseModel):
    """A relative move of the tool from where it is (mm); at least one axis."""

    model_config = {"extra": "forbid"}
    dx_mm: float = Field(0.0, ge=-100.0, le=100.0, allow_inf_nan=False)
    dy_mm: float = Field(0.0, ge=-100.0, le=100.0, allow_inf_nan=False)
    dz_mm: float = Field(0.0, ge=-100.0, le=100.0, allow_inf_nan=False)
    feed_mm_min: float | None = Field(None, gt=0, le=10_000, allow_inf_nan=False,
                                      description="default: the profile's travel feed")


class UnlockRequest(Strict):
    """The operator's confirmation that the machine was checked before its alarm lock is
    cleared (grbl ``$X``: the position may be wrong after an alarm; home when you can)."""

    confirm: Literal[True] = Field(description="true: I checked the machine; clear its alarm lock")


class ConsoleRequest(BaseModel):
    """One G-code or firmware command, as typed at a printer's console."""

    model_config = {"extra": "forbid"}
    command: str = Field(min_length=1, max_length=96, pattern=r"^[ -~]+$",
                         description="one line of printable ASCII (no line breaks)")


class ConsoleOut(BaseModel):
    command: str
    reply: list[str]
    machine: MachineOut


class ProbeCalibrationOut(BaseModel):
    """The current probe calibration: values mm, 1-sigma uncertainties um."""

    job_id: str
    calibrated_at: UtcDatetime
    age_h: float
    stale: bool = Field(description="older than the profile's calibration_max_age_h")
    ball_radius_mm: float
    ball_radius_std_um: float
    pretravel_mm: float = Field(description="isotropic pre-travel p0")
    pretravel_std_um: float
    lobing_cos3_mm: float = Field(description="pre-travel lobing: + sin(theta) (cos3 cos 3phi + sin3 sin 3phi)")
    lobing_cos3_std_um: float
    lobing_sin3_mm: float
    lobing_sin3_std_um: float
    sphere_centre_mm: list[float]
    pad_reading_z_mm: float | None
    residual_rms_um: float
    touches: int
    disagrees: list[str] = Field(description="what differs from the calibration before it (beyond 3 sigma + 2 um)")


class NozzleCalibrationOut(BaseModel):
    """A profile nozzle and, when calibrated, its current offset (tip = carriage + offset)."""

    tool: int
    name: str
    outer_diameter_mm: float
    nominal_offset_mm: list[float]
    calibrated: bool
    job_id: str | None = None
    calibrated_at: UtcDatetime | None = None
    age_h: float | None = None
    stale: bool | None = None
    offset_mm: list[float] | None = None
    offset_std_um: list[float] | None = None
    nominal_difference_mm: list[float] | None = Field(None, description="calibrated - nominal offset")
    probe_job_id: str | None = Field(None, description="the probe calibration this offset rests on")
    touches: int | None = None
    disagrees: list[str] | None = None


class SensorCalibrationOut(BaseModel):
    """The height sensor's stored calibration (the latest succeeded calibrate_sensor job)."""

    job_id: str | None = None
    calibrated_at: UtcDatetime | None = None
    age_h: float | None = None
    stale: bool = False
    sensor_port: str | None = None
    offset_mm: list[float] = Field(description="the spot and zero relative to the carriage [x, y, z], mm")
    scale: float
    time_offset_s: float
    slope_bias_mm: float = 0.0


class CalibrationOut(BaseModel):
    """A machine's current calibration (latest succeeded calibrate_probe / calibrate_nozzle /
    calibrate_sensor jobs)."""

    machine_id: str
    max_age_h: float
    probe: ProbeCalibrationOut | None
    nozzles: list[NozzleCalibrationOut]
    sensor: SensorCalibrationOut | None = None
    flags: list[str] = Field(description="stale calibrations, re-checks that disagree, nozzles calibrated "
                             "against an earlier probe calibration")


class MachineUpdate(Strict):
    """What an operator may change on a registered machine.  ``name`` any time; ``baudrate``
    and ``profile`` (replaced whole) only while the machine is disconnected, since the live
    connection was opened with them.  The port and dialect are the machine itself: register
    another machine for another port."""
    name: str | None = Field(None, min_length=1, max_length=200)
    baudrate: int | None = Field(None, ge=300, le=4_000_000)
    profile: Profile | None = None
    dispense: DispenseProfile | None = Field(None, description="the machine's dispense profile (profile.dispense) "
                                             "alone: any time no program holds the machine, connected or not "
                                             "(it is read when a print starts)")
    material: str | None = Field(None, max_length=80, description="set profile.dispense to this preset's "
                                 "(GET /materials: a paste or an ink)")
    clear_dispense: bool = Field(False, description="remove the machine's dispense profile")

    @model_validator(mode="after")
    def _one_dispense(self) -> MachineUpdate:
        given = [k for k in ("dispense", "material") if getattr(self, k) is not None] + (
            ["clear_dispense"] if self.clear_dispense else [])
        if len(given) > 1:
            raise ValueError(f"give at most one of dispense, material or clear_dispense (got {', '.join(given)})")
        return self


class ConsoleLine(BaseModel):
    seq: int = Field(description="1, 2, ... per machine, never repeated: pass the last one as ``after``")
    t: float = Field(description="Unix time of the line, s")
    direction: Literal["sent", "received"]
    text: str


class ConsoleLogOut(BaseModel):
    """Lines sent to and received from the machine, oldest first (the last
    ``hardware.console_log.DEFAULT_CAPACITY`` lines are kept, across reconnects)."""
    entries: list[ConsoleLine]
    last_seq: int = Field(description="pass as ``after`` to get what comes next")
    dropped: int = Field(description="lines after ``after`` that the ring no longer holds")
