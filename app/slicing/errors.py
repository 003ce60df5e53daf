"""The slicing package's exception family (pure)."""

from __future__ import annotations

from app.domain.errors import InvalidInput


class SlicingError(InvalidInput):
    """Bad input for slicing, offsets, exports or fills (422).

    ``field`` names the offending input (e.g. ``"params.l_min"``, ``"mesh"``) and
    ``value`` carries a short JSON-friendly value.
    """


class MeshError(SlicingError):
    """The mesh cannot be sliced (open, inconsistent, empty) and could not be repaired."""
