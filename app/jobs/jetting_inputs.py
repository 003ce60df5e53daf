"""The jetting kinds' shared inputs: the print-model parameters, the target and stored
height maps, and the core's errors named as API parameters (``jetting`` and
``jetting_next_layer`` both use them; a kind never imports another kind).

Parameters are named once: the API's flat print-model parameters carry the names of the
core's ``DropParams`` / ``FlowParams`` / ``ControllerParams`` fields (the core objects are
built from them by name), so a core error ``drop.dpi`` names ``params.dpi`` and ``target.X``
names ``params.target.X`` by one rule (:func:`api_field`), without a rename table.
"""

from __future__ import annotations

import base64
import binascii
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from app.jetting import (
    ControllerParams,
    DropParams,
    FlowParams,
    JettingError,
    JettingParams,
    Target,
    TargetSpec,
    estimate_bytes,
    target_from_png,
    target_from_rings,
    target_from_spec,
)
from app.jetting.params import BinarizeKind, LayerModelKind, SolverKind
from app.jetting.targets import rings_grid_cells, target_shape
from app.jobs.core_fields import core_field, core_values
from app.jobs.results.models import SliceResult
from app.platform.models import Artifact
from app.runtime.registry import JobParams
from app.slicing import SlicingError
from app.slicing.export import from_json

if TYPE_CHECKING:
    from app.runtime.reads import JobReads

MEMORY_LIMIT_BYTES = 2 * 1024**3  # one run's working set (patterns, snapshots, solver temporaries)
MAX_MASK_BASE64 = 4_000_000       # inline mask PNG, base64 characters
NPZ_MEDIA_TYPE = "application/zip"  # an NPZ is a zip of .npy members (numpy.load reads it)
FLAT_GROUPS = ("drop", "flow", "plant", "controller")  # the core's parameter groups, flat in the API
# core fields the API does not expose (the core's defaults): DropParams.supersample, the slope
# response of the flow, and the controller's kind (``controller`` of the jetting kind; next-layer is MPC)
CORE_ONLY = frozenset({"supersample", "slope_lambda_rad", "slope_gain", "kind"})
_T = TargetSpec()


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid")


class MaskSource(StrictModel):
    """A part mask image: one pixel per print cell at ``dpi``, luminance >= 128 is part."""

    job_id: str | None = Field(None, description="a succeeded job holding the PNG as an artifact")
    artifact: str | None = Field(None, min_length=1, max_length=200,
                                 description="that job's artifact name, e.g. pattern_0001.png")
    png_base64: str | None = Field(None, max_length=MAX_MASK_BASE64,
                                   description="or the PNG itself, base64 (no data: prefix)")

    @model_validator(mode="after")
    def _one_source(self) -> MaskSource:
        if (self.job_id is None) != (self.artifact is None) or (self.job_id is None) == (self.png_base64 is None):
            raise ValueError("give either job_id and artifact, or png_base64")
        return self


class SliceSource(StrictModel):
    """One layer of a slice job's ``layers.json`` (its contours; holes are inner rings)."""

    slice_job_id: str = Field(description="a succeeded slice job")
    layer: int = Field(0, ge=0, le=1_000_000, description="layer index in that job's layers")


class TargetParams(StrictModel):
    """The part to print: the seed's parametric square with a centred square hole
    (default), or a mask image, or a slice layer (give at most one of mask / slice)."""

    shape: Literal["square_with_hole"] | None = Field(None, description="parametric shape (the default)")
    size_mm: float | None = Field(None, gt=0, le=500, allow_inf_nan=False,
                                  description=f"square side, mm (default {_T.size_mm:g})")
    hole_mm: float | None = Field(None, ge=0, le=500, allow_inf_nan=False,
                                  description=f"hole side, mm (default {_T.hole_mm:g}; 0: no hole)")
    mask: MaskSource | None = Field(None, description="part mask image instead of the square")
    slice: SliceSource | None = Field(None, description="slice layer instead of the square")

    @model_validator(mode="after")
    def _one_kind(self) -> TargetParams:
        parametric = [name for name in ("shape", "size_mm", "hole_mm") if getattr(self, name) is not None]
        if self.mask is not None and self.slice is not None:
            raise ValueError("give mask or slice, not both")
        if (self.mask is not None or self.slice is not None) and parametric:
            raise ValueError(f"{parametric} describe the parametric square; not with mask or slice")
        spec = self.spec()
        if spec.hole_mm >= spec.size_mm:
            raise ValueError("hole_mm must be smaller than size_mm")
        return self

    def spec(self) -> TargetSpec:
        """The parametric square with the defaults filled in."""
        return TargetSpec(shape=self.shape or _T.shape, size_mm=_T.size_mm if self.size_mm is None else self.size_mm,
                          hole_mm=_T.hole_mm if self.hole_mm is None else self.hole_mm)


