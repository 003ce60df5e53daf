"""Outline-stroke drawings: copper drawn as closed hairline loops (as ECAD plotters export a
copper layer to DXF: every track a stadium of two lines and two arcs, every pad and pour its
outline) read as copper areas, not as thousands of zero-width traces.

A *loop* is a zero-width curve that closes on itself (a closed polyline, a circle) or a chain
of zero-width curves (lines, arcs, open polylines, splines) meeting end to end, each meeting
point joining exactly two of them (ends closer than :data:`~app.circuits.layout.RESOLUTION_MM`
meet).  A layer is read as an outline drawing when at least :data:`OUTLINE_SHARE` of its
zero-width curves close into loops; on any other layer a closed curve is a drawn trace (a
ring).  Loops nest: a loop inside an even number of others is an area's outline, inside an
odd number a hole of the smallest one around it; areas that overlap or touch are one area
(an outline plot draws each track's outline over its pads).  Curves with a width (a drawn trace, a
polyline of constant width) and chains that do not close or branch stay traces.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import numpy.typing as npt
import shapely
from scipy.spatial import cKDTree
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from app.circuits.layout import RESOLUTION_MM, Area, LayoutTrace, Source
from app.circuits.opens import curve_points

__all__ = ["loops_as_areas"]

#: sampling of a loop's arcs and splines (mm, sagitta)
_CHORD_MM = 0.001
#: the share of a layer's zero-width curves that must close into loops for the layer to be
#: read as an outline drawing (an outline plot's copper text is open strokes)
OUTLINE_SHARE = 0.9


def _ends(traces: list[LayoutTrace]) -> tuple[npt.NDArray[np.float64], list[npt.NDArray[np.float64]]]:
    """Each curve's centre line (k, 2) mm and its two ends (n, 2, 2)."""
    lines = [curve_points(t.curve, _CHORD_MM) for t in traces]
    ends = np.array([[p[0], p[-1]] for p in lines]).reshape(len(lines), 2, 2)
    return ends, lines


def _nodes(ends: npt.NDArray[np.float64]) -> npt.NDArray[np.int_]:
    """The meeting point (n, 2) of each curve end: ends within RESOLUTION_MM share one."""
    flat = ends.reshape(-1, 2)
    pairs = cKDTree(flat).query_pairs(RESOLUTION_MM, output_type="ndarray")
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])) if len(pairs) else ([], ([], [])),
                       shape=(len(flat), len(flat)))
    labels: npt.NDArray[np.int_] = connected_components(graph, directed=False)[1]
    return labels.reshape(-1, 2)


def _rings(traces: list[LayoutTrace]) -> tuple[list[npt.NDArray[np.float64]], list[list[int]]]:
    """The closed rings (k, 2) the zero-width curves form, each with the curves it uses."""
    ends, lines = _ends(traces)
    node = _nodes(ends)
    rings: list[npt.NDArray[np.float64]] = []
    used: list[list[int]] = []
    at: dict[int, list[int]] = defaultdict(list)
    for k, (a, b) in enumerate(node.tolist()):
        if a == b:                           # closes on itself
            if len(lines[k]) >= 4:
                rings.append(lines[k])
                used.append([k])
            continue
        at[a].append(k)
        at[b].append(k)
    seen: set[int] = set()
    for start in range(len(traces)):
        a, b = node[start]
        if start in seen or a == b or len(at[a]) != 2 or len(at[b]) != 2:
            continue
        chain, pts, here, k, ok = [start], [lines[start]], int(b), start, True
        while here != a:
            nxt = [j for j in at[here] if j != k]
            if len(at[here]) != 2 or not nxt or nxt[0] in chain:
                ok = False
                break
            k = nxt[0]
            forward = node[k][0] == here
            pts.append(lines[k] if forward else lines[k][::-1])
            chain.append(k)
            here = int(node[k][1] if forward else node[k][0])
        seen.update(chain)
        ring = np.vstack([p[:-1] for p in pts])
        if ok and len(ring) >= 3:
            rings.append(ring)
            used.append(chain)
    return rings, used


