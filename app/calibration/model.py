"""The calibration's small value types: pre-travel model, probe and nozzle calibrations, planned touches.

Conventions (SPEC16): a probe *reading* is the carriage position at trigger = the stylus
ball centre (tool T0 has offset 0).  The probe triggers ``delta(n)`` mm further along its
move direction ``d`` than first geometric contact, where ``n`` is the outward unit surface
normal at the contact, ``theta`` = angle(n, +Z), ``phi = atan2(n_y, n_x)`` and

    delta(n) = p0 + sin(theta) * (a cos(3 phi) + b sin(3 phi))       (mm).

A nozzle's tip is carriage + offset (mm).  Every type here is frozen and round-trips through
``to_dict`` / ``from_dict`` as plain JSON (lists and floats), the form stored as a job result.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from app.calibration.errors import CalibrationError
from app.geometry.tolerance import LENGTH_EPS_MM

#: a normal vector shorter than this is zero: it has no direction to normalise
_ZERO_NORMAL = 1e-12

__all__ = ["PretravelModel", "ProbeCalibration", "NozzleCalibration", "Touch", "TOUCH_KINDS", "as_normals", "hops"]

TOUCH_KINDS = ("cap", "equator", "pad", "nozzle_pad", "nozzle_side")


def _vec3(value: Any, name: str) -> tuple[float, float, float]:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be three numbers (mm)", field=name, value=value) from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{name} must be three finite numbers (mm)", field=name, value=value)
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _finite(value: Any, name: str, *, minimum: float | None = None) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be a number", field=name, value=value) from None
    if not math.isfinite(number) or (minimum is not None and number < minimum):
        bound = "" if minimum is None else f" >= {minimum}"
        raise CalibrationError(f"{name} must be a finite number{bound}", field=name, value=value)
    return number


def _get(d: Mapping[str, Any], key: str, where: str) -> Any:
    if not isinstance(d, Mapping) or key not in d:
        raise CalibrationError(f"{where}: missing {key!r}", field=f"{where}.{key}")
    return d[key]


def as_normals(normals: npt.ArrayLike, name: str = "normals") -> npt.NDArray[np.float64]:
    """Validate and normalise outward normals: (n, 3) finite, non-zero -> (n, 3) unit vectors."""
    arr = np.asarray(normals, dtype=float)
    if arr.ndim == 1 and arr.shape == (3,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise CalibrationError(f"{name} must have shape (n, 3)", field=name, value=list(arr.shape))
    length = np.linalg.norm(arr, axis=1)
    bad = ~np.isfinite(arr).all(axis=1) | (length < _ZERO_NORMAL)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise CalibrationError(f"{name}[{i}] is not a finite non-zero vector", field=f"{name}[{i}]", value=arr[i])
    unit: npt.NDArray[np.float64] = arr / length[:, None]
    return unit


@dataclass(frozen=True)
class PretravelModel:
    """Direction-dependent pre-travel (mm): ``p0 + sin(theta) (cos3 cos(3 phi) + sin3 sin(3 phi))``."""

    p0_mm: float
    cos3_mm: float = 0.0
    sin3_mm: float = 0.0

    def at(self, normals: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Pre-travel (n,) mm at outward contact normals (n, 3) (normalised here)."""
        n = as_normals(normals)
        rho = np.hypot(n[:, 0], n[:, 1])                       # sin(theta)
        phi = np.arctan2(n[:, 1], n[:, 0])
        lobes = self.cos3_mm * np.cos(3 * phi) + self.sin3_mm * np.sin(3 * phi)
        pretravel: npt.NDArray[np.float64] = self.p0_mm + rho * lobes
        return pretravel

    @property
    def lobing_mm(self) -> float:
        """Amplitude of the 3-lobe term (mm)."""
        return float(math.hypot(self.cos3_mm, self.sin3_mm))

    def to_dict(self) -> dict[str, float]:
        return {"p0_mm": self.p0_mm, "cos3_mm": self.cos3_mm, "sin3_mm": self.sin3_mm}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> PretravelModel:
        return cls(p0_mm=_finite(_get(d, "p0_mm", "pretravel"), "pretravel.p0_mm"),
                   cos3_mm=_finite(d.get("cos3_mm", 0.0), "pretravel.cos3_mm"),
                   sin3_mm=_finite(d.get("sin3_mm", 0.0), "pretravel.sin3_mm"))


