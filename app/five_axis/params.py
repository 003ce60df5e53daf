"""Parameters of a five-axis plan (one explicit object; degrees and mm/min only here)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

from annotated_types import Ge, Gt, Le

from app.domain.checks import require_positive
from app.five_axis.contact import NormalSide, NormalSource
from app.five_axis.errors import FiveAxisError
from app.five_axis.kinematics import MachineConfig
from app.five_axis.post import POSTS, PostName
from app.five_axis.program import FeedMode, ProgramStyle
from app.gcode.writer import DEFAULT_PROBING_DIALECT

__all__ = ["FiveAxisParams"]

_MAX_POLE_WINDOW_DEG = 5.0
_MAX_SPLIT_ROUNDS = 16


@dataclass(frozen=True)
class FiveAxisParams:
    """Everything a five-axis plan needs.

    standoff_mm: nozzle height h above the contact point along the nozzle direction.
    feed_mm_min: print speed of the contact point along the trace.
    period_s: servo (interpolation) period T of the Taylor update.
    segment_mm: program line spacing along the trace (a multiple of v T, >= one period).
    normal: "surface" (nozzle along the surface normal) or "principal" (patent).
    normal_side: which side of the surface is "up" ("up": the +Z side at its centre).
    pivot: table pivot (x0, y0, z0) mm in workpiece coordinates at A = C = 0.
    a_limits_deg: (min, max) table tilt; c_limits_deg: (min, max) or None = endless C.
    c_start_deg: C before the path (biases the first branch; held if the whole path is
    in the pole window).
    pole_window_deg: half-angle of the pole window around +Z (A = 0 singularity; default
    0.05 deg, so that every line keeps the nozzle within 0.05 deg of the normal): where
    the normal is tilted less than this, C is blended smoothly between the window's ends
    instead of following the normal's azimuth, and the nozzle axis may deviate from the
    normal by at most this angle (see :mod:`.branches`).  0 = exact normals everywhere.
    midpoint_tol_mm: max distance of the tool tip from the planned tip path halfway
    between two program lines; longer lines are split (at most ``max_split_rounds``
    halvings) until it holds.
    on_surface_tol_mm: max trace-to-surface distance before the trace counts as "off".
    feed_mode: "inverse_time" (G93) or "tcp" (G94), see :mod:`.program`.
    dialect, job_id, decimals, safe_z_mm, approach_feed_mm_min: program formatting.
    dispense_on / dispense_off: commands (one line each, or None) written after the
    approach move and after the last print move.  program_end: the machine's program end
    (None: the dialect's).
    post: "conforma" (X Y Z = tip in machine coordinates, the project's convention) or
    "linuxcnc_xyzac_trt" (LinuxCNC TCP mode: M428, X Y Z = tip in workpiece
    coordinates), see :mod:`.post`.
    The bounds in the annotations are the ranges a job may ask for (a kind's parameter model
    reads them); ``__post_init__`` checks what the planner needs.
    """

    standoff_mm: float = 0.5
    feed_mm_min: float = 600.0
    period_s: Annotated[float, Ge(1e-4), Le(0.1)] = 0.001
    segment_mm: Annotated[float, Gt(0), Le(50)] = 0.5
    normal: NormalSource = "surface"
    normal_side: NormalSide = "up"
    pivot: tuple[float, float, float] = (0.0, 0.0, 0.0)
    a_limits_deg: tuple[float, float] = (-90.0, 90.0)
    c_limits_deg: tuple[float, float] | None = None
    c_start_deg: Annotated[float, Ge(-3600), Le(3600)] = 0.0
    pole_window_deg: Annotated[float, Ge(0), Le(_MAX_POLE_WINDOW_DEG)] = 0.05
    midpoint_tol_mm: Annotated[float, Gt(0), Le(1)] = 0.01
    max_split_rounds: int = 10
    on_surface_tol_mm: Annotated[float, Gt(0), Le(5)] = 0.05
    feed_mode: FeedMode = "inverse_time"
    dialect: str = DEFAULT_PROBING_DIALECT
    job_id: str | None = None
    decimals: Annotated[int, Ge(3), Le(6)] = 4
    safe_z_mm: Annotated[float, Ge(-1000), Le(1000)] | None = None
    approach_feed_mm_min: Annotated[float, Gt(0), Le(100_000)] = 300.0
    dispense_on: str | None = None
    dispense_off: str | None = None
    program_end: str | None = None
    post: PostName = "conforma"

    def __post_init__(self) -> None:
        positive = ("standoff_mm", "feed_mm_min", "period_s", "segment_mm",
                    "on_surface_tol_mm", "approach_feed_mm_min", "midpoint_tol_mm")
        require_positive(self, positive, FiveAxisError, prefix="params.")
        if not (0 <= self.pole_window_deg <= _MAX_POLE_WINDOW_DEG):
            raise FiveAxisError(f"pole_window_deg must be in [0, {_MAX_POLE_WINDOW_DEG:g}]",
                                field="params.pole_window_deg", value=self.pole_window_deg)
        if not (isinstance(self.max_split_rounds, int) and 0 <= self.max_split_rounds
                <= _MAX_SPLIT_ROUNDS):
            raise FiveAxisError(f"max_split_rounds must be an integer in [0, {_MAX_SPLIT_ROUNDS}]",
                                field="params.max_split_rounds", value=self.max_split_rounds)
        if self.post not in POSTS:
            raise FiveAxisError(f"post must be one of {list(POSTS)}", field="params.post",
                                value=self.post)
        for name in ("dispense_on", "dispense_off", "program_end"):
            command = getattr(self, name)
            if command is not None and not (isinstance(command, str) and command.strip()
                                            and "\n" not in command and "\r" not in command):
                raise FiveAxisError(f"{name} must be one non-empty G-code line or None",
                                    field=f"params.{name}", value=str(command)[:40])
        lo, hi = self.a_limits_deg
        if not (-180.0 <= lo <= hi <= 180.0):
            raise FiveAxisError("a_limits_deg must be (min, max) within [-180, 180]",
                                field="params.a_limits_deg", value=list(self.a_limits_deg))
        if self.c_limits_deg is not None and not (self.c_limits_deg[0] < self.c_limits_deg[1]):
            raise FiveAxisError("c_limits_deg must be (min, max) with min < max",
                                field="params.c_limits_deg", value=list(self.c_limits_deg))
        if self.feed_mode not in ("inverse_time", "tcp"):
            raise FiveAxisError("feed_mode must be 'inverse_time' or 'tcp'",
                                field="params.feed_mode", value=self.feed_mode)
        if self.normal not in ("surface", "principal"):
            raise FiveAxisError("normal must be 'surface' or 'principal'",
                                field="params.normal", value=self.normal)
        if self.normal_side not in ("up", "as_is", "flipped"):
            raise FiveAxisError("normal_side must be 'up', 'as_is' or 'flipped'",
                                field="params.normal_side", value=self.normal_side)

    @property
    def feed_mm_s(self) -> float:
        """Feed in mm/s."""
        return self.feed_mm_min / 60.0

    def machine(self) -> MachineConfig:
        """The machine description in internal units (rad)."""
        c_lim = None if self.c_limits_deg is None else (math.radians(self.c_limits_deg[0]),
                                                        math.radians(self.c_limits_deg[1]))
        px, py, pz = (float(v) for v in self.pivot)
        return MachineConfig(pivot_mm=(px, py, pz),
                             a_limits_rad=(math.radians(self.a_limits_deg[0]), math.radians(self.a_limits_deg[1])),
                             c_limits_rad=c_lim)

    def style(self) -> ProgramStyle:
        """Program formatting."""
        return ProgramStyle(dialect=self.dialect, job_id=self.job_id, decimals=self.decimals,
                            safe_z_mm=self.safe_z_mm,
                            approach_feed_mm_min=self.approach_feed_mm_min,
                            dispense_on=self.dispense_on, dispense_off=self.dispense_off,
                            program_end=self.program_end)
