"""Parse big G-code programs in a worker process, and remember what was parsed.

Parsing 100k moves is ~2 s of pure Python: done in the API process it holds the GIL and
every API request queues behind it (the convoy effect measured in
tests/bench/test_bench_viewer.py).  Programs above ``inline_bytes``, and programs whose
arcs need more than ``inline_chords`` chords (counted before any is made), are parsed in
one spawned worker process, with the arc budget of their size
(:func:`app.gcode.reader.arc_chord_budget`); the result (arrays) comes back pickled.  A
program beyond that budget is refused (:class:`app.gcode.reader.ArcBudgetError` naming
the line), never expanded.  Parsed programs are cached by their content hash, so opening
the same job again is immediate.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
from collections import OrderedDict
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from app.gcode.reader import ArcBudgetError, arc_chord_budget, beyond_size_budget
from app.viewer.gcode_paths import ToolpathSegments, parse_toolpath
from app.viewer.layer_preview import ProgramPreview, program_preview

log = logging.getLogger("conforma.viewer")


class ParsePool:
    """``parse(data, on, off, key)`` -> ToolpathSegments, off the API's GIL when large."""

    def __init__(self, inline_bytes: int = 200_000, cache_size: int = 8, inline_chords: int = 20_000) -> None:
        self.inline_bytes = inline_bytes
        self.inline_chords = inline_chords
        self.cache_size = cache_size
        self._cache: OrderedDict[tuple, ToolpathSegments | ProgramPreview] = OrderedDict()
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None

    def _executor(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
            return self._pool

    def parse(self, data: bytes, dispense_on: str | None, dispense_off: str | None,
              key: str | None = None) -> ToolpathSegments:
        cache_key = (key, dispense_on, dispense_off) if key else None
        if cache_key is not None:
            with self._lock:
                if cache_key in self._cache:
                    self._cache.move_to_end(cache_key)
                    return self._cache[cache_key]  # type: ignore[return-value]
        segments = None
        if len(data) <= self.inline_bytes:
            try:
                # at most the size's budget: a refusal beyond it names the first arc over it
                budget = min(self.inline_chords, arc_chord_budget(len(data)))
                segments = parse_toolpath(data, dispense_on, dispense_off, budget)
            except ArcBudgetError as exc:
                refusal = beyond_size_budget(exc, len(data))
                if refusal is not None:
                    raise refusal from None
                segments = None          # more arc chords than the API process draws: the worker's budget
        if segments is None:
            try:
                segments = self._executor().submit(parse_toolpath, data, dispense_on, dispense_off).result()
            except (BrokenProcessPool, OSError, RuntimeError):
                log.warning("G-code worker process unavailable; parsing in the API process", exc_info=True)
                with self._lock:
                    self._pool = None
                segments = parse_toolpath(data, dispense_on, dispense_off, self.inline_chords)
        if cache_key is not None:
            with self._lock:
                self._cache[cache_key] = segments
                while len(self._cache) > self.cache_size:
                    self._cache.popitem(last=False)
        return segments

    def preview(self, data: bytes, name: str, dispense_on: str | None, dispense_off: str | None,
                floor_z: float = 0.0, key: str | None = None) -> ProgramPreview:
        """:func:`app.viewer.layer_preview.program_preview` of ``data``: in this process when
        small, else in the worker process (as :meth:`parse`); cached by ``key``."""
        cache_key = ("preview", key, name, dispense_on, dispense_off, floor_z) if key else None
        with self._lock:
            if cache_key is not None and cache_key in self._cache:
                self._cache.move_to_end(cache_key)
                return self._cache[cache_key]  # type: ignore[return-value]
        args = (data, name, dispense_on, dispense_off, floor_z)
        if len(data) <= self.inline_bytes:
            preview = program_preview(*args)
        else:
            try:
                preview = self._executor().submit(program_preview, *args).result()
            except (BrokenProcessPool, OSError, RuntimeError):
                log.warning("G-code worker process unavailable; previewing in the API process", exc_info=True)
                with self._lock:
                    self._pool = None
                preview = program_preview(*args)
        if cache_key is not None:
            with self._lock:
                self._cache[cache_key] = preview
                while len(self._cache) > self.cache_size:
                    self._cache.popitem(last=False)
        return preview

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)
