"""Mesh preprocessing (DESIGN.md §2): weld, clean, close, orient, flatten, re-triangulate, validate.

One function, :func:`preprocess`, turns a raw triangle soup into a closed, edge-manifold,
outward-oriented mesh whose planar regions are re-triangulated from their corner vertices only
(constrained Delaunay, no Steiner points), so that a wall is two triangles however finely it
was modelled. Each step that changes the input beyond re-triangulation is recorded in
``Result.repairs``; an input that cannot be made valid raises :class:`~meshsom.errors.MeshError`
whose ``problem`` is the reason written to the manifest.

Steps
-----
1. Check coordinates (finite) and indices (in range).
2. Weld vertices closer than ``weld_tol`` x bounding-box diagonal (KD-tree pairs + connected
   components); drop faces that collapse, and duplicate faces (a pair walked in opposite directions
   is an internal wall between merged parts and goes altogether).
3. Optionally cap open boundary loops that are planar (LoD1 blocks often miss their floor; a
   polygon dropped by a reader leaves a planar hole), after splitting T-junctions and zipping
   cracks where the loops do not close. Where the mesh is still open, T-junctions whose vertex is
   up to ``zip_tol`` metres off its edge (coordinates rounded to a file's grid) are split and the
   capping runs again; where it is closed but an edge has more than two faces, fins that a cap
   doubled are removed, then edges where two solids touch are split apart (each solid keeps its
   own copy of the edge). Any other open boundary, or an edge with more than two faces, rejects
   the mesh (after an optional pymeshlab repair).
4. Orient every face consistently (parity components of the dual graph), then each shell outward
   (positive signed volume).
4a. Clean folds: collapse edges shorter than ``min_edge_length`` metres (every chain of short
   edges becomes one vertex at its centroid), then repair zero-thickness parts that pass the
   closed-and-oriented checks (a fold angle within ``flat_fold_deg`` of 0 or 2 pi): exact fins and
   pairs of faces folded flat onto each other lose their coplanar, opposite-facing overlap; what
   remains (fins and caps that overlap only partly, thin spikes and notches a few millimetres
   wide) is rebuilt by manifold3d with ``fold_repair_tol`` metres of tolerance, which collapses
   features thinner than that. The mesh must stay closed, edge-manifold and oriented, with its
   volume within ``volume_rtol`` and no fold left near 0/2 pi; a mesh that no repair makes so is
   rejected with the reason.
5. Planar regions: edge-connected faces whose normals agree within ``planar_angle_deg`` and whose
   vertices lie within ``planar_dist`` x diagonal of the region's plane. A region boundary vertex is
   kept if it is a corner (or a pinch) in at least one region it touches; otherwise it is collinear
   everywhere and dropped, from every region at once, so no T-junction can appear.
6. Re-triangulate each region from its kept boundary vertices (outer ring and holes). A region that
   cannot be (not planar within tolerance, pinched boundary, failed triangulation) keeps its input
   triangles, and its vertices are then kept by all neighbours.
6a. Tall folds: an edge of at most ``max_collapse_length`` metres with a fold of ``v`` above
   ``max_fold_v`` (a jog of a few centimetres beside walls and roofs metres long) is collapsed,
   each chain of such edges to the point that keeps the enclosed volume, and the mesh is
   re-triangulated (a few rounds); a collapse that breaks the mesh or moves its volume is not made.
7. Validate: closed, edge-manifold, consistently oriented, no degenerate face, volume unchanged
   within ``volume_rtol``. If re-triangulation broke any of these, the cleaned input triangulation
   is kept instead (recorded); if that fails too, the mesh is rejected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from meshsom.errors import MeshError
from meshsom.time_limit import check as check_time
from meshsom.polygons import newell_normal, plane_frame, plane_frames, triangulate_polygon_2d, triangulate_rings_2d
from meshsom.topology import edge_table, half_edges, signed_volume

__all__ = ["PreprocessParams", "Result", "cavity_shells", "check_input", "close_surface", "preprocess", "validate", "weld"]

#: Largest bounding-box diagonal taken: squared face areas (diagonal^4) and volumes (diagonal^3
#: summed over faces) stay far from float64 overflow (1.8e308).
MAX_DIAGONAL = 1e60


#: Edges with more faces than this are left out when :func:`_keep_one_side` joins the faces of a
#: plane into regions (a two-sided surface has four on an edge; a pile of faces is not one).
MAX_FACES_PER_EDGE = 8
#: Share of a mesh's area in faces modelled on both sides above which :func:`_keep_one_side` takes
#: it for a two-sided export and keeps one side (below, they are walls between parts).
TWO_SIDED_SHARE = 0.9
#: Most flat folds :func:`_flip_or_collapse_flat_folds` takes on, and most flat folds times faces:
#: each candidate change is checked on the whole mesh, so its time grows as folds^2 x faces (27
#: folds of 294 faces, the most on the bundled data and Delfshaven: 2.9 s; the union of a BIM
#: model's roof members, 162 of 1,700: minutes; a steel frame's 7 in 14,600: 20 s). Past either,
#: manifold3d's rebuild is the repair.
MAX_LOCAL_FOLD_REPAIRS = 32
MAX_LOCAL_FOLD_WORK = 250_000


@dataclass(frozen=True)
class PreprocessParams:
    """Tolerances and switches of :func:`preprocess` (config section ``preprocess``).

    Attributes
    ----------
    weld_tol : float
        Vertices closer than this fraction of the bounding-box diagonal are merged.
    tjunction_tol : float
        An open edge is split at an open-boundary vertex closer than this fraction of the diagonal
        to it (T-junctions left by modelling tools).
    planar_angle_deg : float
        Largest angle between the normals of two adjacent faces of one planar region.
    planar_dist : float
        Largest distance of a region's vertex from the region's plane, and of a dropped collinear
        vertex from the line through its neighbours, as a fraction of the diagonal.
    volume_rtol : float
        Largest relative change of the enclosed volume allowed by re-triangulation.
    retriangulate : bool
        Re-triangulate planar regions (False keeps the cleaned input triangles).
    flatten_collinear : bool
        Drop boundary vertices that are collinear in every region they touch.
    cap_planar_holes : bool
        Close open boundary loops that are planar (missing floors, missing polygons).
    repair : bool
        Try pymeshlab's non-manifold and hole repairs before rejecting a mesh.
    min_faces : int
        Meshes with fewer faces after cleaning are rejected.
    min_height_kept : float
        The share of its input's height a cleaned mesh must keep (default 0.5): an open roof with a fragment of wall
        (a 3dfier house whose party walls are missing) capped into a slab a few centimetres thick is refused (then
        rebuilt under its roofs), not accepted as a building; 0: no check.
    min_edge_length : float
        Edges shorter than this, in metres (absolute, not relative to the diagonal), are collapsed
        before re-triangulation (default 0.01: a centimetre, below the precision of city models;
        such an edge beside a face tens of metres long gives folds with ``v`` in the thousands).
        0 disables the collapse.
    flat_fold_deg : float
        Fold angles within this many degrees of 0 or 2 pi are zero-thickness fins, faces folded
        flat onto each other, thin spikes or notches: they are repaired (exactly coplanar,
        overlapping, opposite faces removed; otherwise the mesh rebuilt by manifold3d with
        ``fold_repair_tol``) or the mesh is rejected when no repair removes them (default 1.0; no
        accepted mesh has such a fold). 0 disables the check and the repairs.
    fold_repair_tol : float
        Tolerance in metres (absolute) of manifold3d's rebuild of a mesh with flat folds
        (``Manifold.set_tolerance``): vertices, edges and slivers closer than this are merged,
        so a spike or notch thinner than this near its tip, or a partly overlapping fin, goes
        (default 0.01, as ``min_edge_length``). 0 disables the rebuild.
    union_snap_tol : float
        Before a building's parts are united, in metres (absolute): a part's vertex this close in plan to
        another part's wall (its foot line) is moved onto that line, so that walls meant as one (an
        OpenStreetMap part whose corner was drawn a millimetre off its building's outline) are one plane,
        not two planes a hundredth of a degree apart that leave a crevice in the union (default 0.01:
        a centimetre, below the precision of city models; 0: off).
    max_fold_v : float
        After re-triangulation, an edge with a fold whose ``v`` exceeds this (the neighbour's apex
        more than this many edge lengths from the edge: a jog of a few centimetres in a wall tens
        of metres long, a crease split a centimetre from its end, the short diagonal of a sliver)
        is collapsed, if no longer than ``max_collapse_length``, each chain of such edges to the
        point that keeps the enclosed volume (or to the corner of the planes around it), and the
        mesh re-triangulated; a collapse that would leave the mesh invalid, with flat folds or
        outside ``volume_rtol`` is not made (default 100: the corpus's ``v`` tail, which stretches
        the standardization, ends there). 0 disables it.
    max_collapse_length : float
        Longest edge, in metres (absolute), that ``max_fold_v`` collapses (default 0.5: a jog of
        half a metre is a real feature of a building, however tall).
    zip_tol : float
        Open-boundary vertices closer than this, in metres (absolute), are merged where the mesh
        is still open after capping and T-junction splitting, and the closing runs again: the
        cracks a millimetre wide that coordinates rounded to a file's grid leave between a wall
        and its neighbour (default 0.002). Kept only where it closes more than it opens. Where the
        mesh is still open after that, an open edge is split at an open-boundary vertex within this
        distance of it (a T-junction whose vertex the rounding moved off the edge by more than
        ``tjunction_tol``), and the closing runs again. 0 disables both.
    roof_envelope : bool
        A mesh that cannot be closed otherwise (nor united from its parts) is rebuilt as the solid
        under its roofs, down to its lowest vertex (:mod:`meshsom.envelope`: LoD2 roof models
        whose walls stop at the terrain, whose parts' walls overlap, whose roofs do not quite
        meet), and the manifest says so and why (default True). False: such a mesh is rejected.
    wall_tilt_deg : float
        For ``roof_envelope``: faces within this many degrees of vertical are walls, not roofs
        (default 5).
    envelope_tol : float
        For ``roof_envelope``, in metres (absolute): roof vertices closer than this in plan are
        snapped together, a roof vertex this close to another roof's edge splits it, and shells
        thinner than this on average are dropped as slivers (default 0.002, as ``zip_tol``).
    envelope_max_loss : float
        For ``roof_envelope``: walls standing outside every roof in plan are lost by the rebuild
        (a wall 15 cm outside its roof's eave, as where walls come from a cadastre and roofs from
        lidar; a part with no roof). What they would lose (each wall's area times its distance
        outside, an estimate) may be at most this fraction of the rebuilt volume; more, and the
        rebuild is refused (default 0.01).
    envelope_max_roofs : int
        For ``roof_envelope``: a mesh with more roof triangles above its floor than this, or whose
        roof triangles split where they meet make more prisms than this, is not rebuilt (0: no
        limit; default 2000). Roof models give hundreds: at most 511 prisms in the 27 rebuilt
        buildings of Zürich's LoD2 subset, 411 in Delfshaven's 86, 859 in Ingolstadt's LoD3
        buildings (the most rebuilt); the meshes over 2,000 took minutes and were refused anyway
        (Ingolstadt 4018154, 2,016 prisms, 110 s; a 3DCityDB COLLADA LoD3 model, 2,731, 106 s), a
        scanned mesh of 66,000 triangles has 28,000.
    envelope_max_pieces : int
        For ``roof_envelope``: where the first way of uniting the prisms falls into more separate
        pieces than this and preprocessing refuses it, no other way is tried (each costs a union):
        a roof model's union is one piece or a few (at most 21 in Zürich's and Delfshaven's 902
        buildings), a tree crown's a hundred and more (Cesium's 3D Tiles samples); 0: no limit
        (default 64).
    envelope_max_seconds : float
        For ``roof_envelope``: wall-clock seconds the rebuild under the roofs may take, all its ways
        of uniting together (:func:`meshsom.envelope.rebuild_under_roofs`, within ``max_seconds``);
        past it, or where the next way would not end within it, the mesh is rejected ("rebuilding
        it as the solid under its roofs took more than N s"). The slowest rebuild measured took 18 s
        (an Ingolstadt LoD3 building, 859 prisms, on 2 shared cores); Zürich's and Delfshaven's
        take at most 0.6 s; 0: no limit (default 90).
    max_seconds : float
        Wall-clock seconds one mesh's preprocessing may take, its union of parts and its rebuild
        under the roofs included (:mod:`meshsom.time_limit`, checked at each repair round, cut
        search and union attempt); past it the mesh is rejected with the stage it stopped in. The
        bundled corpora take at most a few seconds a building; 0: no limit (default 300).
    """

    weld_tol: float = 1e-8
    tjunction_tol: float = 1e-5
    planar_angle_deg: float = 1.0
    planar_dist: float = 1e-4
    volume_rtol: float = 1e-3
    retriangulate: bool = True
    flatten_collinear: bool = True
    cap_planar_holes: bool = True
    repair: bool = False
    min_faces: int = 4
    min_height_kept: float = 0.5
    min_edge_length: float = 0.01
    flat_fold_deg: float = 1.0
    fold_repair_tol: float = 0.01
    union_snap_tol: float = 0.01
    max_fold_v: float = 100.0
    max_collapse_length: float = 0.5
    zip_tol: float = 0.002
    roof_envelope: bool = True
    wall_tilt_deg: float = 5.0
    envelope_tol: float = 0.002
    envelope_max_loss: float = 0.01
    envelope_max_roofs: int = 2000
    envelope_max_pieces: int = 64
    envelope_max_seconds: float = 90.0
    max_seconds: float = 300.0

    def __post_init__(self):
        for name in ("weld_tol", "tjunction_tol", "planar_dist", "volume_rtol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 <= value < 1):
                raise ValueError(f"{name} must be a number in [0, 1) (a fraction of the diagonal); received {value!r}")
        if not (isinstance(self.planar_angle_deg, (int, float)) and 0 <= self.planar_angle_deg < 90):
            raise ValueError(f"planar_angle_deg must be in [0, 90); received {self.planar_angle_deg!r}")
        if not (isinstance(self.min_edge_length, (int, float)) and 0 <= self.min_edge_length < math.inf):
            raise ValueError(f"min_edge_length must be a finite number >= 0 (metres); received {self.min_edge_length!r}")
        if not (isinstance(self.fold_repair_tol, (int, float)) and 0 <= self.fold_repair_tol < math.inf):
            raise ValueError(f"fold_repair_tol must be a finite number >= 0 (metres); received {self.fold_repair_tol!r}")
        if not (isinstance(self.wall_tilt_deg, (int, float)) and 0 <= self.wall_tilt_deg < 90):
            raise ValueError(f"wall_tilt_deg must be in [0, 90) degrees; received {self.wall_tilt_deg!r}")
        for name in ("max_fold_v", "max_collapse_length", "zip_tol", "envelope_tol", "union_snap_tol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 <= value < math.inf):
                raise ValueError(f"{name} must be a finite number >= 0 (0 disables it); received {value!r}")
        if not (isinstance(self.envelope_max_loss, (int, float)) and 0 <= self.envelope_max_loss < 1):
            raise ValueError(f"envelope_max_loss must be a number in [0, 1) (a fraction of the rebuilt volume); "
                             f"received {self.envelope_max_loss!r}")
        for name in ("envelope_max_roofs", "envelope_max_pieces"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
                raise ValueError(f"{name} must be an integer >= 0 (0: no limit); received {value!r}")
        for name in ("envelope_max_seconds", "max_seconds"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value < math.inf):
                raise ValueError(f"{name} must be a finite number >= 0 (0: no limit); received {value!r}")
        if not (isinstance(self.flat_fold_deg, (int, float)) and 0 <= self.flat_fold_deg < 90):
            raise ValueError(f"flat_fold_deg must be in [0, 90) degrees; received {self.flat_fold_deg!r}")
        if not (isinstance(self.min_faces, int) and self.min_faces >= 4):
            raise ValueError(f"min_faces must be an integer >= 4 (a tetrahedron); received {self.min_faces!r}")
        if not (isinstance(self.min_height_kept, (int, float)) and not isinstance(self.min_height_kept, bool)
                and 0 <= self.min_height_kept <= 1):
            raise ValueError(f"min_height_kept must be a number in [0, 1]; received {self.min_height_kept!r}")


@dataclass
class Result:
    """A preprocessed mesh.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        Closed, edge-manifold, counter-clockwise seen from outside.
    repairs : list of str
        What was changed beyond re-triangulation, in words.
    faces_in, faces_out : int
    volume_in, volume_out : float
        Enclosed volume of the cleaned input and of the output.
    regions : int
        Number of planar regions.
    """

    vertices: np.ndarray
    faces: np.ndarray
    repairs: list[str] = field(default_factory=list)
    faces_in: int = 0
    faces_out: int = 0
    volume_in: float = 0.0
    volume_out: float = 0.0
    regions: int = 0


# --------------------------------------------------------------------------------------------
# Public entry point
# --------------------------------------------------------------------------------------------


def preprocess(
    vertices: np.ndarray, faces: np.ndarray, params: PreprocessParams | None = None, source: str = "mesh",
    weld_vertices: bool = True,
) -> Result:
    """Clean, close, orient and re-triangulate one mesh.

    Parameters
    ----------
    vertices : (V, 3) float64
        Re-centred coordinates.
    faces : (F, 3) int64
    params : PreprocessParams, optional
    source : str
        Named in errors (file and object id).
    weld_vertices : bool
        Weld vertices closer than the tolerance (default). False where the faces' vertex indices are the topology
        already (a boolean union's output: solids touching along an edge or at a corner keep vertices of their own
        there, which welding would join into edges of four faces).

    Returns
    -------
    Result

    Raises
    ------
    MeshError
        With a reason that says what is wrong (``problem``), when the mesh cannot be made valid.
    """
    params = params or PreprocessParams()
    vertices, faces = check_input(vertices, faces, source)
    faces_in = len(faces)
    repairs: list[str] = []
    check_time("cleaning and closing")
    try:
        v, f = _clean(vertices, faces, params, source, repairs, weld_vertices)
    except MeshError:
        if not params.repair:
            raise
        v, f = _pymeshlab_repair(vertices, faces, source)
        repairs = ["repaired with pymeshlab (non-manifold edges, holes)"]
        v, f = _clean(v, f, PreprocessParams(**{**params.__dict__, "repair": False}), source, repairs)
    volume_in = signed_volume(v, f)
    diag = _diagonal(v)
    if not volume_in > params.weld_tol * diag**3:  # thinner than the weld tolerance
        raise MeshError(source, f"zero volume: it encloses {volume_in:.3g} cubic units, not more than "
                                f"{params.weld_tol * diag**3:.3g} (weld_tol x its {diag:.3g} diagonal cubed): a sliver, "
                                f"a spike or faces folded onto each other{_far_vertices(v[np.unique(f)])}")
    check_time("cleaning folds")
    v, f = _clean_folds(v, f, params, diag, volume_in, source, repairs)
    check_time("re-triangulating")
    regions = 0
    out_v, out_f = v, f
    if params.retriangulate:
        try:
            out_v, out_f, regions = _retriangulate(v, f, params, diag)
            problem = validate(out_v, out_f)
            vol = signed_volume(out_v, out_f)
            if problem is None and abs(vol - volume_in) > params.volume_rtol * abs(volume_in):
                problem = f"volume changed by {100 * abs(vol - volume_in) / abs(volume_in):.3g} %"
        except MeshError as err:  # pragma: no cover - defensive: fall back to the cleaned input
            problem = err.problem
        if problem is not None:
            repairs.append(f"kept the input triangulation (re-triangulation gave: {problem})")
            out_v, out_f, regions = v, f, 0
        else:
            out_v, out_f, regions = _collapse_tall_folds(out_v, out_f, regions, params, diag, volume_in, repairs)
    problem = validate(out_v, out_f)
    if problem is not None:
        raise MeshError(source, problem)
    problem = _flat_fold_problem(out_v, out_f, params)
    if problem is not None:  # pragma: no cover - re-triangulation keeps planes; defensive
        raise MeshError(source, f"after re-triangulation: {problem}")
    out_v, out_f = _compact(out_v, out_f)
    if len(out_f) < params.min_faces:
        raise MeshError(source, f"only {len(out_f)} faces after cleaning; at least {params.min_faces} needed")
    height_in = float(np.ptp(vertices[np.unique(faces), 2]))
    height_out = float(np.ptp(out_v[:, 2]))
    if height_out < params.min_height_kept * height_in:
        raise MeshError(source, f"closed only as a slab {height_out:.3g} m high of its {height_in:.3g} m (its walls "
                                f"open: a roof and fragments capped), less than preprocess.min_height_kept "
                                f"({params.min_height_kept:g}) of its height")
    return Result(
        vertices=out_v, faces=out_f, repairs=repairs, faces_in=faces_in, faces_out=len(out_f),
        volume_in=volume_in, volume_out=signed_volume(out_v, out_f), regions=regions,
    )


def close_surface(vertices: np.ndarray, faces: np.ndarray, params: PreprocessParams | None = None,
                  source: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Steps 1-4 of :func:`preprocess` alone: weld, drop bad faces, close what can safely be closed,
    orient outwards; no fold cleaning, no re-triangulation (the solids of a boolean union).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    params : PreprocessParams, optional
        Tolerances (default ``PreprocessParams()``).
    source : str
        Named in errors.

    Returns
    -------
    vertices : (W, 3) float64
    faces : (G, 3) int64
        Closed, edge-manifold, outward-oriented.

    Raises
    ------
    MeshError
        When it cannot be closed so.
    """
    params = params or PreprocessParams()
    vertices, faces = check_input(vertices, faces, source)
    return _clean(vertices, faces, params, source, [])


def validate(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """Why a mesh is not a valid closed one, or None when it is.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64

    Returns
    -------
    problem : str or None
    """
    if len(faces) == 0:
        return "no faces"
    if (faces[:, 0] == faces[:, 1]).any() or (faces[:, 1] == faces[:, 2]).any() or (faces[:, 0] == faces[:, 2]).any():
        return "degenerate faces (repeated vertex)"
    area2 = np.linalg.norm(_cross(vertices, faces), axis=1)
    if not (area2 > 0).all():
        return f"{int((area2 <= 0).sum())} degenerate faces of zero area"
    he = half_edges(faces)
    _, edge_of, counts = edge_table(faces)
    if (counts == 1).any():
        return f"open boundary: {int((counts == 1).sum())} edges have only one face"
    if (counts > 2).any():
        return f"non-manifold: {int((counts > 2).sum())} edges are shared by more than two faces"
    order = np.argsort(edge_of, kind="stable").reshape(-1, 2)
    if not np.array_equal(he[order[:, 0], 0], he[order[:, 1], 1]):
        return "inconsistently oriented faces"
    if signed_volume(vertices, faces) <= 0:
        return "oriented inward (negative volume)"
    return None


def weld(vertices: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices closer than ``tol`` (absolute), transitively.

    Parameters
    ----------
    vertices : (V, 3) float64
    tol : float

    Returns
    -------
    welded : (W, 3) float64
        One representative (the lowest input index) per group, in order of first appearance.
    remap : (V,) int64
        New index of every input vertex.
    """
    n = len(vertices)
    if n == 0:
        return vertices, np.zeros(0, np.int64)
    pairs = cKDTree(vertices).query_pairs(tol, output_type="ndarray") if tol > 0 else np.zeros((0, 2), np.int64)
    if tol == 0 or len(pairs) == 0:
        _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
        labels = inverse.reshape(-1)
    else:
        graph = sparse.coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
    first = np.full(labels.max() + 1, n, np.int64)
    np.minimum.at(first, labels, np.arange(n))
    rank = np.empty(len(first), np.int64)
    order = np.argsort(first, kind="stable")
    rank[order] = np.arange(len(first))
    return vertices[first[order]], rank[labels]


# --------------------------------------------------------------------------------------------
# Steps
# --------------------------------------------------------------------------------------------


def check_input(vertices, faces, source: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """``vertices`` (V, 3) float64 and ``faces`` (F, 3) int64, checked: shapes, at least one face,
    finite coordinates, a diagonal below :data:`MAX_DIAGONAL`, indices in range.

    Raises
    ------
    MeshError
        Naming ``source`` and what is wrong.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(source, f"vertices must have shape (V, 3), received {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(source, f"faces must have shape (F, 3) (triangles), received {faces.shape}")
    if len(faces) == 0:
        raise MeshError(source, "no faces")
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise MeshError(source, f"{bad} vertices have NaN or infinite coordinates")
    diag = _diagonal(vertices)
    if not diag <= MAX_DIAGONAL:
        raise MeshError(source, f"bounding-box diagonal {diag:.3g} is larger than {MAX_DIAGONAL:.0e} (volumes would overflow float64)")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        k = int(np.flatnonzero((faces < 0).any(axis=1) | (faces >= len(vertices)).any(axis=1))[0])
        raise MeshError(source, f"face {k} references vertex index {faces[k].tolist()} out of range (the mesh has {len(vertices)} vertices)")
    used = vertices[np.unique(faces)]
    centred = used - used.mean(axis=0)
    axes = np.linalg.eigh(centred.T @ centred)[1][:, ::-1].T  # (3, 3) whatever the count: an SVD of (V, 3) with
    extent = np.ptp(centred @ axes.T, axis=0)  # full matrices made (V, V); across its principal axes, longest first
    if not extent[2] > min(FLAT_SHEET_THICKNESS * extent[1], FLAT_SHEET_MAX_THICKNESS):
        raise MeshError(source, _flat_sheet(vertices, faces))
    return vertices, faces


#: A mesh whose vertices all lie within this fraction of its width (its second principal extent) of one plane is a
#: surface, not a solid (:func:`check_input`): a tilted polygon on a file's millimetre grid is off its plane by under
#: a millimetre, while a wall 10 cm thick would have to be 100 m high to come this close. Compared with the width, not
#: the length: a needle (a floor read 2,147 km below its roof) is no plane.
FLAT_SHEET_THICKNESS = 1e-3
#: ... and within this many metres of it: a footprint 10 km across (osm-testdata's multipolygons) extruded 10 m is
#: thinner than FLAT_SHEET_THICKNESS of its width, and still a solid.
FLAT_SHEET_MAX_THICKNESS = 0.01


def _flat_sheet(vertices: np.ndarray, faces: np.ndarray) -> str:
    """What a mesh of faces in one plane is, in words: its polygons (the union of its faces in their plane), their
    area and the plane's tilt."""
    import shapely

    points = vertices[faces]
    centred = points.reshape(-1, 3) - points.reshape(-1, 3).mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    plan = (centred @ plane_frame(normal).T).reshape(-1, 3, 2)
    triangles = shapely.polygons(plan)
    cover = shapely.union_all(triangles[shapely.area(triangles) > 0])
    pieces = len(shapely.get_parts(cover)) if not cover.is_empty else 0
    tilt = math.degrees(math.acos(min(1.0, abs(float(normal[2])))))
    if not pieces:
        return f"its {len(faces)} faces have no area (they lie on a line or at a point), not a solid (zero volume)"
    what = "one planar polygon" if pieces == 1 else f"{pieces} planar polygons"
    return (f"{what} of {cover.area:.4g} square units, not a solid: its {len(faces)} faces lie in one plane "
            f"({tilt:.3g} degrees from horizontal; zero volume)")


#: How far from the others, in robust spreads (the median distance to the median, plus a metre), a vertex lies when it
#: is no part of the building: a no-data value written as a coordinate (roofer's ground height of -2^31 mm).
FAR_VERTEX_SPREADS = 1000.0


def _far_vertices(v: np.ndarray) -> str:
    """A clause naming the vertices of ``v`` (V, 3) that lie far from the rest, per axis (:data:`FAR_VERTEX_SPREADS`),
    where there are such; else ``""``."""
    median = np.median(v, axis=0)
    spread = np.median(np.abs(v - median), axis=0) + 1.0
    far = np.abs(v - median) > FAR_VERTEX_SPREADS * spread
    if not far.any():
        return ""
    axis = int(np.argmax(far.sum(axis=0)))
    rest = v[~far.any(axis=1), axis]
    worst = v[far[:, axis], axis]
    gap = float(np.max(np.maximum(rest.min() - worst, worst - rest.max())))
    return (f"; {int(far.any(axis=1).sum())} of its {len(v)} vertices lie up to {gap:.3g} units from the others in "
            f"{'xyz'[axis]}, which span {np.ptp(rest):.3g}: a no-data value written as a coordinate?")


def _diagonal(vertices):
    if len(vertices) == 0:
        return 0.0
    with np.errstate(over="ignore"):
        return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


def _cross(vertices, faces):
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


def _clean(vertices, faces, params, source, repairs, weld_vertices: bool = True):
    """Steps 2-4: weld (unless ``weld_vertices`` is False), drop bad faces, cap, check manifoldness, orient. Returns
    (V, F)."""
    diag = _diagonal(vertices)
    if diag == 0:
        raise MeshError(source, "all vertices coincide (zero size)")
    thickness = _thickness(vertices[np.unique(faces)])
    if thickness <= params.weld_tol * diag and len(np.unique(np.sort(faces, axis=1), axis=0)) >= params.min_faces:
        raise MeshError(source, f"zero volume: it is flat, all its vertices in one plane (within {thickness:.3g} of a "
                                f"{diag:.3g} diagonal): a footprint or a single surface, not a solid")
    v, remap = weld(vertices, params.weld_tol * diag) if weld_vertices else (vertices, np.arange(len(vertices)))
    if len(v) < len(vertices):
        merged = len(vertices) - len(v)
        # Exact duplicates (one vertex per polygon corner, as in many OBJ exports) are not news.
        exact = len(vertices) - len(np.unique(vertices, axis=0))
        if merged > exact:
            repairs.append(f"welded {merged - exact} near-coincident vertices")
    f = remap[faces]
    collapsed = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    # Slivers: a vertex within the weld tolerance of the opposite edge's line (zero area). Dropping
    # one leaves a T-junction that _split_t_junctions closes again.
    longest = np.max(np.linalg.norm(v[np.roll(f, -1, axis=1)] - v[f], axis=2), axis=1)
    height = np.linalg.norm(_cross(v, f), axis=1) / np.where(longest > 0, longest, 1.0)
    collapsed |= height <= params.weld_tol * diag
    if collapsed.any():
        repairs.append(f"dropped {int(collapsed.sum())} degenerate faces")
        f = f[~collapsed]
    f, hull_side = _keep_one_side(v, f, params, repairs)
    if hull_side is None:
        return _close(v, f, params, source, repairs)
    # partly two-sided: walls between parts first (as before), then those surfaces' hull side
    trial_repairs = list(repairs)
    try:
        w, g = _close(v, f, params, source, trial_repairs)
        if signed_volume(w, g) > params.weld_tol * diag**3:
            repairs[:] = trial_repairs
            return w, g
        first_problem = MeshError(source, "zero volume")
    except MeshError as err:
        first_problem = err
    g, note = hull_side
    trial_repairs = [*repairs, note]
    try:
        w, g = _close(v, g, params, source, trial_repairs)
    except MeshError:
        raise first_problem from None
    repairs[:] = trial_repairs
    return w, g


def _close(v, f, params, source, repairs):
    """Steps 3-4 of :func:`_clean` on welded faces ``f``: drop duplicates, cap, close, orient."""
    diag = _diagonal(v)
    f = _drop_duplicates(f, repairs)
    if len(f) < params.min_faces:
        raise MeshError(source, f"only {len(f)} faces after cleaning; at least {params.min_faces} needed")
    _, _, counts = edge_table(f)
    if (counts == 1).any() and params.cap_planar_holes:
        f = _cap_planar_loops(v, f, params.planar_dist * diag, repairs)
        _, _, counts = edge_table(f)
    for tol in sorted({params.weld_tol, params.tjunction_tol}):
        if not (counts == 1).any():
            break
        # Still open: T-junctions (left by slivers first, then by modelling tools) and overlapping
        # walls (footprint spikes); then cap again.
        trial_repairs = list(repairs)
        g = _split_t_junctions(v, f, tol * diag, trial_repairs)
        g, c = _fins_then_caps(v, _drop_duplicates(g, trial_repairs), params, diag, trial_repairs)
        if _fewer_bad_edges(c, counts):
            f, counts, repairs[:] = g, c, trial_repairs
    if (counts == 1).any() and params.zip_tol > 0:
        # still open: cracks between open vertices a rounding apart, zipped; then the same again
        trial_repairs = list(repairs)
        g = _zip_cracks(v, f, params.zip_tol, trial_repairs)
        if g is not None:
            g = _split_t_junctions(v, g, params.tjunction_tol * diag, trial_repairs)
            g, c = _fins_then_caps(v, _drop_duplicates(g, trial_repairs), params, diag, trial_repairs, fins=False)
            if len(g) >= params.min_faces and _fewer_bad_edges(c, counts):
                f, counts, repairs[:] = g, c, trial_repairs
    if (counts == 1).any() and params.zip_tol > 0:
        # still open: T-junctions whose vertex a rounding to the file's grid put off the edge by more
        # than tjunction_tol (a millimetre beside a wall ten metres long), split within zip_tol
        trial_repairs = list(repairs)
        g = _split_t_junctions(v, f, params.zip_tol, trial_repairs)
        if len(trial_repairs) > len(repairs):  # else nothing to split, and capping fails again
            trial_repairs[-1] += f" within {params.zip_tol:g} m of their edge (rounded coordinates)"
            g, c = _fins_then_caps(v, _drop_duplicates(g, trial_repairs), params, diag, trial_repairs)
            if len(g) >= params.min_faces and _fewer_bad_edges(c, counts):
                f, counts, repairs[:] = g, c, trial_repairs
    if (counts > 2).any() and not (counts == 1).any():
        # closed, but edges with four (six...) faces: fins that a cap doubled, then solids touching
        # along an edge (split apart, so each keeps its own copy of the edge)
        trial_repairs = list(repairs)
        g, c = _fins_then_caps(v, _remove_fins(v, f, params.planar_dist * diag, trial_repairs), params, diag,
                               trial_repairs, fins=False)
        w = v
        if (c > 2).any() and not (c == 1).any():
            split = _split_touching_edges(v, g, trial_repairs)
            if split is not None:
                w, g = split
                _, _, c = edge_table(g)
        if len(g) >= params.min_faces and not (c == 1).any() and not (c > 2).any():
            v, f, counts, repairs[:] = w, g, c, trial_repairs
    if (counts > 2).any():
        raise MeshError(source, f"non-manifold: {int((counts > 2).sum())} edges are shared by more than two faces")
    if (counts == 1).any():
        raise MeshError(source, f"open boundary: {int((counts == 1).sum())} edges have only one face (a hole that is not planar)")
    f = _orient(v, f, source, repairs)
    return _compact(v, f)


def _fins_then_caps(v, g, params, diag, repairs, fins: bool = True):
    """``g`` with its zero-thickness fins removed (``fins``; where an edge has more than two faces)
    and its planar holes capped (where it is open); and its edge counts.

    Returns
    -------
    g : (F, 3) int64
    counts : (E,) int64
        Faces per edge of ``g`` (:func:`meshsom.topology.edge_table`).
    """
    _, _, c = edge_table(g)
    if fins and (c > 2).any():
        g = _remove_fins(v, g, params.planar_dist * diag, repairs)
        _, _, c = edge_table(g)
    if (c == 1).any() and params.cap_planar_holes:
        g = _cap_planar_loops(v, g, params.planar_dist * diag, repairs)
        _, _, c = edge_table(g)
    return g, c


def _fewer_bad_edges(c: np.ndarray, counts: np.ndarray) -> bool:
    """Whether edge counts ``c`` have fewer open or non-manifold edges than ``counts``."""
    return bool((c == 1).sum() + (c > 2).sum() < (counts == 1).sum() + (counts > 2).sum())


def _keep_one_side(v, f, params, repairs):
    """One side of a two-sided mesh: one where planar regions of faces holding at least
    :data:`TWO_SIDED_SHARE` of its area each have a twin over the same vertices facing the other
    way, as modelling tools export "two-sided" faces (each face again, reversed, often triangulated
    along the other diagonal). Every face would go as a wall walked both ways
    (:func:`_drop_duplicates`) or leave every edge with four faces; here each twin is dropped and
    :func:`_orient` orients the rest. A mesh with fewer such faces (the walls between the parts of
    a building) is left to :func:`_drop_duplicates`.

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
        Welded, without degenerate faces.

    Returns
    -------
    f : (F', 3) int64
    hull_side : tuple of ((F'', 3) int64, str) or None
        Where some surfaces, under :data:`TWO_SIDED_SHARE` of the area, have such a twin: the
        faces with one side kept of those on the hull (:func:`_two_sided_hull`) and a repair note,
        for :func:`_clean` to try where taking them all for walls between parts fails.
    """
    if not len(f):
        return f, None
    _, edge_of, counts = edge_table(f)
    if not (counts > 2).any() and len(np.unique(np.sort(f, axis=1), axis=0)) == len(f):
        return f, None  # no edge with more than two faces, no face twice: nothing two-sided
    cross = _cross(v, f)
    area2 = np.linalg.norm(cross, axis=1)
    normal = cross / np.where(area2 > 0, area2, 1.0)[:, None]
    # faces on one edge, in pairs (an edge of a two-sided surface has four), joined where coplanar
    order = np.argsort(edge_of, kind="stable")
    face = order // 3
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    small = counts <= MAX_FACES_PER_EDGE
    a_list, b_list = [], []
    for i in range(1, int(counts[small].max(initial=1))):
        for j in range(i):
            on = small & (counts > i)
            a_list.append(face[start[on] + j])
            b_list.append(face[start[on] + i])
    if not a_list or not area2.sum() > 0:  # no edge of two to eight faces; no area at all
        return f, None
    a, b = np.concatenate(a_list), np.concatenate(b_list)
    cos_tol = math.cos(math.radians(params.planar_angle_deg))
    join = np.einsum("ij,ij->i", normal[a], normal[b]) >= cos_tol
    n = len(f)
    graph = sparse.coo_matrix((np.ones(int(join.sum()), np.int8), (a[join], b[join])), shape=(n, n))
    n_regions, region = connected_components(graph, directed=False)
    # each region's vertex set, hashed (two random weights per vertex), and its normal
    rv = np.unique(np.stack([np.repeat(region, 3), f.reshape(-1)], axis=1), axis=0)
    weights = np.random.default_rng(0).integers(1, 2**62, (len(v), 2), dtype=np.int64)
    key = np.zeros((n_regions, 3), np.int64)
    np.add.at(key[:, 0], rv[:, 0], weights[rv[:, 1], 0])
    np.add.at(key[:, 1], rv[:, 0], weights[rv[:, 1], 1])
    key[:, 2] = np.bincount(rv[:, 0], minlength=n_regions)
    plane = np.zeros((n_regions, 3))
    np.add.at(plane, region, cross)
    plane /= np.maximum(np.linalg.norm(plane, axis=1), 1e-300)[:, None]
    _, group, sizes = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    # pairs: two regions of one vertex set facing opposite ways (a set held by more is left alone)
    two = np.flatnonzero(sizes[group] == 2)
    if not len(two):
        return f, None
    by_group = two[np.argsort(group[two], kind="stable")].reshape(-1, 2)
    first, second = by_group[:, 0], by_group[:, 1]
    pairs = np.einsum("ij,ij->i", plane[first], plane[second]) <= -cos_tol
    first, second = first[pairs], second[pairs]
    if not len(first):
        return f, None
    paired = np.zeros(n_regions, bool)
    paired[first] = paired[second] = True
    share = area2[paired[region]].sum() / area2.sum()
    if share >= TWO_SIDED_SHARE:
        gone = np.isin(region, second)
        repairs.append(f"kept one side of a two-sided mesh ({len(first)} surfaces, {100 * share:.3g} % of its "
                       f"area, also modelled facing the other way; {int(gone.sum())} faces dropped)")
        return _oriented_alike(f[~gone]), None
    # some surfaces modelled facing both ways: walls between parts (for _drop_duplicates), or
    # surfaces of the hull exported two-sided; the second reading is tried where the first fails
    hull = _two_sided_hull(v, f, region, paired, first)
    if not hull.any():
        return f, None
    gone = paired[region] & ~np.isin(region, first[hull])
    note = (f"kept one side of {int(hull.sum())} surfaces modelled facing both ways ({100 * share:.3g} % of its "
            f"area; {int(gone.sum())} faces dropped)")
    return f, (_oriented_alike(f[~gone]), note)


def _two_sided_hull(v, f, region, paired, first):
    """Which surface pairs of a partly two-sided mesh lie on its hull: where the mesh without
    every paired face leaves most of the pair's outline (by length) with fewer than two faces.
    The outline of a wall between two parts is still closed there: the parts' own walls, roofs and
    floors meet along it; a two-sided wall of the hull leaves a hole.

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
    region : (F,) int64
        Planar region of each face (:func:`_keep_one_side`).
    paired : (R,) bool
        Regions with a twin facing the other way.
    first : (P,) int64
        One region of each pair.

    Returns
    -------
    hull : (P,) bool
    """
    edges, edge_of, _ = edge_table(f)
    edge_of = edge_of.reshape(-1, 3)  # face by face
    rest = np.bincount(edge_of[~paired[region]].reshape(-1), minlength=len(edges))  # faces once pairs are gone
    mine = np.isin(region, first)
    order = np.argsort(first)
    owner = np.repeat(np.searchsorted(first[order], region[mine]), 3)  # pair of every half-edge, sorted order
    edge = edge_of[mine].reshape(-1)
    # the outline of a pair's region: its edges used once within it
    _, inverse, uses = np.unique(owner * len(edges) + edge, return_inverse=True, return_counts=True)
    outline = uses[inverse.reshape(-1)] == 1
    closed = outline & (rest[edge] >= 2)
    length = np.linalg.norm(v[edges[edge, 0]] - v[edges[edge, 1]], axis=1)
    total = np.bincount(owner[outline], length[outline], minlength=len(first))
    shut = np.bincount(owner[closed], length[closed], minlength=len(first))
    hull = np.zeros(len(first), bool)
    hull[order] = shut < 0.5 * total
    return hull


def _drop_duplicates(f, repairs):
    key = np.sort(f, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    if (counts == 1).all():
        return f
    # Orientation parity relative to the sorted key: +1 for an even permutation, -1 for odd.
    rolled = np.stack([np.roll(f, -k, axis=1) for k in range(3)])
    even = (rolled == key[None]).all(axis=2).any(axis=0)
    parity = np.where(even, 1, -1)
    net = np.zeros(len(counts), np.int64)
    np.add.at(net, inverse, parity)
    first = np.full(len(counts), len(f), np.int64)
    np.minimum.at(first, inverse, np.arange(len(f)))
    dup = counts[inverse] > 1
    keep = ~dup | ((np.arange(len(f)) == first[inverse]) & (net[inverse] != 0))
    # For a kept duplicate, use the majority orientation.
    flip = keep & dup & (np.sign(net[inverse]) != parity)
    f = f.copy()
    f[flip] = f[flip][:, ::-1]
    internal = int((dup & (net[inverse] == 0)).sum())
    dropped = int(dup.sum()) - internal - int((keep & dup).sum())
    if dropped:
        repairs.append(f"dropped {dropped} duplicate faces")
    if internal:
        repairs.append(f"removed {internal} faces of internal walls (face pairs walked both ways)")
    return f[keep]


def _cap_planar_loops(v, f, dist, repairs):
    """Close open boundary loops that are planar (missing floors, missing roof or wall polygons).

    Loops lying in one plane are capped together, so a floor with a courtyard gets its hole. A loop
    that is not planar within ``dist``, or whose polygon cannot be triangulated from its own
    vertices (self-intersecting), is left open and the mesh is then rejected.

    Where loops touch (a vertex with two open edges out) or a hole spans two planes (a row house
    whose party wall and floor are both missing: one loop, bent along the wall's bottom edge that
    no face has), the boundary is decomposed into planar loops first (:func:`_planar_loops`).

    The cap is held to :func:`validate`'s own test: the 2D triangulation works on coordinates
    rounded by the projection, where three vertices on one straight edge of the loop (exactly
    collinear in 3D) can form a triangle of tiny positive area; such a triangle has zero area in
    3D and would reject the mesh after capping. It is flipped away (:func:`_flip_flat_triangles`);
    a cap that still has one is not used.
    """
    he = half_edges(f)
    _, edge_of, counts = edge_table(f)
    directed = he[counts[edge_of] == 1]
    loops = _walk_loops(directed)
    if loops is not None and all(_off_plane(v[loop]) <= dist for loop in loops):
        cap = _cap_loops(v, loops, dist)
    else:
        edges = _edge_keys(f)
        loops = _planar_loops(v, directed, dist, edges)
        cap = _cap_loops(v, loops, dist) if loops else None
        if cap is None and loops and _has_through_chord(v, loops, directed, dist):
            # A chord through another vertex of its loop is an edge with a vertex inside it: the
            # piece beside it has a spike, which is capped only by chance. Cut without such chords.
            loops = _planar_loops(v, directed, dist, edges, through=False)
            cap = _cap_loops(v, loops, dist) if loops else None
    if cap is None:
        return f
    repairs.append(f"capped {len(loops)} open planar loop(s) with {len(cap)} triangles (missing floor or polygon)")
    return np.concatenate([f, cap])


def _cap_loops(v, loops, dist):
    """Triangles that cap the planar ``loops`` (each run the way the mesh's open edges run), or None.

    Parameters
    ----------
    v : (V, 3) float64
    loops : list of (k,) int64
        Closed loops of open edges, each planar within ``dist``.
    dist : float

    Returns
    -------
    cap : (T, 3) int64 or None
        None where some loop is not planar, has no area, or its polygon cannot be triangulated
        from its own vertices, or a triangle of zero area cannot be flipped away.
    """
    import shapely

    planes = []
    for loop in loops:
        p = v[loop]
        n = newell_normal(p - p.mean(axis=0))
        norm = np.linalg.norm(n)
        if not norm > 0:
            return None
        n = n / norm
        if np.abs((p - p.mean(axis=0)) @ n).max() > dist:
            return None
        planes.append((n, float(p.mean(axis=0) @ n)))
    # Group loops by plane (normals may point either way: loops of holes run the other way).
    group = list(range(len(loops)))
    for i in range(len(loops)):
        for j in range(i):
            ni, di = planes[i]
            nj, dj = planes[j]
            if abs(abs(ni @ nj) - 1) < 1e-9 + dist and abs(di - np.sign(ni @ nj) * dj) <= dist:
                group[i] = group[j]
                break
    caps = []
    for g in sorted(set(group)):
        members = [k for k in range(len(loops)) if group[k] == g]
        n = planes[members[0]][0]
        frame = plane_frame(n)
        origin = v[loops[members[0]][0]]
        rings = {k: (v[loops[k]] - origin) @ frame.T for k in members}
        areas = {k: _area2d(rings[k]) for k in members}
        if min(abs(a) for a in areas.values()) <= dist * dist:
            return None
        shells: list[tuple[int, list[int]]] = []
        polys = {}
        for k in sorted(members, key=lambda k: -abs(areas[k])):
            probe = shapely.Polygon(rings[k]).representative_point()
            for s_k, holes in shells:
                if polys[s_k].contains(probe):
                    holes.append(k)
                    break
            else:
                polys[k] = shapely.Polygon(rings[k])
                shells.append((k, []))
        for s_k, holes in shells:
            ids = np.concatenate([loops[s_k], *[loops[h] for h in holes]])
            _, tri = triangulate_polygon_2d(rings[s_k], [rings[h] for h in holes])
            if len(tri) != len(ids) + 2 * len(holes) - 2 or (tri >= len(ids)).any():
                return None
            # The boundary edges run a -> b in the mesh, so the cap must run b -> a: the cap
            # faces the way opposite to the loop's own orientation (fixed again by _orient).
            caps.append(ids[tri] if areas[s_k] < 0 else ids[tri][:, ::-1])
    return _flip_flat_triangles(v, np.concatenate(caps))


def _flip_flat_triangles(v, tri):
    """Replace zero-area triangles of a planar triangulation by flipping their longest edge.

    A zero-area triangle ``(p, q, m)`` whose vertex ``m`` lies on its longest edge ``p -> q``
    and the triangle ``(q, p, x)`` across that edge become ``(p, x, m)`` and ``(x, q, m)``: the
    same area, the same boundary, and positive areas unless ``x`` is on the line too (then the
    next round flips again). Only the (rare) flat triangles are visited.

    Parameters
    ----------
    v : (V, 3) float64
    tri : (T, 3) int64
        Consistently oriented triangles of one planar region.

    Returns
    -------
    tri : (T, 3) int64 or None
        Without zero-area triangles (area as :func:`validate` computes it), or None when some
        cannot be flipped away (the edge is on the region's boundary).
    """
    tri = tri.copy()
    for _ in range(len(tri)):
        flat = np.flatnonzero(~(np.linalg.norm(_cross(v, tri), axis=1) > 0))
        if len(flat) == 0:
            return tri
        t = int(flat[0])
        length = np.linalg.norm(v[np.roll(tri[t], -1)] - v[tri[t]], axis=1)
        k = int(np.argmax(length))  # longest edge: tri[t, k] -> tri[t, k+1]
        p, q, m = tri[t, k], tri[t, (k + 1) % 3], tri[t, (k + 2) % 3]
        across = np.flatnonzero(((tri == q) & (np.roll(tri, -1, axis=1) == p)).any(axis=1))
        if len(across) != 1:
            return None
        s = int(across[0])
        x = int(tri[s][(tri[s] != p) & (tri[s] != q)][0])
        tri[t], tri[s] = (p, x, m), (x, q, m)
    return None


def _zip_cracks(v, f, tol, repairs):
    """Merge open-boundary vertices closer than ``tol`` (each group into its lowest index); faces
    that collapse go. None where no two such vertices are that close.

    Only vertices on open edges move (by at most ``tol``), so a closed part of the mesh keeps its
    geometry.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    he = half_edges(f)
    _, edge_of, counts = edge_table(f)
    ends = np.unique(he[counts[edge_of] == 1])
    pairs = cKDTree(v[ends]).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return None
    n = len(ends)
    _, label = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
                                    directed=False)
    first = np.full(label.max() + 1, np.iinfo(np.int64).max)
    np.minimum.at(first, label, ends)
    remap = np.arange(len(v))
    remap[ends] = first[label]
    g = remap[f]
    collapsed = (g[:, 0] == g[:, 1]) | (g[:, 1] == g[:, 2]) | (g[:, 0] == g[:, 2])
    moved = int((remap[ends] != ends).sum())
    repairs.append(f"merged {moved} open-boundary vertices within {tol:g} m of another (cracks)"
                   + (f", dropping {int(collapsed.sum())} faces" if collapsed.any() else ""))
    return g[~collapsed]


def _split_t_junctions(v, f, tol, repairs, rounds=4):
    """Split open edges at open-boundary vertices lying on them (T-junctions), within ``tol``.

    Only boundary edges are examined (a closed mesh has none), so the cost is that of the defect.
    A triangle whose edge is split becomes a fan from its opposite vertex.
    """
    from scipy.spatial import cKDTree

    split_total = 0
    for _ in range(rounds):
        he = half_edges(f)
        _, edge_of, counts = edge_table(f)
        open_h = np.flatnonzero(counts[edge_of] == 1)
        if len(open_h) == 0:
            break
        cand = np.unique(he[open_h])
        p, q = v[he[open_h, 0]], v[he[open_h, 1]]
        d = q - p
        dd = np.einsum("ek,ek->e", d, d)
        # A zero-length open edge (of a degenerate face: a vertex repeated, or two at one point) has no point between
        # its ends to split it at: passed over, where dividing by its length gave NaN and a RuntimeWarning.
        sound = dd > 0
        if not sound.all():
            open_h, p, q, d, dd = open_h[sound], p[sound], q[sound], d[sound], dd[sound]
            if len(open_h) == 0:
                break
        # Candidate vertices of each open edge: those within half its length (and tol) of its midpoint (a k-d tree,
        # so that the cost follows the pairs that are near, not open edges x open vertices).
        near = cKDTree(v[cand]).query_ball_point((p + q) / 2, np.sqrt(dd) / 2 + tol)
        e_idx = np.repeat(np.arange(len(open_h)), [len(c) for c in near])
        c_idx = np.fromiter((c for found in near for c in found), np.int64, len(e_idx))
        t = np.einsum("ik,ik->i", v[cand[c_idx]] - p[e_idx], d[e_idx]) / dd[e_idx]
        dist = np.linalg.norm(v[cand[c_idx]] - (p[e_idx] + t[:, None] * d[e_idx]), axis=1)
        length = np.sqrt(dd[e_idx])
        on = (dist <= tol) & (t * length > tol) & ((1 - t) * length > tol)
        if not on.any():
            break
        e_idx, c_idx, t = e_idx[on], c_idx[on], t[on]
        new_faces = []
        touched = np.zeros(len(f), bool)
        for e in np.unique(e_idx):
            face, i = divmod(int(open_h[e]), 3)
            if touched[face]:
                continue  # one split per face and round
            touched[face] = True
            mine = e_idx == e
            pts = cand[c_idx[mine]][np.argsort(t[mine])]
            a, b, c = f[face, i], f[face, (i + 1) % 3], f[face, (i + 2) % 3]
            chain = [a, *pts.tolist(), b]
            new_faces += [[chain[k], chain[k + 1], c] for k in range(len(chain) - 1)]
            split_total += len(pts)
        f = np.concatenate([f[~touched], np.array(new_faces, np.int64).reshape(-1, 3)])
    if split_total:
        repairs.append(f"split open edges at {split_total} T-junction vertices")
    return f


def _split_touching_edges(v, f, repairs):
    """Split the edges where closed solids touch, so that each keeps its own copy of the edge.

    Two blocks that meet along an edge (a footprint that touches itself at a corner, extruded; two
    row houses' volumes touching at a ridge) give an edge with four faces. Around such an edge the
    faces, in the order of their angle about it, alternate in the way they walk it (a -> b,
    b -> a, ...); each face is paired with the neighbour on the side its solid lies (the side its
    normal points away from, for an outward-oriented mesh; the other side for an inward one), and
    the edge's vertices are duplicated for every fan of faces that the pairing separates. Nothing
    moves: the surface is the same, only no longer glued along the edge. An edge whose faces do
    not alternate, or two of whose faces are coplanar (a fin), is not split.

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
        Closed (no edge with one face), with edges shared by more than two faces.
    repairs : list of str
        Appended to.

    Returns
    -------
    v : (W, 3) float64
        ``v`` followed by the copies of the split vertices.
    f : (F, 3) int64
        The faces, with split vertices renumbered; None (instead of the pair) where some edge
        cannot be split so.
    """
    n = len(f)
    he = half_edges(f)
    edges, edge_of, counts = edge_table(f)
    volume = signed_volume(v, f)
    if not volume != 0:
        return None
    order = np.argsort(edge_of, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)])
    twin = np.full(3 * n, -1, np.int64)
    two = np.flatnonzero(counts == 2)
    h0, h1 = order[starts[two]], order[starts[two] + 1]
    twin[h0], twin[h1] = h1, h0
    for e in np.flatnonzero(counts > 2):  # a handful of edges
        hs = order[starts[e]:starts[e + 1]]
        a, b = edges[e]
        d = v[b] - v[a]
        d = d / np.linalg.norm(d)
        w = v[f[hs // 3, (hs % 3 + 2) % 3]] - v[a]
        w = w - np.outer(w @ d, d)
        u = w[0] / np.linalg.norm(w[0])
        theta = np.arctan2(w @ np.cross(d, u), w @ u)
        k = np.argsort(theta)
        hs, theta = hs[k], theta[k]
        along = he[hs, 0] == a  # walks a -> b: its normal points to increasing angle
        gaps = np.diff(np.concatenate([theta, [theta[0] + 2 * np.pi]]))
        if (along == np.roll(along, -1)).any() or not (gaps > 1e-9).all():
            return None
        # outward: a face walking a -> b has its solid at decreasing angle, so it pairs with the
        # face before it; inward, with the one after it
        step = -1 if volume > 0 else 1
        i = np.flatnonzero(along)
        j = (i + step) % len(hs)
        twin[hs[i]], twin[hs[j]] = hs[j], hs[i]
    # corners (face, vertex) glued across every (paired) edge; a split vertex gets one copy per
    # connected fan of corners
    h = np.arange(3 * n)
    nxt = 3 * (h // 3) + (h % 3 + 1) % 3  # the corner at the half-edge's end
    t = twin[h]
    same = he[t, 0] == he[h, 0]  # twin walks the same way (not yet consistently oriented)
    src_t = np.where(same, t, 3 * (t // 3) + (t % 3 + 1) % 3)
    dst_t = np.where(same, 3 * (t // 3) + (t % 3 + 1) % 3, t)
    rows = np.concatenate([h, nxt])
    cols = np.concatenate([src_t, dst_t])
    graph = sparse.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(3 * n, 3 * n))
    _, label = connected_components(graph, directed=False)
    corner_vertex = f.reshape(-1)
    split = np.zeros(len(v), bool)
    split[edges[counts > 2].reshape(-1)] = True
    # per split vertex, its first fan keeps the index, the others get new vertices
    fans = np.unique(label[split[corner_vertex]])
    fan_vertex = np.zeros(label.max() + 1, np.int64)
    fan_vertex[label] = corner_vertex
    fv = fan_vertex[fans]
    first = np.ones(len(fans), bool)
    o = np.argsort(fv, kind="stable")
    first[o[1:]] = fv[o[1:]] != fv[o[:-1]]
    new_index = np.full(label.max() + 1, -1, np.int64)
    new_index[fans[first]] = fv[first]
    new_index[fans[~first]] = len(v) + np.arange(int((~first).sum()))
    out = np.where(split[corner_vertex], new_index[label], corner_vertex).reshape(-1, 3)
    v = np.concatenate([v, v[fv[~first]]])
    repairs.append(
        f"split {int((counts > 2).sum())} edges where solids touch (faces of more than two around them), "
        f"duplicating {int((~first).sum())} vertices"
    )
    return v, out


def _remove_fins(v, f, dist, repairs):
    """Remove zero-thickness fins: coplanar faces of opposite orientation that overlap.

    A footprint ring with a spike (it goes out and comes back along the same line) extrudes into
    two walls on top of each other, facing opposite ways. Around an edge with more than two
    faces, such a pair is looked for; in its plane, the faces of either orientation are united
    and every face inside their common area is removed (after T-junction splitting, a face is
    either inside it or outside).
    """
    _, edge_of, counts = edge_table(f)
    cross = _cross(v, f)
    area2 = np.linalg.norm(cross, axis=1)
    normal = cross / np.where(area2 > 0, area2, 1.0)[:, None]
    remove = np.zeros(len(f), bool)
    done = np.zeros(len(f), bool)  # faces of a plane already looked at: each plane once
    for e in np.flatnonzero(counts > 2):
        around = np.flatnonzero(edge_of == e) // 3
        for i, a in enumerate(around):
            for b in around[i + 1:]:
                if normal[a] @ normal[b] > -0.999999 or remove[a] or remove[b] or done[a]:
                    continue
                inside, plane = _opposite_overlap(v, f, normal, a, dist)
                remove |= inside
                done |= plane
    if remove.any():
        repairs.append(f"removed {int(remove.sum())} faces of zero-thickness fins (overlapping opposite walls)")
    return f[~remove]


def _opposite_overlap(v, f, normal, a, dist):
    """Faces inside the overlap of opposite-facing faces in the plane of face ``a``.

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
    normal : (F, 3) float64
        Unit normals (zero for degenerate faces).
    a : int
        A face of the plane.
    dist : float
        Largest distance of a vertex from the plane.

    Returns
    -------
    inside : (F,) bool
        Faces of the plane, of either orientation, lying inside the area that faces of both
        orientations cover (a zero-thickness sheet); all False when they do not overlap.
    coplanar : (F,) bool
        The faces of the plane.
    """
    import shapely

    inside = np.zeros(len(f), bool)
    n, d = normal[a], float(normal[a] @ v[f[a, 0]])
    coplanar = (np.abs(normal @ n) > 0.999999) & (np.abs(v[f] @ n - d).max(axis=1) <= dist)
    idx = np.flatnonzero(coplanar)
    up = normal[idx] @ n > 0
    if up.all() or not up.any():
        return inside, coplanar
    polys = shapely.polygons(v[f[idx]] @ plane_frame(n).T)
    try:
        overlap = shapely.intersection(shapely.union_all(polys[up]), shapely.union_all(polys[~up]))
        covered = shapely.area(shapely.intersection(polys, overlap))
    except shapely.errors.GEOSException:  # GEOS's overlay failed on them (a TopologyException): none found here
        return inside, coplanar
    if overlap.area <= dist * dist:
        return inside, coplanar
    inside[idx[covered >= 0.999 * shapely.area(polys)]] = True
    return inside, coplanar


def _clean_folds(v, f, params, diag, volume_in, source, repairs):
    """Step 4a: collapse short edges, repair flat folds; the mesh stays closed and oriented.

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
        Closed, edge-manifold, outward-oriented (from :func:`_clean`).
    params : PreprocessParams
    diag : float
        Bounding-box diagonal.
    volume_in : float
        Enclosed volume before this step.
    source : str
    repairs : list of str
        Appended to.

    Returns
    -------
    v : (W, 3) float64
    f : (G, 3) int64

    Raises
    ------
    MeshError
        When no repair (removing exact overlaps, manifold3d's rebuild) leaves the mesh closed,
        edge-manifold, oriented, within ``volume_rtol`` of its volume and without a fold within
        ``flat_fold_deg`` of 0/2 pi; the reason says what each repair left. A collapse that would
        break the mesh is not made (recorded in ``repairs``).
    """
    if params.min_edge_length > 0:
        trial = list(repairs)
        cv, cf = _collapse_short_edges(v, f, params.min_edge_length, source, trial)
        problem = validate(cv, cf)
        change = abs(signed_volume(cv, cf) - volume_in) if problem is None else 0.0
        if change > params.volume_rtol * abs(volume_in):  # a small piece (a door's handle) that the collapse flattens
            problem = f"the volume changed by {100 * change / abs(volume_in):.2g} %"
        if problem is None:
            v, f, repairs[:] = cv, cf, trial
        else:  # the mesh stays as it was: valid, with its short edges
            repairs.append(f"kept the edges shorter than {params.min_edge_length:g} m (collapsing them gives: {problem})")
    flat = _flat_fold_problem(v, f, params)
    if flat is None:
        problem = _fold_cleaning_problem(v, f, params, volume_in)
        if problem is not None:
            raise MeshError(source, f"collapsing edges shorter than {params.min_edge_length:g} m: {problem}")
        return _compact(v, f)
    # Exact fins and faces folded flat: their overlap goes. What stays (partial overlaps, thin
    # spikes and notches) is rebuilt by manifold3d, from the mesh without the exact overlaps if
    # their removal left it valid.
    trial = list(repairs)
    v, g = _remove_flat_overlaps(v, f, params, diag, trial)
    problem = _fold_cleaning_problem(v, g, params, volume_in)
    if problem is None:
        repairs[:] = trial
        return _compact(v, g)
    if validate(v, g) is None:
        f, repairs[:] = g, trial
    rebuilds = [("local edge flips and vertex merges", _flip_or_collapse_flat_folds),
                ("re-triangulating folded planes by their net cover", _replanar_flat_folds)]
    if params.fold_repair_tol > 0:
        rebuilds.insert(0, (f"manifold3d's rebuild at {params.fold_repair_tol:g} m tolerance", _manifold_rebuild))
    for name, rebuild in rebuilds:
        rv, rf, summary = rebuild(v, f, params, volume_in)
        if summary is None:
            problem = f"{problem}; {name} failed: {rf}"
            continue
        rproblem = _fold_cleaning_problem(rv, rf, params, volume_in)
        if rproblem is None:
            change = 100 * abs(signed_volume(rv, rf) - volume_in) / abs(volume_in)
            repairs.append(f"{summary} (the volume changed by {change:.2g} %), for flat folds: {flat}")
            return _compact(rv, rf)
        problem = f"{problem}; {name} left: {rproblem}"
    raise MeshError(source, f"{flat}, not repaired: removing overlapping opposite faces left: {problem}")


def _replanar_flat_folds(v, f, params, volume_in):
    """Re-triangulate the planes where faces are folded flat onto each other, by their net cover.

    A boolean union (manifold3d) can leave, where two solids met in a plane, faces of that plane
    folded onto each other: a face and its neighbour facing opposite ways on top of one another,
    with a third face of the first's orientation under both (a stack of +1, -1, +1 layers whose
    outlines differ, so no face lies wholly inside the overlap and :func:`_opposite_overlap`
    removes nothing). The surface such a plane means is its net cover: each point of the plane is
    covered by the faces facing +n less those facing -n (+1, 0 or -1 on a closed surface). So the
    plane's faces are overlaid (their outlines noded and polygonised by shapely), each cell gets
    its net cover (at a point inside it), and the +1 cells and the -1 cells are triangulated
    anew (constrained Delaunay), facing +n and -n; the rest of the mesh meets them at the old
    vertices, and at new ones where outlines crossed (split into its edges as T-junctions).

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
        Closed, edge-manifold, outward-oriented, with flat folds.
    params : PreprocessParams
        ``flat_fold_deg`` (which folds), ``planar_dist`` (a plane's thickness, relative to the
        bounding-box diagonal), ``tjunction_tol``.
    volume_in : float
        Unused (the signature of every flat-fold repair).

    Returns
    -------
    v : (W, 3) float64
    f : (G, 3) int64 or str
        The mesh with its folded planes re-triangulated; on failure ``f`` says why.
    summary : str or None
        What was done; None on failure.
    """
    import shapely

    diag = _diagonal(v)
    dist = params.planar_dist * diag
    tol = math.radians(params.flat_fold_deg)
    alpha, neighbour = _fold_angles(v, f)
    t, i = np.nonzero(np.minimum(alpha, 2 * np.pi - alpha) < tol)
    cross = _cross(v, f)
    area2 = np.linalg.norm(cross, axis=1)
    normal = cross / np.where(area2 > 0, area2, 1.0)[:, None]
    folded = t[np.einsum("ij,ij->i", normal[t], normal[neighbour[t, i]]) <= -math.cos(tol)]
    if len(folded) == 0:
        return v, "no faces folded flat onto each other in one plane", None
    done = np.zeros(len(f), bool)
    drop = np.zeros(len(f), bool)
    new_v, new_f = [v], []
    count = len(v)
    planes = 0
    for a in np.unique(folded):
        if done[a]:
            continue
        n, d = normal[a], float(normal[a] @ v[f[a]].mean(axis=0))
        coplanar = (np.abs(normal @ n) >= math.cos(tol)) & (np.abs(v[f] @ n - d).max(axis=1) <= dist) & (area2 > 0)
        done |= coplanar
        idx = np.flatnonzero(coplanar)
        frame = plane_frame(n)
        corners = np.unique(f[idx])
        flat = v[corners] @ frame.T  # (C, 2): the plane's vertices
        polys = shapely.polygons(v[f[idx]] @ frame.T)
        sign = np.where(normal[idx] @ n > 0, 1, -1)
        cells = np.asarray(shapely.get_parts(shapely.polygonize(
            [shapely.union_all(shapely.boundary(polys), grid_size=None)])))
        cells = cells[shapely.area(cells) > dist * dist]
        if len(cells) == 0:
            return v, "a folded plane has no area left", None
        inside, face = shapely.STRtree(polys).query(shapely.point_on_surface(cells), predicate="within")
        cover = np.bincount(inside, weights=sign[face], minlength=len(cells)).round().astype(np.int64)
        if (np.abs(cover) > 1).any():
            return v, f"a folded plane is covered {int(np.abs(cover).max())} times over in one place", None
        pieces = []
        for facing in (1, -1):
            region = shapely.union_all(cells[cover == facing])
            if region.is_empty:
                continue
            triangles = np.asarray(shapely.get_parts(shapely.constrained_delaunay_triangles(region)))
            if len(triangles):
                points = shapely.get_coordinates(shapely.get_exterior_ring(triangles)).reshape(-1, 4, 2)[:, :3]
                pieces.append((points, facing))
        if not pieces:
            drop |= coplanar
            planes += 1
            continue
        points = np.concatenate([p for p, _ in pieces])
        facing = np.concatenate([np.full(len(p), s) for p, s in pieces])
        # one vertex per point: the plane's own where within dist of one, else new ones (where
        # outlines crossed), points within dist of each other merged
        pts, inverse = np.unique(points.reshape(-1, 2), axis=0, return_inverse=True)
        near, at = cKDTree(flat).query(pts, distance_upper_bound=dist)
        old = np.isfinite(near)
        index = np.where(old, corners[np.minimum(at, len(corners) - 1)], -1)
        fresh = np.flatnonzero(~old)
        if len(fresh):
            pairs = cKDTree(pts[fresh]).query_pairs(dist, output_type="ndarray")
            graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(fresh),) * 2)
            k, group = connected_components(graph, directed=False)
            index[fresh] = count + group
            lifted = np.zeros((k, 2))
            np.add.at(lifted, group, pts[fresh])
            lifted /= np.bincount(group, minlength=k)[:, None]
            new_v.append(lifted @ frame + d * n)
            count += k
        tri = index[inverse.reshape(-1)].reshape(-1, 3)
        e1, e2 = points[:, 1] - points[:, 0], points[:, 2] - points[:, 0]
        ccw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0
        tri = np.where((ccw == (facing > 0))[:, None], tri, tri[:, ::-1])
        new_f.append(tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])])
        drop |= coplanar
        planes += 1
    out_v = np.concatenate(new_v)
    out_f = np.concatenate([f[~drop], *new_f]) if new_f else f[~drop]
    trial: list[str] = []
    out_f = _split_t_junctions(out_v, out_f, params.tjunction_tol * diag, trial)
    return out_v, out_f, (f"re-triangulated {planes} planes where faces were folded flat onto each other "
                          f"({int(drop.sum())} faces, by their net cover)")


def _flip_or_collapse_flat_folds(v, f, params, volume_in, max_steps=64):
    """Remove flat folds one at a time by the local change that moves the volume least.

    For a flat fold across edge ``p -> q`` between faces ``(p, q, a)`` and ``(q, p, b)``, the
    candidates are flipping the edge (to ``(p, b, a)``, ``(b, q, a)``) and merging any of the four
    vertices into another; the candidate kept leaves the mesh valid, has fewer flat folds, and
    changes the enclosed volume least. Used only when manifold3d's rebuild left flat folds, on
    the handful of edges that have them (each candidate is checked on the whole mesh).

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
        Closed, edge-manifold, outward-oriented.
    params : PreprocessParams
    volume_in : float
        The volume the result must stay within ``volume_rtol`` of.
    max_steps : int
        Most changes made.

    Returns
    -------
    v : (V, 3) float64
        The vertices, not moved.
    f : (G, 3) int64
        Faces after the changes.
    summary : str
        The changes made, in words.
    """
    tol = math.radians(params.flat_fold_deg)

    def count(g):
        alpha, _ = _fold_angles(v, g)
        return int((np.minimum(alpha, 2 * np.pi - alpha) < tol).sum())

    steps, n_flat = 0, count(f)
    if n_flat > 2 * MAX_LOCAL_FOLD_REPAIRS:  # (each fold counted from both faces)
        return v, f"{n_flat // 2} flat folds, more than the {MAX_LOCAL_FOLD_REPAIRS} it tries", None
    if n_flat // 2 * len(f) > MAX_LOCAL_FOLD_WORK:
        return v, (f"{n_flat // 2} flat folds in {len(f)} faces, more than the {MAX_LOCAL_FOLD_WORK} "
                   f"folds x faces it tries"), None
    while n_flat and steps < max_steps:
        check_time("flipping or collapsing flat folds")
        alpha, neighbour = _fold_angles(v, f)
        best = None  # (|volume change|, faces, flat folds)
        for t, k in zip(*np.nonzero(np.minimum(alpha, 2 * np.pi - alpha) < tol)):
            s = neighbour[t, k]
            p, q, a = f[t, k], f[t, (k + 1) % 3], f[t, (k + 2) % 3]
            b = f[s][(f[s] != p) & (f[s] != q)][0]
            trials = [np.concatenate([np.delete(f, [t, s], axis=0), [[p, b, a], [b, q, a]]])]
            for x in (p, q, a, b):
                for y in (p, q, a, b):
                    if x != y:
                        g = np.where(f == x, y, f)
                        trials.append(g[(g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])])
            for g in trials:  # the cheap tests first: the volume, then validity (the same choice)
                if len(g) < params.min_faces:
                    continue
                change = abs(signed_volume(v, g) - volume_in)
                if change > params.volume_rtol * abs(volume_in) or (best is not None and change >= best[0]):
                    continue
                if validate(v, g) is not None:
                    continue
                c = count(g)
                if c < n_flat:
                    best = (change, g, c)
        if best is None:
            break
        _, f, n_flat = best
        steps += 1
    return v, f, f"{steps} local edge flips or vertex merges"


def _remove_flat_overlaps(v, f, params, diag, repairs):
    """Remove the overlap of exactly coplanar, opposite faces that meet at a flat fold.

    Returns
    -------
    f : (G, 3) int64
        ``f`` without the faces of zero-thickness fins and pairs folded flat onto each other
        (:func:`_opposite_overlap`); validity is checked by the caller.
    """
    tol = math.radians(params.flat_fold_deg)
    alpha, neighbour = _fold_angles(v, f)
    flat = np.minimum(alpha, 2 * np.pi - alpha) < tol
    cross = _cross(v, f)
    area2 = np.linalg.norm(cross, axis=1)
    normal = cross / np.where(area2 > 0, area2, 1.0)[:, None]
    t, i = np.nonzero(flat)
    s = neighbour[t, i]
    exact = np.einsum("ij,ij->i", normal[t], normal[s]) <= -0.999999  # coplanar, opposite
    remove = np.zeros(len(f), bool)
    done = np.zeros(len(f), bool)  # faces of planes measured already (a flat floor of many faces: once)
    for a in np.unique(t[exact]):
        if not done[a]:
            inside, coplanar = _opposite_overlap(v, f, normal, a, params.planar_dist * diag)
            remove |= inside
            done |= coplanar
    if remove.any():
        repairs.append(
            f"removed {int(remove.sum())} faces of zero-thickness fins or faces folded flat onto each other "
            f"(fold angle within {params.flat_fold_deg:g} degrees of 0 or 2 pi)"
        )
    return v, f[~remove]


def _fold_cleaning_problem(v, f, params, volume_in):
    """Why a cleaned mesh is not acceptable (not valid, too few faces, flat folds, volume), or None."""
    if len(f) < params.min_faces:
        return f"only {len(f)} faces left"
    problem = validate(v, f) or _flat_fold_problem(v, f, params)
    if problem is not None:
        return problem
    volume = signed_volume(v, f)
    if abs(volume - volume_in) > params.volume_rtol * abs(volume_in):
        return f"the volume changed by {100 * abs(volume - volume_in) / abs(volume_in):.3g} %"
    return None


def _manifold_rebuild(v, f, params, volume_in):
    """The mesh rebuilt by manifold3d with an absolute tolerance, which removes thin features.

    manifold3d (``Manifold.set_tolerance``) merges vertices and collapses edges and slivers
    closer than ``tol`` as long as the surface moves by less than ``tol``: the tip of a thin
    spike or notch, a fin whose sides overlap only partly and faces folded onto each other become
    a plain surface. The result is a closed, oriented 2-manifold by construction (checked again by
    the caller, with the flat folds and the volume).

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
        Closed, edge-manifold, outward-oriented.
    params : PreprocessParams
        ``fold_repair_tol``: the absolute tolerance (the mesh's units, metres).
    volume_in : float
        Unused (the signature of every flat-fold repair).

    Returns
    -------
    v : (W, 3) float64
    f : (G, 3) int64 or str
        The rebuilt mesh; on failure ``f`` is manifold3d's status, in words.
    summary : str or None
        What was done, in words; None on failure.
    """
    tol = params.fold_repair_tol
    try:
        import manifold3d
    except ImportError as err:  # pragma: no cover - manifold3d is a declared dependency
        raise ImportError("repairing flat folds needs manifold3d: pip install 'manifold3d>=3.0'") from err
    centre = (v.min(axis=0) + v.max(axis=0)) / 2  # coordinates of the mesh's own size
    solid = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(v - centre, np.float64), tri_verts=np.ascontiguousarray(f, np.uint64),
    ))
    if solid.status() != manifold3d.Error.NoError:
        return v, f"manifold3d refuses the mesh ({solid.status().name})", None
    solid = solid.set_tolerance(tol)
    if solid.status() != manifold3d.Error.NoError or solid.is_empty():
        return v, f"manifold3d's rebuild failed ({solid.status().name if not solid.is_empty() else 'empty'})", None
    mesh = solid.to_mesh64()
    out_v = np.asarray(mesh.vert_properties, np.float64)[:, :3] + centre
    out_f = np.asarray(mesh.tri_verts, np.int64).reshape(-1, 3)
    return out_v, out_f, f"rebuilt with manifold3d at {tol:g} m tolerance ({len(f)} faces to {len(out_f)})"


def _collapse_short_edges(v, f, min_length, source, repairs):
    """Collapse every edge shorter than ``min_length``: each chain of short edges becomes one vertex.

    Detection is one pass over the edge table; the chains are connected components of the short
    edges, each replaced by its centroid (which lies on a single short edge, so in every plane
    through it); faces that collapse go, and pairs that become the same triangle walked both ways
    (a zero-volume pocket) go together. Closedness is checked by the caller.

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
    min_length : float
        Absolute length (metres).
    source : str
    repairs : list of str

    Returns
    -------
    v : (V, 3) float64
        Vertices of collapsed chains moved to their centroid (unused ones stay until compacted).
    f : (G, 3) int64
    """
    edges, _, _ = edge_table(f)
    length = np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)
    short = edges[length < min_length]
    if len(short) == 0:
        return v, f
    v, f, removed = _collapse_edges(v, f, short, repairs)
    repairs.append(f"collapsed {len(short)} edges shorter than {min_length:g} m ({removed} faces removed)")
    return v, f


def _collapse_edges(v, f, short, repairs, keep_volume=False):
    """Collapse the given edges: each chain (connected component) of them becomes one vertex.

    The vertex is the chain's centroid, or with ``keep_volume`` the point on the chain's axis
    (through the centroid towards its farthest vertex, as far as that vertex either way; for one
    edge, the edge itself) where collapsing that chain alone leaves the enclosed volume unchanged:
    a collapse moves the surface by a sliver whose volume is linear in the merged vertex, so
    a 10 cm step between two walls of different lengths leaves the volume as it was instead of
    moving it by a few tenths of a percent.

    Returns
    -------
    v : (V, 3) float64
        Vertices of collapsed chains moved to their centroid (unused ones stay until compacted).
    f : (G, 3) int64
        Faces left (collapsed faces and zero-volume pockets gone; validity is the caller's).
    removed : int
        Faces that collapsed.
    """
    n = len(v)
    labels, size, centroid = _chains(v, short)
    first = np.full(len(size), n, np.int64)
    np.minimum.at(first, labels, np.arange(n))
    v = v.copy()
    moved = size[labels] > 1
    if keep_volume:
        centroid, _ = _volume_keeping_points(v, f, labels, size, centroid)
    v[moved] = centroid[labels[moved]]
    f = first[labels][f]
    collapsed = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    f = _drop_duplicates(f[~collapsed], repairs)
    return v, f, int(collapsed.sum())


def _chains(v, edges):
    """Connected components of ``edges``: labels (V,), sizes (K,), centroids (K, 3)."""
    n = len(v)
    graph = sparse.coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    size = np.bincount(labels, minlength=labels.max() + 1)
    centroid = np.zeros((len(size), 3))
    np.add.at(centroid, labels, v)
    return labels, size, centroid / size[:, None]


def _volume_keeping_points(v, f, labels, size, centroid):
    """Per chain, the point where collapsing the chain alone keeps the volume (or changes it least).

    With only chain k moved to P, every face with exactly one of its vertices changes its
    volume term to P.(x1 x x2)/6 and every face with two or three of them goes, so the volume
    change is P.G/6 - C/6 (G: sum of x1 x x2 over the first kind; C: the volume terms, times 6, of
    all faces touching the chain). P = c + s (a - c), c the centroid, a the chain vertex farthest
    from it, s clamped to [-1, 1]; or, where it changes the volume less, the point nearest to the
    planes of the faces that stay.
    """
    lab = labels[f]  # (F, 3)
    multi = size[lab] > 1
    same = (lab[:, :, None] == lab[:, None, :]).sum(axis=2)  # corners of the face in the same chain
    x = v[f]
    triple = np.einsum("ij,ij->i", x[:, 0], np.cross(x[:, 1], x[:, 2]))
    k = len(size)
    g = np.zeros((k, 3))
    c = np.zeros(k)
    for corner in range(3):
        sel = multi[:, corner]
        once = sel & (same[:, corner] == 1)
        np.add.at(g, lab[once, corner], np.cross(x[once, (corner + 1) % 3], x[once, (corner + 2) % 3]))
        np.add.at(c, lab[sel, corner], triple[sel] / same[sel, corner])
    dist = np.linalg.norm(v - centroid[labels], axis=1)
    order = np.lexsort((-dist, labels))
    far = np.full(k, -1, np.int64)
    far[labels[order[::-1]]] = order[::-1]  # the last write per label is its farthest vertex
    axis = v[far] - centroid
    denom = np.einsum("ij,ij->i", axis, g)
    ok = (size > 1) & (np.abs(denom) > 1e-12 * np.maximum(np.abs(c), 1e-300))
    s = np.where(ok, (c - np.einsum("ij,ij->i", centroid, g)) / np.where(ok, denom, 1.0), 0.0)
    on_axis = centroid + np.clip(s, -1.0, 1.0)[:, None] * axis
    # Second candidate: the point nearest (least squares, area-weighted, minimum-norm from the
    # centroid) to the planes of the faces that stay, which restores a cut corner (a chamfer of a
    # convex corner, where no point of the chamfer keeps the volume) to the corner.
    quad = np.zeros((k, 3, 3))
    rhs = np.zeros((k, 3))
    cross = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    n = cross / np.where(area2 > 0, area2, 1.0)[:, None]
    offset = np.einsum("ij,ij->i", n, x[:, 0])
    stays = (lab[:, 0] != lab[:, 1]) & (lab[:, 1] != lab[:, 2]) & (lab[:, 0] != lab[:, 2])  # after every chain's collapse
    for corner in range(3):
        once = multi[:, corner] & stays
        np.add.at(quad, lab[once, corner], area2[once, None, None] * n[once, :, None] * n[once, None, :])
        np.add.at(rhs, lab[once, corner], (area2[once] * offset[once])[:, None] * n[once])
    idx = np.flatnonzero(size > 1)
    planes = centroid.copy()
    if len(idx):
        pinv = np.linalg.pinv(quad[idx], rcond=1e-9)
        residual = rhs[idx] - np.einsum("kij,kj->ki", quad[idx], centroid[idx])
        planes[idx] = centroid[idx] + np.einsum("kij,kj->ki", pinv, residual)
    candidates = np.stack([on_axis, planes])  # (2, K, 3)
    change = (np.einsum("ckj,kj->ck", candidates, g) - c) / 6.0
    # the planes' point only when it stays near the chain (within its extent) and keeps the volume better
    near = np.linalg.norm(planes - centroid, axis=1) <= 2 * np.linalg.norm(axis, axis=1)
    pick = (near & (np.abs(change[1]) < np.abs(change[0]))).astype(np.int64)
    return candidates[pick, np.arange(k)], change[pick, np.arange(k)]


def _collapse_tall_folds(v, f, regions, params, diag, volume_in, repairs, rounds=4):
    """Step 6a: collapse short edges whose folds have ``v`` above ``max_fold_v``, re-triangulate.

    A fold's ``v`` is the neighbour's apex distance from the edge in edge lengths, so ``v > 100``
    marks an edge a hundred times shorter than the faces beside it: a jog of a few centimetres in
    a footprint (a wall strip 5 cm wide and 10 m tall), a crease split by a vertex a centimetre from
    its end, the short diagonal of a sliver. Such edges no longer than ``max_collapse_length``
    metres are collapsed together (each chain to its centroid) and the planar regions are
    re-triangulated, for a few rounds. A round is kept only when the mesh stays closed,
    edge-manifold, oriented, free of flat folds and within ``volume_rtol`` of ``volume_in``;
    otherwise the chains are tried one at a time and those that break it are left as they are.

    Returns
    -------
    v, f : the mesh after the collapses (compacting is the caller's)
    regions : int
        Planar regions of the last re-triangulation.
    """
    if not params.max_fold_v > 0 or not params.max_collapse_length > 0:
        return v, f, regions
    from meshsom.folds import folds
    from meshsom.topology import adjacency

    collapsed = 0
    for _ in range(rounds):
        check_time("collapsing tall folds")
        fold = folds(v, f, adjacency(f))
        nxt = np.roll(f, -1, axis=1)
        length = np.linalg.norm(v[nxt] - v[f], axis=2)
        tall = (fold[..., 2] > params.max_fold_v) & (length <= params.max_collapse_length)
        if not tall.any():
            break
        edges = np.unique(np.sort(np.stack([f[tall], nxt[tall]], axis=1), axis=1), axis=0)
        trial = _try_collapse(v, f, edges, params, diag, volume_in)
        if trial is None:
            break
        v, f, regions = trial
        collapsed += len(edges)
    if collapsed:
        repairs.append(
            f"collapsed {collapsed} edges of at most {params.max_collapse_length:g} m with folds of v > "
            f"{params.max_fold_v:g} (an edge that short beside faces that large), re-triangulated"
        )
    return v, f, regions


def _try_collapse(v, f, edges, params, diag, volume_in):
    """Collapse the chains of ``edges`` that keep the mesh acceptable, and re-triangulate.

    Only chains whose collapse alone changes the volume by at most 1 % of ``volume_rtol``
    (:func:`_volume_keeping_points`: almost always exactly 0) go; a chain that would move the
    volume more (a notch or slot whose walls beside it are too short to take it up) stays. If
    their collapse together leaves the mesh not acceptable (closed, manifold, oriented, no flat
    folds, volume within ``volume_rtol``), they are tried one at a time (there are a handful).
    None when no chain can be collapsed.
    """
    labels, size, centroid = _chains(v, edges)
    _, change = _volume_keeping_points(v, f, labels, size, centroid)
    chosen = (size > 1) & (np.abs(change) <= 0.01 * params.volume_rtol * abs(volume_in))
    if not chosen.any():
        return None
    cv, cf, _ = _collapse_edges(v, f, edges[chosen[labels[edges[:, 0]]]], [], keep_volume=True)
    if _fold_cleaning_problem(cv, cf, params, volume_in) is not None:
        cv, cf, done = v, f, 0
        for k in np.flatnonzero(chosen):  # one chain at a time
            tv, tf, _ = _collapse_edges(cv, cf, edges[labels[edges[:, 0]] == k], [], keep_volume=True)
            if _fold_cleaning_problem(tv, tf, params, volume_in) is None:
                cv, cf, done = tv, tf, done + 1
        if not done:
            return None
    try:
        rv, rf, regions = _retriangulate(cv, cf, params, diag)
    except MeshError:  # pragma: no cover - defensive
        return None
    if _fold_cleaning_problem(rv, rf, params, volume_in) is not None:
        return None
    return rv, rf, regions


def _fold_angles(v, f):
    """Fold angle across every edge of a closed oriented mesh, and the neighbour across it.

    Returns
    -------
    alpha : (F, 3) float64
        In (0, 2 pi] (DESIGN.md §3).
    neighbour : (F, 3) int64
    """
    from meshsom.folds import folds
    from meshsom.topology import adjacency

    adj = adjacency(f)
    return folds(v, f, adj)[..., 0], adj.neighbour


def _flat_fold_problem(v, f, params):
    """Why a closed oriented mesh has folds within ``flat_fold_deg`` of 0/2 pi, or None."""
    if params.flat_fold_deg <= 0:
        return None
    alpha, _ = _fold_angles(v, f)
    near = np.minimum(alpha, 2 * np.pi - alpha)
    bad = near < math.radians(params.flat_fold_deg)
    if not bad.any():
        return None
    t, i = np.nonzero(bad)
    length = np.linalg.norm(v[f[t, (i + 1) % 3]] - v[f[t, i]], axis=1)
    return (
        f"{int(bad.sum()) // 2} edges fold within {params.flat_fold_deg:g} degrees of 0 or 2 pi (a thin spike or notch, a "
        f"fin or faces folded onto each other; smallest angle {math.degrees(near.min()):.3g} degrees, "
        f"at an edge of {length[np.argmin(near[t, i])]:.3g} m)"
    )


def _walk_loops(directed: np.ndarray) -> list[np.ndarray] | None:
    """Chain directed edges (a -> b) into closed loops; None if a vertex has two outgoing edges."""
    src, dst = directed[:, 0], directed[:, 1]
    order = np.argsort(src, kind="stable")
    s_sorted = src[order]
    if (np.diff(s_sorted) == 0).any():
        return None
    pos = np.searchsorted(s_sorted, dst)
    if (pos >= len(src)).any() or not np.array_equal(s_sorted[np.minimum(pos, len(src) - 1)], dst):
        return None
    nxt = order[pos]  # edge that follows each edge
    seen = np.zeros(len(src), bool)
    loops = []
    for start in range(len(src)):
        if seen[start]:
            continue
        loop = []
        e = start
        while not seen[e]:
            seen[e] = True
            loop.append(src[e])
            e = nxt[e]
        if e != start:
            return None
        loops.append(np.array(loop, np.int64))
    return loops


def _edge_keys(f: np.ndarray) -> set:
    """The mesh's edges as ``(min, max)`` vertex pairs."""
    e = np.sort(half_edges(f), axis=1)
    return set(map(tuple, np.unique(e, axis=0).tolist()))


def _off_plane(p: np.ndarray) -> float:
    """Largest distance of the points ``p`` (k, 3) from their best-fitting plane (0 for k < 4)."""
    if len(p) < 4:
        return 0.0
    q = p - p.mean(axis=0)
    normal = np.linalg.svd(q, full_matrices=False)[2][-1]
    return float(np.abs(q @ normal).max())


def _off_planes(v: np.ndarray, pieces: list[list[int]]) -> np.ndarray:
    """:func:`_off_plane` of many pieces of a loop at once, bit for bit (one batched SVD per length).

    Parameters
    ----------
    v : (V, 3) float64
    pieces : list of list of int
        Vertex indices of each piece.

    Returns
    -------
    (len(pieces),) float64
    """
    out = np.zeros(len(pieces))
    by_length: dict[int, list[int]] = {}
    for k, piece in enumerate(pieces):
        by_length.setdefault(len(piece), []).append(k)
    for length, ks in by_length.items():
        if length < 4:
            continue
        q = v[np.array([pieces[k] for k in ks], np.int64)]
        q = q - q.mean(axis=1, keepdims=True)
        normal = np.linalg.svd(q, full_matrices=False)[2][:, -1, :]
        out[ks] = np.abs(np.matmul(q, normal[:, :, None])[..., 0]).max(axis=1)
    return out


def _planar_loops(v, directed, dist, edges: set, max_edges: int = 256, through: bool = True) -> list[np.ndarray] | None:
    """Open boundary edges (a -> b) decomposed into closed loops that each lie in one plane.

    1. Loops are walked edge to edge; where a vertex has several open edges out (loops touching
       at a vertex), the walk takes the edge whose end stays nearest to the plane of the loop so
       far, and a walk that comes back to one of its own vertices splits that loop off.
    2. A loop not planar within ``dist`` is cut along a chord between two of its vertices into two
       loops that are (the chord becomes the edge the two caps share), the chord that leaves them
       flattest; a chord that is already an edge of the mesh is never used (three faces would
       share it). Up to two cuts: a hole across three planes. Each piece keeps at least four
       vertices, so that it is a polygon that is planar, not a triangle (planar whatever the
       hole): a hole is closed only where walls or floors are missing whole, and a bent hole of
       a few triangles is left to ``repair`` (pymeshlab).

    With ``through`` False, no chord passes through another vertex of its loop
    (:func:`_through_vertex`): the chord to that vertex is used instead (walls missing below
    different heights on three sides, whose bent loop has a corner on the line of another chord).

    Returns None where a walk ends at a vertex with no open edge out, where some loop cannot be
    made planar, or above ``max_edges`` open edges (a mesh that open is not a missing wall).
    """
    if len(directed) > max_edges:
        return None
    out: dict[int, list[int]] = {}
    for k, a in enumerate(directed[:, 0].tolist()):
        out.setdefault(a, []).append(k)
    used = np.zeros(len(directed), bool)
    walked: list[list[int]] = []
    # start where there is no choice (deterministic: edge order)
    for start in sorted(range(len(directed)), key=lambda k: (len(out[int(directed[k, 0])]) > 1, k)):
        if used[start]:
            continue
        used[start] = True
        loop = [int(directed[start, 0])]
        cur = int(directed[start, 1])
        while True:
            if cur in loop:  # back at the start, or at a vertex passed before: a loop closes
                at = loop.index(cur)
                walked.append(loop[at:])
                loop = loop[:at]
                if not loop:
                    break
            choices = [k for k in out.get(cur, []) if not used[k]]
            if not choices:
                return None
            if len(choices) > 1 and len(loop) >= 2:
                pts = v[loop + [cur]]
                choices.sort(key=lambda k: _off_plane(np.vstack([pts, v[directed[k, 1]]])))
            used[choices[0]] = True
            loop.append(cur)
            cur = int(directed[choices[0], 1])
    loops: list[list[int]] = []
    for loop in walked:
        pieces = _cut_flat(v, loop, dist, edges, cuts=2, through=through, search={})
        if pieces is None:
            return None
        loops += pieces
    return [np.array(loop, np.int64) for loop in loops]


#: Most planarity measures one loop's cut search may take (:func:`_cut_flat`): a bound on the time a
#: loop bent every which way (no missing wall) costs before it is left open; real cuts take hundreds.
CUT_SEARCH_BUDGET = 100_000


def _cut_flat(v, loop: list[int], dist: float, edges: set, cuts: int, through: bool = True,
              search: dict | None = None) -> list[list[int]] | None:
    """``loop`` as loops that each lie in one plane within ``dist``, cut along at most ``cuts`` chords
    (the flattest such cut first; with ``through`` False, no chord through another vertex of the
    loop; None where there is none).

    ``search`` holds the planarity of the pieces measured so far (the recursion measures the same
    pieces again and again) and their count; past :data:`CUT_SEARCH_BUDGET` measures the search
    gives up (None).
    """
    search = {} if search is None else search
    key = _spent_key(v, loop, dist, edges, cuts, through)
    if key in _SPENT_SEARCHES:  # the same loop spent the budget before (another try of one mesh)
        return None

    def off_plane(*pieces: list[int]) -> list[float]:
        keys = [tuple(p) for p in pieces]
        new = {k: p for k, p in zip(keys, pieces) if k not in search}
        if new:
            search["measures"] = search.get("measures", 0) + len(new)
            if search["measures"] > CUT_SEARCH_BUDGET:
                raise _SearchSpent
            search.update(zip(new, _off_planes(v, list(new.values())).tolist()))
        return [search[k] for k in keys]

    try:
        return _cut_flat_search(v, loop, dist, edges, cuts, through, off_plane)
    except _SearchSpent:
        if len(_SPENT_SEARCHES) >= MAX_SPENT_SEARCHES:
            _SPENT_SEARCHES.clear()
        _SPENT_SEARCHES.add(key)
        return None


class _SearchSpent(Exception):
    """:data:`CUT_SEARCH_BUDGET` spent."""


#: Loops whose cut search spent :data:`CUT_SEARCH_BUDGET` (:func:`_spent_key`): the repairs try a
#: mesh several ways and meet the same loop again; the search is a function of the key, so it
#: would spend the budget again. Cleared when it holds :data:`MAX_SPENT_SEARCHES`.
_SPENT_SEARCHES: set = set()
MAX_SPENT_SEARCHES = 256


def _spent_key(v, loop: list[int], dist: float, edges: set, cuts: int, through: bool) -> tuple:
    """What :func:`_cut_flat`'s search depends on: the loop's points, the chords it may not use
    (mesh edges, by their positions in the loop), the tolerance, the cuts and ``through``."""
    n = len(loop)
    taken = [(i, j) for i in range(n) for j in range(i + 3, n)
             if (min(loop[i], loop[j]), max(loop[i], loop[j])) in edges]
    return np.asarray(v)[loop].tobytes(), tuple(taken), float(dist), int(cuts), bool(through)


def _cut_flat_search(v, loop, dist, edges, cuts, through, off_plane):
    check_time(f"cutting a boundary loop of {len(loop)} vertices into flat pieces")
    if off_plane(loop)[0] <= dist:
        return [loop]
    if cuts == 0:
        return None
    n = len(loop)
    chords = []
    p = v[loop]
    for i in range(n):
        for j in range(i + 3, min(n, i + n - 2)):  # both pieces of at least four vertices
            if (min(loop[i], loop[j]), max(loop[i], loop[j])) in edges:
                continue
            if not through and _through_vertex(p, i, j, dist):
                continue
            chords.append((i, j, loop[i:j + 1], loop[j:] + loop[:i + 1]))
    measured = off_plane(*[c[2] for c in chords], *[c[3] for c in chords])  # all at once
    candidates = []
    for (i, j, a, b), da, db in zip(chords, measured[:len(chords)], measured[len(chords):]):
        if min(da, db) <= dist:  # one side flat: the other is flat too, or is cut again
            candidates.append((max(da, db), i, j, a, b) if da <= db else (max(da, db), i, j, b, a))
    for worst, _, _, flat, rest in sorted(candidates, key=lambda c: c[:3]):
        if cuts == 1:  # the last cut: ``rest`` (measured, the worse side) must be flat as it is
            if worst <= dist:
                return [flat, rest]
            continue
        more = _cut_flat_search(v, rest, dist, edges, cuts - 1, through, off_plane)
        if more is not None:
            return [flat, *more]
    return None


def _has_through_chord(v, loops, directed, dist) -> bool:
    """Whether a chord of the planar ``loops`` (a side that is no open edge) passes through a vertex.

    Parameters
    ----------
    v : (V, 3) float64
    loops : list of (k,) int64
        Loops from :func:`_planar_loops`.
    directed : (E, 2) int64
        The open edges (a -> b) they were made from.
    dist : float
    """
    open_edges = set(map(tuple, directed.tolist()))
    ids = np.unique(np.concatenate(loops))
    for loop in loops:
        for a, b in zip(loop.tolist(), np.roll(loop, -1).tolist()):
            if (a, b) not in open_edges:
                p = np.vstack([v[[a, b]], v[ids[(ids != a) & (ids != b)]]])
                if _through_vertex(p, 0, 1, dist):
                    return True
    return False


def _through_vertex(p: np.ndarray, i: int, j: int, dist: float) -> bool:
    """Whether the chord ``p[i] -> p[j]`` of a loop passes through another of its vertices.

    Such a chord would be an edge of two caps with a vertex of the loop inside it (a T-junction),
    and the piece beside it a polygon with a spike (there and back along the chord's line).

    Parameters
    ----------
    p : (n, 3) float64
        The loop's vertices, in order.
    i, j : int
        The chord's ends.
    dist : float
        Largest distance from the chord's line of a vertex on it.
    """
    d = p[j] - p[i]
    dd = float(d @ d)
    if not dd > 0:
        return True
    others = np.delete(p, [i, j], axis=0) - p[i]
    t = others @ d / dd
    off = np.linalg.norm(others - t[:, None] * d, axis=1)
    length = math.sqrt(dd)
    return bool(((off <= dist) & (t * length > dist) & ((1 - t) * length > dist)).any())


def _area2d(ring):
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


#: Shells of one mesh looked at for cavities (each pair's bounding boxes compared): a building has a few; a mesh of
#: more (a whole district as one mesh of disjoint blocks) has every shell facing out.
MAX_CAVITY_SHELLS = 1000


def _thickness(points: np.ndarray) -> float:
    """The extent of ``points`` (N, 3) across their best-fitting plane (0 for coplanar points)."""
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    return float(np.ptp(centred @ normal)) if len(points) else 0.0


def _orient(v, f, source, repairs):
    """Consistent orientation by parity components, then each shell outward, but a shell inside an odd number of
    others (a cavity: a Solid's interior shell) inward, so that its volume counts against the solid's."""
    n = len(f)
    parity = _parity(f)
    if parity is None:
        raise MeshError(source, "not orientable (a Moebius-like surface)")
    flip, n_shells, shell = parity
    f = np.where(flip[:, None], f[:, ::-1], f)
    vol = np.zeros(n_shells)
    a, b, c = (v[f[:, k]] - v.mean(axis=0) for k in range(3))
    np.add.at(vol, shell, np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0)
    inward = vol < 0
    cavity = (_cavities(v, f, shell, n_shells, inward) if 1 < n_shells <= MAX_CAVITY_SHELLS
              else np.zeros(n_shells, bool))
    flip_shell = (inward != cavity)[shell]
    f = np.where(flip_shell[:, None], f[:, ::-1], f)
    flipped = int((flip ^ flip_shell).sum())
    if flipped:
        repairs.append(f"flipped {flipped} of {n} faces to a consistent outward orientation"
                       + (f" ({int(cavity.sum())} inner shell(s), cavities, facing in)" if cavity.any() else ""))
    return f


def cavity_shells(vertices: np.ndarray, faces: np.ndarray, face_shell: np.ndarray) -> np.ndarray:
    """Which of a mesh's given shells are cavities, by the rule :func:`preprocess` orients them by.

    A shell is a cavity where every corner of it (up to :data:`CAVITY_POINTS`) lies strictly inside an odd number
    of the other shells (:func:`_cavities`); a shell touching or overlapping another is a solid of its own. The
    shells are those the caller names (a city model's shells of a Solid, CompositeSolid or MultiSolid), each
    oriented alike for the test whatever way the file walks its faces.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    face_shell : (F,) int64
        Each face's shell, 0 .. S-1.

    Returns
    -------
    (S,) bool
        All False where there are more than :data:`MAX_CAVITY_SHELLS` shells (as :func:`preprocess` takes them).
    """
    v = np.asarray(vertices, np.float64)
    face_shell = np.asarray(face_shell, np.int64).reshape(-1)
    n_shells = int(face_shell.max()) + 1 if len(face_shell) else 0
    if not 1 < n_shells <= MAX_CAVITY_SHELLS:
        return np.zeros(n_shells, bool)
    f = _oriented_alike(np.asarray(faces, np.int64))
    a, b, c = (v[f[:, k]] - v.mean(axis=0) for k in range(3))
    vol = np.zeros(n_shells)
    np.add.at(vol, face_shell, np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0)
    return _cavities(v, f, face_shell, n_shells, vol < 0)


def _cavities(v, f, shell, n_shells: int, inward) -> np.ndarray:
    """Which shells are cavities: inside an odd number of the other shells (the even-odd rule of solids).

    A shell is tested where its bounding box lies within another's: the winding number of a point about the other
    shell's faces (the sum of their solid angles, Van Oosterom and Strackee) is 1 inside, 0 outside and 1/2 on a
    face. A cavity lies wholly inside: every one of its corners (up to :data:`CAVITY_POINTS` of them) must be,
    strictly (winding above 3/4). A shell touching the other (a building part standing on another's roof, two
    solids of a MultiSolid sharing a wall) has corners on its faces or outside, and is a solid of its own.

    Parameters
    ----------
    v : (V, 3) float64
    f : (F, 3) int64
        Faces, each shell consistently oriented.
    shell : (F,) int64
        Each face's shell.
    n_shells : int
    inward : (n_shells,) bool
        The shells whose faces face in (negative signed volume) as ``f`` has them.

    Returns
    -------
    (n_shells,) bool
    """
    corners = v[f]
    low = np.full((n_shells, 3), np.inf)
    high = np.full((n_shells, 3), -np.inf)
    np.minimum.at(low, shell, corners.min(axis=1))
    np.maximum.at(high, shell, corners.max(axis=1))
    inside = (low[:, None] >= low[None]).all(axis=2) & (high[:, None] <= high[None]).all(axis=2)
    np.fill_diagonal(inside, False)
    depth = np.zeros(n_shells, np.int64)
    if not inside.any():
        return depth.astype(bool)
    for a, b in zip(*np.nonzero(inside)):  # shell a's bounding box within shell b's
        own = np.unique(f[shell == a])
        points = v[own[np.linspace(0, len(own) - 1, min(len(own), CAVITY_POINTS)).astype(np.int64)]]
        tri = corners[shell == b]
        if inward[b]:
            tri = tri[:, ::-1]
        winding = np.zeros(len(points))
        step = max(1, WINDING_PAIRS // len(points))
        for start in range(0, len(tri), step):  # (points, faces, 3, 3) in pieces of WINDING_PAIRS pairs
            r = tri[None, start:start + step] - points[:, None, None]
            x, y, z = r[:, :, 0], r[:, :, 1], r[:, :, 2]
            lx, ly, lz = (np.linalg.norm(c, axis=2) for c in (x, y, z))
            dot = lambda p, q: np.einsum("pki,pki->pk", p, q)  # noqa: E731
            numerator = dot(x, np.cross(y, z))
            denominator = lx * ly * lz + dot(x, y) * lz + dot(y, z) * lx + dot(z, x) * ly
            winding += np.arctan2(numerator, denominator).sum(axis=1) / (2 * np.pi)
        depth[a] += int((winding > 0.75).all())
    return depth % 2 == 1


#: Corners of a shell whose winding numbers about another shell say whether it lies inside it (:func:`_cavities`).
CAVITY_POINTS = 64
#: (Point, face) pairs of one piece of :func:`_cavities`' winding numbers (each 9 float64 of 8 bytes: 75 MB).
WINDING_PAIRS = 1 << 20


def _parity(f):
    """Which faces to flip so that the faces on every edge of two walk it opposite ways (edges of
    one face, or of more, join nothing): the first face of each shell keeps its way.

    Parameters
    ----------
    f : (F, 3) int64

    Returns
    -------
    (flip, n_shells, shell) : ((F,) bool, int, (F,) int64), or None where a shell cannot be
        oriented (a Moebius-like surface). Shells: faces joined through edges of two faces.
    """
    n = len(f)
    he = half_edges(f)
    _, edge_of, counts = edge_table(f)
    two = counts[edge_of] == 2
    order = np.flatnonzero(two)[np.argsort(edge_of[two], kind="stable")].reshape(-1, 2)
    h0, h1 = order[:, 0], order[:, 1]
    fa, fb = h0 // 3, h1 // 3
    same_way = he[h0, 0] == he[h1, 0]  # both faces walk the edge the same way: one must flip
    # Doubled graph: node (face, state); edge (a, s) -- (b, s xor same_way).
    a0, b0 = 2 * fa, 2 * fb + same_way
    a1, b1 = 2 * fa + 1, 2 * fb + (1 - same_way)
    rows = np.concatenate([a0, a1])
    cols = np.concatenate([b0, b1])
    graph = sparse.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(2 * n, 2 * n))
    _, lab = connected_components(graph, directed=False)
    lab = lab.reshape(n, 2)
    if (lab[:, 0] == lab[:, 1]).any():
        return None
    g1 = sparse.coo_matrix((np.ones(len(fa), np.int8), (fa, fb)), shape=(n, n))
    n_shells, shell = connected_components(g1, directed=False)
    seed = np.full(n_shells, n, np.int64)
    np.minimum.at(seed, shell, np.arange(n))
    return lab[:, 0] != lab[seed[shell], 0], n_shells, shell


def _oriented_alike(f):
    """``f`` with the faces of each shell walking their shared edges opposite ways (one side of a
    two-sided surface kept may face either way; capping needs the open edges to run one way)."""
    parity = _parity(f)
    if parity is None:
        return f
    return np.where(parity[0][:, None], f[:, ::-1], f)


def _compact(v, f):
    used = np.zeros(len(v), bool)
    used[f.reshape(-1)] = True
    if used.all():
        return v, f
    new = np.cumsum(used) - 1
    return v[used], new[f]


# --------------------------------------------------------------------------------------------
# Planar regions and re-triangulation
# --------------------------------------------------------------------------------------------


def _retriangulate(v, f, params, diag):
    """Steps 5-6. Returns (vertices, faces, number of regions)."""
    n = len(f)
    dist = params.planar_dist * diag
    cross = _cross(v, f)
    area2 = np.linalg.norm(cross, axis=1)
    longest = np.max(np.linalg.norm(v[np.roll(f, -1, axis=1)] - v[f], axis=2), axis=1)
    degenerate = area2 <= dist * longest  # height below tolerance: a sliver joins any region
    normal = np.where(degenerate[:, None], 0.0, cross / np.where(area2 > 0, area2, 1.0)[:, None])

    he = half_edges(f)
    _, edge_of, _ = edge_table(f)
    order = np.argsort(edge_of, kind="stable").reshape(-1, 2)
    h0, h1 = order[:, 0], order[:, 1]
    twin = np.empty(3 * n, np.int64)
    twin[h0], twin[h1] = h1, h0
    fa, fb = h0 // 3, h1 // 3
    cos_tol = math.cos(math.radians(params.planar_angle_deg))
    join = (np.einsum("ij,ij->i", normal[fa], normal[fb]) >= cos_tol) | degenerate[fa] | degenerate[fb]
    g = sparse.coo_matrix((np.ones(int(join.sum()), np.int8), (fa[join], fb[join])), shape=(n, n))
    n_regions, region = connected_components(g, directed=False)

    # Region planes: area-weighted normal and centroid; regions off their plane keep their faces.
    plane_n = np.zeros((n_regions, 3))
    np.add.at(plane_n, region, cross)
    norm = np.linalg.norm(plane_n, axis=1)
    fallback = ~(norm > 0)
    plane_n = plane_n / np.where(norm > 0, norm, 1.0)[:, None]
    centroid = v[f].mean(axis=1)
    plane_p = np.zeros((n_regions, 3))
    np.add.at(plane_p, region, centroid * area2[:, None])
    w = np.bincount(region, weights=area2, minlength=n_regions)
    plane_p = plane_p / np.where(w > 0, w, 1.0)[:, None]
    off = np.abs(np.einsum("ij,ij->i", v[f.reshape(-1)] - plane_p[np.repeat(region, 3)], plane_n[np.repeat(region, 3)]))
    far = np.zeros(n_regions)
    np.maximum.at(far, np.repeat(region, 3), off)
    fallback |= far > dist

    # Region boundary half-edges.
    on_boundary = region[np.arange(3 * n) // 3] != region[twin // 3]
    b_idx = np.flatnonzero(on_boundary)
    b_src, b_dst, b_reg = he[b_idx, 0], he[b_idx, 1], region[b_idx // 3]
    nv = len(v)
    key_out = b_reg * nv + b_src
    key_in = b_reg * nv + b_dst
    o_order = np.argsort(key_out, kind="stable")
    k_sorted = key_out[o_order]
    pinch_key = np.unique(k_sorted[1:][np.diff(k_sorted) == 0])
    fallback[np.unique(pinch_key // nv)] = True

    for _ in range(n_regions + 1):
        keep = _kept_vertices(v, f, region, fallback, b_src, b_dst, b_reg, key_in, key_out, o_order, k_sorted, params, dist)
        new_faces, failed = _triangulate_regions(
            v, f, region, n_regions, fallback, keep, plane_n, b_src, b_reg, key_in, o_order, k_sorted, nv
        )
        if not failed:
            break
        fallback[failed] = True
    return v, new_faces, n_regions


def _kept_vertices(v, f, region, fallback, b_src, b_dst, b_reg, key_in, key_out, o_order, k_sorted, params, dist):
    nv = len(v)
    keep = np.zeros(nv, bool)
    keep[f[fallback[region]].reshape(-1)] = True
    if not params.flatten_collinear:
        keep[b_src] = True
        return keep
    # For every boundary edge (v -> w) of region R find the incoming edge (u -> v) of R.
    i_order = np.argsort(key_in, kind="stable")
    pos = np.searchsorted(key_in[i_order], key_out)
    pos = np.minimum(pos, len(key_in) - 1)
    incoming = i_order[pos]
    matched = key_in[incoming] == key_out
    u = b_src[incoming]
    p_u, p_v, p_w = v[u], v[b_src], v[b_dst]
    d1, d2 = p_v - p_u, p_w - p_v
    base = np.linalg.norm(p_w - p_u, axis=1)
    height = np.linalg.norm(np.cross(d1, d2), axis=1) / np.where(base > 0, base, 1.0)
    straight = matched & (height <= dist) & (np.einsum("ij,ij->i", d1, d2) > 0)
    keep[b_src[~straight]] = True
    return keep


def _triangulate_regions(v, f, region, n_regions, fallback, keep, plane_n, b_src, b_reg, key_in, o_order, k_sorted, nv):
    """Triangulate every non-fallback region from its kept boundary vertices.

    Every region is laid into its plane at once; the regions bounded by one loop (almost all) are
    triangulated in one GEOS call (:func:`triangulate_rings_2d`), those with holes or a loop that
    is not a valid polygon one at a time (:func:`triangulate_polygon_2d`).
    """
    loops, loop_region, failed = _region_loops(b_src, b_reg, key_in, o_order, k_sorted, fallback)
    out = [f[fallback[region]]]
    todo = ~fallback
    todo[failed] = False
    loops = [lp[keep[lp]] for lp in loops]
    length = np.array([len(lp) for lp in loops], np.int64)
    n_loops = np.bincount(loop_region, minlength=n_regions)
    short = np.zeros(n_regions, bool)
    short[loop_region[length < 3]] = True
    bad = todo & ((n_loops == 0) | short)
    todo &= ~bad
    chosen = todo[loop_region]
    loops = [lp for lp, c in zip(loops, chosen) if c]
    loop_region, length = loop_region[chosen], length[chosen]
    if not len(loops):
        return _regions_done(out, failed + np.flatnonzero(bad).tolist())

    # Each region's plane frame, its origin at its first loop's first vertex.
    points = np.concatenate(loops)
    first = np.concatenate([[0], np.cumsum(length)[:-1]])
    point_loop = np.repeat(np.arange(len(loops)), length)
    point_region = loop_region[point_loop]
    origin_of = np.zeros(n_regions, np.int64)
    origin_of[loop_region[::-1]] = points[first[::-1]]  # the first loop of each region wins
    frames = np.zeros((n_regions, 2, 3))
    regions = np.unique(loop_region)
    frames[regions] = plane_frames(plane_n[regions])
    flat = np.einsum("pk,pjk->pj", v[points] - v[origin_of[point_region]], frames[point_region])
    nxt = np.arange(len(points)) + 1
    nxt[first + length - 1] = first
    area = 0.5 * np.add.reduceat(flat[:, 0] * flat[nxt, 1] - flat[nxt, 0] * flat[:, 1], first)
    # One outer loop (positive area) per region, the largest of its loops.
    outers = np.bincount(loop_region, weights=area > 0, minlength=n_regions)
    largest = np.zeros(n_regions)
    np.maximum.at(largest, loop_region, np.abs(area))
    is_outer = (area > 0) & (area >= largest[loop_region])
    has_outer = np.bincount(loop_region, weights=is_outer, minlength=n_regions) > 0
    wrong = todo & ((outers != 1) | ~has_outer)
    todo &= ~wrong

    # Regions of one loop: a triangle as it is, the rest in one batch; regions with holes one at a time.
    single = todo & (n_loops == 1)
    batch = single[loop_region] & (length > 3)
    tris = [points[first[(length == 3) & single[loop_region]][:, None] + np.arange(3)]]
    tri_region = [loop_region[(length == 3) & single[loop_region]]]
    one_by_one = np.flatnonzero(todo & ~single).tolist()
    if batch.any():
        ids = np.flatnonzero(batch)
        take = np.concatenate([np.arange(first[i], first[i] + length[i]) for i in ids])
        tri, ring, valid = triangulate_rings_2d(flat[take], length[ids])
        counts = np.bincount(ring, minlength=len(ids))
        whole = valid & (counts == length[ids] - 2)
        tris.append(points[take[tri[whole[ring]]]])
        tri_region.append(loop_region[ids[ring[whole[ring]]]])
        failed += loop_region[ids[valid & ~whole]].tolist()
        one_by_one += loop_region[ids[~valid]].tolist()
    for r in one_by_one:
        mine = np.flatnonzero(loop_region == r)
        k = int(mine[is_outer[mine]][0])
        order = [k, *[i for i in mine if i != k]]
        ids = np.concatenate([loops[i] for i in order])
        rings = [flat[first[i]:first[i] + length[i]] for i in order]
        _, tri = triangulate_polygon_2d(rings[0], rings[1:])
        if len(tri) != len(ids) + 2 * (len(order) - 1) - 2 or (tri >= len(ids)).any():
            failed.append(r)
            continue
        tris.append(ids[tri])
        tri_region.append(np.full(len(tri), r))
    tris = np.concatenate(tris)
    tri_region = np.concatenate(tri_region)
    zero = ~(np.linalg.norm(_cross(v, tris), axis=1) > 0)
    if zero.any():  # flip the (rare) zero-area triangles away, region by region
        for r in np.unique(tri_region[zero]):
            mine = tri_region == r
            flipped = _flip_flat_triangles(v, tris[mine])
            if flipped is None:
                failed.append(int(r))
            else:
                tris[mine] = flipped
    return _regions_done([*out, tris[~np.isin(tri_region, failed)]], failed + np.flatnonzero(bad | wrong).tolist())


def _regions_done(out, failed):
    if failed:
        return None, sorted(set(failed))
    return np.concatenate(out).astype(np.int64), []


def _region_loops(b_src, b_reg, key_in, o_order, k_sorted, fallback):
    """The boundary loops of every region: each as its vertices in order.

    Returns
    -------
    loops : list of (K_i,) int64
    loop_region : (L,) int64
    failed : list of int
        Non-fallback regions whose boundary does not close into loops.
    """
    # next boundary edge of the same region: the outgoing edge at this edge's end vertex
    pos = np.minimum(np.searchsorted(k_sorted, key_in), len(k_sorted) - 1)
    nxt = o_order[pos]
    ok = k_sorted[pos] == key_in
    failed: list[int] = []
    loops, loop_region = [], []
    seen = np.zeros(len(b_src), bool)
    for start in range(len(b_src)):
        if seen[start]:
            continue
        r = int(b_reg[start])
        loop = []
        e = start
        broken = False
        while not seen[e]:
            seen[e] = True
            loop.append(b_src[e])
            if not ok[e]:
                broken = True
                break
            e = nxt[e]
        if broken or e != start:
            if not fallback[r]:
                failed.append(r)
            continue
        loops.append(np.array(loop, np.int64))
        loop_region.append(r)
    return loops, np.array(loop_region, np.int64), failed


def _pymeshlab_repair(vertices, faces, source):
    """pymeshlab's repair, in a child process (:mod:`meshsom.meshlab_repair`: in a worker thread, as the
    pipelines run this, pymeshlab corrupts the process's heap)."""
    import importlib.util

    from meshsom.meshlab_repair import repair

    if importlib.util.find_spec("pymeshlab") is None:  # not imported here: importing loads its plugins
        raise MeshError(source, "repair requested but pymeshlab is not installed (pip install pymeshlab)")  # pragma: no cover

    return repair(vertices, faces, source)
