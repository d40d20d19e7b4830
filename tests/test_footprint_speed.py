"""The footprint reader's fast paths against their plain references (no timings here: bench/footprints.py).

- :func:`meshsom.polygons.triangulate_polygons_3d` (one GEOS call for many polygons) against
  :func:`meshsom.polygons.triangulate_polygon_3d` one by one (:func:`meshsom.io._triangulate_one_by_one`);
- :func:`meshsom.io._cross` and :func:`meshsom.polygons.newell_normal` against ``np.cross`` with ``np.roll``;
- whole footprints read both ways: the same vertices and faces.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import meshsom.io as io
from meshsom.io import ReaderOptions, read_file
from meshsom.polygons import newell_normal, triangulate_polygon_3d, triangulate_polygons_3d

from footprints import COURT_IN, COURT_OUT, L_SHAPE, closed

SPIKE = [(0, 0), (10, 0), (10, 4), (16, 4), (10, 4), (10, 8), (0, 8)]  # goes out and back along y = 4
COLLINEAR = [(0, 0), (5, 0), (10, 0), (10, 5), (10, 10), (5, 10), (0, 10), (0, 5)]
CONCAVE_QUAD = [(0, 0), (10, 0), (3, 3), (0, 10)]
STAR = [(10 * np.cos(a) * (1 if k % 2 else 0.4), 10 * np.sin(a) * (1 if k % 2 else 0.4))
        for k, a in enumerate(np.linspace(0, 2 * np.pi, 14, endpoint=False))]
BOWTIE = [(0, 0), (10, 10), (10, 0), (0, 10), (0, 5)]  # crosses itself: no valid polygon


def _geometries():
    square_hole = [(2, 2), (2, 4), (4, 4), (4, 2)]
    return [
        {"type": "Polygon", "coordinates": [closed(L_SHAPE)]},
        {"type": "Polygon", "coordinates": [closed(COURT_OUT), closed(COURT_IN)]},
        {"type": "MultiPolygon", "coordinates": [[closed(L_SHAPE)], [closed(COURT_OUT), closed(COURT_IN)]]},
        {"type": "Polygon", "coordinates": [closed(SPIKE)]},
        {"type": "Polygon", "coordinates": [closed(COLLINEAR), closed(square_hole)]},
        {"type": "Polygon", "coordinates": [closed(CONCAVE_QUAD)]},
        {"type": "Polygon", "coordinates": [closed([(float(x), float(y)) for x, y in STAR])]},
        {"type": "MultiPolygon", "coordinates": [[closed(COLLINEAR)], [closed([(x + 20, y) for x, y in SPIKE])]]},
    ]


def _read(path, monkeypatch, reference: bool) -> list:
    if reference:
        monkeypatch.setattr(io, "triangulate_polygons_3d", io._triangulate_one_by_one)
    try:
        return list(read_file(path, ReaderOptions(default_height=10, roofs=False)))
    finally:
        monkeypatch.undo()


def test_footprints_read_batched_as_one_by_one(tmp_path, monkeypatch):
    features = [{"type": "Feature", "id": f"b{k}", "geometry": g, "properties": {"height": 7.5}}
                for k, g in enumerate(_geometries())]
    path = tmp_path / "footprints.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    fast = _read(path, monkeypatch, reference=False)
    plain = _read(path, monkeypatch, reference=True)
    assert [m.id for m in fast] == [m.id for m in plain] and len(fast) == len(features)
    for a, b in zip(fast, plain):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces), a.id
        assert a.notes == b.notes


def _rings_3d(ring2d, z, tilt=0.0):
    p = np.asarray(ring2d, np.float64)
    return np.column_stack([p, z + tilt * p[:, 0]])


def test_triangulate_polygons_3d_is_triangulate_polygon_3d_one_by_one():
    rng = np.random.default_rng(7)
    polygons = [
        [_rings_3d(L_SHAPE, 3.0)], [_rings_3d(L_SHAPE[::-1], 0.0)],
        [_rings_3d(COURT_OUT, 1.0), _rings_3d(COURT_IN, 1.0)],
        [_rings_3d(COLLINEAR, 2.0, tilt=0.3)], [_rings_3d(SPIKE, 0.1)], [_rings_3d(CONCAVE_QUAD, 5.0)],
        [_rings_3d(STAR, 0.7, tilt=-0.2)], [_rings_3d(BOWTIE, 0.0)], [_rings_3d([(0, 0), (1, 0)], 0.0)],
        [_rings_3d([(0, 0), (1, 0), (2, 0), (3, 0), (4, 0)], 0.0)],  # on one line: no triangles
        [_rings_3d(closed(L_SHAPE), 1.0)],  # closed: its repeated corner dropped
    ]
    for _ in range(20):  # random simple (star-shaped) rings in random planes
        n = int(rng.integers(5, 12))
        angle = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = rng.uniform(1, 10, n)
        ring = np.column_stack([r * np.cos(angle), r * np.sin(angle), rng.normal() * r * np.cos(angle)])
        polygons.append([ring + rng.normal(size=3) * 100])
    fast = triangulate_polygons_3d(polygons)
    plain = io._triangulate_one_by_one(polygons)
    assert len(fast) == len(plain) == len(polygons)
    for k, (a, b) in enumerate(zip(fast, plain)):
        assert a.dtype == b.dtype and np.array_equal(a, b), k
    assert triangulate_polygons_3d([]) == []


def test_cross_and_newell_normal_are_numpys_bit_for_bit():
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(50, 4, 3)) * 1e3, rng.normal(size=(50, 4, 3)) * 1e-2
    assert np.array_equal(io._cross(a, b), np.cross(a, b))
    for n in (3, 4, 7, 40):
        ring = rng.normal(size=(n, 3)) * 50 + 1e5
        assert np.array_equal(newell_normal(ring), np.cross(ring, np.roll(ring, -1, axis=0)).sum(axis=0))


@pytest.mark.parametrize("seed", [0, 1])
def test_split_quads_splits_as_triangulate_polygon_3d(seed):
    rng = np.random.default_rng(seed)
    rect = np.array([[0, 0, 0], [4, 0, 0], [4, 0, 3], [0, 0, 3]], np.float64)  # a wall: diagonals tie
    local = np.concatenate([rect + rng.normal(size=3) * 10 for _ in range(10)]
                           + [rng.normal(size=(4, 3)) for _ in range(30)])
    quads = np.arange(len(local)).reshape(-1, 4)
    tri, done = io._split_quads(quads, local)
    assert done[:10].all()
    for q, t in zip(quads[done], tri):
        assert np.array_equal(t, q[triangulate_polygon_3d([local[q]])])
