"""IFC building models (BIM: Revit, ArchiCAD, Vectorworks, Allplan, BlenderBIM exports) as one
closed envelope per ``IfcBuilding``, read with IfcOpenShell.

A BIM model is not a surface of the building but a set of elements: walls, slabs, roofs, windows,
doors, columns, stairs, each a closed solid, with rooms, furniture and ducts inside. meshsom's
building is the outer surface of what its walls, slabs and roofs enclose:

1. The elements of each ``IfcBuilding`` (its storeys' contents and parts, recursively) whose class
   is one of :data:`~meshsom.io.IFC_ENVELOPE_CLASSES` (``ReaderOptions.ifc_classes``) are triangulated by IfcOpenShell
   in world coordinates (metres, whatever the file's unit) with openings left closed: a wall is
   whole where its windows and doors are, so the envelope has no holes where a window was left out.
   Spaces, furniture, building services, openings, the site's terrain and annotations are never
   part of it.
2. Each element is welded and must be a closed, oriented volume (the common case); one that is not
   goes through :func:`meshsom.preprocess.close_surface` (capped, closed, oriented), and one that still is not (a door leaf
   modelled as open surfaces, a railing of lines) is left out, counted by class in the mesh's notes.
3. Elements of real models miss each other by hairlines (a gable wall's top a millimetre under
   the roof slab, at a slightly other slope): a crack that the union would keep, leading from
   outside into the attic. So each element is grown by half of ``ReaderOptions.ifc_gap`` (default
   1 cm; :func:`meshsom.offset.mitered_offset`, every plane moved by exactly that), the union is
   taken and its shells are shrunk back by as much: gaps narrower than ``ifc_gap`` close, planar
   walls end where they were.
4. The elements are united by manifold3d (:mod:`meshsom.union`'s boolean); of the union's shells,
   the rooms (shells facing inwards, negative volume) and whatever stands free inside another
   shell (a column or a stair in a room) are dropped: what remains is what one sees from outside.
5. Where the file places its project in a map CRS (``IfcMapConversion``, IFC4 and later), the
   envelope is moved there (eastings, northings, height, the rotation of the x axis, the scale), and
   the CRS's name is noted; otherwise it stays in the project's own frame (noted too).

A file without an ``IfcBuilding`` (a model exported from a tool that writes only storeys, or only
elements) is one building of all its elements. Buildings that hold no element of those classes are
rejected by name, with the classes they do hold.
"""

from __future__ import annotations

import math
import os
import tempfile
import zipfile
from collections import Counter
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError, MeshError
from meshsom.offset import mitered_offset
from meshsom.io import (GZIP_SUFFIX, IFC_ENVELOPE_CLASSES, IFC_SUFFIXES, RawMesh, ReaderOptions, Rejection,
                        read_input_bytes, recentre)

__all__ = ["IFC_ENVELOPE_CLASSES", "IFC_SUFFIXES", "read_ifc", "winding_number"]

#: Elements are welded at this share of their bounding-box diagonal (IfcOpenShell writes each
#: face's corners apart, for normals).
WELD_SHARE = 1e-9
#: Geometry threads IfcOpenShell may use (at most the CPUs this process may run on).
MAX_GEOMETRY_THREADS = 8
#: The first line of a STEP physical file.
STEP_MAGIC = b"ISO-10303-21"
#: The last statement of a STEP physical file.
STEP_END = b"END-ISO-10303-21"


def _ifcopenshell(path: Path):
    try:
        import ifcopenshell
        import ifcopenshell.geom
        import ifcopenshell.util.element
    except ImportError as err:  # pragma: no cover - a declared dependency
        raise InputFileError(str(path), f"reading IFC needs IfcOpenShell: pip install ifcopenshell ({err})") from None
    return ifcopenshell


