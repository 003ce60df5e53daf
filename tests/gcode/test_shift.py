"""The drift shift of a program's absolute Z: exact on what the one modal reader sees,
relative words and homing untouched, refused where it cannot be proved."""

from __future__ import annotations

import numpy as np
import pytest

from app.gcode.reader import read_program
from app.gcode.shift import ShiftError, shift_z
from hardware.protocol import commands_sha256

PROGRAM = """; conforma job=j kind=compensate units=mm
G21
G90
T1
G0 Z12.0000
G0 X1.0000 Y2.0000
G0 Z8.6000
G1 Z8.1000 F60.0
M106
G1 X2.0000 Y2.5000 Z8.1200 F300.0
G1 X3 Y3 Z8.13 ; a comment Z99
M107
G91
G1 Z1.0000
G90
G0 Z12.0000
"""


def test_absolute_z_moves_rise_by_exactly_the_shift_relative_ones_do_not():
    shifted = shift_z(PROGRAM, 0.0123)
    before, after = read_program(PROGRAM), read_program(shifted.text)
    assert np.allclose(after.end[:, :2], before.end[:, :2]) and np.allclose(after.end[:, 2] - before.end[:, 2], 0.0123)
    assert shifted.shifted_lines == 6                   # the G91 Z1 is not among them
    assert "G1 Z1.0000" in shifted.text and "G1 X3 Y3 Z8.1423 ; a comment Z99" in shifted.text
    assert commands_sha256(shifted.text.splitlines()).count == commands_sha256(PROGRAM.splitlines()).count
    assert shift_z(PROGRAM, 0.0).text == PROGRAM


def test_inches_g92_and_homing():
    program = "G20\nG90\nG1 Z1.0 F10\nG92 Z0\nG1 Z0.5\nG28\nG1 X1\nG1 Z0.2\n"
    shifted = shift_z(program, 0.254)
    before, after = read_program(program), read_program(shifted.text)
    dz = after.end[:, 2] - before.end[:, 2]
    # before the homing every move is 0.254 mm higher; the homing and the XY move after it
    # are where they were; the next absolute Z is raised again
    assert np.allclose(dz, [0.254, 0.254, 0.0, 0.0, 0.254])
    assert "G1 Z1.010000" in shifted.text and "G92 Z0.010000" in shifted.text


def test_refused_where_the_shift_cannot_be_proved():
    with pytest.raises(ShiftError) as two:
        shift_z("G90\nG1 Z1 Z2\n", 0.01)
    assert two.value.value["line"] == 2
    with pytest.raises(ShiftError):
        shift_z("G90\nG10 L2 P1 Z3\nG1 Z1\n", 0.01)
    with pytest.raises(ShiftError):
        shift_z("G1 Z1\n", float("nan"))
