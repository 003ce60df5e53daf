"""Real-world-shaped fixtures the project makes: files as CAD tools and scanners write them.

Each maker returns the file bytes (and the true geometry where a test needs it):
an inch 3MF, a metre GLB (glTF: metres, +Y up), a metre STL (no units in the format), an
open teapot-like pot with a spout, an inconsistently wound two-body STL, a bolt whose
height is not a multiple of common layers, and a CAD-like closed part of any size
(manifold3d booleans, refined: not a height field) for benchmarks.
"""

from __future__ import annotations

import io
import re
import zipfile

import manifold3d
import numpy as np
import trimesh

from app.parts.intake import export_mesh

M = manifold3d.Manifold


def to_trimesh(solid: manifold3d.Manifold) -> trimesh.Trimesh:
    mesh = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def inch_3mf(size_in: tuple[float, float, float] = (1.0, 2.0, 0.5)) -> bytes:
    """A box of ``size_in`` inches in a 3MF whose model declares ``unit="inch"``."""
    data = trimesh.creation.box(size_in).export(file_type="3mf")
    source = zipfile.ZipFile(io.BytesIO(data))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for name in source.namelist():
            payload = source.read(name)
            if name.lower().endswith(".model"):
                payload = re.sub(rb'unit="[a-z]+"', b'unit="inch"', payload, count=1)
                if b'unit="inch"' not in payload:
                    payload = payload.replace(b"<model ", b'<model unit="inch" ', 1)
            archive.writestr(name, payload)
    return out.getvalue()


def metre_glb(size_mm: tuple[float, float, float] = (40.0, 30.0, 10.0)) -> bytes:
    """A box of ``size_mm`` written as glTF specifies (metres, +Y up)."""
    return export_mesh(trimesh.creation.box(size_mm), "glb")


def metre_stl(size_mm: tuple[float, float, float] = (40.0, 30.0, 10.0)) -> bytes:
    """A box of ``size_mm`` exported in metres (as some CAD tools do): 0.04 x 0.03 x 0.01."""
    return trimesh.creation.box(np.asarray(size_mm) / 1000.0).export(file_type="stl")


def teapot_like() -> tuple[bytes, float, float]:
    """An open pot with a spout: (STL bytes, volume of the closed pot in mm^3, perimeter of
    the opening in mm).  The pot's lid is missing: one hole of 64 edges at the top."""
    pot = M.cylinder(40.0, 30.0, 25.0, 64)
    spout = M.cylinder(30.0, 4.0, 2.5, 32).rotate([0.0, 50.0, 0.0]).translate([22.0, 0.0, 8.0])
    handle = (M.cube([6.0, 6.0, 24.0]).translate([-36.0, -3.0, 8.0])
              + M.cube([12.0, 6.0, 4.0]).translate([-36.0, -3.0, 28.0]) + M.cube([12.0, 6.0, 4.0])
              .translate([-36.0, -3.0, 8.0]))
    closed = pot + spout + handle
    mesh = to_trimesh(closed)
    top = (mesh.face_normals[:, 2] > 0.999) & (mesh.triangles_center[:, 2] > 40.0 - 1e-6) \
        & (np.linalg.norm(mesh.triangles_center[:, :2], axis=1) < 25.0)
    opened = trimesh.Trimesh(mesh.vertices, mesh.faces[~top], process=False)
    perimeter = 64 * 2 * 25.0 * np.sin(np.pi / 64)
    return opened.export(file_type="stl"), float(closed.volume()), float(perimeter)


def two_body_badly_wound() -> tuple[bytes, float]:
    """Two separate boxes in one STL; the second has a third of its faces flipped
    (inconsistent winding).  (STL bytes, the true volume in mm^3)."""
    a = trimesh.creation.box((10.0, 10.0, 10.0))
    b = trimesh.creation.box((20.0, 10.0, 5.0))
    b.apply_translation((30.0, 0.0, -2.5))
    faces = b.faces.copy()
    faces[::3] = faces[::3, ::-1]
    b = trimesh.Trimesh(b.vertices, faces, process=False)
    both = trimesh.util.concatenate([a, b])
    return both.export(file_type="stl"), 1000.0 + 1000.0


