"""A building's parts as one outer surface: a boolean union by manifold3d.

A CityJSON Building made of BuildingParts (a podium and a tower, two wings sharing a wall) is a set
of closed volumes that touch or overlap. Merging their triangles keeps the shared walls inside and
the touching shells apart; the union of the volumes is the building's outer surface. The boolean
itself is manifold3d's (exact predicates, symbolic perturbation for coplanar and touching faces);
nothing here computes intersections.

1. Each part alone goes through :func:`meshsom.preprocess.preprocess` (weld, cap, orient), so it is
   a closed, outward-oriented volume that manifold3d accepts; a part that cannot be made one is a
   :class:`~meshsom.errors.MeshError` naming the part (the caller then falls back to merging). Its
   corners all stay where they are (no ``flatten_collinear``, no ``max_fold_v`` collapse): a corner
   a centimetre off the line of its wall is where a neighbouring part meets it.
2. A part's vertex within ``union_snap_tol`` in plan of another part's wall is moved onto that
   wall's foot line (:func:`snap_to_walls`): walls drawn as one but a millimetre apart would leave
   a crevice a hundredth of a degree wide, which no later repair closes.
3. The parts are united in float64 (``Mesh64``) about the centre of their bounding box, so large
   national-grid coordinates never reach the boolean.
4. The union's connected components (manifold3d's ``decompose``) are the shells: parts that do not
   touch stay separate shells of one mesh. Each shell keeps its own vertices, so two shells that
   touch along an edge stay two manifold shells instead of being welded into a non-manifold edge.

:func:`preprocess_shells` then preprocesses every shell (re-triangulating the faces the union
joined, e.g. a roof spanning two parts) and puts them together as one
:class:`~meshsom.preprocess.Result`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from meshsom.errors import MeshError

__all__ = ["UnionResult", "union_parts", "unite", "snap_to_walls", "preprocess_shells"]


@dataclass
class UnionResult:
    """The union of a building's parts, and what it removed.

    Attributes
    ----------
    shells : list of ((V_i, 3) float64, (F_i, 3) int64)
        The union's connected components, each closed and outward-oriented, in the caller's
        coordinates.
    parts : int
        Parts united.
    shells_before, shells_after : int
        Closed shells of the parts (summed), and of the union.
    area_in, area_out : float
        Surface area of the parts (summed, after each part's preprocessing) and of the union.
    volume_in, volume_out : float
        Enclosed volume of the parts (summed) and of the union.
    repairs : list of str
        What preprocessing changed in each part, prefixed by the part.
    moved : int
        Corners of parts moved onto another part's wall before the union (:func:`snap_to_walls`).
    """

    shells: list = field(repr=False)
    parts: int
    shells_before: int
    shells_after: int
    area_in: float
    area_out: float
    volume_in: float
    volume_out: float
    repairs: list[str] = field(default_factory=list)
    moved: int = 0

    @property
    def area_removed(self) -> float:
        """Surface the union removed: shared walls, overlaps, enclosed parts."""
        return self.area_in - self.area_out

    def record(self) -> dict:
        """The manifest record's ``union`` entry (JSON-able)."""
        return {
            "status": "united", "parts": self.parts, "shells_before": self.shells_before,
            "shells_after": self.shells_after, "area_in": self.area_in, "area_out": self.area_out,
            "area_removed": self.area_removed, "volume_in": self.volume_in, "volume_out": self.volume_out,
            "corners_moved": self.moved,
        }


def _manifold3d():
    try:
        import manifold3d
    except ImportError as err:  # pragma: no cover - manifold3d is a declared dependency
        raise ImportError("the union of building parts needs manifold3d: pip install 'manifold3d>=3.0'") from err
    return manifold3d


def _area_volume(vertices: np.ndarray, faces: np.ndarray) -> tuple[float, float]:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    return float(0.5 * np.linalg.norm(cross, axis=1).sum()), float(np.einsum("ij,ij->i", a, cross).sum() / 6.0)


def union_parts(
    vertices: np.ndarray,
    faces: np.ndarray,
    face_part: np.ndarray,
    params=None,
    source: str = "mesh",
    part_names: Sequence[str] | None = None,
) -> UnionResult:
    """Unite the closed parts of one building into its outer surface.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    face_part : (F,) int64
        The part of every face, 0 .. P-1.
    params : PreprocessParams, optional
        Tolerances of each part's preprocessing.
    source : str
        Named in errors.
    part_names : sequence of str, optional
        Names of the parts (CityJSON object ids), for errors and repairs.

    Returns
    -------
    UnionResult

    Raises
    ------
    MeshError
        When a part cannot be made a closed volume, manifold3d refuses it, or the union fails or
        is empty; ``problem`` names the part and the reason.
    """
    from meshsom.preprocess import PreprocessParams

    params = params or PreprocessParams()
    vertices, faces, face_part, names = _checked(vertices, faces, face_part, part_names)
    return _united(_prepared(vertices, faces, face_part, params, source, names), params, params.union_snap_tol, source)


def _checked(vertices, faces, face_part, part_names) -> tuple:
    """The arrays as float64 and int64, and a name for each part, checked (ValueError where they do not fit)."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    face_part = np.asarray(face_part, np.int64).reshape(-1)
    if len(face_part) != len(faces):
        raise ValueError(f"face_part must have one entry per face ({len(faces)}), received {len(face_part)}")
    n_parts = int(face_part.max()) + 1 if len(face_part) else 0
    names = list(part_names) if part_names is not None else [str(k) for k in range(n_parts)]
    if len(names) < n_parts:
        raise ValueError(f"part_names must name all {n_parts} parts, received {len(names)}")
    return vertices, faces, face_part, names[:n_parts]


def _prepared(vertices, faces, face_part, params, source: str, names: list) -> tuple:
    """Each part preprocessed alone, about the parts' centre: (centre, [(part, vertices, faces)], repairs, area, volume)."""
    from meshsom.preprocess import preprocess

    # Local origin: the boolean sees coordinates of the building's own size, whatever the input's.
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2 if len(vertices) else np.zeros(3)
    local = vertices - centre
    # Each part keeps its shape: collapsing a part's short jogs (max_fold_v) keeps its volume but moves its walls,
    # into a neighbour's (Vienna's parts overlapped by 20 m3 so); dropping its outline's corners that lie within
    # planar_dist of the line through their neighbours (flatten_collinear: up to 2 cm on a part 200 m across) moves
    # its wall off the neighbour whose corner that was, leaving a wedge a hundredth of a degree wide that no repair
    # of the union closes (OpenStreetMap's parts share their nodes). The united shells are cleaned so afterwards.
    part_params = replace(params, max_fold_v=0.0, flatten_collinear=False)
    repairs, prepared = [], []
    area_in = volume_in = 0.0
    for k in range(len(names)):
        sel = face_part == k
        if not sel.any():
            continue
        try:
            part = preprocess(local, faces[sel], part_params, source=f"{source} part {names[k]}")
        except MeshError as err:
            raise MeshError(source, f"part {names[k]} is not a closed volume ({err.problem})") from None
        repairs += [f"part {names[k]}: {r}" for r in part.repairs]
        a, v = _area_volume(part.vertices, part.faces)
        area_in += a
        volume_in += v
        prepared.append((names[k], part.vertices, part.faces))
    return centre, prepared, repairs, area_in, volume_in


def _united(prepared: tuple, params, snap_tol: float, source: str) -> UnionResult:
    """The union of :func:`_prepared` parts, their corners snapped onto each other's walls within ``snap_tol``."""
    manifold3d = _manifold3d()
    centre, parts, repairs, area_in, volume_in = prepared
    repairs = list(repairs)
    snapped, moved, held = snap_to_walls([(pv, pf) for _, pv, pf in parts], snap_tol, params.wall_tilt_deg,
                                         volume_rtol=params.volume_rtol)
    if moved:
        repairs.append(f"moved {moved} corners of parts by at most {snap_tol:g} m in plan onto another "
                       f"part's wall (walls drawn as one, a little apart)")
    if held.any():
        names = [name for (name, _, _), h in zip(parts, held) if h]
        repairs.append(f"left {len(names)} parts unsnapped, as moving their corners onto walls changed their volume by "
                       f"more than {params.volume_rtol:g} ({', '.join(names[:3])}"
                       f"{', ...' if len(names) > 3 else ''})")
    solids, shells_before = [], 0
    for (name, _, pf), pv in zip(parts, snapped):
        solid = manifold3d.Manifold(manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(pv, np.float64),
            tri_verts=np.ascontiguousarray(pf, np.uint64),
        ))
        if solid.status() != manifold3d.Error.NoError or solid.is_empty():
            raise MeshError(source, f"part {name}: manifold3d refuses it ({solid.status().name})")
        shells_before += len(solid.decompose())
        solids.append(solid)
    united = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if united.status() != manifold3d.Error.NoError or united.is_empty():
        raise MeshError(source, f"the union of {len(solids)} parts failed ({united.status().name})")
    pieces, volumes = [], []
    area_out = volume_out = 0.0
    sheets = 0
    for piece in united.decompose():
        mesh = piece.to_mesh64()
        v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
        f = np.asarray(mesh.tri_verts, np.int64).reshape(-1, 3)
        a, vol = _area_volume(v, f)
        if len(v) and not abs(vol) > params.weld_tol * float(np.linalg.norm(np.ptp(v, axis=0))) ** 3:
            sheets += 1  # a flat sheet (both sides of faces of parts that touched face to face): no volume, no shell
            continue
        area_out += a
        volume_out += vol
        pieces.append((v, f))
        volumes.append(vol)
    shells = [(v + centre, f) for v, f in _with_cavities(pieces, np.asarray(volumes, np.float64))]
    if sheets:
        repairs.append(f"dropped {sheets} flat sheet(s) the union left (zero volume: faces of parts that touch face to "
                       f"face)")
    if not shells:
        raise MeshError(source, f"the union of {len(solids)} parts encloses no volume")
    return UnionResult(shells, len(solids), shells_before, len(shells), area_in, area_out, volume_in, volume_out, repairs,
                       moved)


