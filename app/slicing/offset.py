"""Polygon offsets (Clipper2 through pyclipr) and the seed's beam / track-width compensation.

Offsets act on islands (outer CCW, holes CW); ``delta > 0`` grows the material,
``delta < 0`` shrinks it (outer rings move inward, holes grow).  Results are re-nested from
Clipper's PolyTree, so an offset that splits an island yields several islands.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pyclipr

from app.slicing.errors import SlicingError
from app.slicing.layers import Layer, SliceResult
from app.slicing.rings import Island, oriented, section_stats

CLIPPER_SCALE = 1_000_000  # integer units per mm inside Clipper2 (1 nm)

_JOINS = {"miter": pyclipr.JoinType.Miter, "round": pyclipr.JoinType.Round,
          "square": pyclipr.JoinType.Square}


def _tree_to_islands(node: pyclipr.PolyTreeD, out: list[Island]) -> None:
    """Append the islands under ``node`` (Clipper's PolyTree, in mm) to ``out``."""
    for child in node.children:          # children of the root / of a hole are outers
        holes: list[npt.NDArray[np.float64]] = []
        for hole in child.children:
            holes.append(oriented(np.asarray(hole.polygon, dtype=np.float64), ccw=False))
            _tree_to_islands(hole, out)
        out.append(Island(oriented(np.asarray(child.polygon, dtype=np.float64), ccw=True),
                          tuple(holes)))


def offset_islands(islands: tuple[Island, ...], delta: float, join: str = "miter",
                   miter_limit: float = 2.0) -> tuple[Island, ...]:
    """Offset all rings of ``islands`` by ``delta`` mm; returns the new islands (sorted)."""
    if not islands:
        return ()
    if join not in _JOINS:
        raise SlicingError(f"unknown join {join!r}", field="join", value=join)
    po = pyclipr.ClipperOffset()
    po.scaleFactor = CLIPPER_SCALE
    po.miterLimit = miter_limit
    po.addPaths([r for isl in islands for r in isl.rings()], _JOINS[join],
                pyclipr.EndType.Polygon)
    tree = po.execute2(float(delta))
    out: list[Island] = []
    _tree_to_islands(tree, out)
    out = [i for i in out if len(i.outer) >= 3 and i.area > 0]
    out.sort(key=lambda i: (float(i.outer[:, 1].min()), float(i.outer[:, 0].min())))
    return tuple(out)


@dataclass(frozen=True)
class BeamWidthTable:
    """Heat-affected (compensation) width per layer thickness, interpolated linearly.

    ``thickness_mm`` ascending; ``width_mm`` the contour offset (inward) at each thickness.
    Outside the table the end values are used.
    """

    thickness_mm: tuple[float, ...]
    width_mm: tuple[float, ...]

    def width(self, thickness: float) -> float:
        """Compensation width (mm) for a layer ``thickness`` (mm)."""
        t = np.asarray(self.thickness_mm, dtype=float)
        if len(t) == 0 or len(t) != len(self.width_mm) or np.any(np.diff(t) <= 0):
            raise SlicingError("beam width table needs ascending thicknesses and one width "
                               "each", field="beam.thickness_mm", value=list(self.thickness_mm))
        return float(np.interp(thickness, t, np.asarray(self.width_mm, dtype=float)))


#: The multi-cavity slicing paper: melt tracks 112/116/118/121/126 um at 20..40 um layers -> heat-affected widths.
SEED_HAZ_TABLE = BeamWidthTable(thickness_mm=(0.020, 0.025, 0.030, 0.035, 0.040),
                                width_mm=(0.021, 0.023, 0.024, 0.0255, 0.028))


def compensate_beam(result: SliceResult, table: BeamWidthTable | float = SEED_HAZ_TABLE,
                    join: str = "miter") -> SliceResult:
    """Offset every layer's rings inward by the table width for its thickness (or by a
    constant width in mm when ``table`` is a number, e.g. the API's ``offset_mm``).

    Returns a new :class:`~app.slicing.layers.SliceResult` whose layers carry the
    compensated islands and re-computed areas/ring counts; a layer that vanishes raises
    :class:`SlicingError` (the part is thinner than the beam compensation).
    """
    if not isinstance(table, BeamWidthTable):
        if not (np.isfinite(table) and table >= 0):
            raise SlicingError(f"beam offset must be >= 0 mm, got {table!r}",
                               field="offset_mm", value=table)
        table = BeamWidthTable((1.0,), (float(table),))
    layers: list[Layer] = []
    for lay in result.layers:
        w = table.width(lay.thickness)
        islands = offset_islands(lay.islands, -w, join)
        if not islands:
            raise SlicingError(f"layer {lay.index} at z={lay.z_top:.6g} mm vanishes after a "
                               f"{w * 1000:.1f} um beam offset", field="beam",
                               value=round(w, 6))
        st = section_stats(islands)
        layers.append(dataclasses.replace(
            lay, islands=islands, area=st.area, ring_count=st.ring_count,
            inner_ring_count=st.inner_ring_count))
    notes = (*result.notes, "beam compensation: contours offset inward by the interpolated "
             "heat-affected width of each layer thickness")
    return dataclasses.replace(result, layers=tuple(layers), notes=notes)
