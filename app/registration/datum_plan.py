"""Where to touch the part for registration, and how to find a side face with -Z touches.

:func:`plan_datum_probes` (part mesh, part frame): candidate touch points are sampled on
the mesh (seeded, area-weighted), kept when the probe can reach them (the ray from the
start point along the probe direction first meets the mesh at the point) and when they
keep ``margin_mm`` from the face's edges; then chosen greedily for D-optimality of the
placement fit (each pick maximises the variance it removes, r M^-1 r^T), at least
``min_spacing_mm`` apart.
* ``mode="sides"``: side-face touches probe horizontally along -n (a probe that triggers
  sideways, G38.2 X/Y), top touches probe along -Z.  Determines dx, dy, dz, rz.
* ``mode="z_only"``: only -Z touches (the mock's G30/G38.2 Z) on faces with n_z >=
  ``min_top_nz``: sloped faces make dx, dy, rz observable; a flat top leaves them
  unobservable, which the plan reports (``unobservable``) rather than hides.

:func:`find_edge` locates a vertical side face with -Z touches alone: bisection between a
point over the part and one beside it (a touch higher than ``part_threshold_z`` is on the
part), to ``resolution_mm``.  A ball tip of radius r catches the top edge up to r beyond
the wall, which is corrected.  The wall point it returns (machine frame) is a side datum
for :func:`~app.registration.registration.fit_placement`.

:func:`register_with_z_probe` runs a plan with a -Z probe callable (edges, then heights
at the placed points) and returns the placement with its covariance.  Lengths in mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
import trimesh
from annotated_types import Ge, Gt, Le

from app.domain.checks import require_declared_bounds, require_positive
from app.geometry.placement import Placement, apply_placement, remove_placement
from app.registration.registration import (
    PARAMETERS,
    DegenerateDatumError,
    Registration,
    RegistrationError,
    RegistrationParams,
    _unobservable,
    fit_placement,
    information_rows,
)

__all__ = ["DatumPlan", "DatumProbeParams", "DatumRegistration", "DatumTouch", "EdgeFind",
           "find_edge", "plan_datum_probes", "register_with_z_probe"]

_EPS_INFO = 1e-9


@dataclass(frozen=True, eq=False)
class DatumPlan:
    """Datum touches (part frame, mm).

    points: (n, 3) nominal touch points.  normals: (n, 3) outward face normals.
    directions: (n, 3) probe travel directions.  starts: (n, 3) where each probing move
    starts (``approach_mm`` back along the direction).  targets: (n, 3) end of the probing
    move (``overtravel_mm`` beyond the face).  faces: label per touch ("top", "+x", "-y",
    "side", "slope").  predicted_std: standard uncertainty per observable parameter for
    the plan's sigma (mm; rz in rad).  unobservable: parameters the plan cannot determine.
    """

    mode: str
    points: np.ndarray
    normals: np.ndarray
    directions: np.ndarray
    starts: np.ndarray
    targets: np.ndarray
    faces: tuple[str, ...]
    predicted_std: dict[str, float]
    unobservable: tuple[str, ...]
    pivot_xy: tuple[float, float]


def _first_hit(mesh: trimesh.Trimesh, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Distance (m,) along each ray to its first hit (inf when none)."""
    locs, ray_idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=True)
    dist = np.full(len(origins), np.inf)
    if len(ray_idx):
        t = np.einsum("ij,ij->i", locs - origins[ray_idx], dirs[ray_idx])
        np.minimum.at(dist, ray_idx, t)
    return dist


def _label(normal: np.ndarray, side: bool) -> str:
    if not side:
        return "top" if normal[2] > 0.99 else "slope"
    axis = int(np.argmax(np.abs(normal[:2])))
    if abs(normal[axis]) > 0.99:
        return ("+" if normal[axis] > 0 else "-") + "xy"[axis]
    return "side"


