"""Five-axis post-processors: the same planned poses written for a controller's convention.

``"conforma"`` (the project's own convention, :func:`.program.five_axis_program`)
    ``G1 X Y Z A C``: X Y Z is the nozzle tip in *machine* coordinates,
    ``m = Rx(A) Rz(C) (p - pivot) + pivot`` (the table tilts by A about X and turns by C
    about Z, both through one pivot).  Any controller that moves its joints as
    programmed runs it, e.g. LinuxCNC xyzac-trt in identity kinematics (``M429``, its
    start-up state) or grbl/Marlin builds with A and C axes.  The controller's feed is
    ``G93`` inverse time (or the machine-coordinate tip speed, ``feed_mode="tcp"``).

``"linuxcnc_xyzac_trt"`` (LinuxCNC's tool-centre-point mode)
    ``M428`` switches the ``xyzac-trt`` kinematics on; then ``G1 X Y Z A C`` is the nozzle
    tip in *workpiece* coordinates and LinuxCNC computes the joints.  Its conventions
    (LinuxCNC 2.9 ``xyzac-trt-kins``, verified on the simulator): A turns the table about
    X and C turns the rotary table about Z, with the same signs and order as Conforma's
    (joints = ``Rx(A) Rz(C) (tip - rot_point) + rot_point``) when the kinematics' pivot
    pins equal the machine profile's pivot::

        setp xyzac-trt-kins.x-rot-point <pivot x>    setp xyzac-trt-kins.y-offset 0
        setp xyzac-trt-kins.y-rot-point <pivot y>    setp xyzac-trt-kins.z-offset 0
        setp xyzac-trt-kins.z-rot-point <pivot z>

    (the program's header repeats them).  Between two lines LinuxCNC interpolates the tip
    linearly *in workpiece coordinates*, so the tip follows the planned chord (no swing
    between lines).  Feed: ``G93`` (each line takes its planned time), or
    ``feed_mode="tcp"``: ``G94`` with F = the tip's workpiece-coordinate speed, which is
    what LinuxCNC feeds in TCP mode.  The ``linuxcnc`` dialect's ``G64 P0.001`` bounds
    corner blending to 1 um; ``M429`` restores identity kinematics before the end.

A program written for TCP mode and run without ``M428`` is *accepted silently* by
LinuxCNC and lands millimetres off (measured: 7.5 mm, 46.8 deg): never mix the two.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

from app.five_axis.program import FeedMode, ProgramStyle, dispensed_path, end_program
from app.gcode.writer import ProgramBuilder

__all__ = ["POSTS", "PostName", "linuxcnc_trt_program", "linuxcnc_trt_setup"]

PostName = Literal["conforma", "linuxcnc_xyzac_trt"]
POSTS: tuple[str, ...] = ("conforma", "linuxcnc_xyzac_trt")


def linuxcnc_trt_setup(pivot_mm: tuple[float, float, float]) -> list[str]:
    """The HAL settings of ``xyzac-trt-kins`` the program expects (one per line)."""
    x, y, z = (float(v) for v in pivot_mm)
    return [f"setp xyzac-trt-kins.x-rot-point {x:g}", f"setp xyzac-trt-kins.y-rot-point {y:g}",
            f"setp xyzac-trt-kins.z-rot-point {z:g}", "setp xyzac-trt-kins.y-offset 0",
            "setp xyzac-trt-kins.z-offset 0"]


def linuxcnc_trt_program(tip_mm: npt.NDArray[np.float64], a_deg: npt.NDArray[np.float64],
                         c_deg: npt.NDArray[np.float64],
                         durations_s: npt.NDArray[np.float64], feed_mode: FeedMode, nominal_feed_mm_min: float,
                         style: ProgramStyle, header: list[str],
                         pivot_mm: tuple[float, float, float]) -> str:
    """LinuxCNC xyzac-trt TCP program (see the module doc).

    tip_mm (k,3): nozzle tip in workpiece coordinates (mm); a_deg, c_deg (k,) degrees;
    durations_s (k-1,) segment times (s); header: comment lines after the standard header.
    """
    b = ProgramBuilder("linuxcnc", "five_axis", style.job_id, decimals=style.decimals,
                       feed_decimals=3)
    for line in header:
        b.comment(line)
    b.comment("LinuxCNC xyzac-trt TCP [M428]: X Y Z = nozzle tip in workpiece coordinates; "
              "A about X, C about Z [table rotations]")
    b.comment("expects: " + "; ".join(linuxcnc_trt_setup(pivot_mm)))
    b.raw("M428")
    dispensed_path(b, tip_mm, a_deg, c_deg, durations_s, feed_mode, nominal_feed_mm_min, style)
    b.raw("M429")
    end_program(b, style)
    return b.text()