class PrintModelParams(JobParams):
    """The print grid, droplet, threshold flow and MPC settings (shared by both jetting kinds)."""

    target: TargetParams = Field(default_factory=TargetParams, description="the part to print")
    dpi: float = core_field(DropParams, "dpi", allow_inf_nan=False, description="print resolution, dots per inch")
    drop_diameter_um: float = core_field(DropParams, "drop_diameter_um", allow_inf_nan=False,
                                         description="spread (landed) droplet diameter, um")
    drop_volume_pl: float = core_field(DropParams, "drop_volume_pl", allow_inf_nan=False,
                                       description="nominal droplet volume, pL")
    margin_mm: float = Field(0.25, ge=0, le=10, allow_inf_nan=False, description="empty border around the part, mm")
    threshold_um: float = core_field(
        FlowParams, "threshold_um", allow_inf_nan=False,
        description="threshold flow: ink flows between neighbours only above this step, um")
    mobility: float = core_field(FlowParams, "mobility", allow_inf_nan=False,
                                 description="flow mobility (2/pi) eta_s on a flat substrate, 0..1")
    flow_steps: int = core_field(FlowParams, "flow_steps", description="flow sub-steps per layer before cure")
    horizon: int = core_field(ControllerParams, "horizon", description="MPC horizon m, layers")
    q_weight: float = core_field(ControllerParams, "q_weight", allow_inf_nan=False, description="MPC stage weight Q")
    r_weight: float = core_field(ControllerParams, "r_weight", allow_inf_nan=False, description="MPC input weight R")
    f_weight: float = core_field(ControllerParams, "f_weight", allow_inf_nan=False,
                                 description="MPC terminal weight F")
    outside_weight: float = core_field(ControllerParams, "outside_weight", allow_inf_nan=False,
                                       description="weight of cells off the part relative to part cells")
    fill: float = core_field(ControllerParams, "fill", allow_inf_nan=False,
                             description="MPC reference rise per layer in nominal layer heights")
    edge_lead: float = core_field(ControllerParams, "edge_lead", allow_inf_nan=False,
                                  description="MPC reference lead on the part's edge cells, nominal layer heights "
                                  "(tapering to 0 over edge_rings; 0: the published flat reference)")
    edge_rings: int = core_field(ControllerParams, "edge_rings",
                                 description="cells from the part's edge the lead covers")
    model: LayerModelKind = core_field(
        ControllerParams, "model",
        description="seed_diagonal: the seed's (I + Dg) B; transport: mass-conserving flow operator")
    solver: SolverKind = core_field(ControllerParams, "solver", description="fista (fast) or lbfgsb (reference)")
    binarize: BinarizeKind = core_field(
        ControllerParams, "binarize",
        description="relaxed -> 0/1 drops: greedy flips on the model's QP, threshold, error diffusion")
    max_iter: int = core_field(ControllerParams, "max_iter", description="solver iteration cap per layer")
    tol: float = core_field(ControllerParams, "tol", allow_inf_nan=False, description="solver tolerance (relative)")
    greedy_rounds: int = core_field(ControllerParams, "greedy_rounds", description="greedy flip sweeps")

    def named(self, core: type[Any], **given: Any) -> dict[str, Any]:
        """This model's values of the ``core`` dataclass's fields, by the same names (the
        ``CORE_ONLY`` ones the core's defaults), then ``given``."""
        return core_values(core, self, CORE_ONLY, **given)

    def drop(self) -> DropParams:
        return DropParams(**self.named(DropParams))

    def flow(self) -> FlowParams:
        return FlowParams(**self.named(FlowParams))

    def controller_params(self, kind: str = "mpc") -> ControllerParams:
        return ControllerParams(**self.named(ControllerParams, kind=kind))

    def core(self) -> JettingParams:
        """The pure core's parameters (``layers`` 1: the next-layer kind plans one layer)."""
        return JettingParams(drop=self.drop(), flow=self.flow(), controller=self.controller_params(),
                             target=self.target_spec(), layers=1, margin_mm=self.margin_mm,
                             memory_limit_bytes=MEMORY_LIMIT_BYTES)

    def target_spec(self) -> TargetSpec:
        return self.target.spec()


