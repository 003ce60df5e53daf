"""The region a board's traces cover, as the field planner sees it (pure).

The part's deviation is one band-limited field (:mod:`app.probing.deviation_prior`), so
what matters is *where* the traces are, not how many there are.  This module turns any
number of traces into a bounded set of points whose size depends on the covered area and
the shortest wavelength lambda only:

* **samples**: every trace sampled every ``lambda / SAMPLES_PER_WAVELENGTH`` of arc length
  (the points the criterion is finally checked on);
* **targets**: the samples thinned to one per square cell of ``lambda / CELLS_PER_WAVELENGTH``
  (the posterior variance is smooth on the scale of lambda, so a cell's worst point and its
  kept point differ little); they are also the candidate stations of ``on_traces`` plans;
* **candidates** anywhere on the top (``anywhere_on_top``): the nodes of the same cell grid
  within ``lambda / 4`` of a target where the part's top answers (a :data:`TopSampler`);
* **the Nyquist count** ``A / (lambda / 2)^2 + 6`` — the covered area A (every point
  within lambda / 4 of a trace) in cells of a square lambda / 2 sampling lattice (the
  Nyquist spacing of a field with no wavelength shorter than lambda), plus the 6 placement
  terms: a rule of thumb, blind to the accuracy asked and to the region's rim.  The
  degrees of freedom the planner reports are counted at the target accuracy
  (:mod:`app.probing.field_dof`).

Units: mm.  Shapes in the docstrings.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from app.geometry.tolerance import LENGTH_EPS_MM
from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import Sites, path_gradient
from app.probing.joint import joint_center

SAMPLES_PER_WAVELENGTH = 16
CELLS_PER_WAVELENGTH = 8
REACH_PER_WAVELENGTH = 0.25      # the covered area: within lambda / 4 of a trace
PLACEMENT_TERMS = 6
AREA_RASTER_PER_WAVELENGTH = 16


@dataclass(frozen=True, eq=False)
class TopSample:
    """The part's nominal top at query points: z (m,) mm, grad (m, 2) slope, ok (m,) bool
    (False where the probe cannot reach the top, e.g. off the part)."""

    z: np.ndarray
    grad: np.ndarray
    ok: np.ndarray


TopSampler = Callable[[np.ndarray], TopSample]
"""xy (m, 2) mm -> :class:`TopSample` of the nominal top there."""


@dataclass(frozen=True, eq=False)
class TracePoints:
    """Points on traces: sites (m,), trace index (m,) int, arc length s (m,) mm, nominal z (m,)."""

    sites: Sites
    trace: np.ndarray
    s: np.ndarray
    z: np.ndarray

    def __len__(self) -> int:
        return len(self.s)

    def take(self, idx: np.ndarray) -> TracePoints:
        return TracePoints(self.sites.take(idx), self.trace[idx], self.s[idx], self.z[idx])


# per path: (step mm, its samples' s (m,), points (m, 3), slopes (m, 2)) at the last step asked
_SAMPLED: weakref.WeakKeyDictionary[TracePolyline, tuple[float, np.ndarray, np.ndarray, np.ndarray]] = \
    weakref.WeakKeyDictionary()


def path_samples(path: TracePolyline, step_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(s (m,) mm, points (m, 3) mm, nominal slopes (m, 2)) of ``path`` every about ``step_mm``
    of arc length, both ends included.  The last step's are kept per path (the plans of one
    round, and its verification, sample at one wavelength): read-only arrays."""
    kept = _SAMPLED.get(path)
    if kept is not None and kept[0] == step_mm:
        return kept[1], kept[2], kept[3]
    s = np.linspace(0.0, path.length_mm, max(2, int(math.ceil(path.length_mm / step_mm)) + 1))
    pts, grad = path.at(s), path_gradient(path, s)
    for a in (s, pts, grad):
        a.setflags(write=False)
    _SAMPLED[path] = (step_mm, s, pts, grad)
    return s, pts, grad


def sample_traces(paths: Sequence[TracePolyline], step_mm: float) -> TracePoints:
    """Every path sampled about every ``step_mm`` of arc length, both ends included
    (:func:`path_samples`)."""
    xy, grad, trace, s_all, z = [], [], [], [], []
    for i, path in enumerate(paths):
        s, pts, slope = path_samples(path, step_mm)
        xy.append(pts[:, :2])
        z.append(pts[:, 2])
        grad.append(slope)
        trace.append(np.full(len(s), i))
        s_all.append(s)
    return TracePoints(Sites(np.concatenate(xy), np.concatenate(grad)), np.concatenate(trace),
                       np.concatenate(s_all), np.concatenate(z))


