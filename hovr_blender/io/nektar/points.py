"""Point sets of curved edges and faces: the 1-D Nektar++ points types on [-1, 1], the
evenly spaced triangle, and Lagrange interpolation through them (docs/spec/formats.md §2.3, §2.11)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.polynomial import legendre

from ...engine.expansions import gll_points
from .errors import NektarError

# PointsType enum order (docs/spec/formats.md §2.3): compressed meshes store the index
POINTS_ENUM = ("NoPointsType", "GaussGaussLegendre", "GaussRadauMLegendre", "GaussRadauPLegendre",
               "GaussLobattoLegendre", "GaussGaussChebyshev", "GaussRadauMChebyshev", "GaussRadauPChebyshev",
               "GaussLobattoChebyshev", "GaussRadauMAlpha0Beta1", "GaussRadauMAlpha0Beta2",
               "GaussRadauMAlpha1Beta0", "GaussRadauMAlpha2Beta0", "GaussKronrodLegendre",
               "GaussRadauKronrodMLegendre", "GaussRadauKronrodMAlpha1Beta0", "GaussLobattoKronrodLegendre",
               "PolyEvenlySpaced", "FourierEvenlySpaced", "FourierSingleModeSpaced", "BoundaryLayerPoints",
               "BoundaryLayerPointsRev", "NodalTriElec", "NodalTriFekete", "NodalTriEvenlySpaced",
               "NodalTetEvenlySpaced", "NodalTetElec", "NodalPrismEvenlySpaced", "NodalPrismElec", "NodalTriSPI",
               "NodalTetSPI", "NodalPrismSPI", "NodalQuadElec", "NodalHexElec", "GaussLegendreWithMP",
               "GaussLegendreWithM")


def points_1d(points_type: str, count: int, path, what) -> np.ndarray:
    """Positions on [-1, 1] of `count` points of a Nektar++ 1-D points type."""
    if count < 2 and points_type != "GaussGaussLegendre":
        raise NektarError(f"{path}: {what}: {count} {points_type} points; at least 2 are needed")
    positions = _points_1d(points_type, count)
    if positions is None:
        raise NektarError(f"{path}: {what}: points type {points_type!r} is not supported")
    return positions


@lru_cache(maxsize=None)
def _points_1d(points_type: str, count: int):
    """The positions, or None for a type this reader does not know."""
    if points_type == "GaussLobattoLegendre":
        return gll_points(count)
    if points_type == "PolyEvenlySpaced":
        return np.linspace(-1.0, 1.0, count)
    if points_type == "GaussGaussLegendre":
        return np.sort(legendre.leggauss(count)[0])
    if points_type == "GaussLobattoChebyshev":
        return -np.cos(np.pi * np.arange(count) / (count - 1))
    if points_type == "GaussGaussChebyshev":
        return -np.cos(np.pi * (2 * np.arange(count) + 1) / (2 * count))
    if points_type in ("GaussRadauMLegendre", "GaussRadauPLegendre"):
        # -1 and the roots of (P_{n-1} + P_n) / (1 + x); the P variant is its mirror image
        series = np.zeros(count + 1)
        series[count - 1] = series[count] = 1.0
        roots = np.sort(np.real(legendre.legroots(series)))
        roots[0] = -1.0
        return roots if points_type.endswith("MLegendre") else np.sort(-roots)
    return None


def tri_evenly_spaced(n: int) -> np.ndarray:
    """NodalTriEvenlySpaced points, n along an edge, in Nektar++'s order: vertices, edge 0, 1, 2,
    interior (docs/spec/formats.md §2.11)."""
    points = {}
    for row in range(n):  # rows in y
        for col in range(n - row):
            points[(row, col)] = (-1.0 + 2.0 * col / (n - 1), -1.0 + 2.0 * row / (n - 1))
    vertices = [(0, 0), (0, n - 1), (n - 1, 0)]
    edge0 = [(0, col) for col in range(1, n - 1)]
    edge1 = [(row, n - 1 - row) for row in range(1, n - 1)]
    edge2 = [(row, 0) for row in range(n - 2, 0, -1)]
    interior = [(row, col) for row in range(1, n) for col in range(1, n - row) if row + col != n - 1]
    return np.array([points[k] for k in vertices + edge0 + edge1 + edge2 + interior])


def lagrange_matrix(nodes, x):
    """(len(x), len(nodes)) values of the Lagrange interpolants through nodes at x."""
    nodes = np.asarray(nodes, float)
    x = np.asarray(x, float)
    n = len(nodes)
    out = np.ones((len(x), n))
    for k in range(n):
        for other in range(n):
            if other != k:
                out[:, k] *= (x - nodes[other]) / (nodes[k] - nodes[other])
    return out
