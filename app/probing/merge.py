"""One probe program over several traces: the per-trace plans joined in trace order.

:func:`merge_plans` concatenates the stations of per-trace plans (each (m_i,) arc
lengths, (m_i, 3) points mm, optional (m_i, 3) unit normals) into one :class:`ProbePlan`
and says where each trace's stations start, so trace ``i`` owns stations
``[first[i], first[i] + plans[i].count)`` of the merged plan.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from app.probing.selection import PlanError, ProbePlan

__all__ = ["MergedPlan", "merge_plans"]


class MergedPlan(NamedTuple):
    """plan: the joined stations (sum m_i); first: (T,) int, each trace's first station."""

    plan: ProbePlan
    first: npt.NDArray[np.int64]


def merge_plans(plans: Sequence[ProbePlan], method: str) -> MergedPlan:
    """Join per-trace plans in the given order into one plan named ``method``.

    The merged ``s_mm`` keeps each trace's own arc lengths (mm, not re-based); its normals
    are the concatenated normals when every plan has them, else None (the program then
    takes the mesh's normals for all stations).  Raises PlanError (field ``trace_ids``)
    for no plans.
    """
    if not plans:
        raise PlanError("no plans to merge: at least one trace is needed", field="trace_ids", value=0)
    normals = None if any(p.normals is None for p in plans) else np.concatenate([p.normals for p in plans])
    merged = ProbePlan(method, np.concatenate([p.s_mm for p in plans]),
                       np.concatenate([p.points for p in plans]), normals)
    counts = np.array([p.count for p in plans], dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return MergedPlan(merged, first)
