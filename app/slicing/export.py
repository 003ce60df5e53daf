"""Layer exports (pure: values in, bytes/str out): SLC, CLI (ASCII), JSON, SVG.

SLC (3D Systems Stereolithography Contour, little-endian): ASCII header ending in
``\\r\\n\\x1a`` (<= 2048 bytes), 256 reserved bytes, the sampling table (uint8 count <= 255,
then per entry float32 min-z, layer thickness, line-width compensation, reserved), then per
layer float32 z (the layer bottom) and uint32 boundary count, per boundary uint32 vertex
count (closed: first vertex repeated), uint32 gap count (0) and float32 x, y pairs; the
file ends with float32 max-z and uint32 0xFFFFFFFF.  Outer rings anticlockwise, holes
clockwise.  Layer tops are rounded to the ``quantum_mm`` grid (from the running sum of
the thicknesses, so the stack never drifts; :attr:`SlcExport.notes` says by how much z moved)
and, if more than 255 runs of equal thickness remain, neighbouring runs are merged in the
sampling table (each layer's own z in the contour section stays exact).

CLI (Common Layer Interface 2.0, ASCII, units mm): ``$$LAYER/z`` is the layer top;
``$$POLYLINE/id,dir,n,...`` with dir 1 = anticlockwise (outer), 0 = clockwise (hole);
optional ``$$HATCHES/id,n,x1,y1,x2,y2,...``.
"""

from __future__ import annotations

import dataclasses
import json
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from app.geometry.tolerance import LENGTH_EPS_MM
from app.slicing.errors import SlicingError
from app.slicing.layers import Layer, SliceParams, SliceResult
from app.slicing.ring_text import ring_texts
from app.slicing.rings import Island, oriented, per_array

SLC_END = 0xFFFFFFFF


class SlcExport(NamedTuple):
    """SLC bytes, the sampling table rows (min_z, thickness, compensation) and notes."""

    data: bytes
    table: tuple[tuple[float, float, float], ...]
    notes: tuple[str, ...]


@dataclass(frozen=True)
class SlcOptions:
    """``quantum_mm``: thickness grid; ``compensation_mm``: line-width compensation written
    in every sampling-table entry (0 when the contours are already compensated);
    ``label``: the header's -PACKAGE word."""

    quantum_mm: float = 0.001
    compensation_mm: float = 0.0
    label: str = "CONFORMA"