def _with_cavities(pieces: list, volumes: np.ndarray) -> list:
    """The union's pieces, each cavity (a piece of negative volume: manifold3d's ``decompose`` gives the hollow of a
    part as a piece of its own, facing in) joined to the smallest piece that encloses it, so that preprocessing keeps
    it a cavity (:func:`meshsom.preprocess.cavity_shells`, the rule it orients shells by) instead of turning it
    outward as a solid.

    Parameters
    ----------
    pieces : list of ((V_i, 3) float64, (F_i, 3) int64)
    volumes : (P,) float64
        Each piece's signed volume.

    Returns
    -------
    list of ((V_j, 3) float64, (F_j, 3) int64)
        The pieces of positive volume, each with the cavities it encloses (its vertices first); a cavity that no
        piece encloses stays a piece of its own.
    """
    from meshsom.preprocess import cavity_shells

    hollow = np.flatnonzero(volumes < 0)
    if not len(hollow):
        return pieces
    low = np.array([v.min(axis=0) for v, _ in pieces])
    high = np.array([v.max(axis=0) for v, _ in pieces])
    host = np.full(len(pieces), -1, np.int64)
    for c in hollow:
        within = np.flatnonzero((volumes > 0) & (low <= low[c]).all(axis=1) & (high >= high[c]).all(axis=1))
        for s in within[np.argsort(volumes[within])]:  # the smallest enclosing piece first
            (vs, fs), (vc, fc) = pieces[s], pieces[c]
            both = np.concatenate([fs, fc + len(vs)])
            if cavity_shells(np.concatenate([vs, vc]), both, np.repeat([0, 1], [len(fs), len(fc)]))[1]:
                host[c] = s
                break
    out = []
    for s in range(len(pieces)):
        if host[s] >= 0:
            continue
        mine = [s, *np.flatnonzero(host == s)]
        offsets = np.cumsum([0] + [len(pieces[k][0]) for k in mine])
        out.append((np.concatenate([pieces[k][0] for k in mine]),
                    np.concatenate([pieces[k][1] + offsets[i] for i, k in enumerate(mine)])))
    return out


