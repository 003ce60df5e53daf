"""Least-recently-used maps bounded by the bytes their values hold, in memory and over an
optional disk tier: the per-process caches of meshes, fitted fields and scan fields."""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any


class ByteLru:
    """A thread-safe least-recently-used map bounded by the BYTES its values hold.

    ``put(key, value, nbytes)``; ``get(key)`` (None when absent) marks it used;
    ``resize(key, nbytes)`` re-states an entry's size (e.g. after derived structures were
    built on it).  Entries are dropped oldest first while the total exceeds ``max_bytes``;
    the newest entry always stays, even alone over the bound.
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict[Any, tuple[Any, int]] = OrderedDict()
        self._total = 0  # the sum of the entries' bytes, kept as they change
        self._lock = threading.Lock()

    @property
    def bytes(self) -> int:
        return self._total

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Any) -> bool:
        return key in self._items

    def get(self, key: Any) -> Any:
        with self._lock:
            item = self._items.get(key)
            if item is None:
                return None
            self._items.move_to_end(key)
            return item[0]

    def put(self, key: Any, value: Any, nbytes: int) -> None:
        with self._lock:
            self._set(key, value, int(nbytes))
            self._items.move_to_end(key)
            self._evict()

    def resize(self, key: Any, nbytes: int) -> None:
        with self._lock:
            if key in self._items:
                self._set(key, self._items[key][0], int(nbytes))
                self._evict()

    def _set(self, key: Any, value: Any, nbytes: int) -> None:
        old = self._items.get(key)
        self._total += nbytes - (old[1] if old is not None else 0)
        self._items[key] = (value, nbytes)

    def _evict(self) -> None:
        while self._total > self.max_bytes and len(self._items) > 1:
            _, (_, n) = self._items.popitem(last=False)
            self._total -= n


class BackedLru(ByteLru):
    """A :class:`ByteLru` over an optional disk tier ``backing`` (an object with
    ``load(key) -> (value, nbytes) | None`` and ``store(key, value)``, e.g.
    :class:`app.parts.cache.FieldFitStore`): a miss in memory asks the backing; a put writes
    through to it.  Without a backing it is a plain ByteLru."""

    def __init__(self, max_bytes: int, backing: Any = None) -> None:
        super().__init__(max_bytes)
        self.backing = backing

    def get(self, key: Any) -> Any:
        value = super().get(key)
        if value is None and self.backing is not None:
            loaded = self.backing.load(key)
            if loaded is not None:
                super().put(key, loaded[0], loaded[1])
                value = loaded[0]
        return value

    def put(self, key: Any, value: Any, nbytes: int) -> None:
        super().put(key, value, nbytes)
        if self.backing is not None:
            self.backing.store(key, value)
