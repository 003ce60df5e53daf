"""Scanning plans: passes of a height sensor along the traces and rasters over the field,
mixed to reach the target in the least machine time.

The part's top is cut into square tiles of ``tile_mm``; each tile holding traces is either
**trace-scanned** (one pass along each trace whose middle lies in it, in nearest-neighbour
order, hopping between them) or **rastered** (lines along x at ``spacing_mm`` across the
tile), whichever the cost model (:mod:`app.probing.scan_cost`) prices lower; consecutive
rastered tiles of one row of tiles share long lines (fewer ramps).  Rows run in a serpentine:
a row's raster lines start at the end nearer to where the pass before ended, and a raster
line that ends within one spacing of the next row's first line runs on into it without a
hop (as the lines of a row do).
A pass follows the nominal top at the sensor's zero: the spot's path is sampled every
``step_mm`` and the carriage is the spot minus the sensor's offset, so a reading is the
deviation (far inside the sensor's range).  The plan's predicted bound (coverage x the
largest posterior sd over the traces, :func:`app.reconstruction.scan_field.predicted_sd`)
is judged before anything moves; a raster spacing that misses the target is halved.

Pure: numpy/scipy.  Units: mm, s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from app.domain.errors import InvalidInput
from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import DeviationPrior, Sites, path_gradient
from app.probing.scan_cost import MotionCost, link_time, nearest_order, pass_time

Height = Callable[[np.ndarray], np.ndarray]


class ScanPlanError(InvalidInput):
    """Scan plan parameters that cannot be used."""


@dataclass(frozen=True)
class ScanPass:
    """One pass: spot path (m, 3) mm (xy and the nominal top), kind "trace" or "raster",
    its trace index (-1 for raster lines) and whether the machine hops before it."""

    spot: np.ndarray
    kind: str
    trace: int
    hop: bool

    @property
    def length_mm(self) -> float:
        return float(np.sum(np.linalg.norm(np.diff(self.spot, axis=0), axis=1)))

    def carriage(self, offset_mm: Sequence[float]) -> np.ndarray:
        """Carriage waypoints (m, 3): the spot minus the sensor offset (the zero on the top)."""
        out: np.ndarray = self.spot - np.asarray(offset_mm, dtype=float)
        return out


@dataclass(frozen=True)
class ScanPlan:
    """Passes in order, their machine seconds (scan, links) and what each tile became."""

    passes: list[ScanPass]
    scan_s: float
    link_s: float
    tiles: dict[str, int] = field(default_factory=dict)

    @property
    def machine_s(self) -> float:
        return self.scan_s + self.link_s

    @property
    def length_mm(self) -> float:
        return float(sum(p.length_mm for p in self.passes))

    def samples(self, cost: MotionCost, rate_hz: float) -> np.ndarray:
        """Spot positions (n, 2) of every sample the plan stores (nominal, no time offset)."""
        out = []
        for p in self.passes:
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p.spot[:, :2], axis=0), axis=1))])
            at = np.arange(0.0, s[-1], cost.scan_mm_s / rate_hz)
            out.append(np.column_stack([np.interp(at, s, p.spot[:, 0]), np.interp(at, s, p.spot[:, 1])]))
        return np.concatenate(out) if out else np.zeros((0, 2))


def _dense(xy: np.ndarray, step_mm: float) -> np.ndarray:
    """The polyline xy (m, 2) resampled every ~step_mm (ends kept)."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    at = np.linspace(0.0, s[-1], max(2, int(math.ceil(s[-1] / step_mm)) + 1))
    return np.column_stack([np.interp(at, s, xy[:, 0]), np.interp(at, s, xy[:, 1])])