def _outline_layers(traces: list[LayoutTrace], hair: list[int], used: list[list[int]]) -> set[str]:
    """The layers drawn in outlines: at least :data:`OUTLINE_SHARE` of their zero-width curves
    are in closed loops (a layer of drawn traces holds open curves, the odd ring among them)."""
    looped = {hair[j] for u in used for j in u}
    total: dict[str, int] = defaultdict(int)
    closed: dict[str, int] = defaultdict(int)
    for k in hair:
        total[traces[k].source.layer] += 1
        closed[traces[k].source.layer] += k in looped
    return {layer for layer, n in total.items() if closed[layer] >= OUTLINE_SHARE * n}


def loops_as_areas(traces: list[LayoutTrace]) -> tuple[list[LayoutTrace], list[Area], int]:
    """The traces that are no loops, the loops of outline-drawn layers as areas (with their
    holes, by nesting) and the number of loops read (see the module)."""
    hair = [k for k, t in enumerate(traces) if t.width_mm == 0]
    rings, used = _rings([traces[k] for k in hair])
    layers = _outline_layers(traces, hair, used)
    kept = [i for i, u in enumerate(used) if traces[hair[u[0]]].source.layer in layers]
    rings, used = [rings[i] for i in kept], [used[i] for i in kept]
    polys = [Polygon(r).buffer(0) for r in rings]
    keep = [i for i, p in enumerate(polys) if isinstance(p, Polygon) and p.area > 0]
    if not keep:
        return traces, [], 0
    polys = [polys[i] for i in keep]
    used = [used[i] for i in keep]
    # depth: how many loops contain each one; the parent: the smallest container
    tree = shapely.STRtree(polys)
    containers, items = tree.query(polys, predicate="contains_properly")   # containers[m] contains items[m]
    depth = np.zeros(len(polys), int)
    parent = np.full(len(polys), -1)
    for container, item in zip(containers.tolist(), items.tolist()):
        if container == item:
            continue
        depth[item] += 1
        if parent[item] < 0 or polys[container].area < polys[parent[item]].area:
            parent[item] = container
    areas: list[Area] = []
    index: dict[int, int] = {}
    for i in np.argsort(depth, kind="stable").tolist():
        if depth[i] % 2 == 0:
            src = traces[hair[used[i][0]]].source
            entity = src.entity if len(used[i]) == 1 else f"{src.entity} (+{len(used[i]) - 1} more, a closed loop)"
            index[i] = len(areas)
            ring = np.asarray(orient(polys[i], 1.0).exterior.coords)[:-1]
            areas.append(Area(ring, (), Source(src.file, src.layer, src.net, 0.0, entity)))
    for i in range(len(polys)):
        if depth[i] % 2 == 1 and parent[i] in index:
            k = index[int(parent[i])]
            hole = np.asarray(orient(polys[i], -1.0).exterior.coords)[:-1]
            areas[k] = Area(areas[k].exterior, (*areas[k].holes, hole), areas[k].source)
    gone = {hair[j] for u in used for j in u}
    return [t for k, t in enumerate(traces) if k not in gone], _merged(areas), len(polys)


def _merged(areas: list[Area]) -> list[Area]:
    """Overlapping or touching areas of one layer as one area each (an outline plot draws a
    track's stadium over its pads: one piece of copper, filled once), holes kept; each named
    by its first loop and how many it joins."""
    out: list[Area] = []
    for layer in dict.fromkeys(a.source.layer for a in areas):
        mine = [a for a in areas if a.source.layer == layer]
        shapes = [Polygon(a.exterior, list(a.holes)).buffer(0) for a in mine]
        tree = shapely.STRtree(shapes)
        for part in shapely.get_parts(shapely.union_all(shapes)):
            if not isinstance(part, Polygon) or part.area <= 0:
                continue
            joined = sorted(int(k) for k in tree.query(part, predicate="intersects"))
            src = mine[joined[0]].source if joined else mine[0].source
            entity = src.entity if len(joined) <= 1 else f"{src.entity} (+{len(joined) - 1} overlapping loops)"
            part = orient(part, 1.0)
            out.append(Area(np.asarray(part.exterior.coords)[:-1], tuple(np.asarray(h.coords)[:-1]
                                                                          for h in part.interiors),
                            Source(src.file, src.layer, src.net, 0.0, entity)))
    return out