def _candidates(mesh: trimesh.Trimesh, mode: str, count: int, seed: int, min_top_nz: float,
                margin: float, approach: float) -> tuple[np.ndarray, ...]:
    pts, fid = trimesh.sample.sample_surface(mesh, count, seed=seed)
    nrm = mesh.face_normals[fid]
    side = np.abs(nrm[:, 2]) < 0.05
    top = nrm[:, 2] >= min_top_nz
    use = (side | top) if mode == "sides" else top
    pts, nrm, side = pts[use], nrm[use], side[use] & (mode == "sides")
    dirs = np.where(side[:, None], -nrm, np.array([0.0, 0.0, -1.0]))
    zmin, ztop = mesh.bounds[0][2], mesh.bounds[1][2] + 1.0
    ok = _first_hit(mesh, pts - dirs * approach, dirs) > approach - 1e-6
    down = np.array([[0.0, 0.0, -1.0]])
    for ox, oy in ((margin, 0.0), (-margin, 0.0), (0.0, margin), (0.0, -margin)):
        # the touch keeps margin from the face's edges: neighbours still on the part
        probe = np.where(side[:, None], pts - nrm * margin, pts + np.array([ox, oy, 0.0]))
        origin = np.column_stack([probe[:, :2], np.full(len(pts), ztop)])
        hit_z = ztop - _first_hit(mesh, origin, np.repeat(down, len(pts), axis=0))
        need = np.where(side, pts[:, 2] + margin, zmin + margin)
        ok &= np.isfinite(hit_z) & (hit_z >= need)
    ok &= np.where(side, pts[:, 2] >= zmin + margin, True)
    tangent = np.column_stack([-nrm[:, 1], nrm[:, 0], np.zeros(len(pts))])
    for sign in (1.0, -1.0):
        # side touches: the wall continues margin along it (not near a corner)
        shifted = pts + sign * margin * tangent
        reach = _first_hit(mesh, shifted - dirs * approach, dirs)
        ok &= ~side | (np.abs(reach - approach) < 1e-3)
    return pts[ok], nrm[ok], dirs[ok], side[ok]


def plan_datum_probes(mesh: trimesh.Trimesh, mode: str = "sides", count: int | None = None,
                      approach_mm: float = 2.0, overtravel_mm: float = 1.0,
                      margin_mm: float = 2.0, min_spacing_mm: float = 3.0,
                      candidates: int = 3000, seed: int = 0, min_top_nz: float = 0.3,
                      pivot_xy: tuple[float, float] | None = None,
                      sigma_mm: float = 0.001) -> DatumPlan:
    """Plan datum touches on a part ``mesh`` (part frame); see the module doc.

    count: touches (default 6 for "sides", 8 for "z_only").  pivot_xy: rotation axis
    (default the centre of the mesh's xy bounds).  Raises RegistrationError when no
    reachable candidate exists.
    """
    if mode not in ("sides", "z_only"):
        raise RegistrationError("mode must be 'sides' or 'z_only'", field="mode", value=mode)
    count = int(count or (6 if mode == "sides" else 8))
    if count < 1:
        raise RegistrationError("count must be >= 1", field="count", value=count)
    if pivot_xy is None:
        centre = mesh.bounds.mean(axis=0)
        pivot_xy = (float(centre[0]), float(centre[1]))
    pts, nrm, dirs, side = _candidates(mesh, mode, candidates, seed, min_top_nz, margin_mm,
                                       approach_mm)
    if len(pts) == 0:
        raise RegistrationError("no reachable datum candidates on this mesh", field="mesh",
                                value=mode)
    lever = max(float(np.sqrt(np.mean(np.sum((pts[:, :2] - pivot_xy) ** 2, axis=1)))), 1.0)
    rows = information_rows(pts, nrm, pivot_xy, lever)
    rows = rows / np.maximum(np.abs(np.einsum("ij,ij->i", nrm, dirs)), 1e-3)[:, None]
    info = _EPS_INFO * np.eye(4)
    free = np.ones(len(pts), dtype=bool)
    chosen: list[int] = []
    for _ in range(count):
        if not free.any():
            break
        inv = np.linalg.inv(info)
        gain = np.einsum("ij,jk,ik->i", rows, inv, rows)
        gain[~free] = -1.0
        best = int(np.argmax(gain))
        chosen.append(best)
        info += np.outer(rows[best], rows[best])
        free &= np.linalg.norm(pts - pts[best], axis=1) >= min_spacing_mm
    idx = np.array(chosen)
    info -= _EPS_INFO * np.eye(4)
    w, v = np.linalg.eigh(info)
    observable = w > 1e-6 * max(w.max(), 1e-30)
    unobservable: list[str] = []
    for k in np.flatnonzero(~observable):
        unobservable += [n for n in _unobservable(v[:, k], PARAMETERS) if n not in unobservable]
    keep = [i for i, n in enumerate(PARAMETERS) if n not in unobservable]
    std: dict[str, float] = {}
    if keep:
        cov = sigma_mm ** 2 * np.linalg.pinv(info[np.ix_(keep, keep)])
        for j, i in enumerate(keep):
            scale = lever if PARAMETERS[i] == "rz" else 1.0
            std[PARAMETERS[i]] = float(math.sqrt(max(cov[j, j], 0.0)) / scale)
    return DatumPlan(mode=mode, points=pts[idx], normals=nrm[idx], directions=dirs[idx],
                     starts=pts[idx] - dirs[idx] * approach_mm,
                     targets=pts[idx] + dirs[idx] * overtravel_mm,
                     faces=tuple(_label(nrm[i], bool(side[i])) for i in idx),
                     predicted_std=std, unobservable=tuple(unobservable),
                     pivot_xy=(float(pivot_xy[0]), float(pivot_xy[1])))


