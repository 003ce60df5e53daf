"""Job ``surface_fit``: a NURBS surface of a region of a part (the EHD patent, step 1).

Where the heights come from:

* ``points`` (JSON ``[[x, y, z], ...]``) or ``points_csv`` (CSV text, one ``x, y, z`` per
  line): CMM measurements, fitted as given (least squares over x, y) or, with
  ``resample_to_grid``, resampled onto the ``grid`` first (densification);
* neither: the planned probing grid is sampled from the part mesh's top surface (the
  nominal part: vertical rays).  Probing the grid on a machine (``machine_id``) comes with
  the hardware issue; until then measured heights arrive as ``points``.

Preprocessing and fit are :func:`app.reconstruction.surface_fit.fit_surface` (bad points,
holes, densification, smoothing, interpolating or least-squares NURBS).  The result's
``surface`` is the "real surface" a ``five_axis`` job uses via ``surface_fit_job_id``; the
same surface is stored as the artifact ``surface.json``.  Units: mm.
"""

from __future__ import annotations

import json
import math
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from app.jobs.core_fields import core_field, core_values
from app.jobs.results.models import SurfaceFitResult
from app.probing.grid import ProbeRegion, plan_probe_grid
from app.reconstruction.surface_fit import (
    GridHoleError,
    SurfaceFitError,
    SurfaceFitParams,
    fit_surface,
    grid_from_plan,
    sample_nominal_grid,
)
from app.reconstruction.surface_fit.fit import FitMethod, HolePolicy, Smoothing
from app.reconstruction.surface_fit.points import check_points, parse_points_csv
from app.reconstruction.surface_fit.work import work_estimate
from app.runtime.context import JobContext
from app.runtime.cost import Cost
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

MAX_POINTS = 100_000
MAX_GRID = 200

Finite = Annotated[float, Field(allow_inf_nan=False)]
Interval = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Point = Annotated[list[Finite], Field(min_length=3, max_length=3)]


class Region(BaseModel):
    """Axis-aligned rectangle of the part, seen from above (mm)."""

    model_config = ConfigDict(extra="forbid")
    x: Interval = Field(description="[x0, x1] mm with x0 < x1")
    y: Interval = Field(description="[y0, y1] mm with y0 < y1")

    @model_validator(mode="after")
    def _ordered(self) -> Region:
        if not (self.x[0] < self.x[1] and self.y[0] < self.y[1]):
            raise ValueError("region needs x0 < x1 and y0 < y1")
        return self

    def probe_region(self) -> ProbeRegion:
        return ProbeRegion(self.x[0], self.x[1], self.y[0], self.y[1])


