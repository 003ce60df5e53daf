"""Droplet-jetting morphology compensation (the jetting MPC method): height model, threshold ink flow,
plant simulator, layer-to-layer MPC with binary drop patterns, targets and metrics.

Entry points for the job adapter: ``JettingParams``, ``simulate``, ``next_layer``,
``target_from_png`` / ``target_from_rings`` / ``target_from_spec``, ``pattern_png``,
``npz_bytes``. Pure: arrays and bytes in, named results out.
"""

from .controller import LayerDecision, QpFigures, SolveFigures
from .encode import npz_arrays, npz_bytes, pattern_png, png_pattern
from .errors import JettingError
from .kernel import DropKernel, drop_kernel
from .metrics import SurfaceMetrics, surface_metrics
from .params import (
                     ControllerParams,
                     DropParams,
                     FlowParams,
                     JettingParams,
                     PlantParams,
                     TargetSpec,
)
from .simulate import (
                     LayerRecord,
                     LayerSolve,
                     SimulationResult,
                     estimate_bytes,
                     next_layer,
                     simulate,
)
from .targets import (
                     Target,
                     target_from_mask,
                     target_from_png,
                     target_from_rings,
                     target_from_spec,
)

__all__ = [
    "ControllerParams", "DropKernel", "DropParams", "FlowParams", "JettingError", "JettingParams",
    "LayerDecision", "LayerRecord", "LayerSolve", "PlantParams", "QpFigures", "SimulationResult", "SolveFigures",
    "SurfaceMetrics", "Target",
    "TargetSpec", "drop_kernel", "estimate_bytes", "next_layer", "npz_arrays", "npz_bytes",
    "pattern_png", "png_pattern", "simulate", "surface_metrics", "target_from_mask",
    "target_from_png", "target_from_rings", "target_from_spec",
]
