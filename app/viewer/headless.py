"""A drawing target with no browser behind it.

Each view keeps one headless builder and panel that record what the view shows (the
registry behind ``GET /api/v1/viewer/scene``) even before any browser has connected; the
browsers of that view get the same scene drawn into their own, per-client scene.
"""

from __future__ import annotations

import inspect
from typing import Any, Literal


class NullHandle:
    """Accepts any attribute, call, decorator or ``with`` block and does nothing."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return NullHandle()

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return NullHandle()

    def __enter__(self) -> NullHandle:
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        return False


class RecordedNode(NullHandle):
    """A scene node that keeps the arguments it was added with as attributes (e.g. ``points``)."""

    def __init__(self, arguments: dict[str, Any]) -> None:
        self.__dict__.update(arguments)
        self.visible = True

    def remove(self) -> None:
        self.removed = True


class RecordingScene:
    """Mirrors viser's ``SceneApi.add_*`` signatures, recording instead of sending."""

    def __getattr__(self, name: str) -> Any:
        import viser

        real = getattr(viser.SceneApi, name, None)
        if real is None or not name.startswith("add_"):
            return NullHandle()
        signature = inspect.signature(real)

        def add(*args: Any, **kwargs: Any) -> RecordedNode:
            bound = signature.bind(None, *args, **kwargs)
            return RecordedNode({k: v for k, v in bound.arguments.items() if k != "self"})

        return add


class HeadlessTarget:
    """Something with ``.scene`` and ``.gui`` like a viser server or client handle."""

    def __init__(self) -> None:
        self.scene = RecordingScene()
        self.gui = NullHandle()
