"""A kind's parameters composed from the core's dataclasses: the schema shows the core's
defaults and bounds, a value outside them is a 422 naming the field, and the core's object is
built from the job's parameters by name."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import pytest
from annotated_types import Ge, Gt, Le, Lt
from pydantic import BaseModel, ValidationError

from app.compensation.standoff import CompensationError, CompensationParams
from app.five_axis import FiveAxisParams
from app.gcode.estimator import MachineLimits
from app.gcode.fdm import FdmParams
from app.gcode.writer import GcodeError
from app.jobs.core_fields import core_bounds, core_field, core_values
from app.jobs.kinds.toolpath import ToolpathJobParams
from app.jobs.params import ProbePlanParams, RegisterParams
from app.probing import PlanParams
from app.probing.program import ProbeProgramParams
from app.reconstruction.surface_fit import SurfaceFitError, SurfaceFitParams
from app.registration.datum_plan import DatumProbeParams
from app.registration.registration import RegistrationError
from app.slicing import SliceParams, SlicingError, ToolpathParams
from app.slicing.fractal import MergeWeights
from tests.conftest import auth
from tests.helpers.jobs import submit


@dataclass(frozen=True)
class Core:
    width_mm: Annotated[float, Gt(0), Le(5)] = 1.5
    count: Annotated[int, Ge(2)] | None = None
    ratio: Annotated[float, Gt(0), Lt(1)] = 0.5
    name: str = "core"


class Model(BaseModel):
    width_mm: float = core_field(Core, "width_mm", description="the model's words")
    count: int | None = core_field(Core, "count")
    name: str = core_field(Core, "name")


def test_a_field_takes_the_cores_default_and_bounds():
    assert core_bounds(Core, "width_mm") == {"gt": 0, "le": 5} and core_bounds(Core, "count") == {"ge": 2}
    assert core_bounds(Core, "name") == {}
    schema = Model.model_json_schema()["properties"]
    assert schema["width_mm"] == {"default": 1.5, "description": "the model's words", "exclusiveMinimum": 0,
                                  "maximum": 5, "title": "Width Mm", "type": "number"}
    assert {"minimum": 2, "type": "integer"} in schema["count"]["anyOf"]
    assert Model().width_mm == 1.5 and Model(width_mm=5).width_mm == 5
    for bad in ({"width_mm": 0}, {"width_mm": 5.01}, {"count": 1}):
        with pytest.raises(ValidationError) as caught:
            Model(**bad)
        assert caught.value.errors()[0]["loc"] == tuple(bad)
    with pytest.raises(KeyError):
        core_field(Core, "height_mm")  # a name the core does not have fails where the model is declared


def test_the_core_object_is_built_by_name():
    values = core_values(Core, Model(width_mm=2.0, name="job"), ratio=0.25)
    assert values == {"width_mm": 2.0, "count": None, "name": "job", "ratio": 0.25}
    assert Core(**values) == Core(width_mm=2.0, ratio=0.25, name="job")
    assert core_values(Core, Model(), core_only={"ratio"}) == {"width_mm": 1.5, "count": None, "name": "core"}
    with pytest.raises(TypeError, match="ratio"):  # a core field the model lost is not silently the default
        core_values(Core, Model())


def test_probe_plan_builds_the_planners_parameters_from_its_own():
    params = ProbePlanParams(trace_id="trc_x", chord_error_mm=0.01, count=12, coverage=2.0, probe_feed_mm_min=50.0,
                             dialect="marlin", probe_style="g30")
    plan = params.plan_params()
    assert (plan.chord_error_mm, plan.count, plan.coverage) == (0.01, 12, 2.0)
    assert plan.end_ratio == PlanParams().end_ratio and plan.min_count == PlanParams().min_count  # the core's own
    program = params.program_params(part_max_z_mm=3.0)
    assert (program.probe_feed_mm_min, program.dialect, program.style, program.part_max_z_mm) == (50.0, "marlin",
                                                                                                  "g30", 3.0)
    assert program.sample_mm == ProbeProgramParams().sample_mm


def test_the_probe_plan_schema_shows_the_cores_bounds_and_a_bad_value_is_named(client):
    kinds = {k["name"]: k["params_schema"] for k in client.get("/api/v1/job-kinds", headers=auth("viewer")).json()}
    fields = kinds["probe_plan"]["properties"]
    assert fields["chord_error_mm"]["default"] == PlanParams().chord_error_mm
    assert (fields["chord_error_mm"]["exclusiveMinimum"], fields["chord_error_mm"]["maximum"]) == (0, 10)
    assert (fields["probe_sigma_mm"]["minimum"], fields["probe_sigma_mm"]["maximum"]) == (0, 1)
    assert fields["approach_mm"]["default"] == ProbeProgramParams().approach_mm
    assert {"exclusiveMinimum": 0.5, "exclusiveMaximum": 1, "type": "number"} in fields["confidence"]["anyOf"]
    for name, bad in (("chord_error_mm", 0), ("count", 3), ("approach_mm", 51)):
        refused = submit(client, "probe_plan", {"trace_id": "trc_none", name: bad})
        assert refused.status_code == 422, refused.text
        error = refused.json()["errors"][0]
        assert error["loc"] == ["params", name] and error["value"] == bad


def test_the_five_axis_schema_shows_the_cores_bounds(client):
    kinds = {k["name"]: k["params_schema"] for k in client.get("/api/v1/job-kinds", headers=auth("viewer")).json()}
    fields = kinds["five_axis"]["properties"]
    core = FiveAxisParams()
    assert (fields["period_s"]["default"], fields["period_s"]["minimum"], fields["period_s"]["maximum"]) == (
        core.period_s, 1e-4, 0.1)
    assert (fields["pole_window_deg"]["default"], fields["pole_window_deg"]["maximum"]) == (core.pole_window_deg, 5)
    assert {"minimum": -1000, "maximum": 1000, "type": "number"} in fields["safe_z_mm"]["anyOf"]
    refused = submit(client, "five_axis", {"part_id": "prt_none", "trace_id": "trc_none", "decimals": 7})
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"] == ["params", "decimals"]


def _fields_of(client, kind):
    kinds = {k["name"]: k["params_schema"] for k in client.get("/api/v1/job-kinds", headers=auth("viewer")).json()}
    return kinds[kind]["properties"]


def _refused(client, kind, params, name, bad):
    """A submission of ``kind`` with ``params`` and ``name: bad`` is a 422 naming the field and the value."""
    refused = submit(client, kind, {**params, name: bad})
    assert refused.status_code == 422, refused.text
    error = refused.json()["errors"][0]
    assert error["loc"] == ["params", name] and error["value"] == bad, error


def _refused_by_both(client, kind, params, name, bad, core, error, field=None):
    """:func:`_refused`, and ``core(name=bad)`` (the core's own check of the same value) raises
    ``error`` naming ``field`` (default ``params.<name>``) and the value."""
    _refused(client, kind, params, name, bad)
    with pytest.raises(error) as caught:
        core(**{name: bad})
    assert (caught.value.field, caught.value.value) == (field or f"params.{name}", bad)


def test_slice_takes_the_cores_bounds_and_the_core_refuses_them_too(client):
    fields, core = _fields_of(client, "slice"), SliceParams()
    assert (fields["layer_mm"]["default"], fields["layer_mm"]["exclusiveMinimum"], fields["layer_mm"]["maximum"]) == (
        core.layer_mm, 0, 100)
    assert (fields["mu1"]["default"], fields["mu1"]["maximum"], fields["remainder"]["default"]) == (
        core.mu1, 1, core.remainder)
    for name, bad in (("layer_mm", 100.5), ("cusp_mm", 0), ("sigma0", 1.2), ("max_hole_mm", 200_000)):
        _refused_by_both(client, "slice", {"part_id": "prt_none"}, name, bad,
                         lambda **kw: SliceParams(**kw).validate(), SlicingError)
    SliceParams(layer_mm=100, cusp_mm=10, sigma0=1, max_hole_mm=100_000).validate()  # the bounds themselves pass


def test_surface_fit_takes_the_cores_bounds_and_the_core_refuses_them_too(client):
    fields, core = _fields_of(client, "surface_fit"), SurfaceFitParams()
    assert (fields["degree"]["default"], fields["degree"]["minimum"], fields["degree"]["maximum"]) == (
        core.degree, 1, 5)
    assert (fields["moving_average_window"]["maximum"], fields["bad_point_sigma"]["maximum"]) == (15, 100)
    base = {"part_id": "prt_none", "region": {"x": [0, 1], "y": [0, 1]}}
    for name, bad in (("degree", 6), ("penalty", 2e6), ("moving_average_window", 17), ("bad_point_min_mm", -0.1)):
        _refused_by_both(client, "surface_fit", base, name, bad, SurfaceFitParams, SurfaceFitError)
    SurfaceFitParams(degree=5, penalty=1e6, moving_average_window=15, bad_point_min_mm=0)  # the bounds pass


def test_toolpath_takes_the_cores_bounds_and_the_core_refuses_them_too(client):
    fields, core = _fields_of(client, "toolpath"), ToolpathParams()
    assert (fields["resolution_mm"]["default"], fields["resolution_mm"]["minimum"]) == (core.resolution_mm, 0.001)
    assert (fields["merge_weight_across"]["default"], fields["merge_weight_across"]["maximum"]) == (
        core.merge_weights.across, 1000)
    for name, bad in (("line_width_mm", 25), ("infill", 0), ("perimeters", 101), ("resolution_mm", 0.0005),
                      ("angle_deg", -400), ("layer_height_mm", 0)):
        _refused_by_both(client, "toolpath", {"slice_job_id": "job_none"}, name, bad,
                         lambda **kw: ToolpathParams(**kw).validate(), SlicingError)
    _refused_by_both(client, "toolpath", {"slice_job_id": "job_none"}, "merge_weight_along", 1001,
                     lambda merge_weight_along: ToolpathParams(
                         merge_weights=MergeWeights(along=merge_weight_along)).validate(), SlicingError)
    ToolpathParams(line_width_mm=20, infill=1, perimeters=100, resolution_mm=0.001, angle_deg=-360).validate()


def test_toolpath_takes_the_machine_limits_and_program_options_bounds_from_their_cores(client):
    fields = _fields_of(client, "toolpath")
    assert (fields["junction_deviation_mm"]["default"], fields["junction_deviation_mm"]["maximum"]) == (
        MachineLimits().junction_deviation_mm, 10)
    assert (fields["bed_temp_c"]["default"], fields["bed_temp_c"]["maximum"]) == (FdmParams().bed_temp_c, 200)
    for name, bad in (("accel_mm_s2", 2e6), ("junction_deviation_mm", -0.01)):
        _refused_by_both(client, "toolpath", {"slice_job_id": "job_none"}, name, bad,
                         lambda **kw: ToolpathParams(limits=MachineLimits(**kw)).validate(), SlicingError)
    for name, bad in (("nozzle_temp_c", 501), ("z_lift_mm", 51), ("min_travel_for_retract_mm", -1)):
        _refused_by_both(client, "toolpath", {"slice_job_id": "job_none"}, name, bad, FdmParams, GcodeError)
    params = {"slice_job_id": "job_x", "accel_mm_s2": 2500.0, "junction_deviation_mm": 0.02, "bed_temp_c": 80.0}
    assert ToolpathJobParams(**params).limits() == MachineLimits(accel_mm_s2=2500.0, junction_deviation_mm=0.02)


def test_compensate_takes_the_cores_bounds_and_the_core_refuses_them_too(client):
    fields, core = _fields_of(client, "compensate"), CompensationParams()
    assert (fields["chord_error_mm"]["default"], fields["chord_error_mm"]["maximum"]) == (core.chord_error_mm, 1)
    assert (fields["hold_mm"]["default"], fields["hold_mm"]["maximum"], fields["clearance_mm"]["maximum"]) == (
        core.hold_mm, 5, 100)
    assert {"exclusiveMinimum": 0, "maximum": 100_000, "type": "number"} in fields["feed_mm_min"]["anyOf"]
    base = {"trace_id": "trc_none", "reconstruct_job_id": "job_none"}
    for name, bad in (("chord_error_mm", 1.5), ("hold_mm", 5.5), ("clearance_mm", 0), ("feed_mm_min", 200_000)):
        _refused_by_both(client, "compensate", base, name, bad, CompensationParams, CompensationError, field=name)
    CompensationParams(chord_error_mm=1, hold_mm=5, clearance_mm=100, feed_mm_min=100_000)  # the bounds pass
    loop = {"part_id": "prt_none", "trace_ids": ["trc_none"], "machine_id": "mch_none"}  # its compensate steps'
    _refused(client, "closed_loop", loop, "hold_mm", 5.5)
    _refused(client, "closed_loop", loop, "chord_error_mm", 1.5)


def test_register_takes_the_cores_bounds_and_the_core_refuses_them_too(client):
    fields, core = _fields_of(client, "register"), DatumProbeParams()
    assert (fields["search_mm"]["default"], fields["search_mm"]["maximum"]) == (core.search_mm, 20)
    assert {"minimum": 0, "maximum": 10, "type": "number"} in fields["tip_radius_mm"]["anyOf"]
    base = {"part_id": "prt_none", "machine_id": "mch_none"}
    for name, bad in (("search_mm", 25), ("resolution_mm", 0), ("sigma_mm", 2), ("tip_radius_mm", 10.5)):
        _refused_by_both(client, "register", base, name, bad, DatumProbeParams, RegistrationError, field=name)
    probe = RegisterParams(part_id="prt_x", machine_id="mch_x", search_mm=1.0, pivot_xy=[3.0, 4.0]).probe_params(10.0)
    assert probe == DatumProbeParams(search_mm=1.0, tip_radius_mm=10.0, pivot_xy=(3.0, 4.0))  # built by name