def _closed(ring: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``ring`` (n, 2) with its first vertex repeated at the end (n + 1, 2)."""
    return np.vstack([ring, ring[:1]])


def _quantised_boundaries(result: SliceResult, q: float) -> npt.NDArray[np.float64]:
    """Layer boundaries (L+1,): each layer's true top (the running sum of thicknesses)
    rounded to the ``q`` grid above the first bottom, so rounding never accumulates."""
    z0 = result.layers[0].z_bottom
    tops = np.array([lay.z_top for lay in result.layers])
    zq: npt.NDArray[np.float64] = z0 + np.concatenate([[0.0], np.round((tops - z0) / q) * q])
    thin = np.flatnonzero(np.diff(zq) <= 0)
    if len(thin):
        k = int(thin[0])
        raise SlicingError(f"layer {k} ({result.layers[k].thickness:.6g} mm) vanishes on the SLC "
                           f"thickness quantum {q} mm", field="slc.quantum_mm", value=q)
    return zq


def _sampling_table(zq: npt.NDArray[np.float64], comp: float,
                    notes: list[str]) -> tuple[tuple[float, float, float], ...]:
    """SLC sampling-table rows (min_z mm, thickness mm, compensation mm), at most 255."""
    t = np.round(np.diff(zq), 9)
    starts = [0] + [i for i in range(1, len(t)) if t[i] != t[i - 1]]
    runs: list[list[float]] = [[zq[s], t[s], (starts + [len(t)])[k + 1] - s] for k, s in enumerate(starts)]
    if len(runs) > 255:
        notes.append(f"{len(runs)} runs of equal thickness merged into 255 sampling-table "
                     f"entries (entry thickness = the run's most common one); each layer's "
                     f"exact z is in the contour section")
        while len(runs) > 255:
            k = min(range(len(runs) - 1), key=lambda i: runs[i][2] + runs[i + 1][2])
            a, b = runs[k], runs[k + 1]
            runs[k] = [a[0], a[1] if a[2] >= b[2] else b[1], a[2] + b[2]]
            del runs[k + 1]
    return tuple((float(r[0]), float(r[1]), comp) for r in runs)


def _slc_ring(ring: npt.NDArray[np.float64]) -> bytes:
    """One SLC boundary: its point count, a zero, then the closed ring's points as float32."""
    pts = _closed(ring).astype("<f4")
    return struct.pack("<II", len(pts), 0) + pts.tobytes()


def to_slc(result: SliceResult, options: SlcOptions = SlcOptions()) -> SlcExport:
    """Encode ``result`` (a SliceResult) as SLC bytes; see the module docstring."""
    if not result.layers:
        raise SlicingError("no layers to export", field="layers", value=0)
    if not options.quantum_mm > 0:
        raise SlicingError("quantum_mm must be > 0", field="slc.quantum_mm",
                           value=options.quantum_mm)
    notes: list[str] = []
    zq = _quantised_boundaries(result, options.quantum_mm)
    moved = float(np.max(np.abs(zq - np.array([result.layers[0].z_bottom]
                                              + [lay.z_top for lay in result.layers]))))
    if moved > 0:
        notes.append(f"layer thicknesses quantised to multiples of {options.quantum_mm} mm "
                     f"(layer z shifted by up to {moved:.3g} mm)")
    table = _sampling_table(zq, options.compensation_mm, notes)
    b = result.bounds
    header = (f"-SLCVER 2.0 -UNIT MM -TYPE PART -PACKAGE {options.label} -EXTENTS "
              f"{b[0, 0]:.6f},{b[1, 0]:.6f} {b[0, 1]:.6f},{b[1, 1]:.6f} "
              f"{b[0, 2]:.6f},{b[1, 2]:.6f}").encode("ascii") + b"\r\n\x1a"
    if len(header) > 2048:
        raise SlicingError("SLC header too long", field="slc.label", value=options.label)
    out = [header, bytes(256), struct.pack("<B", len(table))]
    for min_z, thick, comp in table:
        out.append(struct.pack("<4f", min_z, thick, comp, 0.0))
    packed = per_array(_slc_ring)  # a ring array shared by layers: packed once
    for lay, z in zip(result.layers, zq[:-1]):
        rings = [r for isl in lay.islands for r in
                 (oriented(isl.outer, True), *(oriented(h, False) for h in isl.holes))]
        out.append(struct.pack("<fI", z, len(rings)))
        out.extend(packed(r) for r in rings)
    out.append(struct.pack("<fI", zq[-1], SLC_END))
    return SlcExport(b"".join(out), table, tuple(notes))


def to_cli(result: SliceResult, hatches: dict[int, npt.NDArray[np.float64]] | None = None, label: str = "part",
           decimals: int = 6) -> str:
    """Encode ``result`` as ASCII CLI text; ``hatches[layer_index]``: (k, 4) x1,y1,x2,y2 mm."""
    if not result.layers:
        raise SlicingError("no layers to export", field="layers", value=0)
    b = result.bounds
    f = f"{{:.{decimals}f}}".format
    lines = ["$$HEADERSTART", "$$ASCII", "$$UNITS/1.000000", "$$VERSION/200",
             f"$$LABEL/1,{label}",
             "$$DIMENSION/" + ",".join(f(v) for v in (*b[0], *b[1])),
             f"$$LAYERS/{len(result.layers)}", "$$HEADEREND", "$$GEOMETRYSTART"]
    rings = (ring for lay in result.layers for isl in lay.islands
             for ring in (oriented(isl.outer, True), *(oriented(h, False) for h in isl.holes)))
    texts = ring_texts(rings, decimals)  # formatted a block of rings at a time, consumed in order
    for lay in result.layers:
        lines.append(f"$$LAYER/{f(lay.z_top)}")
        for isl in lay.islands:
            for direction, ring in ((1, isl.outer), *((0, h) for h in isl.holes)):
                text = next(texts)  # the polyline closed: its first point again at the end
                first = text[:text.index(",", text.index(",") + 1)] if len(ring) > 1 else text
                lines.append(f"$$POLYLINE/1,{direction},{len(ring) + 1},{text},{first}")
        if hatches and lay.index in hatches and len(hatches[lay.index]):
            h = np.asarray(hatches[lay.index], dtype=float).reshape(-1, 4)
            lines.append(f"$$HATCHES/1,{len(h)}," + ",".join(f(v) for v in h.ravel()))
    lines.append("$$GEOMETRYEND")
    return "\n".join(lines) + "\n"


def _island_json(isl: Island, texts: Iterator[str]) -> str:
    """An island as JSON, its rings' ``[x,y],...`` the next texts of ``texts`` (outer, then holes)."""
    outer = next(texts)
    holes = ",".join(f"[{next(texts)}]" for _ in isl.holes)
    return f'{{"outer":[{outer}],"holes":[{holes}]}}'


def layer_rows(result: SliceResult) -> list[dict[str, Any]]:
    """Each layer's statistics as :func:`to_json` writes them (without its contours)."""
    return [{"index": lay.index, "z_bottom": round(lay.z_bottom, 9),
             "z_top": round(lay.z_top, 9), "z_sample": round(lay.z_sample, 9),
             "thickness": round(lay.thickness, 9), "area_mm2": round(lay.area, 9),
             "rings": lay.ring_count, "inner_rings": lay.inner_ring_count,
             "sigma": round(lay.sigma, 9), "mu": round(lay.mu, 9), "eps": round(lay.eps, 9),
             "reason": lay.reason}
            for lay in result.layers]


def document_head(result: SliceResult) -> dict[str, Any]:
    """The fields of :func:`to_json`'s document but its layers (an empty list)."""
    return {"units": "mm", "mode": result.params.mode, "z_min": result.z_min,
            "z_max": result.z_max, "bounds": np.asarray(result.bounds, dtype=float).tolist(),
            "volume_mm3": float(result.volume), "params": dataclasses.asdict(result.params),
            "repairs": list(result.repairs), "notes": list(result.notes), "layers": []}


def to_json(result: SliceResult, decimals: int = 6) -> str:
    """Per-layer contours and statistics as JSON text (mm, mm^2)."""
    head = json.dumps(document_head(result), separators=(",", ":"))[:-len("[]}")]
    texts = ring_texts((ring for lay in result.layers for isl in lay.islands for ring in isl.rings()), decimals,
                       pairs=True)  # formatted a block of rings at a time, consumed in order
    rows = (json.dumps(row, separators=(",", ":"))[:-1] + ',"islands":['
            + ",".join(_island_json(i, texts) for i in lay.islands) + "]}"
            for row, lay in zip(layer_rows(result), result.layers))
    return head + "[" + ",".join(rows) + "]}"


def _ring(points: npt.ArrayLike, where: str) -> npt.NDArray[np.float64]:
    ring = np.asarray(points, dtype=np.float64)
    if ring.ndim != 2 or ring.shape[1] != 2 or len(ring) < 3 or not np.all(np.isfinite(ring)):
        raise SlicingError(f"{where}: a ring needs >= 3 finite [x, y] points", field=where,
                           value=list(ring.shape))
    return ring


def from_json(text: str | bytes) -> SliceResult:
    """Rebuild a :class:`SliceResult` from :func:`to_json` text.

    Contours come back at the JSON's precision (``decimals``); rings keep their order and
    orientation (outer CCW, holes CW).  Raises :class:`SlicingError` (field ``layers.json``
    or the offending ``layers[i]...`` entry) for anything that is not such a document.
    """
    try:
        doc = json.loads(text)
        return from_document(doc, [[(isl["outer"], isl["holes"]) for isl in row["islands"]] for row in doc["layers"]])
    except SlicingError:
        raise
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise SlicingError(f"not a layers.json document: {type(exc).__name__}: {exc}",
                           field="layers.json", value=str(exc)[:80]) from None


def from_document(doc: dict[str, Any], contours: Sequence[Sequence[tuple[Any, Sequence[Any]]]], *,
                  checked: bool = False) -> SliceResult:
    """A :class:`SliceResult` from :func:`to_json`'s document ``doc`` (its layers' islands
    ignored) and, per layer, per island, the outer ring and the holes ((n, 2) mm each);
    rings are oriented (outer CCW, holes CW), unless ``checked``: rings the caller has already
    checked (finite (n >= 3, 2) float64 arrays) and oriented are taken as they are.  KeyError,
    ValueError or TypeError for a malformed document, :class:`SlicingError` naming a bad ring."""
    params = SliceParams(**doc["params"]) if "params" in doc else SliceParams(mode=doc["mode"])
    if not doc["layers"]:
        raise SlicingError("layers.json has no layers", field="layers.json", value=0)
    layers: list[Layer] = []
    for k, (row, islands_in) in enumerate(zip(doc["layers"], contours, strict=True)):
        where = f"layers[{k}]"
        islands = tuple(
            Island(outer, tuple(holes)) if checked else
            Island(oriented(_ring(outer, f"{where}.outer"), ccw=True),
                   tuple(oriented(_ring(h, f"{where}.holes"), ccw=False) for h in holes))
            for outer, holes in islands_in)
        layers.append(Layer(index=int(row["index"]), z_bottom=float(row["z_bottom"]),
                            z_top=float(row["z_top"]), z_sample=float(row["z_sample"]),
                            islands=islands, area=float(row["area_mm2"]),
                            ring_count=int(row["rings"]),
                            inner_ring_count=int(row["inner_rings"]),
                            sigma=float(row["sigma"]), mu=float(row["mu"]),
                            eps=float(row["eps"]), reason=str(row["reason"])))
    z_min, z_max = float(doc["z_min"]), float(doc["z_max"])
    if "bounds" in doc:
        bounds = np.asarray(doc["bounds"], dtype=np.float64).reshape(2, 3)
    else:
        xy = np.vstack([r for lay in layers for isl in lay.islands for r in isl.rings()])
        bounds = np.array([[*xy.min(axis=0), z_min], [*xy.max(axis=0), z_max]])
    volume = float(doc.get("volume_mm3", float("nan")))
    repairs, notes = tuple(map(str, doc["repairs"])), tuple(map(str, doc["notes"]))
    return SliceResult(layers=tuple(layers), params=params, z_min=z_min, z_max=z_max,
                       bounds=bounds, volume=volume, repairs=repairs, notes=notes)


def layer_svg(result: SliceResult, index: int, paths: list[npt.NDArray[np.float64]] | None = None,
              size_px: int = 600) -> str:
    """SVG of layer ``index``: material filled (even-odd), optional (n, 2) polylines on top."""
    if not 0 <= index < len(result.layers):
        raise SlicingError(f"layer index {index} out of range 0..{len(result.layers) - 1}",
                           field="layer", value=index)
    lay = result.layers[index]
    (x0, y0), (x1, y1) = result.bounds[0, :2], result.bounds[1, :2]
    w, h = max(x1 - x0, LENGTH_EPS_MM), max(y1 - y0, LENGTH_EPS_MM)
    pad = 0.02 * max(w, h)

    def pts(a: npt.NDArray[np.float64]) -> str:
        return " ".join(f"{x:.4f},{y0 + y1 - y:.4f}" for x, y in a)   # flip y (SVG is y-down)

    d = " ".join(f"M {pts(r)} Z" for isl in lay.islands for r in isl.rings())
    lines = "".join(f'<polyline points="{pts(p)}" fill="none" stroke="#d33" '
                    f'stroke-width="{0.002 * max(w, h):.4f}"/>' for p in (paths or []))
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{size_px}" '
            f'height="{int(size_px * h / w)}" viewBox="{x0 - pad:.4f} {y0 - pad:.4f} '
            f'{w + 2 * pad:.4f} {h + 2 * pad:.4f}"><title>layer {index} z={lay.z_top:.4f} '
            f'mm</title><path d="{d}" fill="#8ab" fill-rule="evenodd" stroke="#234" '
            f'stroke-width="{0.001 * max(w, h):.4f}"/>{lines}</svg>')
