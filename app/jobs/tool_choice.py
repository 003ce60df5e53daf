"""Which tool a program is written for, and at which offset: the policy of the kinds that
write programs for a machine with nozzles.

On a machine whose profile has nozzles a program is written for a nozzle (default the
profile's first): every coordinate the carriage's = desired tip - the nozzle's CALIBRATED
offset (the latest ``calibrate_nozzle`` job, :func:`app.jobs.calibration.current_calibration`).
An uncalibrated nozzle is refused (422 ``params.tool``) unless allowed (nominal offset, with
a warning).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from app.domain.errors import InvalidInput
from app.jobs.calibration import current_calibration, machine_profile

if TYPE_CHECKING:
    from app.runtime.reads import JobReads


@dataclass
class ToolChoice:
    """The frame the programs are written in: ``tool`` None = the probe frame of before.

    offset_mm (3,) mm, source "calibrated" | "nominal" | "probe"; outer_diameter_mm None
    skips the body check."""

    tool: int | None = None
    name: str = ""
    offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    source: str = "probe"
    calibration_job_id: str | None = None
    outer_diameter_mm: float | None = None
    dispense_on: str | None = None
    dispense_off: str | None = None
    warnings: list[str] = field(default_factory=list)

    def to_result(self) -> dict[str, Any]:
        return {"tool": self.tool, "name": self.name, "offset_mm": [round(v, 6) for v in self.offset_mm],
                "offset_source": self.source, "calibration_job_id": self.calibration_job_id,
                "outer_diameter_mm": self.outer_diameter_mm}


def _xyz(values: Sequence[float]) -> tuple[float, float, float]:
    """An [x, y, z] offset (mm) as three floats."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def choose_tool(reads: JobReads, machine_id: str | None, tool: int | None, *, offsets: bool = True,
                allow_uncalibrated: bool = False) -> ToolChoice:
    """The tool and offset a program is written for (422 ``params.tool`` for a tool the
    machine does not have or an uncalibrated nozzle without ``allow_uncalibrated``).

    machine_id: the machine the program is for (None: the probe frame, tool None or 0);
    tool: the nozzle asked for (None: the profile's first); offsets: False uses the nozzle's
    NOMINAL offset on purpose (ablation)."""
    if machine_id is None:
        if tool not in (None, 0):
            raise InvalidInput(f"tool {tool} needs machine_id (its offset is the machine's)",
                               field="params.tool", value=tool)
        return ToolChoice(tool=tool)
    row = reads.machine(machine_id, field="params.machine_id")
    tools = machine_profile(row).tools
    nozzles = {n.tool: n for n in (tools.nozzles if tools else [])}
    tool = tool if tool is not None else next(iter(nozzles), None)  # the profile's first
    if tool in (None, 0):
        return ToolChoice(tool=tool)
    if tool not in nozzles:
        raise InvalidInput(f"machine {row.id!r} has no nozzle T{tool} (its nozzles: "
                           f"{sorted(nozzles) or 'none'})", field="params.tool", value=tool)
    nozzle = nozzles[tool]
    choice = ToolChoice(tool=tool, name=nozzle.name, offset_mm=_xyz(nozzle.offset_mm),
                        source="nominal", outer_diameter_mm=float(nozzle.outer_diameter_mm),
                        dispense_on=nozzle.dispense_on, dispense_off=nozzle.dispense_off)
    if not offsets:
        choice.warnings.append(f"T{tool} at its NOMINAL offset {list(choice.offset_mm)} mm "
                               "(corrections.offsets is false)")
        return choice
    calibration = current_calibration(reads, row.id)
    calibrated = calibration.nozzles.get(tool)
    if calibrated is None:
        if not allow_uncalibrated:
            raise InvalidInput(f"nozzle T{tool} of machine {row.id!r} has no calibration: run calibrate_nozzle "
                               f"with tool {tool} first, or set allow_uncalibrated to print at its nominal "
                               f"offset {list(choice.offset_mm)} mm", field="params.tool", value=tool)
        choice.warnings.append(f"T{tool} is not calibrated: its NOMINAL offset {list(choice.offset_mm)} mm "
                               "is used (allow_uncalibrated)")
        return choice
    choice.offset_mm = _xyz(calibrated.offset_mm)
    choice.source, choice.calibration_job_id = "calibrated", calibration.nozzle_job_ids[tool]
    if calibrated.outer_diameter_mm:
        choice.outer_diameter_mm = float(calibrated.outer_diameter_mm)
    choice.warnings += [f for f in calibration.flags if f"T{tool}" in f]
    return choice
