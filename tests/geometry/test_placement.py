"""The one rigid Placement: apply/remove/inverse are inverses, compose is the matrix product,
s1's as-made placement keeps its old formula, the G-code bed rule is a translation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.gcode.placement import BedPlacement, MachineVolume, bed_placement, placement_shift
from app.geometry.errors import GeometryError
from app.geometry.placement import Placement, PlacementInputError, apply_placement, remove_placement
from app.reference import s1

finite = st.floats(-50, 50, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)
placements = st.builds(Placement, finite, finite, finite, angle, finite, finite)
POINTS = np.random.default_rng(3).uniform(-40, 40, (25, 3))


@settings(max_examples=60, deadline=None)
@given(placements)
def test_apply_then_inverse_is_the_identity(pl: Placement) -> None:
    moved = pl.apply(POINTS)
    np.testing.assert_allclose(pl.inverse().apply(moved), POINTS, atol=1e-9)
    np.testing.assert_allclose(pl.remove(moved), POINTS, atol=1e-9)
    np.testing.assert_allclose(pl.inverse().matrix() @ pl.matrix(), np.eye(4), atol=1e-12)
    # a rigid motion keeps distances
    d0 = np.linalg.norm(POINTS[1:] - POINTS[:-1], axis=1)
    np.testing.assert_allclose(np.linalg.norm(moved[1:] - moved[:-1], axis=1), d0, rtol=1e-12)


@settings(max_examples=60, deadline=None)
@given(placements, placements)
def test_compose_matches_the_matrix_product(a: Placement, b: Placement) -> None:
    ab = a.compose(b)
    np.testing.assert_allclose(ab.matrix(), a.matrix() @ b.matrix(), atol=1e-9)
    np.testing.assert_allclose(ab.apply(POINTS), a.apply(b.apply(POINTS)), atol=1e-9)
    assert (ab.pivot_x, ab.pivot_y) == (b.pivot_x, b.pivot_y)


def test_matrix_rotation_translation_and_the_dict_form() -> None:
    pl = Placement.from_deg(dx=1.0, dy=2.0, dz=3.0, rz_deg=90.0, pivot_xy=(10.0, 0.0))
    # (10, 0) is the pivot: only translated; (11, 0, 0) turns to (10, 1, 0) first
    np.testing.assert_allclose(pl.apply([[10.0, 0.0, 0.0], [11.0, 0.0, 0.0]]),
                               [[11.0, 2.0, 3.0], [11.0, 3.0, 3.0]], atol=1e-12)
    np.testing.assert_allclose(pl.apply([[11.0, 0.0]]), [[11.0, 3.0]], atol=1e-12)  # xy ignores dz
    np.testing.assert_allclose(pl.rotate([[1.0, 0.0, 0.0]]), [[0.0, 1.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(pl.matrix()[:3, 3], pl.translation())
    assert pl.to_dict() == {"dx": 1.0, "dy": 2.0, "dz": 3.0, "rz_deg": pytest.approx(90.0), "pivot": [10.0, 0.0]}
    np.testing.assert_allclose(apply_placement(POINTS, pl), pl.apply(POINTS))
    np.testing.assert_allclose(remove_placement(POINTS, pl), pl.remove(POINTS))


def test_bad_points_are_a_named_422() -> None:
    with pytest.raises(PlacementInputError) as info:
        Placement().apply([[1.0, 2.0, 3.0, 4.0]])
    assert isinstance(info.value, GeometryError) and info.value.field == "points"
    with pytest.raises(PlacementInputError):
        Placement().apply([[np.nan, 0.0, 0.0]])


def test_s1_as_made_placement_keeps_its_old_formula() -> None:
    """Before, s1 had its own Placement: rz_deg about the part centre then (dx, dy), dz on top."""
    dx, dy, dz, rz = 0.1, -0.05, 0.02, 0.3
    part = s1.as_made(5, placement=s1.centred_placement(dx, dy, dz, rz))
    xy = np.random.default_rng(1).uniform(0, 40, (30, 2))
    a = math.radians(rz)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    old_machine = (xy - s1.CENTER) @ rot.T + s1.CENTER + np.array([dx, dy])
    np.testing.assert_allclose(part.to_machine(xy), old_machine, atol=1e-12)
    back = (xy - s1.CENTER - np.array([dx, dy])) @ rot + s1.CENTER
    np.testing.assert_allclose(part.to_part(xy), back, atol=1e-12)
    p = part.to_part(xy)
    np.testing.assert_allclose(part.true_height(xy), s1.nominal_height(p) + part.machining_error(p) + dz,
                               equal_nan=True)


def test_the_bed_rule_gives_a_translation() -> None:
    volume = MachineVolume((0.0, 200.0), (0.0, 100.0), (5.0, 50.0))
    bounds = np.array([[-10.0, -5.0, 2.0], [10.0, 5.0, 7.0]])
    centre = bed_placement(bounds, BedPlacement(), volume)
    assert centre == Placement(100.0, 50.0, 3.0)
    np.testing.assert_allclose(placement_shift(bounds, BedPlacement(), volume), [100.0, 50.0, 3.0])
    offset = bed_placement(bounds, BedPlacement("offset", (20.0, 30.0), drop_to_bed=False), volume)
    np.testing.assert_allclose(offset.apply(bounds)[0], [20.0, 30.0, 2.0])
    assert bed_placement(bounds, BedPlacement("as_is"), volume) == Placement(0.0, 0.0, 3.0)
