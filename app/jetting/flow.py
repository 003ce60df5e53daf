"""The published threshold ink flow (eq. 7), mass-conserving and liquid-limited.

After a layer's drops land, liquid ink moves between 4-neighbours i, j whose surface
heights differ by more than the threshold, from high to low (the seed's eq. 7 leaves the
sign implicit): flux_ij = w_ij (s_i - s_j), w_ij = (2/pi) eta_s / 8 with the edge
mobility (2/pi) eta_s(k, lambda) in [0, 1] (the 1/8 = 1/(2|M|) keeps the explicit step
monotone). A cell can only give away the liquid it holds (cured ink does not flow), so
every flux out of a donor is scaled by min(1, liquid / outflow). Fluxes are antisymmetric,
so the total volume is conserved to rounding.

The same run records the fraction of each cell's liquid sent to each neighbour per
sub-step: the frozen **transport operator** P (column-stochastic, matrix-free) with
P d = the deposit d after flow. The seed's (I + Dg) is its diagonal reading:
d_ii = dh_i / d_i = (P d)_i / d_i - 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .params import FlowParams

EDGE_WEIGHT = 1.0 / 8.0  # 1 / (2 |M|), |M| = 4 neighbours


@dataclass(frozen=True)
class FlowResult:
    """``surface``: (L, W) heights after flow, mm; ``transport``: the frozen operator."""

    surface: npt.NDArray[np.float64]
    transport: TransportOperator


@dataclass(frozen=True)
class TransportOperator:
    """Per sub-step fractions (each (S, L, W)) of a cell's liquid sent right/left/down/up.

    ``apply(d)`` moves a deposit d (L, W) like the recorded flow; ``adjoint(y)`` is its
    exact transpose. Columns sum to 1 (mass conserving), entries are >= 0.
    """

    right: npt.NDArray[np.float64]
    left: npt.NDArray[np.float64]
    down: npt.NDArray[np.float64]
    up: npt.NDArray[np.float64]
    moving: tuple[bool, ...]

    @property
    def steps(self) -> int:
        return int(self.right.shape[0])

    def _stay(self, s: int) -> npt.NDArray[np.float64]:
        """(L, W) fraction of each cell's liquid that stays put in step ``s``."""
        stay: npt.NDArray[np.float64] = 1.0 - self.right[s] - self.left[s] - self.down[s] - self.up[s]
        return stay

    def apply(self, d: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        x = np.asarray(d, dtype=float)
        for s in range(self.steps):
            if not self.moving[s]:
                continue
            ar, al, ad, au = self.right[s], self.left[s], self.down[s], self.up[s]
            y = x * self._stay(s)
            y[:, 1:] += x[:, :-1] * ar[:, :-1]
            y[:, :-1] += x[:, 1:] * al[:, 1:]
            y[1:, :] += x[:-1, :] * ad[:-1, :]
            y[:-1, :] += x[1:, :] * au[1:, :]
            x = y
        return x

    def adjoint(self, y: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        g = np.asarray(y, dtype=float)
        for s in reversed(range(self.steps)):
            if not self.moving[s]:
                continue
            ar, al, ad, au = self.right[s], self.left[s], self.down[s], self.up[s]
            out = g * self._stay(s)
            out[:, :-1] += ar[:, :-1] * g[:, 1:]
            out[:, 1:] += al[:, 1:] * g[:, :-1]
            out[:-1, :] += ad[:-1, :] * g[1:, :]
            out[1:, :] += au[1:, :] * g[:-1, :]
            g = out
        return g

    def diagonal_gain(self, deposit: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The seed's 1 + d_ii = (P d)_i / d_i (1 where nothing was deposited), (L, W)."""
        moved = self.apply(deposit)
        safe = np.where(deposit > 0.0, deposit, 1.0)
        return np.where(deposit > 0.0, moved / safe, 1.0)

    def norm_bound(self) -> float:
        """Upper bound of the spectral norm: prod over steps sqrt(max col sum * max row sum)."""
        bound = 1.0
        for s in range(self.steps):
            ar, al, ad, au = self.right[s], self.left[s], self.down[s], self.up[s]
            rows = self._stay(s)
            rows[:, 1:] += ar[:, :-1]
            rows[:, :-1] += al[:, 1:]
            rows[1:, :] += ad[:-1, :]
            rows[:-1, :] += au[1:, :]
            bound *= float(np.sqrt(max(rows.max(), 1.0)))
        return bound


def substrate_tilt(substrate_mm: npt.NDArray[np.float64] | None, shape: tuple[int, int],
                   pitch_mm: float) -> npt.NDArray[np.float64]:
    """k_i of eq. 6 for the surface z - z_sub(x, y) = 0: arctan |grad z_sub|, rad, (L, W)."""
    if substrate_mm is None:
        return np.zeros(shape)
    gy, gx = np.gradient(np.asarray(substrate_mm, dtype=float), pitch_mm)
    tilt: npt.NDArray[np.float64] = np.arctan(np.hypot(gx, gy))
    return tilt


def mobility_map(tilt_rad: npt.NDArray[np.float64], flow: FlowParams, factor: float = 1.0) -> npt.NDArray[np.float64]:
    """(2/pi) eta_s(k_i, lambda) per cell, clipped to [0, 1]: flat value, rising above lambda."""
    excess = np.maximum(tilt_rad - flow.slope_lambda_rad, 0.0)
    return np.clip(flow.mobility * factor * (1.0 + flow.slope_gain * excess), 0.0, 1.0)


def flow_layer(
    surface: npt.NDArray[np.float64],
    liquid: npt.NDArray[np.float64],
    mobility: npt.NDArray[np.float64],
    flow: FlowParams,
    threshold_factor: float = 1.0,
) -> FlowResult:
    """Run ``flow.flow_steps`` threshold-flow sub-steps on one freshly printed layer.

    surface: (L, W) heights including the liquid, mm; liquid: (L, W) liquid thickness on
    top (the layer's deposit), mm; mobility: (L, W) per-cell mobility in [0, 1].
    Returns the new surface (same total volume) and the transport operator of this run.
    """
    s = np.array(surface, dtype=float, copy=True)
    liq = np.maximum(np.array(liquid, dtype=float, copy=True), 0.0)
    tau = flow.threshold_mm * threshold_factor
    wx = EDGE_WEIGHT * 0.5 * (mobility[:, :-1] + mobility[:, 1:])
    wy = EDGE_WEIGHT * 0.5 * (mobility[:-1, :] + mobility[1:, :])
    n = max(int(flow.flow_steps), 0)
    frac = np.zeros((4, n) + s.shape)  # right, left, down, up
    for step in range(n):
        dx = s[:, :-1] - s[:, 1:]
        dy = s[:-1, :] - s[1:, :]
        qx = np.where(np.abs(dx) > tau, wx * dx, 0.0)
        qy = np.where(np.abs(dy) > tau, wy * dy, 0.0)
        out = np.zeros_like(s)
        out[:, :-1] += np.maximum(qx, 0.0)
        out[:, 1:] += np.maximum(-qx, 0.0)
        out[:-1, :] += np.maximum(qy, 0.0)
        out[1:, :] += np.maximum(-qy, 0.0)
        scale = np.ones_like(s)
        np.divide(liq, out, out=scale, where=out > liq)
        qx = np.where(qx > 0.0, qx * scale[:, :-1], qx * scale[:, 1:])
        qy = np.where(qy > 0.0, qy * scale[:-1, :], qy * scale[1:, :])
        safe = np.where(liq > 0.0, liq, 1.0)
        has = liq > 0.0
        frac[0, step][:, :-1] = np.where(has[:, :-1], np.maximum(qx, 0.0) / safe[:, :-1], 0.0)
        frac[1, step][:, 1:] = np.where(has[:, 1:], np.maximum(-qx, 0.0) / safe[:, 1:], 0.0)
        frac[2, step][:-1, :] = np.where(has[:-1, :], np.maximum(qy, 0.0) / safe[:-1, :], 0.0)
        frac[3, step][1:, :] = np.where(has[1:, :], np.maximum(-qy, 0.0) / safe[1:, :], 0.0)
        delta = np.zeros_like(s)
        delta[:, :-1] -= qx
        delta[:, 1:] += qx
        delta[:-1, :] -= qy
        delta[1:, :] += qy
        s += delta
        liq = np.maximum(liq + delta, 0.0)
    moving = tuple(bool(frac[:, step].any()) for step in range(n))
    op = TransportOperator(right=frac[0], left=frac[1], down=frac[2], up=frac[3], moving=moving)
    return FlowResult(surface=s, transport=op)
