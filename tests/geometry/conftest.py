"""Shared mesh builders for the geometry tests (small, analytic surfaces)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import trimesh


def height_field_mesh(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray], nx: int, ny: int, size: tuple[float, float] = (40.0, 60.0)
) -> trimesh.Trimesh:
    """Open triangulated height field z = f(x, y) over [0, size[0]] x [0, size[1]]."""
    x, y = np.linspace(0, size[0], nx), np.linspace(0, size[1], ny)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    verts = np.column_stack([xx.ravel(), yy.ravel(), f(xx, yy).ravel()])
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return trimesh.Trimesh(verts, faces, process=False)


def wavy(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 5.0 + np.sin(x / 5.0) + np.cos(y / 7.0)


@pytest.fixture(scope="session")
def wavy_mesh() -> trimesh.Trimesh:
    return height_field_mesh(wavy, 41, 61)