def _cells(xy: np.ndarray, x0: float, y0: float, tw: float, th: float, nx: int, ny: int) -> set[tuple[int, int]]:
    """The tiles the points xy (n, 2) fall in."""
    cx = np.clip(((xy[:, 0] - x0) // tw).astype(int), 0, nx - 1)
    cy = np.clip(((xy[:, 1] - y0) // th).astype(int), 0, ny - 1)
    return {(int(a), int(b)) for a, b in zip(cx, cy)}


def _on_top(xy: np.ndarray, height: Height) -> np.ndarray:
    return np.column_stack([xy, height(xy)])


def _raster_ys(y0: float, y1: float, spacing: float) -> np.ndarray:
    """Raster line ordinates (k,) from y0 to y1 inclusive, at most ``spacing`` apart (the rim
    lines lie on the bounds: no trace point is extrapolated to)."""
    return np.linspace(y0, y1, max(2, int(math.ceil((y1 - y0) / spacing)) + 1))


def _raster_lines(x0: float, x1: float, ys: np.ndarray, step: float, height: Height) -> list[np.ndarray]:
    lines = []
    for i, y in enumerate(ys):
        xs = (x0, x1) if i % 2 == 0 else (x1, x0)
        lines.append(_on_top(_dense(np.array([[xs[0], y], [xs[1], y]]), step), height))
    return lines


def _row_ys(ys: np.ndarray, row: int, y0: float, th: float, ny: int) -> np.ndarray:
    """The raster ordinates that belong to tile row ``row`` (the last row keeps its top)."""
    lo, hi = y0 + row * th, y0 + (row + 1) * th
    out: np.ndarray = ys[(ys >= lo - 1e-9) & ((ys < hi - 1e-9) | (row == ny - 1))]
    return out


def _continued(lines: list[np.ndarray], last: ScanPass | None, spacing: float) -> tuple[list[np.ndarray], bool]:
    """A run of serpentine raster lines entered from the end of the pass before it: each line
    reversed when that starts the run nearer to it; and whether the run's first line needs a
    hop (not when a raster line ends within one spacing of it: the same straight move at scan
    height as between the lines of a run)."""
    if last is None:
        return lines, True
    here = last.spot[-1, :2]
    if np.linalg.norm(lines[0][-1, :2] - here) < np.linalg.norm(lines[0][0, :2] - here):
        lines = [line[::-1] for line in lines]
    near = float(np.linalg.norm(lines[0][0, :2] - here)) <= spacing * (1 + 1e-6)
    return lines, not (last.kind == "raster" and near)


def _trace_cost(paths: Sequence[np.ndarray], cost: MotionCost) -> float:
    if not paths:
        return 0.0
    starts = np.array([p[0, :2] for p in paths])
    ends = np.array([p[-1, :2] for p in paths])
    order, flipped = nearest_order(starts, ends)
    total, here = 0.0, None
    for i, f in zip(order, flipped):
        a, b = (ends[i], starts[i]) if f else (starts[i], ends[i])
        if here is not None:
            total += link_time(cost, float(np.linalg.norm(a - here)), hop=True)
        total += pass_time(cost, float(np.sum(np.linalg.norm(np.diff(paths[i], axis=0), axis=1))))
        here = b
    return total


def plan_scans(paths: Sequence[TracePolyline], height: Height, bounds: tuple[float, float, float, float],
               cost: MotionCost, spacing_mm: float, tile_mm: float = 30.0, step_mm: float = 2.0,
               mode: str = "mixed") -> ScanPlan:
    """Scan passes over the traces ``paths`` (nominal, xy frame of ``height``: top z (n,) at
    xy (n, 2)) inside ``bounds`` (x0, y0, x1, y1) mm.  ``mode``: "mixed" (per tile, the
    cheaper), "traces" or "raster" (every tile alike)."""
    if mode not in ("mixed", "traces", "raster"):
        raise ScanPlanError("mode must be mixed, traces or raster", field="mode", value=mode)
    for name, value in (("spacing_mm", spacing_mm), ("tile_mm", tile_mm), ("step_mm", step_mm)):
        if not (math.isfinite(value) and value > 0):
            raise ScanPlanError(f"{name} must be > 0", field=name, value=value)
    x0, y0, x1, y1 = bounds
    nx, ny = max(1, int(math.ceil((x1 - x0) / tile_mm))), max(1, int(math.ceil((y1 - y0) / tile_mm)))
    tw, th = (x1 - x0) / nx, (y1 - y0) / ny
    ys = _raster_ys(y0, y1, spacing_mm)
    tiles: dict[tuple[int, int], list[int]] = {}
    spots = [_on_top(_dense(p.points[:, :2], step_mm), height) for p in paths]
    for k, p in enumerate(paths):
        mid = p.at(np.array([p.length_mm / 2]))[0, :2]
        key = (min(nx - 1, max(0, int((mid[0] - x0) // tw))), min(ny - 1, max(0, int((mid[1] - y0) // th))))
        tiles.setdefault(key, []).append(k)
    choice: dict[tuple[int, int], str] = {}
    for key, members in tiles.items():
        if mode != "mixed":
            choice[key] = "trace" if mode == "traces" else "raster"
            continue
        tx = x0 + key[0] * tw
        lines = _raster_lines(tx, tx + tw, _row_ys(ys, key[1], y0, th, ny), step_mm, height)
        raster = sum(pass_time(cost, float(np.sum(np.linalg.norm(np.diff(line, axis=0), axis=1)))) for line in lines)
        raster += (len(lines) - 1) * link_time(cost, spacing_mm, hop=False)
        choice[key] = "trace" if _trace_cost([spots[k] for k in members], cost) < raster else "raster"
    # a rastered tile must cover every trace point in it: tiles that traces of rastered owners
    # reach are rastered too
    for key, members in list(tiles.items()):
        if choice[key] != "raster":
            continue
        for k in members:
            for cell in _cells(_dense(paths[k].points[:, :2], min(tw, th) / 4), x0, y0, tw, th, nx, ny):
                choice[cell] = "raster"
    passes: list[ScanPass] = []
    for row in range(ny):
        cols = range(nx) if row % 2 == 0 else range(nx - 1, -1, -1)
        run: list[int] = []

        def flush(run: list[int], row: int) -> None:
            if run:
                a, b = min(run), max(run)
                lines = _raster_lines(x0 + a * tw, x0 + (b + 1) * tw, _row_ys(ys, row, y0, th, ny), step_mm,
                                      height)
                lines, hop = _continued(lines, passes[-1] if passes else None, spacing_mm)
                passes.extend(ScanPass(line, "raster", -1, hop and i == 0) for i, line in enumerate(lines))
                run.clear()

        for col in cols:
            kind = choice.get((col, row))
            if kind == "raster":
                run.append(col)
                continue
            flush(run, row)
            if kind == "trace":
                members = tiles[(col, row)]
                starts = np.array([spots[k][0, :2] for k in members])
                ends = np.array([spots[k][-1, :2] for k in members])
                here = passes[-1].spot[-1, :2] if passes else None
                order, flipped = nearest_order(starts, ends, here)
                passes.extend(ScanPass(spots[members[i]][::-1] if f else spots[members[i]], "trace", members[i], True)
                              for i, f in zip(order, flipped))
        flush(run, row)
    scan_s = sum(pass_time(cost, p.length_mm) for p in passes)
    link_s = sum(link_time(cost, float(np.linalg.norm(b.spot[0, :2] - a.spot[-1, :2])), b.hop)
                 for a, b in zip(passes, passes[1:]))
    counts = {"trace": sum(1 for v in choice.values() if v == "trace"),
              "raster": sum(1 for v in choice.values() if v == "raster")}
    return ScanPlan(passes, float(scan_s), float(link_s), counts)


@dataclass(frozen=True)
class TargetedPlan:
    """The plan chosen for a target: the plan, its raster spacing, its predicted bound
    (coverage x the largest posterior sd over the trace points, mm) and every spacing tried
    with its bound and machine seconds."""

    plan: ScanPlan
    spacing_mm: float
    bound_mm: float
    tried: list[dict[str, float]]


def plan_to_target(paths: Sequence[TracePolyline], height: Height, slope: Callable[[np.ndarray], np.ndarray],
                   bounds: tuple[float, float, float, float], cost: MotionCost, prior: DeviationPrior,
                   coverage: float, target_mm: float, rate_hz: float, spacings_mm: Sequence[float],
                   mode: str = "mixed", block: int = 5) -> TargetedPlan:
    """The fastest of the plans at ``spacings_mm`` whose predicted bound meets ``target_mm``
    (their bounds judged with samples averaged in blocks of ``block``, noise
    ``prior.sigma_mm / sqrt(block)``, as the fit sees them); ``ScanPlanError`` naming
    ``spacings_mm`` when none does."""
    from app.reconstruction.scan_field import predicted_sd  # the fit's own posterior: one model

    query = Sites(np.concatenate([p.at(np.linspace(0, p.length_mm, 9))[:, :2] for p in paths]),
                  np.concatenate([path_gradient(p, np.linspace(0, p.length_mm, 9)) for p in paths]))
    center = np.array([(bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2])
    averaged = replace(prior, sigma_mm=prior.sigma_mm / math.sqrt(block))
    tried: list[dict[str, float]] = []
    best: TargetedPlan | None = None
    for spacing in sorted(spacings_mm, reverse=True):
        plan = plan_scans(paths, height, bounds, cost, spacing, mode=mode)
        xy = plan.samples(cost, rate_hz)
        xy = xy[: len(xy) // block * block].reshape(-1, block, 2).mean(axis=1)
        bound = coverage * float(predicted_sd(averaged, Sites(xy, slope(xy)), center, query, slope).max())
        tried.append({"spacing_mm": float(spacing), "bound_mm": bound, "machine_s": plan.machine_s})
        if bound <= target_mm and (best is None or plan.machine_s < best.plan.machine_s):
            best = TargetedPlan(plan, float(spacing), bound, tried)
    if best is None:
        raise ScanPlanError(f"no raster spacing of {list(spacings_mm)} meets the target {target_mm * 1e3:.2f} um",
                            field="spacings_mm", value=list(spacings_mm))
    return replace(best, tried=tried)
