"""Making trace records: a trace's geometry draped or snapped onto its part, its slope
checked, and the nominal polyline stored with the record."""

from __future__ import annotations

import gc
import json
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from sqlalchemy import insert

from app.domain.errors import ConformaError
from app.geometry.slope import SlopePolicy, check_slope
from app.geometry.tolerance import Tolerance
from app.geometry.traces import TracePolyline, build_nominal_trace, build_nominal_traces
from app.parts.meshes import MeshCache
from app.platform.models import Part, Trace, new_id, utcnow

if TYPE_CHECKING:
    from sqlmodel import Session


def build_trace(meshes: MeshCache, part: Part, body: Any, field_prefix: str = "") -> Trace:
    """Drape/snap a trace (an API ``TraceCreate``) onto its part and make the record (not added).

    Errors from the geometry core name their field under ``field_prefix`` (the index of a
    trace in a bulk import)."""
    geometry = body.geometry.model_dump()
    return _trace_record(part, body, geometry, field_prefix,
                         lambda: build_nominal_trace(meshes.mesh(part), geometry, body.frame, Tolerance()))


def build_traces(meshes: MeshCache, part: Part, bodies: list[Any]) -> list[dict[str, Any]]:
    """:func:`build_trace` of each body (API ``TraceCreate``), errors named by index, as the
    records' column values (every field of :class:`Trace`; :func:`insert_traces` stores them
    in one statement, the ORM's per-object work left out); top-view traces are draped all at
    once (:func:`app.geometry.traces.build_nominal_traces`, the same polylines), anything else
    (or a batch with an error) one by one."""
    geometries = [body.geometry.model_dump() for body in bodies]
    nominals = None
    if all(body.frame == "xy" for body in bodies):
        nominals = build_nominal_traces(meshes.mesh(part), geometries, Tolerance())
    if nominals is None:
        return [_columns(build_trace(meshes, part, body, field_prefix=str(i))) for i, body in enumerate(bodies)]
    return [_trace_row(part, body, geometry, str(i), _given(nominal))
            for i, (body, geometry, nominal) in enumerate(zip(bodies, geometries, nominals))]


def insert_traces(session: Session, rows: list[dict[str, Any]]) -> None:
    """Insert trace records (:func:`build_traces`' column values) in one executemany, in the
    session's transaction; raises ``sqlalchemy.exc.IntegrityError`` when the part is gone."""
    if rows:
        session.execute(insert(Trace), rows)


_pause_lock = threading.Lock()
_pauses = 0
_resume = False


@contextmanager
def collection_paused() -> Iterator[None]:
    """The cycle collector paused while a bulk import makes its records (re-entrant across
    threads: it resumes when the last pause ends, if it was enabled before the first).

    A board's records hold their nominal polylines as nested lists: some 10^5 small lists
    that live until the response is sent.  With the collector running, each young
    collection promotes them, and their growing count sets off full collections that walk
    the service's whole heap: 0.3-0.4 s of a 1000-trace import.  They hold no cycles:
    reference counting frees them without the collector."""
    global _pauses, _resume
    with _pause_lock:
        if _pauses == 0:
            _resume = gc.isenabled()
            gc.disable()
        _pauses += 1
    try:
        yield
    finally:
        with _pause_lock:
            _pauses -= 1
            if _pauses == 0 and _resume:
                gc.enable()

class DrapedAhead:
    """Top-view trace geometries (API ``TraceGeometry`` dicts) draped all at once before their
    records are made one by one (a circuit import's traces and probe rings): :meth:`build` is
    :func:`build_trace` with the batch's polyline when the body's geometry is one of them
    (equal to draping it alone), else (a batch with an error, another frame) draped alone,
    which names the error."""

    def __init__(self, meshes: MeshCache, part: Part, geometries: list[dict[str, Any]]) -> None:
        nominals = build_nominal_traces(meshes.mesh(part), geometries, Tolerance()) if geometries else None
        self._nominal = {} if nominals is None else {_geometry_key(g): n for g, n in zip(geometries, nominals)}

    def build(self, meshes: MeshCache, part: Part, body: Any, field_prefix: str = "") -> Trace:
        geometry = body.geometry.model_dump()
        nominal = self._nominal.get(_geometry_key(geometry)) if body.frame == "xy" else None
        if nominal is None:
            return build_trace(meshes, part, body, field_prefix=field_prefix)
        return _trace_record(part, body, geometry, field_prefix, lambda: nominal)


def _given(nominal: TracePolyline) -> Callable[[], TracePolyline]:
    return lambda: nominal


def _geometry_key(geometry: dict[str, Any]) -> str:
    return json.dumps(geometry, sort_keys=True)


def _columns(trace: Trace) -> dict[str, Any]:
    return {name: getattr(trace, name) for name in Trace.model_fields}


def _trace_record(part: Part, body: Any, geometry: dict[str, Any], field_prefix: str,
                  nominal_of: Callable[[], TracePolyline]) -> Trace:
    return Trace(**_trace_row(part, body, geometry, field_prefix, nominal_of))


def _trace_row(part: Part, body: Any, geometry: dict[str, Any], field_prefix: str,
               nominal_of: Callable[[], TracePolyline]) -> dict[str, Any]:
    policy = SlopePolicy(warn_deg=min(body.slope_warn_deg, body.slope_max_deg), max_deg=body.slope_max_deg)
    try:
        nominal = nominal_of()
        assert nominal.normals is not None, "a draped or snapped trace carries its surface normals"
        slope = check_slope(nominal.points, nominal.normals, policy)
    except ConformaError as exc:
        if field_prefix and exc.field:
            exc.field = f"{field_prefix}.{exc.field}"
        raise
    return dict(
        id=new_id("trace"), part_id=part.id, name=body.name, frame=body.frame, geometry=geometry,
        standoff_mm=body.standoff_mm, width_mm=body.width_mm, feed_mm_min=body.feed_mm_min,
        length_mm=float(nominal.length_mm), z_min=float(nominal.z_range[0]), z_max=float(nominal.z_range[1]),
        nominal=replace(nominal, slope=slope.to_json()).to_dict(),
        created_at=utcnow(), source=None,
    )
