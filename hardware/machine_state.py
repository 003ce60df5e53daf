"""The one-operation-at-a-time rule every machine backend keeps (a mixin): an operation
claims the machine (``MachineBusy`` while another holds it, ``MachineStateError`` when it
is disconnected or in error) and releases it with the state it leaves."""

from __future__ import annotations

from .errors import InvalidConfig, MachineBusy, MachineStateError


class ClaimedOperations:
    """Mixin: needs ``link``, ``_hold`` (a Lock), ``_state`` and a ``state`` property."""

    def _claim(self, state: str) -> None:
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        if not self._hold.acquire(blocking=False):
            raise MachineBusy(f"machine is {self._state}", field="state", value=self._state)
        if self.state == "error":
            self._hold.release()
            raise MachineStateError("machine is in error state: reconnect first", field="state",
                                    value="error")
        self._state = state

    def _release(self, state: str = "idle") -> None:
        self._state = state
        self._hold.release()


def axis_words(x: float | None, y: float | None, z: float | None) -> str:
    """`` X.. Y.. Z..`` (mm, 4 decimals) of the axes given; ``InvalidConfig`` when none is."""
    words = "".join(f" {a}{v:.4f}" for a, v in zip("XYZ", (x, y, z)) if v is not None)
    if not words:
        raise InvalidConfig("move needs at least one of x, y, z", field="move")
    return words
