"""The typed result of the ``five_axis`` kind: the core's :class:`~app.five_axis.planner.FiveAxisFigures`
and the job's own keys, flat.  Written and read through one model, see :mod:`app.jobs.results.models`
(kept apart from it so that reading the other results does not load the five-axis core)."""

from __future__ import annotations

from typing import Any, ClassVar

from app.five_axis.planner import FiveAxisFigures
from app.jobs.results.models import KindResult


class FiveAxisResult(KindResult, FiveAxisFigures):
    """A five_axis job: the path's figures (the core's :class:`~app.five_axis.planner.FiveAxisFigures`:
    degrees, mm, s, percent), the program's frame (``pivot`` [x0, y0, z0] mm, ``post``) and
    dispense codes, the surface it was planned on (``surface``:
    :meth:`~app.geometry.nurbs_surface.NurbsSurface.to_dict`, ``surface_source`` says which),
    the nozzle tips' curve (``offset_curve``) and both programs' G-code summaries."""

    kind: ClassVar[str] = "five_axis"
    dispense_on: str
    dispense_off: str
    post: str
    standoff_mm: float
    feed_mm_min: float
    feed_mode: str
    pivot: list[float]
    surface_source: dict[str, Any]
    surface: dict[str, Any]
    offset_curve: dict[str, Any]
    program: dict[str, Any]
    nominal_program: dict[str, Any]
