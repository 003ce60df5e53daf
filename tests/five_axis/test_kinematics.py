"""Kinematics of the table-tilting A/C machine: round trips and the +Z rule."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from app.five_axis.kinematics import (
    AxisPose,
    MachineConfig,
    ToolPose,
    angles_for_normal,
    forward_kinematics,
    inverse_kinematics,
    rotation_matrices,
    tool_axis_from_angles,
    workpiece_to_machine,
)

coord = st.floats(-200, 200, allow_nan=False)
angle_a = st.floats(-np.pi / 2, np.pi / 2, allow_nan=False)
angle_c = st.floats(-np.pi, np.pi, allow_nan=False)


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@given(angle_a, angle_c)
@settings(max_examples=50, deadline=None)
def test_rotation_matrix_is_rx_times_rz(a: float, c: float) -> None:
    np.testing.assert_allclose(rotation_matrices(np.array([a]), np.array([c]))[0],
                               _rx(a) @ _rz(c), atol=1e-15)


@given(st.tuples(coord, coord, coord), st.tuples(coord, coord, coord),
       st.floats(0.01, np.pi / 2 - 1e-6), angle_c)
@settings(max_examples=80, deadline=None)
def test_forward_inverse_round_trip_from_workpiece(tip, pivot, tilt, azimuth) -> None:
    """forward(inverse(pose)) == pose to 1e-9 mm / 1e-9 rad on random poses."""
    cfg = MachineConfig(pivot_mm=pivot)
    axis = np.array([[np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                      np.cos(tilt)]])
    pose = ToolPose(tip_mm=np.array([tip]), axis=axis)
    for branch in (1, -1):
        axes = inverse_kinematics(pose, cfg, branch=branch)
        back = forward_kinematics(axes, cfg)
        np.testing.assert_allclose(back.tip_mm, pose.tip_mm, atol=1e-9, rtol=0)
        angle = np.arccos(np.clip(np.sum(back.axis * axis), -1, 1))
        assert angle < 1e-9 or np.linalg.norm(back.axis - axis) < 1e-9
        # the rule itself: Rx(A) Rz(C) n == +Z
        r = _rx(axes.a_rad[0]) @ _rz(axes.c_rad[0])
        np.testing.assert_allclose(r @ axis[0], [0, 0, 1], atol=1e-12)


@given(st.tuples(coord, coord, coord), st.tuples(coord, coord, coord),
       st.floats(1e-3, np.pi / 2), angle_c, st.sampled_from([1, -1]))
@settings(max_examples=80, deadline=None)
def test_inverse_forward_round_trip_from_axes(xyz, pivot, a_abs, c, sign) -> None:
    """inverse(forward(axes)) == axes on the branch the axes belong to (A != 0)."""
    cfg = MachineConfig(pivot_mm=pivot)
    a = sign * a_abs
    axes = AxisPose(xyz_mm=np.array([xyz]), a_rad=np.array([a]), c_rad=np.array([c]))
    again = inverse_kinematics(forward_kinematics(axes, cfg), cfg, branch=sign)
    np.testing.assert_allclose(again.xyz_mm, axes.xyz_mm, atol=1e-9, rtol=0)
    assert abs(again.a_rad[0] - a) < 1e-9
    dc = (again.c_rad[0] - c + np.pi) % (2 * np.pi) - np.pi
    assert abs(dc) < 1e-9


def test_machine_rule_matches_explicit_matrices() -> None:
    pivot = np.array([10.0, -5.0, 30.0])
    p = np.array([[3.0, 4.0, 5.0]])
    a, c = 0.3, -1.1
    expected = _rx(a) @ _rz(c) @ (p[0] - pivot) + pivot
    got = workpiece_to_machine(p, np.array([a]), np.array([c]), pivot)[0]
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_both_branches_and_their_relation() -> None:
    n = np.array([[0.3, -0.4, np.sqrt(1 - 0.25)]])
    cand = angles_for_normal(n)
    np.testing.assert_allclose(tool_axis_from_angles(cand.a_pos, cand.c_pos), n, atol=1e-15)
    np.testing.assert_allclose(tool_axis_from_angles(-cand.a_pos, cand.c_pos + np.pi), n,
                               atol=1e-15)
    assert abs(cand.a_pos[0] - np.arccos(n[0, 2])) < 1e-15


def test_vertical_axis_holds_c() -> None:
    cfg = MachineConfig()
    pose = ToolPose(tip_mm=np.array([[1.0, 2.0, 3.0]]), axis=np.array([[0.0, 0.0, 1.0]]))
    axes = inverse_kinematics(pose, cfg, c_hold_rad=0.7)
    assert axes.c_rad[0] == 0.7 and abs(axes.a_rad[0]) < 1e-15
