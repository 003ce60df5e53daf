"""What the field plans of one sequential round share, computed once (pure).

A round's plans (:func:`app.probing.field.plan_field` with ``fixed``: the pointwise targets
a round's search tries, :mod:`app.reconstruction.field_forecast`) differ only in the target;
the prior, the traces and the stations already touched are the same.  So they share

* the region (:func:`app.probing.field_region.field_region`) at the prior's wavelength;
* the greedy state after the touched stations (:class:`app.probing.field.GreedyField` with
  the ``fixed`` stations added first), and where a looser target's greedy sequence stopped:
  a plan for a tighter one continues from a copy of it;
* the rows of the unit kernel (:func:`app.probing.deviation_prior.jinc_kernel`, the
  Bessel function: most of the prior covariance's cost) between a station and the trace
  samples (the fresh posterior every plan checks its stations on): a greedy sequence does
  not depend on the target until it stops, so the plans of one round choose mostly the
  same stations.  The placement part of the covariance is computed with the plan's own
  stations, as a plan without the reuse does (a matrix product's last bit depends on its
  shape).

Each is the very computation a plan without it does (the same operations on the same
numbers), kept: a plan with a :class:`PlanReuse` gives the same stations and figures to the
bit (the kernel is elementwise: a row is the same whichever block computed it).  One object
per round: it holds the round's kernel rows (stations x samples, 8 bytes each) until it is
dropped.

Pure: numpy.  Units: mm.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import DeviationPrior, Sites, jinc_kernel
from app.probing.field_posterior import KernelRows
from app.probing.field_region import FieldRegion, TopSampler, field_region

if TYPE_CHECKING:
    from app.probing.field import GreedyField


def _copy(greedy: GreedyField) -> GreedyField:
    """A copy of ``greedy`` to go on from: the arrays it changes in place copied (the others
    are replaced, never changed, as it goes on), only their rows in use (n stations: R (n, N)
    and L (n, n), at least one row; the greedy's room for more, up to as many again, is made
    when it adds the next station)."""
    out = copy.copy(greedy)
    n = max(len(greedy.chosen), 1)
    out.rows, out.low, out.chosen = greedy.rows[:n].copy(), greedy.low[:n, :n].copy(), list(greedy.chosen)
    return out


def _greedy_key(prior: DeviationPrior, sites: Sites, center: np.ndarray, fixed: int) -> tuple[object, ...]:
    """What a kept greedy state is kept under: the prior, the centre, the sites bit for bit, ``fixed``."""
    return (prior, center.tobytes(), sites.xy.tobytes(), sites.grad.tobytes(), fixed)


class PlanReuse:
    """The shared parts of one round's field plans (see the module doc); pass the same
    object to every :func:`app.probing.field.plan_field` call of the round."""

    def __init__(self) -> None:
        self._regions: dict[tuple[object, ...], tuple[Sequence[TracePolyline], FieldRegion]] = {}
        self._starts: dict[tuple[object, ...], GreedyField] = {}
        self._stops: dict[tuple[object, ...], dict[tuple[float, int], GreedyField]] = {}
        self._spines: dict[tuple[object, ...], np.ndarray] = {}   # per key: the longest kept state's R
        self._rows: dict[tuple[object, ...], tuple[Sites, dict[bytes, np.ndarray]]] = {}

    def region(self, paths: Sequence[TracePolyline], wavelength_mm: float, top: TopSampler | None) -> FieldRegion:
        """:func:`app.probing.field_region.field_region` of ``paths``, kept per wavelength and top."""
        key = (tuple(id(p) for p in paths), wavelength_mm, id(top))
        kept = self._regions.get(key)
        if kept is None:
            kept = (list(paths), field_region(paths, wavelength_mm, top))   # the paths held: their ids stay theirs
            self._regions[key] = kept
        return kept[1]

    def start(self, prior: DeviationPrior, sites: Sites, center: np.ndarray, fixed: int,
              make: Callable[[], GreedyField], stop: tuple[float, int] | None = None) -> GreedyField:
        """A copy of the greedy state ``make()`` gives over ``sites`` (N,) after its first
        ``fixed`` sites were added (kept per prior, centre and sites, bit for bit).  ``stop``:
        (target variance mm^2, least stations) of an automatic count: the state where the
        sequence of a looser or equal target stopped (:meth:`stopped`), the most stations
        such, when one was kept: a step's choice does not depend on the target, and a looser
        target's stop comes first, so the tighter sequence passes through that state."""
        key = _greedy_key(prior, sites, center, fixed)
        kept = self._starts.get(key)
        if kept is None:
            kept = make()
            self._starts[key] = kept
        looser = [g for (t, least), g in self._stops.get(key, {}).items()
                  if stop is not None and least == stop[1] and t >= stop[0]]
        return _copy(max(looser, key=lambda g: len(g.chosen)) if looser else kept)

    def stopped(self, prior: DeviationPrior, sites: Sites, center: np.ndarray, fixed: int,
                stop: tuple[float, int], greedy: GreedyField) -> None:
        """Keep (a copy of) ``greedy`` where its first sequence for ``stop`` stopped (as :meth:`start`).

        The kept states of one key are points of one greedy sequence, so the rows R of the
        one with fewer stations are the first rows of the other's: they are held once (the
        longest R, the others views of its first rows) where they are equal bit for bit,
        checked here (a state whose rows differ keeps its own)."""
        key = _greedy_key(prior, sites, center, fixed)
        kept = _copy(greedy)
        stops = self._stops.setdefault(key, {})
        spine = self._spines.get(key)
        n = len(kept.rows)
        if spine is None:
            self._spines[key] = kept.rows
        elif n <= len(spine) and np.array_equal(spine[:n], kept.rows):
            kept.rows = spine[:n]
        elif n > len(spine) and np.array_equal(kept.rows[:len(spine)], spine):
            for other in stops.values():  # the shorter states: views of the longer R
                if other.rows.base is spine or other.rows is spine:
                    other.rows = kept.rows[:len(other.rows)]
            self._spines[key] = kept.rows
        stops[stop] = kept

    def jinc(self, xy: np.ndarray, where: Sites, wavelength_mm: float) -> KernelRows:
        """:func:`app.probing.deviation_prior.jinc_kernel` (n, N) of the points ``xy`` (n, 2)
        and ``where`` (N,), its rows kept per point (for this wavelength and ``where``); given
        as those rows (:class:`app.probing.field_posterior.KernelRows`), not a new (n, N) copy."""
        key = (wavelength_mm, id(where))
        kept = self._rows.get(key)
        if kept is None:
            kept = (where, {})   # ``where`` held: its id stays its own
            self._rows[key] = kept
        rows = kept[1]
        keys = [row.tobytes() for row in np.ascontiguousarray(xy)]
        missing = list(dict.fromkeys(k for k in keys if k not in rows))
        if missing:
            first = {k: i for i, k in reversed(list(enumerate(keys)))}
            rows.update(zip(missing, jinc_kernel(xy[[first[k] for k in missing]], where.xy, wavelength_mm)))
        return KernelRows([rows[k] for k in keys], len(where.xy))
