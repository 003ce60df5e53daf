"""Deviation drawn on the part, standoff errors on the programs, and the colour legends:
the deviation as a colour map on the part, traces coloured by standoff error, a legend
with units.

- :func:`deviation_ribbon`: a band on the part along a trace, coloured by the rebuilt
  deviation (real minus nominal height) at each point of the trace;
- :func:`standoff_errors`: for each move of a program over a trace, the tip's height above
  the rebuilt real surface minus the set standoff (the nominal program's error is the
  negative deviation; a compensated program's is its chord error);
- :func:`scene_legends`: one symmetric diverging scale in µm shared by every signed value
  of a scene (deviation ribbons, measured probes, standoff errors), so that colours compare
  across traces and between the nominal and the compensated program; plus one sequential
  scale per unsigned map (the field's posterior sd) and one diverging scale per map of
  verification residuals (:mod:`app.viewer.residual_map`).

Lengths mm in the data, µm in the legends.  numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.viewer.colors import DIVERGING_STOPS, RAMP_STOPS
from app.viewer.scene_data import FocusScene, ScalarSurface
from app.viewer.trace_math import project_onto_polyline

SIGNED = "signed"
RESIDUAL = "residual"


@dataclass(frozen=True)
class Legend:
    """A colour scale: values lo_um..hi_um map to ``stops`` [(position 0..1, "#rrggbb")];
    data_min_um / data_max_um: the extremes the scene really holds; ``items``: what uses it."""

    name: str
    title: str
    unit: str
    lo_um: float
    hi_um: float
    data_min_um: float
    data_max_um: float
    stops: tuple[tuple[float, str], ...]
    items: int

    def to_dict(self) -> dict:
        return {"name": self.name, "title": self.title, "unit": self.unit, "lo": self.lo_um, "hi": self.hi_um,
                "data_min": self.data_min_um, "data_max": self.data_max_um,
                "stops": [list(s) for s in self.stops], "items": self.items}


def deviation_ribbon(points: np.ndarray, dz_mm: np.ndarray, width_mm: float,
                     lift_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat band of ``width_mm`` centred on a trace (k, 3) mm, lifted ``lift_mm``:
    vertices (2k', 3), faces (2(k'-1), 3), values (2k',) = dz at each trace point (k'
    after dropping repeated points; empty arrays for fewer than two)."""
    p = np.asarray(points, float).reshape(-1, 3)
    dz = np.asarray(dz_mm, float).reshape(-1)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1) > 1e-9])
    p, dz = p[keep], dz[keep]
    if len(p) < 2:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0)
    tangent = np.gradient(p[:, :2], axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0], np.zeros(len(p))])
    lift = np.array([0.0, 0.0, lift_mm])
    left, right = p + 0.5 * width_mm * normal + lift, p - 0.5 * width_mm * normal + lift
    vertices = np.empty((2 * len(p), 3))
    vertices[0::2], vertices[1::2] = left, right
    i = np.arange(len(p) - 1)
    faces = np.concatenate([np.column_stack([2 * i, 2 * i + 1, 2 * i + 2]),
                            np.column_stack([2 * i + 1, 2 * i + 3, 2 * i + 2])]).astype(np.int64)
    return vertices, faces, np.repeat(dz, 2)


def deviation_at(points: np.ndarray, nominal: np.ndarray, s_mm: np.ndarray, dz_mm: np.ndarray) -> np.ndarray:
    """The rebuilt deviation (mm) at points (n, 3), read at their foot on the nominal trace
    (k, 3) from samples (s_mm, dz_mm); NaN outside the sampled span."""
    s = np.asarray(s_mm, float)
    order = np.argsort(s)
    s, dz = s[order], np.asarray(dz_mm, float)[order]
    foot = project_onto_polyline(points, nominal).s_mm
    out = np.interp(foot, s, dz)
    out[(foot < s[0] - 1e-6) | (foot > s[-1] + 1e-6)] = np.nan
    return out


