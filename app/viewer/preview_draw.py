"""Draw a :class:`~app.viewer.layer_preview.ProgramPreview` like a slicer does: each move type
in its own colour, the layers up to the slider's layer k and nothing above it, the dispenser's
on/off points, and a machine's head on the path.

Nodes (under ``/focus/preview/<program>/``): one ``add_line_segments`` node per move type
holding the moves of layers 0..k (split above ``max_segments_per_node``), ``dispense_on`` and
``dispense_off`` point clouds of the same layers.  Moving the slider replaces these nodes,
so a layer above k is not drawn at all (not merely hidden).  The head is ``/focus/head``.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from app.viewer.layer_preview import ProgramPreview

RGB = tuple[int, int, int]
ROOT = "/focus/preview"
HEAD = "/focus/head"

# Move types (perimeter, infill, thin wall from the FDM writer; trace, pass, pad, area from a
# circuit program); unknown tags fall back to PRINT_COLOR.  Chosen apart from the slate part,
# from each other, and from the dispense on/off markers.
MOVE_COLORS: dict[str, RGB] = {
    "perimeter": (230, 120, 20),   # orange
    "infill": (30, 150, 60),       # green
    "thin_wall": (140, 60, 200),   # violet
    "trace": (20, 110, 230),       # blue
    "pass": (0, 165, 180),         # teal
    "pad": (200, 50, 160),         # magenta
    "area": (170, 130, 30),        # ochre
    "print": (230, 120, 20),
    "travel": (160, 160, 160),     # grey, thin
}
PRINT_COLOR: RGB = (230, 120, 20)
DISPENSE_ON: RGB = (0, 190, 255)   # sky blue
DISPENSE_OFF: RGB = (230, 0, 0)     # red
HEAD_COLOR: RGB = (255, 0, 255)
LABELS = {"thin_wall": "thin wall", "travel": "travel (not dispensing)", "print": "dispensing (untagged)"}


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "item"


def color_of(kind: str) -> RGB:
    return MOVE_COLORS.get(kind, PRINT_COLOR)


def hex_of(rgb: RGB) -> str:
    return "#%02x%02x%02x" % rgb


def layer_label(preview: ProgramPreview, k: int) -> str:
    lay = preview.layers[k]
    z = "no dispensing" if not np.isfinite(lay.z_mm) else f"z {lay.z_mm:.3f} mm"
    return f"layer {lay.index} ({k + 1} of {len(preview.layers)}): {z}"


def preview_info(preview: ProgramPreview, k: int) -> dict[str, Any]:
    """What the page shows beside the view: the layer k, every layer's z, height and time,
    the legend of move types (with their move counts) and markers."""
    def num(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    counts = preview.counts()
    shown = preview.layer <= k
    return {
        "name": preview.name, "layer": k, "layer_count": len(preview.layers), "time_s": preview.time_s,
        "layers": [{"index": lay.index, "z_mm": num(lay.z_mm), "height_mm": num(lay.height_mm), "time_s": lay.time_s,
                    "moves": lay.moves, "dispense_mm": lay.dispense_mm} for lay in preview.layers],
        "legend": [{"type": kind, "label": LABELS.get(kind, kind), "color": hex_of(color_of(kind)),
                    "moves": counts[kind], "shown": int(np.count_nonzero(shown & (preview.kind == i)))}
                   for i, kind in enumerate(preview.kinds)]
        + [{"type": "dispense_on", "label": "dispense on", "color": hex_of(DISPENSE_ON),
            "moves": len(preview.on_points), "shown": int(np.count_nonzero(preview.on_layer <= k))},
           {"type": "dispense_off", "label": "dispense off", "color": hex_of(DISPENSE_OFF),
            "moves": len(preview.off_points), "shown": int(np.count_nonzero(preview.off_layer <= k))}],
    }


def draw_layers(builder: Any, preview: ProgramPreview, k: int) -> int:
    """(Re)draw ``preview`` up to layer position ``k`` (clipped) into ``builder``'s scene;
    returns k.  ``builder`` is a :class:`app.viewer.scenes.SceneBuilder` (its lock held)."""
    k = int(np.clip(k, 0, len(preview.layers) - 1))
    base = f"{ROOT}/{_slug(preview.name)}"
    for name in [n for n in builder.node_names() if n.startswith(base + "/")]:
        builder.remove_node(name)
    shown = preview.layer <= k
    step = builder.params.max_segments_per_node
    for i, kind in enumerate(preview.kinds):
        chosen = preview.segments[shown & (preview.kind == i)].astype(np.float32)
        width = builder.params.toolpath_px * (0.6 if kind == "travel" else 1.6)
        for part, start in enumerate(range(0, len(chosen), step)):
            name = f"{base}/{_slug(kind)}" + ("" if len(chosen) <= step else f"_{part}")
            chunk = chosen[start:start + step]
            handle = builder.server.scene.add_line_segments(name, chunk, color_of(kind), thickness=width,
                                                            thickness_units="screen")
            builder.add_node(name, "toolpaths", handle, "segments", len(chunk), role="preview", move=kind, layer=k)
    size = builder.point_size * 1.5
    for label, points, layers, rgb in (("dispense_on", preview.on_points, preview.on_layer, DISPENSE_ON),
                                       ("dispense_off", preview.off_points, preview.off_layer, DISPENSE_OFF)):
        pts = np.asarray(points[layers <= k], np.float32)
        if len(pts):
            name = f"{base}/{label}"
            handle = builder.server.scene.add_point_cloud(name, pts, rgb, point_size=size, point_shape="circle",
                                                          precision="float32")
            builder.add_node(name, "toolpaths", handle, "points", len(pts), role="preview", move=label, layer=k)
    builder.registry.set_slider(preview.name, 0, len(preview.layers) - 1, k,
                                [layer_label(preview, j) for j in range(len(preview.layers))])
    builder.registry.set_preview(preview.name, preview_info(preview, k))
    return k


def draw_head(builder: Any, position_mm: np.ndarray, line: int | None) -> None:
    """The machine's head as a magenta ball at ``position_mm`` (3,) (the scene's frame)."""
    radius = max(builder.point_size * 4.0, 0.3)   # ~3 % of the framed extent: seen at a glance
    position = tuple(float(v) for v in position_mm)
    handle = builder.handle(HEAD)
    if handle is not None:    # moved in place: the node (and what the registry says) never goes missing
        handle.position = position
    else:
        handle = builder.server.scene.add_icosphere(HEAD, radius=radius, color=HEAD_COLOR, position=position)
    builder.add_node(HEAD, "head", handle, "mesh", 1, position_mm=[float(v) for v in position_mm], line=line,
                     radius_mm=radius)