def thin(points: TracePoints, cell_mm: float) -> TracePoints:
    """One point per square cell of ``cell_mm`` (the first in trace order)."""
    keys = np.floor(points.sites.xy / cell_mm).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points.take(np.sort(first))


def covered_area_mm2(xy: np.ndarray, wavelength_mm: float) -> float:
    """Area (mm^2) of the set of points within ``REACH_PER_WAVELENGTH * lambda`` of any of
    ``xy`` (m, 2), measured on a raster of lambda / AREA_RASTER_PER_WAVELENGTH."""
    reach = REACH_PER_WAVELENGTH * wavelength_mm
    step = wavelength_mm / AREA_RASTER_PER_WAVELENGTH
    lo = xy.min(axis=0) - reach
    hi = xy.max(axis=0) + reach
    gx = np.arange(lo[0] + step / 2, hi[0], step)
    gy = np.arange(lo[1] + step / 2, hi[1], step)
    grid = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
    dist, _ = cKDTree(xy).query(grid, distance_upper_bound=reach)
    return float(np.count_nonzero(np.isfinite(dist)) * step * step)


def nyquist_dof(area_mm2: float, wavelength_mm: float) -> float:
    """The Nyquist count over ``area_mm2``: A / (lambda / 2)^2 + the placement terms."""
    return area_mm2 / (wavelength_mm / 2.0) ** 2 + PLACEMENT_TERMS


@dataclass(frozen=True, eq=False)
class FieldRegion:
    """What the field planner works on (see the module doc).

    samples, targets: :class:`TracePoints`.  free: Sites (c,) of free stations with their
    nominal z (c,) (empty unless ``anywhere_on_top``).  area_mm2, nyquist_dof: the covered
    area and its Nyquist count.  center (2,) mm: the placement terms' rotation/tilt centre (the
    traces' length-weighted mean point, as the joint planner's).
    """

    samples: TracePoints
    targets: TracePoints
    free: Sites
    free_z: np.ndarray
    area_mm2: float
    nyquist_dof: float
    center: np.ndarray


def free_candidates(targets: TracePoints, cell_mm: float, reach_mm: float,
                    top: TopSampler) -> tuple[Sites, np.ndarray]:
    """Cell-grid nodes within ``reach_mm`` of a target where ``top`` answers: (Sites, z)."""
    xy = targets.sites.xy
    lo = np.floor((xy.min(axis=0) - reach_mm) / cell_mm) * cell_mm
    hi = xy.max(axis=0) + reach_mm
    gx = np.arange(lo[0], hi[0] + LENGTH_EPS_MM, cell_mm)
    gy = np.arange(lo[1], hi[1] + LENGTH_EPS_MM, cell_mm)
    grid = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
    dist, _ = cKDTree(xy).query(grid, distance_upper_bound=reach_mm)
    grid = grid[np.isfinite(dist)]
    if len(grid) == 0:
        return Sites(np.zeros((0, 2)), np.zeros((0, 2))), np.zeros(0)
    found = top(grid)
    ok = np.asarray(found.ok, dtype=bool) & np.isfinite(found.z)
    return Sites(grid[ok], np.asarray(found.grad)[ok]), np.asarray(found.z)[ok]


def field_region(paths: Sequence[TracePolyline], wavelength_mm: float,
                 top: TopSampler | None = None) -> FieldRegion:
    """The region of ``paths`` (all in one frame); with ``top``, free candidates too."""
    samples = sample_traces(paths, wavelength_mm / SAMPLES_PER_WAVELENGTH)
    cell = wavelength_mm / CELLS_PER_WAVELENGTH
    targets = thin(samples, cell)
    if top is None:
        free, free_z = Sites(np.zeros((0, 2)), np.zeros((0, 2))), np.zeros(0)
    else:
        free, free_z = free_candidates(targets, cell, REACH_PER_WAVELENGTH * wavelength_mm, top)
    area = covered_area_mm2(samples.sites.xy, wavelength_mm)
    return FieldRegion(samples, targets, free, free_z, area, nyquist_dof(area, wavelength_mm),
                       joint_center(paths))
