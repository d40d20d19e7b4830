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
