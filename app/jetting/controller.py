"""One layer of control: the seed's receding-horizon MPC (solve, binarize, apply first).

``mpc_layer`` is what a real printer calls between layers: measured height map in,
next 0/1 pattern out. The reference sequence R_l (eq. 14) is the part mask raised
``fill`` nominal layer heights per layer: r_(l+i) = (l + i) * fill * t on the part, 0 off it
(the published MPC, ``edge_lead`` 0). The edge-aware target adds a lead e_c * t on the cells
near the part's edges (:func:`edge_lead_map`): r_(l+i) = ((l + i) * fill + e_c) * t.

Why the edges need a lead: the threshold flow drains a liquid edge cell into the empty cell
beside the part on every layer (it holds liquid only where it was just jetted), and that
skirt rises with the part, so the edge loses about a layer's rise per layer. With ``fill`` f
a part cell has (1 - f) of a drop to spare, so about f / (1 - f) rings of cells (4 at 0.8)
must jet every layer and pass ink outwards through steps above the threshold. Against a
flat reference the MPC starts jetting those rings only once they already lag; the lead makes
it jet them from the first layers, so the edges fall behind later and less.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .binarize import BINARIZE_METHODS, binarize
from .errors import JettingError
from .kernel import DropKernel
from .model import MODEL_KINDS, build_layer_model
from .params import ControllerParams, DropParams, FlowParams
from .qp import LayerQP, QPSolution, solve_fista, solve_lbfgsb
from .targets import Target

CONTROLLER_KINDS = ("open_loop", "mpc")
SOLVERS = ("fista", "lbfgsb")


@dataclass(frozen=True)
class SolveFigures:
    """The controller's solve of one layer: ``solve_ms`` (model + QP + binarization, wall clock)
    and ``solve_cpu_ms`` (its CPU time), the solver's ``iterations``, the binarization's
    ``integer_gap`` and the QP's ``kkt_residual`` (all 0 open loop)."""

    solve_ms: float
    solve_cpu_ms: float
    iterations: int
    integer_gap: float
    kkt_residual: float


@dataclass(frozen=True)
class QpFigures(SolveFigures):
    """A layer QP's figures: its solve (:class:`SolveFigures`), its objectives (relaxed, and
    with the binary first layer) and the greedy binarization's ``flips``."""

    objective_relaxed: float
    objective_binary: float
    flips: int


@dataclass(frozen=True)
class LayerDecision(QpFigures):
    """The next layer: its QP's figures (:class:`QpFigures`), pattern: (L, W) bool drops to
    print; relaxed: (m, L, W) QP optimum; reference_mm: (L, W) r_(l+1); level_mm: the
    reference's level (l + 1) * fill * t away from the edges, mm."""

    pattern: npt.NDArray[np.bool_]
    relaxed: npt.NDArray[np.float64]
    reference_mm: npt.NDArray[np.float64]
    level_mm: float


def validate_controller(ctrl: ControllerParams) -> None:
    """Raise ``JettingError`` for controller settings that cannot be used."""
    checks = [
        (ctrl.kind in CONTROLLER_KINDS, "controller", ctrl.kind),  # the controller chosen (its kind)
        (ctrl.model in MODEL_KINDS, "controller.model", ctrl.model),
        (ctrl.solver in SOLVERS, "controller.solver", ctrl.solver),
        (ctrl.binarize in BINARIZE_METHODS, "controller.binarize", ctrl.binarize),
        (1 <= ctrl.horizon <= 10, "controller.horizon", ctrl.horizon),
        (0.0 < ctrl.fill <= 1.0, "controller.fill", ctrl.fill),
        (ctrl.q_weight >= 0 and ctrl.f_weight > 0 and ctrl.r_weight >= 0, "controller.weights",
         [ctrl.q_weight, ctrl.r_weight, ctrl.f_weight]),
        (ctrl.outside_weight >= 0, "controller.outside_weight", ctrl.outside_weight),
        (0.0 <= ctrl.edge_lead <= 1000.0, "controller.edge_lead", ctrl.edge_lead),
        (0 <= ctrl.edge_rings <= 100, "controller.edge_rings", ctrl.edge_rings),
        (ctrl.max_iter >= 1 and ctrl.tol > 0, "controller.max_iter", [ctrl.max_iter, ctrl.tol]),
    ]
    for ok, name, value in checks:
        if not ok:
            raise JettingError(f"invalid {name}", field=name, value=value)


def edge_lead_map(target: Target, ctrl: ControllerParams) -> npt.NDArray[np.float64]:
    """(L, W) lead e_c of the reference, nominal layer heights: on a part cell k cells from
    the part's edge (k = 1: a part cell beside a cell off the part, 4-neighbour steps; holes
    count as off the part) e_c = edge_lead * (R + 1 - k) / R for k <= R = ``edge_rings``,
    0 farther in and off the part."""
    if ctrl.edge_lead == 0.0 or ctrl.edge_rings == 0:
        return np.zeros(target.shape)
    ring = ndimage.distance_transform_cdt(target.mask, metric="taxicab")  # scipy: untyped
    rings = ctrl.edge_rings
    lead: npt.NDArray[np.float64] = ctrl.edge_lead * np.clip((rings + 1 - ring) / rings, 0.0, 1.0) * target.mask
    return lead


