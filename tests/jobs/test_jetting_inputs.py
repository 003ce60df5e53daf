"""The jetting kinds' shared inputs: the core's parameter objects built from the flat API
parameters by name, and a core error naming the API parameter (one rule, no rename table)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.jetting import ControllerParams, DropParams, JettingError, PlantParams
from app.jetting.controller import validate_controller
from app.jetting.targets import target_from_rings
from app.jobs.jetting_inputs import PrintModelParams, SliceSource, TargetParams, core_errors, target_of
from app.jobs.kinds.jetting import JettingJobParams
from tests.conftest import auth
from tests.helpers.jobs import submit


def test_the_core_objects_carry_the_jobs_values():
    params = JettingJobParams(dpi=150, flow_steps=3, horizon=2, n_nozzles=7, dead_nozzles=[1, 3],
                              controller="open_loop", threshold_um=2.5)
    core = params.core()
    assert (core.drop.dpi, core.flow.flow_steps, core.flow.threshold_um, core.controller.horizon,
            core.plant.n_nozzles, core.plant.dead_nozzles, core.controller.kind) == (150, 3, 2.5, 2, 7, (1, 3),
                                                                                     "open_loop")
    assert core.drop.supersample == DropParams().supersample  # a core-only field keeps the core's default


@pytest.mark.parametrize("core_field, api_field", [("drop.dpi", "params.dpi"), ("flow.mobility", "params.mobility"),
                                                   ("target.mask", "params.target.mask"),
                                                   ("measured", "params.measured")])
def test_a_core_error_names_the_api_parameter(core_field, api_field):
    with pytest.raises(JettingError) as caught, core_errors():
        raise JettingError("bad", field=core_field, value=1)
    assert caught.value.field == api_field and caught.value.message.startswith(api_field)


def test_core_errors_about_the_slice_target_name_params_target_slice():
    core = PrintModelParams().core()
    spec = TargetParams(slice=SliceSource(slice_job_id="job_s"))
    with pytest.raises(JettingError) as caught:
        target_of(spec, core, lambda job_id, name: b"not json")
    assert caught.value.field == "params.target.slice"
    with pytest.raises(JettingError) as caught, core_errors():
        target_from_rings([np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])], core.drop, field="target.slice")
    assert caught.value.field == "params.target.slice" and "no area" in caught.value.message
    with pytest.raises(JettingError) as caught, core_errors():
        validate_controller(dataclasses.replace(core.controller, kind="pid"))
    assert caught.value.field == "params.controller"


@pytest.mark.parametrize("kind", ["jetting", "jetting_next_layer"])
def test_the_schema_shows_the_cores_defaults_and_bounds_and_a_bad_value_is_named(client, kind):
    kinds = {k["name"]: k["params_schema"] for k in client.get("/api/v1/job-kinds", headers=auth("viewer")).json()}
    fields = kinds[kind]["properties"]
    assert (fields["dpi"]["default"], fields["dpi"]["minimum"], fields["dpi"]["maximum"]) == (DropParams().dpi, 25,
                                                                                           2400)
    assert (fields["fill"]["default"], fields["fill"]["exclusiveMinimum"]) == (ControllerParams().fill, 0)
    assert ("seed" in fields) == (kind == "jetting")  # the plant is the simulation's
    if kind == "jetting":
        assert (fields["seed"]["default"], fields["seed"]["maximum"]) == (PlantParams().seed, 2**32 - 1)
    for name, bad in (("dpi", 24), ("horizon", 11), ("mobility", 1.5)):
        refused = submit(client, kind, {name: bad})
        assert refused.status_code == 422, refused.text
        error = refused.json()["errors"][0]
        assert error["loc"] == ["params", name] and error["value"] == bad
