"""Continuous (A, C) branch choice along a path."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.five_axis.branches import choose_axes
from app.five_axis.errors import AxisLimitError
from app.five_axis.kinematics import MachineConfig, rotation_matrices


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
    choice = choose_axes(normals, MachineConfig(), pole_tilt_rad=0.0)
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
    # the unavoidable half turn of C, spread over the two moves around the vertical normal
    assert abs(choice.c_rad[-1] - choice.c_rad[0]) == pytest.approx(np.pi)
    assert np.abs(np.diff(choice.c_rad)).max() == pytest.approx(np.pi / 2)
    assert _max_angle_to_z(normals, choice.a_rad, choice.c_rad) < 1e-7


def test_full_turn_unwraps_c() -> None:
    phi = np.linspace(0, 4 * np.pi, 81)
    normals = _tilted(np.full_like(phi, 0.3), phi)
    choice = choose_axes(normals, MachineConfig())
    assert abs(choice.c_rad[-1] - choice.c_rad[0]) == pytest.approx(4 * np.pi, abs=1e-9)
    with pytest.raises(AxisLimitError) as info:
        choose_axes(normals, MachineConfig(c_limits_rad=(-2 * np.pi, 2 * np.pi)))
    assert info.value.field == "params.c_limits_deg"


def test_vertical_start_holds_the_first_c_and_all_vertical_holds_the_start_c() -> None:
    normals = _tilted(np.array([0.0, 0.0, 0.2]), np.array([0.0, 0.0, 1.0]))
    choice = choose_axes(normals, MachineConfig(), c_start_rad=0.4)
    # C is set before printing (by the approach move) and does not turn at the pole
    np.testing.assert_allclose(choice.c_rad, choice.c_rad[2], atol=1e-12)
    assert _max_angle_to_z(normals, choice.a_rad, choice.c_rad) < 1e-7
    assert choice.held.tolist() == [True, True, False]
    vertical = choose_axes(_tilted(np.zeros(3), np.zeros(3)), MachineConfig(), c_start_rad=0.4)
    np.testing.assert_allclose(vertical.c_rad, 0.4)
    np.testing.assert_allclose(vertical.a_rad, 0.0)


def _passing_beside_the_pole(d: float, radius: float = 40.0, half: float = 10.0,
                             k: int = 201) -> tuple[np.ndarray, np.ndarray]:
    """Sphere normals (k,3) along the straight plan-view line y = d, x in [-half, half],
    and the x positions (k,) as path positions."""
    x = np.linspace(-half, half, k)
    n = np.column_stack([x, np.full(k, d), np.sqrt(radius**2 - x**2 - d**2)]) / radius
    return n, x


@pytest.mark.parametrize("d", [0.0, 0.02, 0.1, 0.3])
def test_pole_window_blends_c_instead_of_swinging(d: float) -> None:
    """Exact normals need C to turn by ~180 deg at up to 1/d rad per mm beside the pole;
    in the window C is linear in path length, outside it the alignment is exact."""
    window = np.radians(1.0)
    normals, x = _passing_beside_the_pole(d)
    choice = choose_axes(normals, MachineConfig(), pole_tilt_rad=window, arc_mm=x)
    tilt = np.arctan2(np.hypot(normals[:, 0], normals[:, 1]), normals[:, 2])
    turned = np.einsum("kij,kj->ki", rotation_matrices(choice.a_rad, choice.c_rad), normals)
    err = np.arctan2(np.hypot(turned[:, 0], turned[:, 1]), turned[:, 2])
    inside = tilt <= window
    np.testing.assert_array_equal(choice.held, inside)
    assert inside.sum() >= 3
    assert err[~inside].max() < 1e-9
    assert (err[inside] <= tilt[inside] + 1e-12).all()
    # C moves by the same amount per mm through the window (linear blend), small in total
    j0, j1 = np.flatnonzero(inside)[[0, -1]] + [-1, 1]
    rate = np.diff(choice.c_rad[j0:j1 + 1]) / np.diff(x[j0:j1 + 1])
    np.testing.assert_allclose(rate, rate[0], atol=1e-9)
    turn = abs(choice.c_rad[j1] - choice.c_rad[j0])
    expected = 2 * np.arctan2(d, abs(x[j0]))  # the exit branch is the flipped one
    assert turn == pytest.approx(expected, abs=1e-9)
    exact = choose_axes(normals, MachineConfig(), pole_tilt_rad=0.0, arc_mm=x)
    assert np.abs(np.diff(choice.c_rad)).max() <= 0.25 * np.abs(np.diff(exact.c_rad)).max() + 1e-12
    assert choice.a_rad[0] * choice.a_rad[-1] < 0  # A changes sign instead


def test_without_a_window_beside_the_pole_c_swings() -> None:
    """The reference: exact normals at d = 0.1 mm need C to turn ~180 deg within 1 mm."""
    normals, x = _passing_beside_the_pole(0.1)
    choice = choose_axes(normals, MachineConfig(), pole_tilt_rad=0.0, arc_mm=x)
    near = np.abs(x) <= 0.5
    assert abs(choice.c_rad[near][-1] - choice.c_rad[near][0]) > np.radians(150.0)
    assert _max_angle_to_z(normals, choice.a_rad, choice.c_rad) < 1e-9


def test_a_limit_error_names_the_point() -> None:
    normals = _tilted(np.array([0.1, 0.8]), np.array([0.0, 0.0]))
    with pytest.raises(AxisLimitError) as info:
        choose_axes(normals, MachineConfig(a_limits_rad=(-0.5, 0.5)))
    assert info.value.value["index"] == 1
    assert info.value.value["a_deg"] == pytest.approx(np.degrees(0.8))