def read_ifc(path: Path, options: ReaderOptions = ReaderOptions(), name: str | None = None
             ) -> Iterator[RawMesh | Rejection]:
    """Read every ``IfcBuilding`` of an IFC file as one envelope mesh, id ``name#GlobalId``.

    Parameters
    ----------
    path : Path
        ``.ifc`` (``.ifc.gz``) or ``.ifczip``.
    options : ReaderOptions
        ``ifc_classes``: the element classes of the envelope; ``ifc_gap``: gaps between elements
        closed; ``max_bytes`` and ``max_expansion``.
    name : str, optional
        The start of the ids (default: the file name).

    Yields
    ------
    RawMesh or Rejection
        A building mesh (vertices about ``origin``, notes on what was left out and where it was
        placed), or a building that has no closed element of those classes.

    Raises
    ------
    InputFileError
        When the file is not an IFC file IfcOpenShell can read.
    """
    ifcopenshell = _ifcopenshell(path)
    name = name or path.name
    model = _open_model(path, options, ifcopenshell)
    wanted = _envelope_elements(model, options.ifc_classes)
    groups = _building_groups(model, wanted, ifcopenshell)
    if not groups:
        raise InputFileError(str(path), f"an IFC file ({model.schema}) without elements of the envelope classes "
                                        f"({', '.join(options.ifc_classes)}); it holds {_class_list(model)}")
    try:
        shapes = _triangulated(model, [e for _, members in groups for e in members], ifcopenshell)
    except Exception as err:  # IfcOpenShell's geometry kernel raises RuntimeError and its own errors
        raise InputFileError(str(path), f"IfcOpenShell cannot triangulate its elements ({type(err).__name__}: {err})") from None
    placement, placed_note = _map_conversion(model)
    for building, members in groups:
        mesh_id = f"{name}#{building.GlobalId}" if building is not None else f"{name}#model"
        what = f"IfcBuilding {building.Name!r}" if building is not None and building.Name else "the model"
        try:
            vertices, faces, shell_of, notes = _envelope(members, shapes, mesh_id, options.ifc_gap)
        except MeshError as err:
            yield Rejection(mesh_id, str(path), f"{what}: {err.problem}")
            continue
        vertices = placement(vertices)
        local, origin = recentre(vertices)
        shells = int(shell_of.max()) + 1
        # several shells (a canopy apart from the house, wings that touch along an edge) go as parts:
        # preprocessing keeps each shell's vertices its own (meshsom.union), never welding them together
        parts = tuple(f"shell {k + 1}" for k in range(shells)) if shells > 1 else ()
        yield RawMesh(mesh_id, str(path), local, faces, origin, parts=parts,
                      face_part=shell_of if parts else None, notes=(*notes, placed_note))


def _open_model(path: Path, options: ReaderOptions, ifcopenshell):
    """The parsed file: ``.ifc`` opened in place, ``.ifc.gz`` and ``.ifczip`` unpacked to a
    temporary file first (IfcOpenShell parses files)."""
    lower = path.name.lower()
    if lower.endswith(".ifczip"):
        try:
            with zipfile.ZipFile(path) as archive:
                members = [i for i in archive.infolist() if i.filename.lower().endswith(".ifc") and not i.is_dir()]
                if len(members) != 1:
                    raise InputFileError(str(path), f"an IFC-ZIP archive must hold one .ifc file; it holds {len(members)}")
                if members[0].file_size > options.max_bytes:
                    raise InputFileError(str(path), f"its IFC file is {members[0].file_size} bytes, more than "
                                                    f"max_bytes ({options.max_bytes})")
                content = archive.read(members[0])
        except zipfile.BadZipFile as err:
            raise InputFileError(str(path), f"not a zip archive ({err}); an .ifczip file is a zip of one .ifc file") from None
    elif lower.endswith(GZIP_SUFFIX):
        content = bytes(read_input_bytes(path, options))
    else:
        with open(path, "rb") as fh:
            head = fh.read(64)
            fh.seek(max(0, os.fstat(fh.fileno()).st_size - 1024))
            tail = fh.read()
        _check_step(path, head, tail)
        return _parse(path, str(path), ifcopenshell)
    _check_step(path, content[:64], content[-1024:])
    with tempfile.NamedTemporaryFile(suffix=".ifc", delete=False) as tmp:
        tmp.write(content)
    try:
        return _parse(path, tmp.name, ifcopenshell)
    finally:
        os.unlink(tmp.name)


