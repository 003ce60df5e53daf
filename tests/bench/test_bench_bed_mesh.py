"""Benchmark (make bench): the warp beside the bed-mesh methods of bCNC, Klipper and
OpenCNCPilot on the same probes, checked against the true surface.

Each method gets the same grid of probes (1 um noise) and the same program of printing moves;
its printed path (piecewise linear between the points it emits) is compared with the true
surface + the standoff, sampled 16 times per emitted piece.  The reference methods, as their
sources describe them:

* bCNC (autolevel): bilinear interpolation in the probed cell; every move split where it
  crosses a grid line;
* OpenCNCPilot: bilinear interpolation between the four nearest probes; every move longer than
  the grid spacing split into equal pieces shorter than it;
* Klipper (bed_mesh, ``algorithm: bicubic``, ``mesh_pps: 2``, ``bicubic_tension: 0.2``): the
  probed matrix upsampled by a cardinal spline, heights bilinear in the upsampled mesh, moves
  split every ``move_check_distance`` (5 mm).

Ours: :func:`app.circuits.height_model.height_model_from_points` then
:func:`app.circuits.warp.warp_program` (chord bound 2 um against its height model).
"""

from __future__ import annotations

import numpy as np
import pytest

from app.circuits.height_model import height_model_from_points
from app.circuits.warp import WarpOptions, warp_program
from tests.helpers.warped_surfaces import bow, dome

STANDOFF_MM = 0.1
SAMPLES = 16


CASES = {"dome": (dome, 60.0, 40.0, 13, 9), "pcb_bow": (bow, 100.0, 80.0, 7, 5)}


def _bilinear(gx, gy, z, x, y):
    i = np.clip(np.searchsorted(gx, x, side="right") - 1, 0, len(gx) - 2)
    j = np.clip(np.searchsorted(gy, y, side="right") - 1, 0, len(gy) - 2)
    tx = np.clip((x - gx[i]) / (gx[i + 1] - gx[i]), 0, 1)
    ty = np.clip((y - gy[j]) / (gy[j + 1] - gy[j]), 0, 1)
    return ((1 - tx) * (1 - ty) * z[i, j] + tx * (1 - ty) * z[i + 1, j]
            + (1 - tx) * ty * z[i, j + 1] + tx * ty * z[i + 1, j + 1])


def _cardinal_upsample(values, pps, tension):
    """Klipper's bicubic upsampling along the last axis: ``pps`` points inside each interval."""
    n = values.shape[-1]
    out = []
    for i in range(n - 1):
        p0, p1 = values[..., max(i - 1, 0)], values[..., i]
        p2, p3 = values[..., i + 1], values[..., min(i + 2, n - 1)]
        m1, m2 = tension * (p2 - p0), tension * (p3 - p1)
        for k in range(pps + 1):
            t = k / (pps + 1)
            t2, t3 = t * t, t * t * t
            out.append(p1 * (2 * t3 - 3 * t2 + 1) + p2 * (-2 * t3 + 3 * t2) + m1 * (t3 - 2 * t2 + t) + m2 * (t3 - t2))
    out.append(values[..., -1])
    return np.stack(out, axis=-1)


def _klipper_mesh(gx, gy, z, pps=2, tension=0.2):
    up = _cardinal_upsample(_cardinal_upsample(z, pps, tension).T, pps, tension).T
    return np.linspace(gx[0], gx[-1], up.shape[0]), np.linspace(gy[0], gy[-1], up.shape[1]), up


def _moves(width, height, count, seed):
    rng = np.random.default_rng(seed)
    p0 = rng.uniform([1, 1], [width - 1, height - 1], (count, 2))
    p1 = np.clip(p0 + rng.uniform(-25, 25, (count, 2)), [1, 1], [width - 1, height - 1])
    return p0, p1


def _path_error(points, surface):
    """Worst |z - (truth + standoff)| mm along the polyline through points (k, 3)."""
    a, b = points[:-1], points[1:]
    t = np.linspace(0, 1, SAMPLES + 1)[:, None, None]
    p = a[None] + t * (b - a)[None]
    return float(np.abs(p[..., 2] - surface(p[..., 0], p[..., 1]) - STANDOFF_MM).max())