def lead_ramp(level_mm: npt.NDArray[np.float64], threshold_mm: float) -> npt.NDArray[np.float64]:
    """The share (0..1) of the edge lead at reference levels ``level_mm`` (any shape), mm: no
    ink leaves an edge before it stands a flow threshold above the empty cell beside it, and
    the drain grows with that step, so the lead comes in linearly while the level rises from
    one threshold to two (all of it at once for a threshold of 0)."""
    if threshold_mm <= 0.0:
        return np.ones(np.shape(level_mm))
    ramp: npt.NDArray[np.float64] = np.clip(np.asarray(level_mm) / threshold_mm - 1.0, 0.0, 1.0)
    return ramp


def references(target: Target, drop: DropParams, ctrl: ControllerParams, layer: int,
               threshold_mm: float = 0.0) -> npt.NDArray[np.float64]:
    """(m, L, W) reference heights r_(l+1..l+m), mm, after ``layer`` printed layers: the level
    (l + i) * fill * t on the part plus the edge lead (:func:`edge_lead_map`) scaled by
    :func:`lead_ramp` of that level and the flow's ``threshold_mm``."""
    level = (layer + np.arange(1, ctrl.horizon + 1, dtype=np.float64)) * (ctrl.fill * drop.layer_mm)
    lead = edge_lead_map(target, ctrl) * drop.layer_mm
    refs: npt.NDArray[np.float64] = (level[:, None, None] * target.mask[None]
                                     + lead_ramp(level, threshold_mm)[:, None, None] * lead[None])
    return refs


def build_qp(measured_mm: npt.NDArray[np.float64], target: Target, guess: npt.NDArray[np.float64], kernel: DropKernel,
             drop: DropParams, flow: FlowParams, mobility: npt.NDArray[np.float64], ctrl: ControllerParams,
             layer: int) -> LayerQP:
    """The layer's QP with G frozen at the predicted flow of ``guess`` (L, W)."""
    model = build_layer_model(measured_mm, guess, kernel, flow, mobility, ctrl.model)
    m = ctrl.horizon
    stage = np.full(m, ctrl.q_weight)
    stage[-1] = ctrl.f_weight
    cell_weight = np.where(target.mask, 1.0, ctrl.outside_weight)
    return LayerQP(model=model, h0=measured_mm, references=references(target, drop, ctrl, layer, flow.threshold_mm),
                   free=target.mask, stage_weights=stage, cell_weight=cell_weight,
                   rho=ctrl.r_weight, scale_mm=drop.layer_mm)


def solve_qp(qp: LayerQP, ctrl: ControllerParams, warm: npt.NDArray[np.float64] | None = None) -> QPSolution:
    """Solve with the configured solver (FISTA or the L-BFGS-B reference)."""
    if ctrl.solver == "lbfgsb":
        return solve_lbfgsb(qp, warm)
    return solve_fista(qp, warm, ctrl.max_iter, ctrl.tol)


def mpc_layer(measured_mm: npt.NDArray[np.float64], target: Target, kernel: DropKernel, drop: DropParams,
              flow: FlowParams, mobility: npt.NDArray[np.float64], ctrl: ControllerParams, layer: int,
              guess: npt.NDArray[np.float64] | None = None,
              warm: npt.NDArray[np.float64] | None = None) -> LayerDecision:
    """Next layer's 0/1 pattern from the measured heights (L, W), mm, after ``layer`` layers.

    guess: (L, W) pattern the flow is frozen at (default: ``fill`` on the part);
    warm: (m, L, W) starting point of the solver (e.g. the previous relaxed solution).
    """
    start, start_cpu = time.perf_counter(), time.thread_time()
    if guess is None:
        guess = ctrl.fill * target.mask.astype(np.float64)
    qp = build_qp(measured_mm, target, guess, kernel, drop, flow, mobility, ctrl, layer)
    solution = solve_qp(qp, ctrl, warm)
    binary = binarize(qp, solution.x, solution.objective, ctrl.binarize, ctrl.greedy_rounds)
    return LayerDecision(
        pattern=binary.pattern, relaxed=solution.x, objective_relaxed=float(solution.objective),
        objective_binary=float(binary.objective), integer_gap=float(binary.integer_gap),
        kkt_residual=float(solution.kkt_residual), iterations=int(solution.iterations),
        solve_ms=(time.perf_counter() - start) * 1e3,
        solve_cpu_ms=(time.thread_time() - start_cpu) * 1e3, flips=int(binary.flips),
        reference_mm=qp.references[0], level_mm=(layer + 1) * ctrl.fill * drop.layer_mm)
