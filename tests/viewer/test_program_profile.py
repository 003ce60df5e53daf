"""The program summary an operator reads before printing: counts, estimated time, and a
five-axis program's A/C angles and tip speed, checked on programs with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from app.five_axis.kinematics import workpiece_to_machine
from app.gcode.estimator import estimate_gcode
from app.viewer.program_profile import program_summary

THREE_AXIS = "G21\nG90\nG0 Z5\nG0 X10 Y0\nG1 Z1 F300\nG1 X40 Y0 F600\nG1 X40 Y30\nG0 Z5\n"


def test_three_axis_programs_are_timed_by_the_estimator():
    summary = program_summary(THREE_AXIS)
    assert summary["lines"] == 8
    assert summary["time_s"] == pytest.approx(estimate_gcode(THREE_AXIS).total_s)
    assert summary["rotary"] is None


def five_axis_program(speed_mm_s: float, pivot: np.ndarray, n: int = 50) -> tuple[str, np.ndarray, np.ndarray]:
    """A tip moving at ``speed_mm_s`` along a straight workpiece line while A and C turn (G93)."""
    tip = np.column_stack([np.linspace(0, 20, n), np.linspace(5, 15, n), np.full(n, 2.0)])
    a = np.radians(np.linspace(0, 30, n))
    c = np.radians(np.linspace(0, 120, n))
    machine = workpiece_to_machine(tip, a, c, pivot)
    lines = ["G21", "G90", f"G0 X{machine[0, 0]:.6f} Y{machine[0, 1]:.6f} Z{machine[0, 2]:.6f} A0 C0", "G93"]
    for i in range(1, n):
        dt_min = np.linalg.norm(tip[i] - tip[i - 1]) / speed_mm_s / 60.0
        lines.append(f"G1 X{machine[i, 0]:.6f} Y{machine[i, 1]:.6f} Z{machine[i, 2]:.6f} "
                     f"A{np.degrees(a[i]):.6f} C{np.degrees(c[i]):.6f} F{1.0 / dt_min:.6f}")
    lines.append("G94")
    return "\n".join(lines) + "\n", tip, np.degrees(np.column_stack([a, c]))


def test_five_axis_profile_gives_the_tip_speed_and_angles_in_workpiece_coordinates():
    pivot = np.array([10.0, -5.0, -20.0])
    text, tip, angles = five_axis_program(8.0, pivot)
    summary = program_summary(text, pivot)
    rotary = summary["rotary"]
    length = float(np.linalg.norm(tip[-1] - tip[0]))
    assert rotary["points"] == len(tip) - 1
    assert rotary["s_mm"][-1] == pytest.approx(length, rel=1e-5)
    assert np.allclose(rotary["tip_speed_mm_s"], 8.0, rtol=1e-4)
    assert summary["time_s"] == pytest.approx(length / 8.0, rel=1e-4)
    assert np.allclose(rotary["a_deg"], angles[1:, 0], atol=1e-5)
    assert np.allclose(rotary["c_deg"], angles[1:, 1], atol=1e-5)
    # read in the wrong frame (no pivot) the tip speed is not constant: the frame matters
    wrong = program_summary(text)["rotary"]["tip_speed_mm_s"]
    assert np.ptp(wrong) > 0.1


def test_the_profile_follows_the_dispensing_path_not_the_approach():
    pivot = np.array([0.0, 0.0, -10.0])
    text, tip, _angles = five_axis_program(5.0, pivot)
    lines = text.splitlines()
    g93 = lines.index("G93")
    far = "G1 X60 Y60 Z30 F2"  # a slow approach far away, before the path, in inverse time
    with_approach = "\n".join(lines[:g93 + 1] + [far, lines[2].replace("G0", "G1") + " F20", "M106"]
                              + lines[g93 + 1:-1] + ["M107", "G94"]) + "\n"
    summary = program_summary(with_approach, pivot, dispense_on="M106", dispense_off="M107")
    rotary = summary["rotary"]
    assert rotary["points"] == len(tip) - 1
    assert rotary["s_mm"][-1] == pytest.approx(np.linalg.norm(tip[-1] - tip[0]), rel=1e-5)
    assert np.allclose(rotary["tip_speed_mm_s"], 5.0, rtol=1e-4)
    # the time counts every feed line: the path, plus 1/2 min and 1/20 min for the two approach lines
    assert summary["time_s"] == pytest.approx(np.linalg.norm(tip[-1] - tip[0]) / 5.0 + 30.0 + 3.0, rel=1e-4)
