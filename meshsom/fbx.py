"""Reading FBX scenes (``.fbx``, binary or ASCII): city models exported for games and visualisation (Japan's PLATEAU
offers every city as FBX; Esri CityEngine, 3ds Max, Revit, Blender and SketchUp export it).

The scene is parsed by assimp (the Open Asset Import Library, through ``assimp-py``), its polygons triangulated and
equal vertices joined. Then:

- **Objects**: each node of the scene that holds meshes is one building, its meshes united, id
  ``<file>#<node name>`` (a name met again: ``<name> (2)``, ...; a node without a name: ``node-<k>``).
- **Placement**: each node's transform is composed from the root down (``Lcl Translation``, ``Rotation``,
  ``Scaling``, pivots), so that instances of one geometry stand where the scene puts them; a mirroring transform
  keeps the faces' sides (their order is turned).
- **Axes**: assimp turns the file's axis system (``GlobalSettings``: ``UpAxis``, ``FrontAxis``, ``CoordAxis`` and
  their signs) into its own, y up; meshsom turns that to z up (:data:`Y_UP_TO_Z_UP`, a proper rotation).
- **Units**: FBX counts in centimetres times ``UnitScaleFactor`` (:func:`unit_scale`: 100 for a scene in metres);
  assimp leaves coordinates in the file's unit, so meshsom scales them to metres. A file that names no unit is in
  centimetres, as the format says, noted.
- **CityEngine / PRT scenes**: Esri CityEngine (and PyPRT, its procedural runtime) writes a flat scene, the root
  holding one node per generated shape and inserted asset (``SingleBrick_175``, ``Glass_3``, ``YellowWall_4``: 673
  nodes for one building) and none for the building. In a file whose ``SceneInfo`` names CityEngine
  (:data:`CITYENGINE_MARK`), the root's models whose placed meshes touch or overlap (within :data:`TOUCH_TOL_M`)
  are one building (:func:`touching_groups`), its pieces kept as parts that preprocessing unites, noted; other FBX
  files keep the rule above.
- **Labels**: ``labels.csv`` beside the file (``file`` ``<name>`` or ``<name>#<node>``, ``label``), as for OBJ.
- **Georeferencing**: FBX has none; ``corpus.reader.crs`` names the CRS of the coordinates where they are in one.
- Lines and points are not surfaces: a node of only those is a rejection saying so.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: Centimetres per unit where a file names none (FBX's own unit).
DEFAULT_UNIT_SCALE = 1.0
#: Bytes at the start of a file looked at for its ``UnitScaleFactor`` (``GlobalSettings`` comes before the objects).
SETTINGS_SEARCH_BYTES = 1 << 22
#: assimp's frame (y up, right-handed) turned to meshsom's (z up): a quarter turn about x.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: What assimp puts in the names of the nodes it adds for a model's pivots and offsets (``house_$AssimpFbx$_Rotation``).
PIVOT_MARK = "_$AssimpFbx$_"
#: Names of nodes that hold one surface of a building (a scene written per surface: CityGML's thematic surfaces by
#: class, as converters name them, or by ids that start with the surface's kind, as PLATEAU's do: ``wall_...``,
#: ``roof_...``): such a node is part of the model above it, where there is one below the root and every model under
#: it holding meshes is so named (else it is a group of buildings).
SURFACE_NAME = re.compile(r"^(?:(?:Wall|Roof|Ground|Closure|OuterCeiling|OuterFloor|Floor|Ceiling)Surface|wall|roof|"
                          r"ground|closure)(?:$|[_\-\s.:#0-9])", re.IGNORECASE)
#: What a CityEngine or PRT export writes in its ``SceneInfo`` (``Original|ApplicationName`` "CityEngine", the
#: document's ``Subject`` "CityEngine 2020.0...", the vendor "Esri R&D Center Zurich Inc."), searched in the header.
CITYENGINE_MARK = re.compile(rb"CityEngine|Esri R&D Center Zurich")
#: Bytes at the start of a file searched for :data:`CITYENGINE_MARK` (the header extension comes first).
SCENE_INFO_BYTES = 1 << 16
#: Pieces of a CityEngine scene closer than this (metres) touch: assets are set on their shapes' faces, and the
#: scene's coordinates (LV03 or UTM, some 1e5-1e6 m, in doubles) carry them to well under a millimetre; 1 cm also
#: takes a frame set a hair off its wall, never a building across a street or a wall's thickness away.
TOUCH_TOL_M = 0.01
#: Boxes compared against all others at once in :func:`touching_groups` (a city scene of 50,000 pieces: 50,000 x 512
#: comparisons a step, not 2.5e9 at once).
TOUCH_BOX_ROWS = 512
#: Point-triangle pairs measured at once in :func:`_near_surface` (memory: some 200 bytes a pair).
TOUCH_PAIRS_CHUNK = 1 << 20
#: The start of a binary FBX file.
BINARY_MAGIC = b"Kaydara FBX Binary"
#: The unit's property in an ASCII file: ``P: "UnitScaleFactor", "double", "Number", "",100``.
_ASCII_UNIT = re.compile(rb'"UnitScaleFactor"\s*,\s*"[^"]*"\s*,\s*"[^"]*"\s*,\s*"[^"]*"\s*,\s*([-+0-9.eE]+)')


def unit_scale(head: bytes) -> float | None:
    """A file's ``UnitScaleFactor`` (centimetres per unit) from its first bytes, binary or ASCII; None where it names
    none (or a value that is not a positive number)."""
    if head.startswith(BINARY_MAGIC):
        at = head.find(b"UnitScaleFactor")
        # a P record's properties: S"UnitScaleFactor", S"double", S"Number", S"", then D (a double)
        while at >= 0:
            pos = at + len(b"UnitScaleFactor")
            for _ in range(4):
                if pos >= len(head):
                    break
                kind = head[pos:pos + 1]
                if kind == b"S" and pos + 5 <= len(head):
                    pos += 5 + struct.unpack_from("<I", head, pos + 1)[0]
                elif kind in (b"D", b"F") and pos + (9 if kind == b"D" else 5) <= len(head):
                    value = struct.unpack_from("<d" if kind == b"D" else "<f", head, pos + 1)[0]
                    return float(value) if np.isfinite(value) and value > 0 else None
                else:
                    break
            at = head.find(b"UnitScaleFactor", at + 1)
        return None
    match = _ASCII_UNIT.search(head)
    if match is None:
        return None
    try:
        value = float(match.group(1))
    except ValueError:
        return None
    return value if np.isfinite(value) and value > 0 else None


def read_fbx(path: Path, options, name: str | None = None) -> Iterator:
    """The buildings of an FBX scene: a RawMesh per node holding meshes (or a Rejection), as the module says.

    Raises
    ------
    InputFileError
        assimp is not installed, the file is larger than ``options.max_bytes``, assimp cannot parse it, or it holds
        no mesh.
    """
    from meshsom.io import (
        RawMesh, Rejection, _connected_pieces, _labels_beside, file_crs, free_id, library_input, placed_mesh,
        read_decompressed,
    )

    assimp_py, gzipped = library_input(path, options, "FBX", "assimp_py", "assimp-py")
    if gzipped:  # assimp reads files: the content, decompressed, in a temporary one
        yield from read_decompressed(path, options, name, read_fbx)
        return
    with open(path, "rb") as fh:
        head = fh.read(SETTINGS_SEARCH_BYTES)
    unit = unit_scale(head)
    cityengine = bool(CITYENGINE_MARK.search(head[:SCENE_INFO_BYTES]))
    notes = () if unit is not None else (
        "the file names no UnitScaleFactor: read in centimetres, FBX's own unit",)
    metres = (DEFAULT_UNIT_SCALE if unit is None else unit) / 100.0
    try:
        scene = assimp_py.import_file(str(path), assimp_py.Process_Triangulate | assimp_py.Process_JoinIdenticalVertices)
    except Exception as err:  # assimp says what it could not parse (RuntimeError)
        raise InputFileError(str(path), f"cannot be read as FBX ({str(err).split(': ', 1)[-1]})") from None
    meshes = [_triangles(m) for m in scene.meshes]
    labels = _labels_beside(path)
    label = labels.get(path.name)
    name = name or path.name
    crs = file_crs(None, options)
    placed_nodes = [(k, *n) for k, n in enumerate(_placed_nodes(scene.root_node)) if n[0].mesh_indices]
    mixed = {id(above[1]) for _, _, _, model, above in placed_nodes  # a group of buildings, not of one's surfaces
             if above is not None and not SURFACE_NAME.match(model[0])}
    owners: dict[int, list] = {}  # a building's node -> [its name, its pieces (placed vertices, faces)]
    for k, node, world, model, above in placed_nodes:
        surface = above is not None and id(above[1]) not in mixed and SURFACE_NAME.match(model[0])
        owner = above if surface else model
        entry = owners.setdefault(id(owner[1]), [owner[0] or f"node-{k}", []])
        for i in node.mesh_indices:
            if meshes[i] is None:
                continue
            vertices, faces = meshes[i]
            turn = Y_UP_TO_Z_UP @ world[:3, :3]
            placed = (vertices @ turn.T + Y_UP_TO_Z_UP @ world[:3, 3]) * metres
            if np.linalg.det(world[:3, :3]) < 0:  # mirrored: the faces' order turned so that they keep their side
                faces = faces[:, ::-1]
            entry[1].append((placed, np.ascontiguousarray(faces)))
    groups = _cityengine_buildings(list(owners.values())) if cityengine else [[entry] for entry in owners.values()]
    items, taken, item_parts = [], set(), {}
    for group in groups:
        node_name, parts = max(group, key=lambda entry: sum(len(f) for _, f in entry[1]))  # named by its largest piece
        key = free_id(node_name, taken) if node_name in taken else node_name  # a name met again: "<name> (2)"
        taken.add(key)
        mesh_id = f"{name}#{key}"
        item_label = labels.get(f"{path.name}#{key}", label)
        if not parts:
            items.append(Rejection(mesh_id, str(path), "holds no faces (only lines or points)", 0, item_label))
            continue
        if len(group) > 1:
            item_parts[mesh_id] = group
            parts = [piece for _, pieces in group for piece in pieces]
        vertices, faces = _united(parts)
        items.append((mesh_id, vertices, faces, item_label))
    if not items:
        raise InputFileError(str(path), "holds no mesh (an FBX scene of only cameras, lights or empty nodes)")
    pieces = []
    for item in items:
        if isinstance(item, Rejection) or not options.split_components:
            pieces.append(item)
        else:
            pieces.extend(_connected_pieces(*item))
    for item in pieces:
        if isinstance(item, Rejection):
            yield item
            continue
        mesh_id, v, f, item_label = item
        raw = placed_mesh(mesh_id, str(path), v, f, item_label, crs, notes, options)
        if mesh_id in item_parts and isinstance(raw, RawMesh):
            raw = _with_pieces(raw, item_parts[mesh_id], v, f)
        yield raw


def _with_pieces(raw, group: list, vertices: np.ndarray, faces: np.ndarray):
    """A CityEngine building's RawMesh with its pieces as parts (each face's piece; preprocessing unites them) and a
    note naming them (``vertices (V, 3)``, ``faces (F, 3)`` as :func:`_united` joined them, faces in the pieces' order)."""
    import dataclasses

    names = tuple(name or f"piece-{k}" for k, (name, _) in enumerate(group))
    counts = [sum(len(f) for _, f in pieces) for _, pieces in group]
    shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    note = (f"a CityEngine scene writes a building as a node per generated piece: {len(names)} root nodes whose meshes "
            f"touch or overlap (within {TOUCH_TOL_M:g} m) read as one building ({shown})")
    face_part = np.repeat(np.arange(len(names)), counts)
    if len(face_part) != len(raw.faces):  # pieces of no faces: the parts cannot be told, the mesh stays one
        return dataclasses.replace(raw, notes=raw.notes + (note,))
    return dataclasses.replace(raw, parts=names, face_part=face_part, notes=raw.notes + (note,))


def _cityengine_buildings(entries: list) -> list[list]:
    """The owners ``[name, [(placed vertices (V, 3), faces (F, 3)), ...]]`` of a CityEngine scene grouped into
    buildings: those whose pieces touch or overlap (:func:`touching_groups`), in the order of their first."""
    meshes = []
    for _, pieces in entries:
        if pieces:
            meshes.append((np.concatenate([v for v, _ in pieces]),
                           np.concatenate([f + o for (_, f), o in zip(pieces, np.cumsum([0] + [len(v) for v, _ in pieces]))])))
        else:
            meshes.append((np.zeros((0, 3)), np.zeros((0, 3), np.int64)))
    labels = touching_groups(meshes, TOUCH_TOL_M)
    grouped: dict[int, list] = {}
    for entry, group in zip(entries, labels):
        grouped.setdefault(int(group), []).append(entry)
    return list(grouped.values())


def touching_groups(meshes: list[tuple[np.ndarray, np.ndarray]], tol: float) -> np.ndarray:
    """Which meshes touch or overlap, transitively: union-find (connected components) over the pairs whose bounding
    boxes, grown by ``tol``, overlap and where a vertex of either lies within ``tol`` of the other's surface or one's
    box lies inside the other's (a piece set into another).

    Parameters
    ----------
    meshes : list of (vertices (V, 3) float, faces (F, 3) int)
    tol : float

    Returns
    -------
    (N,) int
        A group number per mesh (a mesh of no faces is alone).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(meshes)
    boxes = np.array([[v.min(axis=0), v.max(axis=0)] if len(f) else [[np.inf] * 3, [-np.inf] * 3] for v, f in meshes])
    lo, hi = boxes[:, 0] - tol, boxes[:, 1] + tol
    pairs = []
    for start in range(0, n, TOUCH_BOX_ROWS):  # rows of the box-against-box table at a time: memory O(rows x N)
        rows = np.arange(start, min(start + TOUCH_BOX_ROWS, n))
        near = np.all((lo[rows, None] <= hi[None]) & (lo[None] <= hi[rows, None]), axis=2) & (rows[:, None] < np.arange(n))
        r, c = np.nonzero(near)
        pairs.append((rows[r], c))
    i, j = (np.concatenate(side) for side in zip(*pairs)) if pairs else (np.zeros(0, int), np.zeros(0, int))
    inside = np.all((boxes[i, 0] >= lo[j]) & (boxes[i, 1] <= hi[j]), axis=1) | np.all(
        (boxes[j, 0] >= lo[i]) & (boxes[j, 1] <= hi[i]), axis=1)
    linked = [bool(a) or _touch(meshes[p], meshes[q], tol) for p, q, a in zip(i, j, inside)]
    i, j = i[np.asarray(linked, bool)], j[np.asarray(linked, bool)]
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _touch(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], tol: float) -> bool:
    """Whether a vertex of mesh ``a`` lies within ``tol`` of ``b``'s surface or one of ``b``'s of ``a``'s."""
    return _near_surface(a[0], b, tol) or _near_surface(b[0], a, tol)


def _near_surface(points: np.ndarray, mesh: tuple[np.ndarray, np.ndarray], tol: float) -> bool:
    """Whether any of ``points (P, 3)`` within the grown box of ``mesh`` (vertices (V, 3), faces (F, 3)) lies within
    ``tol`` of one of its triangles (first by scipy's cKDTree against its vertices, then point-triangle distances
    in chunks of :data:`TOUCH_PAIRS_CHUNK`)."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point

    vertices, faces = mesh
    lo, hi = vertices.min(axis=0) - tol, vertices.max(axis=0) + tol
    points = points[np.all((points >= lo) & (points <= hi), axis=1)]
    if len(points) == 0:
        return False
    if np.isfinite(cKDTree(vertices).query(points, distance_upper_bound=tol)[0]).any():
        return True
    triangles = vertices[faces]
    tri_lo, tri_hi = triangles.min(axis=1) - tol, triangles.max(axis=1) + tol
    step = max(1, TOUCH_PAIRS_CHUNK // max(len(triangles), 1))
    for start in range(0, len(points), step):
        chunk = points[start:start + step]
        p, t = np.nonzero(np.all((chunk[:, None] >= tri_lo[None]) & (chunk[:, None] <= tri_hi[None]), axis=2))
        if len(p) and (np.linalg.norm(closest_point(triangles[t], chunk[p]) - chunk[p], axis=1) <= tol).any():
            return True
    return False


def _triangles(mesh) -> tuple[np.ndarray, np.ndarray] | None:
    """``(vertices (V, 3) float64, faces (F, 3) int64)`` of an assimp mesh, or None where its faces are not
    triangles (lines, points)."""
    if mesh.num_faces == 0 or mesh.num_indices != 3 * mesh.num_faces:
        return None
    vertices = np.asarray(mesh.vertices, np.float64).reshape(-1, 3)
    faces = np.asarray(mesh.indices, np.int64).reshape(-1, 3)
    return vertices, faces


def _united(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """One mesh of a building's pieces (its meshes, its surfaces' nodes), vertices at the same place one vertex (the
    surfaces of a scene written per surface meet at their edges)."""
    if len(parts) == 1:
        return parts[0]
    offsets = np.cumsum([0] + [len(v) for v, _ in parts])
    vertices = np.concatenate([v for v, _ in parts])
    faces = np.concatenate([f + o for (_, f), o in zip(parts, offsets)])
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[faces]


def _placed_nodes(root) -> list:
    """Every node of a scene with its transform from the root (4 x 4, the root's own included), the model it is or
    helps (``(name, node)``: a pivot helper's is its model's) and the nearest other model above that one, below the
    root (or None), depth first."""
    out, stack = [], [(root, np.eye(4), None, None)]
    while stack:
        node, parent, model, above = stack.pop()
        world = parent @ np.asarray(node.transformation, np.float64).reshape(4, 4)
        own = node.name.split(PIVOT_MARK)[0]
        if model is None or own != model[0]:  # a model of its own (else a helper's chain goes on)
            above, model = (model if model is not None and model[1] is not root else None), (own, node)
        out.append((node, world, model, above))
        stack.extend((child, world, model, above) for child in reversed(list(node.children)))
    return out