def _check_step(path: Path, head: bytes, tail: bytes) -> None:
    """A STEP file starts with ``ISO-10303-21;`` and ends with ``END-ISO-10303-21;``: IfcOpenShell
    reads a file cut short without a word, as the buildings of its first part."""
    if not head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(STEP_MAGIC):
        shown = head[:24].decode("latin-1").encode("unicode_escape").decode()
        raise InputFileError(str(path), f"not an IFC file: a STEP file (.ifc) starts with {STEP_MAGIC.decode()!r}; "
                                        f"this one starts with {shown!r} (IFC-XML and IFC-JSON are not read)")
    if STEP_END not in tail:
        shown = tail.rstrip()[-40:].decode("latin-1").encode("unicode_escape").decode()
        raise InputFileError(str(path), f"truncated: an IFC file ends with {STEP_END.decode()!r}; this one ends "
                                        f"with {shown!r} (a download or export cut short?)")


def _parse(path: Path, filename: str, ifcopenshell):
    try:
        return ifcopenshell.open(filename)
    except Exception as err:  # IfcOpenShell raises its own errors, RuntimeError and OSError
        raise InputFileError(str(path), f"IfcOpenShell cannot parse it ({type(err).__name__}: {err})") from None


def _envelope_elements(model, classes) -> list:
    """Elements of ``classes`` (and subclasses) that have a representation, each once, in file order."""
    found = {}
    for cls in classes:
        try:
            elements = model.by_type(cls)
        except RuntimeError:  # not in this schema
            continue
        for e in elements:
            if getattr(e, "Representation", None) is not None:
                found[e.id()] = e
    return [found[k] for k in sorted(found)]


def _building_groups(model, wanted: list, ifcopenshell) -> list[tuple]:
    """(IfcBuilding or None, its wanted elements) for every building with any. Elements under no
    building are one group (None) where the file has no building with any; otherwise they stand
    on the site beside the buildings (a garden wall) and are not read."""
    util = ifcopenshell.util.element
    wanted_ids = {e.id() for e in wanted}
    groups, taken = [], set()
    for building in model.by_type("IfcBuilding"):
        members = sorted((e for e in util.get_decomposition(building) if e.id() in wanted_ids and e.id() not in taken),
                         key=lambda e: e.id())  # (a set: the union's order, and so its rounding, fixed)
        taken.update(e.id() for e in members)
        if members:
            groups.append((building, members))
    rest = [e for e in wanted if e.id() not in taken]
    if rest and not groups:
        groups.append((None, rest))
    return groups


def _class_list(model) -> str:
    counts = Counter(e.is_a() for e in model.by_type("IfcProduct") if getattr(e, "Representation", None) is not None)
    if not counts:
        return "no element with geometry"
    return ", ".join(f"{n} {cls}" for cls, n in counts.most_common(8)) + (" ..." if len(counts) > 8 else "")


def _triangulated(model, elements: list, ifcopenshell) -> dict:
    """{element id: ((V, 3) float64 metres, (F, 3) int64)} for the elements IfcOpenShell can
    triangulate, in world coordinates, openings not cut."""
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    settings.set("disable-opening-subtractions", True)
    settings.set("weld-vertices", True)
    try:
        threads = max(1, min(MAX_GEOMETRY_THREADS, len(os.sched_getaffinity(0))))
    except AttributeError:  # pragma: no cover - not Linux
        threads = max(1, min(MAX_GEOMETRY_THREADS, os.cpu_count() or 1))
    shapes = {}
    if not elements:
        return shapes
    iterator = ifcopenshell.geom.iterator(settings, model, threads, include=elements)
    if not iterator.initialize():
        return shapes
    while True:
        shape = iterator.get()
        geometry = shape.geometry
        vertices = np.asarray(geometry.verts, np.float64).reshape(-1, 3)
        faces = np.asarray(geometry.faces, np.int64).reshape(-1, 3)
        if len(faces):
            shapes[shape.id] = (vertices, faces)
        if not iterator.next():
            break
    return shapes


