"""Continuous (A, C) branch choice along a path."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.compensation.five_axis.branches import choose_axes
from app.compensation.five_axis.errors import AxisLimitError
from app.compensation.five_axis.kinematics import MachineConfig, rotation_matrices


def _tilted(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                            np.cos(theta)])


def _max_angle_to_z(normals: np.ndarray, a: np.ndarray, c: np.ndarray) -> float:
    t = np.einsum("kij,kj->ki", rotation_matrices(a, c), normals)
    return float(np.degrees(np.arctan2(np.hypot(t[:, 0], t[:, 1]), t[:, 2])).max())


@given(st.lists(st.tuples(st.floats(0.0, 1.4), st.floats(-np.pi, np.pi)), min_size=2,
                max_size=30))
@settings(max_examples=40, deadline=None)
def test_random_paths_stay_aligned_and_never_flip(samples) -> None:
    arr = np.array(samples)
    normals = _tilted(arr[:, 0], arr[:, 1])
    choice = choose_axes(normals, MachineConfig(), singular_rho=0.0)
    assert _max_angle_to_z(normals, choice.a_rad, choice.c_rad) < 1e-7
    assert np.abs(np.diff(choice.c_rad)).max(initial=0) <= np.pi + 1e-12
    assert np.all(np.abs(choice.a_rad) <= np.pi / 2 + 1e-12)


def test_crossing_the_pole_switches_branch_instead_of_turning_c() -> None:
    theta = np.linspace(-0.5, 0.5, 21)  # tilt in the x-z plane, through vertical
    normals = np.column_stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)])
    choice = choose_axes(normals, MachineConfig())
    assert np.abs(np.diff(choice.c_rad)).max() < 1e-12
    assert choice.held[10] and not choice.held[9]
    assert set(choice.branch.tolist()) == {1, -1}
    assert _max_angle_to_z(normals, choice.a_rad, choice.c_rad) < 1e-7


def test_one_sided_a_limit_forces_the_branch_and_keeps_moves_short() -> None:
    theta = np.linspace(-0.5, 0.5, 21)
    normals = np.column_stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)])
    choice = choose_axes(normals, MachineConfig(a_limits_rad=(0.0, np.pi / 2)))
    assert (choice.a_rad >= -1e-12).all()
    assert np.abs(np.diff(choice.c_rad)).max() == pytest.approx(np.pi)  # the unavoidable flip
    assert _max_angle_to_z(normals, choice.a_rad, choice.c_rad) < 1e-7


def test_full_turn_unwraps_c() -> None:
    phi = np.linspace(0, 4 * np.pi, 81)
    normals = _tilted(np.full_like(phi, 0.3), phi)
    choice = choose_axes(normals, MachineConfig())
    assert abs(choice.c_rad[-1] - choice.c_rad[0]) == pytest.approx(4 * np.pi, abs=1e-9)
    with pytest.raises(AxisLimitError) as info:
        choose_axes(normals, MachineConfig(c_limits_rad=(-2 * np.pi, 2 * np.pi)))
    assert info.value.field == "params.c_limits_deg"


def test_vertical_start_holds_the_start_c() -> None:
    normals = _tilted(np.array([0.0, 0.0, 0.2]), np.array([0.0, 0.0, 1.0]))
    choice = choose_axes(normals, MachineConfig(), c_start_rad=0.4)
    assert choice.c_rad[0] == pytest.approx(0.4) and choice.c_rad[1] == pytest.approx(0.4)


def test_a_limit_error_names_the_point() -> None:
    normals = _tilted(np.array([0.1, 0.8]), np.array([0.0, 0.0]))
    with pytest.raises(AxisLimitError) as info:
        choose_axes(normals, MachineConfig(a_limits_rad=(-0.5, 0.5)))
    assert info.value.value["index"] == 1
    assert info.value.value["a_deg"] == pytest.approx(np.degrees(0.8))
