"""Shared analytic surfaces for the five-axis tests."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.fitting import interpolate_surface
from app.geometry.nurbs_surface import NurbsSurface

SPHERE_R = 40.0


def sphere_cap(n: int = 25, half: float = 25.0, radius: float = SPHERE_R) -> NurbsSurface:
    """Interpolated cap of z = sqrt(R^2 - x^2 - y^2) over [-half, half]^2 (mm)."""
    x = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    zz = np.sqrt(radius**2 - xx**2 - yy**2)
    return interpolate_surface(np.stack([xx, yy, zz], axis=-1))


@pytest.fixture(scope="session")
def sphere() -> NurbsSurface:
    return sphere_cap()
