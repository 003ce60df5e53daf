"""How many degrees of freedom a board's deviation field has at the accuracy asked (pure).

The field planner's count of stations is compared with two counts, both fixed before any
probe touches the part and independent of the number of traces:

* **dof** (:func:`truncation_dof`): the Karhunen-Loeve truncation dimension at the target.
  The prior covariance of the deviation (band-limited machining field + the 6 placement
  terms, :mod:`app.probing.deviation_prior`) over the covered region R (every point within
  lambda / 4 of a trace) has eigenmodes phi_i with variances v_i (their mean square over R,
  largest first).  dof is the fewest modes n whose capture leaves the rest's mean variance
  ``sum_{i > n} v_i`` at or below the target variance sd_t^2.  It is also a lower bound on
  stations: n noise-free point probes reduce the prior covariance by rank n at most, so no
  design with fewer than dof stations brings even the *mean* posterior variance over R to
  the target (the planner bounds the *largest* variance on every trace, with probe noise).
  It grows with the target's precision, and with the region's rim: a field must be pinned
  down along the rim without neighbours outside, which a small region (S1) feels most.
* **nyquist_dof** (:func:`app.probing.field_region.nyquist_dof`): ``A / (lambda / 2)^2 + 6``,
  a square lattice at the Nyquist spacing of the shortest wavelength, blind to the target
  and the rim: the rule of thumb.

The eigenproblem is solved by the Nystrom method on a square grid of spacing lambda /
GRID_PER_WAVELENGTH over R (each node weighs 1 / m of the region): counts at lambda / 5 are
within 1 % of lambda / 8 on the bench's boards (S1 and a 150 x 100 mm part).  The jinc
kernel on a grid depends only on the node offset (di, dj), so it is tabulated once.

The count costs an eigendecomposition of the grid's covariance (O(m^3), m up to
MAX_GRID_NODES): a plan carries it as a :class:`Deferred` figure (:func:`region_dof`), computed
when it is first read, so the plans a sequential planner makes and never reports cost none.

Units: mm.  Shapes in the docstrings.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.linalg import eigvalsh
from scipy.spatial import cKDTree

from app.probing.deviation_prior import DeviationPrior, Sites, jinc_kernel, placement_basis
from app.probing.field_region import REACH_PER_WAVELENGTH, TracePoints

GRID_PER_WAVELENGTH = 5
MAX_GRID_NODES = 6000   # ~0.3 GiB for the covariance; a region needing more is coarsened


def region_grid(samples: TracePoints, wavelength_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Grid nodes of the covered region: (xy (m, 2) mm, ij (m, 2) int node indices, sample
    index (m,) of each node's nearest trace sample, spacing mm).  The spacing is lambda / 5, coarsened if
    the region would need more than MAX_GRID_NODES nodes."""
    xy = samples.sites.xy
    reach = REACH_PER_WAVELENGTH * wavelength_mm
    lo = xy.min(axis=0) - reach
    span = xy.max(axis=0) + reach - lo
    h = wavelength_mm / GRID_PER_WAVELENGTH
    tree = cKDTree(xy)
    while True:
        shape = np.ceil(span / h).astype(int)
        ij = np.stack(np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij"), -1).reshape(-1, 2)
        nodes = lo + (ij + 0.5) * h
        dist, nearest = tree.query(nodes, distance_upper_bound=reach)
        inside = np.isfinite(dist)
        if np.count_nonzero(inside) <= MAX_GRID_NODES:
            return nodes[inside], ij[inside], nearest[inside], h
        h *= math.sqrt(np.count_nonzero(inside) / MAX_GRID_NODES) * 1.01


def mode_variances(prior: DeviationPrior, samples: TracePoints, center: np.ndarray) -> np.ndarray:
    """Variances (m,) mm^2 of the prior's eigenmodes over the covered region, largest first
    (each a mode's mean square over the region; they sum to the mean prior variance)."""
    xy, ij, nearest, h = region_grid(samples, prior.wavelength_mm)
    offsets = np.arange(int(ij.max()) + 1) * h
    table = jinc_kernel(np.zeros((1, 2)), np.stack(np.meshgrid(offsets, offsets, indexing="ij"), -1)
                        .reshape(-1, 2), prior.wavelength_mm).reshape(len(offsets), len(offsets))
    di = np.abs(ij[:, None, 0] - ij[None, :, 0])
    dj = np.abs(ij[:, None, 1] - ij[None, :, 1])
    cov = prior.rms_mm ** 2 * table[di, dj]
    del di, dj
    # the placement terms need the nominal's slope: the nearest trace sample's (within lambda / 4)
    basis = placement_basis(Sites(xy, samples.sites.grad[nearest]), center) * prior.basis_sd
    cov += basis @ basis.T
    cov /= len(ij)
    values: np.ndarray = eigvalsh(cov, overwrite_a=True, check_finite=False, driver="evr")[::-1]
    out: np.ndarray = np.maximum(values, 0.0)
    return out


def truncation_dof(variances: np.ndarray, target_sd_mm: float) -> int:
    """The fewest leading modes n with ``sum(variances[n:]) <= target_sd_mm^2``
    (``variances`` (m,) largest first, as :func:`mode_variances` gives them)."""
    tail = np.cumsum(variances[::-1])[::-1]      # tail[n] = sum of variances[n:]
    within = np.flatnonzero(tail <= target_sd_mm ** 2)
    return int(within[0]) if len(within) else len(variances)


def region_dof(prior: DeviationPrior, samples: TracePoints, center: np.ndarray, target_sd_mm: float) -> int:
    """The truncation dof (:func:`truncation_dof`) of the prior over the region the trace
    ``samples`` cover, placement centre ``center`` (2,) mm, at the pointwise ``target_sd_mm``."""
    return truncation_dof(mode_variances(prior, samples, center), target_sd_mm)


class Deferred:
    """A float field of a frozen dataclass given either as a value or as a function of no
    arguments, called when the field is first read and its value kept (a figure a caller
    may never read costs nothing).  Give a ``functools.partial`` of a module-level function
    where the object may be pickled.  The field's default is NaN (not counted)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = f"_deferred_{name}"

    def __get__(self, obj: Any, owner: type | None = None) -> float:
        if obj is None:
            return math.nan   # the dataclass's default
        value = obj.__dict__[self.slot]
        if callable(value):
            value = float(value())
            obj.__dict__[self.slot] = value
        return float(value)

    def __set__(self, obj: Any, value: float | Callable[[], float]) -> None:
        obj.__dict__[self.slot] = value