def _closed_solid(vertices: np.ndarray, faces: np.ndarray, params):
    """An element as a closed volume facing outwards: ((V, 3), (F, 3)), or None."""
    from meshsom.preprocess import close_surface, weld
    from meshsom.topology import edge_table, signed_volume

    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    if not diag > 0:
        return None
    v, remap = weld(vertices, WELD_SHARE * diag)
    f = remap[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    if len(f) >= 4:
        _, _, counts = edge_table(f)
        if (counts == 2).all():  # the common case: closed as IfcOpenShell wrote it
            volume = signed_volume(v, f)
            if volume != 0:
                return v, (f if volume > 0 else f[:, ::-1])
    try:
        return close_surface(vertices, faces, params)
    except MeshError:
        return None


def _envelope(members: list, shapes: dict, mesh_id: str, gap: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """The outer surface of the union of ``members``' solids, each grown by ``gap / 2`` (and the
    union shrunk back by as much: gaps narrower than ``gap`` closed): vertices (V, 3), faces
    (F, 3), the shell of every face (F,), and notes on what went."""
    from meshsom.preprocess import PreprocessParams
    from meshsom.union import _manifold3d

    manifold3d = _manifold3d()
    params = PreprocessParams()
    solids, used, no_geometry, not_closed = [], Counter(), Counter(), Counter()
    every = np.concatenate([shapes[e.id()][0] for e in members if e.id() in shapes]) if any(
        e.id() in shapes for e in members) else np.zeros((0, 3))
    if not len(every):
        raise MeshError(mesh_id, f"IfcOpenShell made no geometry of its {len(members)} envelope elements "
                                 f"({_counted(Counter(e.is_a() for e in members))})")
    centre = (every.min(axis=0) + every.max(axis=0)) / 2
    for e in members:
        if e.id() not in shapes:
            no_geometry[e.is_a()] += 1
            continue
        v, f = shapes[e.id()]
        solid = _closed_solid(v - centre, f, params)
        if solid is not None:
            body = manifold3d.Manifold(manifold3d.Mesh64(
                vert_properties=np.ascontiguousarray(mitered_offset(*solid, gap / 2), np.float64),
                tri_verts=np.ascontiguousarray(solid[1], np.uint64)))
            if body.status() == manifold3d.Error.NoError and not body.is_empty():
                solids.append(body)
                used[e.is_a()] += 1
                continue
        not_closed[e.is_a()] += 1
    if not solids:
        raise MeshError(mesh_id, f"none of its {len(members)} envelope elements is a closed volume "
                                 f"({_counted(not_closed + no_geometry)})")
    united = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if united.status() != manifold3d.Error.NoError or united.is_empty():
        raise MeshError(mesh_id, f"the union of its {len(solids)} elements failed ({united.status().name})")
    shells = []
    for piece in united.decompose():
        mesh = piece.to_mesh64()
        shells.append((np.asarray(mesh.vert_properties, np.float64)[:, :3],
                       np.asarray(mesh.tri_verts, np.int64).reshape(-1, 3), piece.volume()))
    outer = _outer_shells(shells)
    notes = [f"IFC: the union of {sum(used.values())} elements ({_counted(used)})"]
    if not_closed:
        notes.append(f"IFC: {sum(not_closed.values())} elements that are not closed volumes left out ({_counted(not_closed)})")
    if no_geometry:
        notes.append(f"IFC: {sum(no_geometry.values())} elements without geometry from IfcOpenShell ({_counted(no_geometry)})")
    inner = len(shells) - len(outer)
    if inner:
        notes.append(f"IFC: {inner} shells inside the envelope not kept (rooms, and what stands free in them)")
    kept = [_shrunk(shells[k][0], shells[k][1], gap / 2) for k in outer]
    grown = sum(v is None for v in kept)
    if grown:
        notes.append(f"IFC: {grown} of {len(outer)} shells left {1000 * gap / 2:g} mm outside the elements' faces "
                     f"(shrinking them back would fold features thinner than {1000 * gap:g} mm onto themselves)")
    pieces = [shells[k][:2] if done is None else done for k, done in zip(outer, kept)]
    offsets = np.cumsum([0] + [len(v) for v, _ in pieces])
    vertices = np.concatenate([v for v, _ in pieces]) + centre
    faces = np.concatenate([f + offsets[j] for j, (_, f) in enumerate(pieces)])
    shell_of = np.repeat(np.arange(len(pieces)), [len(f) for _, f in pieces])
    return vertices, faces, shell_of, notes


def _shrunk(vertices: np.ndarray, faces: np.ndarray, distance: float) -> tuple[np.ndarray, np.ndarray] | None:
    """A shell moved in by ``distance`` (the growth undone), or None where that turns a face over
    or brings two vertices together (a feature thinner than twice the distance). Edges shorter
    than ``distance`` (slivers where grown elements meet at a corner) are collapsed first."""
    from meshsom.preprocess import _collapse_short_edges, validate

    if distance == 0:
        return vertices, faces
    v, f = _collapse_short_edges(vertices, faces, distance, "shell", [])
    if validate(v, f) is None:
        vertices, faces = v, f
    moved = mitered_offset(vertices, faces, -distance)
    before = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    after = np.cross(moved[faces[:, 1]] - moved[faces[:, 0]], moved[faces[:, 2]] - moved[faces[:, 0]])
    if (np.einsum("ij,ij->i", before, after) <= 0).any():
        return None
    from scipy.spatial import cKDTree

    if len(cKDTree(moved).query_pairs(distance / 2)) > len(cKDTree(vertices).query_pairs(distance / 2)):
        return None
    return moved, faces


def _counted(counts: Counter) -> str:
    return ", ".join(f"{n} {cls}" for cls, n in counts.most_common())


def _outer_shells(shells: list) -> list[int]:
    """Indices of the shells seen from outside: facing outwards (positive volume) and not inside
    another such shell (a point of theirs has winding number 0 about every other).

    Parameters
    ----------
    shells : list of ((V, 3) float64, (F, 3) int64, float volume)
    """
    positive = [k for k, (_, _, vol) in enumerate(shells) if vol > 0]
    outer = []
    for k in positive:
        point = shells[k][0][shells[k][1][0]].mean(axis=0)  # a point on its surface
        inside = any(abs(winding_number(point, shells[j][0], shells[j][1])) > 0.5
                     for j in positive if j != k and shells[j][2] > shells[k][2])
        if not inside:
            outer.append(k)
    return outer


def winding_number(point: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> float:
    """The winding number of a closed, oriented triangle mesh about ``point``: 1 inside (outward
    faces), 0 outside (the sum of the triangles' signed solid angles over 4 pi; Van Oosterom and
    Strackee's formula).

    Parameters
    ----------
    point : (3,) float64
    vertices : (V, 3) float64
    faces : (F, 3) int64

    Returns
    -------
    float
    """
    a, b, c = (vertices[faces[:, k]] - point for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la
           + np.einsum("ij,ij->i", c, a) * lb)
    return float(2 * np.arctan2(det, den).sum() / (4 * math.pi))


def _map_conversion(model):
    """(placement function on (V, 3) arrays, note): where ``IfcMapConversion`` puts the project."""
    try:
        conversions = model.by_type("IfcMapConversion")
    except RuntimeError:  # IFC2X3 has none
        conversions = []
    if not conversions:
        return (lambda v: v), "IFC: no IfcMapConversion: placed in the project's own frame, not in a map CRS"
    c = conversions[0]
    scale = c.Scale if getattr(c, "Scale", None) else 1.0
    angle = math.atan2(c.XAxisOrdinate or 0.0, c.XAxisAbscissa or 1.0) if (
        getattr(c, "XAxisAbscissa", None) is not None or getattr(c, "XAxisOrdinate", None) is not None) else 0.0
    cos, sin = math.cos(angle), math.sin(angle)
    shift = np.array([c.Eastings, c.Northings, c.OrthogonalHeight or 0.0], np.float64)
    target = getattr(c, "TargetCRS", None)
    crs = getattr(target, "Name", None) or "an unnamed CRS"

    def place(v: np.ndarray) -> np.ndarray:
        x, y, z = v[:, 0], v[:, 1], v[:, 2]
        return np.stack([scale * (cos * x - sin * y), scale * (sin * x + cos * y), scale * z], axis=1) + shift

    return place, (f"IFC: placed by its IfcMapConversion in {crs} (eastings {c.Eastings:g}, northings "
                   f"{c.Northings:g}, x axis turned {math.degrees(angle):.6g} degrees, scale {scale:g})")
