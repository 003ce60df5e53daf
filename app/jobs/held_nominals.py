"""Traces' placed nominal polylines, held in memory from one job to the next of a process.

A board's closed loop runs a dozen jobs on the same traces in one compute process (the pool
gives a part's jobs the process that holds the part): the pilot plan, the sequential rounds,
reconstruct, compensate.  Each would parse every trace's stored nominal into a new
:class:`~app.geometry.traces.TracePolyline`, and the core keeps what it derives from a
polyline per polyline *object*: the smoothed slope's spline
(:func:`app.probing.deviation_prior.path_gradient`), a field plan's samples
(:func:`app.probing.field_region.path_samples`), the trace's centre.  For a 1000-trace board
those cost about 0.8 s of CPU per job (parsing 0.13 s, a plan's samples 0.67 s against
0.11 s on held polylines), rebuilt identically by every job.

A stored trace never changes (there is no route that edits one; its id is random and never
reused), so the polyline parsed from it and placed by a given placement is the same for
every job: it is held here under (trace id, created at, placement), its arrays read-only,
and every job of the process gets the same object, with what the core derived from it.
Bounded by the estimated bytes held (points, arc lengths, normals and the slope spline,
:data:`MAX_BYTES`), least recently used let go first.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

from app.geometry.traces import TracePolyline
from app.parts.lru import ByteLru
from app.probing.deviation_prior import SLOPE_SAMPLE_MM

MAX_BYTES = 64 * 2**20           # ~6,000 board traces of the dome (~11 KB each with their slope splines)
POINT_BYTES = 7 * 8              # a point (3), its arc length (1) and its normal (3), float64
SPLINE_BYTES = 3 * 8             # per slope sample: two spline coefficients and a knot, float64


def held_bytes(path: TracePolyline) -> int:
    """Estimated bytes ``path`` and the slope spline the core keeps for it occupy."""
    return len(path.points) * POINT_BYTES + int(path.length_mm / SLOPE_SAMPLE_MM) * SPLINE_BYTES


def _read_only(path: TracePolyline) -> TracePolyline:
    for array in (path.points, path.s, path.normals):
        if array is not None:
            array.setflags(write=False)
    return path


#: (trace id, created at, placement) -> its placed nominal polyline, least recently used out
HELD = ByteLru(MAX_BYTES)


def held_polyline(key: Hashable, make: Callable[[], TracePolyline], held: ByteLru = HELD) -> TracePolyline:
    """The polyline ``held`` keeps under ``key``, else ``make()``'s, kept (read-only)."""
    path: TracePolyline | None = held.get(key)
    if path is None:
        path = _read_only(make())
        held.put(key, path, held_bytes(path))
    return path
