"""app/calibration: probe qualification, nozzle offsets, radius / pre-travel / drift correction,
nozzle clearance (pure: numpy/scipy only).  The physical conventions are in model.py's docstring."""

from app.calibration.agreement import disagreements
from app.calibration.clearance import Clearance, nozzle_clearance
from app.calibration.correct import SurfaceReadings, surface_heights, tilted_normals
from app.calibration.drift import DriftTrack, drift_offsets, plan_times, retouch_schedule, touch_times
from app.calibration.errors import CalibrationError
from app.calibration.model import NozzleCalibration, PretravelModel, ProbeCalibration, Touch, hops
from app.calibration.nozzle import fit_nozzle_offset, plan_nozzle_calibration
from app.calibration.qualify import fit_qualification, plan_qualification

__all__ = [
    "CalibrationError", "NozzleCalibration", "PretravelModel", "ProbeCalibration", "Touch", "hops",
    "SurfaceReadings", "surface_heights", "tilted_normals", "plan_qualification", "fit_qualification",
    "plan_nozzle_calibration", "fit_nozzle_offset", "touch_times", "plan_times", "DriftTrack", "drift_offsets",
    "retouch_schedule", "Clearance", "nozzle_clearance", "disagreements",
]