def bolt(height_mm: float = 31.00026) -> bytes:
    """A hex-headed bolt-like solid whose height is not a multiple of 0.1, 0.2 or 0.25 mm."""
    head = M.cylinder(6.0, 8.0, 8.0, 6)
    shank = M.cylinder(height_mm - 6.0, 4.0, 4.0, 48).translate([0.0, 0.0, 6.0])
    return to_trimesh(head + shank).export(file_type="stl")


def cad_part(refine: int = 10) -> trimesh.Trimesh:
    """A CAD-like closed part (block with a boss, a dome, a pocket and four through holes),
    13,392 faces refined by ``refine`` (faces x refine^2: 10 -> 1,339,200 faces)."""
    body = M.cube([60.0, 40.0, 20.0])
    boss = M.cylinder(6.0, 12.0, 12.0, 576).translate([30.0, 20.0, 20.0])
    dome = M.sphere(14.0, 256).translate([15.0, 20.0, 12.0])
    pocket = M.cube([14.0, 20.0, 12.0]).translate([40.0, 10.0, 10.0])
    solid = (body + boss + dome) - pocket
    for x in (6.0, 54.0):
        for y in (6.0, 34.0):
            solid = solid - M.cylinder(30.0, 3.0, 3.0, 128).translate([x, y, -5.0])
    return to_trimesh(solid.refine(refine) if refine > 1 else solid)


def large_plate(size_mm: float = 300.0, height_mm: float = 12.0, refine: int = 2) -> trimesh.Trimesh:
    """A large CAD-like part (a countertop-sized plate, as trimesh's ``counter`` model): a
    ``size_mm`` square block with a raised rim, a round boss, a dome, two pockets and a grid of
    through holes; 21k faces, refined by ``refine`` (faces x refine^2: 2 -> ~84k)."""
    solid = M.cube([size_mm, size_mm, height_mm])
    rim_inner = M.cube([size_mm - 20.0, size_mm - 20.0, 10.0]).translate([10.0, 10.0, height_mm])
    solid = solid + (M.cube([size_mm, size_mm, 10.0]).translate([0.0, 0.0, height_mm]) - rim_inner)
    solid = solid + M.cylinder(20.0, 30.0, 30.0, 256).translate([size_mm * 0.3, size_mm * 0.7, height_mm])
    solid = solid + M.sphere(40.0, 192).scale([1.0, 1.0, 0.4]).translate([size_mm * 0.7, size_mm * 0.3, height_mm])
    solid = solid - M.cube([60.0, 40.0, 8.0]).translate([size_mm * 0.15, size_mm * 0.15, height_mm - 6.0])
    solid = solid - M.cube([40.0, 80.0, 8.0]).translate([size_mm * 0.6, size_mm * 0.6, height_mm - 6.0])
    for x in np.linspace(25.0, size_mm - 25.0, 5):
        for y in (25.0, size_mm - 25.0):
            solid = solid - M.cylinder(height_mm + 40.0, 4.0, 4.0, 96).translate([x, y, -5.0])
    return to_trimesh(solid.refine(refine) if refine > 1 else solid)


def thin_tube(wall_mm: float = 0.305, radius_mm: float = 10.0, height_mm: float = 30.0) -> trimesh.Trimesh:
    """A round tube whose wall (``wall_mm``) is thinner than two 0.4 mm beads: what a
    single-bead (vase-like) wall looks like in an STL; 128 sides."""
    outer = M.cylinder(height_mm, radius_mm, radius_mm, 128)
    inner = M.cylinder(height_mm + 2.0, radius_mm - wall_mm, radius_mm - wall_mm, 128).translate([0.0, 0.0, -1.0])
    return to_trimesh(outer - inner)
