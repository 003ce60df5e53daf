"""Where a part sits on the machine, and whether a program stays inside the machine (pure).

A part is modelled in its own frame; a printer moves in its own.  A :class:`BedPlacement`
is the rule that puts the part on the bed; :func:`bed_placement` turns it into the rigid
:class:`app.geometry.placement.Placement` (a translation) from the part's frame into the
machine's: ``drop_to_bed`` puts
the part's lowest point on the bed (z = the volume's z minimum), ``xy: "center"`` centres
its bounding box on the bed, ``xy: "offset"`` puts its bounding box's minimum corner at
``offset_mm`` (bed coordinates), ``xy: "as_is"`` keeps the part's x, y.  A
:class:`MachineVolume` is the machine's travel (mm, per axis); :func:`check_inside`
refuses anything that leaves it, naming the axis and by how much.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from app.domain.errors import InvalidInput
from app.geometry.placement import Placement
from app.geometry.tolerance import LENGTH_EPS_MM

AXES = "xyz"


class PlacementError(InvalidInput):
    """A program would leave the machine's volume (422); ``value`` names axis and amount."""


@dataclass(frozen=True)
class MachineVolume:
    """Travel limits (mm): ``x``, ``y``, ``z`` as (min, max); ``source`` says where they came
    from (machine profile, job parameters or the default bed)."""

    x: tuple[float, float] = (0.0, 200.0)
    y: tuple[float, float] = (0.0, 200.0)
    z: tuple[float, float] = (0.0, 200.0)
    source: str = "default: a 200 x 200 x 200 mm machine with its origin at the bed's front-left corner"

    def limits(self) -> np.ndarray:
        """(2, 3) [[xmin, ymin, zmin], [xmax, ymax, zmax]] mm."""
        return np.array([[self.x[0], self.y[0], self.z[0]], [self.x[1], self.y[1], self.z[1]]], dtype=float)

    def describe(self) -> dict[str, Any]:
        return {"x": list(self.x), "y": list(self.y), "z": list(self.z), "source": self.source}


@dataclass(frozen=True)
class BedPlacement:
    """How the part goes onto the bed (see the module docstring): a rule, not a transform."""

    xy: Literal["center", "offset", "as_is"] = "center"
    offset_mm: tuple[float, float] = (0.0, 0.0)
    drop_to_bed: bool = True


def bed_placement(part_bounds: np.ndarray, rule: BedPlacement, volume: MachineVolume) -> Placement:
    """The placement (a translation, mm) from the part's frame into the machine's.

    ``part_bounds``: (2, 3) the part's (or its layers') bounding box in its own frame."""
    lo, hi = np.asarray(part_bounds, dtype=float)
    bed = volume.limits()
    shift = np.zeros(3)
    if rule.xy == "center":
        shift[:2] = 0.5 * (bed[0, :2] + bed[1, :2]) - 0.5 * (lo[:2] + hi[:2])
    elif rule.xy == "offset":
        shift[:2] = np.asarray(rule.offset_mm, dtype=float) - lo[:2]
    if rule.drop_to_bed:
        shift[2] = bed[0, 2] - lo[2]
    return Placement.translation_by(shift)


def placement_shift(part_bounds: np.ndarray, rule: BedPlacement, volume: MachineVolume) -> np.ndarray:
    """(3,) translation (mm) of :func:`bed_placement` (what is added to part coordinates)."""
    return bed_placement(part_bounds, rule, volume).translation()


def check_inside(bounds: np.ndarray, volume: MachineVolume, field: str = "params.placement",
                 what: str = "the program") -> None:
    """Raise :class:`PlacementError` when ``bounds`` (2, 3) mm leave ``volume``, naming the
    first axis and by how much (mm)."""
    lo, hi = np.asarray(bounds, dtype=float)
    limits = volume.limits()
    for k, axis in enumerate(AXES):
        below = limits[0, k] - lo[k]
        above = hi[k] - limits[1, k]
        if below > LENGTH_EPS_MM or above > LENGTH_EPS_MM:
            side, amount, edge = ("below", below, limits[0, k]) if below > above else ("beyond", above, limits[1, k])
            raise PlacementError(
                f"{what} leaves the machine's volume on {axis.upper()}: it reaches "
                f"{(lo if side == 'below' else hi)[k]:.4f} mm, {amount:.4f} mm {side} the limit {edge:g} mm "
                f"({volume.source}); move or shrink the part, or give the machine's real travel",
                field=field, value={"axis": axis, "beyond_mm": round(float(amount), 6),
                                    "limit_mm": float(edge)})


def profile_volume(profile: dict[str, Any] | None, label: str) -> MachineVolume | None:
    """The travel limits in a machine profile's ``volume_mm`` ({x: [min, max], y, z}), or None."""
    given = (profile or {}).get("volume_mm")
    if not given:
        return None
    return MachineVolume(tuple(given["x"]), tuple(given["y"]), tuple(given["z"]),
                         f"{label} profile.volume_mm")