@dataclass(frozen=True)
class EdgeFind:
    """A side face found by -Z touches: wall point (3,) machine frame, mm (z: the part's
    top next to the edge), outward horizontal normal (3,), touches used, final bracket."""

    point: np.ndarray
    normal: np.ndarray
    touches: int
    bracket_mm: float


def find_edge(probe_z: Callable[[float, float], float], inside_xy: Any, outside_xy: Any,
              part_threshold_z: float, resolution_mm: float = 0.001,
              tip_radius_mm: float = 0.0, max_touches: int = 40) -> EdgeFind:
    """Bisect for the wall between ``inside_xy`` (over the part) and ``outside_xy``.

    probe_z(x, y) -> measured z of a -Z touch (machine frame).  A touch above
    ``part_threshold_z`` is on the part.  Raises RegistrationError when the ends do not
    straddle the wall or the resolution is not reached within ``max_touches``.
    """
    a = np.asarray(inside_xy, dtype=float)[:2]
    b = np.asarray(outside_xy, dtype=float)[:2]
    span = float(np.linalg.norm(b - a))
    if not (span > 0 and resolution_mm > 0):
        raise RegistrationError("inside and outside points must differ", field="outside_xy",
                                value=b.tolist())
    z_in = probe_z(*a)
    z_out = probe_z(*b)
    if not (z_in > part_threshold_z >= z_out):
        raise RegistrationError(
            f"edge search ends do not straddle the wall: z = {z_in:.3f} at {a.tolist()} and "
            f"{z_out:.3f} at {b.tolist()} (threshold {part_threshold_z})", field="inside_xy",
            value=[round(z_in, 4), round(z_out, 4)])
    touches, lo, hi, z_top = 2, 0.0, span, z_in
    direction = (b - a) / span
    while hi - lo > resolution_mm:
        if touches >= max_touches:
            raise RegistrationError(f"edge not resolved to {resolution_mm} mm within "
                                    f"{max_touches} touches", field="max_touches",
                                    value=max_touches)
        mid = 0.5 * (lo + hi)
        z = probe_z(*(a + mid * direction))
        touches += 1
        if z > part_threshold_z:
            lo, z_top = mid, z
        else:
            hi = mid
    wall = a + (0.5 * (lo + hi) - tip_radius_mm) * direction
    return EdgeFind(point=np.array([wall[0], wall[1], z_top]),
                    normal=np.array([direction[0], direction[1], 0.0]), touches=touches,
                    bracket_mm=hi - lo)


ProbeZ = Callable[[float, float], float]


@dataclass(frozen=True)
class DatumProbeParams:
    """How a :class:`DatumPlan` is touched with -Z probes (:func:`register_with_z_probe`).

    search_mm: an edge search runs from ``search_mm`` inside to ``search_mm`` outside the
    nominal wall, so it finds walls displaced by less than that (keep it below the plan's
    ``margin_mm``).  resolution_mm / tip_radius_mm / max_touches_per_edge: see
    :func:`find_edge`.  sigma_mm: probe repeatability (1 sigma).  pivot_xy: rotation axis
    of the estimated placement (mm, machine frame).  The bounds in the annotations are the
    ranges a register job may ask for (its parameter model reads them); a value outside them
    is refused here too."""

    search_mm: Annotated[float, Gt(0), Le(20)] = 1.5
    resolution_mm: Annotated[float, Gt(0), Le(1)] = 0.001
    tip_radius_mm: Annotated[float, Ge(0), Le(10)] = 0.0  # the largest stylus ball a machine profile declares
    max_touches_per_edge: int = 40
    sigma_mm: Annotated[float, Gt(0), Le(1)] = 0.001
    pivot_xy: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        require_positive(self, ("search_mm", "resolution_mm", "sigma_mm"), RegistrationError)
        require_declared_bounds(self, RegistrationError)


