"""app/probing: point count (the published formula), probe selection, probe programs, probe grids (pure).

The trace they plan along is :class:`app.geometry.traces.TracePolyline`."""

from app.probing.deviation_prior import DeviationPosterior, DeviationPrior, PriorError, Sites, fit_posterior, path_sites
from app.probing.joint import plan_joint
from app.probing.point_count import PointCount, PointCountError, seed_point_count
from app.probing.program import ProbeProgram, ProbeProgramParams, ProbeRecord, build_probe_program, segment_top_max
from app.probing.selection import METHODS, PlanError, PlanParams, ProbePlan, chord_height_select, plan_probes

__all__ = [
    "DeviationPosterior", "DeviationPrior", "PriorError", "Sites", "fit_posterior", "path_sites",
    "PointCount", "PointCountError",
    "seed_point_count", "ProbeProgram", "ProbeProgramParams", "ProbeRecord",
    "build_probe_program", "segment_top_max", "METHODS", "PlanError", "PlanParams",
    "ProbePlan", "chord_height_select", "plan_probes", "plan_joint",
]
