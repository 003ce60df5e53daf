"""``layers.npz``: a slice's layers as arrays, for the toolpath job to read without parsing text.

The same content as :func:`app.slicing.export.to_json`'s document: its head and per-layer
rows as JSON (``header``, UTF-8 bytes), and the contours, each number rounded to the JSON's
decimals exactly as that text reads back (:func:`app.gcode.writer.as_written`), so that
``from_binary(to_binary(r))`` equals ``from_json(to_json(r))`` ring for ring, bit for bit
(``tests/slicing/test_export_binary.py``).  Arrays (``numpy.savez``, no pickles): ``points``
(V, 2) float64 mm, every ring after the other in the JSON's order (per layer, per island: the
outer, then its holes); ``rings`` (R, 4) int64: layer position, island position, 1 for a
hole, vertex count.
"""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np

from app.gcode.writer import as_written
from app.slicing.errors import SlicingError
from app.slicing.export import document_head, from_document, layer_rows
from app.slicing.layers import SliceResult
from app.slicing.rings import oriented, split_at

NAME = "layers.npz"


def to_binary(result: SliceResult, decimals: int = 6) -> bytes:
    """``result`` as ``layers.npz`` bytes (contours at ``decimals``, as ``to_json`` writes them)."""
    doc = document_head(result)
    doc["layers"] = layer_rows(result)
    table = [(k, j, hole, len(ring)) for k, lay in enumerate(result.layers) for j, isl in enumerate(lay.islands)
             for hole, ring in ((0, isl.outer), *((1, h) for h in isl.holes))]
    points = np.empty((sum(row[3] for row in table), 2))
    at = 0
    done: dict[int, int] = {}  # a ring array already written (a prismatic stretch's shared rings): where
    for lay in result.layers:   # ring by ring: no temporaries of the whole stack
        for isl in lay.islands:
            for ring in isl.rings():
                if id(ring) in done:
                    points[at:at + len(ring)] = points[done[id(ring)]:done[id(ring)] + len(ring)]
                else:
                    done[id(ring)] = at
                    points[at:at + len(ring)] = as_written(np.asarray(ring, dtype=np.float64), decimals)
                at += len(ring)
    out = io.BytesIO()
    np.savez(out, header=np.frombuffer(json.dumps(doc, separators=(",", ":")).encode(), dtype=np.uint8),
             points=points, rings=np.array(table, dtype=np.int64).reshape(-1, 4))
    del points
    return out.getvalue()


def from_binary(data: bytes) -> SliceResult:
    """The :class:`SliceResult` of ``layers.npz`` bytes (as :func:`app.slicing.export.from_json`
    of the same slice's ``layers.json``).  :class:`SlicingError` (field ``layers.npz``) for
    anything else."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as arrays:
            doc = json.loads(arrays["header"].tobytes())
            points, table = arrays["points"], arrays["rings"]
        if points.ndim != 2 or points.shape[1] != 2 or table.ndim != 2 or table.shape[1] != 4 \
                or table[:, 3].sum() != len(points):
            raise ValueError(f"points {points.shape} and ring table {table.shape} do not agree")
        contours: list[list[tuple[np.ndarray, list[np.ndarray]]]] = [[] for _ in doc["layers"]]
        checked = points.dtype == np.float64 and bool((table[:, 3] >= 3).all()) and bool(np.isfinite(points).all())
        rings = split_at(points, np.cumsum(table[:, 3])[:-1])
        if checked:  # every ring valid: oriented here at once (else from_document names the bad one)
            rings = _shared_repeats(table, _oriented(points, table, rings))
        for (k, j, hole, _), ring in zip(table.tolist(), rings):
            if hole:
                contours[k][j][1].append(ring)
            else:
                contours[k].append((ring, []))
        return from_document(doc, contours, checked=checked)
    except SlicingError:
        raise
    except (ValueError, KeyError, TypeError, IndexError, AttributeError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise SlicingError(f"not a {NAME} document: {type(exc).__name__}: {exc}", field=NAME,
                           value=str(exc)[:80]) from None


def _shared_repeats(table: np.ndarray, rings: list[np.ndarray]) -> list[np.ndarray]:
    """``rings`` (the rows of ``table``), each ring equal bit for bit to the ring at its place in
    the layer before (a prismatic stretch: one section for many layers) replaced by that ring's
    array, so that the layers share it as the slice's layers did (what reads them may then
    work on each array once)."""
    out = list(rings)
    before: list[np.ndarray] = []
    current: list[np.ndarray] = []
    layer = -1
    for i, k in enumerate(table[:, 0].tolist()):
        if k != layer:
            before, current, layer = current, [], k
        if len(current) < len(before):
            other = before[len(current)]
            if other.shape == out[i].shape and other.tobytes() == out[i].tobytes():
                out[i] = other
        current.append(out[i])
    return out


def _oriented(points: np.ndarray, table: np.ndarray, rings: list[np.ndarray]) -> list[np.ndarray]:
    """``rings`` (views of ``points`` (V, 2) mm, the rows of ``table``) each as
    :func:`app.slicing.rings.oriented` makes it: outer rings anticlockwise, holes clockwise.
    Every ring's shoelace sum at once; a ring whose sum is too close to zero for its sign to
    be sure (within the rounding of either summation) is decided by ``signed_area`` itself."""
    if not len(rings):
        return rings
    sizes = table[:, 3]
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    following = np.arange(1, len(points) + 1)
    following[starts + sizes - 1] = starts  # each ring's last vertex is followed by its first
    x, y = points[:, 0], points[:, 1]
    terms = x * y[following] - x[following] * y
    twice = np.add.reduceat(terms, starts)
    scale = np.add.reduceat(np.abs(x * y[following]) + np.abs(x[following] * y), starts)
    sure = np.abs(twice) > 4.0 * (sizes + 4) * np.finfo(np.float64).eps * scale
    wrong = np.where(table[:, 2] == 1, twice > 0, twice < 0) & sure  # a hole anticlockwise, an outer clockwise
    out = list(rings)
    for i in np.flatnonzero(wrong).tolist():
        out[i] = rings[i][::-1].copy()
    for i in np.flatnonzero(~sure).tolist():
        out[i] = oriented(rings[i], ccw=not table[i, 2])
    return out
