"""The typed result of a ``closed_loop`` job (written and read through one model, see
:mod:`app.jobs.results.models`): one row per trace naming its children, the measured standoff
table with ``evaluate``, the registration it used and the loop's own files."""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict

from app.jobs.results.models import KindResult


class PrintReport(BaseModel):
    """How one printed program lay on the part (mm), measured on the machine."""

    model_config = ConfigDict(extra="forbid")
    standoff_error_max_mm: float
    standoff_error_rms_mm: float
    width_mean_mm: float
    width_std_mm: float
    length_mm: float
    xy_error_max_mm: float | None = None
    xy_error_rms_mm: float | None = None


class LoopEvaluation(BaseModel):
    """The nominal and the compensated program of one trace, both printed and measured."""

    model_config = ConfigDict(extra="forbid")
    nominal: PrintReport
    compensated: PrintReport


class LoopTrace(BaseModel):
    """One trace of a closed loop: its children's job ids, its probes, the model's largest
    deviation (mm); a board compensate child names the trace's programs
    (``print_artifact`` / ``nominal_artifact``, else ``print.gcode`` / ``nominal.gcode``)."""

    model_config = ConfigDict(extra="forbid")
    trace_id: str
    probe_plan: str | None = None  # touch: the plan and run that measured the trace
    probe_run: str | None = None
    scan_run: str | None = None  # scan: the scan that measured it (and touched its verification points)
    reconstruct: str
    compensate: str
    probes: int
    deviation_max_mm: float
    print_artifact: str | None = None
    nominal_artifact: str | None = None
    evaluation: LoopEvaluation | None = None
    print: str | None = None  # the print child's job id (print without evaluate)
    bound_mm: float | None = None  # field: coverage x the trace's largest posterior sd under the fitted model
    worse_than_nominal: bool | None = None  # field: the correction did not help at a verification point
    held_ends_mm: list[float] | None = None  # (before, after) mm beyond the trace's probes, held at the nearest
    role: str | None = None  # "pad_probe": a pad's probe ring, probed and rebuilt, never printed

    @property
    def program(self) -> str:
        """The compensated program's artifact name in the compensate job."""
        return self.print_artifact or "print.gcode"


class ClosedLoopResult(KindResult):
    kind: ClassVar[str] = "closed_loop"
    traces: list[LoopTrace]
    table: list[dict[str, Any]]
    registration: dict[str, Any] | None = None
    verdict: dict[str, Any] | None = None  # field: learned prior, verification, needs_attention and why
    needs_attention: bool = False  # the verdict asks for attention: the job ends in that state (app.platform.models)
    files: dict[str, Any] | None = None  # set last (app.jobs.loop_files), from the rows above

    def by_trace(self) -> dict[str, LoopTrace]:
        """trace id -> its row."""
        return {row.trace_id: row for row in self.traces}
