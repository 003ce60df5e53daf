"""The MPC quadratic program of one layer (the jetting MPC paper's eqs. 12-15) and its two solvers.

Decision x = (f_l, ..., f_(l+m-1)), shape (m, L, W), 0 <= x <= 1 on printable cells and 0
elsewhere. With G frozen over the horizon, h_(l+i) = h_l + G (f_l + ... + f_(l+i-1)).
Errors are counted in nominal layer heights t, so the weights are dimensionless:

J(x) = sum_i w_i sum_c omega_c ((h_(l+i) - r_(l+i)) / t)_c^2 + rho |x|^2,
w_i = q for i < m and f for i = m (Q = q Omega, F = f Omega, R = rho I, diagonal).
The seed's eq. 15 sums the input term over i = 1..m-1 only (empty for m = 1, and the
applied f_l never penalised); here every planned layer f_l..f_(l+m-1) carries R, and
rho = 0 recovers the literal m = 1 cost.

Fast solver: FISTA (projected accelerated gradient, matrix-free, adaptive restart).
Reference: scipy L-BFGS-B with the same bounds. Both report the projected-gradient
(KKT) residual max |PG J(x)|.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import optimize

from .model import LayerModel

#: default convergence tolerance of the L-BFGS-B reference solve (scipy ftol; gtol is 1e-2 of it)
_LBFGSB_TOL = 1e-10


@dataclass(frozen=True)
class LayerQP:
    """h0: (L, W) measured heights, mm; references: (m, L, W), mm; free: (L, W) bool
    printable cells; stage_weights: (m,); cell_weight: (L, W) omega; rho: R weight;
    scale_mm: nominal layer height t."""

    model: LayerModel
    h0: npt.NDArray[np.float64]
    references: npt.NDArray[np.float64]
    free: npt.NDArray[np.bool_]
    stage_weights: npt.NDArray[np.float64]
    cell_weight: npt.NDArray[np.float64]
    rho: float
    scale_mm: float

    @property
    def horizon(self) -> int:
        return int(self.references.shape[0])

    def residuals(self, x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """(m, L, W) errors (h_(l+i) - r_(l+i)) / t for decision x (m, L, W)."""
        cumulative = x if self.horizon == 1 else np.cumsum(x, axis=0)
        out = np.empty(x.shape)
        for i, c in enumerate(cumulative):
            out[i] = (self.h0 - self.references[i] + self.model.apply(c)) / self.scale_mm
        return out

    def objective(self, x: npt.NDArray[np.float64]) -> float:
        return self.objective_and_gradient(x, need_gradient=False)[0]

    def objective_and_gradient(self, x: npt.NDArray[np.float64],
                               need_gradient: bool = True) -> tuple[float, npt.NDArray[np.float64]]:
        """J(x) and its gradient (m, L, W) (zero on fixed cells)."""
        e = self.residuals(x)
        value = self.rho * float(np.sum(x * x))
        u = np.empty(x.shape) if need_gradient else x
        for i in range(self.horizon):
            we = (self.stage_weights[i] * self.cell_weight) * e[i]
            value += float(np.sum(we * e[i]))
            if need_gradient:
                u[i] = self.model.adjoint(we) * (2.0 / self.scale_mm)
        if not need_gradient:
            return value, x
        grad = u if self.horizon == 1 else np.flip(np.cumsum(np.flip(u, axis=0), axis=0), axis=0)
        grad = grad + 2.0 * self.rho * x
        return value, grad * self.free[None]

    def lipschitz(self) -> float:
        """Upper bound of the gradient's Lipschitz constant."""
        m = self.horizon
        s = np.tril(np.ones((m, m)))
        stage = float(np.linalg.eigvalsh(s.T @ np.diag(self.stage_weights) @ s).max())
        g = self.model.norm_bound() / self.scale_mm
        return 2.0 * stage * float(self.cell_weight.max()) * g * g + 2.0 * self.rho

    def project(self, x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.clip(x, 0.0, 1.0) * self.free[None]

    def kkt_residual(self, x: npt.NDArray[np.float64], grad: npt.NDArray[np.float64] | None = None) -> float:
        """max |projected gradient| over the free cells (0 at a KKT point)."""
        if grad is None:
            grad = self.objective_and_gradient(x)[1]
        inner = np.where(x >= 1.0, np.maximum(grad, 0.0), grad)
        pg = np.where(x <= 0.0, np.minimum(grad, 0.0), inner)
        pg = pg * self.free[None]
        return float(np.abs(pg).max()) if pg.size else 0.0


@dataclass(frozen=True)
class QPSolution:
    """x: (m, L, W) relaxed optimum; objective; iterations; kkt_residual; seconds."""

    x: npt.NDArray[np.float64]
    objective: float
    iterations: int
    kkt_residual: float
    seconds: float


def solve_fista(qp: LayerQP, x0: npt.NDArray[np.float64] | None = None, max_iter: int = 300,
                tol: float = 1e-4) -> QPSolution:
    """Projected FISTA with gradient-based adaptive restart; stops when the gradient
    mapping L |y - x_new|_inf <= tol (units: objective per drop)."""
    start = time.perf_counter()
    shape = qp.references.shape
    x = qp.project(np.zeros(shape) if x0 is None else x0)
    step = 1.0 / qp.lipschitz()
    y, t = x.copy(), 1.0
    iterations = 0
    for iterations in range(1, max_iter + 1):
        _, g = qp.objective_and_gradient(y)
        x_new = qp.project(y - step * g)
        if np.abs(y - x_new).max() / step <= tol:
            x = x_new
            break
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        if np.sum((y - x_new) * (x_new - x)) > 0.0:  # momentum points uphill: restart
            t_new, y = 1.0, x_new.copy()
        else:
            y = x_new + ((t - 1.0) / t_new) * (x_new - x)
        x, t = x_new, t_new
    value, grad = qp.objective_and_gradient(x)
    return QPSolution(x=x, objective=value, iterations=iterations,
                      kkt_residual=qp.kkt_residual(x, grad), seconds=time.perf_counter() - start)


def solve_lbfgsb(qp: LayerQP, x0: npt.NDArray[np.float64] | None = None, max_iter: int = 2000,
                 tol: float = _LBFGSB_TOL) -> QPSolution:
    """Reference solve with scipy's L-BFGS-B on the free cells (bounds [0, 1])."""
    start = time.perf_counter()
    shape = qp.references.shape
    free = np.broadcast_to(qp.free[None], shape)
    full = np.zeros(shape)
    start_x = qp.project(np.zeros(shape) if x0 is None else x0)[free]

    def fun(v: npt.NDArray[np.float64]) -> tuple[float, npt.NDArray[np.float64]]:
        full[free] = v
        value, grad = qp.objective_and_gradient(full)
        return value, grad[free]

    result = optimize.minimize(fun, start_x, jac=True, method="L-BFGS-B",
                               bounds=optimize.Bounds(0.0, 1.0),
                               options={"maxiter": max_iter, "ftol": tol, "gtol": tol * 1e-2,
                                        "maxcor": 20})
    x = np.zeros(shape)
    x[free] = np.clip(result.x, 0.0, 1.0)
    value, grad = qp.objective_and_gradient(x)
    return QPSolution(x=x, objective=value, iterations=int(result.nit),
                      kkt_residual=qp.kkt_residual(x, grad), seconds=time.perf_counter() - start)
