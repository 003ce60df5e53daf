"""A field plan's JSON form (what a probe plan job stores) and the plan read back from it (pure).

Units: mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.probing.deviation_prior import DeviationPrior, Sites
from app.probing.field import FieldPlan


def field_result(plan: FieldPlan, prior: DeviationPrior) -> dict[str, Any]:
    """JSON form of a field plan: what the reconstruction and the viewer read back.

    ``stations``: [{xy, z, grad, trace, s_mm}] in probing order (trace -1 / s_mm None off the traces; a verification
    point has ``verify: true``); ``prior``: the deviation prior the design used (the reconstruction must use it).
    """
    return {
        "stations_mode": plan.stations_mode,
        "center": plan.center.tolist(),
        "dof": plan.dof,
        "nyquist_dof": plan.nyquist_dof,
        "area_mm2": plan.area_mm2,
        "max_sd_mm": plan.max_sd_mm,
        "prior": {k: float(v) for k, v in prior.__dict__.items()},
        "stations": [{"xy": [float(a), float(b)], "z": float(z), "grad": [float(g), float(h)], "trace": int(t),
                      "s_mm": None if math.isnan(s) else float(s)} | ({"verify": True} if v else {})
                     for (a, b), z, (g, h), t, s, v in zip(plan.xy, plan.z, plan.grad, plan.trace, plan.s_mm,
                                                           plan.verify_mask)],
    }


@dataclass(frozen=True, eq=False)
class StoredField:
    """A field plan read back from :func:`field_result`: prior, center (2,), stations Sites
    (n,), nominal z (n,), trace (n,), s_mm (n,), verify (n,) bool (verification points)."""

    prior: DeviationPrior
    center: np.ndarray
    stations: Sites
    z: np.ndarray
    trace: np.ndarray
    s_mm: np.ndarray
    verify: np.ndarray


def stored_field(result: dict[str, Any]) -> StoredField:
    """Inverse of :func:`field_result` (its ``field`` entry)."""
    rows = result["stations"]
    return StoredField(
        DeviationPrior(**result["prior"]), np.asarray(result["center"], dtype=float),
        Sites(np.array([r["xy"] for r in rows], dtype=float).reshape(-1, 2),
              np.array([r["grad"] for r in rows], dtype=float).reshape(-1, 2)),
        np.array([r["z"] for r in rows], dtype=float), np.array([r["trace"] for r in rows], dtype=int),
        np.array([np.nan if r["s_mm"] is None else r["s_mm"] for r in rows], dtype=float),
        np.array([bool(r.get("verify", False)) for r in rows], dtype=bool))
