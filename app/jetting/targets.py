"""Print targets on the print grid: a part mask with a margin, its outer and hole edges.

Three sources: a mask image (PNG bytes, one pixel per print cell, white = part), a set
of polygon rings in mm (a part mesh slice; even-odd rule, so holes are simply inner
rings), or the seed's parametric square with a square hole. All validate before work.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import shapely
from PIL import Image, UnidentifiedImageError
from scipy import ndimage

from .errors import JettingError
from .params import DropParams, TargetSpec

FOUR_NEIGHBOURS = ndimage.generate_binary_structure(2, 1)
DEFAULT_MAX_CELLS = 25_000_000  # a 50 mm part at 600 dpi is 1.4 M cells


def check_cells(cells: int, max_cells: int, drop: DropParams) -> None:
    """Refuse grids larger than ``max_cells`` before allocating them."""
    if cells > max_cells:
        raise JettingError(f"{cells} print cells at {drop.dpi} dpi exceed the limit of {max_cells}",
                           field="drop.dpi", value=drop.dpi)


@dataclass(frozen=True)
class Target:
    """``mask``: (L, W) bool part cells (grid = part bounding box + margin);
    ``outer_edge`` / ``hole_edge``: (L, W) bool part cells touching the outside / a hole;
    ``interior``: (L, W) bool part cells farther than ``interior_mm`` from any edge;
    ``pitch_mm``: cell size."""

    mask: npt.NDArray[np.bool_]
    outer_edge: npt.NDArray[np.bool_]
    hole_edge: npt.NDArray[np.bool_]
    interior: npt.NDArray[np.bool_]
    pitch_mm: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape


def target_pad_cells(drop: DropParams, margin_mm: float) -> int:
    """Empty cells padded on each side of a part's bounding box (cells): the margin
    ``margin_mm`` (mm) at the print pitch, at least the drop kernel's radius plus 3."""
    kernel_radius = int(np.ceil(drop.radius_mm / drop.pitch_mm + 0.5)) - 1
    return max(int(np.ceil(margin_mm / drop.pitch_mm)), kernel_radius + 3)


def target_shape(part_cells: tuple[int, int], drop: DropParams, margin_mm: float = 0.25) -> tuple[int, int]:
    """Grid shape (L, W) cells of the target built around a part whose bounding box is
    ``part_cells`` (L, W) cells: that box plus :func:`target_pad_cells` on every side."""
    pad = 2 * target_pad_cells(drop, margin_mm)
    return int(part_cells[0]) + pad, int(part_cells[1]) + pad


def target_from_mask(mask: npt.ArrayLike, drop: DropParams, margin_mm: float = 0.25,
                     interior_mm: float = 0.5, field: str = "target.mask") -> Target:
    """Target from a boolean (L, W) part mask at the print pitch; pads ``margin_mm``."""
    part = np.asarray(mask, dtype=bool)
    if part.ndim != 2 or part.size == 0:
        raise JettingError("mask must be a non-empty 2-D image", field=field,
                           value=list(part.shape))
    if not part.any():
        raise JettingError("mask has no part cells (all black)", field=field,
                           value=list(part.shape))
    rows, cols = np.nonzero(part)
    part = part[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    extent_mm = min(part.shape) * drop.pitch_mm
    if drop.drop_diameter_um * 1e-3 > extent_mm:
        raise JettingError(
            f"drop diameter {drop.drop_diameter_um} um is larger than the part "
            f"({extent_mm * 1e3:.0f} um)",
            field="drop.drop_diameter_um", value=drop.drop_diameter_um)
    part = np.pad(part, target_pad_cells(drop, margin_mm))
    labels, _ = ndimage.label(~part, structure=FOUR_NEIGHBOURS)
    outside = labels == labels[0, 0]
    holes = (~part) & ~outside
    outer_edge = part & ndimage.binary_dilation(outside, structure=FOUR_NEIGHBOURS)
    hole_edge = part & ndimage.binary_dilation(holes, structure=FOUR_NEIGHBOURS)
    dist_mm = ndimage.distance_transform_edt(part) * drop.pitch_mm
    interior = part & (dist_mm > interior_mm)
    if not interior.any():  # small parts: the cells farthest from the edges
        interior = part & (dist_mm >= dist_mm.max())
    return Target(mask=part, outer_edge=outer_edge, hole_edge=hole_edge,
                  interior=interior, pitch_mm=drop.pitch_mm)


def target_from_png(data: bytes, drop: DropParams, margin_mm: float = 0.25,
                    max_cells: int = DEFAULT_MAX_CELLS) -> Target:
    """Target from PNG (or any PIL) bytes: one pixel per print cell, luminance >= 128 is part."""
    if not data:
        raise JettingError("mask image is empty", field="target.mask", value=0)
    try:
        image = Image.open(io.BytesIO(data))
        image.load()
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError) as exc:
        raise JettingError(f"mask is not a readable image: {exc}", field="target.mask",
                           value=len(data)) from exc
    check_cells(image.width * image.height, max_cells, drop)
    grey = np.asarray(image.convert("L"))
    return target_from_mask(grey >= 128, drop, margin_mm)


