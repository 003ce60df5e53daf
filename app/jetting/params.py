"""Parameters of the droplet-jetting model, plant, controller and job (frozen dataclasses).

Units: mm inside; user-facing fields carry their unit in the name (``_um``, ``_pl``,
``_rad``). Every number the package uses lives here, so one object is passed explicitly.
The bounds in the annotations are the ranges a job may ask for (a kind's parameter model
reads them); the package checks what it needs where it uses a value.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

from annotated_types import Ge, Gt, Le

LayerModelKind = Literal["transport", "seed_diagonal"]  # ControllerParams.model
SolverKind = Literal["fista", "lbfgsb"]  # ControllerParams.solver
BinarizeKind = Literal["greedy", "threshold", "error_diffusion"]  # ControllerParams.binarize

MM_PER_INCH = 25.4
MM3_PER_PL = 1e-6  # 1 pL = 1e-9 cm^3 = 1e-6 mm^3
MM_PER_UM = 1e-3


@dataclass(frozen=True)
class DropParams:
    """Print resolution and the nominal droplet (as published: 300 dpi, ~60 um spread).

    ``drop_volume_pl`` is not given by the seed; 6 pL puts one full layer at 0.84 um,
    which makes the open-loop Sa at 200 layers with 2 % nozzle spread close to the
    seed's 2.65 um (Sa ~ 0.8 * spread * height).
    """

    dpi: Annotated[float, Ge(25), Le(2400)] = 300.0
    drop_diameter_um: Annotated[float, Gt(0), Le(2000)] = 60.0
    drop_volume_pl: Annotated[float, Gt(0), Le(10_000)] = 6.0
    supersample: int = 9  # sub-samples per cell and axis when integrating the drop cap

    @property
    def pitch_mm(self) -> float:
        return MM_PER_INCH / self.dpi

    @property
    def volume_mm3(self) -> float:
        return self.drop_volume_pl * MM3_PER_PL

    @property
    def radius_mm(self) -> float:
        return 0.5 * self.drop_diameter_um * MM_PER_UM

    @property
    def layer_mm(self) -> float:
        """Height of one full layer (one drop per cell): V / pitch^2, mm."""
        return self.volume_mm3 / self.pitch_mm**2


@dataclass(frozen=True)
class FlowParams:
    """The published threshold flow (eq. 7): ink moves between 4-neighbours i, j only when
    |h_i - h_j| > threshold; the edge's mobility (2/pi) eta_s(k, lambda) in [0, 1] is
    ``mobility`` on a flat substrate and grows by ``slope_gain`` per radian of substrate
    tilt k above ``slope_lambda_rad``. ``flow_steps`` explicit sub-steps per layer (how far the
    liquid travels before UV cure)."""

    threshold_um: Annotated[float, Ge(0), Le(1000)] = 3.0
    mobility: Annotated[float, Ge(0), Le(1)] = 0.5
    slope_lambda_rad: float = 0.2
    slope_gain: float = 1.0
    flow_steps: Annotated[int, Ge(0), Le(50)] = 1

    @property
    def threshold_mm(self) -> float:
        return self.threshold_um * MM_PER_UM


@dataclass(frozen=True)
class PlantParams:
    """What the controller does not know: per-nozzle volume spread (relative std), per-drop
    noise (relative std), model mismatch (mean volume, flow mobility and threshold
    factors), dead nozzles (indices) and height-sensor noise. Seeded, reproducible.
    Grid column j is printed by nozzle ``j % n_nozzles`` (GH2220: 384 nozzles)."""

    nozzle_spread: Annotated[float, Ge(0), Le(0.5)] = 0.02
    drop_noise: Annotated[float, Ge(0), Le(0.5)] = 0.01
    volume_bias: Annotated[float, Ge(0.1), Le(10)] = 1.0
    mobility_factor: Annotated[float, Ge(0), Le(10)] = 1.0
    threshold_factor: Annotated[float, Ge(0), Le(10)] = 1.0
    dead_nozzles: tuple[int, ...] = ()
    n_nozzles: Annotated[int, Ge(1), Le(100_000)] = 384
    sensor_noise_um: Annotated[float, Ge(0), Le(100)] = 0.2
    seed: Annotated[int, Ge(0), Le(2**32 - 1)] = 0


@dataclass(frozen=True)
class ControllerParams:
    """Open loop or the seed's MPC (eqs. 12-15).

    Cost per layer, errors in units of the nominal layer height t:
    sum_{i<m} q |h_i - r_i|^2 + f |h_m - r_m|^2 + r sum_k |f_k|^2, weights on part cells
    (``outside_weight`` times that off the part). The reference rises ``fill`` layer
    heights per layer (< 1 leaves the controller room to add drops where material is
    missing). ``edge_lead`` (nominal layer heights) raises the reference of the part cells
    within ``edge_rings`` cells of the part's edge (outer and hole edges), tapering linearly
    from ``edge_lead`` on the edge cells to ``edge_lead / edge_rings`` on the last ring, and
    coming in while the reference level rises from one flow threshold to two: the edge-aware
    target (:func:`app.jetting.controller.edge_lead_map`; chosen on plant seeds 0 and 1 of the
    seed case); ``edge_lead`` 0 is the published MPC's flat reference. ``model``: "seed_diagonal" = the seed's
    (I + Dg) B; "transport" = the same frozen flow kept as a mass-conserving sparse transport operator. ``solver``:
    "fista" (fast) or "lbfgsb" (reference). ``binarize``: "threshold", "error_diffusion"
    or "greedy" (greedy flips on the model's QP, started from the threshold pattern).
    """

    kind: str = "mpc"
    horizon: Annotated[int, Ge(1), Le(10)] = 1
    q_weight: Annotated[float, Ge(0), Le(1e6)] = 1.0
    r_weight: Annotated[float, Ge(0), Le(1e6)] = 1e-3
    f_weight: Annotated[float, Gt(0), Le(1e6)] = 1.0
    outside_weight: Annotated[float, Ge(0), Le(1e6)] = 0.0
    fill: Annotated[float, Gt(0), Le(1)] = 0.8
    edge_lead: Annotated[float, Ge(0), Le(1000)] = 8.0
    edge_rings: Annotated[int, Ge(0), Le(100)] = 4
    model: LayerModelKind = "transport"
    solver: SolverKind = "fista"
    binarize: BinarizeKind = "greedy"
    max_iter: Annotated[int, Ge(1), Le(100_000)] = 300
    tol: Annotated[float, Gt(0), Le(1)] = 1e-2
    greedy_rounds: Annotated[int, Ge(0), Le(50)] = 1


@dataclass(frozen=True)
class TargetSpec:
    """Parametric target: the seed's square (``size_mm``) with a centred square hole."""

    shape: str = "square_with_hole"
    size_mm: float = 10.0
    hole_mm: float = 4.0


@dataclass(frozen=True)
class JettingParams:
    """Everything one simulated closed-loop run needs."""

    drop: DropParams = field(default_factory=DropParams)
    flow: FlowParams = field(default_factory=FlowParams)
    plant: PlantParams = field(default_factory=PlantParams)
    controller: ControllerParams = field(default_factory=ControllerParams)
    target: TargetSpec = field(default_factory=TargetSpec)
    layers: int = 200
    margin_mm: float = 0.25
    snapshot_every: int = 0  # keep a height map every k layers (0: final only)
    memory_limit_bytes: int = 2 * 1024**3
