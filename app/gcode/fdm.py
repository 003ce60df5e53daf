"""FDM / dispensing G-code from a planned toolpath: start, process and end sections.

``write_fdm_gcode(toolpath, FdmParams) -> str`` (pure, byte-identical for equal inputs).
Sections (as the published FDM path planning writes them: only the process part depends on the part):

* start - header (from :class:`~app.gcode.writer.ProgramBuilder`), machine limits
  (M204/M205 for Marlin), heating (extrusion) and relative/absolute E, homing, prime;
* process - per layer ``;LAYER:n`` then for every piece ``; TYPE:<kind>`` (perimeter, infill,
  thin_wall: what a preview colours the moves by), travel (retract in extrusion mode,
  never before the first extrusion) and the extruded moves with E (per mm: the stadium bead
  cross-section :func:`bead_area_mm2` over the filament's) (``mode="extrude"``) or dispenser on/off commands around
  the piece (``mode="dispense"``: Marlin ``M106 S255``/``M107``, grbl ``M8``/``M9`` unless
  overridden);
* end - lift, heaters and dispenser off, motors off (Marlin), program end (grbl ``M2``).
Units: mm and mm/s inside; feeds written as mm/min, temperatures in deg C.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
import numpy.typing as npt
from annotated_types import Ge, Le

from app.domain.checks import require_declared_bounds
from app.gcode.fdm_block import ExtrudeState, LayerBlock, extrude_layers
from app.gcode.reader import Program
from app.gcode.writer import DEFAULT_DIALECT, DIALECTS, Dialect, GcodeError, ProgramBuilder
from app.geometry.tolerance import LENGTH_EPS_MM

if TYPE_CHECKING:  # the slicer imports this writer; the toolpath types are needed only here
    from app.slicing.toolpath import LayerToolpath, Toolpath, ToolpathParams

FdmMode = Literal["extrude", "dispense"]  # E-axis extrusion or dispenser on/off
END_LIFT_MM = 5.0  # the end section lifts the nozzle this far above the last layer
# extrusion layers are written in blocks of about this many points (a few layers of a small
# part at once: a block costs its lines; its arrays stay a few MB)
BLOCK_POINTS = 50_000


def bead_area_mm2(width_mm: float, height_mm: float) -> float:
    """Cross-section of an extruded bead, mm^2: a rectangle with semicircular sides (a
    stadium, PrusaSlicer's Flow model) - ``(w - h) h + pi h^2 / 4``; a bead narrower than
    it is high is a circle of diameter w."""
    w, h = float(width_mm), float(height_mm)
    if w <= h:
        return math.pi * w * w / 4.0
    return (w - h) * h + math.pi * h * h / 4.0


@dataclass(frozen=True)
class FdmParams:
    """G-code output options (mm, mm/s, deg C).  The bounds in the annotations are the ranges
    a toolpath job may ask for (its parameter model reads them); a value outside them is a
    :class:`GcodeError` naming it."""

    dialect: str = DEFAULT_DIALECT
    mode: FdmMode = "extrude"
    job_id: str | None = None
    nozzle_temp_c: Annotated[float, Ge(0), Le(500)] = 210.0
    bed_temp_c: Annotated[float, Ge(0), Le(200)] = 60.0
    retract_mm: Annotated[float, Ge(0), Le(50)] = 0.8
    retract_feed_mm_s: float = 35.0
    z_lift_mm: Annotated[float, Ge(0), Le(50)] = 0.0
    min_travel_for_retract_mm: Annotated[float, Ge(0), Le(1000)] = 1.0
    home: bool = True
    dispense_on: str | None = None
    dispense_off: str | None = None

    def __post_init__(self) -> None:
        require_declared_bounds(self, GcodeError, prefix="params.")


def _start(b: ProgramBuilder, tpp: ToolpathParams, p: FdmParams, rules: Dialect) -> None:
    """The start section: limits, heating, E mode, homing."""
    lim = tpp.limits
    b.comment("start")
    if rules.machine_limits:
        b.raw(f"M204 P{lim.accel_mm_s2:g} T{lim.travel_accel_mm_s2:g} "
              f"R{lim.retract_accel_mm_s2:g}")
        b.raw(f"M205 J{lim.junction_deviation_mm:g}")
    if rules.extrusion and p.mode == "extrude":
        b.raw(f"M140 S{p.bed_temp_c:g}").raw(f"M104 S{p.nozzle_temp_c:g}")
        b.raw(f"M190 S{p.bed_temp_c:g}").raw(f"M109 S{p.nozzle_temp_c:g}")
        b.raw("M82")
    if p.home:
        b.raw("G28")
    if p.mode == "extrude":
        b.raw("G92 E0")


def _end(b: ProgramBuilder, p: FdmParams, z: float, off: str, rules: Dialect) -> None:
    """The end section from the last layer's height ``z`` (mm)."""
    b.comment("end")
    if p.mode == "dispense":
        b.raw(off)
    b.move(z=z + END_LIFT_MM, feed_mm_min=600.0)
    if rules.extrusion and p.mode == "extrude":
        b.raw("M104 S0").raw("M140 S0")
    if rules.motors_off:
        b.raw(rules.motors_off)
    b.end()


def _piece_moves(b: ProgramBuilder, points: list[list[float]], feed_mm_min: float, e_per_mm: float | None,
                 e: float) -> tuple[float, bool]:
    """Write the moves along ``points`` ((x, y) mm, n of them) from the first: a move no
    longer than ``LENGTH_EPS_MM`` is skipped, and so is one whose written X and Y equal the
    last written (its filament goes with the next move).  ``e_per_mm``: filament per mm
    (None: no E words) added to the absolute ``e`` (mm) move by move.  The feed goes on the
    first line.  Returns the E after the piece and whether a line was written.

    Each number is written as :func:`~app.gcode.writer.format_number` writes it, and its
    value as read back is ``round(v, decimals) + 0.0`` (CPython rounds correctly, as the
    text is; ``+ 0.0`` turns -0.0 into the 0.0 that "0.0000" reads as)."""
    decimals = b.decimals
    spec = f".{decimals}f"
    ax, ay = points[0]
    written = (round(ax, decimals), round(ay, decimals))
    lines: list[str] = []
    xs: list[float] = []
    ys: list[float] = []
    es: list[float] = []
    for cx, cy in points[1:]:
        seg = math.hypot(cx - ax, cy - ay)
        ax, ay = cx, cy
        if seg <= LENGTH_EPS_MM:
            continue
        if e_per_mm is not None:
            e += seg * e_per_mm
        target = (round(cx, decimals), round(cy, decimals))
        if target == written:
            continue  # the same line again: its filament goes with the next move
        written = target
        x, y = format(cx, spec), format(cy, spec)
        if x[0] == "-" or y[0] == "-" or x[-1] in "fn" or y[-1] in "fn":   # -0.0000, inf, nan
            x, y = b.coord_text(cx, "x"), b.coord_text(cy, "y")
        xs.append(target[0] + 0.0)
        ys.append(target[1] + 0.0)
        if e_per_mm is None:
            lines.append(f"G1 X{x} Y{y}")
        else:
            w = b.coord_text(e, "e")
            lines.append(f"G1 X{x} Y{y} E{w}")
            es.append(round(e, decimals) + 0.0)
    if not lines:
        return e, False
    feed = b.feed_word(feed_mm_min)
    lines[0] += " " + feed
    b.extend_xy_moves(lines, xs, ys, es if e_per_mm is not None else None, float(feed[1:]))
    return e, True


def write_fdm_gcode(toolpath: Toolpath, params: FdmParams = FdmParams()) -> str:
    """G-code text of ``toolpath`` (a :class:`~app.slicing.toolpath.Toolpath`)."""
    return write_fdm_layers(toolpath.layers, toolpath.params, params)


def write_fdm_layers(layers: Iterable[LayerToolpath], tpp: ToolpathParams, params: FdmParams = FdmParams()) -> str:
    """G-code text of ``layers`` (planned with ``tpp``), consumed one at a time: a generator
    (:func:`~app.slicing.toolpath.iter_toolpath`) is written without holding every layer.
    A move whose written X and Y equal the position before is not written (its E goes with
    the next one): no repeated or zero-length line."""
    return _write(layers, tpp, params, record=False).text()


def write_fdm_program(layers: Iterable[LayerToolpath], tpp: ToolpathParams,
                      params: FdmParams = FdmParams()) -> tuple[str, Program]:
    """:func:`write_fdm_layers` and the :class:`~app.gcode.reader.Program` that
    :func:`~app.gcode.reader.read_program` reads from that text, followed as it is written
    (:class:`~app.gcode.recorder.ProgramRecorder`): the time estimate and the bounds
    without reading the text again."""
    b = _write(layers, tpp, params, record=True)
    return b.text(), b.program()


def _dispense_commands(params: FdmParams) -> tuple[str, str]:
    """The dispenser's (on, off) commands: the job's, else its dialect's own.  GcodeError on an
    unknown mode, extrusion on a dialect without an E axis, or dispensing on a dialect
    with no dispenser commands of its own when the job gives none."""
    if params.mode not in ("extrude", "dispense"):
        raise GcodeError(f"unknown mode {params.mode!r}", field="mode", value=params.mode)
    rules = DIALECTS.get(params.dialect)
    if params.mode == "extrude" and not (rules is not None and rules.extrusion):
        raise GcodeError("extrusion (E axis) output needs the marlin dialect", field="dialect",
                         value=params.dialect)
    on, off = params.dispense_on or "", params.dispense_off or ""  # "": the dialect's
    if rules is None:
        return on, off   # the builder names the unknown dialect
    if rules.dispense is not None:
        return on or rules.dispense[0], off or rules.dispense[1]
    if params.mode == "dispense" and not (on and off):
        raise GcodeError(f"the {params.dialect} dialect has no dispenser commands of its own: give dispense_on "
                         "and dispense_off", field="dispense_on" if not on else "dispense_off", value=None)
    return on, off


def _write(layers: Iterable[LayerToolpath], tpp: ToolpathParams, params: FdmParams, record: bool) -> ProgramBuilder:
    on, off = _dispense_commands(params)
    b = ProgramBuilder(params.dialect, "toolpath", params.job_id, record=record)
    rules = b.dialect
    fil_area = math.pi * (tpp.filament_mm / 2) ** 2
    _start(b, tpp, params, rules)
    b.comment("process")
    e, retracted, extruded = 0.0, False, False
    pos: npt.NDArray[np.float64] | None = None
    travel = tpp.travel_feed_mm_s * 60.0
    z = 0.0
    batch: list[tuple[LayerBlock, LayerToolpath, float]] = []   # extrusion layers written together
    held = 0

    def one_by_one(lay: LayerToolpath, h: float) -> None:
        """A layer written move by move (dispensing, or a point that is not finite: the
        builder names its axis)."""
        nonlocal e, extruded, pos, retracted
        b.raw(f";LAYER:{lay.index}")
        b.move(z=lay.z + params.z_lift_mm, feed_mm_min=travel)
        for piece in lay.pieces:
            start = piece.points[0]
            dist = math.inf if pos is None else math.hypot(*(start - pos))
            if params.mode == "extrude" and extruded and dist > params.min_travel_for_retract_mm \
                    and params.retract_mm > 0:   # never before anything was extruded
                e -= params.retract_mm
                b.move(e=e, feed_mm_min=params.retract_feed_mm_s * 60.0)
                retracted = True
            if dist > LENGTH_EPS_MM:
                b.move(x=start[0], y=start[1], feed_mm_min=travel)
            if params.z_lift_mm:
                b.move(z=lay.z, feed_mm_min=travel)
            if retracted:
                e += params.retract_mm
                b.move(e=e, feed_mm_min=params.retract_feed_mm_s * 60.0)
                retracted = False
            b.comment(f"TYPE:{piece.kind}")
            if params.mode == "dispense":
                b.raw(on)
            feed = piece.feed_mm_s * 60.0
            e_per_mm = bead_area_mm2(piece.width_mm or tpp.line_width_mm, h) / fil_area
            e, wrote = _piece_moves(b, piece.points.tolist(), feed, e_per_mm if params.mode == "extrude" else None, e)
            extruded |= wrote and params.mode == "extrude"
            if params.mode == "dispense":
                b.raw(off)
            pos = piece.points[-1]
            if params.z_lift_mm:
                b.move(z=lay.z + params.z_lift_mm, feed_mm_min=travel)

    def in_blocks(blocks: list[LayerBlock]) -> None:
        nonlocal e, extruded, pos
        e, extruded, pos = extrude_layers(b, blocks, ExtrudeState(e, extruded, pos), travel, params.retract_mm,
                                          params.retract_feed_mm_s * 60.0, params.min_travel_for_retract_mm,
                                          params.z_lift_mm)

    def flush() -> None:
        """Write the held layers: in one block when every point is finite, else each on its own."""
        nonlocal held
        points = [piece.points for block, _, _ in batch for piece in block.pieces]
        if not points or np.isfinite(np.concatenate(points)).all():
            in_blocks([block for block, _, _ in batch])
        else:
            for block, lay, h in batch:
                if all(np.isfinite(piece.points).all() for piece in block.pieces):
                    in_blocks([block])
                else:
                    one_by_one(lay, h)
        batch.clear()
        held = 0

    for lay in layers:
        z = lay.z
        h = tpp.layer_height_mm or lay.thickness
        if params.mode != "extrude":
            one_by_one(lay, h)
            continue
        line_rate = bead_area_mm2(tpp.line_width_mm, h) / fil_area   # most pieces are a line wide
        rates = [bead_area_mm2(piece.width_mm, h) / fil_area if piece.width_mm else line_rate for piece in lay.pieces]
        batch.append((LayerBlock(lay.index, z, lay.pieces, rates), lay, h))
        held += sum(len(piece.points) for piece in lay.pieces) + 1
        if held >= BLOCK_POINTS:
            flush()
    flush()
    _end(b, params, z, off, rules)
    return b
