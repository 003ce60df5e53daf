"""The one-operation-at-a-time rule every machine backend keeps (a mixin): an operation
claims the machine (``MachineBusy`` while another holds it, ``MachineStateError`` when it
is disconnected or in error) and releases it with the state it leaves."""

from __future__ import annotations

import threading
from typing import Protocol, TypeVar

from .errors import InvalidConfig, MachineBusy, MachineStateError


class Claimable(Protocol):
    """What the rule needs of a backend: its link (None while disconnected), the lock an
    operation holds, the state it sets and the state it reports."""

    _state: str
    _hold: threading.Lock

    @property
    def link(self) -> object | None: ...

    @property
    def state(self) -> str: ...


class ClaimedOperations:
    """Part of every backend (``Claimable``: what it uses of it)."""

    def _claim(self: Claimable, state: str) -> None:
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        if not self._hold.acquire(blocking=False):
            raise MachineBusy(f"machine is {self._state}", field="state", value=self._state)
        if self.state == "error":
            self._hold.release()
            raise MachineStateError("machine is in error state: reconnect first", field="state",
                                    value="error")
        self._state = state

    def _release(self: Claimable, state: str = "idle") -> None:
        self._state = state
        self._hold.release()


_Link = TypeVar("_Link")


def connected(link: _Link | None) -> _Link:
    """``link``, an operation's open link; ``MachineStateError`` while disconnected (None)."""
    if link is None:
        raise MachineStateError("machine is not connected", field="state", value="disconnected")
    return link


def axis_words(x: float | None, y: float | None, z: float | None) -> str:
    """`` X.. Y.. Z..`` (mm, 4 decimals) of the axes given; ``InvalidConfig`` when none is."""
    words = "".join(f" {a}{v:.4f}" for a, v in zip("XYZ", (x, y, z)) if v is not None)
    if not words:
        raise InvalidConfig("move needs at least one of x, y, z", field="move")
    return words
