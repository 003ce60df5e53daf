"""Pages of a circuit import's answer: a 5,000-track board's answer holds thousands of
traces, pads and warnings; ``limit`` / ``offset`` cut every list of it to one page, and the
answer's ``totals`` give every list's full length (so a client pages on until it has them)."""

from __future__ import annotations

from typing import Any

__all__ = ["PAGED", "paged"]

#: the lists of an import's answer that are paged (each with the same offset and limit)
PAGED = ("traces", "pads", "areas", "warnings", "vias", "probe_paths", "outline")


def paged(answer: Any, offset: int, limit: int | None) -> dict[str, int]:
    """Cut every :data:`PAGED` list of ``answer`` (a model) to rows ``offset .. offset + limit``
    (all from ``offset`` when ``limit`` is None) in place; their full lengths."""
    totals = {}
    for name in PAGED:
        rows = getattr(answer, name)
        totals[name] = len(rows)
        setattr(answer, name, rows[offset:] if limit is None else rows[offset:offset + limit])
    return totals
