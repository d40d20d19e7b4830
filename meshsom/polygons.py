"""Planar polygons: triangulation (with holes) and extrusion into closed blocks.

Polygons are given as rings of coordinates. A ring is not closed (its first
vertex is not repeated at the end). Triangulation uses shapely's constrained
Delaunay triangulation (GEOS), never the ``triangle`` package (whose licence
forbids commercial use).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import shapely


def _ring_array(ring) -> np.ndarray:
    arr = np.asarray(ring, dtype=np.float64)
    if len(arr) >= 2 and np.array_equal(arr[0], arr[-1]):
        arr = arr[:-1]
    return arr


def triangulate_polygon_2d(
    shell: np.ndarray, holes: Sequence[np.ndarray] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """Constrained Delaunay triangulation of a 2D polygon with holes.

    Only the polygon's own vertices are used (no Steiner points), so the
    result joins watertight with anything sharing the boundary.

    Parameters
    ----------
    shell : (S, 2) float64
        Outer ring, either orientation, not closed.
    holes : sequence of (H_i, 2) float64
        Inner rings.

    Returns
    -------
    points : (P, 2) float64
        ``shell`` followed by every hole's vertices, in input order.
    triangles : (T, 3) int64
        Indices into ``points``, counter-clockwise.
    """
    shell = _ring_array(shell)
    holes = [h for h in (_ring_array(h) for h in holes) if len(h) >= 3]
    points = np.concatenate([shell, *holes]) if holes else shell
    if len(shell) < 3:
        return points, np.zeros((0, 3), np.int64)
    if not holes and len(shell) == 3:
        tri = np.array([[0, 1, 2]], np.int64)
        return points, _ccw(points, tri)
    poly = shapely.Polygon(shell, holes)
    if not poly.is_valid:
        poly = shapely.make_valid(poly)
    tris = shapely.constrained_delaunay_triangles(poly)
    parts = shapely.get_parts(tris)
    if len(parts) == 0:
        return points, np.zeros((0, 3), np.int64)
    coords = shapely.get_coordinates(parts).reshape(len(parts), 4, 2)[:, :3]
    lookup = {tuple(p): i for i, p in enumerate(points.tolist())}
    flat = coords.reshape(-1, 2).tolist()
    idx = np.fromiter((lookup.get(tuple(p), -1) for p in flat), np.int64, len(flat))
    if (idx < 0).any():
        # make_valid may have introduced intersection points: append them.
        extra = {}
        for k in np.flatnonzero(idx < 0):
            key = tuple(flat[k])
            if key not in extra:
                extra[key] = len(points) + len(extra)
            idx[k] = extra[key]
        points = np.concatenate([points, np.array(list(extra), np.float64)])
    tri = idx.reshape(-1, 3)
    return points, _ccw(points, tri)


def triangulate_rings_2d(points: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constrained Delaunay triangulations of many simple polygons (no holes) in one call.

    What :func:`triangulate_polygon_2d` gives each valid polygon, for whole arrays: one GEOS
    call for all of them, and the corners mapped back to the input points at once.

    Parameters
    ----------
    points : (P, 2) float64
        The rings one after another, each not closed.
    lengths : (R,) int64
        Points of each ring, at least 3.

    Returns
    -------
    triangles : (T, 3) int64
        Indices into ``points``, counter-clockwise; zero-area triangles left out (as
        :func:`triangulate_polygon_2d` does).
    ring : (T,) int64
        The ring of each triangle.
    valid : (R,) bool
        False for a ring that is not a valid polygon (it crosses or touches itself): it has no
        triangles here; :func:`triangulate_polygon_2d` makes it valid first.
    """
    points = np.asarray(points, np.float64)
    lengths = np.asarray(lengths, np.int64)
    n_rings = len(lengths)
    empty = np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(n_rings, bool)
    if n_rings == 0:
        return empty
    ring_of_point = np.repeat(np.arange(n_rings), lengths)
    polys = shapely.polygons(shapely.linearrings(points, indices=ring_of_point))
    valid = shapely.is_valid(polys)
    if not valid.any():
        return empty[0], empty[1], valid
    chosen = np.flatnonzero(valid)
    parts, which = shapely.get_parts(shapely.constrained_delaunay_triangles(polys[chosen]), return_index=True)
    corners = shapely.get_coordinates(parts).reshape(len(parts), 4, 2)[:, :3].reshape(-1, 2)
    ring_of_corner = np.repeat(chosen[which], 3)
    # Corner -> point: both as (ring, x, y) rows, matched exactly (GEOS copies the input coordinates).
    rows = np.concatenate([
        np.column_stack([ring_of_point.astype(np.float64), points]),
        np.column_stack([ring_of_corner.astype(np.float64), corners]),
    ]) + 0.0  # -0.0 -> 0.0, as a lookup by value would match them
    keys = np.ascontiguousarray(rows).view(np.dtype((np.void, rows.dtype.itemsize * 3))).ravel()
    _, inverse = np.unique(keys, return_inverse=True)
    inverse = inverse.reshape(-1)
    point_of_key = np.full(inverse.max() + 1, -1, np.int64)
    point_of_key[inverse[: len(points)]] = np.arange(len(points))
    tri = point_of_key[inverse[len(points):]].reshape(-1, 3)
    ring = chosen[which]
    unmatched = (tri < 0).any(axis=1)
    if unmatched.any():  # pragma: no cover - GEOS adds no points to a valid polygon
        valid[np.unique(ring[unmatched])] = False
        keep = ~np.isin(ring, np.flatnonzero(~valid))
        tri, ring = tri[keep], ring[keep]
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    tri[cross < 0] = tri[cross < 0][:, ::-1]
    return tri[cross != 0], ring[cross != 0], valid


