"""Reading Rhino models (``.3dm``): one mesh per building, through McNeel's openNURBS (rhino3dm).

Rhino (with Grasshopper) is where computational designers model; a massing study or a design
variant is a ``.3dm`` of closed polysurfaces, extrusions, meshes and block instances. Rhino 3 to 8
files are read (openNURBS reads each older version).

- **Buildings**: each model-space object of a solid kind is one building: a polysurface or surface
  (Brep), an extrusion (its Brep form), a mesh, or a block instance (every object of its
  definition, nested blocks included, placed by the instance's transformation). Objects that share
  a Rhino *group* are one building of several parts (``name#<group name>``), which preprocessing
  unites (:mod:`meshsom.union`), as Rhino users group the volumes of one building. Other objects
  (curves, points, annotations, hatches, lights, SubDs) are not buildings: counted by kind in a
  note on the file's meshes (a SubD, which openNURBS cannot evaluate, is a rejection saying how to
  convert it).
- **Polysurfaces**: a Brep whose faces are all planar (a massing model's are) is triangulated from
  its topology: each face's loops walked through their trims, each edge as its polyline (a straight
  edge by its two ends, a curved one sampled at :data:`EDGE_SAMPLES_PER_SPAN` points per span, the
  same points for the two faces that share it, so the faces join watertight), the outer loop and
  its holes triangulated in the face's plane (:func:`meshsom.polygons.triangulate_polygon_3d`) and
  turned to the face's side (its surface normal, reversed where the face is). A Brep with a curved
  face (a barrel roof, a round tower) is read from the render meshes Rhino saved with it (Rhino
  meshes shared edges alike; an extrusion's render mesh is kept on the extrusion). One saved
  without them ("Save small", or written by a script with rhino3dm) is tessellated here where its
  curved faces are untrimmed (cylinders, cones, vaults, spheres, lofts: :meth:`_Model._curved_face`,
  the planar faces as above, the shared edges' points on both sides, so it closes); a trimmed
  curved face (a hole in a round wall) without a render mesh is a rejection saying what to do.
- **Units**: the model's unit system (``Settings.ModelUnitSystem``), scaled to metres
  (:data:`METRES_PER_UNIT`); a model of no unit is read as metres, noted. Rhino is z-up.
- **Labels**: :attr:`meshsom.io.ReaderOptions.label_attribute` names an object's user text (the
  object's attribute user string, else its geometry's); ``"layer"`` labels each building by its
  layer's full path.
- **Ids**: ``name#<object name>`` where the object's name is set and unique in the file, else
  ``name#<object id>`` (its GUID); ``name#<group name>`` (else the group's index) for a group.
  With :attr:`meshsom.io.ReaderOptions.split_components` (a district exported as one object, as
  city-model services export their building layers) each connected piece of an object is a
  building, ``...#cN``.

Vertices are read one by one through rhino3dm's Python objects (it exposes no arrays): a mesh of
90,000 vertices in 1.5 s, 1,000 box polysurfaces in 2.7 s (2 cores, AMD EPYC). A damaged file is
refused from its top-level chunks (:func:`chunk_damage`) before openNURBS, which would search it
byte by byte for its tables, sees it.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: The bytes every Rhino model starts with.
MAGIC = b"3D Geometry File Format"
#: Metres per unit of each of Rhino's unit systems (``rhino3dm.UnitSystem`` names).
METRES_PER_UNIT = {
    "Angstroms": 1e-10, "Nanometers": 1e-9, "Microns": 1e-6, "Millimeters": 1e-3, "Centimeters": 1e-2,
    "Decimeters": 0.1, "Meters": 1.0, "Dekameters": 10.0, "Hectometers": 100.0, "Kilometers": 1e3,
    "Megameters": 1e6, "Gigameters": 1e9, "Microinches": 2.54e-8, "Mils": 2.54e-5, "Inches": 0.0254,
    "Feet": 0.3048, "Yards": 0.9144, "Miles": 1609.344, "NauticalMiles": 1852.0, "PrinterPoints": 0.0254 / 72,
    "PrinterPicas": 0.0254 / 6,
}
#: Unit systems that say nothing of the model's size: read as metres, noted.
NO_UNITS = ("None", "Unset", "CustomUnits")
#: Points per span of a curved edge's NURBS form (a quarter circle: one span, 8 points, 11.25 degrees).
EDGE_SAMPLES_PER_SPAN = 8
#: Points of one curved edge at most.
EDGE_MAX_SAMPLES = 1024
#: Points of each side of a curved face's domain, to find where its edges' points lie on it.
SIDE_SAMPLES = 257
#: Golden-section steps refining a point's parameter on a side (0.618^24: 1e-5 of two dense steps).
GOLDEN_STEPS = 24
GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
#: Block instances nested deeper than this are a rejection (a definition that names itself).
MAX_BLOCK_DEPTH = 32
#: Tolerance of "planar" and "linear", in model units, where the model gives none.
DEFAULT_TOLERANCE = 1e-6


#: Bytes of a 3dm header: :data:`MAGIC`, a space, the version right-aligned in 8 characters.
HEADER_BYTES = 32
#: A top-level chunk: its type code (uint32), then its length (int32 before version 5, int64 since).
TCODE_BYTES = 4
#: The type-code bit of a short chunk, whose value is its data (no content follows).
TCODE_SHORT = 0x80000000
#: The type code of the chunk that ends a model.
TCODE_ENDOFFILE = 0x00007FFF


def chunk_damage(data: bytes) -> str | None:
    """What is wrong with a 3dm file's top-level chunks (the tables openNURBS reads in turn), or None.

    Checked before openNURBS sees the file: where a chunk's length runs past the end of the file or
    the end-of-file chunk is missing, openNURBS searches the rest byte by byte for a table it can
    read, which takes it tens of seconds on a file of tens of kilobytes.

    Parameters
    ----------
    data : bytes
        The whole file.
    """
    version_text = bytes(data[len(MAGIC):HEADER_BYTES]).strip()
    if not version_text.isdigit():
        return f"its header's version is {version_text!r}, expected a number"
    version = int(version_text)
    length_bytes = 8 if version >= 50 else 4  # openNURBS: 64-bit chunk lengths from version 50 (Rhino 5) on
    at, end = HEADER_BYTES, len(data)
    while at + TCODE_BYTES + length_bytes <= end:
        tcode = int.from_bytes(data[at:at + TCODE_BYTES], "little")
        length = int.from_bytes(data[at + TCODE_BYTES:at + TCODE_BYTES + length_bytes], "little", signed=True)
        start = at + TCODE_BYTES + length_bytes
        if tcode & TCODE_SHORT:
            at = start
            continue
        if length < 0 or start + length > end:
            return (f"the chunk of type {tcode:#010x} at byte {at:,} claims {length:,} bytes and the file has {end - start:,} "
                    "more (truncated, or corrupt)")
        at = start + length
        if tcode == TCODE_ENDOFFILE:
            return None
    return f"it ends at byte {end:,} without its end-of-file chunk (truncated?)"


class _Unreadable(Exception):
    """One object cannot be made a mesh: the reason, in words."""


def read_3dm(path: Path, options, name: str | None = None) -> Iterator:
    """Read every building of a Rhino model (as the module says): RawMesh or Rejection items.

    Raises
    ------
    InputFileError
        Larger than ``options.max_bytes`` (gzip undone), not a Rhino model openNURBS can read, or
        no object of a solid kind in model space.
    """
    from meshsom.io import RawMesh, Rejection, _in_metres, file_crs, recentre

    try:
        import rhino3dm
    except ImportError as err:
        raise InputFileError(str(path), f"is a Rhino model and rhino3dm is not importable ({err})") from None
    from meshsom.io import read_input_bytes

    data = read_input_bytes(path, options)  # gzip undone, max_bytes applied
    if not data.startswith(MAGIC):
        raise InputFileError(str(path), f"is not a Rhino model (starts {bytes(data[:24])!r}, expected {MAGIC.decode()!r})")
    damage = chunk_damage(data)
    if damage:
        raise InputFileError(str(path), f"is a damaged Rhino model: {damage}")
    model = rhino3dm.File3dm.FromByteArray(data)  # the buffer itself, not a copy
    del data
    if model is None:
        raise InputFileError(str(path), "cannot be read as a Rhino model by openNURBS (damaged, or newer than Rhino 8)")
    name = name or path.name
    unit = model.Settings.ModelUnitSystem.name
    notes: list[str] = []
    if unit in METRES_PER_UNIT:
        scale = METRES_PER_UNIT[unit]
        if unit != "Meters":
            notes.append(f"model units: {unit.lower()}, scaled to metres")
    elif unit in NO_UNITS:
        scale = 1.0
        notes.append(f"the model's unit system is {unit}: read as metres")
    else:
        raise InputFileError(str(path), f"its unit system is {unit!r}; expected one of {', '.join(METRES_PER_UNIT)}")
    crs = file_crs(None, options)
    if crs[0] is not None and scale != 1.0:  # a CRS given: coordinates are in its units, scaled by it
        notes = [n for n in notes if not n.startswith("model units")]
        notes.append(f"model units ({unit.lower()}) not applied: coordinates read in the units of the CRS given ({crs[0].name})")
        scale = 1.0
    tolerance = float(model.Settings.ModelAbsoluteTolerance) or DEFAULT_TOLERANCE
    reader = _Model(model, rhino3dm, tolerance)
    buildings, skipped = reader.buildings()
    if not buildings:
        kinds = ", ".join(f"{k} x {n}" for k, n in sorted(skipped.items())) or "nothing"
        raise InputFileError(str(path), f"holds no polysurface, extrusion, mesh or block instance in model space: {kinds}")
    if skipped:
        notes.append("not buildings, not read: " + ", ".join(f"{k} x {n}" for k, n in sorted(skipped.items())))
    for key, members in buildings:
        label = reader.label(members[0], options.label_attribute)
        mesh_id = f"{name}#{key}"
        pieces, parts = [], []
        try:
            for obj in members:
                part = reader.mesh(obj.Geometry, np.eye(4), 0)
                if len(part[1]):
                    pieces.append(part)
                    parts.append(str(obj.Attributes.Id))
        except _Unreadable as err:
            yield Rejection(mesh_id, str(path), str(err), 0, label)
            continue
        except Exception as err:  # openNURBS, SciPy's Qhull or NumPy on geometry they cannot handle
            yield Rejection(mesh_id, str(path), f"its geometry cannot be made a mesh ({type(err).__name__}: {err})", 0, label)
            continue
        if not pieces:
            yield Rejection(mesh_id, str(path), "holds no faces", 0, label)
            continue
        offsets = np.cumsum([0] + [len(v) for v, _ in pieces])
        vertices = np.concatenate([v for v, _ in pieces]) * scale
        faces = np.concatenate([f + o for (_, f), o in zip(pieces, offsets)])
        united = {}
        if len(pieces) > 1:  # a group or a block of several objects: parts that preprocessing unites
            united = {"parts": tuple(parts), "face_part": np.repeat(np.arange(len(pieces)), [len(f) for _, f in pieces])}
            split = [(mesh_id, vertices, faces, label)]
        elif options.split_components:  # a district modelled as one object: a building per connected piece
            from meshsom.io import _connected_pieces

            split = _connected_pieces(mesh_id, vertices, faces, label)
        else:
            split = [(mesh_id, vertices, faces, label)]
        for piece_id, v, f, _ in split:
            if len(v) > int(options.max_vertices):
                yield Rejection(piece_id, str(path), f"has {len(v):,} vertices, more than {int(options.max_vertices):,} "
                                                     "(ReaderOptions.max_vertices)", len(f), label)
                continue
            local, origin = recentre(v)
            try:
                local, more = _in_metres(piece_id, local, origin, crs)
            except InputFileError as err:
                yield Rejection(piece_id, str(path), err.problem, len(f), label)
                continue
            said = notes + more + reader.notes(members) + ([f"one of {len(split)} connected pieces of its object "
                                                            "(split_components)"] if len(split) > 1 else [])
            yield RawMesh(piece_id, str(path), local, f, origin, label, None, notes=tuple(said), **united)


class _Model:
    """An opened model: its objects, blocks and layers, and the meshes of its geometry."""

    def __init__(self, model, rhino3dm, tolerance: float):
        self.model, self.rhino3dm, self.tolerance = model, rhino3dm, tolerance
        self.objects = {str(o.Attributes.Id): o for o in model.Objects}
        self.definitions = {str(d.Id): d for d in model.InstanceDefinitions}
        self.layers = {layer.Index: layer.FullPath for layer in model.Layers}
        self.groups = {group.Index: group.Name for group in model.Groups}
        self.used: dict[str, list[str]] = {}
        kinds = rhino3dm.ObjectType
        self.solid = {kinds.Brep, kinds.Extrusion, kinds.Mesh, kinds.InstanceReference, kinds.Surface, kinds.SubD}

    def buildings(self) -> tuple[list[tuple[str, list]], Counter]:
        """``[(id, [objects])]`` in file order (a group where its first member comes), and the
        model-space objects that are not buildings, counted by kind."""
        skipped: Counter = Counter()
        members: dict[str, list] = {}
        names = Counter(o.Attributes.Name for o in self.objects.values() if o.Attributes.Name)
        for obj in self.model.Objects:
            attributes = obj.Attributes
            if attributes.IsInstanceDefinitionObject:
                continue
            kind = obj.Geometry.ObjectType
            if kind not in self.solid:
                skipped[kind.name] += 1
                continue
            groups = list(attributes.GetGroupList() or [])
            if groups:
                group = min(groups)
                key = self.groups.get(group) or f"group {group}"
            elif attributes.Name and names[attributes.Name] == 1:
                key = attributes.Name
            else:
                key = str(attributes.Id)
            members.setdefault(key, []).append(obj)
        return list(members.items()), skipped

    def label(self, obj, attribute: str) -> str | None:
        if attribute == "layer":
            return self.layers.get(obj.Attributes.LayerIndex)
        value = obj.Attributes.GetUserString(attribute) or obj.Geometry.GetUserString(attribute)
        return value or None

    def notes(self, members: list) -> list[str]:
        out = []
        if len(members) > 1:
            out.append(f"{len(members)} objects of one group, read as the parts of one building")
        for obj in members:
            kind = obj.Geometry.ObjectType
            if kind == self.rhino3dm.ObjectType.InstanceReference:
                definition = self.definitions.get(str(obj.Geometry.ParentIdefId))
                out.append(f"block instance of {definition.Name!r}" if definition is not None else "block instance")
        return out

    # ---------------------------------------------------------------------------------- geometry

    def mesh(self, geometry, transform: np.ndarray, depth: int) -> tuple[np.ndarray, np.ndarray]:
        """One object's triangles: vertices (V, 3) float64 in model units placed by ``transform``
        (4, 4), faces (F, 3) int64.

        Raises
        ------
        _Unreadable
            A curved polysurface without render meshes, a SubD, a block that nests too deep or
            names a definition the file lacks.
        """
        kinds = self.rhino3dm.ObjectType
        kind = geometry.ObjectType
        if kind == kinds.Mesh:
            vertices, faces = _mesh_arrays(geometry)
        elif kind == kinds.Extrusion:
            brep = geometry.ToBrep(False)
            if brep is None:
                raise _Unreadable("is an extrusion with no polysurface form")
            saved = geometry.GetMesh(self.rhino3dm.MeshType.Any)  # Rhino keeps an extrusion's render mesh on it
            vertices, faces = self.brep(brep, saved)
        elif kind == kinds.Brep:
            vertices, faces = self.brep(geometry)
        elif kind == kinds.Surface:
            brep = self.rhino3dm.Brep.CreateFromSurface(geometry)
            if brep is None:
                raise _Unreadable("is a surface with no polysurface form")
            vertices, faces = self.brep(brep)
        elif kind == kinds.InstanceReference:
            return self.instance(geometry, transform, depth)
        elif kind == kinds.SubD:
            raise _Unreadable("is a SubD, which openNURBS cannot evaluate; convert it in Rhino (ToNURBS, or Mesh) and save again")
        else:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        if np.linalg.det(transform[:3, :3]) < 0:  # a mirrored block: faces keep their side
            faces = faces[:, ::-1]
        return _placed(vertices, transform), faces

    def instance(self, reference, transform: np.ndarray, depth: int) -> tuple[np.ndarray, np.ndarray]:
        if depth >= MAX_BLOCK_DEPTH:
            raise _Unreadable(f"is a block instance nested more than {MAX_BLOCK_DEPTH} deep (a block that holds itself?)")
        definition = self.definitions.get(str(reference.ParentIdefId))
        if definition is None:
            raise _Unreadable(f"is an instance of block {reference.ParentIdefId}, which the file does not define")
        xform = reference.Xform
        placed = transform @ np.array([[getattr(xform, f"M{i}{j}") for j in range(4)] for i in range(4)], np.float64)
        pieces = []
        for object_id in definition.GetObjectIds():
            obj = self.objects.get(str(object_id))
            if obj is not None:
                pieces.append(self.mesh(obj.Geometry, placed, depth + 1))
        pieces = [p for p in pieces if len(p[1])]
        if not pieces:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        offsets = np.cumsum([0] + [len(v) for v, _ in pieces])
        return np.concatenate([v for v, _ in pieces]), np.concatenate([f + o for (_, f), o in zip(pieces, offsets)])

    def brep(self, brep, saved=None) -> tuple[np.ndarray, np.ndarray]:
        """A polysurface's triangles (as the module says): (V, 3) float64, (F, 3) int64. ``saved``
        is the render mesh of the object it was made from (an extrusion's), used for curved faces."""
        faces = [brep.Faces[k] for k in range(len(brep.Faces))]
        planar = [face.IsPlanar(self.tolerance) for face in faces]
        if not all(planar):
            if saved is not None:
                return _mesh_arrays(saved)
            meshes = [face.GetMesh(self.rhino3dm.MeshType.Any) for face in faces]
            if all(m is not None for m in meshes):
                pieces = [_mesh_arrays(m) for m in meshes]
                offsets = np.cumsum([0] + [len(v) for v, _ in pieces])
                return np.concatenate([v for v, _ in pieces]), np.concatenate([f + o for (_, f), o in zip(pieces, offsets)])
        edges: dict[int, np.ndarray] = {}
        vertices, triangles, count = [], [], 0
        for face, flat in zip(faces, planar):
            points, found = (self._planar_face if flat else self._curved_face)(brep, face, edges)
            if len(found):
                vertices.append(points)
                triangles.append(found + count)
                count += len(points)
        if not vertices:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        return np.concatenate(vertices), np.concatenate(triangles).astype(np.int64)

    def _edge(self, brep, edges: dict, index: int) -> np.ndarray:
        if index not in edges:
            edges[index] = self._edge_points(brep.Edges[index])
        return edges[index]

    def _planar_face(self, brep, face, edges: dict) -> tuple[np.ndarray, np.ndarray]:
        """A planar face's triangles from its loops' edges (as the module says): points (P, 3), triangles (T, 3)."""
        from meshsom.polygons import triangulate_polygon_3d

        rings = []
        for loop in (face.Loops[k] for k in range(len(face.Loops))):
            if loop.LoopType.name not in ("Outer", "Inner"):
                continue  # slits, curves and points on the surface bound nothing
            ring = []
            for trim in (loop.Trims[k] for k in range(len(loop.Trims))):
                if trim.EdgeIndex < 0:
                    continue  # a singular trim (a pole): no edge
                points = self._edge(brep, edges, trim.EdgeIndex)
                ring.append((points[::-1] if trim.IsReversed else points)[:-1])
            if ring:
                ring = np.concatenate(ring)
                (rings.insert(0, ring) if loop.LoopType.name == "Outer" else rings.append(ring))
        if not rings or len(rings[0]) < 3:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        found = triangulate_polygon_3d(rings)
        points = np.concatenate(rings)
        if len(found):
            tri = points[found]
            if np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(axis=0) @ self._face_normal(face) < 0:
                found = found[:, ::-1]
        return points, found

    def _curved_face(self, brep, face, edges: dict) -> tuple[np.ndarray, np.ndarray]:
        """A curved face without a render mesh, tessellated here where it is untrimmed (its one loop
        runs along its surface's domain, as a cylinder's, a cone's, a vault's or a sphere's does):
        its boundary is its edges' polylines (the points its neighbours use), each point put at its
        place on the domain's side (the nearest of :data:`SIDE_SAMPLES` points of that side,
        refined by a golden-section search), the inside a grid of the surface's points
        (:data:`EDGE_SAMPLES_PER_SPAN` per span), all triangulated in the domain (Delaunay) and
        turned to the face's side.

        Raises
        ------
        _Unreadable
            The face is trimmed (a hole, or a loop inside its domain).
        """
        from scipy.spatial import Delaunay

        domain = [face.Domain(0), face.Domain(1)]
        (u0, u1), (v0, v1) = [(d.T0, d.T1) for d in domain]
        loops = [face.Loops[k] for k in range(len(face.Loops))]
        trimmed = _Unreadable("is a polysurface with a trimmed curved face and no render mesh (saved with 'Save small', "
                              "or written by a script): open it in Rhino and save it with render meshes, or export it as OBJ")
        if len(loops) != 1:
            raise trimmed
        t = np.linspace(0.0, 1.0, SIDE_SAMPLES)
        sides = {"v0": np.column_stack([u0 + t * (u1 - u0), np.full_like(t, v0)]),
                 "u1": np.column_stack([np.full_like(t, u1), v0 + t * (v1 - v0)]),
                 "v1": np.column_stack([u1 - t * (u1 - u0), np.full_like(t, v1)]),
                 "u0": np.column_stack([np.full_like(t, u0), v1 - t * (v1 - v0)])}
        images = {name: self._points(face, uv) for name, uv in sides.items()}
        size = max(float(np.ptp(np.concatenate(list(images.values())), axis=0).max()), self.tolerance)
        reach = max(4.0 / SIDE_SAMPLES * size, 10 * self.tolerance)  # a side's dense points are this close to it
        ring_uv, ring_xyz, previous = [], [], None
        for trim in (loops[0].Trims[k] for k in range(len(loops[0].Trims))):
            if trim.EdgeIndex < 0:
                continue  # a singular side (a pole): its neighbours end at the pole
            points = self._edge(brep, edges, trim.EdgeIndex)
            points = points[::-1] if trim.IsReversed else points
            distance = {name: np.sqrt(((points[:, None] - image[None]) ** 2).sum(-1)).min(axis=1).max() for name, image in images.items()}
            candidates = [name for name, d in distance.items() if d <= reach]
            if not candidates:
                raise trimmed
            uvs = {name: self._side_params(face, sides[name], images[name], points) for name in candidates}
            name = min(candidates, key=lambda c: 0.0 if previous is None else float(np.abs(uvs[c][0] - previous).sum()))
            ring_uv.append(uvs[name][:-1])
            ring_xyz.append(points[:-1])
            previous = uvs[name][-1]
        if not ring_uv:
            raise trimmed
        spans = face.ToNurbsSurface()
        counts = [int(np.clip(EDGE_SAMPLES_PER_SPAN * max(int(spans.SpanCount(d)) if spans else 1, 1), 2, EDGE_MAX_SAMPLES))
                  for d in (0, 1)]
        for name, side in sides.items():  # a side that is a point (a pole, an apex): its trim has no edge
            if np.ptp(images[name], axis=0).max() <= reach:
                levels = np.linspace(0.0, 1.0, counts[0 if name[0] == "v" else 1] + 1)
                along = side[0] + levels[:, None] * (side[-1] - side[0])
                ring_uv.append(along)
                ring_xyz.append(np.repeat(images[name][:1], len(along), axis=0))
        gu, gv = np.meshgrid(np.linspace(u0, u1, counts[0] + 1)[1:-1], np.linspace(v0, v1, counts[1] + 1)[1:-1], indexing="ij")
        inside = np.column_stack([gu.ravel(), gv.ravel()])
        uv = np.concatenate(ring_uv + [inside])
        unit = (uv - [u0, v0]) / [u1 - u0, v1 - v0]
        triangles = Delaunay(unit).simplices.astype(np.int64)
        a, b, c = (unit[triangles[:, k]] for k in range(3))
        ccw = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        triangles[ccw < 0] = triangles[ccw < 0][:, ::-1]  # counter-clockwise in the domain: the surface's normal
        if face.OrientationIsReversed:
            triangles = triangles[:, ::-1]
        points = np.concatenate(ring_xyz + [self._points(face, inside)])
        return points, triangles

    def _points(self, face, uv: np.ndarray) -> np.ndarray:
        """The surface's points at parameters ``uv`` (K, 2): (K, 3) float64."""
        found = [face.PointAt(float(u), float(v)) for u, v in uv]
        return np.array([[p.X, p.Y, p.Z] for p in found], np.float64).reshape(-1, 3)

    def _side_params(self, face, side_uv: np.ndarray, image: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The parameters (K, 2) on one side of the domain of ``points`` (K, 3) on its image: the
        nearest of the side's dense points, refined by a golden-section search between its neighbours."""
        distance = np.sqrt(((points[:, None] - image[None]) ** 2).sum(-1))
        nearest = distance.argmin(axis=1)
        near = distance <= distance.min(axis=1, keepdims=True) + 1e-9 * (1.0 + distance.max())
        nearest[0] = np.flatnonzero(near[0])[0]  # a closed side (a circle) starts and ends at one point:
        nearest[-1] = np.flatnonzero(near[-1])[-1]  # its trim runs from the side's start to its end
        out = side_uv[nearest].copy()
        last = len(side_uv) - 1
        for k, (p, j) in enumerate(zip(points, nearest.tolist())):
            lo, hi = side_uv[max(j - 1, 0)], side_uv[min(j + 1, last)]
            a, b = 0.0, 1.0
            gap = lambda s: float(((self._points(face, (lo + s * (hi - lo))[None])[0] - p) ** 2).sum())  # noqa: E731
            for _ in range(GOLDEN_STEPS):
                c, d = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
                if gap(c) < gap(d):
                    b = d
                else:
                    a = c
            out[k] = lo + 0.5 * (a + b) * (hi - lo)
        return out

    def _face_normal(self, face) -> np.ndarray:
        """The side a face faces: its surface's normal at the middle of its domain, reversed where the face is."""
        u, v = face.Domain(0), face.Domain(1)
        n = face.NormalAt(0.5 * (u.T0 + u.T1), 0.5 * (v.T0 + v.T1))
        normal = np.array([n.X, n.Y, n.Z], np.float64)
        return -normal if face.OrientationIsReversed else normal

    def _edge_points(self, edge) -> np.ndarray:
        """An edge as a polyline from its start to its end: (K, 3) float64, K >= 2 (a curved one at
        :data:`EDGE_SAMPLES_PER_SPAN` points per span of its NURBS form: a circle's four spans, 32)."""
        if edge.IsLinear(self.tolerance):
            ends = (edge.PointAtStart, edge.PointAtEnd)
            return np.array([[p.X, p.Y, p.Z] for p in ends], np.float64)
        domain = edge.Domain
        nurbs = edge.ToNurbsCurve()
        spans = max(int(edge.SpanCount), int(nurbs.SpanCount) if nurbs is not None else 1, 1)
        count = int(np.clip(EDGE_SAMPLES_PER_SPAN * spans, 2, EDGE_MAX_SAMPLES))
        points = [edge.PointAt(t) for t in np.linspace(domain.T0, domain.T1, count + 1)]
        return np.array([[p.X, p.Y, p.Z] for p in points], np.float64)


def _mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """A Rhino mesh's vertices (V, 3) float64 (double precision where it keeps them) and its
    triangles (F, 3) int64 (each quad split along its 0-2 diagonal)."""
    vertices = mesh.Vertices
    points = [vertices.Point3dAt(k) for k in range(len(vertices))]
    v = np.array([[p.X, p.Y, p.Z] for p in points], np.float64).reshape(-1, 3)
    quads = np.array([tuple(mesh.Faces[k]) for k in range(len(mesh.Faces))], np.int64).reshape(-1, 4)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[quads[:, 2] != quads[:, 3]][:, [0, 2, 3]]])
    return v, triangles


def _placed(vertices: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """``vertices`` (V, 3) moved by the homogeneous ``transform`` (4, 4)."""
    if np.array_equal(transform, np.eye(4)):
        return vertices
    h = vertices @ transform[:3, :3].T + transform[:3, 3]
    w = vertices @ transform[3, :3] + transform[3, 3]
    return h / w[:, None]
