"""app/calibration: probe qualification, nozzle offsets, radius / pre-travel / drift correction,
nozzle clearance (pure: numpy/scipy only).  Conventions: /work SPEC16, summarised in model.py."""

from app.calibration.correct import SurfaceReadings, surface_heights, tilted_normals
from app.calibration.errors import CalibrationError
from app.calibration.model import NozzleCalibration, PretravelModel, ProbeCalibration, Touch

__all__ = [
    "CalibrationError", "NozzleCalibration", "PretravelModel", "ProbeCalibration", "Touch",
    "SurfaceReadings", "surface_heights", "tilted_normals",
]
