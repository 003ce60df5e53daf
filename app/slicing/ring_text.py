"""Many rings' coordinates as fixed-decimal text at once, for the CLI and JSON exports.

A slice's exports write every contour vertex as ``%.{d}f`` text (never ``-0.000...``); one
``%``-format per ring costs a Python call per ring and per number.  :func:`ring_texts` formats
blocks of rings together with :func:`app.gcode.fixed_text.number_columns` (the digits printf
writes, as byte columns) and cuts the block's text back into one string per ring: the same
characters as the per-ring formatters :func:`points_text` and :func:`pairs_text`, which it
falls back to for a block it cannot lay out exactly (a number beyond 2**52 units of the last
decimal, or a negative one that would read ``-0.000...``, as printf writes it).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator, Sequence

import numpy as np
import numpy.typing as npt

from app.gcode.fixed_text import number_columns

BLOCK_VALUES = 65_536  # numbers formatted together (memory: ~30 bytes each while a block is built)
_NUL = 0


def _flat(ring: npt.NDArray[np.float64], decimals: int) -> npt.NDArray[np.float64]:
    """``ring``'s numbers (2n,), row by row, with those that print as zero made 0.0."""
    flat = np.asarray(ring, dtype=np.float64).ravel() + 0.0
    flat[np.abs(flat) < 0.5 * 10.0 ** -decimals] = 0.0
    return flat


def points_text(ring: npt.NDArray[np.float64], decimals: int) -> str:
    """``x,y,x,y,...`` of ``ring`` (n, 2) at ``decimals`` (formatted in C, never ``-0.000...``)."""
    flat = _flat(ring, decimals)
    return (",".join([f"%.{decimals}f"] * len(flat))) % tuple(flat.tolist())


def pairs_text(ring: npt.NDArray[np.float64], decimals: int) -> str:
    """``[x,y],[x,y],...`` of ``ring`` (n, 2) at ``decimals`` (formatted in C, never ``-0.000...``)."""
    flat = _flat(ring, decimals)
    pair = f"[%.{decimals}f,%.{decimals}f]"
    return ",".join([pair] * (len(flat) // 2)) % tuple(flat.tolist())


def _literal(text: bytes, n: int) -> npt.NDArray[np.uint8]:
    return np.tile(np.frombuffer(text, dtype=np.uint8), (n, 1))


def _block_texts(rings: Sequence[npt.NDArray[np.float64]], decimals: int, pairs: bool) -> list[str]:
    """The text of each of ``rings`` ((n_i, 2) mm each), as :func:`pairs_text` (``pairs``) or
    :func:`points_text` writes it."""
    format_one = pairs_text if pairs else points_text
    sizes = [len(ring) for ring in rings]
    if not sum(sizes):
        return [format_one(ring, decimals) for ring in rings]
    flat = np.concatenate([_flat(ring, decimals) for ring in rings])
    try:
        columns = number_columns(flat, decimals)
    except ValueError:  # beyond the columns' exact range: printf, ring by ring
        return [format_one(ring, decimals) for ring in rings]
    if bool(((flat < 0) & (columns[:, 0] != ord("-"))).any()):
        # a negative number that prints as -0.000... (printf keeps its sign; the columns do not)
        return [format_one(ring, decimals) for ring in rings]
    n = len(flat) // 2
    xs, ys = columns[0::2], columns[1::2]
    parts = ([_literal(b"[", n), xs, _literal(b",", n), ys, _literal(b"],", n)] if pairs
             else [xs, _literal(b",", n), ys, _literal(b",", n)])
    table = np.concatenate(parts, axis=1)
    ends = np.cumsum(np.count_nonzero(table != _NUL, axis=1))
    text = table[table != _NUL].tobytes().decode("ascii")
    out: list[str] = []
    start = point = 0
    for size in sizes:
        if not size:
            out.append("")
            continue
        point += size
        end = int(ends[point - 1])
        out.append(text[start:end - 1])  # without the last separator
        start = end
    return out


def ring_texts(rings: Iterable[npt.NDArray[np.float64]], decimals: int, *, pairs: bool = False) -> Iterator[str]:
    """The text of each of ``rings`` in order (:func:`points_text`, or :func:`pairs_text` with
    ``pairs``), formatted a block of about :data:`BLOCK_VALUES` numbers at a time.  A ring that
    is the same array as one before it (the layers of a prismatic stretch share their section's
    rings) is formatted once."""
    every = list(rings)  # held while formatting: an array's id names it alone meanwhile
    uses = Counter(id(ring) for ring in every)  # a text is let go after its ring's last use
    text: dict[int, str] = {}
    block: list[npt.NDArray[np.float64]] = []
    values = 0
    queued: set[int] = set()
    done = 0  # every[:done] have their text

    def format_block() -> None:
        nonlocal block, values
        for ring, t in zip(block, _block_texts(block, decimals, pairs)):
            text[id(ring)] = t
        block, values = [], 0

    def texts(upto: int) -> Iterator[str]:
        for ring in every[done:upto]:
            key = id(ring)
            uses[key] -= 1
            yield text[key] if uses[key] else text.pop(key)

    for k, ring in enumerate(every):
        if id(ring) not in queued:
            queued.add(id(ring))
            block.append(ring)
            values += 2 * len(ring)
            if values >= BLOCK_VALUES:
                format_block()
                yield from texts(k + 1)
                done = k + 1
    if block:
        format_block()
    yield from texts(len(every))
