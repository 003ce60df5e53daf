"""The reading and mapping of a circuit import, done in a bounded child process.

``POST /parts/{id}/circuits:import`` hands the uploaded files here through
:func:`app.runtime.isolated.call_isolated`: every file is read (within the bounds of
:mod:`app.circuits.budget`), the import's traces, pads and areas are counted together against
:data:`~app.circuits.budget.MAX_SHAPES`, and each layout is mapped onto the part's mesh
(loaded in the child from the blob store and the part cache).  What comes back is small and
bounded: the files' facts and their :class:`~app.circuits.mapping.MappedLayout`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.circuits.budget import MAX_SHAPES
from app.circuits.errors import CircuitFileError
from app.circuits.formats import read_layout
from app.circuits.layout import Layout
from app.circuits.mapping import MappedLayout, MappingOptions, map_layout
from app.circuits.placement import LayoutPlacement, board_center


@dataclass(frozen=True)
class PartMesh:
    """What the child needs to load a part's mesh: its blob's sha256 and its format."""

    sha256: str
    format: str


@dataclass(frozen=True)
class ImportRequest:
    """One import's files ((name, path of the uploaded bytes)) and how to read and lay them."""

    files: list[tuple[str, str]]
    format: str | None
    layers: list[str] | None
    origin_mm: tuple[float, float]
    rotation_deg: float
    mirror: bool
    anchor: str  # "board_center" (the boards' own centre, over all files) or "file_origin" (0, 0)
    mapping: MappingOptions
    part: PartMesh
    graphics: bool = False   # a KiCad board's copper graphics and text printed (else reported)
    copper_layer: str | None = None   # the KiCad copper layer printed (top, bottom, inner<n>, a name)


@dataclass(frozen=True)
class FileFacts:
    """One file as read: its name, format, units, the layers read, the reader's notes and how many
    traces, pads, areas and vias it holds (``metadata["description"]``: what the API says of a field)."""

    file: str
    format: str
    units: str
    layers: list[str]
    notes: list[str]
    traces: int
    pads: int
    areas: int
    vias: int = field(default=0, metadata={"description": "vias read (interconnect points; not pads, not filled)"})
    stack: list[dict[str, object]] = field(default_factory=list, metadata={
        "description": "the file's copper layers, top to bottom: layer, side (top/inner/bottom), printed, tracks, "
                       "pads, zones, vias"})

    @classmethod
    def of(cls, layout: Layout) -> FileFacts:
        """The facts of a layout as read (:func:`~app.circuits.formats.read_layout`)."""
        return cls(layout.file, layout.format, layout.units, list(layout.layers), list(layout.notes),
                   len(layout.traces), len(layout.pads), len(layout.areas), len(layout.vias), list(layout.stack))


@dataclass(frozen=True)
class FileMapped:
    """One file read and mapped: its facts and its layout on the part."""

    facts: FileFacts
    mapped: MappedLayout
    connections: list[dict[str, object]]   # the named nets' connected pieces in the file (indices)


@dataclass(frozen=True)
class ImportMapped:
    """The import's placement (its anchor resolved over every file) and each file mapped."""

    placement: LayoutPlacement
    files: list[FileMapped]


def _mesh(settings: Any, part: PartMesh) -> Any:
    from app.parts.cache import MeshStore, part_cache_for
    from app.parts.meshes import MeshCache
    from app.platform.blobs import BlobStore

    cache = part_cache_for(settings)
    meshes = MeshCache(BlobStore(settings.blob_dir), store=MeshStore(cache) if cache else None)
    return meshes.mesh(part)  # type: ignore[arg-type]  # a Part's sha256 and format are all it reads


def read_and_map(request: ImportRequest, settings: Any) -> ImportMapped:
    """Every file read, counted and mapped (see the module); CircuitFileError (422) naming the
    file when the import's traces, pads and areas pass MAX_SHAPES."""
    layouts = []
    shapes = 0
    for name, path in request.files:
        layout = read_layout(Path(path).read_bytes(), name, request.format, request.layers, graphics=request.graphics,
                             copper_layer=request.copper_layer)
        shapes += len(layout.traces) + len(layout.pads) + len(layout.areas)
        if shapes > MAX_SHAPES:
            raise CircuitFileError(f"more than {MAX_SHAPES} traces, pads and areas in one import", file=name,
                                   where="traces, pads and areas", field="files")
        layouts.append(layout)
    anchor_xy = board_center(layouts) if request.anchor == "board_center" else (0.0, 0.0)
    placement = LayoutPlacement(request.origin_mm, request.rotation_deg, request.mirror,
                                (float(anchor_xy[0]), float(anchor_xy[1])))
    mesh = _mesh(settings, request.part) if layouts else None
    out = []
    for layout in layouts:
        assert mesh is not None  # read above when there is a layout
        mapped = map_layout(layout, placement, mesh, request.mapping)
        out.append(FileMapped(FileFacts.of(layout), mapped, [c.to_dict() for c in layout.connections]))
    return ImportMapped(placement, out)
