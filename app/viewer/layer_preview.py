"""A slicer-style preview of one G-code program: every move with its type and layer, the
dispenser's on/off points, and per layer its height and estimated time.

Read through the one G-code reader (:func:`app.gcode.reader.read_program`) and timed by the
one estimator (:func:`app.gcode.estimator.estimate_program`: the program's own M201/M203/
M204/M205 limits over :class:`~app.gcode.estimator.MachineLimits`' defaults, so a toolpath
job's per-layer ``time_s`` is found again here).

Move types: a dispensing move (dispenser on, or the extruder advancing) takes the type of the
last tag before its line — ``; TYPE:<kind>`` (the FDM writer's perimeter / infill /
thin_wall; Cura's ``;TYPE:WALL-OUTER`` ...) or a circuit program's stroke comment
(``; trace <name>``, ``; pass``, ``; pad``, ``; area``) — else ``print``; every other move is
``travel``.  Layers: the program's ``;LAYER:n`` tags in order (the moves before the first
tag are drawn with it, but their time is no layer's: as the estimator's ``layer_times``); a
program without them is one layer.  A layer's z is the highest z its dispensing moves end at; its height is that z minus
the previous layer's (the first: minus ``floor_z``).

``offset_mm`` is added to every point: the program drawn in another frame.  Units mm, s.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from app.gcode.estimator import estimate_program
from app.gcode.lines import GcodeReadError
from app.gcode.reader import ReadOptions, read_program

TRAVEL = "travel"
PRINT = "print"
_TYPE_TAG = re.compile(r"^\s*;\s*TYPE:\s*([A-Za-z0-9_-]+)", re.IGNORECASE)
_STROKE_TAG = re.compile(r"^\s*;\s*(trace|pass|pad|area)\b", re.IGNORECASE)


class PreviewError(GcodeReadError):
    """A program the preview cannot draw (no move at all)."""


@dataclass(frozen=True)
class PreviewLayer:
    """One layer: its tag ``index`` (0 for an untagged program), ``z_mm`` (highest dispensing
    end, NaN without one), ``height_mm`` (z minus the layer below's), ``time_s`` (its moves'
    estimated time), ``moves`` (drawn moves) and ``dispense_mm`` (dispensed path length)."""

    index: int
    z_mm: float
    height_mm: float
    time_s: float
    moves: int
    dispense_mm: float


@dataclass(frozen=True)
class ProgramPreview:
    """The moves of a program, m of them (zero-length moves left out), and its k layers.

    segments: (m, 2, 3) float64 mm start/end; kind: (m,) int index into ``kinds``;
    layer: (m,) int position in ``layers`` (0..k-1); line: (m,) 1-based source line;
    on_points / off_points: (j, 3) where the dispenser switches on (start of a dispensing
    run) / off (its end), with on_layer / off_layer (j,) their layer positions;
    layers: the k :class:`PreviewLayer`; time_s: the whole program's estimate (s)."""

    name: str
    segments: np.ndarray
    kind: np.ndarray
    kinds: tuple[str, ...]
    layer: np.ndarray
    line: np.ndarray
    on_points: np.ndarray
    on_layer: np.ndarray
    off_points: np.ndarray
    off_layer: np.ndarray
    layers: tuple[PreviewLayer, ...]
    time_s: float

    def counts(self) -> dict[str, int]:
        """Moves per type."""
        return {k: int(np.count_nonzero(self.kind == i)) for i, k in enumerate(self.kinds)}

    def drawn_points(self) -> np.ndarray:
        """(q, 3) the ends of the dispensing moves (every move's when none dispenses): what a
        camera frames (a start section's travel from the machine's origin is not the part)."""
        printing = self.kind != self.kinds.index(TRAVEL) if TRAVEL in self.kinds else np.ones(len(self.kind), bool)
        chosen = self.segments[printing] if printing.any() else self.segments
        return chosen.reshape(-1, 3)

    def shifted(self, offset_mm: np.ndarray) -> ProgramPreview:
        """The same preview moved by ``offset_mm`` (3,)."""
        off = np.asarray(offset_mm, float).reshape(3)
        return ProgramPreview(self.name, self.segments + off, self.kind, self.kinds, self.layer, self.line,
                              self.on_points + off, self.on_layer, self.off_points + off, self.off_layer,
                              tuple(PreviewLayer(lay.index, lay.z_mm + off[2], lay.height_mm, lay.time_s, lay.moves,
                                                 lay.dispense_mm) for lay in self.layers), self.time_s)


