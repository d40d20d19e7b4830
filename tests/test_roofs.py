"""S3DB roof shapes (meshsom.roofs): closed, outward blocks whose volumes are computed here by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from meshsom.polygons import triangulate_polygon_3d
from meshsom.roofs import roof_faces, roof_height


def _mesh(faces):
    """The faces triangulated and welded: vertices (V, 3), triangles (T, 3)."""
    points, triangles, count = [], [], 0
    for face in faces:
        tri = triangulate_polygon_3d([face])
        assert len(tri) == len(face) - 2, face  # every face planar and whole
        points.append(face)
        triangles.append(tri + count)
        count += len(face)
    v = np.concatenate(points)
    welded, index = np.unique(np.round(v, 9), axis=0, return_inverse=True)
    return welded, index.reshape(-1)[np.concatenate(triangles)]


def _volume_closed(faces) -> float:
    v, t = _mesh(faces)
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    _, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert (counts == 2).all() and len(np.unique(directed, axis=0)) == len(directed)  # closed, one orientation
    p = v[t]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6)


RECT = np.array([[0.0, 0.0], [12.0, 0.0], [12.0, 8.0], [0.0, 8.0]])  # L 12 along x, W 8


@pytest.mark.parametrize("clockwise", [False, True])
def test_gabled_and_hipped_volumes(clockwise):
    """Eaves at 6 m, top at 9 m: gabled = block + triangular prism; hipped = block + a prism over
    L - W and a pyramid of W x W; the ridge runs along the longer sides (x), across on request."""
    ring = RECT[::-1] if clockwise else RECT
    block = 12 * 8 * 6
    gabled = roof_faces(ring, 0.0, 6.0, 9.0, "gabled", (1.0, 1.0))
    assert _volume_closed(gabled) == pytest.approx(block + 12 * 8 * 3 / 2)
    ridge = np.array([p for f in gabled for p in f if p[2] == 9.0])
    assert np.ptp(ridge[:, 0]) == pytest.approx(12) and np.ptp(ridge[:, 1]) == pytest.approx(0)  # along x
    across = roof_faces(ring, 0.0, 6.0, 9.0, "gabled", (1.0, 1.0), across=True)
    ridge = np.array([p for f in across for p in f if p[2] == 9.0])
    assert np.ptp(ridge[:, 1]) == pytest.approx(8) and np.ptp(ridge[:, 0]) == pytest.approx(0)
    hipped = roof_faces(ring, 0.0, 6.0, 9.0, "hipped", (1.0, 1.0))
    assert _volume_closed(hipped) == pytest.approx(block + 3 * 8 * (12 - 8) / 2 + 3 * 8 * 8 / 3)


def test_pyramidal_and_skillion_volumes():
    """A pyramid over a regular pentagon (block + area x rise / 3); a skillion over the rectangle
    facing south (roof:direction 180: lowest along y = 0), block + half the rise."""
    k = np.arange(5)
    pentagon = np.column_stack([5 * np.cos(2 * np.pi * k / 5), 5 * np.sin(2 * np.pi * k / 5)])
    area = 0.5 * 5 * 25 * math.sin(2 * math.pi / 5)
    assert _volume_closed(roof_faces(pentagon, 0.0, 4.0, 7.0, "pyramidal", (1.0, 1.0))) == pytest.approx(area * 4 + area * 3 / 3)
    skillion = roof_faces(RECT, 0.0, 6.0, 9.0, "skillion", (1.0, 1.0), direction_deg=180.0)
    assert _volume_closed(skillion) == pytest.approx(12 * 8 * 6 + 12 * 8 * 3 / 2)
    roof = next(f for f in skillion if len(f) == 4 and np.ptp(f[:, 2]) > 0 and np.ptp(f[:, 1]) > 0 and np.ptp(f[:, 0]) > 0)
    assert roof[roof[:, 1] == 0.0][:, 2] == pytest.approx([6.0, 6.0]) and roof[roof[:, 1] == 8.0][:, 2] == pytest.approx([9.0, 9.0])


def test_shapes_that_cannot_be_built_and_roof_heights():
    """Gabled on an L (six corners) or a non-convex quad, a pyramid over a footprint its apex does
    not see: None (the caller models them flat). Heights from roof:height, roof:levels, roof:angle,
    and the 30 degree default over half the width (8 m: 4 tan 30)."""
    el = np.array([[0, 0], [10, 0], [10, 4], [4, 4], [4, 10], [0, 10]], float)
    dart = np.array([[0, 0], [10, 5], [0, 10], [3, 5]], float)
    assert roof_faces(el, 0, 5, 8, "gabled", (1, 1)) is None and roof_faces(dart, 0, 5, 8, "hipped", (1, 1)) is None
    crescent = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [9, 5]], float)
    assert roof_faces(crescent, 0, 5, 8, "pyramidal", (1, 1)) is None
    assert roof_faces(RECT, 0, 5, 8, "onion", (1, 1)) is None

    def number(v):
        return None if v is None else float(v)

    assert roof_height("gabled", RECT, (1, 1), {"roof:height": "2.5"}, 3.0, number) == 2.5
    assert roof_height("gabled", RECT, (1, 1), {"roof:levels": "2"}, 3.0, number) == 6.0
    assert roof_height("gabled", RECT, (1, 1), {"roof:angle": "45"}, 3.0, number) == pytest.approx(4.0)
    assert roof_height("gabled", RECT, (1, 1), {}, 3.0, number) == pytest.approx(4 * math.tan(math.radians(30)))
    assert roof_height("skillion", RECT, (1, 1), {}, 3.0, number) == pytest.approx(8 * math.tan(math.radians(30)))
