"""Parameters named once: the API models of five_axis and the jetting kinds carry the core
dataclasses' field names (no rename table), so a drift of a name fails here, and a bad value
the core finds still comes back as a 422 naming the API's parameter."""

from __future__ import annotations

import dataclasses
import io

import numpy as np
import pytest

from app.five_axis import FiveAxisParams
from app.jetting import ControllerParams, DropParams, FlowParams, JettingError, JettingParams, PlantParams, TargetSpec
from app.jetting.controller import validate_controller
from app.jetting.targets import target_from_rings
from app.jobs.jetting_inputs import CORE_ONLY as JETTING_CORE_ONLY
from app.jobs.jetting_inputs import (
    FLAT_GROUPS,
    PrintModelParams,
    SliceSource,
    TargetParams,
    api_field,
    core_errors,
    target_of,
)
from app.jobs.kinds.five_axis import CORE_ONLY as FIVE_AXIS_CORE_ONLY
from app.jobs.kinds.five_axis import FiveAxisJobParams
from app.jobs.kinds.jetting import JettingJobParams
from app.jobs.kinds.slice import SliceJobParams
from app.jobs.kinds.surface_fit import SurfaceFitJobParams
from app.jobs.kinds.toolpath import ToolpathJobParams
from app.reconstruction.surface_fit import SurfaceFitParams
from app.slicing import SliceParams, ToolpathParams
from tests.conftest import auth
from tests.jobs.test_five_axis_jobs import add_trace
from tests.jobs.test_jetting_jobs import error_field, small_target, submit, wait_for
from tests.jobs.test_slicing_jobs import box_with_hole, upload

OP = auth("operator")
GROUPS = {DropParams: "drop", FlowParams: "flow", ControllerParams: "controller"}  # JettingParams' groups


def _names(core: type) -> set[str]:
    return {f.name for f in dataclasses.fields(core)}


def test_five_axis_parameters_have_the_core_names():
    core, api = _names(FiveAxisParams), set(FiveAxisJobParams.model_fields)
    assert core - FIVE_AXIS_CORE_ONLY <= api, core - FIVE_AXIS_CORE_ONLY - api
    assert FIVE_AXIS_CORE_ONLY <= core and not FIVE_AXIS_CORE_ONLY & api  # the list hides no API parameter


def test_jetting_parameters_have_the_core_names():
    flat = set(PrintModelParams.model_fields)
    for group, group_name in GROUPS.items():
        assert _names(group) - JETTING_CORE_ONLY <= flat, (group.__name__, _names(group) - JETTING_CORE_ONLY - flat)
        assert isinstance(getattr(JettingParams(), group_name), group) and group_name in FLAT_GROUPS
        for name in _names(group) - JETTING_CORE_ONLY:  # a core error in the group names the API parameter
            assert api_field(f"{group_name}.{name}") == f"params.{name}"
    assert not JETTING_CORE_ONLY & (flat | set(JettingJobParams.model_fields))
    assert _names(PlantParams) <= set(JettingJobParams.model_fields)
    assert _names(TargetSpec) <= set(TargetParams.model_fields)
    assert {"layers", "margin_mm", "snapshot_every"} <= set(JettingJobParams.model_fields) & _names(JettingParams)
    params = JettingJobParams(dpi=150, flow_steps=3, horizon=2, n_nozzles=7, controller="open_loop")
    core = params.core()
    assert (core.drop.dpi, core.flow.flow_steps, core.controller.horizon, core.plant.n_nozzles,
            core.controller.kind) == (150, 3, 2, 7, "open_loop")


def test_core_errors_about_the_slice_target_name_params_target_slice():
    core = PrintModelParams().core()
    spec = TargetParams(slice=SliceSource(slice_job_id="job_s"))
    with pytest.raises(JettingError) as caught:  # was "layers.json" through the table
        target_of(spec, core, lambda job_id, name: b"not json")
    assert caught.value.field == "params.target.slice"
    with pytest.raises(JettingError) as caught, core_errors():  # was "target.rings" through the table
        target_from_rings([np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])], core.drop, field="target.slice")
    assert caught.value.field == "params.target.slice" and "no area" in caught.value.message
    with pytest.raises(JettingError) as caught, core_errors():
        validate_controller(dataclasses.replace(core.controller, kind="pid"))
    assert caught.value.field == "params.controller"  # was "controller.kind" through the table


def test_a_non_finite_measured_map_is_a_422_naming_params_measured(client):
    """The core's ``measured`` error (was ``measured_height`` through the table)."""
    base = {"dpi": 150, "target": {"size_mm": 5, "hole_mm": 2}, "layer": 4}
    heights = np.zeros(small_target().shape)  # the grid of base's target
    heights[0, 0] = np.nan
    buffer = io.BytesIO()
    np.savez(buffer, heights=heights)
    upload_row = client.post("/api/v1/files", files={"file": ("nan.npz", buffer.getvalue())}, headers=OP).json()
    response = submit(client, "jetting_next_layer", {**base, "measured": {"file_id": upload_row["id"]}})
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"])
    assert done["status"] == "failed" and done["error"]["status"] == 422
    assert done["error"]["errors"][0]["loc"] == ["params", "measured"] and "non-finite" in done["error"]["detail"]


def test_a_straight_trace_with_the_principal_normal_is_a_422_naming_params_normal(client):
    """The core's ``params.normal`` (was ``params.normal_source`` through the table)."""
    part = upload(client, box_with_hole())  # a flat top at z = 3: a straight trace stays straight
    trace = add_trace(client, part, {"type": "line", "start": [2.0, 2.0], "end": [18.0, 2.5]})
    response = submit(client, "five_axis", {"part_id": part, "trace_id": trace["id"], "normal": "principal"})
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=60.0)
    assert done["status"] == "failed" and done["error"]["status"] == 422, done
    assert done["error"]["errors"][0]["loc"] == ["params", "normal"] and "straight" in done["error"]["detail"]
    refused = submit(client, "five_axis", {"part_id": part, "trace_id": trace["id"], "period_s": 0})
    assert refused.status_code == 422 and error_field(refused) == "params.period_s"


# the other kinds whose parameters build a core dataclass: every core field is the API's
# parameter of the same name, except these (the core's defaults, or derived: feeds in mm/s
# from the API's mm/min, the machine limits, the placement prior of a registration)
OTHER_CORE_ONLY = {
    "slice": (SliceParams, SliceJobParams, {"max_layers", "z_tol"}),
    "surface_fit": (SurfaceFitParams, SurfaceFitJobParams, {"resample_shape"}),
    "toolpath": (ToolpathParams, ToolpathJobParams, {"limits", "merge_weights", "perimeter_feed_mm_s",
                                                     "print_feed_mm_s", "travel_feed_mm_s"}),
}


@pytest.mark.parametrize("name", sorted(OTHER_CORE_ONLY))
def test_other_kinds_parameters_have_the_core_names(name):
    core, api, core_only = OTHER_CORE_ONLY[name]
    assert _names(core) - core_only <= set(api.model_fields), _names(core) - core_only - set(api.model_fields)
    assert core_only <= _names(core) and not core_only & set(api.model_fields)