def line_tags(text: str) -> tuple[tuple[str, ...], np.ndarray]:
    """The move types named in ``text`` and, per source line (index = line number - 1), the
    index of the type in force after it (-1 before any tag)."""
    names: dict[str, int] = {}
    codes = []
    current = -1
    for raw in text.splitlines():
        found = (_TYPE_TAG.match(raw) or _STROKE_TAG.match(raw)) if ";" in raw else None
        if found:
            current = names.setdefault(found.group(1).lower(), len(names))
        codes.append(current)
    return tuple(names), np.asarray(codes, np.int64)


def _runs(flag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last index of each run of True in ``flag`` (m,)."""
    padded = np.concatenate([[False], flag, [False]]).astype(np.int8)
    edges = np.diff(padded)
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1


def program_preview(text: str | bytes, name: str = "program", dispense_on: str | None = None,
                    dispense_off: str | None = None, floor_z: float = 0.0) -> ProgramPreview:
    """The preview of G-code ``text`` (see the module docstring).  ``dispense_on``/``off``:
    the profile's exact lines.  Raises :class:`GcodeReadError` on unreadable text and
    :class:`PreviewError` for a program without moves."""
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise GcodeReadError("the program is not UTF-8 text", field="gcode", value=str(exc)[:80]) from None
    program = read_program(text, ReadOptions(dispense_on=dispense_on, dispense_off=dispense_off))
    times = estimate_program(program).block_times if program.count else np.zeros(0)
    start, end = program.start[:, :3], program.end[:, :3]
    moved = np.any(end != start, axis=1)
    if not moved.any():
        raise PreviewError("the program has no moves", field="gcode", value=len(text))
    vocab, codes = line_tags(text)
    line = program.line
    dispense = program.dispense & moved
    # per move: a tag's index, len(vocab) for an untagged dispensing move (PRINT), +1 for travel
    inside = (line >= 1) & (line <= len(codes))
    tagged = np.where(inside, codes[np.clip(line - 1, 0, max(len(codes) - 1, 0))] if len(codes) else -1, -1)
    raw = np.where(dispense, np.where(tagged >= 0, tagged, len(vocab)), len(vocab) + 1)
    names = (*vocab, PRINT, TRAVEL)
    seen = sorted({names[i] for i in np.unique(raw[moved])}, key=lambda k: (k == TRAVEL, k == PRINT, k))
    index_of = np.array([seen.index(n) if n in seen else -1 for n in names], np.int64)
    tag_ids = np.unique(program.layer[program.layer >= 0])
    if len(tag_ids):   # moves before the first tag (the start section) go with the first layer
        position = np.searchsorted(tag_ids, np.maximum(program.layer, tag_ids[0]))
    else:
        position = np.zeros(program.count, np.int64)
    layers = []
    below = float(floor_z)
    for k, tag in enumerate(tag_ids if len(tag_ids) else [0]):
        mine = position == k
        printed = mine & dispense
        z = float(end[printed, 2].max()) if printed.any() else float("nan")
        height = z - below if np.isfinite(z) else float("nan")
        below = z if np.isfinite(z) else below
        length = float(np.linalg.norm(end[printed] - start[printed], axis=1).sum())
        timed = program.layer == tag if len(tag_ids) else mine   # the start section is no layer's time
        layers.append(PreviewLayer(int(tag), z, height, float(times[timed].sum()), int(np.count_nonzero(mine & moved)),
                                   length))
    first, last = _runs(dispense)
    keep = np.flatnonzero(moved)
    return ProgramPreview(
        name, np.stack([start[keep], end[keep]], axis=1), index_of[raw[keep]],
        tuple(seen), position[keep].astype(np.int64), line[keep].astype(np.int64),
        start[first].copy(), position[first].astype(np.int64), end[last].copy(), position[last].astype(np.int64),
        tuple(layers), float(times.sum() + program.dwell_s))
