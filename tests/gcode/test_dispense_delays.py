"""The dispenser's on/off delays written into a program: a dwell after each switch, in the
dialect's G4 unit, every other line kept as it was."""

from __future__ import annotations

from app.gcode.dispense_delays import with_dispense_delays

PROGRAM = "G21\nG90\nG0 X0 Y0 Z1\nm106  s255 ; start\nG1 X5 F300\nM107\nG0 Z5\nM106 S255\nG1 X9\nM107\n"


def test_marlin_dwells_in_milliseconds_after_each_switch():
    out = with_dispense_delays(PROGRAM, "M106 S255", "M107", 120, 80, "marlin")
    lines = out.text.splitlines()
    assert (out.on_dwells, out.off_dwells) == (2, 2)
    assert lines[3:6] == ["m106  s255 ; start", "G4 P120", "G1 X5 F300"]
    assert lines[6:8] == ["M107", "G4 P80"]
    assert [line for line in lines if not line.startswith("G4")] == PROGRAM.splitlines()  # nothing else changed
    assert out.text.endswith("\n")


def test_grbl_and_linuxcnc_dwell_in_seconds():
    grbl = with_dispense_delays("M8\nG1 X1 F100\nM9\n", "M8", "M9", 250, 1500, "grbl").text.splitlines()
    assert grbl == ["M8", "G4 P0.250", "G1 X1 F100", "M9", "G4 P1.500"]
    cnc = with_dispense_delays("M64 P0\nG1 X1 F100\nM65 P0\n", "M64 P0", "M65 P0", 50, 0, "linuxcnc")
    assert cnc.text.splitlines() == ["M64 P0", "G4 P0.050", "G1 X1 F100", "M65 P0"] and cnc.off_dwells == 0


def test_zero_delays_leave_the_program_as_it_is():
    out = with_dispense_delays(PROGRAM, "M106 S255", "M107", 0, 0, "marlin")
    assert out.text == PROGRAM and (out.on_dwells, out.off_dwells) == (0, 0)


def test_a_line_that_only_resembles_the_command_gets_no_dwell():
    out = with_dispense_delays("M106 S128\nM1070\nM107 ; off\n", "M106 S255", "M107", 100, 100, "marlin")
    assert out.text.splitlines() == ["M106 S128", "M1070", "M107 ; off", "G4 P100"]
