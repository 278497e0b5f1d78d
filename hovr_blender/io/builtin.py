"""Datasets shipped with the add-on (no file needed)."""
from __future__ import annotations

import numpy as np

from ..engine.expansions import fit_tensor_coefficients
from ..engine.mesh import VolumeMesh
from ..engine.shapes import HEX, VERTICES

# The paper's sphere (Nelson, Kirby, Haimes 2014, §6): one hexahedron, f = x^2 + y^2 + z^2.
SPHERE_LOWER = np.array([-1.0, -1.0, -2.0])
SPHERE_UPPER = np.array([1.0, 1.0, 4.0])


def box_vertices(lower, upper) -> np.ndarray:
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    return lower + (VERTICES[HEX] + 1.0) * 0.5 * (upper - lower)


def sphere_field(x, y, z):
    return x * x + y * y + z * z


def sphere(modes: int = 3) -> VolumeMesh:
    """The paper's sphere volume: field x^2+y^2+z^2 represented exactly (degree 2 per direction)."""
    vertices = box_vertices(SPHERE_LOWER, SPHERE_UPPER)
    half, mid = 0.5 * (SPHERE_UPPER - SPHERE_LOWER), 0.5 * (SPHERE_UPPER + SPHERE_LOWER)

    def at_reference(a, b, c):
        return sphere_field(mid[0] + half[0] * a, mid[1] + half[1] * b, mid[2] + half[2] * c)

    coeffs = fit_tensor_coefficients(at_reference, (modes,) * 3)
    return VolumeMesh.from_affine_hexes(vertices[None], (modes,) * 3, [coeffs], field_name="f", source="builtin:sphere")


BUILTIN = {"sphere": sphere}
