import numpy as np
import pytest
import trimesh

from meshsom.polygons import extrude_polygon, triangulate_polygon_2d, triangulate_polygon_3d


def _area2d(points, tri):
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def test_square_with_hole_triangulates_to_exact_area_without_new_points():
    shell = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float)
    hole = np.array([[1, 1], [1, 3], [3, 3], [3, 1]], float)
    pts, tri = triangulate_polygon_2d(shell, [hole])
    assert len(pts) == 8  # no Steiner points
    areas = _area2d(pts, tri)
    assert (areas > 0).all()
    assert areas.sum() == pytest.approx(16 - 4)
    assert len(tri) == 8  # n + 2h - 2 = 8 + 2 - 2


def test_3d_polygon_keeps_orientation_of_outer_ring():
    # A vertical L-shaped wall, counter-clockwise seen from -y (normal -y).
    ring = np.array([[0, 0, 0], [2, 0, 0], [2, 0, 1], [1, 0, 1], [1, 0, 2], [0, 0, 2]], float)
    tri = triangulate_polygon_3d([ring])
    assert len(tri) == 4
    n = np.cross(ring[tri[:, 1]] - ring[tri[:, 0]], ring[tri[:, 2]] - ring[tri[:, 0]])
    assert (n[:, 1] < 0).all()
    assert np.abs(n).sum(axis=1).sum() / 2 == pytest.approx(3.0)


def test_extruded_courtyard_is_closed_outward_with_exact_volume():
    shell = np.array([[0, 0], [10, 0], [10, 8], [0, 8]], float)
    hole = np.array([[2, 2], [8, 2], [8, 6], [2, 6]], float)  # CCW: the function orients it
    v, f = extrude_polygon(shell, [hole], 1.0, 4.0)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx((80 - 24) * 3.0)


def test_extrusion_rejects_inverted_heights():
    with pytest.raises(ValueError, match="z1 > z0"):
        extrude_polygon(np.eye(3)[:, :2], [], 2.0, 1.0)


def test_quads_split_at_once_as_one_by_one():
    """meshsom.io splits plain convex quads in one vectorised step: the same triangles, in the same
    order, as triangulating every polygon on its own (rectangles, whose diagonals tie, included)."""
    from meshsom.io import _drop_closing_vertex, _drop_spikes, _triangulate_polygons

    rng = np.random.default_rng(7)
    local = []
    polygons = []

    def add(points, ring=None):
        start = sum(len(p) for p in local)
        local.append(np.asarray(points, float))
        polygons.append([list(range(start, start + len(points))) if ring is None else [start + i for i in ring]])

    for _ in range(200):  # random convex quads, rotated rectangles (a tie), squares
        a, b = rng.uniform(0.5, 20, 2)
        rect = np.array([[0, 0, 0], [a, 0, 0], [a, 0, b], [0, 0, b]])
        rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        add(rect @ rot.T + rng.uniform(-1e5, 1e5, 3))
        add(np.array([[0, 0, 0], [a, 0, 0], [a, a, 0], [0, a, 0]]) + rng.uniform(-1e3, 1e3, 3))
        angles = np.sort(rng.uniform(0, 2 * np.pi, 4))
        add(np.column_stack([np.cos(angles), np.sin(angles), rng.uniform(0, 1e-9, 4)]) * rng.uniform(1, 50))
    add([[0, 0, 0], [4, 0, 0], [1, 1, 0], [0, 4, 0]])  # a dart: not convex
    add([[0, 0, 0], [4, 0, 0], [8, 0, 0], [4, 0, 0]])  # a spike along a line: degenerate
    add([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]], ring=[0, 1, 1, 2])  # a repeated vertex
    add([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]])  # collinear
    add([[0, 0, 0], [4, 0, 0], [4, 4, 0]])  # a triangle and a pentagon among them
    add([[0, 0, 0], [4, 0, 0], [5, 2, 0], [2, 5, 0], [0, 4, 0]])
    local = np.concatenate(local)
    inverse = np.concatenate([poly[0] for poly in polygons])  # ring positions -> vertices, as the reader builds it
    faces, face_poly, _ = _triangulate_polygons(polygons, inverse, local)
    want, want_poly = [], []
    for p, poly in enumerate(polygons):
        ring = _drop_spikes(_drop_closing_vertex(np.asarray(poly[0])), local)
        if len(ring) < 3:
            continue
        tri = triangulate_polygon_3d([local[ring]])
        want.append(ring[tri])
        want_poly.append(np.full(len(tri), p))
    simple = [k for k, poly in enumerate(polygons) if len(poly[0]) == 3]  # plain triangles come first
    order = np.argsort([0 if p in simple else 1 for p in np.concatenate(want_poly)], kind="stable")
    assert np.array_equal(faces, np.concatenate(want).reshape(-1, 3)[order])
    assert np.array_equal(face_poly, np.concatenate(want_poly)[order])


def test_rings_triangulated_at_once_as_one_by_one():
    """triangulate_rings_2d gives every valid ring the triangles triangulate_polygon_2d gives it alone
    (the same GEOS triangulation: same triangles, rectangles' tied diagonals included), and leaves out
    rings that are not valid polygons."""
    from meshsom.polygons import triangulate_rings_2d

    rng = np.random.default_rng(3)
    rings = []
    for _ in range(150):
        k = int(rng.integers(4, 12))
        angles = np.sort(rng.uniform(0, 2 * np.pi, k))
        radius = rng.uniform(0.5, 1.0, k) * rng.uniform(1, 100)
        rings.append(np.column_stack([np.cos(angles), np.sin(angles)]) * radius[:, None] + rng.uniform(-1e4, 1e4, 2))
        a, b = rng.uniform(0.1, 30, 2)
        rings.append(np.array([[0, 0], [a, 0], [a, b], [0, b]]) + rng.uniform(-100, 100, 2))
    rings.append(np.array([[0, 0], [4, 0], [0, 4], [4, 4]], float))  # a bow tie: not valid
    rings.append(np.array([[-0.0, 0], [4, 0], [4, 4], [0, 4]]))  # -0.0 matches 0.0
    rings.append(np.array([[0, 0], [1, 0], [2, 0], [3, 0]], float))  # collinear: not valid
    lengths = np.array([len(r) for r in rings])
    tri, ring, valid = triangulate_rings_2d(np.concatenate(rings), lengths)
    first = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    import shapely

    assert valid.tolist() == [shapely.Polygon(r).is_valid for r in rings]
    assert valid.sum() > 250 and valid.tolist()[-3:] == [False, True, False]
    for r, points in enumerate(rings):
        if not valid[r]:
            assert not (ring == r).any()
            continue
        _, want = triangulate_polygon_2d(points)
        got = tri[ring == r] - first[r]
        assert np.array_equal(got, want), r
        assert _area2d(points, got).sum() == pytest.approx(shapely.Polygon(points).area)


def test_plane_frames_are_right_handed_orthonormal_bases():
    from meshsom.polygons import plane_frame, plane_frames

    rng = np.random.default_rng(0)
    normals = np.concatenate([rng.normal(size=(50, 3)) * rng.uniform(1e-3, 1e3, (50, 1)), np.eye(3), -np.eye(3)])
    frames = plane_frames(normals)
    n = normals / np.linalg.norm(normals, axis=1)[:, None]
    assert np.allclose(np.einsum("rij,rkj->rik", frames, frames), np.eye(2))
    assert np.allclose(np.einsum("rj,rij->ri", n, frames), 0)
    assert np.allclose(np.cross(frames[:, 0], frames[:, 1]), n)
    assert np.allclose(plane_frame(normals[7]), frames[7])