class SurfaceFitJobParams(JobParams):
    part_id: str = Field(description="the part whose region is measured")
    region: Region = Field(description="where to probe: {x: [x0, x1], y: [y0, y1]} mm")
    grid: list[Annotated[int, Field(ge=2, le=MAX_GRID)]] = Field(
        [20, 20], min_length=2, max_length=2,
        description="probing grid [nu, nv]: nu lines along x (surface u), nv along y (v)")
    points: list[Point] | None = Field(
        None, min_length=1, max_length=MAX_POINTS,
        description="CMM points [[x, y, z], ...] mm; without points (or points_csv) the grid is "
        "sampled from the part's nominal top surface (machine probing comes with the hardware issue)")
    points_csv: str | None = Field(
        None, max_length=8_000_000,
        description="CMM points as CSV text, one 'x, y, z' per line (mm); instead of points")
    method: FitMethod = core_field(
        SurfaceFitParams, "method", description="least_squares: smoothing NURBS fit (control net by GCV unless "
        "control_points); interpolate: through every (preprocessed) grid point")
    degree: int = core_field(SurfaceFitParams, "degree", description="degree in u and v")
    control_points: list[Annotated[int, Field(ge=2, le=MAX_GRID * 8)]] | None = Field(
        None, min_length=2, max_length=2, description="least-squares control net [n_u, n_v]; default: GCV")
    penalty: float = core_field(SurfaceFitParams, "penalty",
                                description="second-difference smoothing weight (least squares)")
    smoothing: Smoothing = core_field(SurfaceFitParams, "smoothing",
                                      description="grid smoothing of the patent's preprocessing")
    moving_average_window: int = core_field(SurfaceFitParams, "moving_average_window",
                                            description="odd window of the moving average")
    smoothing_passes: int = core_field(SurfaceFitParams, "smoothing_passes",
                                       description="how often the smoothing is applied")
    remove_bad_points: bool = core_field(SurfaceFitParams, "remove_bad_points",
                                         description="remove outliers before fitting (reported)")
    bad_point_sigma: float = core_field(SurfaceFitParams, "bad_point_sigma",
                                        description="outlier threshold in robust sigmas")
    bad_point_min_mm: float = core_field(SurfaceFitParams, "bad_point_min_mm",
                                         description="never call a point bad below this residual")
    hole_policy: HolePolicy = core_field(
        SurfaceFitParams, "hole_policy", description="missing grid heights (a probe that failed, a grid point off "
        "the part): error, or fill by interpolation")
    densify_factor: int = core_field(SurfaceFitParams, "densify_factor",
                                     description="grid refinement factor before smoothing and fit")
    resample_to_grid: bool = Field(False, description="points: resample onto the grid before the fit")

    @field_validator("moving_average_window")
    @classmethod
    def _odd(cls, value: int) -> int:
        if value % 2 == 0:
            raise ValueError("the moving-average window must be odd")
        return value

    @field_validator("points_csv")
    @classmethod
    def _parses(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                parse_points_csv(value, MAX_POINTS)
            except SurfaceFitError as exc:  # pydantic names the field: 422 at params.points_csv
                raise ValueError(exc.message) from None
        return value

    @model_validator(mode="after")
    def _one_source(self) -> SurfaceFitJobParams:
        if self.points is not None and self.points_csv is not None:
            raise ValueError("give points or points_csv, not both")
        return self

    def measured_points(self) -> np.ndarray | None:
        """The CMM points (k, 3) mm, or None when the nominal grid is to be sampled."""
        if self.points is not None:
            return np.asarray(self.points, dtype=float)
        if self.points_csv is not None:
            return parse_points_csv(self.points_csv, MAX_POINTS)
        return None

    @property
    def points_field(self) -> str:
        return "params.points_csv" if self.points_csv is not None else "params.points"

    def fit_params(self) -> SurfaceFitParams:
        """The core's parameters (raises SurfaceFitError naming params.<field>)."""
        resample = (self.grid[0], self.grid[1]) if self.resample_to_grid and self.has_points else None
        return SurfaceFitParams(**core_values(SurfaceFitParams, self, resample_shape=resample))

    @property
    def has_points(self) -> bool:
        return self.points is not None or self.points_csv is not None


def _check(params: SurfaceFitJobParams, reads: JobReads) -> None:
    """Content checks at submission: region over the part, grid and net sizes, point count."""
    part = reads.part(params.part_id, field="params.part_id")
    fit = params.fit_params()
    (x_lo, y_lo, _), (x_hi, y_hi, _) = part.bounds
    if not params.has_points and (params.region.x[0] < x_lo or params.region.x[1] > x_hi
                                  or params.region.y[0] < y_lo or params.region.y[1] > y_hi):
        raise SurfaceFitError(
            f"params.region {params.region.model_dump()} reaches beyond the part's footprint "
            f"x [{x_lo:g}, {x_hi:g}], y [{y_lo:g}, {y_hi:g}] mm", field="params.region",
            value=params.region.model_dump())
    grid_fitted = not params.has_points or params.resample_to_grid
    if grid_fitted and min(params.grid) < fit.degree + 1:
        raise SurfaceFitError(f"params.grid {params.grid}: a degree-{fit.degree} fit needs at least "
                              f"{fit.degree + 1} points per direction", field="params.grid", value=params.grid)
    points = params.measured_points()
    if points is not None:
        try:
            check_points(points, fit)
        except SurfaceFitError as exc:
            raise _in_params(exc, params) from None
    if fit.control_points is None or fit.method != "least_squares":
        return
    if grid_fitted:
        dense = [(n - 1) * fit.densify_factor + 1 for n in params.grid]
        if fit.control_points[0] > dense[0] or fit.control_points[1] > dense[1]:
            raise SurfaceFitError(f"params.control_points {list(fit.control_points)} exceed the fitted "
                                  f"grid {dense}", field="params.control_points", value=list(fit.control_points))
    elif points is not None and math.prod(fit.control_points) > points.shape[0]:
        raise SurfaceFitError(f"params.control_points {list(fit.control_points)} need more than the "
                              f"{points.shape[0]} points given", field="params.control_points",
                              value=list(fit.control_points))


def _in_params(exc: SurfaceFitError, params: SurfaceFitJobParams) -> SurfaceFitError:
    """The core's error with its field named as the job parameter it comes from."""
    message, field = exc.message, exc.field
    if params.has_points and field == "points":
        field = params.points_field
    elif not params.has_points and isinstance(exc, GridHoleError):
        message = f"the part's top surface is missing under some grid points of params.region: {message}"
        field = "params.region"
    elif not params.has_points and field == "grid.z":  # e.g. the heights found lie on one line
        message, field = f"the part's top sampled over params.region: {message}", "params.region"
    return type(exc)(message, field=field, value=exc.value)


def _json_z(values: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in values]


# Cost model (MiB, s), calibrated on a 2-core machine (tests/bench/test_bench_compute_limits.py).
# The peak is the base, the fitted points (design rows, grids, ~2 KiB each) and the largest of
# the stages, which run one after the other:
# * the bad-point test: per 600-point k-d-tree tile, ~20 MiB whatever the count, ~2.5 ms per
#   point on a loaded 2-core machine (40,000 points: 40-98 s);
# * the least-squares solve: a grid without penalty separates by direction (two 1-D banded
#   solves: memory O(grid), 0.05 s at 200 x 200 / net 200 x 200, where the old 40,000-unknown
#   sparse solve peaked at 468 MiB / 61 s); a penalty or scattered points need the banded
#   normal equations: 8 (w + 1) N bytes for N unknowns of bandwidth w = degree min(n_u, n_v)
#   (+ degree), N w^2 flops (200 x 200 net: 193 MiB band, 231 MiB measured, 10-17 s);
# * the residuals: the surface inversion samples the surface 2 degree times per knot span in
#   each direction (~100 bytes per sample: 128 MiB at a 200 x 200 net) and runs Newton per
#   measured point (~0.2 ms each);
# * the GCV net search (no control_points) repeats the fit for every net size up to about
#   sqrt(points / 3) per direction.
POINT_MB = 2 / 1024
BAD_POINT_MB = 20.0
BAD_POINT_S = 2.5e-3
SAMPLE_MB = 100 / 2**20
NEWTON_S = 2.5e-4
EVAL_S = 5e-6  # per fitted point and net tried by the GCV search (evaluation, residuals)
FLOP_S = 4e-9  # banded Cholesky (58 s for 1.5e10 flops on a loaded 2-core machine)
BAND_OVERHEAD = 1.25  # the band plus the right-hand sides and the design while it is built
BASE_MB = 100.0  # interpreter, numpy/scipy buffers and BLAS arenas of a fresh process


def _net_cost(net: tuple[float, float], degree: int, separable: bool) -> tuple[float, float, float]:
    """(solve MiB, solve s, inversion MiB) of one fit with a net (n_u, n_v): the core's
    :func:`~app.reconstruction.surface_fit.work.work_estimate` at this machine's rates."""
    work = work_estimate(net, degree, separable)
    return BAND_OVERHEAD * work.band_bytes / 2**20, FLOP_S * work.flops, SAMPLE_MB * work.inversion_samples


def _estimate(params: SurfaceFitJobParams, reads: JobReads) -> Cost:
    """Predicted peak memory and time of the fit (see the model above), naming the parameter
    that drives it: the grid, the point count, the densification or the control net."""
    measured = (len(params.points) if params.points is not None
                else params.points_csv.count("\n") + 1 if params.points_csv is not None
                else params.grid[0] * params.grid[1])
    grid_fitted = not params.has_points or params.resample_to_grid
    shape = ([(n - 1) * params.densify_factor + 1 for n in params.grid] if grid_fitted
             else [math.isqrt(measured)] * 2)
    fitted = math.prod(shape) if grid_fitted else measured
    separable = grid_fitted and params.penalty == 0
    searched = 0
    if params.method == "interpolate":
        net: tuple[float, float] = (shape[0], shape[1])
        separable = True
    elif params.control_points is not None:
        net = (params.control_points[0], params.control_points[1])
    else:  # GCV: nets of the data's aspect up to fitted / 3 unknowns, each a full fit
        side = math.sqrt(fitted / 3 / max(shape[0] * shape[1], 1))
        net = (max(shape[0] * side, 1.0), max(shape[1] * side, 1.0))
        searched = int(max(net))
    solve_mb, solve_s, inversion_mb = _net_cost(net, params.degree, separable)
    if searched:  # sum over the nets tried: N w^2 grows as m^4, so ~ m / 5 times the last
        solve_s = solve_s * searched / 5 + EVAL_S * fitted * searched
    point_mb = POINT_MB * fitted
    bad_mb = BAD_POINT_MB if params.remove_bad_points else 0.0
    terms = {  # field -> (memory, time) it brings
        params.points_field if params.has_points else "params.grid": (
            POINT_MB * measured + bad_mb, (BAD_POINT_S if params.remove_bad_points else 0.0) * measured
            + NEWTON_S * measured),
        "params.densify_factor": (point_mb - POINT_MB * measured if grid_fitted else 0.0, 0.0),
        "params.control_points": (max(solve_mb, inversion_mb), solve_s),
    }
    field = max(terms, key=lambda f: terms[f])
    if field == "params.control_points" and params.control_points is None:  # the searched nets grow with
        field = "params.densify_factor" if grid_fitted and params.densify_factor > 1 else "params.grid"  # the data
    value = {"params.grid": params.grid, "params.densify_factor": params.densify_factor,
             "params.control_points": params.control_points}.get(field, measured)
    memory = BASE_MB + point_mb + max(solve_mb, inversion_mb, bad_mb)
    seconds = sum(t for _, t in terms.values())
    unknowns = int(net[0] * net[1])
    return Cost(memory_mb=memory, time_s=seconds, field=field, value=value,
                basis=f"{measured} measured points, {fitted} fitted, {unknowns} unknowns"
                + ("" if separable else ", banded normal equations"))


@job_kind("surface_fit", SurfaceFitJobParams, references=lambda p: [("part", p.part_id)], check=_check,
          estimate=_estimate)
def run(ctx: JobContext, params: SurfaceFitJobParams) -> dict:
    """Fit a NURBS surface to measured points or the sampled nominal grid of a part region."""
    mesh = ctx.mesh(params.part_id)
    plan = plan_probe_grid(params.region.probe_region(), params.grid[0], params.grid[1])
    nominal_z = sample_nominal_grid(mesh, plan)
    ctx.progress(0.2, f"probing grid {params.grid[0]} x {params.grid[1]} planned")
    points = params.measured_points()
    data: Any = grid_from_plan(plan, nominal_z) if points is None else points
    try:
        fit = fit_surface(data, params.fit_params())
    except SurfaceFitError as exc:
        raise _in_params(exc, params) from None
    ctx.progress(0.8, f"fitted: residual max {fit.residual_max_mm:.4g} mm")
    surface = fit.surface.to_dict()
    ctx.artifact("surface.json", json.dumps(surface, sort_keys=True).encode(), "application/json",
                 {"degree_u": fit.surface.degree_u, "degree_v": fit.surface.degree_v,
                  "control_points": list(fit.control_points)})
    return SurfaceFitResult.written({
        "source": "nominal_grid" if points is None else "points",
        "surface": surface,
        "residual": {"max_mm": fit.residual_max_mm, "rms_mm": fit.residual_rms_mm,
                     "points": int(fit.residuals_mm.size)},
        "probe_grid": {
            "shape": list(params.grid), "x": plan.x.tolist(), "y": plan.y.tolist(),
            "index": plan.index.tolist(),
            "points": [[float(x), float(y), z] for (x, y), z in zip(plan.points_xy, _json_z(nominal_z))],
        },
        "removed_points": fit.removed_points.tolist(),
        "filled_holes": fit.filled_holes,
        "method": fit.method,
        "smoothing": fit.smoothing,
        "control_net": list(fit.control_points),
        "region": params.region.model_dump(),
    })
