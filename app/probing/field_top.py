"""The part's nominal top seen from above, for free field stations (``anywhere_on_top``).

A station anywhere on the top needs the nominal height there and the slope the placement
terms use (:mod:`app.probing.deviation_prior`).  On a faceted mesh a facet's own normal
jumps from face to face, so the slope is taken as the central difference of the first
downward ray hits ``SLOPE_STEP_MM`` to either side (the smoothing the traces' slopes get).
Uses the mesh's cached ray intersector (embree when installed).  Units: mm.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import trimesh

from app.probing.field_region import TopSample, TopSampler

if TYPE_CHECKING:
    from app.probing.deviation_prior import DeviationPrior, Sites

SLOPE_STEP_MM = 0.25


def first_hit_z(mesh: trimesh.Trimesh, xy: np.ndarray) -> np.ndarray:
    """Height (m,) mm of the first surface hit by a ray straight down at xy (m, 2); NaN on a miss."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    top = float(mesh.bounds[1][2]) + 1.0
    origins = np.column_stack([xy, np.full(len(xy), top)])
    down = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    face = np.asarray(mesh.ray.intersects_first(origins, down), dtype=np.int64)
    z = np.full(len(xy), np.nan)
    hit = face >= 0
    if hit.any():
        n = mesh.face_normals[face[hit]]
        p0 = mesh.triangles[face[hit], 0]
        ok = np.abs(n[:, 2]) > 1e-9
        zz = np.full(int(hit.sum()), np.nan)
        zz[ok] = p0[ok, 2] - ((xy[hit][ok] - p0[ok, :2]) * n[ok, :2]).sum(axis=1) / n[ok, 2]
        z[hit] = zz
    return z


def mesh_top_sampler(mesh: trimesh.Trimesh) -> TopSampler:
    """A :data:`app.probing.field_region.TopSampler` over ``mesh``'s upper surface."""

    def sample(xy: np.ndarray) -> TopSample:
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        h = SLOPE_STEP_MM
        offsets = np.array([[0, 0], [h, 0], [-h, 0], [0, h], [0, -h]])
        z = first_hit_z(mesh, (xy[None, :, :] + offsets[:, None, :]).reshape(-1, 2)).reshape(5, -1)
        grad = np.stack([(z[1] - z[2]) / (2 * h), (z[3] - z[4]) / (2 * h)], axis=1)
        ok = np.isfinite(z).all(axis=0)
        return TopSample(z[0], np.where(ok[:, None], grad, 0.0), ok)

    return sample


def field_sd_surface(mesh: trimesh.Trimesh, stations: Sites, center: np.ndarray, prior: DeviationPrior,
                     margin_mm: float, max_points: int = 20_000, lift_mm: float = 0.02
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The field's posterior sd over the part's top around the stations, for a colour map.

    A regular grid over the stations' xy box widened by ``margin_mm`` (at most ``max_points``
    nodes), heights from downward rays (lifted ``lift_mm`` so the map sits on the part),
    slopes by central differences.  Returns vertices (v, 3) mm, faces (f, 3) (cells whose
    four corners hit the part) and sd (v,) mm at the vertices.
    """
    from app.probing.deviation_prior import Sites
    from app.probing.field_posterior import posterior_sd

    lo = stations.xy.min(axis=0) - margin_mm
    hi = stations.xy.max(axis=0) + margin_mm
    step = max(float(np.sqrt(np.prod(hi - lo) / max_points)), 1e-3)
    gx = np.arange(lo[0], hi[0] + step / 2, step)
    gy = np.arange(lo[1], hi[1] + step / 2, step)
    xx, yy = np.meshgrid(gx, gy, indexing="ij")
    xy = np.column_stack([xx.ravel(), yy.ravel()])
    sample = mesh_top_sampler(mesh)(xy)
    ok = sample.ok
    sd = np.full(len(xy), np.nan)
    if ok.any():
        sd[ok] = posterior_sd(prior, stations, Sites(xy[ok], sample.grad[ok]), center)
    idx = np.arange(len(xy)).reshape(len(gx), len(gy))
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    cell_ok = ok[a] & ok[b] & ok[c] & ok[d]
    faces = np.concatenate([np.column_stack([a, b, c])[cell_ok], np.column_stack([a, c, d])[cell_ok]])
    vertices = np.column_stack([xy, np.where(ok, sample.z, 0.0) + lift_mm])
    used = np.unique(faces)
    remap = np.full(len(xy), -1)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces], sd[used]