def _split_at_grid_lines(p0, p1, gx, gy):
    ts = [0.0, 1.0]
    for g, a, b in ((gx, p0[0], p1[0]), (gy, p0[1], p1[1])):
        if b != a:
            ts += [float((v - a) / (b - a)) for v in g if 0 < (v - a) / (b - a) < 1]
    return np.unique(ts)


def _method_error(kind, p0s, p1s, gx, gy, z, surface):
    worst = 0.0
    if kind == "klipper":
        kx, ky, kz = _klipper_mesh(gx, gy, z)
    for p0, p1 in zip(p0s, p1s):
        length = float(np.hypot(*(p1 - p0)))
        if kind == "bcnc":
            t = _split_at_grid_lines(p0, p1, gx, gy)
        elif kind == "opencncpilot":
            step = min(gx[1] - gx[0], gy[1] - gy[0])
            t = np.linspace(0, 1, max(1, int(np.ceil(length / step))) + 1)
        else:
            t = np.linspace(0, 1, max(1, int(np.ceil(length / 5.0))) + 1)
        xy = p0 + t[:, None] * (p1 - p0)
        h = _bilinear(kx, ky, kz, xy[:, 0], xy[:, 1]) if kind == "klipper" else _bilinear(gx, gy, z, xy[:, 0], xy[:, 1])
        worst = max(worst, _path_error(np.column_stack([xy, h + STANDOFF_MM]), surface))
    return worst


def _ours_error(p0s, p1s, pts, surface):
    """Worst error (mm) of our warped program's printing pieces, the height model and the result."""
    field, model = height_model_from_points(pts, 1.0)
    text = "G21\nG90\nM83\n" + "".join(f"G0 X{a[0]:.4f} Y{a[1]:.4f}\nG1 X{b[0]:.4f} Y{b[1]:.4f} E0.5 F600\n"
                                          for a, b in zip(p0s, p1s))
    out = warp_program(text, field, WarpOptions(standoff_mm=STANDOFF_MM, chord_error_mm=0.002))
    here = np.full(3, np.nan)
    pieces = []
    for line in out.text.splitlines():
        if not line.startswith(("G0", "G1")):
            continue
        words = {w[0]: float(w[1:]) for w in line.split()[1:]}
        nxt = np.array([words.get("X", here[0]), words.get("Y", here[1]), words.get("Z", here[2])])
        if "E" in words:                                   # a printing piece: from where the tool is
            pieces.append([here, nxt])
        here = nxt
    seg = np.array(pieces)                                 # (k, 2, 3)
    t = np.linspace(0, 1, SAMPLES + 1)[:, None, None]
    p = seg[None, :, 0] + t * (seg[:, 1] - seg[:, 0])[None]
    return float(np.abs(p[..., 2] - surface(p[..., 0], p[..., 1]) - STANDOFF_MM).max()), model, out


@pytest.mark.parametrize("case", sorted(CASES))
def test_warp_beside_bcnc_klipper_and_opencncpilot(case):
    surface, width, height, nx, ny = CASES[case]
    rng = np.random.default_rng(0)
    gx, gy = np.linspace(0, width, nx), np.linspace(0, height, ny)
    X, Y = np.meshgrid(gx, gy, indexing="ij")
    z = surface(X, Y) + rng.normal(0, 0.001, X.shape)
    pts = np.column_stack([X.ravel(), Y.ravel(), z.ravel()])
    p0s, p1s = _moves(width, height, 200, 1)
    ours, model, out = _ours_error(p0s, p1s, pts, surface)
    others = {kind: _method_error(kind, p0s, p1s, gx, gy, z, surface) for kind in ("bcnc", "klipper", "opencncpilot")}
    print(f"\n{case}: {nx} x {ny} grid probes, 200 printing moves; ours ({model.kind}, {out.pieces} pieces, "
          f"model cv max {model.cv_max_mm * 1000:.1f} um) worst {ours * 1000:.1f} um; "
          + ", ".join(f"{k} {v * 1000:.1f} um" for k, v in others.items())
          + f"; ours / bCNC {ours / others['bcnc']:.2f}, / Klipper {ours / others['klipper']:.2f}, "
            f"/ OpenCNCPilot {ours / others['opencncpilot']:.2f}")
    assert ours <= min(others.values()), (ours, others)
