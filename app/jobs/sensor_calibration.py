"""A machine's stored height-sensor calibration: the latest succeeded ``calibrate_sensor``
job, and what a scan uses (a calibration given with the job, else the stored one).

Not a job kind: ``calibrate_sensor``, ``scan_run`` and ``closed_loop`` import it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from app.calibration.errors import CalibrationError
from app.calibration.sensor import SensorCalibration
from app.domain.errors import InvalidInput
from app.jobs.calibration import latest_calibration_job
from app.jobs.results.calibration import CalibrateSensorResult

if TYPE_CHECKING:
    from app.runtime.reads import JobReads


def stored_sensor_calibration(reads: JobReads, machine_id: str) -> tuple[SensorCalibration, str] | None:
    """(the calibration, its job id) of the machine's newest succeeded ``calibrate_sensor``
    job, or None."""
    job = latest_calibration_job(reads, machine_id, "calibrate_sensor")
    if job is None:
        return None
    return CalibrateSensorResult.of(job).calibration(), job.id


def given_calibration(data: dict[str, Any], field: str) -> SensorCalibration:
    """A calibration given as a dict (422 naming ``field`` when it is not one)."""
    try:
        return SensorCalibration.from_dict(data)
    except (KeyError, TypeError, ValueError, CalibrationError) as exc:
        raise InvalidInput(f"{field}: {exc}", field=field, value=str(data)[:80]) from None


def scan_calibration(reads: JobReads, machine_id: str, given: dict[str, Any] | None,
                     field: str = "params.calibration") -> tuple[SensorCalibration, dict[str, Any]]:
    """(the calibration a scan uses, where it comes from: ``{"source": "params"}`` or
    ``{"source": "stored", "job_id": ...}``); 422 on ``field`` when none is given and the
    machine has none stored."""
    if given is not None:
        return given_calibration(given, field), {"source": "params"}
    stored = stored_sensor_calibration(reads, machine_id)
    if stored is None:
        raise InvalidInput(f"machine {machine_id!r} has no height sensor calibration: calibrate the sensor first "
                           "(job calibrate_sensor) or give the calibration", field=field, value=None)
    return stored[0], {"source": "stored", "job_id": stored[1]}
