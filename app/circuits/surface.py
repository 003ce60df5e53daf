"""The measured surface a circuit is printed on, and what every printed point knows of it.

:class:`MeasuredSurface` is the one height function of a circuit program: the nominal top
(``nominal``: xy (m, 2) mm -> z (m,) mm and slope (m, 2)) plus the deviation the loop's
probes measured (``deviation``: xy, slope -> mean (m,) mm and its posterior sd (m,) mm, or
None where the deviation is interpolated between stations without a model).  Pad and area
fills are lifted onto it; the traces' compensated tips are checked against it.

:class:`PrintedPoints` gathers, per printed item, the worst predicted error (posterior sd),
its bound (``coverage`` x sd) and the smallest clearance of the nozzle over the surface;
:meth:`PrintedPoints.below` names the items whose nozzle would go below the surface plus
their standoff less a tolerance.

Pure: numpy.  Units: mm.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["MeasuredSurface", "PrintedPoints"]

Array = npt.NDArray[np.float64]
NominalTop = Callable[[Array], tuple[Array, Array]]                    # xy (m, 2) -> z (m,), slope (m, 2)
#: xy (m, 2), slope (m, 2), whether the sd is wanted -> mean (m,), sd (m,) | None
Deviation = Callable[[Array, Array, bool], tuple[Array, Array | None]]


@dataclass(frozen=True)
class MeasuredSurface:
    """Nominal top + measured deviation; ``coverage``: the bound is coverage x sd (None
    without a posterior); ``sd_step_mm``: the sd (smooth on the field's wavelength, and
    costly: one solve against every station per point) is judged at points this far apart
    along each stroke (and at its ends); None: at every point."""

    nominal: NominalTop
    deviation: Deviation
    coverage: float | None = None
    sd_step_mm: float | None = None

    def at(self, xy: Array, sd: bool = False) -> tuple[Array, Array | None]:
        """(surface z (m,) mm, posterior sd (m,) mm when ``sd`` and modelled, else None) at
        xy (m, 2) mm."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        z, slope = self.nominal(xy)
        mean, spread = self.deviation(xy, slope, sd)
        return np.asarray(z, dtype=float) + np.asarray(mean, dtype=float), spread


def _judged(xy: Array, step_mm: float | None) -> npt.NDArray[np.intp]:
    """Indices of the points (k, 2) of a stroke where the sd is judged: the first point of
    every ``step_mm`` of top-view length, and the last (all with ``step_mm`` None)."""
    if step_mm is None or len(xy) < 3:
        return np.arange(len(xy))
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    first = np.flatnonzero(np.diff(np.floor(s / step_mm), prepend=-1.0) > 0)
    return np.unique(np.concatenate([first, [len(xy) - 1]]))


@dataclass
class _Item:
    kind: str
    standoff_mm: float
    points: int = 0
    sd_mm: float = 0.0
    clearance_mm: float = np.inf
    low_mm: float = np.inf          # smallest clearance - standoff


