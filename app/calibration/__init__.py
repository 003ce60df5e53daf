"""app/calibration: probe qualification, nozzle offsets, radius / pre-travel / drift correction,
nozzle clearance (pure: numpy/scipy only).  Conventions: /work SPEC16, summarised in model.py."""

from app.calibration.correct import SurfaceReadings, surface_heights, tilted_normals
from app.calibration.errors import CalibrationError
from app.calibration.model import NozzleCalibration, PretravelModel, ProbeCalibration, Touch
from app.calibration.nozzle import fit_nozzle_offset, plan_nozzle_calibration
from app.calibration.qualify import fit_qualification, plan_qualification

__all__ = [
    "CalibrationError", "NozzleCalibration", "PretravelModel", "ProbeCalibration", "Touch",
    "SurfaceReadings", "surface_heights", "tilted_normals", "plan_qualification", "fit_qualification",
    "plan_nozzle_calibration", "fit_nozzle_offset",
]