def _ccw(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    tri = tri.copy()
    flip = cross < 0
    tri[flip] = tri[flip][:, ::-1]
    return tri[cross != 0]


def newell_normal(ring: np.ndarray) -> np.ndarray:
    """Unnormalised polygon normal by Newell's method.

    Parameters
    ----------
    ring : (K, 3) float64

    Returns
    -------
    normal : (3,) float64
        Length = twice the polygon's area; zero for a degenerate ring.
    """
    # np.cross(ring, np.roll(ring, -1, axis=0)).sum(axis=0), written out: the same products, differences and
    # sum (the same bits), without the two calls' overhead (a footprint's every floor and roof comes here)
    nxt = np.concatenate([ring[1:], ring[:1]])
    x, y, z = ring[:, 0], ring[:, 1], ring[:, 2]
    xn, yn, zn = nxt[:, 0], nxt[:, 1], nxt[:, 2]
    return np.stack([y * zn - z * yn, z * xn - x * zn, x * yn - y * xn], axis=-1).sum(axis=0)


def plane_frame(normal: np.ndarray) -> np.ndarray:
    """Orthonormal (2, 3) basis of the plane with the given normal, right-handed with it."""
    return plane_frames(np.asarray(normal, np.float64)[None])[0]


def plane_frames(normals: np.ndarray) -> np.ndarray:
    """:func:`plane_frame` of many planes at once.

    Parameters
    ----------
    normals : (R, 3) float64
        Non-zero normals, any length.

    Returns
    -------
    frames : (R, 2, 3) float64
        Each plane's orthonormal basis ``(e1, e2)``, right-handed with its normal.
    """
    n = normals / np.linalg.norm(normals, axis=1)[:, None]
    helper = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(helper, n)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(n, e1)
    return np.stack([e1, e2], axis=1)


def triangulate_polygon_3d(rings: Sequence[np.ndarray]) -> np.ndarray:
    """Triangulate a planar 3D polygon (outer ring + holes), keeping its orientation.

    Parameters
    ----------
    rings : sequence of (K_i, 3) float64
        Outer ring first; the polygon's orientation is that of the outer ring
        (counter-clockwise seen from the side its normal points to).

    Returns
    -------
    triangles : (T, 3) int64
        Indices into the concatenation of ``rings``, oriented like the outer ring.
        Empty for a degenerate polygon.
    """
    rings = [_ring_array(r) for r in rings]
    outer = rings[0]
    n_outer = len(outer)
    if n_outer < 3:
        return np.zeros((0, 3), np.int64)
    if len(rings) == 1 and n_outer == 3:
        return np.array([[0, 1, 2]], np.int64)
    normal = newell_normal(outer - outer.mean(axis=0))
    if not np.linalg.norm(normal) > 0:
        return np.zeros((0, 3), np.int64)
    if len(rings) == 1 and n_outer == 4:
        # Quads are the common case: split along the shorter diagonal if convex.
        frame = plane_frame(normal)
        p = (outer - outer.mean(axis=0)) @ frame.T
        if _is_convex(p):
            d02 = np.linalg.norm(outer[0] - outer[2])
            d13 = np.linalg.norm(outer[1] - outer[3])
            return (np.array([[0, 1, 2], [0, 2, 3]]) if d02 <= d13 else np.array([[0, 1, 3], [1, 2, 3]])).astype(np.int64)
    frame = plane_frame(normal)
    origin = outer.mean(axis=0)
    flat = [(r - origin) @ frame.T for r in rings]
    points, tri = triangulate_polygon_2d(flat[0], flat[1:])
    n_in = sum(len(r) for r in rings)
    # Points appended by make_valid cannot be mapped back to input vertices: drop those triangles.
    return tri[(tri < n_in).all(axis=1)]


def _is_convex(p: np.ndarray) -> bool:
    d1 = np.roll(p, -1, axis=0) - p
    d2 = np.roll(d1, -1, axis=0)
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    return bool((cross > 0).all() or (cross < 0).all())


def extrude_polygon(
    shell: np.ndarray, holes: Sequence[np.ndarray], z0: float, z1: float
) -> tuple[np.ndarray, np.ndarray]:
    """Extrude a 2D polygon with holes into a closed, outward-oriented block.

    Parameters
    ----------
    shell : (S, 2) float64
        Outer ring of the footprint.
    holes : sequence of (H_i, 2) float64
        Courtyards.
    z0, z1 : float
        Base and top heights, ``z1 > z0``.

    Returns
    -------
    vertices : (2P, 3) float64
        Bottom ring vertices followed by top ring vertices.
    faces : (F, 3) int64
        Counter-clockwise seen from outside.
    """
    if not z1 > z0:
        raise ValueError(f"extrusion needs z1 > z0, received z0={z0}, z1={z1}")
    shell = _orient_ring(_ring_array(shell), ccw=True)
    holes = [_orient_ring(_ring_array(h), ccw=False) for h in holes]
    points, tri = triangulate_polygon_2d(shell, holes)
    n = len(points)
    vertices = np.concatenate(
        [np.column_stack([points, np.full(n, z0)]), np.column_stack([points, np.full(n, z1)])]
    )
    bottom = tri[:, ::-1]
    top = tri + n
    walls = []
    start = 0
    for ring in [shell, *holes]:
        k = len(ring)
        i = start + np.arange(k)
        j = start + (np.arange(k) + 1) % k
        # Outer ring CCW and holes CW seen from above: the outside is to the right.
        walls.append(np.column_stack([i, j, j + n]))
        walls.append(np.column_stack([i, j + n, i + n]))
        start += k
    faces = np.concatenate([bottom, top, *walls]).astype(np.int64)
    return vertices, faces


def _orient_ring(ring: np.ndarray, ccw: bool) -> np.ndarray:
    area2 = np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
    return ring if (area2 > 0) == ccw else ring[::-1]


def triangulate_polygons_3d(polygons: Sequence[Sequence[np.ndarray]]) -> list[np.ndarray]:
    """:func:`triangulate_polygon_3d` of many polygons, its GEOS calls batched.

    Polygons of one ring of at least five corners (a footprint's floor and roof) are projected
    into their planes as :func:`triangulate_polygon_3d` projects them (frames by
    :func:`plane_frames`, all at once) and triangulated in one GEOS call
    (:func:`triangulate_rings_2d`); the others, and rings that are no valid polygon there, go
    through :func:`triangulate_polygon_3d` one by one. The result is the same, triangle for
    triangle (tests/test_footprint_speed.py holds it to the reference).

    Parameters
    ----------
    polygons : sequence of sequences of (K_i, 3) float64
        Each polygon's rings, outer ring first.

    Returns
    -------
    list of (T_j, 3) int64
        Each polygon's triangles, as :func:`triangulate_polygon_3d` gives them.
    """
    out: list = [None] * len(polygons)
    take, centred, normals = [], [], []
    for i, rings in enumerate(polygons):
        outer = _ring_array(rings[0]) if len(rings) == 1 else None
        if outer is None or len(outer) < 5:
            out[i] = triangulate_polygon_3d(rings)
            continue
        c = outer - outer.mean(axis=0)
        normal = newell_normal(c)
        if not np.linalg.norm(normal) > 0:
            out[i] = np.zeros((0, 3), np.int64)
            continue
        take.append(i)
        centred.append(c)
        normals.append(normal)
    if not take:
        return out
    frames = plane_frames(np.array(normals))
    flat = [c @ f.T for c, f in zip(centred, frames)]
    # a ring whose projection closes on itself is shortened by triangulate_polygon_2d: left to it
    plain = np.array([not np.array_equal(f[0], f[-1]) for f in flat], bool)
    lengths = np.array([len(f) for f in flat], np.int64)
    chosen = np.flatnonzero(plain)
    valid = np.zeros(len(take), bool)
    if len(chosen):
        tri, ring, ok = triangulate_rings_2d(np.concatenate([flat[k] for k in chosen]), lengths[chosen])
        valid[chosen] = ok
        start = np.concatenate([[0], np.cumsum(lengths[chosen])])[:-1]
        tri = tri - start[ring][:, None]
        bounds = np.searchsorted(ring, np.arange(len(chosen) + 1))
        for j, k in enumerate(chosen):
            if ok[j]:
                out[take[k]] = tri[bounds[j]:bounds[j + 1]]
    for k in np.flatnonzero(~valid):
        out[take[k]] = triangulate_polygon_3d(polygons[take[k]])
    return out
