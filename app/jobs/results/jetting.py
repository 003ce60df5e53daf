"""Typed results of the jetting kinds (``jetting``, ``jetting_next_layer``).

Written by the kinds through :meth:`app.jobs.results.models.KindResult.written` and read back through
:meth:`~app.jobs.results.models.KindResult.of` (see :mod:`app.jobs.results.models`).  Heights and surface
metrics are in um, pitches in mm, solve times in ms.
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import BaseModel, ConfigDict
from pydantic.dataclasses import dataclass

from app.jetting.controller import QpFigures
from app.jetting.metrics import SurfaceMetrics
from app.jetting.simulate import LayerSolve
from app.jobs.results.models import KindResult

_STRICT = ConfigDict(extra="forbid")  # a stored layer with an unknown key is an error, as in KindResult


class JettingGrid(BaseModel):
    """The print grid: ``shape`` [L, W] cells at ``pitch_mm``, ``part_cells`` on the part, the
    nominal ``layer_height_um``."""

    model_config = ConfigDict(extra="forbid")
    shape: list[int]
    pitch_mm: float
    part_cells: int
    layer_height_um: float


@dataclass(frozen=True, config=_STRICT)
class JettingLayer(LayerSolve, SurfaceMetrics):
    """One printed layer (:meth:`app.jetting.simulate.LayerRecord.as_dict`): its surface
    metrics (the core's :class:`~app.jetting.metrics.SurfaceMetrics`, um) and its own figures
    (the core's :class:`~app.jetting.simulate.LayerSolve`: drops, the controller's solve)."""


class JettingResult(KindResult):
    """A jetting job: per-layer figures (``layers``), the last layer's again (``final``), the grid,
    the controller, the median solve time (ms) and the pattern PNG artifacts' names."""

    kind: ClassVar[str] = "jetting"
    layers: list[JettingLayer]
    final: JettingLayer
    grid: JettingGrid
    controller: str
    solve_ms_median: float
    pattern_pngs: list[str]


class NextLayerResult(KindResult, QpFigures):
    """A jetting_next_layer job: the layer QP's figures (the core's
    :class:`~app.jetting.controller.QpFigures`: solve ms, iterations, gap, KKT residual, relaxed
    and binary objectives, greedy flips), the pattern's drops, the reference's level over the
    part (um; the edge-aware lead near the edges comes on top), the snapshot layer used (None
    for inline / 2-D maps) and the grid."""

    kind: ClassVar[str] = "jetting_next_layer"
    drops: int
    reference_height_um: float
    measured_layer: int | None
    grid: JettingGrid


@dataclass(frozen=True, config=_STRICT)
class MachineLayer(SurfaceMetrics):
    """One layer jetted on a machine: the surface metrics of its MEASURED map (um; cells the scan
    did not see taken from the model's prediction), the drops in its pattern and fired by the
    head (-1: unknown, a layer an interruption cut short), the controller's solve (ms; 0 open loop), the scan's valid
    fraction, the cells filled from the prediction, and the scan passes it took."""

    layer: int
    drops: int
    fired: int
    solve_ms: float
    valid_fraction: float
    filled_cells: int
    scans: int


class JettingRunResult(KindResult):
    """A jetting_run job: per-layer figures (``layers``), the last layer's (``final``), the grid,
    the controller, the operator's resumes and the median solve time (ms); each layer's measured
    map is the artifact ``measured_NNNN.npz`` (the substrate's: ``substrate.npz``)."""

    kind: ClassVar[str] = "jetting_run"
    layers: list[MachineLayer]
    final: MachineLayer
    grid: JettingGrid
    controller: str
    resumes: int
    solve_ms_median: float
