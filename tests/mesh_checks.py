"""Checks of read meshes worked out independently of the readers (tests of meshsom.usd, meshsom.threemf and
meshsom.x3d): volumes and areas by the divergence theorem and cross products, world coordinates compared as sets,
and the L-shaped footprint whose fan from its first corner folds over itself."""

from __future__ import annotations

import numpy as np

#: An L-shaped footprint (metres), its ring started at a corner that does not see the whole L (a fan from it folds
#: over itself), its area and perimeter; the height of the prisms built on it.
L_SHAPE = [(12.0, 4.0), (4.0, 4.0), (4.0, 10.0), (0.0, 10.0), (0.0, 0.0), (12.0, 0.0)]
L_AREA = 12 * 4 + 4 * 6
L_PERIMETER = 12 + 4 + 8 + 6 + 4 + 10
HEIGHT = 7.0


def l_prism_polygons() -> tuple[np.ndarray, list[list[int]]]:
    """The L-prism in metres, z up: points (12, 3) and polygons turned outwards (counter-clockwise seen from
    outside): the floor and roof one concave polygon each, the walls quads."""
    n = len(L_SHAPE)
    points = np.array([(x, y, 0.0) for x, y in L_SHAPE] + [(x, y, HEIGHT) for x, y in L_SHAPE])
    ccw = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(L_SHAPE, L_SHAPE[1:] + L_SHAPE[:1])) > 0
    ring = list(range(n)) if ccw else list(range(n))[::-1]
    polygons = [ring[::-1], [i + n for i in ring]]
    polygons += [[a, b, b + n, a + n] for a, b in zip(ring, ring[1:] + ring[:1])]
    return points, polygons


def signed_volume(mesh) -> float:
    """The volume a RawMesh's closed faces enclose (positive when they face outwards), from its vertices about its
    origin (the same for a closed mesh anywhere, and exact where world coordinates are millions of metres)."""
    corners = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6)


def unsigned_area(mesh) -> float:
    """The sum of a RawMesh's triangle areas (more than the surface's where triangles fold over each other)."""
    corners = mesh.vertices[mesh.faces]
    return float(np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                                axis=1).sum() / 2)


def rotation_z(degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def same_points(got, expected: np.ndarray, decimals: int = 6, atol: float = 1e-6) -> None:
    """A RawMesh's world vertices are the expected points, as sets (rounded to ``decimals``)."""
    world = np.unique(np.round(got.vertices + got.origin, decimals), axis=0)
    want = np.unique(np.round(expected, decimals), axis=0)
    assert world.shape == want.shape, (world.shape, want.shape)
    np.testing.assert_allclose(world, want, atol=atol)
