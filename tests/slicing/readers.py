"""Independent readers of SLC and CLI written from the format descriptions (for tests).

Deliberately shares no code with app.slicing.export.
"""

from __future__ import annotations

import struct

import numpy as np


def read_slc(data: bytes) -> dict:
    """Parse SLC bytes -> {header, table, layers: [(z, [ring (n, 2)])], end_z}."""
    end = data.index(b"\x0d\x0a\x1a")
    header = data[:end].decode("ascii")
    assert end + 3 <= 2048
    pos = end + 3 + 256
    (n_entries,) = struct.unpack_from("<B", data, pos)
    pos += 1
    table = []
    for _ in range(n_entries):
        table.append(struct.unpack_from("<ffff", data, pos))
        pos += 16
    layers = []
    while True:
        z, n_bound = struct.unpack_from("<fI", data, pos)
        pos += 8
        if n_bound == 0xFFFFFFFF:
            break
        rings = []
        for _ in range(n_bound):
            n_vert, n_gaps = struct.unpack_from("<II", data, pos)
            pos += 8
            pts = np.frombuffer(data, dtype="<f4", count=2 * n_vert, offset=pos)
            pos += 8 * n_vert
            rings.append(pts.reshape(-1, 2).astype(float))
        layers.append((z, rings))
    assert pos == len(data)
    return {"header": header, "table": table, "layers": layers, "end_z": z}


def read_cli(text: str) -> dict:
    """Parse ASCII CLI -> {units, n_layers, layers: [(z, [(dir, ring)], hatches)]}."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    assert lines[0] == "$$HEADERSTART"
    i = 1
    head = {}
    while lines[i] != "$$HEADEREND":
        key, _, val = lines[i][2:].partition("/")
        head[key] = val
        i += 1
    units = float(head["UNITS"])
    layers = []
    for ln in lines[i + 1:]:
        if ln.startswith("$$LAYER/"):
            layers.append((float(ln[8:]) * units, [], []))
        elif ln.startswith("$$POLYLINE/"):
            v = ln[11:].split(",")
            n = int(v[2])
            pts = np.array([float(x) for x in v[3:]]).reshape(n, 2) * units
            layers[-1][1].append((int(v[1]), pts))
        elif ln.startswith("$$HATCHES/"):
            v = ln[10:].split(",")
            layers[-1][2].append(np.array([float(x) for x in v[2:]]).reshape(int(v[1]), 4))
    return {"units": units, "n_layers": int(head["LAYERS"]), "layers": layers}
