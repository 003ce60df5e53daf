"""Five-axis conformal paths (the EHD patent's method): nozzle-normal traverses on a measured surface for a
table-tilting A/C machine, with constant-feed Taylor interpolation and G-code output."""

from app.five_axis.branches import BranchChoice, choose_axes
from app.five_axis.errors import (
    AxisLimitError,
    DegenerateTraceError,
    FiveAxisError,
    TraceOffSurfaceError,
)
from app.five_axis.kinematics import (
    AxisPose,
    MachineConfig,
    ToolPose,
    forward_kinematics,
    inverse_kinematics,
)
from app.five_axis.params import FiveAxisParams
from app.five_axis.planner import FiveAxisFigures, FiveAxisPath, plan_five_axis
from app.five_axis.trace import trace_on_surface

__all__ = [
    "AxisLimitError", "AxisPose", "BranchChoice", "DegenerateTraceError", "FiveAxisError",
    "FiveAxisFigures", "FiveAxisParams", "FiveAxisPath", "MachineConfig", "ToolPose", "TraceOffSurfaceError",
    "choose_axes", "forward_kinematics", "inverse_kinematics", "plan_five_axis",
    "trace_on_surface",
]