@dataclass
class PrintedPoints:
    """Per item (name): the points printed, the worst sd, the smallest clearance (tip z -
    surface z) of the nozzle over the surface.  Strokes are gathered by :meth:`add` and the
    surface is evaluated once over all of them (in ``chunk`` points) when a figure is read: a
    board's thousands of strokes cost a few large evaluations, not two small ones each."""

    surface: MeasuredSurface
    items: dict[str, _Item] = field(default_factory=dict)
    chunk: int = 20_000
    _pending: list[tuple[str, Array, float]] = field(default_factory=list)

    def add(self, name: str, kind: str, tip: Array, standoff_mm: float) -> None:
        """Record the tip points (k, 3) mm of one stroke of item ``name`` printed at ``standoff_mm``."""
        tip = np.asarray(tip, dtype=float).reshape(-1, 3)
        item = self.items.setdefault(name, _Item(kind, standoff_mm))
        item.points += len(tip)
        self._pending.append((name, tip, standoff_mm))

    def _settle(self) -> None:
        """Evaluate the surface under every pending stroke at once and fold it into the items."""
        if not self._pending:
            return
        pending, self._pending = self._pending, []
        names = list(dict.fromkeys(n for n, _, _ in pending))
        index = {n: i for i, n in enumerate(names)}
        tips = np.vstack([t for _, t, _ in pending])
        owner = np.concatenate([np.full(len(t), index[n]) for n, t, _ in pending])
        standoff = np.concatenate([np.full(len(t), s) for _, t, s in pending])
        judged = np.concatenate([_judged(t[:, :2], self.surface.sd_step_mm) + start for (_, t, _), start in
                                 zip(pending, np.cumsum([0] + [len(t) for _, t, _ in pending[:-1]]))])
        z = np.concatenate([self.surface.at(tips[i:i + self.chunk, :2])[0] for i in range(0, len(tips), self.chunk)])
        clearance = tips[:, 2] - z
        clear = np.full(len(names), np.inf)
        low = np.full(len(names), np.inf)
        ok = np.isfinite(clearance)
        np.minimum.at(clear, owner[ok], clearance[ok])
        np.minimum.at(low, owner[ok], clearance[ok] - standoff[ok])
        worst_sd = np.zeros(len(names))
        sds = [self.surface.at(tips[judged[i:i + self.chunk], :2], sd=True)[1]
               for i in range(0, len(judged), self.chunk)]
        if sds and all(sd is not None for sd in sds):
            sd = np.concatenate([np.asarray(v, dtype=float) for v in sds if v is not None])
            good = np.isfinite(sd)
            np.maximum.at(worst_sd, owner[judged][good], sd[good])
        for n, i in index.items():
            item = self.items[n]
            item.clearance_mm = min(item.clearance_mm, float(clear[i]))
            item.low_mm = min(item.low_mm, float(low[i]))
            item.sd_mm = max(item.sd_mm, float(worst_sd[i]))

    def below(self, tolerance_mm: float) -> list[tuple[str, float, float]]:
        """Items whose nozzle comes below surface + standoff - ``tolerance_mm`` or below the
        surface itself: (name, smallest clearance, its standoff)."""
        self._settle()
        return [(n, i.clearance_mm, i.standoff_mm) for n, i in self.items.items()
                if i.clearance_mm < 0.0 or i.low_mm < -tolerance_mm]

    def as_dict(self) -> dict[str, Any]:
        """JSON form: ``items`` {name: {kind, points, sd_mm, bound_mm, clearance_min_mm,
        standoff_mm}}, the overall worst (``sd_mm``, ``bound_mm``, ``clearance_min_mm``) and
        ``bound_over_standoff``: the items whose bound reaches their standoff (the nozzle may
        touch the real surface there: probe them more)."""
        self._settle()
        k = self.surface.coverage
        modelled = k is not None

        def row(i: _Item) -> dict[str, Any]:
            return {"kind": i.kind, "points": i.points, "standoff_mm": i.standoff_mm,
                    "sd_mm": i.sd_mm if modelled else None, "bound_mm": k * i.sd_mm if k is not None else None,
                    "clearance_min_mm": i.clearance_mm if np.isfinite(i.clearance_mm) else None}

        rows = {n: row(i) for n, i in self.items.items()}
        sd = max((i.sd_mm for i in self.items.values()), default=0.0)
        clear = [i.clearance_mm for i in self.items.values() if np.isfinite(i.clearance_mm)]
        risky = sorted(n for n, i in self.items.items() if k is not None and k * i.sd_mm >= i.standoff_mm)
        return {"points": sum(i.points for i in self.items.values()), "coverage": k, "bound_over_standoff": risky,
                "sd_mm": sd if modelled else None, "bound_mm": k * sd if k is not None else None,
                "clearance_min_mm": min(clear) if clear else None, "items": rows}
