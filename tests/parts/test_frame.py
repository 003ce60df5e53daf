"""A part's frame at intake: units and up axis map file coordinates exactly."""

from __future__ import annotations

import numpy as np
import pytest

from app.domain.errors import InvalidInput
from app.parts.frame import parse_angles, part_frame, size_warnings


@pytest.mark.parametrize(("up", "axis"), [("+z", [0, 0, 1]), ("-z", [0, 0, -1]), ("+y", [0, 1, 0]),
                                          ("-y", [0, -1, 0]), ("+x", [1, 0, 0]), ("-x", [-1, 0, 0])])
def test_the_up_axis_becomes_plus_z_by_a_proper_rotation(up, axis):
    frame = part_frame("stl", None, up=up)
    assert np.array_equal(frame.rotation @ np.array(axis, dtype=float), [0.0, 0.0, 1.0])
    assert np.allclose(frame.rotation @ frame.rotation.T, np.eye(3)) and np.linalg.det(frame.rotation) == 1.0


def test_units_declared_chosen_and_default():
    assert part_frame("glb", "m").scale == 1000.0 and part_frame("glb", "m").up == "+y"
    assert part_frame("3mf", "inch").units_source == "file"
    chosen = part_frame("3mf", "inch", units="mm")
    assert chosen.scale == 1.0 and chosen.units_source == "upload"
    assert part_frame("stl", None).units_source == "default" and part_frame("stl", None).is_identity
    with pytest.raises(InvalidInput):
        part_frame("stl", None, units="furlong")


def test_rotation_then_warnings():
    frame = part_frame("stl", None, rotate_deg=(0.0, 0.0, 90.0))
    assert np.allclose(frame.rotation @ [1.0, 0, 0], [0, 1.0, 0])
    assert parse_angles("0, 0, 90") == (0.0, 0.0, 90.0) and parse_angles(None) == (0.0, 0.0, 0.0)
    with pytest.raises(InvalidInput):
        parse_angles("1,2")
    assert size_warnings(np.array([0.04, 0.03, 0.01]), frame)[0].startswith("the part is only 0.04 mm")
    assert size_warnings(np.array([1500.0, 10, 10]), frame) and not size_warnings(np.array([40.0, 30, 10]), frame)
