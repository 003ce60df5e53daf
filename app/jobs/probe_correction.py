"""Probe readings -> surface points on a calibrated machine (shared by probe_run, reconstruct
and register; not a job kind).

A reading is the stylus ball centre at trigger (SPEC16).  With the machine's probe
calibration (:func:`app.jobs.calibration.current_calibration`) a vertical reading at a station
with outward normal n becomes the station-equivalent surface height
``h = z_read + drift + delta(n) - r / n_z`` (:func:`app.calibration.surface_heights`); the
drift offset comes from re-touches of the reference pad (:mod:`app.calibration.drift`).
``corrections`` switches each part off for the ablation bench.  Units: mm, s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from app.calibration import ProbeCalibration, surface_heights, tilted_normals
from app.jobs.calibration import current_calibration
from app.jobs.results.models import ProbeRunResult
from app.platform.models import Job
from app.runtime.context import JobContext

PAD_CLEARANCE_MM = 2.0   # the pad touch starts this far above the pad's top
PAD_OVERTRAVEL_MM = 1.0  # ... and may go this far below it


class Corrections(BaseModel):
    """Which corrections a calibrated machine applies (all by default; false for ablation)."""

    model_config = ConfigDict(extra="forbid")

    radius: bool = Field(True, description="stylus ball radius along the surface normal")
    pretravel: bool = Field(True, description="the calibrated pre-travel (direction dependent)")
    drift: bool = Field(True, description="Z drift from re-touches of the reference pad")


@dataclass(frozen=True)
class MachineProbe:
    """The probe calibration of a machine and its reference pad (None when it has none).

    pad_mm: (x, y, z top) nominal pad centre from the machine profile."""

    calibration: ProbeCalibration
    job_id: str | None
    pad_mm: tuple[float, float, float] | None


def machine_probe(ctx: JobContext, machine_id: str) -> MachineProbe | None:
    """The machine's current probe calibration with its profile's reference pad, or None
    when the probe has never been calibrated (today's ideal-probe behaviour)."""
    with ctx.reads() as reads:
        current = current_calibration(reads, machine_id)
    if current.probe is None:
        return None
    profile = ctx.machine(machine_id).profile or {}
    pad = ((profile.get("reference") or {}).get("pad") or {}).get("centre_mm")
    pad_mm = None if pad is None else (float(pad[0]), float(pad[1]), float(pad[2]))
    return MachineProbe(current.probe, current.probe_job_id, pad_mm)


def station_normals(normals: list[Any], count: int) -> np.ndarray:
    """(count, 3) unit normals from stored record normals; a missing one is vertical."""
    out = np.tile([0.0, 0.0, 1.0], (count, 1))
    for i, n in enumerate(normals):
        if n is not None:
            out[i] = n
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def corrected_heights(readings: np.ndarray, normals: np.ndarray, drift_mm: np.ndarray,
                      probe: ProbeCalibration | None, corrections: Corrections) -> np.ndarray:
    """Station-equivalent heights (n,) mm of vertical readings (n, 3) with outward normals
    (n, 3) and drift offsets (n,) mm to add (zeros when drift is not corrected).

    ``corrections.radius`` False takes the ball radius off vertically (as on a flat surface,
    which is how the pad-referenced nozzle offset sees it) instead of along the normal: the
    error left is ``r (1 / n_z - 1)``, what radius compensation buys on slopes."""
    shifted = np.array(readings, dtype=float)
    shifted[:, 2] += drift_mm
    z = surface_heights(shifted, normals, probe, radius=corrections.radius, pretravel=corrections.pretravel).z_mm
    if probe is not None and not corrections.radius:
        z = z - probe.ball_radius_mm
    return z


REFINE_PASSES = 2  # rebuild -> real normals -> heights again; the second pass changes < 0.1 um on S1


@dataclass(frozen=True)
class RunCalibration:
    """The probe calibration a probe run applied and its corrections."""

    probe: ProbeCalibration
    corrections: Corrections


def run_probe_calibration(probe_run: Job) -> RunCalibration | None:
    """The calibration stored in a probe run's result when its points can be refined along
    the real surface normal (readings of a calibrated probe, radius corrected), else None."""
    stored = ProbeRunResult.of(probe_run).calibration
    if stored is None or not stored.probe:
        return None
    corrections = Corrections.model_validate(stored.corrections)
    if not corrections.radius:
        return None
    return RunCalibration(ProbeCalibration.from_dict(stored.probe), corrections)


def refined(model: Any, rows: list[dict], calibration: RunCalibration,
            gradient: Callable[[Any, np.ndarray], np.ndarray],
            build: Callable[[np.ndarray], Any]) -> tuple[Any, dict[str, Any]]:
    """Iterate the normal: REFINE_PASSES times take the deviation gradient (m, 2) of ``model``
    at the stations (``gradient(model, xy (m, 2))``), tilt the rows' nominal normals by it,
    turn the rows' readings (with their stored drift offsets) into heights again and
    ``build`` the model from the points (m, 3).  Returns (model, {passes, max_change_mm per
    pass, max_tilt_deg: largest angle between the nominal and the final normal})."""
    readings = np.array([p["reading"] for p in rows], dtype=float)
    xy = np.array([p["nominal"][:2] for p in rows], dtype=float)
    nominal = station_normals([p.get("normal") for p in rows], len(rows))
    drift = np.array([p.get("drift_mm", 0.0) for p in rows], dtype=float)
    z_prev = np.array([p["measured"][2] for p in rows], dtype=float)
    changes: list[float] = []
    normals = nominal
    for _ in range(REFINE_PASSES):
        normals = tilted_normals(nominal, gradient(model, xy))
        z = corrected_heights(readings, normals, drift, calibration.probe, calibration.corrections)
        changes.append(float(np.abs(z - z_prev).max()))
        z_prev = z
        model = build(np.column_stack([xy, z]))
    tilt = np.degrees(np.arccos(np.clip(np.sum(normals * nominal, axis=1), -1.0, 1.0)))
    return model, {"passes": REFINE_PASSES, "max_change_mm": changes, "max_tilt_deg": float(tilt.max())}
