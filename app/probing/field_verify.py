"""Verification points of a field plan: where the traces' posterior is least certain.

After the stations, a handful of points on the traces are touched and never used in the fit:
what they read against what the fitted field predicts there checks the field
(:mod:`app.reconstruction.field_trust`).  Each is the trace point of largest posterior
variance once the stations and the previous verification points are (hypothetically)
touched, so they spread instead of clustering at one worst spot; like every posterior sd
of the field, this does not depend on what the probes read, so they are planned in advance.

Those points are where the *model* is least certain; a structure the smooth field cannot
represent (a step, a scratch) is elsewhere: where the touches disagree with each other.
When the touches so far are known (the last round of a sequential plan), :func:`gap_points`
adds points in the gaps along the trace on either side of the stations that the others
predict worst (the residual of each station's spot left out, re-touches and all:
:mod:`app.reconstruction.field_surprise`): a step between stations bends the smooth fit
there, and a touch in the gap reads the step against the fit (far outside its predictive
band), where a touch far from it reads nothing unusual.  The fit passes through the
surprising station and bends towards the others over the gap, so a step at or beside the
station is off the fit by nearly its whole height close to the station and by about half at
the gap's middle: a gap point lies GAP_FRACTION of the gap from its station.  It sits between
two stations, where the posterior is uncertain too: it counts among the verification points,
and the least certain points fill the rest (at least MIN_LEAST_CERTAIN of them), chosen as
if the gap points were touched.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from app.geometry.traces import TracePolyline, as_trace_polyline
from app.probing.deviation_prior import DeviationPrior, Sites, path_gradient
from app.probing.field import FieldPlan, GreedyField
from app.probing.field_region import TracePoints, field_region

GAP_STATIONS = 2      # the stations whose gaps are verified (the worst predicted by the others, in sd)
GAP_RESIDUAL_STATIONS = 2  # ... and the worst predicted in mm (where the leave-one-out sd is large: a trace's end)
MIN_GAP_MM = 0.5      # a neighbour closer than this along the trace is the same spot (a re-touch)
MIN_LEAST_CERTAIN = 2  # least-certain verification points beside the gap points, however many those are
GAP_FRACTION = 0.25   # a gap point lies this fraction of the gap from its surprising station


def verification_indices(prior: DeviationPrior, stations: Sites, samples: Sites, center: np.ndarray,
                         count: int) -> np.ndarray:
    """``count`` indices (k,) into ``samples`` (trace points) where the field given the
    stations is least certain: each the sample of largest posterior variance once the
    previous ones are (hypothetically) touched too, so they spread instead of clustering
    at one worst spot.  Their sd does not depend on what the probes read."""
    greedy = GreedyField(prior, Sites(np.concatenate([stations.xy, samples.xy]),
                                      np.concatenate([stations.grad, samples.grad])), center)
    n = len(stations.xy)
    greedy.add_many(np.arange(n))
    picked: list[int] = []
    for _ in range(min(count, len(samples.xy))):
        var = greedy.var[n:].copy()
        var[picked] = -1.0
        j = int(np.argmax(var))
        picked.append(j)
        greedy.add(n + j)
    return np.array(picked, dtype=int)


def gap_points(paths: Sequence[TracePolyline], trace: np.ndarray, s_mm: np.ndarray, loo_z: np.ndarray,
               loo_residual_mm: np.ndarray | None = None, stations: int = GAP_STATIONS,
               by_residual: int = GAP_RESIDUAL_STATIONS) -> TracePoints:
    """Points (<= 2 x (``stations`` + ``by_residual``)) in the gaps beside the most surprising stations.

    trace (n,) / s_mm (n,): each fitted station's trace index and arc length (-1 / NaN off
    the traces); loo_z (n,): its standardised leave-one-out residual under the fitted prior
    (its spot's: :func:`app.reconstruction.field_surprise.spot_residuals`);
    loo_residual_mm (n,): the same residual in mm (optional).  For the ``stations`` on-trace
    stations of largest |z| and the ``by_residual`` others of largest |residual| (a station
    the others predict far off in mm though within their sd: where the leave-one-out sd is
    large, at a trace's end, a step or an edge at the station itself bends the fit over the
    gap beside it unseen by the z), the point GAP_FRACTION (in arc length) of the way from it
    to the next station along the same trace on each side (none past a trace's end;
    neighbours within MIN_GAP_MM are the same spot, and a spot is picked once: :func:`worst_spots`).
    Sorted by (trace, s), duplicates dropped."""
    trace = np.asarray(trace, dtype=int)
    s_mm = np.asarray(s_mm, dtype=float)
    on = np.flatnonzero(trace >= 0)
    worst = worst_spots(trace, s_mm, on[np.argsort(-np.abs(np.asarray(loo_z, dtype=float)[on]), kind="stable")],
                        stations, [])
    if loo_residual_mm is not None and by_residual > 0:
        order = on[np.argsort(-np.abs(np.asarray(loo_residual_mm, dtype=float)[on]), kind="stable")]
        worst = worst_spots(trace, s_mm, order, by_residual, worst)
    picked: set[tuple[int, float]] = set()
    for i in worst:
        along = s_mm[trace == trace[i]]
        below, above = along[along < s_mm[i] - MIN_GAP_MM], along[along > s_mm[i] + MIN_GAP_MM]
        if len(below):
            picked.add((int(trace[i]), round(float(s_mm[i] + GAP_FRACTION * (below.max() - s_mm[i])), 6)))
        if len(above):
            picked.add((int(trace[i]), round(float(s_mm[i] + GAP_FRACTION * (above.min() - s_mm[i])), 6)))
    rows = sorted(picked)
    xy, grad, z = [], [], []
    for t, s in rows:
        point = paths[t].at(np.array([s]))
        xy.append(point[:, :2])
        z.append(point[:, 2])
        grad.append(path_gradient(paths[t], np.array([s])))
    if not rows:
        return TracePoints(Sites(np.zeros((0, 2)), np.zeros((0, 2))), np.zeros(0, dtype=int), np.zeros(0), np.zeros(0))
    return TracePoints(Sites(np.concatenate(xy), np.concatenate(grad)), np.array([t for t, _ in rows], dtype=int),
                       np.array([s for _, s in rows]), np.concatenate(z))


def worst_spots(trace: np.ndarray, s_mm: np.ndarray, order: np.ndarray, count: int, chosen: list[int]) -> list[int]:
    """``chosen`` and ``count`` more stations, the first in ``order`` (station indices, worst
    first) whose spot (the same trace within MIN_GAP_MM of arc length: its re-touches) no
    chosen station holds: a spot touched three times is one surprise, not three."""
    out = list(chosen)
    for i in order:
        if len(out) == len(chosen) + count:
            break
        if not any(trace[j] == trace[i] and abs(s_mm[j] - s_mm[i]) <= MIN_GAP_MM for j in out):
            out.append(int(i))
    return out


def with_verification(plan: FieldPlan, nominals: Sequence[object], prior: DeviationPrior, count: int) -> FieldPlan:
    """``plan`` (of the traces ``nominals``, designed for ``prior``) with ``count``
    verification points (:func:`verification_indices`) on the traces appended after its
    stations (touched last; ``verify`` marks them)."""
    return with_sequential_verification(plan, Sites(plan.xy[:0], plan.grad[:0]), nominals, prior, count)


def with_sequential_verification(plan: FieldPlan, touched: Sites, nominals: Sequence[object],
                                 prior: DeviationPrior, count: int,
                                 surprise: tuple[np.ndarray, ...] | None = None) -> FieldPlan:
    """``plan`` (a sequential round's added stations, possibly none) with ``count``
    verification points chosen given every station: the ``touched`` ones (earlier rounds)
    and the plan's own.  ``surprise``: (trace (n,), s_mm (n,), loo_z (n,)[, loo_residual_mm (n,)])
    of the touched stations: then the :func:`gap_points` beside the most surprising ones are
    verified too and count among the ``count``: the least certain points, chosen as if the
    gap points were touched too, are ``count`` less the gap points, at least
    MIN_LEAST_CERTAIN (of ``count``)."""
    if count <= 0:
        return plan
    paths = [as_trace_polyline(n, field=f"traces[{i}]") for i, n in enumerate(nominals)]
    samples = field_region(paths, prior.wavelength_mm).samples
    every = Sites(np.concatenate([touched.xy, plan.xy]), np.concatenate([touched.grad, plan.grad]))
    gaps, least = None, count
    if surprise is not None:
        gaps = gap_points(paths, surprise[0], surprise[1], surprise[2], surprise[3] if len(surprise) > 3 else None)
        every = Sites(np.concatenate([every.xy, gaps.sites.xy]), np.concatenate([every.grad, gaps.sites.grad]))
        least = max(count - len(gaps), min(count, MIN_LEAST_CERTAIN))
    idx = verification_indices(prior, every, samples.sites, plan.center, least)
    points = samples.take(idx)
    if gaps is not None:
        points = TracePoints(Sites(np.concatenate([points.sites.xy, gaps.sites.xy]),
                                   np.concatenate([points.sites.grad, gaps.sites.grad])),
                             np.concatenate([points.trace, gaps.trace]), np.concatenate([points.s, gaps.s]),
                             np.concatenate([points.z, gaps.z]))
    n, k = plan.count, len(points)
    return replace(plan, xy=np.concatenate([plan.xy, points.sites.xy]),
                   z=np.concatenate([plan.z, points.z]), grad=np.concatenate([plan.grad, points.sites.grad]),
                   trace=np.concatenate([plan.trace, points.trace]),
                   s_mm=np.concatenate([plan.s_mm, points.s]),
                   verify=np.concatenate([np.zeros(n, dtype=bool), np.ones(k, dtype=bool)]))
