"""Reconstructions a board reconstruct job stored, held in memory for the compensate job that
reads them next.

A board's closed loop runs ``reconstruct`` and then ``compensate`` on the same traces, and the
compute pool gives the second the process that ran the first (it holds their part).  Each
stored reconstruction is an artifact (``reconstruction.<trace_id>.npz``) that the compensate
job would parse back, spline by spline, for every trace: about a fifth of compensating it.  The
reconstruct job also leaves each :class:`Reconstruction` here, under the sha256 of the
bytes it stored, and the compensate job takes it (once) instead of parsing those bytes: a
stored artifact's sha256 names exactly those bytes, so what it takes is what it would have
read (:func:`app.reconstruction.stored.read_reconstruction` of the same bytes writes the same
programs: ``tests/jobs/test_held_reconstructions.py``).  A miss (another process, a later
attempt, an entry let go) reads the artifact as before.  Bounded by the stored bytes
(:data:`MAX_BYTES`), the oldest let go first.
"""

from __future__ import annotations

import dataclasses
import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

from app.geometry.tolerance import LENGTH_EPS_MM
from app.geometry.traces import TracePolyline
from app.reconstruction.reconstruct import Reconstruction
from app.reconstruction.stored import read_reconstruction

MAX_BYTES = 32 * 2**20  # ~2,000 board traces' stored reconstructions (~14 KB each on the dome)


class HeldReconstructions:
    """sha256 of stored bytes -> the reconstruction they hold, taken at most once."""

    def __init__(self, max_bytes: int = MAX_BYTES) -> None:
        self.max_bytes = max_bytes
        self._items: OrderedDict[str, tuple[Reconstruction, int]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def hold(self, reconstruction: Reconstruction, data: bytes) -> None:
        """Hold ``reconstruction``, stored as ``data`` (its npz bytes)."""
        key = hashlib.sha256(data).hexdigest()
        with self._lock:
            old = self._items.pop(key, None)
            self._bytes += len(data) - (old[1] if old else 0)
            self._items[key] = (reconstruction, len(data))
            while self._bytes > self.max_bytes and self._items:
                _, (_, size) = self._items.popitem(last=False)
                self._bytes -= size

    def take(self, sha256: str) -> Reconstruction | None:
        """The reconstruction stored as the bytes ``sha256``, let go here; None when not held."""
        with self._lock:
            item = self._items.pop(sha256, None)
            if item is None:
                return None
            self._bytes -= item[1]
            return item[0]

    def __len__(self) -> int:
        return len(self._items)


HELD = HeldReconstructions()


def stored_reconstruction(sha256: str, read: Callable[[], bytes], nominal: TracePolyline) -> Reconstruction:
    """The reconstruction stored as the blob ``sha256`` over ``nominal`` (the trace's polyline
    in its frame): the held one when there is one (checked against ``nominal`` as the reader
    checks it, its nominal then ``nominal``), else ``read()``'s bytes parsed."""
    held = HELD.take(sha256)
    if held is not None and np.isclose(held.nominal.length_mm, nominal.length_mm, rtol=0.0, atol=LENGTH_EPS_MM):
        return held if held.nominal is nominal else dataclasses.replace(held, nominal=nominal)
    return read_reconstruction(read(), nominal)
