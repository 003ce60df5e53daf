"""Kinematics of a table-tilting A/C five-axis machine with a vertical nozzle.

Convention (the project's machine-coordinate rule)
--------------------------------------------------
The table tilts by A about the X axis and rotates by C about the Z axis, both through
the pivot ``o = (x0, y0, z0)``.  A workpiece point ``p`` and a workpiece direction ``d``
appear in machine coordinates as::

    m = Rx(A) Rz(C) (p - o) + o,        d_m = Rx(A) Rz(C) d

with the right-handed rotations ``Rx(a) = [[1,0,0],[0,c,-s],[0,s,c]]`` and
``Rz(c) = [[c,-s,0],[s,c,0],[0,0,1]]``.  The program's X Y Z are the nozzle tip in machine
coordinates (equal to workpiece coordinates at A = C = 0).  The nozzle points along -Z,
its axis is +Z.

Inverse (derived here; the patent's printed formulas are OCR-damaged)
---------------------------------------------------------------------
A surface normal ``n = (nx, ny, nz)`` (unit) must map to +Z.  With ``v = Rz(C) n``::

    v = (nx cC - ny sC,  nx sC + ny cC,  nz)
    Rx(A) v = (vx,  vy cA - vz sA,  vy sA + vz cA) = (0, 0, 1)

so ``vx = 0``, ``vy = sin A`` and ``nz = cos A``.  With ``rho = sqrt(nx^2 + ny^2)``::

    branch +1:  A =  atan2(rho, nz),  C = atan2(nx, ny)
    branch -1:  A = -atan2(rho, nz),  C = atan2(nx, ny) + pi

Forward (the tool axis in workpiece coordinates) is ``n = Rz(-C) Rx(-A) e_z =
(sin A sin C, sin A cos C, cos A)``.  At ``A = 0`` (normal already vertical) C is undefined:
the caller chooses it (:mod:`.branches`: C is blended across a pole window).

All angles in radians, lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

#: default singularity threshold of the inverse kinematics: where rho = sin A is at or below
#: this the rotary axis is vertical and C is held
_SINGULAR_RHO = 1e-12

__all__ = [
    "MachineConfig",
    "AxisPose",
    "ToolPose",
    "rotation_matrices",
    "workpiece_to_machine",
    "machine_to_workpiece",
    "tool_axis_from_angles",
    "angles_for_normal",
    "inverse_kinematics",
    "forward_kinematics",
]


@dataclass(frozen=True)
class MachineConfig:
    """A table-tilting A/C machine.

    pivot_mm: (x0, y0, z0), the point both rotary axes pass through (mm).
    a_limits_rad: (min, max) of A (rad), inclusive.
    c_limits_rad: (min, max) of C (rad) or None for an endless C axis.
    """

    pivot_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    a_limits_rad: tuple[float, float] = (-np.pi / 2, np.pi / 2)
    c_limits_rad: tuple[float, float] | None = None

    @property
    def pivot(self) -> npt.NDArray[np.float64]:
        """Pivot as a (3,) float array (mm)."""
        return np.asarray(self.pivot_mm, dtype=float)


@dataclass(frozen=True)
class AxisPose:
    """Machine axes for k poses: xyz_mm (k,3) nozzle tip in machine coordinates; a_rad,
    c_rad (k,) rotary angles."""

    xyz_mm: npt.NDArray[np.float64]
    a_rad: npt.NDArray[np.float64]
    c_rad: npt.NDArray[np.float64]


@dataclass(frozen=True)
class ToolPose:
    """k tool poses in workpiece coordinates: tip_mm (k,3) nozzle tip; axis (k,3) unit
    tool axis (pointing from the surface to the nozzle)."""

    tip_mm: npt.NDArray[np.float64]
    axis: npt.NDArray[np.float64]


def rotation_matrices(a_rad: npt.NDArray[np.float64], c_rad: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Rx(A) @ Rz(C) for each pose: (k,) x (k,) -> (k,3,3)."""
    a = np.atleast_1d(np.asarray(a_rad, dtype=float))
    c = np.atleast_1d(np.asarray(c_rad, dtype=float))
    ca, sa, cc, sc = np.cos(a), np.sin(a), np.cos(c), np.sin(c)
    m = np.empty(a.shape + (3, 3))
    m[..., 0, 0], m[..., 0, 1], m[..., 0, 2] = cc, -sc, 0.0
    m[..., 1, 0], m[..., 1, 1], m[..., 1, 2] = ca * sc, ca * cc, -sa
    m[..., 2, 0], m[..., 2, 1], m[..., 2, 2] = sa * sc, sa * cc, ca
    return m