@dataclass(frozen=True)
class DatumTouch:
    """One datum measurement: face label, nominal point / outward normal used in the fit
    (3,) part frame, measured point (3,) machine frame, probe direction (3,), and the
    number of -Z touches it took (an edge search takes several)."""

    face: str
    nominal: np.ndarray
    normal: np.ndarray
    measured: np.ndarray
    direction: np.ndarray
    touches: int

    def to_dict(self) -> dict[str, Any]:
        return {"face": self.face, "nominal": self.nominal.tolist(), "normal": self.normal.tolist(),
                "measured": self.measured.tolist(), "touches": self.touches}


@dataclass(frozen=True, eq=False)
class DatumRegistration:
    """Placement from datum touches.  std: 1-sigma per estimated parameter (mm; rz rad).
    covariance: (4, 4) in :data:`PARAMETERS` order (mm, rad), zero rows/columns for
    parameters not estimated.  unobservable: parameters the touches cannot see (held 0).
    fits: the underlying fits, named by fit_names ("edges", "heights" or "z_only")."""

    placement: Placement
    std: dict[str, float]
    covariance: np.ndarray
    unobservable: tuple[str, ...]
    touches: tuple[DatumTouch, ...]
    fits: tuple[Registration, ...]
    fit_names: tuple[str, ...]

    @property
    def probe_count(self) -> int:
        return sum(t.touches for t in self.touches)

    def to_result(self) -> dict[str, Any]:
        """JSON form; lengths mm, angles degrees (covariance in mm and deg)."""
        names = [p for p in PARAMETERS if p in self.std]
        unit = {p: math.degrees(1.0) if p == "rz" else 1.0 for p in PARAMETERS}
        labels = [f"{p}_deg" if p == "rz" else f"{p}_mm" for p in names]
        idx = [PARAMETERS.index(p) for p in names]
        scale = np.array([unit[p] for p in names])
        cov = self.covariance[np.ix_(idx, idx)] * np.outer(scale, scale)
        return {"placement": self.placement.to_dict(),
                "std": {lab: self.std[p] * unit[p] for lab, p in zip(labels, names)},
                "covariance": {"parameters": labels, "matrix": cov.tolist()},
                "unobservable": list(self.unobservable),
                "rms_mm": {name: f.rms_mm for name, f in zip(self.fit_names, self.fits)},
                "probe_count": self.probe_count, "touches": [t.to_dict() for t in self.touches]}


def _edge_touch(plan: DatumPlan, i: int, probe_z: ProbeZ, floor_z: float,
                params: DatumProbeParams) -> DatumTouch:
    q, n = plan.points[i], plan.normals[i]
    inside, outside = q[:2] - n[:2] * params.search_mm, q[:2] + n[:2] * params.search_mm
    # the plan keeps the part's top >= q_z + margin next to a side touch: halfway to q_z
    edge = find_edge(probe_z, inside, outside, 0.5 * (floor_z + q[2]), params.resolution_mm,
                     params.tip_radius_mm, params.max_touches_per_edge)
    return DatumTouch(plan.faces[i], q.copy(), n.copy(), edge.point, edge.normal, edge.touches)


def _combine(parts: list[tuple[str, Registration, tuple[str, ...]]], pivot: tuple[float, float],
             unobservable: tuple[str, ...], touches: list[DatumTouch]) -> DatumRegistration:
    theta, std, cov = np.zeros(4), {}, np.zeros((4, 4))
    for _, reg, names in parts:
        idx = [PARAMETERS.index(p) for p in names]
        values = (reg.placement.dx, reg.placement.dy, reg.placement.dz, reg.placement.rz_rad)
        theta[idx] = [values[k] for k in idx]
        cov[np.ix_(idx, idx)] = reg.covariance
        std.update(reg.std)
    return DatumRegistration(Placement(float(theta[0]), float(theta[1]), float(theta[2]), float(theta[3]),
                                       pivot[0], pivot[1]), std, cov, unobservable,
                             tuple(touches), tuple(r for _, r, _ in parts),
                             tuple(n for n, _, _ in parts))