def standoff_errors(starts: np.ndarray, ends: np.ndarray, dispense: np.ndarray, nominal: np.ndarray,
                    s_mm: np.ndarray, dz_mm: np.ndarray, standoff_mm: float) -> np.ndarray:
    """(m,) mm for a program's moves over a trace: at each dispensed move's midpoint, its
    height above the real surface (nominal height at its foot + the rebuilt deviation)
    minus ``standoff_mm``; NaN for travel and outside the rebuilt span."""
    out = np.full(len(starts), np.nan)
    mask = np.asarray(dispense, bool)
    if not mask.any() or len(s_mm) < 2:
        return out
    mid = 0.5 * (np.asarray(starts, float)[mask, :3] + np.asarray(ends, float)[mask, :3])
    foot = project_onto_polyline(mid, nominal)
    real = foot.nominal[:, 2] + deviation_at(mid, nominal, s_mm, dz_mm)
    out[mask] = mid[:, 2] - real - standoff_mm
    return out


def ribbon_surface(name: str, nominal: np.ndarray, s_mm: np.ndarray, dz_mm: np.ndarray,
                   width_mm: float, lift_mm: float) -> ScalarSurface | None:
    """The deviation ribbon of one trace as a signed :class:`ScalarSurface` (None if empty)."""
    dz = deviation_at(nominal, nominal, s_mm, dz_mm)
    inside = np.isfinite(dz)
    if inside.sum() < 2:
        return None
    vertices, faces, values = deviation_ribbon(np.asarray(nominal, float)[inside], dz[inside], width_mm, lift_mm)
    if not len(faces):
        return None
    return ScalarSurface(name, vertices, faces, values, float(values.min()), float(values.max()), "mm", signed=True)


def _signed_values(scene: FocusScene) -> list[np.ndarray]:
    chunks = [np.asarray(s.values, float) for s in scene.scalar_surfaces if s.signed]
    chunks += [np.asarray(p.deviation_mm, float) for p in scene.probes if p.deviation_mm is not None]
    chunks += [np.asarray(t.standoff_error_mm, float) for t in scene.toolpaths if t.standoff_error_mm is not None]
    return [c[np.isfinite(c)] for c in chunks if np.isfinite(c).any()]


def signed_limit_mm(scene: FocusScene) -> float:
    """The symmetric limit (mm) of the scene's signed scale: its largest |value|."""
    values = _signed_values(scene)
    return float(max(np.abs(v).max() for v in values)) if values else 0.0


def scene_legends(scene: FocusScene) -> list[Legend]:
    """The legends of a scene: the shared signed scale (if any signed value is drawn) and
    one scale per unsigned map."""
    legends = []
    values = _signed_values(scene)
    if values:
        allv = np.concatenate(values)
        limit = float(np.abs(allv).max())
        legends.append(Legend(SIGNED, "deviation / standoff error (blue: low, red: high)", "µm", -limit * 1000,
                              limit * 1000, float(allv.min()) * 1000, float(allv.max()) * 1000,
                              DIVERGING_STOPS, len(values)))
    for residuals in scene.residuals:
        r = np.asarray(residuals.residual_mm, float)
        if len(r):
            limit = float(np.abs(r).max())
            legends.append(Legend(f"{RESIDUAL}:{residuals.name}", "verification residual, measured - predicted "
                                  "(blue: part below the field, red: above; ringed: flagged)", "µm", -limit * 1000,
                                  limit * 1000, float(r.min()) * 1000, float(r.max()) * 1000, DIVERGING_STOPS, 1))
    for surface in scene.scalar_surfaces:
        if not surface.signed:
            values_s = np.asarray(surface.values, float)
            scale = 1000.0 if surface.unit == "mm" else 1.0
            legends.append(Legend(f"map:{surface.name}", surface.name, "µm" if surface.unit == "mm" else surface.unit,
                                  surface.lo * scale, surface.hi * scale, float(np.nanmin(values_s)) * scale,
                                  float(np.nanmax(values_s)) * scale, RAMP_STOPS, 1))
    return legends