def rings_grid_cells(extent_mm: tuple[float, float], pitch_mm: float) -> tuple[int, int]:
    """Cells (nx, ny) >= 1 that cover a region of ``extent_mm`` (width x, height y, mm) at
    ``pitch_mm``: the grid :func:`target_from_rings` rasterises the rings on."""
    return max(int(np.ceil(extent_mm[0] / pitch_mm)), 1), max(int(np.ceil(extent_mm[1] / pitch_mm)), 1)


def target_from_rings(rings: list[npt.NDArray[np.float64]], drop: DropParams, margin_mm: float = 0.25,
                      max_cells: int = DEFAULT_MAX_CELLS, field: str = "target.rings") -> Target:
    """Target from polygon rings ((n_i, 2) arrays, mm; even-odd rule: inner rings are holes).

    A cell belongs to the part when its centre lies inside the even-odd region.  ``field``
    names the rings in errors (the caller's name for where they came from).
    """
    if not rings:
        raise JettingError("no rings given", field=field, value=0)
    region = shapely.Polygon()
    for index, ring in enumerate(rings):
        pts = np.asarray(ring, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3 or not np.isfinite(pts).all():
            raise JettingError("a ring must be an (n >= 3, 2) array of finite mm coordinates",
                               field=f"{field}[{index}]", value=list(pts.shape))
        poly = shapely.make_valid(shapely.Polygon(pts))
        region = shapely.symmetric_difference(region, poly)
    if region.is_empty or region.area <= 0.0:
        raise JettingError("rings enclose no area", field=field, value=len(rings))
    x0, y0, x1, y1 = region.bounds
    p = drop.pitch_mm
    nx, ny = rings_grid_cells((x1 - x0, y1 - y0), p)
    check_cells(nx * ny, max_cells, drop)
    xs = x0 + (np.arange(nx) + 0.5) * p
    ys = y0 + (np.arange(ny) + 0.5) * p
    gx, gy = np.meshgrid(xs, ys, indexing="xy")  # rows = y, columns = x
    shapely.prepare(region)
    mask = shapely.contains_xy(region, gx, gy)
    return target_from_mask(mask, drop, margin_mm, field=field)


def target_from_spec(spec: TargetSpec, drop: DropParams, margin_mm: float = 0.25,
                     max_cells: int = DEFAULT_MAX_CELLS) -> Target:
    """The seed's sample: a ``size_mm`` square with a centred ``hole_mm`` square hole."""
    if spec.shape != "square_with_hole":
        raise JettingError("unknown target shape", field="target.shape", value=spec.shape)
    if not (spec.size_mm > 0 and 0 <= spec.hole_mm < spec.size_mm):
        raise JettingError("need size_mm > hole_mm >= 0", field="target.hole_mm",
                           value=[spec.size_mm, spec.hole_mm])
    half, hole = spec.size_mm / 2.0, spec.hole_mm / 2.0
    outer = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    rings = [outer] if hole == 0 else [outer, outer * (hole / half)]
    return target_from_rings(rings, drop, margin_mm, max_cells, field="target")