def workpiece_to_machine(points_mm: npt.NDArray[np.float64], a_rad: npt.NDArray[np.float64],
                         c_rad: npt.NDArray[np.float64],
                         pivot_mm: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Map workpiece points (k,3) to machine points (k,3): R (p - o) + o (mm)."""
    r = rotation_matrices(a_rad, c_rad)
    o = np.asarray(pivot_mm, dtype=float)
    machine: npt.NDArray[np.float64] = np.einsum("kij,kj->ki", r, np.asarray(points_mm, dtype=float) - o) + o
    return machine


def machine_to_workpiece(points_mm: npt.NDArray[np.float64], a_rad: npt.NDArray[np.float64],
                         c_rad: npt.NDArray[np.float64],
                         pivot_mm: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Inverse of :func:`workpiece_to_machine`: R^T (m - o) + o, (k,3) -> (k,3) mm."""
    r = rotation_matrices(a_rad, c_rad)
    o = np.asarray(pivot_mm, dtype=float)
    workpiece: npt.NDArray[np.float64] = np.einsum("kji,kj->ki", r, np.asarray(points_mm, dtype=float) - o) + o
    return workpiece


def tool_axis_from_angles(a_rad: npt.NDArray[np.float64], c_rad: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Tool axis (machine +Z) seen in workpiece coordinates: (sinA sinC, sinA cosC, cosA),
    (k,) -> (k,3) unit vectors."""
    a = np.atleast_1d(np.asarray(a_rad, dtype=float))
    c = np.atleast_1d(np.asarray(c_rad, dtype=float))
    return np.stack([np.sin(a) * np.sin(c), np.sin(a) * np.cos(c), np.cos(a)], axis=-1)


@dataclass(frozen=True)
class AngleCandidates:
    """Both inverse solutions for k normals (rad): branch +1 (a_pos, c_pos, A >= 0) and
    branch -1 (-a_pos, c_pos + pi).  ``rho`` (k,) = sin|A|, the horizontal part of n."""

    a_pos: npt.NDArray[np.float64]
    c_pos: npt.NDArray[np.float64]
    rho: npt.NDArray[np.float64]


def angles_for_normal(normals: npt.NDArray[np.float64]) -> AngleCandidates:
    """Both (A, C) solutions that bring each unit normal (k,3) to +Z (see module doc)."""
    n = np.atleast_2d(np.asarray(normals, dtype=float))
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    rho = np.hypot(n[:, 0], n[:, 1])
    return AngleCandidates(a_pos=np.arctan2(rho, n[:, 2]), c_pos=np.arctan2(n[:, 0], n[:, 1]),
                           rho=rho)


def inverse_kinematics(pose: ToolPose, config: MachineConfig, branch: int = 1,
                       c_hold_rad: float = 0.0, singular_rho: float = _SINGULAR_RHO) -> AxisPose:
    """Machine axes for workpiece tool poses, one fixed branch (+1: A >= 0, -1: A <= 0).

    Where the axis is vertical within ``singular_rho`` (= sin A) C is undefined and
    ``c_hold_rad`` is used; A is then chosen to best align the axis for that C.
    The tip (k,3, mm) maps with the rotation: X = R (tip - o) + o.  Continuous branch
    choice along a path is :func:`app.five_axis.branches.choose_axes`.
    """
    cand = angles_for_normal(pose.axis)
    if branch not in (1, -1):
        raise ValueError("branch must be +1 or -1")
    a = branch * cand.a_pos
    c = cand.c_pos + (0.0 if branch == 1 else np.pi)
    c = np.where(cand.rho <= singular_rho, c_hold_rad, np.arctan2(np.sin(c), np.cos(c)))
    n = np.atleast_2d(np.asarray(pose.axis, dtype=float))
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    held = cand.rho <= singular_rho
    a_held = np.arctan2(n[:, 0] * np.sin(c) + n[:, 1] * np.cos(c), n[:, 2])
    a = np.where(held, a_held, a)
    xyz = workpiece_to_machine(np.atleast_2d(pose.tip_mm), a, c, config.pivot)
    return AxisPose(xyz_mm=xyz, a_rad=a, c_rad=c)


def forward_kinematics(axes: AxisPose, config: MachineConfig) -> ToolPose:
    """Workpiece tool poses for machine axes: tip = R^T (X - o) + o and the tool axis
    (machine +Z) in workpiece coordinates.  (k,3)+(k,)+(k,) -> ToolPose of (k,3)."""
    tip = machine_to_workpiece(np.atleast_2d(axes.xyz_mm), axes.a_rad, axes.c_rad, config.pivot)
    return ToolPose(tip_mm=tip, axis=tool_axis_from_angles(axes.a_rad, axes.c_rad))