def register_with_z_probe(plan: DatumPlan, probe_z: ProbeZ, floor_z_mm: float,
                          params: DatumProbeParams | None = None,
                          surface_z: Callable[[float, np.ndarray], float] | None = None) -> DatumRegistration:
    """Touch ``plan`` with -Z probes only and fit the placement (mm, machine frame).

    probe_z(x, y) -> z: one -Z touch (machine frame); beside the part it meets the floor
    at about ``floor_z_mm`` (the part's bottom).  ``mode="sides"`` plans: each side touch
    becomes an edge search across the nominal wall (:func:`find_edge`), which fixes dx,
    dy, rz (fit 1, planar walls); top touches are then made at the points placed by fit 1,
    so each lands on its nominal point and measures the height there: fit 2 gives dz from
    them with a vertical normal, free of the slopes (a machining error of the top biases
    dz only).  The two fits share no parameter; their covariances form the blocks of
    ``covariance``.  ``mode="z_only"`` plans: one fit of the observable parameters from
    touches at the nominal xy (planar faces at the touch points; see the registration
    module doc for the bias of free-form tops).  ``surface_z(z_read, normal (3,))`` turns a
    height touch's reading into the surface height under it, given the outward normal of the
    touched face (a calibrated ball probe: radius along the normal, pre-travel); None: the
    reading is the surface (an ideal point probe).  Raises RegistrationError /
    DegenerateDatumError naming what cannot be determined.
    """
    params = params or DatumProbeParams()
    pivot = (float(params.pivot_xy[0]), float(params.pivot_xy[1]))

    def height(x: float, y: float, normal: np.ndarray) -> float:
        z = probe_z(x, y)
        return z if surface_z is None else float(surface_z(z, normal))

    vertical = np.abs(plan.directions[:, 2]) > 0.5
    if plan.mode == "z_only" or vertical.all():
        names = tuple(p for p in PARAMETERS if p not in plan.unobservable)
        touches = [DatumTouch(plan.faces[i], plan.points[i].copy(), plan.normals[i].copy(),
                              np.array([*plan.points[i][:2], height(float(plan.points[i][0]), float(plan.points[i][1]),
                                                                      plan.normals[i])]),
                              plan.directions[i].copy(), 1) for i in range(len(plan.points))]
        reg = _fit(touches, names, pivot, params)
        return _combine([("z_only", reg, names)], pivot, tuple(plan.unobservable), touches)
    edges = [_edge_touch(plan, int(i), probe_z, floor_z_mm, params) for i in np.flatnonzero(~vertical)]
    xy_names = ("dx", "dy", "rz")
    first = _fit(edges, xy_names, pivot, params)
    parts: list[tuple[str, Registration, tuple[str, ...]]] = [("edges", first, xy_names)]
    heights: list[DatumTouch] = []
    for i in np.flatnonzero(vertical):
        at = apply_placement(plan.points[i][None, :2], first.placement)[0]
        heights.append(DatumTouch(plan.faces[i], plan.points[i].copy(), np.array([0.0, 0.0, 1.0]),
                                  np.array([at[0], at[1], height(at[0], at[1], plan.normals[i])]),
                                  plan.directions[i].copy(), 1))
    if heights:
        # heights in the frame of fit 1: only dz is left (a z shift commutes with it)
        level = [DatumTouch(t.face, t.nominal, t.normal,
                            remove_placement(t.measured[None], first.placement)[0], t.direction, 1)
                 for t in heights]
        parts.append(("heights", _fit(level, ("dz",), pivot, params), ("dz",)))
    return _combine(parts, pivot, () if heights else ("dz",), edges + heights)


def _fit(touches: list[DatumTouch], names: tuple[str, ...], pivot: tuple[float, float],
         params: DatumProbeParams) -> Registration:
    if not touches:
        raise DegenerateDatumError(f"no datum touches to determine {list(names)}",
                                   field="plan", value=list(names))
    sigma = max(params.sigma_mm, params.resolution_mm / math.sqrt(12.0))
    return fit_placement(np.array([t.nominal for t in touches]), np.array([t.normal for t in touches]),
                         np.array([t.measured for t in touches]),
                         RegistrationParams(sigma_mm=sigma, estimate=names, pivot_xy=pivot),
                         directions=np.array([t.direction for t in touches]))