# errors and limits ---------------------------------------------------------------------
def api_field(field: str | None) -> str:
    """The API parameter a core error field names: a field of a flat group by its own name
    (``drop.dpi`` -> ``params.dpi``), anything else under ``params`` (``target.mask`` ->
    ``params.target.mask``, ``measured`` -> ``params.measured``)."""
    if not field:
        return "params"
    if field.startswith("params"):
        return field
    head, _, rest = field.partition(".")
    return f"params.{rest}" if rest and head in FLAT_GROUPS else f"params.{field}"


@contextmanager
def core_errors() -> Iterator[None]:
    """Re-raise the core's JettingError / SlicingError naming the API parameter."""
    try:
        yield
    except (JettingError, SlicingError) as exc:
        field = api_field(exc.field)
        message = exc.message if exc.message.startswith(field) else f"{field}: {exc.message}"
        raise JettingError(message, field=field, value=exc.value) from None


def max_cells(core: JettingParams) -> int:
    """The largest grid the memory limit allows (checked before a grid is allocated)."""
    return max(1, core.memory_limit_bytes // estimate_bytes((1, 1), core))


def check_grid(shape: tuple[int, int], core: JettingParams) -> None:
    """422 naming ``params.dpi`` when a grid of ``shape`` needs more than the memory limit."""
    need = estimate_bytes(shape, core)
    if need > core.memory_limit_bytes:
        raise JettingError(f"params.dpi: a {shape[0]} x {shape[1]} grid at {core.drop.dpi:g} dpi for "
                           f"{core.layers} layers needs ~{need / 2**20:.0f} MiB, over the "
                           f"{core.memory_limit_bytes / 2**20:.0f} MiB limit", field="params.dpi",
                           value=core.drop.dpi)


def _mask_bytes(source: MaskSource) -> bytes:
    try:
        return base64.b64decode(source.png_base64 or "", validate=True)
    except (binascii.Error, ValueError) as exc:
        raise JettingError(f"params.target.mask.png_base64: not base64 ({exc})",
                           field="params.target.mask.png_base64", value=len(source.png_base64 or "")) from None


# targets ---------------------------------------------------------------------------------
ArtifactReader = Callable[[str, str], bytes]  # (job_id, artifact name) -> bytes


def target_of(spec: TargetParams, core: JettingParams, read: ArtifactReader) -> Target:
    """The print target on its grid; ``read(job_id, name)`` returns an artifact's bytes."""
    limit = max_cells(core)
    with core_errors():
        if spec.mask is not None:
            data = _mask_bytes(spec.mask) if spec.mask.png_base64 is not None else \
                read(spec.mask.job_id or "", spec.mask.artifact or "")
            target = target_from_png(data, core.drop, core.margin_mm, limit)
        elif spec.slice is not None:
            layers = _slice_layers(read(spec.slice.slice_job_id, "layers.json"))
            if spec.slice.layer >= len(layers):
                raise JettingError(f"layer {spec.slice.layer} does not exist ({len(layers)} layers)",
                                   field="params.target.slice.layer", value=spec.slice.layer)
            rings = [ring for island in layers[spec.slice.layer].islands for ring in island.rings()]
            target = target_from_rings(rings, core.drop, core.margin_mm, limit, field="target.slice")
        else:
            target = target_from_spec(core.target, core.drop, core.margin_mm, limit)
    check_grid(target.shape, core)
    return target


def _slice_layers(data: bytes) -> list[Any]:
    """The layers of a slice job's stored ``layers.json``; a file that does not read is the
    slice the target names (``params.target.slice``)."""
    try:
        return list(from_json(data).layers)
    except SlicingError as exc:
        raise JettingError(f"the slice's layers.json: {exc.message}", field="params.target.slice",
                           value=exc.value) from None


def stored_artifact(reads: JobReads, job_id: str, name: str, field: str, media_type: str) -> Artifact:
    """The artifact row of a succeeded job with the expected media type, or a 422 naming ``field``."""
    reads.succeeded_job(job_id, None, field, error=JettingError, missing_is_invalid=True)
    row = reads.artifact(job_id, name)
    if row is None or row.media_type != media_type or row.bytes == 0:
        what = "does not exist" if row is None else f"is an empty or {row.media_type} file"
        raise JettingError(f"{field}: artifact {name!r} of job {job_id!r} {what}; a {media_type} is needed",
                           field=field, value=name)
    return row


def check_target(spec: TargetParams, core: JettingParams, reads: JobReads) -> tuple[int, int] | None:
    """Submission-time checks of the target: the grid's memory need, the mask artifact's
    type and part cells, the slice layer's existence and the sliced part's extent; when the
    reads can read stored files (as they can at submission), the target is built and fully
    validated now.  Returns the grid shape when it is known."""
    reader = _stored_reader(reads)
    if spec.mask is not None and spec.mask.job_id is not None:
        row = stored_artifact(reads, spec.mask.job_id, spec.mask.artifact or "", "params.target.mask", "image/png")
        if row.meta.get("drops") == 0:
            raise JettingError("params.target.mask: the mask image is all black (no part cells)",
                               field="params.target.mask", value=spec.mask.artifact)
        if "shape" in row.meta:  # the image bounds the part's box: the core's padding around it
            image = (int(row.meta["shape"][0]), int(row.meta["shape"][1]))
            check_grid(target_shape(image, core.drop, core.margin_mm), core)
        return target_of(spec, core, reader).shape if reader is not None else None
    if spec.slice is not None:
        job = reads.succeeded_job(spec.slice.slice_job_id, "slice", "params.target.slice.slice_job_id",
                                  error=JettingError, missing_is_invalid=True)
        count = SliceResult.of(job).layer_count
        if spec.slice.layer >= count:
            raise JettingError(f"params.target.slice.layer: layer {spec.slice.layer} does not exist "
                               f"({count} layers)", field="params.target.slice.layer", value=spec.slice.layer)
        part = reads.find_part(job.params.get("part_id", ""))
        if part is not None:
            # a layer lies within the part's footprint: the core's grid of that footprint bounds it
            extent = np.ptp(np.asarray(part.bounds, dtype=float)[:, :2], axis=0)
            nx, ny = rings_grid_cells((float(extent[0]), float(extent[1])), core.drop.pitch_mm)
            check_grid(target_shape((ny, nx), core.drop, core.margin_mm), core)
        return target_of(spec, core, reader).shape if reader is not None else None
    return target_of(spec, core, _no_reader).shape  # parametric or inline mask: built now


def _stored_reader(reads: JobReads) -> ArtifactReader | None:
    """Reads a stored artifact's bytes during a submission check (the runtime gives the
    reads a blob reader), so stored masks and slices are fully checked up front."""
    read_blob = reads.read_blob
    if read_blob is None:
        return None

    def read(job_id: str, name: str) -> bytes:
        row = reads.artifact(job_id, name)
        if row is None:
            raise JettingError(f"artifact {name!r} of job {job_id!r} does not exist", field="params.target",
                               value=name)
        return read_blob(row.sha256)

    return read


def _no_reader(job_id: str, name: str) -> bytes:  # parametric and inline targets read no artifacts
    raise AssertionError(f"unexpected read of {job_id}/{name}")


def target_references(spec: TargetParams) -> list[tuple[str, str]]:
    if spec.mask is not None and spec.mask.job_id is not None:
        return [("job", spec.mask.job_id)]
    if spec.slice is not None:
        return [("job", spec.slice.slice_job_id)]
    return []


def npz_meta(**shapes: object) -> dict:
    return {"format": "npz", "arrays": shapes}
