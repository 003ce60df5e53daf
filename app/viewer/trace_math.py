"""Small geometry for the view: where measured points fall along a trace, contour rings
as line segments.  Lengths mm."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Projection(NamedTuple):
    """s_mm (n,): arc length along the polyline (3-D length) of each point's foot;
    nominal (n, 3): the foot point on the polyline (mm)."""

    s_mm: np.ndarray
    nominal: np.ndarray


def project_onto_polyline(points: np.ndarray, polyline: np.ndarray) -> Projection:
    """Feet of points (n, 3) on a polyline (k, 3), found in the top (xy) view.

    Probing measures along z, so the foot of a measured point is the nearest polyline
    point in xy; its z is the nominal height there and ``s`` its 3-D arc length.
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    line = np.asarray(polyline, float).reshape(-1, 3)
    if len(line) < 2:
        return Projection(np.zeros(len(pts)), np.repeat(line[:1], len(pts), axis=0))
    a, b = line[:-1], line[1:]
    d = b[:, :2] - a[:, :2]
    dd = np.einsum("ij,ij->i", d, d)
    rel = pts[:, None, :2] - a[None, :, :2]
    t = np.clip(np.einsum("nkj,kj->nk", rel, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    feet_xy = a[None, :, :2] + t[..., None] * d[None]
    dist = np.linalg.norm(pts[:, None, :2] - feet_xy, axis=-1)
    seg = np.argmin(dist, axis=1)
    tt = t[np.arange(len(pts)), seg]
    feet = a[seg] + tt[:, None] * (b[seg] - a[seg])
    seg_len = np.linalg.norm(b - a, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    return Projection(cum[seg] + tt * seg_len[seg], feet)


def rings_to_segments(rings: list, z: float) -> np.ndarray:
    """Closed rings (each (k, 2) mm) at height z -> (m, 2, 3) segments, closing each ring."""
    chunks = []
    for ring in rings:
        r = np.asarray(ring, float).reshape(-1, 2)
        if len(r) < 2:
            continue
        if not np.allclose(r[0], r[-1]):
            r = np.vstack([r, r[:1]])
        p = np.column_stack([r, np.full(len(r), z)])
        chunks.append(np.stack([p[:-1], p[1:]], axis=1))
    return np.concatenate(chunks) if chunks else np.zeros((0, 2, 3))
