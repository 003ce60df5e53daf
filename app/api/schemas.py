"""Request and response models of the HTTP API (lengths mm, angles degrees, feeds mm/min)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Generic, Literal, TypeVar

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from app.compensation.standoff import DEFAULT_STANDOFF_MM
from app.machines.materials import DispenseProfile

T = TypeVar("T")


def _as_utc(value: datetime) -> datetime:
    """SQLite returns naive datetimes; every stored time is UTC."""
    return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


UtcDatetime = Annotated[datetime, AfterValidator(_as_utc)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
# Coordinates in mm are finite and bounded (±1e6 mm = 1 km, as app.api.part_checks): beyond,
# squares and cross products overflow (±1e308 gave 500s); a 422 names the coordinate.
Coordinate = Annotated[float, Field(allow_inf_nan=False, ge=-1e6, le=1e6)]
XY = Annotated[list[Coordinate], Field(min_length=2, max_length=2)]
XYorXYZ = Annotated[list[Coordinate], Field(min_length=2, max_length=3)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Page(BaseModel, Generic[T]):
    items: list[T]
    total: int


class PartOut(BaseModel):
    id: str
    name: str
    format: str
    faces: int
    vertices: int
    bounds: list[list[float]]
    watertight: bool
    volume_mm3: float | None
    area_mm2: float
    sha256: str
    created_at: UtcDatetime
    units: str = Field("mm", description="the uploaded file's units (the part itself is always in mm)")
    frame: dict[str, Any] | None = Field(
        None, description="file -> part map: units, units_source (file|upload|default), up, rotate_deg, "
        "scale_to_mm, rotation (3x3)")
    source_sha256: str | None = Field(None, description="sha256 of the uploaded file (sha256 is the stored mesh)")
    source_format: str | None = None
    warnings: list[str] | None = Field(None, description="e.g. a size that suggests wrong units")
    defects: dict[str, Any] | None = Field(
        None, description="an open mesh's open_edges, non_manifold_edges, holes, largest_hole_mm and whether "
        "slicing's repair can close it (closable); null when watertight")


class LineGeometry(Strict):
    type: Literal["line"]
    start: XY
    end: XY


class ArcGeometry(Strict):
    type: Literal["arc"]
    center: XY
    radius: Finite = Field(gt=0, le=1e6)
    start_deg: Finite = Field(ge=-1e6, le=1e6)
    end_deg: Finite = Field(ge=-1e6, le=1e6)


class PolylineGeometry(Strict):
    type: Literal["polyline"]
    points: list[XYorXYZ] = Field(min_length=2, max_length=100_000)


class NurbsGeometry(Strict):
    type: Literal["nurbs"]
    degree: int = Field(ge=1, le=10)
    control_points: list[XYorXYZ] = Field(min_length=2, max_length=100_000)
    weights: list[Finite] | None = None
    knots: list[Finite] | None = None


Geometry = Annotated[LineGeometry | ArcGeometry | PolylineGeometry | NurbsGeometry, Field(discriminator="type")]


class TraceCreate(Strict):
    name: str = Field(min_length=1, max_length=200)
    geometry: Geometry
    frame: Literal["xy", "3d"] = "xy"
    standoff_mm: Finite = Field(DEFAULT_STANDOFF_MM, gt=0, le=50)
    width_mm: Finite | None = Field(None, gt=0, le=50)
    feed_mm_min: Finite | None = Field(None, gt=0, le=100_000)
    slope_warn_deg: Finite = Field(30.0, ge=0, le=90, description="warn when the surface under the trace is "
                                   "steeper than this for a vertical nozzle, deg")
    slope_max_deg: Finite = Field(60.0, ge=0, le=90, description="refuse the trace beyond this slope, deg "
                                  "(steeper traces need five_axis paths)")


class NominalOut(BaseModel):
    points: list[list[float]]
    normals: list[list[float]] | None = None
    slope_stretch: float | None = None
    slope: dict[str, Any] | None = Field(None, description="largest surface slope under the trace (deg), where, "
                                         "the standoff error per mm of lateral error there, and warnings")


class TraceOut(BaseModel):
    id: str
    part_id: str
    name: str
    frame: str
    geometry: dict[str, Any]
    standoff_mm: float
    width_mm: float | None
    feed_mm_min: float | None
    length_mm: float
    z_range: list[float]
    nominal: NominalOut
    created_at: UtcDatetime
    source: dict[str, Any] | None = Field(None, description="imported traces: file, layer, net, width_mm, ...")


class JobCreate(Strict):
    kind: str = Field(min_length=1, max_length=40, description="a job kind; see GET /api/v1/job-kinds")
    params: dict[str, Any] = Field(default_factory=dict, description="the kind's parameters (schema per kind)")


class ArtifactOut(BaseModel):
    name: str
    media_type: str
    bytes: int
    sha256: str
    url: str
    meta: dict[str, Any] = Field(default_factory=dict)


class ResumeRequest(Strict):
    confirm: bool = Field(description="true: the operator knows the machine will re-home and move")


class JobOut(BaseModel):
    id: str
    kind: str
    status: Literal["queued", "running", "succeeded", "needs_attention", "failed", "cancelled", "interrupted",
                    "waiting"]
    progress: float
    message: str
    params: dict[str, Any] = Field(description=(
        "the parameters; when over 16 KiB of JSON their long lists and objects (a board's trace_ids) "
        "are left out unless asked for with ?include=params (params_omitted names them)"))
    params_omitted: dict[str, int] | None = Field(None, description=(
        "the parameters left out of params (name -> the value's length); null when none is"))
    parent_id: str | None
    attempts: int
    earlier_attempts: list[dict[str, Any]] | None = Field(None, description=(
        "the attempts that ended without finishing and were queued again, oldest first: attempt, "
        "ended_at, reason (e.g. its worker stopped reporting); null when the job ran once"))
    cancel_requested: bool
    created_at: UtcDatetime
    started_at: UtcDatetime | None
    finished_at: UtcDatetime | None
    error: dict[str, Any] | None
    result: dict[str, Any] | None = Field(description=(
        "the result; null while unfinished, and when larger than 16 KiB of JSON unless asked for "
        "with ?include=result (then result_omitted is true)"))
    result_omitted: bool = Field(False, description="the result exists but is not inlined (ask ?include=result)")
    result_bytes: int | None = Field(None, description="size of the whole result as JSON, bytes")
    result_summary: dict[str, Any] | None = Field(None, description=(
        "when the result is omitted: its top-level scalars, the kind's summary fields and <list>_count "
        "(the length of each top-level list)"))
    input_hashes: dict[str, str] = Field(description=(
        "what the job was made from (part:<id>, trace:<id> ... -> sha256); more than 100 (a board's traces) "
        "are left out unless asked for with ?include=input_hashes (input_hashes_omitted counts them)"))
    input_hashes_omitted: int | None = Field(None, description="how many input hashes were left out; null when none")
    software_version: str
    artifacts: list[ArtifactOut] = Field(description=(
        "the artifacts the job wrote, in order: the first 20 unless asked for with ?include=artifacts"))
    artifact_count: int = Field(0, description="how many artifacts the job wrote")
    title: str | None = Field(None, description="in lists: the job's name for people, part · trace (or net) · "
                              "what it is, e.g. \"dome · GND · circuit program\"")
    program_state: dict[str, Any] | None = Field(
        None, description="machine jobs: commands executed (known) and total, last acknowledged firmware line, "
        "and once interrupted: when, why, the position if known; resumes and the resume preamble. closed_loop: "
        "``waiting`` (the pause point it waits at: at, key, round, since, summary, needs_attention), ``passed`` "
        "(the pause points an operator continued), ``accepted``, ``replans`` (stations added on request)")


class JobKindOut(BaseModel):
    name: str
    queue: str
    description: str
    params_schema: dict[str, Any]


class MaterialOut(BaseModel):
    """A material preset (:mod:`app.machines.materials`): the job parameters a form fills in for it and,
    for what a dispenser deposits, its dispense profile."""

    name: str
    label: str
    kind: Literal["conductive", "dielectric", "substrate"]
    description: str
    params: dict[str, Any] = Field(description="job parameters by name (e.g. mode, line_width_mm, nozzle_temp_c): "
                                   "a form sets those it has")
    dispense: DispenseProfile | None = Field(description="for pastes and inks: what a machine's profile.dispense "
                                             "takes; none for a substrate's plastic")
    default: bool = Field(description="the preset the console's forms start from")


class KeyCreate(Strict):
    role: Literal["viewer", "operator", "admin"]
    name: str = Field("", max_length=200)


class KeyOut(BaseModel):
    id: str
    name: str
    role: str
    prefix: str
    created_at: UtcDatetime
    revoked_at: UtcDatetime | None


class KeyCreated(KeyOut):
    key: str = Field(description="shown once; only its hash is stored")
