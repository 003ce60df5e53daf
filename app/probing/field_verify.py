"""Verification points of a field plan: where the traces' posterior is least certain.

After the stations, a handful of points on the traces are touched and never used in the fit:
what they read against what the fitted field predicts there checks the field
(:mod:`app.reconstruction.field_trust`).  Each is the trace point of largest posterior
variance once the stations and the previous verification points are (hypothetically)
touched, so they spread instead of clustering at one worst spot; like every posterior sd
of the field, this does not depend on what the probes read, so they are planned in advance.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from app.geometry.traces import as_trace_polyline
from app.probing.deviation_prior import DeviationPrior, Sites
from app.probing.field import FieldPlan, GreedyField
from app.probing.field_region import field_region


def verification_indices(prior: DeviationPrior, stations: Sites, samples: Sites, center: np.ndarray,
                         count: int) -> np.ndarray:
    """``count`` indices (k,) into ``samples`` (trace points) where the field given the
    stations is least certain: each the sample of largest posterior variance once the
    previous ones are (hypothetically) touched too, so they spread instead of clustering
    at one worst spot.  Their sd does not depend on what the probes read."""
    greedy = GreedyField(prior, Sites(np.concatenate([stations.xy, samples.xy]),
                                      np.concatenate([stations.grad, samples.grad])), center)
    n = len(stations.xy)
    for j in range(n):
        greedy.add(j)
    picked: list[int] = []
    for _ in range(min(count, len(samples.xy))):
        var = greedy.var[n:].copy()
        var[picked] = -1.0
        j = int(np.argmax(var))
        picked.append(j)
        greedy.add(n + j)
    return np.array(picked, dtype=int)


def with_verification(plan: FieldPlan, nominals: Sequence[object], prior: DeviationPrior, count: int) -> FieldPlan:
    """``plan`` (of the traces ``nominals``, designed for ``prior``) with ``count``
    verification points (:func:`verification_indices`) on the traces appended after its
    stations (touched last; ``verify`` marks them)."""
    return with_sequential_verification(plan, Sites(plan.xy[:0], plan.grad[:0]), nominals, prior, count)


def with_sequential_verification(plan: FieldPlan, touched: Sites, nominals: Sequence[object],
                                 prior: DeviationPrior, count: int) -> FieldPlan:
    """``plan`` (a sequential round's added stations, possibly none) with ``count``
    verification points chosen given every station: the ``touched`` ones (earlier rounds)
    and the plan's own."""
    if count <= 0:
        return plan
    paths = [as_trace_polyline(n, field=f"traces[{i}]") for i, n in enumerate(nominals)]
    samples = field_region(paths, prior.wavelength_mm).samples
    every = Sites(np.concatenate([touched.xy, plan.xy]), np.concatenate([touched.grad, plan.grad]))
    idx = verification_indices(prior, every, samples.sites, plan.center, count)
    n = plan.count
    return replace(plan, xy=np.concatenate([plan.xy, samples.sites.xy[idx]]),
                   z=np.concatenate([plan.z, samples.z[idx]]), grad=np.concatenate([plan.grad, samples.sites.grad[idx]]),
                   trace=np.concatenate([plan.trace, samples.trace[idx]]),
                   s_mm=np.concatenate([plan.s_mm, samples.s[idx]]),
                   verify=np.concatenate([np.zeros(n, dtype=bool), np.ones(len(idx), dtype=bool)]))
