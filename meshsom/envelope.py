"""A building as the solid under its roofs (2.5D): the last resort for city models that cannot be closed.

LoD2 city models are roof models: their roofs are measured (aerial images, lidar), their walls hang
from the roofs' outlines down to the terrain. Many are surfaces, not solids (CityJSON/CityGML
``MultiSurface``): walls that stop at the sloping terrain, no ground surface, parts whose walls
overlap with edges that do not meet, roofs of two parts a millimetre apart. Where such a mesh
cannot be closed as it is (:func:`meshsom.preprocess.preprocess`, :mod:`meshsom.union`), the shape
it stands for still is: everything under the roofs, down to the ground. That is what is built here.

1. Roofs: every face not within ``wall_tilt_deg`` of vertical (roof, dormer, a ground or overhang
   surface, whichever way it faces). Walls are not used; they are the roofs' outlines.
2. Coordinates rounded to a file's grid leave roofs that should meet a millimetre apart in plan.
   Within ``envelope_tol`` (metres, in plan): vertices are snapped onto one another, and a roof
   triangle with another roof's vertex beside one of its edges is split there (a T-junction in
   plan), so that the prisms below share their side faces exactly. Two roofs on either side of an
   edge whose heights cross along it are split at the crossing (manifold3d's union leaves a flap,
   two faces folded onto each other, where the wall between them crosses itself).
3. Every roof triangle is extruded down to the building's lowest vertex, a prism; manifold3d
   unites the prisms (exact predicates; nothing here computes intersections). The union is the
   set under the upper envelope of the roofs: overlapping roofs keep the higher, dormers stand on
   the roof, parts become one solid.
4. Undersides: a face facing down with another face above it (a raised or sloping floor, the
   soffit of an overhang) and, under some point of it, nothing solid (the winding of the faces above
   that point: the bottom of a part standing inside another or on another's roof is none; nor the winding of
   the faces below it: a roof slab's soffit over the walls, the ground under it, is none) has the
   column under it taken away again, and the prisms under faces at or below an underside (a lower
   roof under an overhang, the roof of a part another stands on) put back.
5. Shells of the union thinner than ``envelope_tol`` on average (slivers between roofs that did
   not quite meet) are dropped; the caller preprocesses the rest
   (:func:`meshsom.union.preprocess_shells`).

Refused (:class:`~meshsom.errors.MeshError`): no roof above the lowest vertex; roofs only (no wall,
no ground surface within ``envelope_tol`` of the lowest vertex: nothing says where the ground is, and
a roof sheet alone would stand on its own eaves); more roof triangles, or prisms
once split, than ``envelope_max_roofs`` (a detailed or scanned mesh: LoD2 roof models give tens to
hundreds; 2,700 prisms took 106 s to be refused, 43,000 took 5 minutes to unite, once); a first
union that preprocessing refuses and that falls into more than ``envelope_max_pieces`` pieces (a
tree crown: no other way is tried); walls standing outside every roof in plan that would lose more
than ``envelope_max_loss`` of the volume (each wall face's area times its distance outside, an
estimate: walls a few centimetres outside their eaves lose next to nothing, a part with no roof
loses itself); and a rebuild that runs past ``envelope_max_seconds``, all its ways together.

What is lost: whatever is not 2.5D (passages, arcades, overhangs become walls down to the floor)
and the terrain under the walls (the floor is flat, at the lowest vertex). The manifest records
that a mesh was rebuilt, why, and from how many roof and wall faces.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from meshsom.errors import MeshError

__all__ = ["EnvelopeResult", "rebuild_under_roofs", "roof_faces", "solid_under_roofs"]

#: The 8 triangles of a prism over vertices 0-2 (top, counter-clockwise seen from above) and 3-5
#: (their feet), facing outwards.
PRISM_TRIANGLES = np.array(
    [[0, 1, 2], [3, 5, 4], [0, 3, 1], [1, 3, 4], [1, 4, 2], [2, 4, 5], [2, 5, 0], [0, 5, 3]], np.uint64
)
#: How far below the floor the columns under undersides reach, in metres: any depth, so that their
#: bottoms are not coplanar with the floor's.
HOLLOW_DEPTH = 1.0
#: Most rounds of T-junction splitting (each cuts every roof triangle along one of its edges, at every
#: point on it).
MAX_SPLIT_ROUNDS = 32
#: Most roof triangles the splitting may make, as a multiple of the roof triangles it starts from.
MAX_SPLIT_GROWTH = 8


@dataclass
class EnvelopeResult:
    """The solid under a mesh's roofs.

    Attributes
    ----------
    shells : list of ((V_i, 3) float64, (F_i, 3) int64)
        Closed, outward-oriented components, in the caller's coordinates.
    roof_faces, wall_faces : int
        Input faces used as roofs, and faces within ``wall_tilt_deg`` of vertical (not used).
    splits : int
        Roof triangles split where another roof's vertex lies beside an edge (in plan), or where the
        heights of two roofs on either side of an edge cross along it.
    base : float
        z of the floor (the lowest input vertex), in the caller's coordinates.
    volume : float
        Volume of the kept shells.
    slivers : int
        Shells dropped as thinner than ``envelope_tol``.
    sheets : int
        Of the slivers, those of no volume (within ``weld_tol`` x their diagonal cubed): both sides of
        prisms' faces that touch face to face, where walls of parts stand against each other inside
        the building; not pieces of the solid (:func:`rebuild_under_roofs`' ``envelope_max_pieces``).
    undersides : int
        Roof faces (of those above the floor) facing down under another: floors above the lowest
        vertex, soffits of overhangs; the column under them is left empty.
    walls_outside : int
        Wall faces standing more than ``envelope_tol`` outside every roof in plan (lost).
    lost_volume : float
        What they lose: each one's area times its distance outside, summed (an estimate, m3).
    tol : float
        The snapping tolerance used: ``envelope_tol``, or a multiple of it
        (:data:`TOL_FACTORS`) where no way of uniting gave a clean solid at it.
    """

    shells: list = field(repr=False)
    roof_faces: int
    wall_faces: int
    splits: int
    base: float
    volume: float
    slivers: int = 0
    sheets: int = 0
    undersides: int = 0
    walls_outside: int = 0
    lost_volume: float = 0.0
    tol: float = 0.0

    def record(self) -> dict:
        """The manifest record's ``envelope`` entry (JSON-able), without its ``because``."""
        return {
            "status": "rebuilt", "roof_faces": self.roof_faces, "wall_faces": self.wall_faces,
            "splits": self.splits, "undersides": self.undersides, "shells": len(self.shells), "slivers": self.slivers,
            "volume": self.volume, "walls_outside": self.walls_outside, "lost_volume": self.lost_volume,
            "tol": self.tol,
        }

    def describe(self) -> str:
        """One line for the manifest record's repairs."""
        extra = f", {self.splits} roof triangles split where roofs meet or cross in plan" if self.splits else ""
        slivers = f", {self.slivers} sliver shell(s) dropped" if self.slivers else ""
        if self.undersides:
            extra += f", nothing under its {self.undersides} undersides (floors, overhangs)"
        if self.walls_outside:
            extra += (f", {self.walls_outside} walls outside its roofs in plan losing about {self.lost_volume:.3g} m3 "
                      f"({100 * self.lost_volume / self.volume:.2g} %)")
        return (
            f"rebuilt as the solid under its {self.roof_faces} roof faces (2.5D, down to its lowest vertex, roofs "
            f"snapped within {self.tol:g} m; "
            f"{self.wall_faces} wall faces not used{extra}{slivers}): {len(self.shells)} shell(s), "
            f"volume {self.volume:.6g}"
        )


def roof_faces(vertices: np.ndarray, faces: np.ndarray, wall_tilt_deg: float) -> np.ndarray:
    """Which faces are roofs: not within ``wall_tilt_deg`` of vertical, and of non-zero area.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    wall_tilt_deg : float

    Returns
    -------
    (F,) bool
    """
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    area2 = np.linalg.norm(n, axis=1)
    nz = np.abs(n[:, 2]) / np.where(area2 > 0, area2, 1.0)
    return (area2 > 0) & (nz > math.sin(math.radians(wall_tilt_deg)))


def _snap_plan(vertices: np.ndarray, tol: float) -> np.ndarray:
    """``vertices`` with those within ``tol`` of each other in plan moved onto one (the lowest index
    of each group of such neighbours) in x and y; z is kept."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(vertices[:, :2]).query_pairs(tol, output_type="ndarray")
    if not len(pairs):
        return vertices
    n = len(vertices)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    first = np.full(label.max() + 1, n, np.int64)
    np.minimum.at(first, label, np.arange(n))
    out = vertices.copy()
    out[:, :2] = vertices[first[label], :2]
    return out


def _plan_edges(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every edge of every triangle, each from its lower to its higher end in plan (x, then y).

    Both triangles of a shared edge get it the same way round, so that a point computed along it
    is the same bit for bit.

    Parameters
    ----------
    tri : (R, 3, 3) float64

    Returns
    -------
    lo, hi : (3 R, 3) float64
        Edge ``3 r + k`` runs between corners ``k`` and ``k + 1`` of triangle ``r``.
    """
    start, end = tri, tri[:, [1, 2, 0]]
    swap = (start[..., 0] > end[..., 0]) | ((start[..., 0] == end[..., 0]) & (start[..., 1] > end[..., 1]))
    return np.where(swap[..., None], end, start).reshape(-1, 3), np.where(swap[..., None], start, end).reshape(-1, 3)


def _split_once(tri: np.ndarray, label: np.ndarray, outline: np.ndarray, edge: np.ndarray, point: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Each triangle with split points on an edge cut there, at every point of its first such edge.

    A triangle ``(a, b, c)`` with points ``p1 ... pn`` on edge ``a b`` (in order from ``a``) becomes
    the fan ``(a, p1, c), (p1, p2, c), ..., (pn, b, c)``: one round takes every point of an edge, so
    an edge along a row of a hundred vertices is cut in one round, not a hundred.

    Parameters
    ----------
    tri : (R, 3, 3) float64
    label : (R,) int64
    outline : (R, 3) bool
        Which edges (edge ``k`` from corner ``k`` to ``k + 1``) lie on the outline of the roof
        triangle they were cut from; the fan's new edges (to ``c``) do not.
    edge : (S,) int64
        Edges (``3 r + k``, as :func:`_plan_edges`), sorted, with a split point each.
    point : (S, 3) float64

    Returns
    -------
    tri : (R', 3, 3) float64
    label : (R',) int64
    outline : (R', 3) bool
    splits : int
        Triangles cut.
    """
    row = edge // 3
    start = np.concatenate([[True], row[1:] != row[:-1]])
    first_edge = edge[start][np.cumsum(start) - 1]
    on_first = edge == first_edge  # every point of each triangle's first edge
    edge, point, row = edge[on_first], point[on_first], row[on_first]
    k = edge % 3
    a, b, c = tri[row, k], tri[row, (k + 1) % 3], tri[row, (k + 2) % 3]
    along = np.einsum("ij,ij->i", point[:, :2] - a[:, :2], b[:, :2] - a[:, :2])
    order = np.lexsort((along, row))
    row, k, point, along = row[order], k[order], point[order], along[order]
    distinct = np.concatenate([[True], (row[1:] != row[:-1]) | (along[1:] != along[:-1])])
    row, k, point = row[distinct], k[distinct], point[distinct]
    a, b, c = tri[row, k], tri[row, (k + 1) % 3], tri[row, (k + 2) % 3]
    on_ab, on_bc, on_ca = outline[row, k], outline[row, (k + 1) % 3], outline[row, (k + 2) % 3]
    first = np.concatenate([[True], row[1:] != row[:-1]])
    last = np.concatenate([row[1:] != row[:-1], [True]])
    before = np.where(first[:, None], a, np.roll(point, 1, axis=0))  # the fan's previous corner
    keep = np.ones(len(tri), bool)
    keep[row] = False
    pieces = np.concatenate([np.stack([before, point, c], axis=1), np.stack([point[last], b[last], c[last]], axis=1)])
    none = np.zeros(len(row), bool)
    edges = np.concatenate([np.stack([on_ab, none, first & on_ca], axis=1),
                            np.stack([on_ab[last], on_bc[last], none[last]], axis=1)])
    return (np.concatenate([tri[keep], pieces]), np.concatenate([label[keep], label[row], label[row[last]]]),
            np.concatenate([outline[keep], edges]), int(last.sum()))


def _split_in_rounds(tri: np.ndarray, label: np.ndarray, cuts, what: str) -> tuple[np.ndarray, np.ndarray, int]:
    """Triangles cut by :func:`_split_once` in rounds, until ``cuts`` finds no more.

    Parameters
    ----------
    tri : (R, 3, 3) float64
    label : (R,) int64
        A label of each triangle, that its pieces keep.
    cuts : callable
        ``cuts(tri, outline)`` -> ``(edge, point)``: the edges to cut (``3 r + k``), sorted so that
        each triangle's first is the one to cut, and the points, or None where there is none.
        ``outline`` (R, 3) bool says which edges lie on the outline of the triangle they were cut
        from (all of them at the start).
    what : str
        What the cuts are, for the error.

    Returns
    -------
    tri : (R', 3, 3) float64
    label : (R',) int64
    splits : int
        Triangles split.

    Raises
    ------
    ValueError
        When the cutting makes more than :data:`MAX_SPLIT_GROWTH` times the triangles (plus 64), or
        finds cuts still after :data:`MAX_SPLIT_ROUNDS` rounds.
    """
    from meshsom.time_limit import check as check_time

    limit = MAX_SPLIT_GROWTH * len(tri) + 64
    outline = np.ones((len(tri), 3), bool)
    splits = 0
    for _ in range(MAX_SPLIT_ROUNDS):
        check_time(f"splitting {len(tri)} roof triangles {what}")
        found = cuts(tri, outline)
        if found is None:
            break
        tri, label, outline, n = _split_once(tri, label, outline, *found)
        splits += n
        if len(tri) > limit:
            raise ValueError(f"splitting roofs {what} made more than {limit} triangles")
    else:
        if cuts(tri, outline) is not None:
            raise ValueError(f"splitting roofs {what} did not end in {MAX_SPLIT_ROUNDS} rounds")
    return tri, label, splits


def _plan_widths(tri: np.ndarray) -> np.ndarray:
    """Each triangle's width in plan: its smallest height (twice its plan area over its longest plan edge).

    Parameters
    ----------
    tri : (R, 3, 3) float64

    Returns
    -------
    (R,) float64
        0 for a triangle that is a point in plan.
    """
    e = tri[:, [1, 2, 0], :2] - tri[:, :, :2]
    area2 = np.abs(e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])
    longest = np.linalg.norm(e, axis=2).max(axis=1)
    return np.divide(area2, longest, out=np.zeros(len(tri)), where=longest > 0)


def _t_junction_cuts(tri: np.ndarray, outline: np.ndarray, tol: float, slivers: bool = True):
    """Where a roof vertex lies within ``tol`` of an edge's inside, in plan (for :func:`_split_in_rounds`).

    The cut point takes the vertex's x and y exactly and the edge's height there, so that the
    prisms under the two roofs share the vertical side above that stretch of the edge; a triangle
    is cut at every T-point of its first such edge (:func:`_split_once`).

    Only edges on the outline of the roof triangles are cut (``outline``): an edge a cut made inside
    a triangle, from the cut point to the opposite corner, has other roofs' vertices near it only
    where they overlap the triangle in plan, where no prisms need to share a side; cutting there
    too never ended where a barrel vault's rows of vertices lie almost in line with a far corner.
    With ``slivers`` False, triangles narrower than ``tol`` in plan (:func:`_plan_widths`: a needle,
    a face a few degrees off vertical) are not cut either (:data:`SPLIT_RULES`).
    """
    from scipy.spatial import cKDTree

    points = np.unique(tri[:, :, :2].reshape(-1, 2), axis=0)
    lo, hi = _plan_edges(tri)
    d = hi[:, :2] - lo[:, :2]
    length = np.linalg.norm(d, axis=1)
    cut = outline if slivers else outline & (_plan_widths(tri) > tol)[:, None]
    length[~cut.reshape(-1)] = 0.0
    near = cKDTree(points).query_ball_point((lo[:, :2] + hi[:, :2]) / 2, length / 2 + tol)
    counts = np.fromiter((len(c) for c in near), np.int64, len(near))
    edge = np.repeat(np.arange(len(lo)), counts)
    point = np.fromiter((i for c in near for i in c), np.int64, int(counts.sum()))
    rel = points[point] - lo[edge, :2]
    safe = np.where(length > 0, length, 1.0)[edge]
    t = np.einsum("ij,ij->i", rel, d[edge]) / safe**2
    off = np.abs(rel[:, 0] * d[edge, 1] - rel[:, 1] * d[edge, 0]) / safe
    ok = (length[edge] > 0) & (off <= tol) & (t * length[edge] > tol) & ((1 - t) * length[edge] > tol)
    if not ok.any():
        return None
    edge, point, t = edge[ok], point[ok], t[ok]
    order = np.lexsort((t, edge))
    edge, point, t = edge[order], point[order], t[order]
    p = np.empty((len(edge), 3))
    p[:, :2] = points[point]
    p[:, 2] = lo[edge, 2] + t * (hi[edge, 2] - lo[edge, 2])
    return edge, p


def _crossing_cuts(tri: np.ndarray, outline: np.ndarray, tol: float):
    """Where two roofs share an edge in plan and their heights cross along it (for :func:`_split_in_rounds`).

    Two roofs on either side of one edge in plan, one higher at its start and the other at its end,
    meet at a wall whose top crosses itself; manifold3d's union of their prisms leaves a flap there
    (two faces folded onto each other). Both are cut at the crossing, one point for both (the first
    triangle's height there), so that the wall is two triangles meeting at a shared vertex.
    Crossings within ``tol`` of an end are left.
    """
    lo, hi = _plan_edges(tri)
    _, group = np.unique(np.concatenate([lo[:, :2], hi[:, :2]], axis=1), axis=0, return_inverse=True)
    group = group.reshape(-1)
    order = np.argsort(group, kind="stable")
    g = group[order]
    # every pair of edges on one plan edge (pairs of neighbours in the sorted order, then further)
    pairs = [np.stack([order[:-gap][g[gap:] == g[:-gap]], order[gap:][g[gap:] == g[:-gap]]], axis=1)
             for gap in range(1, 4)]
    i, j = np.concatenate(pairs).T
    s = lo[i, 2] - lo[j, 2]
    e = hi[i, 2] - hi[j, 2]
    t = s / np.where(s != e, s - e, 1.0)
    length = np.linalg.norm(hi[i, :2] - lo[i, :2], axis=1)
    crossing = (s * e < 0) & (t * length > tol) & ((1 - t) * length > tol) & (i // 3 != j // 3)
    if not crossing.any():
        return None
    i, j, t = i[crossing], j[crossing], t[crossing]
    point = lo[i] + t[:, None] * (hi[i] - lo[i])
    edge = np.concatenate([i, j])
    o = np.argsort(edge, kind="stable")
    return edge[o], np.concatenate([point, point])[o]


def _prisms(tri: np.ndarray, base: float) -> tuple[np.ndarray, np.ndarray]:
    """The prisms under roof triangles, down to ``base``.

    Parameters
    ----------
    tri : (R, 3, 3) float64
    base : float

    Returns
    -------
    vertices : (R, 6, 3) float64
        Each prism's corners: the triangle counter-clockwise seen from above, then its feet.
    """
    ccw = _plan_area2(tri)
    top = np.where((ccw < 0)[:, None, None], tri[:, ::-1], tri)
    feet = top.copy()
    feet[..., 2] = base
    return np.concatenate([top, feet], axis=1), ccw != 0


#: Most point-triangle pairs :func:`_covered_above` and :func:`_winding_above` test at once (memory:
#: about 100 bytes each).
COVER_CHUNK = 1 << 20
#: The points of a roof face whose columns decide whether it is an underside, or under one
#: (:func:`_roof_prisms`), as barycentric weights: its centroid, and points a hundredth of the way in
#: from its corners and from the middles of its edges (on an edge, a point would be a neighbour's too).
SAMPLES = np.array([[1 / 3, 1 / 3, 1 / 3], [0.98, 0.01, 0.01], [0.01, 0.98, 0.01], [0.01, 0.01, 0.98],
                    [0.495, 0.495, 0.01], [0.01, 0.495, 0.495], [0.495, 0.01, 0.495]])
#: z mirrored (x and y kept, so a face's facing in plan is kept): what lies below a point lies above it, for
#: :func:`_winding_above` to count the faces below (-1 or less inside a closed solid, 0 outside every one).
Z_MIRROR = np.array([1.0, 1.0, -1.0])
#: How far from a triangle's edge in plan, in metres, a point counts as on it (:func:`_winding_above`):
#: float64 rounding of local coordinates a few hundred metres across, not a modelling tolerance.
ON_EDGE = 1e-9


def _heights_in_plan(points: np.ndarray, tri: np.ndarray):
    """Barycentric coordinates in plan of points in triangles, and the triangles' heights there.

    Parameters
    ----------
    points : (P, 3) float64
    tri : (T, 3, 3) float64
        Not vertical (non-zero area in plan).

    Returns
    -------
    s, t : (P, T) float64
        Coordinates along edges 0-1 and 0-2.
    above : (P, T) float64
        How far each triangle lies above each point, at the point's x and y.
    """
    a = tri[:, 0]
    e1, e2 = tri[:, 1] - a, tri[:, 2] - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    p = points[:, None, :] - a[None]
    s = (p[..., 0] * e2[:, 1] - p[..., 1] * e2[:, 0]) / det
    t = (e1[:, 0] * p[..., 1] - e1[:, 1] * p[..., 0]) / det
    return s, t, s * e1[:, 2] + t * e2[:, 2] - p[..., 2]


def _covered_above(points: np.ndarray, tri: np.ndarray, margin: float) -> np.ndarray:
    """Whether a triangle lies above each point: covers it in plan, higher there than its z + ``margin``.

    Parameters
    ----------
    points : (P, 3) float64
    tri : (T, 3, 3) float64
    margin : float

    Returns
    -------
    (P,) bool
    """
    out = np.zeros(len(points), bool)
    if not len(points) or not len(tri):
        return out
    tri = tri[_plan_area2(tri) != 0]
    step = max(1, COVER_CHUNK // max(len(tri), 1))
    for lo in range(0, len(points), step):
        s, t, above = _heights_in_plan(points[lo:lo + step], tri)
        inside = (s >= -1e-9) & (t >= -1e-9) & (s + t <= 1 + 1e-9)
        out[lo:lo + step] = (inside & (above > margin)).any(axis=1)
    return out


def _plan_area2(tri: np.ndarray) -> np.ndarray:
    """Twice each triangle's signed area in plan, (T,) float64: positive counter-clockwise seen from above."""
    x, y = tri[..., 0], tri[..., 1]
    return (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (y[:, 1] - y[:, 0]) * (x[:, 2] - x[:, 0])


def _winding_above(points: np.ndarray, tri: np.ndarray, margin: float) -> np.ndarray:
    """How many of the faces above each point face up, less how many face down: 1 or more inside a closed
    solid (a part), 0 outside every one.

    A vertical line crosses a closed, outward-oriented solid's surface going up as often through faces
    facing down (entering) as through faces facing up (leaving); above a point inside, one more faces up.
    A point on an edge that two triangles share in plan counts for one of them only (the one whose
    counter-clockwise edge runs downwards in y, or along +x), so that a face's triangulation does not
    count twice.

    Parameters
    ----------
    points : (P, 3) float64
    tri : (T, 3, 3) float64
        Oriented triangles: counter-clockwise seen from outside.
    margin : float
        Triangles count where they lie higher than the point's z + ``margin``.

    Returns
    -------
    (P,) int64
    """
    out = np.zeros(len(points), np.int64)
    if not len(points) or not len(tri):
        return out
    area2 = _plan_area2(tri)
    tri, sign = tri[area2 != 0], np.sign(area2[area2 != 0]).astype(np.int64)
    ccw = np.where((sign < 0)[:, None, None], tri[:, ::-1], tri)  # counter-clockwise seen from above
    d = ccw[:, [1, 2, 0], :2] - ccw[:, :, :2]
    length = np.linalg.norm(d, axis=2)
    owns = (d[..., 1] < 0) | ((d[..., 1] == 0) & (d[..., 0] > 0))  # a point on this edge is this triangle's
    step = max(1, COVER_CHUNK // max(3 * len(tri), 1))
    for lo in range(0, len(points), step):
        p = points[lo:lo + step, None, None, :2] - ccw[None, :, :, :2]
        left = (d[None, ..., 0] * p[..., 1] - d[None, ..., 1] * p[..., 0]) / length[None]  # metres left of each edge
        inside = ((left > ON_EDGE) | ((np.abs(left) <= ON_EDGE) & owns[None])).all(axis=2)
        _, _, above = _heights_in_plan(points[lo:lo + step], tri)
        out[lo:lo + step] = ((inside & (above > margin)) * sign[None]).sum(axis=1)
    return out


def _walls_outside(walls: np.ndarray, roofs: np.ndarray, tol: float) -> tuple[int, float, float]:
    """Walls (W, 3, 3) standing more than ``tol`` outside every roof (R, 3, 3) in plan, and what the
    solid under the roofs loses by them.

    Returns
    -------
    count : int
        Wall faces whose centroid stands more than ``tol`` outside the roofs in plan.
    reach : float
        The farthest of them, metres (0 without any).
    lost : float
        Each such wall face's area times its centroid's distance outside, summed (cubic metres): the
        slab between the wall and the roofs' outline, an estimate of the volume the rebuild loses.
    """
    import shapely

    if not len(walls):
        return 0, 0.0, 0.0
    plan = shapely.union_all(shapely.polygons(roofs[:, :, :2]))
    distance = shapely.distance(plan, shapely.points(walls.mean(axis=1)[:, :2]))
    outside = distance > tol
    if not outside.any():
        return 0, 0.0, 0.0
    w = walls[outside]
    area = 0.5 * np.linalg.norm(np.cross(w[:, 1] - w[:, 0], w[:, 2] - w[:, 0]), axis=1)
    return int(outside.sum()), float(distance[outside].max()), float(area @ distance[outside])


#: The ways :func:`solid_under_roofs` can unite the prisms, tried in this order by
#: :func:`rebuild_under_roofs`: manifold3d's ``batch_boolean``, then a balanced tree of pairwise
#: unions. Where walls of three or more prisms meet in one vertical plane, manifold3d's result can
#: hold a flap (faces folded onto each other) or touch itself along an edge, depending on the order
#: of the unions; on val3dity's Delfshaven tile each order leaves a few buildings that the other
#: unites cleanly (9 and 12 of 853 when every building is rebuilt; 3 with both, one of them refused
#: for a wall outside its roofs).
UNION_ORDERS = ("batch", "pairwise")
#: Which roof triangles the T-junction splitting cuts (:func:`_t_junction_cuts`), tried in this order
#: by :func:`rebuild_under_roofs`, each with every union order: every triangle, or all but those
#: narrower than ``envelope_tol`` in plan. Each leaves a few buildings that the other rebuilds (on
#: Zürich's LoD2 models and val3dity's Delfshaven tile, one each), by the same flaps of the union.
SPLIT_RULES = ("all", "no slivers")
#: Multiples of ``envelope_tol`` tried in turn by :func:`rebuild_under_roofs`, each with every split
#: rule and union order: files on a centimetre grid (CityJSON drafts without a transform, exports
#: rounded to 1 cm) leave roofs that should meet a centimetre apart, where 2 mm snaps too little
#: (val3dity's Delfshaven tile as Solids: one building, rebuilt at 2 cm).
TOL_FACTORS = (1, 10)


def _union_of_prisms(manifold3d, tri: np.ndarray, base: float, order: str = "batch"):
    """manifold3d's union of the prisms under triangles ``tri`` (R, 3, 3) down to ``base`` (in one of
    :data:`UNION_ORDERS`), or None."""
    corners, ok = _prisms(tri, base)
    solids = []
    for prism in corners[ok]:
        solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(prism), tri_verts=PRISM_TRIANGLES))
        if solid.status() == manifold3d.Error.NoError and not solid.is_empty():
            solids.append(solid)
    if not solids:
        return None
    if order == "batch":
        return manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if order != "pairwise":
        raise ValueError(f"order must be one of {UNION_ORDERS}; received {order!r}")
    while len(solids) > 1:
        solids = [solids[i] + solids[i + 1] if i + 1 < len(solids) else solids[i] for i in range(0, len(solids), 2)]
    return solids[0]


class _Refusal(MeshError):
    """A refusal that no other way of uniting changes: walls outside the roofs losing too much, too
    many roof triangles, roof faces only."""


@dataclass
class _RoofPrisms:
    """A building's roof triangles ready to be extruded (:func:`_roof_prisms`), in local coordinates."""

    centre: np.ndarray
    tri: np.ndarray
    label: np.ndarray  # 0 a roof, 1 an underside, 2 a roof under an underside
    base: float
    roof_faces: int
    wall_faces: int
    splits: int
    tol: float
    walls_outside: int = 0
    wall_reach: float = 0.0
    lost_volume: float = 0.0
    max_loss: float = 0.01
    weld_tol: float = 0.0


def _check_ground(vertices: np.ndarray, faces: np.ndarray, roofs: np.ndarray, base: float, tol: float,
                  wall_tilt_deg: float, source: str) -> None:
    """Refuse a mesh of roof faces only: no wall, no ground surface (module docstring, refusals).

    The floor of the rebuild is the mesh's lowest vertex; that is the ground only where walls hang
    towards it or a ground surface lies on it. A roof sheet alone (a gable roof without walls or
    floor, a floor polygon of a 3D Tiles batch split from its walls) has neither: its lowest vertex is
    its eave, which the rebuild would take for the ground (a 10 x 10 m gable roof 3 m high was
    accepted as 150 m3). Roofs over a ground plate without walls are kept (the plate is the floor).
    Walls are enough, wherever they end: LoD3 models whose lowest faces are a sloping ground surface
    or a soffit (3DCityDB's railway scene) have hundreds of walls that stop above it.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    roofs : (F,) bool
        :func:`roof_faces`.
    base : float
        The lowest vertex's z.
    tol : float
        Roof faces whose highest vertex is within this of ``base`` lie on the floor: ground surfaces
        (``envelope_tol``, as for the ground surfaces left out of the prisms).
    wall_tilt_deg : float
        Named in the refusal (``roofs`` are the faces not within it of vertical).
    source : str

    Raises
    ------
    _Refusal
        When no face of non-zero area is a wall and none lies on the floor.
    """
    tri = vertices[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    ground = (~roofs | (tri[..., 2].max(axis=1) - base <= tol)) & (area2 > 0)
    if not ground.any():
        raise _Refusal(
            source, f"only roof faces: no wall or floor says where the ground is: its {int(roofs.sum())} faces are all "
                    f"roofs, none within {wall_tilt_deg:g} degrees of vertical and none lying on its lowest vertex (within "
                    f"preprocess.envelope_tol, {tol:g} m); a roof or floor sheet, not a building's shell")


def _roof_prisms(vertices: np.ndarray, faces: np.ndarray, params, source: str, split: str = "all") -> _RoofPrisms:
    """Steps 1, 2 and the sorting of undersides of the module docstring; the refusals."""
    from meshsom.preprocess import check_input

    vertices, faces = check_input(vertices, faces, source)
    # a local origin: the boolean sees coordinates of the building's own size
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    local = vertices - centre
    tol = params.envelope_tol
    used = np.unique(faces)
    snapped = local.copy()
    if tol > 0:
        snapped[used] = _snap_plan(local[used], tol)
    roofs = roof_faces(snapped, faces, params.wall_tilt_deg)
    base = float(local[used, 2].min())
    every = snapped[faces[roofs]]  # the ground surfaces on the floor too
    tri = every[every[..., 2].max(axis=1) - base > tol]  # not a ground surface on the floor
    if not len(tri):
        raise MeshError(
            source, f"no roof to rebuild it under: of its {len(faces)} faces, {int((~roofs).sum())} are walls "
                    f"(within {params.wall_tilt_deg:g} degrees of vertical) and none of the rest is above its lowest vertex")
    _check_ground(snapped, faces, roofs, base, tol, params.wall_tilt_deg, source)
    if params.envelope_max_roofs and len(tri) > params.envelope_max_roofs:
        raise _Refusal(
            source, f"{len(tri)} roof triangles, more than preprocess.envelope_max_roofs ({params.envelope_max_roofs}): "
                    f"a detailed or scanned mesh, not a roof model (uniting that many prisms takes minutes)")
    walls_outside = _walls_outside(snapped[faces[~roofs]], tri, tol)
    # Undersides: faces facing down with a face above them (a sloping or raised floor, the soffit
    # of an overhang) and nothing solid under some point of them; the column under them is not filled,
    # except under faces under some point of them (a lower roof under an overhang, the roof of a part
    # that another part stands on). The bottom of a part standing inside another (a box in a hall, a
    # part on a lower one's roof) has the other's inside under it (_winding_above, counting the faces
    # within tol above the points, itself and a roof it stands on included): no underside; hollowed, its
    # column was lost (the Bolshoi Theatre's boxes in its hall: 8 % of its volume). Points of each face
    # (SAMPLES), not its centroid alone: a capital on a column is an underside where it overhangs it.
    normal_z = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]
    centroid = tri.mean(axis=1)
    under = np.zeros(len(tri), bool)
    down = np.flatnonzero(normal_z < 0)
    down = down[_covered_above(centroid[down], tri, tol)]
    points = np.einsum("sk,tkd->tsd", SAMPLES, tri[down]).reshape(-1, 3)
    # A point with a solid under it is no underside either (the winding of the faces below it, the ground surfaces
    # on the floor included): a roof slab's soffit that the walls stand against, as LoD3 writes a roof, has its top
    # and itself above it, which wind to none as over an overhang, yet the storeys under it (geoRES's test data lost
    # 85 % of a house so). An overhang's soffit has no ground under it.
    beneath = _winding_above(points * Z_MIRROR, every * Z_MIRROR, tol)  # -1 or less inside a solid
    empty = (_winding_above(points, tri, -tol) <= 0) & (beneath >= 0)
    under[down] = empty.reshape(len(down), len(SAMPLES)).any(axis=1)
    below = ~under
    points = np.einsum("sk,tkd->tsd", SAMPLES, tri[below]).reshape(-1, 3)
    below[below] = _covered_above(points, tri[under], -tol).reshape(-1, len(SAMPLES)).any(axis=1)
    label = under.astype(np.int64) + 2 * below
    splits = 0
    try:
        if tol > 0:
            tri, label, splits = _split_in_rounds(tri, label, lambda t, o: _t_junction_cuts(t, o, tol, split == "all"), "at T-junctions")
        tri, label, crossings = _split_in_rounds(tri, label, lambda t, o: _crossing_cuts(t, o, tol), "where their heights cross")
    except ValueError as err:
        raise MeshError(source, f"cannot rebuild it under its roofs: {err}") from None
    if params.envelope_max_roofs and len(tri) > params.envelope_max_roofs:  # the splits multiply them
        raise _Refusal(
            source, f"{int(roofs.sum())} roof triangles, split where they meet into {len(tri)} prisms, more than "
                    f"preprocess.envelope_max_roofs ({params.envelope_max_roofs}): a detailed mesh, not a roof model "
                    f"(uniting that many prisms takes minutes; roof models give at most hundreds)")
    return _RoofPrisms(centre, tri, label, base, int(roofs.sum()), int((~roofs).sum()), splits + crossings, tol,
                       *walls_outside, params.envelope_max_loss, params.weld_tol)


def _unite(prisms: _RoofPrisms, order: str, source: str) -> EnvelopeResult:
    """Steps 3-5 of the module docstring: the prisms united in one of :data:`UNION_ORDERS`."""
    from meshsom.time_limit import check as check_time
    from meshsom.union import _area_volume, _manifold3d

    manifold3d = _manifold3d()
    tri, label, base, tol = prisms.tri, prisms.label, prisms.base, prisms.tol
    united = _union_of_prisms(manifold3d, tri, base, order)
    check_time(f"uniting its {len(tri)} roof prisms ({order} union)")
    if united is None:
        raise MeshError(source, "no roof to rebuild it under: every roof triangle is vertical in plan")
    if (label == 1).any():
        hollow = _union_of_prisms(manifold3d, tri[label == 1], base - HOLLOW_DEPTH, order)
        if hollow is not None:
            united = united - hollow
        if (label == 2).any():
            refill = _union_of_prisms(manifold3d, tri[label == 2], base, order)
            if refill is not None:
                united = united + refill
    if united.status() != manifold3d.Error.NoError or united.is_empty():
        raise MeshError(source, f"the union of the prisms under its {len(tri)} roof triangles failed ({united.status().name})")
    shells, slivers, sheets, volume = [], 0, 0, 0.0
    for piece in united.decompose():
        mesh = piece.to_mesh64()
        v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
        f = np.asarray(mesh.tri_verts, np.int64).reshape(-1, 3)
        area, vol = _area_volume(v, f)
        if not 2 * vol > tol * area:  # thinner than the tolerance on average: a sliver between roofs
            slivers += 1
            sheets += not abs(vol) > prisms.weld_tol * float(np.linalg.norm(np.ptp(v, axis=0))) ** 3
            continue
        volume += vol
        shells.append((v + prisms.centre, f))
    if not shells:
        raise MeshError(source, f"the solid under its roofs is thinner than {tol:g} m everywhere")
    if prisms.lost_volume > prisms.max_loss * volume:
        raise _Refusal(
            source, f"{prisms.walls_outside} of its {prisms.wall_faces} wall faces stand outside every roof in plan "
                    f"(up to {prisms.wall_reach:.3g} m): the solid under its roofs ({volume:.6g} m3) would lose about "
                    f"{prisms.lost_volume:.3g} m3 with them ({100 * prisms.lost_volume / volume:.2g} %, more than "
                    f"preprocess.envelope_max_loss {100 * prisms.max_loss:g} %: a part whose roof is missing?)")
    return EnvelopeResult(
        shells=shells, roof_faces=prisms.roof_faces, wall_faces=prisms.wall_faces, splits=prisms.splits,
        base=base + float(prisms.centre[2]), volume=volume, slivers=slivers, sheets=sheets, undersides=int((label == 1).sum()),
        walls_outside=prisms.walls_outside, lost_volume=prisms.lost_volume, tol=tol,
    )


def solid_under_roofs(vertices: np.ndarray, faces: np.ndarray, params=None, source: str = "mesh",
                      order: str = "batch", split: str = "all") -> EnvelopeResult:
    """The solid under the roofs of a building, down to its lowest vertex (module docstring).

    Parameters
    ----------
    vertices : (V, 3) float64
        In metres, z up.
    faces : (F, 3) int64
    params : PreprocessParams, optional
        ``wall_tilt_deg`` and ``envelope_tol``.
    source : str
        Named in errors.
    order : str
        How the prisms are united (:data:`UNION_ORDERS`).
    split : str
        Which roof triangles are cut at T-junctions (:data:`SPLIT_RULES`).

    Returns
    -------
    EnvelopeResult

    Raises
    ------
    MeshError
        When the input is not a mesh (:func:`meshsom.preprocess.check_input`), has no roof above its
        lowest vertex, has walls outside its roofs that lose more than ``envelope_max_loss`` of the
        volume, or manifold3d's union fails.
    """
    from meshsom.preprocess import PreprocessParams

    if split not in SPLIT_RULES:
        raise ValueError(f"split must be one of {SPLIT_RULES}; received {split!r}")
    return _unite(_roof_prisms(vertices, faces, params or PreprocessParams(), source, split), order, source)


def rebuild_under_roofs(vertices: np.ndarray, faces: np.ndarray, params=None, source: str = "mesh"):
    """The solid under a building's roofs, preprocessed: the roof prisms (made once for each of
    :data:`SPLIT_RULES`, at ``envelope_tol`` and then at its multiples :data:`TOL_FACTORS`) united
    in each of :data:`UNION_ORDERS` until :func:`meshsom.union.preprocess_shells` accepts the
    union's shells, within ``envelope_max_seconds``.

    The budget (:mod:`meshsom.time_limit`, nested in the mesh's own ``max_seconds``, the earlier
    deadline kept) is checked at every step of every way; manifold3d's union is not interrupted, so
    a way is not started when the time left is shorter than the longest way so far took
    (:data:`ATTEMPT_MARGIN` times it). Running out of it is a rejection like any other; running out of
    ``max_seconds`` still ends the mesh's preprocessing (:class:`~meshsom.time_limit.TimeLimitExceeded`).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    params : PreprocessParams, optional
    source : str

    Returns
    -------
    envelope : EnvelopeResult
    result : meshsom.preprocess.Result

    Raises
    ------
    MeshError
        A refusal of the roofs themselves (no roof, roof faces only, walls outside
        them losing too much: no order changes that), the budget spent (naming it, the ways tried and
        the first way's reason), or the first way's reason when no way gives shells that preprocess.
    TimeLimitExceeded
        When the mesh's own ``max_seconds`` has run out.
    """
    from meshsom.preprocess import PreprocessParams
    from meshsom.time_limit import TimeLimitExceeded, check as check_time, time_limit

    params = params or PreprocessParams()
    budget = params.envelope_max_seconds
    tried: list = []  # (seconds, reason) of each way that failed
    start = time.monotonic()
    try:
        with time_limit(budget):
            return _rebuild(vertices, faces, params, source, tried, start)
    except TimeLimitExceeded as err:
        check_time(err.stage)  # the mesh's own max_seconds has run out too: that ends the mesh
        took, stage = "took", f"stopped while {err.stage}"
    except _OutOfTime as err:
        took, stage = "would take", f"not started: {err.stage}"
    ways = len(SPLIT_RULES) * len(UNION_ORDERS) * (len(TOL_FACTORS) if params.envelope_tol > 0 else 1)
    first = f"; the first failed: {tried[0][1]}" if tried else ""
    raise MeshError(
        source, f"{took} more than {budget:g} s (preprocess.envelope_max_seconds; raise it, or 0 for no limit): "
                f"{len(tried)} of {ways} ways of uniting its roof prisms tried "
                f"in {time.monotonic() - start:.1f} s, {stage}{first}") from None


class _OutOfTime(Exception):
    """The next way of uniting would not end within ``envelope_max_seconds`` (:func:`rebuild_under_roofs`)."""

    def __init__(self, stage: str):
        self.stage = stage
        super().__init__(stage)


#: A way of uniting is started only where the time left of ``envelope_max_seconds`` is at least this many
#: times the longest way so far (:func:`rebuild_under_roofs`): the next one takes about as long (on the
#: 3DCityDB COLLADA model of 2,700 prisms, 7 to 21 s each), and manifold3d's union cannot be interrupted.
ATTEMPT_MARGIN = 1.0


def _rebuild(vertices: np.ndarray, faces: np.ndarray, params, source: str, tried: list, start: float):
    """:func:`rebuild_under_roofs` within its budget; ``tried`` gets (seconds, reason) of each way that fails."""
    from meshsom import union
    from meshsom.time_limit import check as check_time

    budget = params.envelope_max_seconds
    first = None
    for factor in TOL_FACTORS if params.envelope_tol > 0 else (1,):
        snap = replace(params, envelope_tol=params.envelope_tol * factor)
        for split in SPLIT_RULES:
            try:
                prisms = _roof_prisms(vertices, faces, snap, source, split)
            except _Refusal:
                raise
            except MeshError as err:
                first = first or err
                continue
            for order in UNION_ORDERS:
                stage = (f"uniting its {len(prisms.tri)} roof prisms ({split} roof triangles split, {order} union, "
                         f"{snap.envelope_tol:g} m snap)")
                check_time(stage)
                longest = max((t for t, _ in tried), default=0.0)
                if budget and tried and time.monotonic() - start + ATTEMPT_MARGIN * longest > budget:
                    raise _OutOfTime(f"{stage}, as each took up to {longest:.1f} s")
                envelope = None
                began = time.monotonic()
                try:
                    envelope = _unite(prisms, order, source)
                    return envelope, union.preprocess_shells(envelope.shells, params, source=source)
                except _Refusal:
                    raise
                except MeshError as err:
                    first = first or err
                    tried.append((time.monotonic() - began, err.problem))
                    # flat sheets are no pieces: where parts' walls stand against each other inside a building
                    pieces = len(envelope.shells) + envelope.slivers - envelope.sheets if envelope is not None else 0
                    if params.envelope_max_pieces and pieces > params.envelope_max_pieces:
                        raise _Refusal(source, f"{first.problem}; its union under the roofs falls into {pieces} "
                                               f"pieces, more than preprocess.envelope_max_pieces "
                                               f"({params.envelope_max_pieces}): not a roof model (a tree, a "
                                               f"scan?), no other way of uniting tried") from None
    raise first
