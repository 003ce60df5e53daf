"""Scenes of the jobs that write a program to print: the part and the program in ONE frame.

A toolpath job's program is in the machine's coordinates: its part was moved onto the bed
(``result.placement.shift_mm``, e.g. centred on a 200 x 200 mm bed, so without it the part
and the program are drawn ~100 mm apart).  A circuit program after a loop in machine
coordinates went through the loop's part -> machine placement
(``result.surface.placement``).  Both are drawn in the program's (machine) frame: the part's
mesh is moved by that placement (``FocusScene.part_matrix``), the program is drawn as it
is, and so is a machine's live head position.  A ``print`` job shows the program it
prints, as its source job's scene.  Each program is a slicer-style preview
(:mod:`app.viewer.layer_preview`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from sqlmodel import Session, select

from app.geometry.placement import Placement
from app.platform.models import Artifact, Job, Program
from app.viewer.layer_preview import ProgramPreview
from app.viewer.scene_data import FocusScene


def translation(offset_mm: Any) -> np.ndarray:
    """The 4 x 4 matrix moving points by ``offset_mm`` (3,)."""
    matrix = np.eye(4)
    matrix[:3, 3] = np.asarray(offset_mm, float).reshape(3)
    return matrix


def placement_matrix(stored: dict[str, Any] | None) -> np.ndarray | None:
    """The 4 x 4 part -> machine matrix of a stored placement ({dx, dy, dz, rz_deg, pivot}); None
    for none."""
    if not stored:
        return None
    pivot = stored.get("pivot") or (0.0, 0.0)
    return Placement(float(stored.get("dx", 0.0)), float(stored.get("dy", 0.0)), float(stored.get("dz", 0.0)),
                     math.radians(float(stored.get("rz_deg", 0.0))), float(pivot[0]), float(pivot[1])).matrix()


def _artifact(loader: Any, session: Session, job_id: str, name: str) -> tuple[bytes, str] | None:
    row = session.exec(select(Artifact).where(Artifact.job_id == job_id, Artifact.name == name)).first()
    return None if row is None else (loader.runtime.blobs.read(row.sha256), row.sha256)


def _preview(loader: Any, session: Session, job: Job, artifact: str, on: str | None, off: str | None,
             floor_z: float = 0.0) -> ProgramPreview | None:
    found = _artifact(loader, session, job.id, artifact)
    if found is None:
        return None
    data, sha = found
    return loader.parser.preview(data, artifact, on, off, floor_z, key=sha)


def toolpath_scene(loader: Any, session: Session, job: Job, artifact: str = "print.gcode") -> FocusScene:
    """A toolpath job: its program with move types and layers, the part moved onto the bed as the
    job placed it; each layer's z and thickness as the slicer cut them (the first layer's floor)."""
    result = job.result or {}
    shift = (result.get("placement") or {}).get("shift_mm") or (0.0, 0.0, 0.0)
    layers = result.get("layers") or []
    floor = float(layers[0]["z"]) - float(layers[0]["thickness"]) if layers else 0.0
    params = job.params or {}
    preview = _preview(loader, session, job, artifact, params.get("dispense_on"), params.get("dispense_off"), floor)
    notes = (f"drawn in the machine's frame: the part moved by {np.round(np.asarray(shift, float), 3).tolist()} mm "
             "onto the bed, as the toolpath placed it",)
    return FocusScene({}, "", previews=(preview,) if preview else (), part_matrix=translation(shift), notes=notes)


def circuit_program_scene(loader: Any, session: Session, job: Job, artifact: str = "circuit.gcode") -> FocusScene:
    """A circuit program: strokes by kind (trace, pass, pad, area), travel, dispense on/off, on the
    part placed as the loop placed it (machine frame)."""
    result = job.result or {}
    matrix = placement_matrix((result.get("surface") or {}).get("placement"))
    preview = _preview(loader, session, job, artifact, result.get("dispense_on"), result.get("dispense_off"))
    notes = ("drawn in the machine's frame (the loop's part -> machine placement)",) if matrix is not None else ()
    return FocusScene({}, "", previews=(preview,) if preview else (), part_matrix=matrix, notes=notes)


PROGRAM_SCENES = {"toolpath": toolpath_scene, "circuit_program": circuit_program_scene}


def print_scene(loader: Any, session: Session, job: Job) -> FocusScene:
    """A print job: the program it prints (its source job's artifact, drawn as that job's scene;
    an uploaded program in its own coordinates)."""
    params = job.params or {}
    source = session.get(Job, params.get("job_id") or "")
    if source is not None and params.get("artifact"):
        build = PROGRAM_SCENES.get(source.kind)
        if build is not None:
            return build(loader, session, source, params["artifact"])
        preview = _preview(loader, session, source, params["artifact"], None, None)
        return FocusScene({}, "", previews=(preview,) if preview else ())
    program = session.get(Program, params.get("program_id") or "")
    if program is None:
        return FocusScene({}, "", notes=("the printed program is gone",))
    data = loader.runtime.blobs.read(program.sha256)
    preview = loader.parser.preview(data, program.name, None, None, 0.0, key=program.sha256)
    return FocusScene({}, "", previews=(preview,))
