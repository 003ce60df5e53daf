"""Probe grids for surface measurement: even spacing, serpentine order, named errors."""

from __future__ import annotations

import numpy as np
import pytest

from app.domain.errors import InvalidInput
from app.probing.grid import ProbeGridError, ProbeRegion, plan_probe_grid
from app.reconstruction.surface_fit import grid_from_plan


def test_the_grid_covers_the_region_in_serpentine_order() -> None:
    plan = plan_probe_grid(ProbeRegion(0.0, 30.0, -5.0, 5.0), 4, 3)
    assert plan.x.tolist() == [0.0, 10.0, 20.0, 30.0] and plan.y.tolist() == [-5.0, 0.0, 5.0]
    assert plan.index[:6].tolist() == [[0, 0], [0, 1], [0, 2], [1, 2], [1, 1], [1, 0]]
    np.testing.assert_array_equal(plan.points_xy, np.column_stack([plan.x[plan.index[:, 0]], plan.y[plan.index[:, 1]]]))
    # every cell once; consecutive probes are neighbours (short travel)
    assert len({tuple(ij) for ij in plan.index.tolist()}) == 12
    assert np.all(np.abs(np.diff(plan.index, axis=0)).sum(axis=1) == 1)
    # heights measured in probing order land in their cells
    grid = grid_from_plan(plan, plan.points_xy[:, 0] + 100 * plan.points_xy[:, 1])
    xx, yy = np.meshgrid(plan.x, plan.y, indexing="ij")
    np.testing.assert_allclose(grid.z, xx + 100 * yy)


@pytest.mark.parametrize(("region", "nx", "ny", "field"), [
    ((0.0, 1.0, 0.0, 1.0), 1, 3, "params.nx"),
    ((0.0, 1.0, 0.0, 1.0), 3, 1001, "params.ny"),
    ((0.0, 1.0, 0.0, 1.0), True, 3, "params.nx"),
])
def test_bad_grid_sizes_name_the_field(region, nx, ny, field) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ProbeGridError) as info:
        plan_probe_grid(ProbeRegion(*region), nx, ny)
    assert info.value.field == field and isinstance(info.value, InvalidInput)


def test_an_empty_or_non_finite_region_is_refused() -> None:
    for bad in ((1.0, 1.0, 0.0, 1.0), (0.0, 1.0, 2.0, 1.0), (0.0, np.inf, 0.0, 1.0)):
        with pytest.raises(ProbeGridError) as info:
            ProbeRegion(*bad)
        assert info.value.field == "region"