@dataclass(frozen=True)
class ProbeCalibration:
    """A probe qualification on the reference sphere (all mm).

    ball_radius_mm: effective stylus ball radius r.  pretravel: the fitted delta(n).
    sphere_centre_mm: the sphere centre in machine (probe ball-centre) coordinates.
    pad_reading_z_mm: mean vertical reading on the reference pad (the drift / offset
    reference), None without a pad.  std: 1-sigma of each fitted parameter, keys
    ``ball_radius_mm, p0_mm, cos3_mm, sin3_mm, centre_x_mm, centre_y_mm, centre_z_mm,
    pad_reading_z_mm`` (those fitted) and ``p0_minus_radius_mm`` (the correlated combination
    that turns a vertical reading into a surface height).  residual_rms_mm: RMS of the sphere residuals.
    touches: number of touches used.  drift_mm_per_min: the Z drift rate fitted during the
    qualification (when the touch times were given; None otherwise), mm/min.
    """

    ball_radius_mm: float
    pretravel: PretravelModel
    sphere_centre_mm: tuple[float, float, float]
    pad_reading_z_mm: float | None
    std: dict[str, float] = field(default_factory=dict)
    residual_rms_mm: float = 0.0
    touches: int = 0
    drift_mm_per_min: float | None = None

    def pad_surface_z_mm(self) -> float | None:
        """Pad top surface z in the probe frame: pad reading + delta(+Z) - r (None without a pad)."""
        if self.pad_reading_z_mm is None:
            return None
        return float(self.pad_reading_z_mm + self.pretravel.at([[0.0, 0.0, 1.0]])[0] - self.ball_radius_mm)

    def to_dict(self) -> dict[str, Any]:
        return {"ball_radius_mm": self.ball_radius_mm, "pretravel": self.pretravel.to_dict(),
                "sphere_centre_mm": list(self.sphere_centre_mm), "pad_reading_z_mm": self.pad_reading_z_mm,
                "std": {k: float(v) for k, v in self.std.items()}, "residual_rms_mm": self.residual_rms_mm,
                "touches": self.touches, "drift_mm_per_min": self.drift_mm_per_min}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ProbeCalibration:
        pad = d.get("pad_reading_z_mm") if isinstance(d, Mapping) else None
        std = d.get("std", {}) if isinstance(d, Mapping) else {}
        if not isinstance(std, Mapping):
            raise CalibrationError("probe calibration std must be an object", field="std", value=std)
        return cls(ball_radius_mm=_finite(_get(d, "ball_radius_mm", "probe"), "ball_radius_mm"),
                   pretravel=PretravelModel.from_dict(_get(d, "pretravel", "probe")),
                   sphere_centre_mm=_vec3(_get(d, "sphere_centre_mm", "probe"), "sphere_centre_mm"),
                   pad_reading_z_mm=None if pad is None else _finite(pad, "pad_reading_z_mm"),
                   std={str(k): _finite(v, f"std.{k}", minimum=0.0) for k, v in std.items()},
                   residual_rms_mm=_finite(d.get("residual_rms_mm", 0.0), "residual_rms_mm", minimum=0.0),
                   touches=int(_finite(d.get("touches", 0), "touches", minimum=0)),
                   drift_mm_per_min=None if d.get("drift_mm_per_min") is None
                   else _finite(d["drift_mm_per_min"], "drift_mm_per_min"))


@dataclass(frozen=True)
class NozzleCalibration:
    """A nozzle's measured offset to the probe: tip = carriage + offset_mm (mm), 1-sigma std_mm (3,)."""

    tool: int
    offset_mm: tuple[float, float, float]
    std_mm: tuple[float, float, float]
    outer_diameter_mm: float | None = None
    touches: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"tool": self.tool, "offset_mm": list(self.offset_mm), "std_mm": list(self.std_mm),
                "outer_diameter_mm": self.outer_diameter_mm, "touches": self.touches}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> NozzleCalibration:
        diameter = d.get("outer_diameter_mm") if isinstance(d, Mapping) else None
        return cls(tool=int(_finite(_get(d, "tool", "nozzle"), "tool", minimum=0)),
                   offset_mm=_vec3(_get(d, "offset_mm", "nozzle"), "offset_mm"),
                   std_mm=_vec3(_get(d, "std_mm", "nozzle"), "std_mm"),
                   outer_diameter_mm=None if diameter is None else _finite(diameter, "outer_diameter_mm", minimum=0),
                   touches=int(_finite(d.get("touches", 0), "touches", minimum=0)))


@dataclass(frozen=True)
class Touch:
    """One planned probing move in carriage coordinates (mm): from ``start_mm`` toward ``target_mm``.

    kind: "cap" / "equator" (probe on the sphere), "pad" (probe on the pad), "nozzle_pad"
    (nozzle flat end on the pad), "nozzle_side" (nozzle body side against the sphere).
    The caller reaches ``start_mm`` safely (up to a clearance height, across, down) and probes
    toward ``target_mm``; the reading is the carriage position at trigger.  ``local``: the
    planner vouches that, straight after the previous touch of the same tool and kind, the
    start is reached safely by a short hop near the artifact: up (or down) to
    ``max(trigger z, start z)``, straight across, then to the start -- no trip to the
    clearance height (pad spots at one height, neighbouring equator touches, a repeated
    side touch).
    """

    start_mm: tuple[float, float, float]
    target_mm: tuple[float, float, float]
    kind: str
    local: bool = False

    def __post_init__(self) -> None:
        if self.kind not in TOUCH_KINDS:
            raise CalibrationError(f"touch kind must be one of {', '.join(TOUCH_KINDS)}", field="kind",
                                   value=self.kind)
        object.__setattr__(self, "start_mm", _vec3(self.start_mm, "start_mm"))
        object.__setattr__(self, "target_mm", _vec3(self.target_mm, "target_mm"))
        if math.dist(self.start_mm, self.target_mm) < LENGTH_EPS_MM:
            raise CalibrationError("a touch's target must differ from its start", field="target_mm",
                                   value=self.target_mm)

    @property
    def direction(self) -> npt.NDArray[np.float64]:
        """Unit move direction (3,) = unit(target - start)."""
        d = np.subtract(self.target_mm, self.start_mm)
        unit: npt.NDArray[np.float64] = d / np.linalg.norm(d)
        return unit

    def to_dict(self) -> dict[str, Any]:
        return {"start_mm": list(self.start_mm), "target_mm": list(self.target_mm), "kind": self.kind,
                **({"local": True} if self.local else {})}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Touch:
        return cls(start_mm=_get(d, "start_mm", "touch"), target_mm=_get(d, "target_mm", "touch"),
                   kind=str(_get(d, "kind", "touch")), local=bool(d.get("local", False)))


def hops(previous: Touch | None, touch: Touch) -> bool:
    """Whether ``touch`` is reached by a local hop after ``previous`` (None: the first touch of
    a run, or the first after a resume): it is ``local`` and follows a touch of its kind (the
    same tool)."""
    return previous is not None and touch.local and previous.kind == touch.kind