def unite(vertices: np.ndarray, faces: np.ndarray, face_part: np.ndarray, params=None, source: str = "mesh",
          part_names: Sequence[str] | None = None):
    """:func:`union_parts`, then :func:`preprocess_shells` of its shells.

    When the union whose parts' corners were snapped onto each other's walls cannot be preprocessed, the parts
    are united again as they are (a snap can tilt a part's underside off the sloped roof it stands on, a union
    left as drawn can still close).

    Returns
    -------
    united : UnionResult
    result : meshsom.preprocess.Result

    Raises
    ------
    MeshError
        From the union, or the preprocessing of its shells (the union as drawn, where both were tried).
    """
    from meshsom.preprocess import PreprocessParams

    params = params or PreprocessParams()
    vertices, faces, face_part, names = _checked(vertices, faces, face_part, part_names)
    prepared = _prepared(vertices, faces, face_part, params, source, names)  # the parts preprocessed once, for both
    united = _united(prepared, params, params.union_snap_tol, source)
    try:
        return united, preprocess_shells(united.shells, params, source=source)
    except MeshError:
        if not united.moved:
            raise
    united = _united(prepared, params, 0.0, source)  # as drawn
    return united, preprocess_shells(united.shells, params, source=source)


def snap_to_walls(parts: Sequence[tuple[np.ndarray, np.ndarray]], tol: float, wall_tilt_deg: float,
                  rounds: int = 2, volume_rtol: float | None = None) -> tuple[list[np.ndarray], int, np.ndarray]:
    """Move every part's vertices that lie within ``tol`` in plan of another part's wall onto it.

    A wall is a face within ``wall_tilt_deg`` of vertical; seen from above it is a segment (its foot
    line). A vertex that close to another part's wall segment (its ends included) moves in x and y,
    not z, to the nearest point of that segment: every copy of a footprint's corner (its foot, its
    eaves) moves alike, so the part's wall becomes the other's plane. Parts of one footprint file
    drawn a millimetre apart then meet in one plane, which the union merges exactly.

    Parameters
    ----------
    parts : sequence of ((V_i, 3) float64, (F_i, 3) int64)
        Closed parts, in metres.
    tol : float
        Largest move, metres in plan; 0: nothing moves.
    wall_tilt_deg : float
        Faces within this many degrees of vertical are walls.
    rounds : int
        Passes (a vertex moved onto a wall that itself moved is moved again).
    volume_rtol : float, optional
        A part whose volume the moves change by more than this fraction keeps all its vertices (a window's pane a
        centimetre thick beside its frame would be flattened); the others are snapped again without it. None: no
        part is held.

    Returns
    -------
    vertices : list of (V_i, 3) float64
        Each part's vertices after the moves (new arrays; the inputs are untouched).
    moved : int
        Vertices moved (in the last pass that moved any, counted once each).
    held : (P,) bool
        The parts left as they are because the moves changed their volume (``volume_rtol``).
    """
    verts = [np.array(v, np.float64) for v, _ in parts]
    held = np.zeros(len(parts), bool)
    if tol <= 0 or len(parts) < 2:
        return verts, 0, held
    before = np.array([_area_volume(v, f)[1] for v, f in zip(verts, (f for _, f in parts))])
    while True:
        snapped, moved = _snapped(parts, verts, tol, wall_tilt_deg, rounds, held)
        if volume_rtol is None or not moved:
            return snapped, moved, held
        after = np.array([_area_volume(v, f)[1] for v, f in zip(snapped, (f for _, f in parts))])
        distorted = np.abs(after - before) > volume_rtol * np.abs(before)
        if not distorted.any():
            return snapped, moved, held
        held |= distorted  # held parts keep their volume: each pass holds new ones, so this ends


