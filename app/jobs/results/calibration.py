"""The typed results of the calibration kinds (``calibrate_probe``, ``calibrate_nozzle``,
``calibrate_sensor``): the core's calibration (each model is built on the core's dataclass,
:class:`app.calibration.ProbeCalibration`, :class:`~app.calibration.NozzleCalibration` or
:class:`~app.calibration.sensor.SensorCalibration`: its fields, stored as its ``to_dict`` writes
them), how it agrees with the one before it, and the touches it read.  Written and read through
one model, see :mod:`app.jobs.results.models`; ``agreement`` and ``readings`` may be absent from
results stored by hand (tests, imports), never from a job's."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field

from app.calibration import NozzleCalibration, ProbeCalibration
from app.calibration.sensor import SensorCalibration
from app.jobs.results.models import KindResult


class Agreement(BaseModel):
    """A calibration against the machine's previous one of the same kind (and tool):
    ``differences_mm`` new - old per named value, ``disagrees`` the names beyond 3 sigma."""

    model_config = ConfigDict(extra="forbid")
    previous_job_id: str | None = None
    differences_mm: dict[str, float] = Field(default_factory=dict)
    disagrees: list[str] = Field(default_factory=list)


class CalibrateProbeResult(KindResult, ProbeCalibration):
    """A probe qualification (the core's :class:`~app.calibration.ProbeCalibration`: ball radius,
    pre-travel model, sphere centre, pad reading, their std, residual rms, touches, drift; mm),
    its agreement with the one before, the nominal ball radius and the touches it read."""

    kind: ClassVar[str] = "calibrate_probe"
    # the core's default factory: a model built on a stdlib dataclass takes its plain defaults only
    std: dict[str, float] = Field(default_factory=dict)
    agreement: Agreement = Field(default_factory=Agreement)
    nominal_ball_radius_mm: float | None = None
    readings: list[dict[str, Any]] = Field(default_factory=list)

    def calibration(self) -> ProbeCalibration:
        """The core's probe calibration (its own checks: finite values, a 3-vector centre)."""
        return ProbeCalibration.from_dict(self.model_dump())


class CalibrateNozzleResult(KindResult, NozzleCalibration):
    """A nozzle's calibration (the core's :class:`~app.calibration.NozzleCalibration`: tool, offset_mm
    and its std_mm (3,) mm, outer_diameter_mm, touches), its agreement with the one before, the
    machine profile's nominal offset and the difference (mm), the probe job it rests on and the touches."""

    kind: ClassVar[str] = "calibrate_nozzle"
    agreement: Agreement = Field(default_factory=Agreement)
    nominal_offset_mm: list[float] | None = None
    nominal_difference_mm: list[float] | None = None
    probe_job_id: str | None = None  # the probe calibration the offsets rest on
    readings: list[dict[str, Any]] = Field(default_factory=list)

    def calibration(self) -> NozzleCalibration:
        """The core's nozzle calibration."""
        return NozzleCalibration.from_dict(self.model_dump())


class CalibrateSensorResult(KindResult, SensorCalibration):
    """The height sensor's calibration (the core's :class:`app.calibration.sensor.SensorCalibration`:
    offset_mm (3,) mm, scale, time_offset_s, slope_bias_mm, sd), the link it was made over,
    the reference heights it rests on and each procedure's report."""

    kind: ClassVar[str] = "calibrate_sensor"
    sensor_port: str | None = None
    sensor_rate_hz: float | None = None
    references: dict[str, Any] = Field(default_factory=dict)
    report: dict[str, Any] = Field(default_factory=dict)

    def calibration(self) -> SensorCalibration:
        """The core's sensor calibration."""
        return SensorCalibration.from_dict(self.model_dump(include={f.name for f in fields(SensorCalibration)}))
