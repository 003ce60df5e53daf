"""Five-axis post-processors: the same poses in Conforma's and LinuxCNC's TCP convention."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.five_axis import FiveAxisError, FiveAxisParams, plan_five_axis
from app.five_axis.kinematics import machine_to_workpiece
from app.five_axis.trace import trace_over_xy

PIVOT = (2.0, -1.0, -15.0)
MOVE = re.compile(r"^G1 X(\S+) Y(\S+) Z(\S+) A(\S+) C(\S+) F")


def _moves(program: str) -> np.ndarray:
    return np.array([[float(v) for v in m.groups()] for m in map(MOVE.match, program.splitlines()) if m])


def _plan(sphere, post: str):
    t = np.linspace(0.0, 1.5, 40)
    trace = trace_over_xy(sphere, np.stack([15 * np.cos(t), 15 * np.sin(t)], -1))
    return plan_five_axis(sphere, trace, FiveAxisParams(
        pivot=PIVOT, post=post, dialect="linuxcnc", dispense_on="M64 P0", dispense_off="M65 P0"))


def test_linuxcnc_post_writes_workpiece_tips_between_m428_and_m429(sphere):
    ours, lcnc = _plan(sphere, "conforma"), _plan(sphere, "linuxcnc_xyzac_trt")
    a, b = _moves(ours.program), _moves(lcnc.program)
    assert a.shape == b.shape and np.array_equal(a[:, 3:], b[:, 3:])  # same angles, same lines
    tips = machine_to_workpiece(a[:, :3], np.radians(a[:, 3]), np.radians(a[:, 4]), np.array(PIVOT))
    assert b[:, :3] == pytest.approx(tips, abs=2e-4)  # the machine tips mapped back, 4 decimals
    lines = lcnc.program.splitlines()
    assert lines.index("M428") < lines.index("M64 P0") < lines.index("M65 P0") < lines.index("M429")
    assert lines[-1] == "M2" and "G64 P0.001" in lines
    assert "setp xyzac-trt-kins.z-rot-point -15" in lcnc.program
    assert "M428" not in ours.program and ours.program.splitlines()[-1] == "M2"


def test_unknown_post_is_refused():
    with pytest.raises(FiveAxisError) as info:
        FiveAxisParams(post="fanuc")
    assert info.value.field == "params.post"
