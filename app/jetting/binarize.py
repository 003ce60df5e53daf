"""Binary (0/1) drop patterns from the relaxed QP solution, with the integer gap.

* ``threshold``: f >= 1/2. Exact where the QP is separable (no flow or kernel coupling
  between neighbouring cells): rounding a separable convex quadratic to the nearest
  integer is its integer optimum.
* ``error_diffusion``: row by row, each row's rounding error is pushed to the next row
  (weights 1/4, 1/2, 1/4), keeping the local drop density of the relaxed solution.
* ``greedy``: start from ``threshold``, then flip single drops while the exact QP
  objective decreases. Cells are coloured so that cells of one colour do not interact in
  G^T G; all improving flips of one colour are made at once and their gains add exactly.
  Only cells coupled to a neighbour (flow or a kernel wider than one cell) are visited.

Integer gap = J(binary first layer, later layers relaxed) - J(relaxed) >= 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .errors import JettingError
from .model import diamond
from .qp import LayerQP

BINARIZE_METHODS = ("threshold", "error_diffusion", "greedy")
#: a greedy flip is taken only when it lowers the objective by more than this (round-off)
_MIN_FLIP_GAIN = 1e-12
DIFFUSION_WEIGHTS = np.array([0.25, 0.5, 0.25])


@dataclass(frozen=True)
class BinaryPattern:
    """pattern: (L, W) bool drops of the first layer; objective J at it; integer_gap."""

    pattern: npt.NDArray[np.bool_]
    objective: float
    integer_gap: float
    flips: int


def threshold_pattern(relaxed: npt.NDArray[np.float64], free: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """(L, W) bool: relaxed >= 1/2 on free cells."""
    pattern: npt.NDArray[np.bool_] = (relaxed >= 0.5) & free
    return pattern


def error_diffusion_pattern(relaxed: npt.NDArray[np.float64], free: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """(L, W) bool by row-wise error diffusion of the relaxed drop map."""
    out = np.zeros(relaxed.shape, dtype=bool)
    carry = np.zeros(relaxed.shape[1])
    for i in range(relaxed.shape[0]):
        want = np.where(free[i], relaxed[i] + carry, 0.0)
        out[i] = (want >= 0.5) & free[i]
        err = np.where(free[i], want - out[i], 0.0)
        carry = ndimage.convolve1d(err, DIFFUSION_WEIGHTS, mode="constant")
    return out


def lee_colours(shape: tuple[int, int], radius: int) -> tuple[npt.NDArray[np.int64], int]:
    """(L, W) colour per cell and the colour count; same colours are >= 2R+1 apart in L1."""
    i, j = np.indices(shape, dtype=np.int64)
    count = 2 * radius * radius + 2 * radius + 1
    return (i + (2 * radius + 1) * j) % count, count


def first_stage_hessian_diagonal(qp: LayerQP, cells: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """diag of d^2 J / d f_l^2 at ``cells`` (L, W) by probing G with spaced unit drops."""
    radius = qp.model.support_radius()
    colours, count = lee_colours(qp.h0.shape, radius)
    footprint = diamond(radius).astype(float)
    diag = np.zeros(qp.h0.shape)
    total_w = float(qp.stage_weights.sum())
    for colour in range(count):
        probe = (colours == colour) & cells
        if not probe.any():
            continue
        y = qp.model.apply(probe.astype(float)) / qp.scale_mm
        sums = ndimage.correlate(qp.cell_weight * y * y, footprint, mode="constant")
        diag = np.where(probe, sums, diag)
    return 2.0 * total_w * diag + 2.0 * qp.rho


def _with_first(x: npt.NDArray[np.float64], first: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``x`` (m, L, W) with its first layer replaced by ``first`` (L, W)."""
    out = x.copy()
    out[0] = first
    return out


def greedy_pattern(qp: LayerQP, x: npt.NDArray[np.float64], start: npt.NDArray[np.bool_],
                   rounds: int) -> tuple[npt.NDArray[np.bool_], int]:
    """Improve the 0/1 first layer ``start`` (L, W) by exact single-drop flips.

    x: (m, L, W) relaxed solution (later layers stay relaxed). Returns (pattern, flips).
    """
    cells = qp.model.coupled_cells(qp.h0.shape) & qp.free
    pattern = start.astype(float)
    if not cells.any() or rounds <= 0:
        return start, 0
    hdiag = first_stage_hessian_diagonal(qp, cells)
    colours, count = lee_colours(qp.h0.shape, qp.model.support_radius())
    _, grad = qp.objective_and_gradient(_with_first(x, pattern))
    flips = 0
    for _ in range(rounds):
        changed = 0
        for c in range(count):
            delta = 1.0 - 2.0 * pattern
            gain = delta * grad[0] + 0.5 * hdiag
            flip = (colours == c) & cells & (gain < -_MIN_FLIP_GAIN)
            if not flip.any():
                continue
            pattern = np.where(flip, 1.0 - pattern, pattern)
            changed += int(flip.sum())
            _, grad = qp.objective_and_gradient(_with_first(x, pattern))
        flips += changed
        if changed == 0:
            break
    return pattern > 0.5, flips


def binarize(qp: LayerQP, x: npt.NDArray[np.float64], relaxed_objective: float, method: str,
             rounds: int = 3) -> BinaryPattern:
    """0/1 first-layer pattern from the relaxed solution x (m, L, W) by ``method``."""
    if method not in BINARIZE_METHODS:
        raise JettingError("unknown binarization method", field="controller.binarize", value=method)
    if method == "error_diffusion":
        pattern, flips = error_diffusion_pattern(x[0], qp.free), 0
    else:
        pattern, flips = threshold_pattern(x[0], qp.free), 0
        if method == "greedy":
            pattern, flips = greedy_pattern(qp, x, pattern, rounds)
    value = qp.objective(_with_first(x, pattern.astype(float)))
    return BinaryPattern(pattern=pattern, objective=value,
                         integer_gap=value - relaxed_objective, flips=flips)
