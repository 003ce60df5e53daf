"""What the view currently shows: scene nodes, plots and sliders, as plain JSON.

The viewer records every node it pushes here, so that the API (``GET
/api/v1/viewer/scene``), the browser tests and operators can check what is on screen
without reading pixels.  Thread-safe: the API reads while a focus change writes.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class NodeInfo:
    """One scene node: ``kind`` (mesh, points, segments, surface), the toggle ``group`` it
    belongs to, ``count`` (points / segments / faces) and free ``meta``."""

    kind: str
    group: str
    count: int
    meta: dict[str, Any] = field(default_factory=dict)


class SceneRegistry:
    """Nodes, plots and sliders of the current focus, plus a generation counter."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._focus: dict[str, Any] = {}
        self._nodes: dict[str, NodeInfo] = {}
        self._hidden_groups: set[str] = set()
        self._plots: dict[str, dict[str, Any]] = {}
        self._sliders: dict[str, dict[str, Any]] = {}
        self._notes: list[str] = []
        self._legends: list[dict[str, Any]] = []
        self._previews: dict[str, dict[str, Any]] = {}
        self.generation = 0

    def reset(self, focus: dict[str, Any]) -> None:
        with self._lock:
            self._focus = dict(focus)
            self._nodes.clear()
            self._plots.clear()
            self._sliders.clear()
            self._notes.clear()
            self._legends = []
            self._previews.clear()
            self.generation += 1

    def add_node(self, name: str, info: NodeInfo) -> None:
        with self._lock:
            self._nodes[name] = info

    def remove_node(self, name: str) -> None:
        with self._lock:
            self._nodes.pop(name, None)

    def set_group_visible(self, group: str, visible: bool) -> None:
        with self._lock:
            (self._hidden_groups.discard if visible else self._hidden_groups.add)(group)

    def group_visible(self, group: str) -> bool:
        with self._lock:
            return group not in self._hidden_groups

    def add_plot(self, name: str, title: str, x: list[float], y: list[float], x_label: str, y_label: str) -> None:
        with self._lock:
            self._plots[name] = {"title": title, "x": list(x), "y": list(y), "x_label": x_label, "y_label": y_label}

    def set_slider(self, name: str, minimum: int, maximum: int, value: int, labels: list[str] | None = None) -> None:
        with self._lock:
            self._sliders[name] = {"min": minimum, "max": maximum, "value": value, "labels": labels or []}

    def set_preview(self, name: str, info: dict[str, Any]) -> None:
        """A program preview's layer, per-layer figures and legend of move types."""
        with self._lock:
            self._previews[name] = copy.deepcopy(info)

    def set_legends(self, legends: list[dict[str, Any]]) -> None:
        """The colour scales of what is drawn (see :class:`app.viewer.deviation_map.Legend`)."""
        with self._lock:
            self._legends = copy.deepcopy(legends)

    def legends(self) -> list[dict[str, Any]]:
        with self._lock:
            return copy.deepcopy(self._legends)

    def note(self, text: str) -> None:
        with self._lock:
            self._notes.append(text)

    def groups(self) -> list[str]:
        with self._lock:
            return sorted({n.group for n in self._nodes.values()})

    def snapshot(self) -> dict[str, Any]:
        """The JSON form: focus, nodes by name, groups with visibility, plots, sliders, notes."""
        with self._lock:
            nodes = {name: {"kind": n.kind, "group": n.group, "count": n.count,
                            "visible": n.group not in self._hidden_groups, **n.meta}
                     for name, n in sorted(self._nodes.items())}
            groups = {g: g not in self._hidden_groups for g in sorted({n.group for n in self._nodes.values()})}
            return {"generation": self.generation, "focus": dict(self._focus), "nodes": nodes,
                    "groups": groups, "plots": copy.deepcopy(self._plots),
                    "sliders": copy.deepcopy(self._sliders), "notes": list(self._notes),
                    "legends": copy.deepcopy(self._legends), "previews": copy.deepcopy(self._previews)}
