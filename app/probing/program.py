"""The probe program: G-code that touches the part at each planned point.

Per point: retract to the travel height of the coming segment, move in X/Y at that height,
drop (rapid) to the approach height, probe along -Z at the probe feed, and on to the next.

Safe travel: the travel height of a segment is the part's highest point *along that
segment* (not just at its ends) plus ``clearance_mm``.  ``top`` is either a trimesh
(exact: the part is cut by the vertical plane through the segment and the section's
highest point inside the segment is taken; every segment of a program at once,
:mod:`app.probing.travel_height`) or a callable ``top(xy (m, 2)) -> z (m,)``
(NaN where off the part) sampled every ``sample_mm`` along the segment (plus both ends).

Dialects: ``g38`` (grbl/LinuxCNC, Marlin with G38 support): ``G38.2 Z<target> F<feed>``
from the approach height down to ``expected - overtravel_mm`` (an alarm if the probe never
triggers).  ``g30`` (Marlin): ``G30 X Y`` probes down at X/Y with the firmware's own
feed and limits; the program only positions it at the travel height.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Annotated, Any

import numpy as np
from annotated_types import Gt, Le

from app.domain.checks import require_positive
from app.gcode.writer import DEFAULT_PROBING_DIALECT, DIALECTS, ProgramBuilder
from app.geometry.tolerance import DEGENERATE_LENGTH_MM
from app.probing.selection import PlanError, ProbePlan
from app.probing.travel_height import segments_top_max

TopHeight = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ProbeProgramParams:
    """Probe program settings (mm, mm/min).

    approach_mm: the probing move starts this far above the expected trigger height; it
        must exceed the largest upward deviation of the real part from the nominal.
    overtravel_mm: the probe may travel this far below the expected height (G38.2 target).
    part_max_z_mm: highest point of the whole part if known; the program's first move
        raises Z to max(this, every travel height) + clearance before any X/Y move.
    The bounds in the annotations are the ranges a job may ask for (a kind's model reads them).
    """

    dialect: str = DEFAULT_PROBING_DIALECT
    probe_style: str | None = None
    clearance_mm: Annotated[float, Gt(0), Le(100)] = 2.0
    approach_mm: Annotated[float, Gt(0), Le(50)] = 1.0
    overtravel_mm: Annotated[float, Gt(0), Le(50)] = 1.0
    probe_feed_mm_min: Annotated[float, Gt(0), Le(10_000)] = 100.0
    sample_mm: float = 0.25
    part_max_z_mm: float | None = None
    decimals: int = 4

    def __post_init__(self) -> None:
        if self.dialect not in DIALECTS:
            raise PlanError(f"unknown dialect {self.dialect!r}", field="dialect",
                            value=self.dialect)
        style = self.style
        if style not in DIALECTS[self.dialect].probe_styles:
            raise PlanError(f"dialect {self.dialect} cannot probe with {style!r}",
                            field="probe_style", value=style)
        require_positive(self, ("clearance_mm", "approach_mm", "overtravel_mm",
                                "probe_feed_mm_min", "sample_mm"), PlanError)

    @property
    def style(self) -> str:
        """Probe style: given, or the dialect's first (grbl g38, Marlin g30)."""
        return self.probe_style or DIALECTS[self.dialect].probe_styles[0]


@dataclass(frozen=True)
class ProbeRecord:
    """Plan record of one probe point (mm).

    normal: the nominal outward unit surface normal at the station (placed frame, n_z > 0),
    which turns a ball-centre reading into a surface height (``app.calibration``); None
    when the plan has none."""

    index: int
    s_mm: float
    nominal: tuple[float, float, float]
    safe_z_mm: float
    approach_z_mm: float
    target_z_mm: float
    expected_trigger_z_mm: float
    normal: tuple[float, float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["nominal"] = list(self.nominal)
        d["normal"] = None if self.normal is None else list(self.normal)
        return d


@dataclass(frozen=True, eq=False)
class ProbeProgram:
    """gcode: program text.  records: one per probe point.  moves: (q, 3) planned tool-tip
    waypoints in order (for checks and viewers; G30 probing shown as its expected trigger).
    """

    gcode: str
    records: tuple[ProbeRecord, ...]
    moves: np.ndarray


def segment_top_max(top: Any, a: np.ndarray, b: np.ndarray, sample_mm: float) -> float:
    """Highest point (mm) of the part over the xy segment a-b ((2,) each); -inf if none."""
    return float(_travel_tops(top, np.atleast_2d(a), np.atleast_2d(b), sample_mm)[0])


def _travel_tops(top: Any, a: np.ndarray, b: np.ndarray, sample_mm: float) -> np.ndarray:
    """Highest point (mm) of the part over each xy segment a -> b ((m, 2) each), -inf where
    none: a mesh's exactly (:func:`app.probing.travel_height.segments_top_max`, all at
    once), a callable's sampled every ``sample_mm``."""
    if hasattr(top, "vertices") and hasattr(top, "faces"):
        return segments_top_max(top, a, b)
    out = np.full(len(a), -math.inf)
    for i, (p, q) in enumerate(zip(np.asarray(a, dtype=float), np.asarray(b, dtype=float))):
        n = max(2, int(math.ceil(float(np.linalg.norm(q - p)) / sample_mm)) + 1)
        t = np.linspace(0.0, 1.0, n)
        z = np.asarray(top(p + t[:, None] * (q - p)), dtype=float)
        z = z[np.isfinite(z)]
        out[i] = float(z.max()) if len(z) else -math.inf
    return out


def upward_normals(normals: np.ndarray | None, count: int) -> np.ndarray | None:
    """Unit normals (count, 3) turned to point up (n_z >= 0: a top surface probed along -Z),
    or None when ``normals`` is None or not (count, 3) finite and non-zero."""
    if normals is None:
        return None
    n = np.asarray(normals, dtype=float)
    if n.shape != (count, 3) or not np.isfinite(n).all():
        return None
    length = np.linalg.norm(n, axis=1, keepdims=True)
    if (length < DEGENERATE_LENGTH_MM).any():
        return None
    n = n / length
    out: np.ndarray | None = np.where(n[:, 2:3] < 0, -n, n)
    return out


def mesh_station_normals(mesh: Any, xy: np.ndarray) -> np.ndarray | None:
    """Outward unit normals (m, 3) of the mesh's top face straight below each station xy
    (m, 2) mm (the highest face a downward ray meets); None when a station misses the mesh."""
    q = np.atleast_2d(np.asarray(xy, dtype=float))[:, :2]
    origins = np.column_stack([q, np.full(len(q), float(mesh.bounds[1][2]) + 1.0)])
    dirs = np.tile([0.0, 0.0, -1.0], (len(q), 1))
    loc, ray, tri = mesh.ray.intersects_location(origins, dirs, multiple_hits=True)
    if len(loc) == 0:
        return None
    best = np.full(len(q), -1)
    top = np.full(len(q), -np.inf)
    for k in range(len(ray)):
        if loc[k, 2] > top[ray[k]]:
            top[ray[k]], best[ray[k]] = loc[k, 2], tri[k]
    if (best < 0).any():
        return None
    return upward_normals(np.asarray(mesh.face_normals)[best], len(q))


def build_probe_program(plan: ProbePlan, top: Any, params: ProbeProgramParams | None = None,
                        *, job_id: str | None = None) -> ProbeProgram:
    """Probe program for ``plan`` over a part whose top is ``top`` (trimesh or callable).

    Returns G-code, one :class:`ProbeRecord` per point and the planned tool-tip path.
    """
    p = params or ProbeProgramParams()
    pts = np.asarray(plan.points, dtype=float)
    if len(pts) == 0:
        raise PlanError("probe plan has no points", field="plan.points", value=0)
    b = ProgramBuilder(p.dialect, "probe_plan", job_id, decimals=p.decimals)
    b.comment(f"probe plan method={plan.method} points={len(pts)} style={p.style} "
              f"clearance={p.clearance_mm:g}mm")
    xy = pts[:, :2]
    # the first point's own column, then every segment between consecutive points, then the last's
    ends = _travel_tops(top, np.vstack([xy[:1], xy[:-1], xy[-1:]]), np.vstack([xy[:1], xy[1:], xy[-1:]]),
                        p.sample_mm)
    travel_tops = ends[:-1]
    approach = pts[:, 2] + p.approach_mm
    safe = []
    for i, t in enumerate(travel_tops):
        prev = approach[i - 1] if i else -math.inf
        floor = max(t, pts[i, 2], pts[i - 1, 2] if i else -math.inf) + p.clearance_mm
        safe.append(max(floor, approach[i], prev))
    start_z = max(max(safe), (p.part_max_z_mm + p.clearance_mm) if p.part_max_z_mm is not None
                  else -math.inf)
    b.rapid(z=start_z)
    moves: list[tuple[float, float, float]] = []
    records = []
    normals = upward_normals(plan.normals, len(pts))
    for i, (x, y, z) in enumerate(pts):
        if i == 0:
            b.rapid(x=x, y=y)
            moves.append((x, y, start_z))
            if start_z > safe[0]:
                b.rapid(z=safe[0])
        else:
            b.rapid(z=safe[i])
            moves.append((pts[i - 1, 0], pts[i - 1, 1], safe[i]))
            b.rapid(x=x, y=y)
        moves.append((x, y, safe[i]))
        b.comment(f"point {i} s={plan.s_mm[i]:.4f} expected z={z:.4f}")
        target = z - p.overtravel_mm
        if p.style == "g38":
            b.rapid(z=approach[i])
            moves.append((x, y, approach[i]))
            b.probe("g38", z=target, feed_mm_min=p.probe_feed_mm_min)
        else:
            b.probe("g30", x=x, y=y)
        moves.append((x, y, z))
        normal = None if normals is None else (float(normals[i, 0]), float(normals[i, 1]), float(normals[i, 2]))
        records.append(ProbeRecord(i, float(plan.s_mm[i]), (float(x), float(y), float(z)),
                                   float(safe[i]), float(approach[i]), float(target), float(z), normal))
    end_z = max(float(ends[-1]), pts[-1, 2]) + p.clearance_mm
    b.rapid(z=end_z)
    moves.append((pts[-1, 0], pts[-1, 1], end_z))
    b.end()
    return ProbeProgram(gcode=b.text(), records=tuple(records), moves=np.asarray(moves))
