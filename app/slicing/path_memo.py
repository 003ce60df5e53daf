"""What the toolpath planner remembers between layers: a prismatic stretch of a part (a cube,
a tube, a plate's walls) repeats one section bit for bit once its collinear vertices are
dropped, so its unordered paths are made once (:class:`PathMemo`), and a layer that repeats
a section, its bead height and the nozzle's start exactly is ordered and measured once
(:class:`LayerMemo`): its pieces, end and statistics are those of the layer it repeats."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import numpy as np
import numpy.typing as npt

from app.slicing.rings import Island, following, preceding

if TYPE_CHECKING:
    from app.slicing.toolpath import ToolpathParams

# a vertex this close to the line through its neighbours adds nothing to a ring: ten times the
# quantum of the layers the toolpath job reads (layers.npz holds 6 decimals, so a vertex on a
# straight wall may sit ~1.4e-6 mm off the line through its rounded neighbours)
COLLINEAR_MM = 1e-5
_SEPARATOR = np.array([[np.nan, np.nan]])
T = TypeVar("T")

SectionKey = tuple[bytes, float, int]


def _without_collinear(ring: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``ring`` (n, 2) mm without the vertices that lie on the line through their neighbours
    (within ``COLLINEAR_MM``): a mesh's side faces cut a straight wall into pieces whose
    joints move from layer to layer; the wall is the same."""
    prev, nxt = preceding(ring), following(ring)
    chord = np.hypot(*(nxt - prev).T)
    cross = np.abs((ring[:, 0] - prev[:, 0]) * (nxt[:, 1] - prev[:, 1])
                   - (ring[:, 1] - prev[:, 1]) * (nxt[:, 0] - prev[:, 0]))
    keep = cross > COLLINEAR_MM * chord
    return ring[keep] if np.count_nonzero(keep) >= 3 else ring


def normalised(islands: tuple[Island, ...]) -> tuple[Island, ...]:
    """``islands`` with every ring's collinear vertices dropped (:func:`_without_collinear`):
    the same region, and the same arrays for the same section at another height."""
    return tuple(Island(_without_collinear(isl.outer), tuple(_without_collinear(h) for h in isl.holes))
                 for isl in islands)


def _geometry(islands: tuple[Island, ...]) -> bytes:
    """The exact bytes of every ring of ``islands`` (NaN-separated)."""
    rings = [r for isl in islands for r in (isl.outer, *isl.holes, _SEPARATOR)]
    return np.concatenate(rings).tobytes() if rings else b""


class _Recent(Generic[T]):
    """At most ``size`` values by key, the oldest dropped first."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.entries: dict[Any, T] = {}

    def get(self, key: Any) -> T | None:
        found = self.entries.pop(key, None)
        if found is not None:
            self.entries[key] = found
        return found

    def put(self, key: Any, value: T) -> None:
        if key not in self.entries and len(self.entries) >= self.size:
            self.entries.pop(next(iter(self.entries)))
        self.entries[key] = value


class PathMemo(Generic[T]):
    """The last few sections' paths (``make(islands, layer_index, params)`` of the normalised
    islands) by their exact geometry and infill angle; at most ``size`` sections."""

    def __init__(self, params: ToolpathParams, make: Callable[[tuple[Island, ...], int, ToolpathParams], T],
                 size: int = 4) -> None:
        self.params = params
        self.make = make
        self.normal: _Recent[tuple[bytes, tuple[Island, ...]]] = _Recent(size)
        self.paths: _Recent[T] = _Recent(size)
        # the ring arrays of the section seen last (held: their ids stay theirs) and its normal form
        self._last: tuple[list[np.ndarray | None], tuple[bytes, tuple[Island, ...]]] | None = None

    def key(self, islands: tuple[Island, ...], layer_index: int) -> tuple[SectionKey, tuple[Island, ...]]:
        """The section's key (normalised geometry, infill angle, layer parity) and its
        normalised islands (a section seen as it is lately is not normalised again; the very ring
        arrays of the section before, a prismatic stretch's shared rings, are not even read)."""
        rings = [ring for isl in islands for ring in (isl.outer, *isl.holes, None)]
        last = self._last
        if last is not None and len(last[0]) == len(rings) and all(a is b for a, b in zip(last[0], rings)):
            known = last[1]
        else:
            raw = _geometry(islands)
            found = self.normal.get(raw)
            if found is None:
                normal = normalised(islands)
                found = (_geometry(normal), normal)
                self.normal.put(raw, found)
            known = found
            self._last = (rings, known)
        p = self.params
        return (known[0], round((p.angle_deg + layer_index * p.angle_step_deg) % 360.0, 9), layer_index % 2), known[1]

    def lookup(self, key: SectionKey, normal: tuple[Island, ...], layer_index: int) -> T:
        """The paths of the section ``key`` (made from ``normal`` unless remembered)."""
        found = self.paths.get(key)
        if found is None:
            found = self.make(normal, layer_index, self.params)
            self.paths.put(key, found)
        return found


class ShellMemo(Generic[T]):
    """The last few sections' paths that do not turn with the layer (``make(islands, params)``
    of the normalised islands: the perimeters and thin walls) by their exact geometry alone;
    :class:`PathMemo`'s keys also hold the infill angle and parity, so a prismatic stretch
    has up to four of those for one section (angle steps of 90 degrees)."""

    def __init__(self, params: ToolpathParams, make: Callable[[tuple[Island, ...], ToolpathParams], T],
                 size: int = 4) -> None:
        self.params = params
        self.make = make
        self.recent: _Recent[T] = _Recent(size)

    def get(self, normal: tuple[Island, ...]) -> T:
        """The paths of the section ``normal`` (made unless remembered)."""
        geometry = _geometry(normal)
        found = self.recent.get(geometry)
        if found is None:
            found = self.make(normal, self.params)
            self.recent.put(geometry, found)
        return found


class LayerMemo(Generic[T]):
    """The last few layers' planned results by (section key, bead height mm, start (2,) mm)."""

    def __init__(self, size: int = 8) -> None:
        self.recent: _Recent[T] = _Recent(size)

    def get(self, key: SectionKey, height_mm: float, start: npt.NDArray[np.float64]) -> T | None:
        return self.recent.get((key, height_mm, np.asarray(start, dtype=np.float64).tobytes()))

    def put(self, key: SectionKey, height_mm: float, start: npt.NDArray[np.float64], value: T) -> None:
        self.recent.put((key, height_mm, np.asarray(start, dtype=np.float64).tobytes()), value)
