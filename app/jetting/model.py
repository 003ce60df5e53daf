"""The controller's linear layer model h_(l+1) = h_l + G f_l (the jetting MPC paper's eq. 9).

G = (I + Dg) B in the seed's form: B deposits drops (kernel convolution) and the flow is
frozen at a predicted pattern (the previous layer's, or ``fill`` everywhere at the first
layer). Two readings of the frozen flow:

* ``"seed_diagonal"``: Dg diagonal, d_ii = dh_i / (B f)_i, exactly as published;
* ``"transport"``: the same flow kept as the sparse, mass-conserving transport operator
  P (G = P B), which also knows where the ink that leaves a cell goes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .errors import JettingError
from .flow import TransportOperator, flow_layer
from .kernel import DropKernel, deposit, deposit_adjoint
from .params import FlowParams

MODEL_KINDS = ("seed_diagonal", "transport")


@dataclass(frozen=True)
class LayerModel:
    """G as a matrix-free operator on (L, W) drop maps; ``transport`` xor ``gain`` is set."""

    kernel: DropKernel
    transport: TransportOperator | None = None
    gain: npt.NDArray[np.float64] | None = None

    def apply(self, drops: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """G f: heights (L, W) mm added by drops (L, W)."""
        d = deposit(drops, self.kernel)
        if self.transport is not None:
            return self.transport.apply(d)
        return d if self.gain is None else self.gain * d

    def adjoint(self, heights: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """G^T y for y (L, W)."""
        if self.transport is not None:
            y = self.transport.adjoint(heights)
        else:
            y = heights if self.gain is None else self.gain * heights
        return deposit_adjoint(y, self.kernel)

    def norm_bound(self) -> float:
        """Upper bound of ||G||_2 (||B||_2 <= sum of the non-negative kernel), mm."""
        b = float(self.kernel.heights_mm.sum())
        if self.transport is not None:
            return b * self.transport.norm_bound()
        return b * (1.0 if self.gain is None else float(np.abs(self.gain).max()))

    def support_radius(self) -> int:
        """L1 radius (|di| + |dj|) of a column of G: cells farther from a drop are untouched."""
        steps = sum(self.transport.moving) if self.transport is not None else 0
        return self.kernel.l1_radius + steps

    def coupled_cells(self, shape: tuple[int, int]) -> npt.NDArray[np.bool_]:
        """(L, W) bool: cells whose drop interacts with a neighbour's in G^T G.

        Cells elsewhere are decoupled: their QP is separable and rounding is exact there.
        """
        if self.kernel.l1_radius > 0:
            return np.ones(shape, dtype=bool)
        if self.transport is None or not any(self.transport.moving):
            return np.zeros(shape, dtype=bool)
        t = self.transport
        active = (t.right + t.left + t.down + t.up).sum(axis=0) > 0.0
        footprint = diamond(2 * self.support_radius())
        coupled: npt.NDArray[np.bool_] = ndimage.binary_dilation(active, structure=footprint)  # scipy: untyped
        return coupled


def diamond(radius: int) -> npt.NDArray[np.bool_]:
    """(2r+1, 2r+1) bool footprint of the L1 ball of ``radius``."""
    i, j = np.indices((2 * radius + 1, 2 * radius + 1)) - radius
    return (np.abs(i) + np.abs(j)) <= radius


def build_layer_model(measured_mm: npt.NDArray[np.float64], guess: npt.NDArray[np.float64], kernel: DropKernel,
                      flow: FlowParams, mobility: npt.NDArray[np.float64], kind: str) -> LayerModel:
    """Freeze the flow of ``guess`` (L, W drops, may be fractional) printed on ``measured_mm``."""
    if kind not in MODEL_KINDS:
        raise JettingError("unknown controller model", field="controller.model", value=kind)
    d0 = deposit(guess, kernel)
    result = flow_layer(measured_mm + d0, d0, mobility, flow)
    if kind == "transport":
        return LayerModel(kernel=kernel, transport=result.transport)
    return LayerModel(kernel=kernel, gain=np.maximum(result.transport.diagonal_gain(d0), 0.0))
