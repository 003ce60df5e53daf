"""Slice a mesh into layers of closed rings: the entry point of the slicing package.

``slice_mesh(mesh, SliceParams) -> SliceResult``.  Layers are slabs
``[z_bottom, z_top]`` (mm); each carries the section sampled at ``z_sample`` as nested,
oriented rings (:class:`~app.slicing.rings.Island`) plus the multi-cavity slicing statistics (area,
ring counts, sigma, mu), the area deviation eps to the previous layer and the reason
its thickness was chosen.  Modes (see :mod:`app.slicing.adaptive`):

* ``uniform`` - slabs of ``layer_mm`` with the remainder distributed over all of them
  (default) or merged into the last one, never a sliver; sampled at mid-height;
* ``area`` - the seed's area-deviation rule (eps0, l_min, l_max), sampled at mid-height
  (``seed_sample="top"``: at the slab top, as published);
* ``cavity`` - the seed's multi-cavity refinement (S4 steps 1-11: sigma0, mu0, mu1, theta);
* ``cusp`` - our geometric-error rule: the largest thickness whose cusp height
  ``t * |n_z|`` stays below ``cusp_mm`` on every facet crossing the slab, with slab
  boundaries snapped to horizontal faces; sampled at mid-height.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Annotated, Literal, NamedTuple

import manifold3d
import numpy as np
import numpy.typing as npt
from annotated_types import Ge, Gt, Le

from app.domain.checks import require_declared_bounds, require_non_negative, require_positive
from app.slicing.cavity import cavity_mu
from app.slicing.errors import SlicingError
from app.slicing.mesh_prep import PreparedMesh
from app.slicing.rings import Island, SectionStats, following, oriented, per_array, section_stats, signed_area

SliceMode = Literal["uniform", "area", "cavity", "cusp"]
ThetaRule = Literal["indicator", "printed"]
SeedSample = Literal["top", "mid"]
Remainder = Literal["distribute", "merge"]


@dataclass(frozen=True)
class SliceParams:
    """Slicing parameters (lengths in mm).

    ``layer_mm``: uniform thickness.  ``l_min``/``l_max``: adaptive bounds.  ``eps0``:
    allowed relative area deviation.  ``sigma0``, ``mu0``, ``mu1``: multi-cavity
    discriminants.  ``theta_rule``: ``"indicator"`` (theta = 1 iff sigma >= sigma0, as the
    seed's text states) or ``"printed"`` (int(ln(sigma - sigma0 + 55) / 4) evaluated
    literally: it is 1 already from sigma >= sigma0 - 0.4018).  ``step9_resets_to_lmax``:
    read step 9 literally (a non-cavity layer always gets l_max, discarding the step found
    by the area rule); default False keeps the area rule's step.  ``seed_sample``: where the
    area/cavity modes take a layer's contour: ``"mid"`` (default: mid-height, inside the
    slab, halves the staircase error and never lands on a horizontal face at the slab top)
    or ``"top"`` (the plane Z' the seed stores); the rule itself is unchanged.
    ``remainder``: uniform mode's top, ``"distribute"`` or ``"merge"`` (see
    :func:`app.slicing.adaptive.uniform_plan`).
    ``cusp_mm``: allowed cusp
    height (cusp mode).  ``z_tol``: planes at the very bottom/top are moved this far into
    the part.  ``repair``: repair bad meshes instead of refusing them; ``max_hole_mm``: the
    longest hole boundary repair fills (None: the perimeter of the bounding box's largest face).
    The bounds in the annotations are the ranges a slice may ask for (the slice job's
    parameter model reads them); :meth:`validate` refuses a value outside them.
    """

    mode: SliceMode = "uniform"
    layer_mm: Annotated[float, Gt(0), Le(100)] = 0.2
    l_min: Annotated[float, Gt(0), Le(100)] = 0.03
    l_max: Annotated[float, Gt(0), Le(100)] = 0.1
    eps0: Annotated[float, Ge(0), Le(10)] = 0.05
    sigma0: Annotated[float, Ge(0), Le(1)] = 0.45
    mu0: Annotated[float, Ge(0), Le(1)] = 0.005
    mu1: Annotated[float, Ge(0), Le(1)] = 0.167
    theta_rule: ThetaRule = "indicator"
    step9_resets_to_lmax: bool = False
    cusp_mm: Annotated[float, Gt(0), Le(10)] = 0.02
    seed_sample: SeedSample = "mid"
    remainder: Remainder = "distribute"
    z_tol: float = 1e-5
    repair: bool = True
    max_hole_mm: Annotated[float, Gt(0), Le(100_000)] | None = None
    max_layers: int = 200_000

    def validate(self) -> None:
        """Raise :class:`SlicingError` naming the first bad field."""
        if self.mode not in ("uniform", "area", "cavity", "cusp"):
            raise SlicingError(f"unknown slicing mode {self.mode!r}", field="params.mode",
                               value=self.mode)
        require_positive(self, ("layer_mm", "l_min", "l_max", "cusp_mm", "z_tol"), SlicingError,
                         prefix="params.")
        if self.l_min > self.l_max:
            raise SlicingError(f"l_min ({self.l_min} mm) is larger than l_max "
                               f"({self.l_max} mm)", field="params.l_min", value=self.l_min)
        require_non_negative(self, ("eps0", "sigma0", "mu0", "mu1"), SlicingError,
                             prefix="params.")
        require_declared_bounds(self, SlicingError, prefix="params.")
        if self.mu0 > self.mu1:
            raise SlicingError(f"mu0 ({self.mu0}) is larger than mu1 ({self.mu1})",
                               field="params.mu0", value=self.mu0)
        if self.seed_sample not in ("top", "mid"):
            raise SlicingError(f"unknown seed_sample {self.seed_sample!r}",
                               field="params.seed_sample", value=self.seed_sample)
        if self.remainder not in ("distribute", "merge"):
            raise SlicingError(f"unknown remainder rule {self.remainder!r}",
                               field="params.remainder", value=self.remainder)
        if self.theta_rule not in ("indicator", "printed"):
            raise SlicingError(f"unknown theta rule {self.theta_rule!r}",
                               field="params.theta_rule", value=self.theta_rule)


@dataclass(frozen=True, eq=False)
class Layer:
    """One slab ``[z_bottom, z_top]`` (mm) and its section sampled at ``z_sample``.

    ``area``: net area mm^2; ``sigma``, ``mu``: the multi-cavity ratios; ``eps``: relative area
    deviation to the previous layer (0 for the first); ``reason``: why this thickness.
    """

    index: int
    z_bottom: float
    z_top: float
    z_sample: float
    islands: tuple[Island, ...]
    area: float
    ring_count: int
    inner_ring_count: int
    sigma: float
    mu: float
    eps: float
    reason: str

    @property
    def thickness(self) -> float:
        """Slab thickness, mm."""
        return self.z_top - self.z_bottom

    @property
    def z(self) -> float:
        """The slab top, mm (the height the layer is built to)."""
        return self.z_top


@dataclass(frozen=True, eq=False)
class SliceResult:
    """All layers of one part plus what was repaired or approximated.

    ``bounds``: (2, 3) mm; ``volume``: mm^3 of the (repaired) solid; ``repairs``: mesh
    repairs; ``notes``: other remarks (e.g. seed-rule interpretations).
    """

    layers: tuple[Layer, ...]
    params: SliceParams
    z_min: float
    z_max: float
    bounds: npt.NDArray[np.float64]
    volume: float
    repairs: tuple[str, ...]
    notes: tuple[str, ...] = ()

    @property
    def thicknesses(self) -> npt.NDArray[np.float64]:
        """(L,) slab thicknesses, mm."""
        return np.array([lay.thickness for lay in self.layers])


def section_at(solid: manifold3d.Manifold, z: float) -> tuple[Island, ...]:
    """Section of ``solid`` by the plane at height ``z`` (mm) as sorted islands."""
    islands = []
    section = solid.slice(float(z))
    whole = [np.asarray(p, dtype=np.float64) for p in section.to_polygons()]
    # one outer boundary (every other ring a hole in it): one island, its rings as decompose gives them
    # (the same arrays in the same order); else the islands one by one
    parts = [whole] if sum(signed_area(p) > 0 for p in whole) == 1 else \
        [[np.asarray(p, dtype=np.float64) for p in part.to_polygons()] for part in section.decompose()]
    for polys in parts:
        if not polys:
            continue
        areas = [abs(float(np.dot(p[:, 0], following(p[:, 1])) - np.dot(following(p[:, 0]), p[:, 1])))
                 for p in polys] if len(polys) > 1 else [0.0]
        k = int(np.argmax(areas))  # the outer ring: the largest
        holes = tuple(oriented(p, ccw=False) for i, p in enumerate(polys) if i != k)
        islands.append(Island(oriented(polys[k], ccw=True), holes))
    islands.sort(key=lambda i: (float(i.outer[:, 1].min()), float(i.outer[:, 0].min())))
    return tuple(islands)


class Section(NamedTuple):
    """One cross-section: its islands and their multi-cavity slicing statistics."""

    islands: tuple[Island, ...]
    stats: SectionStats


class Sampler:
    """Caches sections of one prepared mesh by height (planes nudged into the part)."""

    def __init__(self, prepared: PreparedMesh, z_tol: float) -> None:
        self.prepared = prepared
        self.z_tol = z_tol
        self._cache: dict[float | tuple[str, int], Section] = {}

    def clamp(self, z: float) -> float:
        """``z`` moved inside ``[z_min + z_tol, z_max - z_tol]``."""
        lo = self.prepared.z_min + self.z_tol
        hi = self.prepared.z_max - self.z_tol
        return min(max(z, lo), hi)

    def section(self, z: float) -> Section:
        """The section (islands, stats) at ``clamp(z)``; inside a prismatic band of the mesh
        (:func:`app.slicing.mesh_prep.prism_bands`: the same region at every height) the one
        taken first in that band, the same objects (its rings' collinear points, where the
        walls' diagonals cross, at that height)."""
        at = round(self.clamp(z), 12)
        band = self.prepared.prism_band(at)
        key: float | tuple[str, int] = at if band is None else ("band", band)
        if key not in self._cache:
            islands = section_at(self.prepared.solid, at)
            self._cache[key] = Section(islands, section_stats(islands))
        return self._cache[key]


def make_layer(index: int, z_bottom: float, z_top: float, z_sample: float,
               sampler: Sampler, prev_area: float | None, reason: str,
               params: SliceParams) -> Layer:
    """Build a :class:`Layer`; raises :class:`SlicingError` when the section is empty."""
    if not z_top - z_bottom > 0:
        raise SlicingError(f"layer {index} has zero thickness at z={z_top:.6g} mm",
                           field="params", value=float(z_top - z_bottom))
    islands, st = sampler.section(z_sample)
    if st.area <= 0:
        raise SlicingError(f"layer {index} at z={z_sample:.6g} mm has no area (the part is "
                           f"empty there)", field="mesh", value=round(float(z_sample), 6))
    eps = abs(st.area - prev_area) / prev_area if prev_area else 0.0
    return Layer(index=index, z_bottom=float(z_bottom), z_top=float(z_top),
                 z_sample=float(sampler.clamp(z_sample)), islands=islands, area=st.area,
                 ring_count=st.ring_count, inner_ring_count=st.inner_ring_count,
                 sigma=st.sigma, mu=cavity_mu(st, params.sigma0, params.theta_rule), eps=float(eps), reason=reason)


def translated(result: SliceResult, shift: npt.NDArray[np.float64]) -> SliceResult:
    """``result`` moved by ``shift`` (3,) mm: every ring, every z and the bounds (the machine
    placement of a part sliced in its own frame)."""
    dx, dz = np.asarray(shift[:2], dtype=np.float64), float(shift[2])
    move = per_array(lambda ring: ring + dx)  # layers that share a ring share the moved one

    layers = tuple(dataclasses.replace(
        lay, z_bottom=lay.z_bottom + dz, z_top=lay.z_top + dz, z_sample=lay.z_sample + dz,
        islands=tuple(Island(move(isl.outer), tuple(move(h) for h in isl.holes)) for isl in lay.islands))
        for lay in result.layers)
    return dataclasses.replace(result, layers=layers, z_min=result.z_min + dz, z_max=result.z_max + dz,
                               bounds=np.asarray(result.bounds, dtype=np.float64) + np.asarray(shift, dtype=float))