def _snapped(parts, verts: list, tol: float, wall_tilt_deg: float, rounds: int, held: np.ndarray
             ) -> tuple[list[np.ndarray], int]:
    """:func:`snap_to_walls`' passes, the vertices of the ``held`` (P,) bool parts left where they are (their walls
    still taken)."""
    import shapely

    part_of_vertex = np.repeat(np.arange(len(parts)), [len(v) for v in verts])
    offsets = np.concatenate([[0], np.cumsum([len(v) for v in verts])])
    faces = np.concatenate([f + offsets[k] for k, (_, f) in enumerate(parts)])
    part_of_face = np.repeat(np.arange(len(parts)), [len(f) for _, f in parts])
    moved_any = np.zeros(len(part_of_vertex), bool)
    sin_tilt = np.sin(np.radians(wall_tilt_deg))
    for _ in range(rounds):
        v = np.concatenate(verts)
        tri = v[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normal, axis=1)
        wall = (length > 0) & (np.abs(normal[:, 2]) <= sin_tilt * np.where(length > 0, length, 1.0))
        if not wall.any():
            break
        # A vertical triangle seen from above: the segment between its two corners farthest apart in plan.
        plan = tri[wall][:, :, :2]
        pairs = np.array([[0, 1], [1, 2], [2, 0]])
        span = np.linalg.norm(plan[:, pairs[:, 0]] - plan[:, pairs[:, 1]], axis=2)
        ends = pairs[np.argmax(span, axis=1)]
        a = plan[np.arange(len(plan)), ends[:, 0]]
        b = plan[np.arange(len(plan)), ends[:, 1]]
        seg_part = part_of_face[wall]
        ok = np.linalg.norm(b - a, axis=1) > 0
        a, b, seg_part = a[ok], b[ok], seg_part[ok]
        tree = shapely.STRtree(shapely.linestrings(np.stack([a, b], axis=1)))
        vi, si = tree.query(shapely.points(v[:, :2]), predicate="dwithin", distance=tol)
        other = (part_of_vertex[vi] != seg_part[si]) & ~held[part_of_vertex[vi]]
        vi, si = vi[other], si[other]
        if not len(vi):
            break
        d = b[si] - a[si]
        t = np.clip(np.einsum("ij,ij->i", v[vi, :2] - a[si], d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        foot = a[si] + t[:, None] * d
        dist = np.linalg.norm(foot - v[vi, :2], axis=1)
        # The nearest wall of each vertex; vertices on a wall already (dist 0) stay.
        order = np.lexsort((dist, vi))
        first = order[np.r_[True, vi[order][1:] != vi[order][:-1]]]
        move = first[(dist[first] > 0) & (dist[first] <= tol)]
        if not len(move):
            break
        v = v.copy()
        v[vi[move], :2] = foot[move]
        moved_any[vi[move]] = True
        verts = [v[offsets[k]:offsets[k + 1]] for k in range(len(parts))]
    return verts, int(moved_any.sum())


def preprocess_shells(shells: Sequence[tuple[np.ndarray, np.ndarray]], params=None, source: str = "mesh"):
    """Preprocess every shell alone and put them together as one mesh.

    Parameters
    ----------
    shells : sequence of ((V_i, 3) float64, (F_i, 3) int64)
    params : PreprocessParams, optional
    source : str

    Returns
    -------
    Result
        Vertices and faces of all shells (each shell keeps its own vertices), repairs of each
        shell prefixed by the shell when there are several, faces, volumes and regions summed.

    Raises
    ------
    MeshError
        When a shell fails preprocessing (naming the shell).
    """
    from meshsom.preprocess import PreprocessParams, Result, preprocess
    from meshsom.time_limit import check as check_time

    params = params or PreprocessParams()
    results = []
    for k, (v, f) in enumerate(shells):
        name = source if len(shells) == 1 else f"{source} shell {k + 1} of {len(shells)}"
        check_time(f"preprocessing shell {k + 1} of {len(shells)} ({len(f)} faces)")
        try:
            results.append(preprocess(v, f, params, source=name))
            continue
        except MeshError as err:
            problem = err.problem
        kept = None
        if problem.startswith("non-manifold"):  # where solids touch, the union gives each its own vertices: kept apart
            try:
                kept = preprocess(v, f, params, source=name, weld_vertices=False)
            except MeshError:
                pass
        if kept is None:
            raise MeshError(source, problem if len(shells) == 1 else f"shell {k + 1} of {len(shells)}: {problem}")
        results.append(replace(kept, repairs=["kept the union's vertices apart where its solids touch (welding them "
                                              "made edges of more than two faces)", *kept.repairs]))
    offsets = np.concatenate([[0], np.cumsum([len(r.vertices) for r in results])]).astype(np.int64)
    repairs = [r if len(results) == 1 else f"shell {k + 1}: {r}" for k, res in enumerate(results) for r in res.repairs]
    return Result(
        vertices=np.concatenate([r.vertices for r in results]),
        faces=np.concatenate([r.faces + offsets[k] for k, r in enumerate(results)]).astype(np.int64),
        repairs=repairs,
        faces_in=sum(r.faces_in for r in results),
        faces_out=sum(r.faces_out for r in results),
        volume_in=sum(r.volume_in for r in results),
        volume_out=sum(r.volume_out for r in results),
        regions=sum(r.regions for r in results),
    )
