"""IFC building models (BIM: Revit, ArchiCAD, Vectorworks, Allplan, BlenderBIM exports) as one
closed envelope per ``IfcBuilding``, read with IfcOpenShell.

A BIM model is not a surface of the building but a set of elements: walls, slabs, roofs, windows,
doors, columns, stairs, each a closed solid, with rooms, furniture and ducts inside. meshsom's
building is the outer surface of what its walls, slabs and roofs enclose:

1. The elements of each ``IfcBuilding`` (its storeys' contents and parts, recursively) whose class
   is one of :data:`~meshsom.io.IFC_ENVELOPE_CLASSES` (``ReaderOptions.ifc_classes``) are triangulated by IfcOpenShell
   in world coordinates (metres, whatever the file's unit) with openings left closed: a wall is
   whole where its windows and doors are, so the envelope has no holes where a window was left out.
   Instances of the abstract ``IfcBuildingElement`` (``IfcBuiltElement``), which cadwork writes for
   insulation, battens and boards, are read as proxies (noted). Spaces, furniture, building services,
   openings, the site's terrain and annotations are never part of it; the building's elements left out
   are counted by class in a note. A building of framing elements alone (beams, columns, members,
   plates: a steel frame) is rejected as a structural model before anything is triangulated.
2. Each element is welded and must be a closed, consistently oriented volume (the common case;
   :func:`meshsom.preprocess.validate`); one that is not goes through
   :func:`meshsom.preprocess.close_surface` (capped, closed, oriented), and one that still is not (a door leaf
   modelled as open surfaces, a railing of lines) is left out, counted by class in the mesh's notes.
3. Elements of real models miss each other by hairlines (a gable wall's top a millimetre under
   the roof slab, at a slightly other slope): a crack that the union would keep, leading from
   outside into the attic. So each element is grown by half of ``ReaderOptions.ifc_gap`` (default
   1 cm; :func:`meshsom.offset.mitered_offset`, every plane moved by exactly that) and the union is
   taken; manifold3d carries every face's id through it, so each face of the union is moved back
   onto the plane of the element face it lies on (:func:`_shrunk`): gaps narrower than ``ifc_gap``
   close, everything else is the union of the elements as drawn.
4. The elements are united by manifold3d (:mod:`meshsom.union`'s boolean); of the union's shells,
   the rooms (shells facing inwards, negative volume) and whatever stands free inside another
   shell (a column or a stair in a room) are dropped: what remains is what one sees from outside.
   A building whose union has no cavity of :data:`MIN_ROOM_VOLUME` encloses no room (walls without
   a roof, a timber frame whose windows are not in the file) and is rejected saying so.
5. Where the file places its project in a map CRS (``IfcMapConversion`` or
   ``IfcMapConversionScaled``, IFC4 and later; IFC2X3's ``ePSet_MapConversion``), the envelope is
   moved there (eastings, northings, height in the map's unit, the rotation of the x axis, the grid
   scale; the building keeps its size in metres), and the CRS's name is noted. Else, where its
   ``IfcSite`` gives a reference latitude and longitude (most exports do), the site's origin is
   put there in WGS 84's UTM zone, turned by the model's true north (noted with the EPSG code);
   otherwise it stays in the project's own frame (noted too).

A file without an ``IfcBuilding`` (a model exported from a tool that writes only storeys, or only
elements) is one building of all its elements. Buildings that hold no element of those classes are
rejected by name, with the classes they do hold.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
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

#: Geometry threads IfcOpenShell may use (at most the CPUs this process may run on).
MAX_GEOMETRY_THREADS = 8
#: Elements united at a time (manifold3d's batch union), the time taken checked between batches.
UNION_BATCH = 64
#: A map conversion's grid scale (its Scale over the ratio of the project's length unit to the
#: map's) further than this from 1 is not a grid scale but a unit written wrongly: not applied.
MAX_GRID_SCALE_OFF = 0.1
#: Metres per international foot and per US survey foot (a map unit named by name).
FOOT_M, US_SURVEY_FOOT_M = 0.3048, 1200.0 / 3937.0
#: The first line of a STEP physical file.
STEP_MAGIC = b"ISO-10303-21"
#: The last statement of a STEP physical file.
STEP_END = b"END-ISO-10303-21"
#: Abstract classes that some exporters write instances of, for elements they give no type (cadwork: insulation,
#: battens, boards): read as ``IfcBuildingElementProxy`` where that class is read.
IFC_UNTYPED_CLASSES = ("IfcBuildingElement", "IfcBuiltElement")
#: A building whose envelope elements are all of these classes is a structural model (a steel or timber frame of
#: Tekla, cadwork, GeometryGym): it encloses nothing and is rejected as such, where the classes read include an
#: enclosing one (:data:`IFC_ENCLOSING_CLASSES`).
IFC_FRAMING_CLASSES = ("IfcBeam", "IfcColumn", "IfcMember", "IfcPlate")
#: Classes that enclose a building: walls, slabs, roofs, curtain walls, coverings.
IFC_ENCLOSING_CLASSES = ("IfcWall", "IfcSlab", "IfcRoof", "IfcCurtainWall", "IfcCovering")
#: Elements of these classes are neither read nor counted as left out: the spatial structure and the openings.
IFC_NOT_ELEMENTS = ("IfcSpatialStructureElement", "IfcSpatialElement", "IfcOpeningElement", "IfcVirtualElement",
                    "IfcAnnotation", "IfcGrid")
#: Faces of elements are on one plane where their unit normals and offsets (metres) are this close (4D distance).
PLANE_TOLERANCE = 1e-6
#: A face of the grown union further than this share of the growth from its grown plane fixes no vertex.
PLANE_SLACK = 0.02
#: Vertices of the union moved back farther than this many growth distances: nearly parallel planes, the shell
#: kept grown (a corner of planes at a few degrees moves a few distances; a 45-degree chamfer grown to nothing, four).
MAX_MOVE = 20.0
#: Singular values of a vertex's planes below this share of the largest are taken for zero (one plane, or two).
RCOND_PLANES = 1e-6
#: Faces turned over less high than this share of the growth (over their longest side) are collapsed slivers,
#: not folds.
SLIVER_HEIGHT = 0.01
#: The shrunk shell's volume may differ from the grown one's less the growth times its area by this share of
#: that product (second-order terms at edges and corners are far smaller) where the product is at most
#: THICK_SHARE of the grown volume; a thinner shell (a bar, a sheet) may lose anything from nothing to
#: (1 + VOLUME_SLACK) times the product.
VOLUME_SLACK = 0.25
THICK_SHARE = 0.05
#: A union without a cavity of this many cubic metres (a closet) encloses no room: the cavities between the
#: layers of a timber wall or inside a steel tube are not rooms.
MIN_ROOM_VOLUME = 2.0
#: A union without rooms whose mean thickness (twice its volume over its area: a slab's thickness, a third of
#: a cube's side) is at least this many metres is a massing (solid blocks: urban design models, CityGML
#: converted to proxies), the building itself; walls, frames and details are thinner.
MIN_MASSING_THICKNESS = 1.0
#: manifold3d's simplification of a shell before and after it is shrunk, and the vertices it keeps apart at one
#: point (metres): only what moves nothing.
SIMPLIFY_TOLERANCE = 1e-7
#: Sweeps in which a vertex free along an edge or a face follows its neighbours when a shell is shrunk.
FREE_SWEEPS = 20
#: Rounds in which the points of faces that a shrink turns over are placed otherwise (at last left where they were).
KEEP_ROUNDS = 40


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
    if groups[0][0] is not None:  # a building of no envelope element beside others (a garage of spaces only): listed
        held = {b.id() for b, _ in groups}
        for building in model.by_type("IfcBuilding"):
            if building.id() not in held:
                what = f"IfcBuilding {building.Name!r}" if building.Name else "an IfcBuilding"
                kinds = Counter(e.is_a() for e in ifcopenshell.util.element.get_decomposition(building))
                yield Rejection(f"{name}#{building.GlobalId}", str(path), (
                    f"{what} holds no element of the envelope classes ({', '.join(options.ifc_classes)}); it holds "
                    + (", ".join(f"{n} {k}" for k, n in kinds.most_common(6)) or "nothing")))
    # a structural model is told by its classes before its elements are triangulated (Tekla's costmodell: 4,319
    # elements, minutes)
    enclosing = bool(set(options.ifc_classes) & set(IFC_ENCLOSING_CLASSES))  # an envelope is asked for
    framing = {id(members) for _, members in groups
               if enclosing and all(any(e.is_a(c) for c in IFC_FRAMING_CLASSES) for e in members)}
    try:
        shapes = _triangulated(model, [e for _, members in groups if id(members) not in framing for e in members],
                               ifcopenshell)
    except Exception as err:  # IfcOpenShell's geometry kernel raises RuntimeError and its own errors
        raise InputFileError(str(path), f"IfcOpenShell cannot triangulate its elements ({type(err).__name__}: {err})") from None
    shapes, unit_note = _in_metres(model, shapes)
    placement, placed_note = _placement(model)
    for building, members in groups:
        mesh_id = f"{name}#{building.GlobalId}" if building is not None else f"{name}#model"
        what = ("the model" if building is None else f"IfcBuilding {building.Name!r}" if building.Name
                else "its IfcBuilding (no name)")
        kinds = Counter(e.is_a() for e in members)
        if id(members) in framing:
            yield Rejection(mesh_id, str(path), (
                f"{what}: a structural model, {len(members)} framing elements ({_counted(kinds)}) and no "
                f"{', '.join(IFC_ENCLOSING_CLASSES)}: a frame encloses no building, it has no envelope"))
            continue
        try:
            vertices, faces, shell_of, notes = _envelope(members, shapes, mesh_id, options.ifc_gap,
                                                         rooms=building is not None and enclosing)
        except MeshError as err:
            yield Rejection(mesh_id, str(path), f"{what}: {err.problem}")
            continue
        vertices = placement(vertices)
        local, origin = recentre(vertices)
        shells = int(shell_of.max()) + 1
        # several shells (a canopy apart from the house, wings that touch along an edge) go as parts:
        # preprocessing keeps each shell's vertices its own (meshsom.union), never welding them together
        parts = tuple(f"shell {k + 1}" for k in range(shells)) if shells > 1 else ()
        notes = (*notes, *_left_out(building if building is not None else model, members, ifcopenshell))
        untyped = sum(n for k, n in kinds.items() if k in IFC_UNTYPED_CLASSES)
        if untyped:
            notes = (f"IFC: {untyped} elements of the abstract class {' or '.join(k for k in IFC_UNTYPED_CLASSES if kinds[k])} "
                     f"(elements the exporter gave no type: cadwork's insulation, battens, boards) read as "
                     f"IfcBuildingElementProxy", *notes)
        if building is None:  # a model of elements alone (a wall, a covering exported on its own) is no building
            notes = (f"the file has no IfcBuilding: its {len(members)} element(s) read as one building ("
                     + ", ".join(f"{k} x {n}" for k, n in kinds.most_common(6)) + ")", *notes)
        yield RawMesh(mesh_id, str(path), local, faces, origin, parts=parts,
                      face_part=shell_of if parts else None, notes=(*notes, *unit_note, placed_note))


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
            size = os.fstat(fh.fileno()).st_size
            if size > options.max_bytes:
                raise InputFileError(str(path), f"{size} bytes, more than max_bytes ({options.max_bytes})")
            head = fh.read(64)
            fh.seek(max(0, size - 1024))
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
    """Elements of ``classes`` (and subclasses) that have a representation, each once, in file order; with
    instances of the abstract :data:`IFC_UNTYPED_CLASSES` where ``IfcBuildingElementProxy`` is one of them."""
    found = {}
    untyped = IFC_UNTYPED_CLASSES if "IfcBuildingElementProxy" in classes else ()
    for cls, subtypes in [(c, True) for c in classes] + [(c, False) for c in untyped]:
        try:
            elements = model.by_type(cls, include_subtypes=subtypes)
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


def _left_out(holder, members: list, ifcopenshell) -> tuple[str, ...]:
    """A note on the elements with geometry of a building (or of a model without one) that are not read, by class
    (furniture, building services, railings, footings, fasteners...): () where there are none. The spatial
    structure and openings (:data:`IFC_NOT_ELEMENTS`) are not counted."""
    read = {e.id() for e in members}
    if isinstance(holder, ifcopenshell.entity_instance):
        held = ifcopenshell.util.element.get_decomposition(holder)
    else:  # the file
        held = holder.by_type("IfcProduct")
    kinds = Counter(e.is_a() for e in held if e.id() not in read and getattr(e, "Representation", None) is not None
                    and not any(e.is_a(c) for c in IFC_NOT_ELEMENTS))
    if not kinds:
        return ()
    shown = ", ".join(f"{n} {k}" for k, n in kinds.most_common(8)) + (" ..." if len(kinds) > 8 else "")
    return (f"IFC: {sum(kinds.values())} elements not of the envelope classes left out ({shown}): what stands in "
            f"or on a building, not what encloses it",)


def _triangulated(model, elements: list, ifcopenshell) -> dict:
    """{element id: ((V, 3) float64 metres, (F, 3) int64)} for the elements IfcOpenShell can
    triangulate, in world coordinates, openings not cut."""
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    settings.set("disable-opening-subtractions", True)
    settings.set("weld-vertices", True)
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cpus = os.cpu_count() or 1
    # a Dask worker is given one compute thread (OMP_NUM_THREADS, pipelines.cluster.WORKER_ENV)
    allowed = os.environ.get("OMP_NUM_THREADS", "")
    threads = max(1, min(MAX_GEOMETRY_THREADS, cpus, int(allowed) if allowed.isdigit() else cpus))
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


def _in_metres(model, shapes: dict) -> tuple[dict, tuple[str, ...]]:
    """The kernel's shapes in metres, and a note where they were not: IfcOpenShell's kernel converts the project's
    length unit to metres only where the file holds one context (``[GEO308] Not a single project or context in
    file``: an IfcProjectLibrary beside the IfcProject, as IfcOpenShell's own test models have) and otherwise leaves
    coordinates in that unit (a wall of 3000 x 300 x 2000 mm read as kilometres)."""
    import ifcopenshell.util.unit

    contexts = model.by_type("IfcContext") if model.schema != "IFC2X3" else model.by_type("IfcProject")
    if len(contexts) <= 1 or not shapes:
        return shapes, ()
    project_m = float(ifcopenshell.util.unit.calculate_unit_scale(model))
    if project_m == 1.0:
        return shapes, ()
    scaled = {k: (v * project_m, f) for k, (v, f) in shapes.items()}
    kinds = ", ".join(sorted({c.is_a() for c in contexts}))
    return scaled, (f"IFC: scaled to metres by its length unit ({project_m:g} m), which IfcOpenShell's kernel leaves "
                    f"unapplied in a file of {len(contexts)} contexts ({kinds})",)


def _closed_solid(vertices: np.ndarray, faces: np.ndarray, params):
    """An element as a closed volume facing outwards: ((V, 3), (F, 3)), or None.

    Most elements are closed and consistently oriented once welded (IfcOpenShell writes each
    face's corners apart, for normals): those are taken as they are (:func:`meshsom.preprocess.validate`
    says so, turned over where they face inwards); the rest go through
    :func:`meshsom.preprocess.close_surface` (capped, closed, oriented)."""
    from meshsom.preprocess import close_surface, validate, weld

    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))) if len(vertices) else 0.0
    if not diag > 0:
        return None
    v, remap = weld(vertices, params.weld_tol * diag)
    f = remap[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    problem = validate(v, f) if len(f) >= 4 else "too few faces"
    if problem is None:
        return v, f
    if problem.startswith("oriented inward"):
        return v, f[:, ::-1]
    try:
        return close_surface(vertices, faces, params)
    except MeshError:
        return None


def _envelope(members: list, shapes: dict, mesh_id: str, gap: float, rooms: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """The outer surface of the union of ``members``' solids, each grown by ``gap / 2`` (and the
    union shrunk back by as much: gaps narrower than ``gap`` closed): vertices (V, 3), faces
    (F, 3), the shell of every face (F,), and notes on what went. ``rooms``: a union that encloses
    no room (no cavity of :data:`MIN_ROOM_VOLUME`) is a MeshError (a building), not a note (elements alone)."""
    from meshsom.preprocess import PreprocessParams
    from meshsom.topology import signed_volume, vertex_pieces
    from meshsom.union import _manifold3d

    manifold3d = _manifold3d()
    params = PreprocessParams()
    solids, used, no_geometry, not_closed = [], Counter(), Counter(), Counter()
    planes = []  # (normals, offsets, areas) of every element's faces, as drawn: the faces' ids in the union
    drawn = [shapes[e.id()][0] for e in members if e.id() in shapes]
    if not drawn:
        raise MeshError(mesh_id, f"IfcOpenShell made no geometry of its {len(members)} envelope elements "
                                 f"({_counted(Counter(e.is_a() for e in members))})")
    every = np.concatenate(drawn)
    centre = (every.min(axis=0) + every.max(axis=0)) / 2
    first_face = 0
    for e in members:
        if e.id() not in shapes:
            no_geometry[e.is_a()] += 1
            continue
        v, f = shapes[e.id()]
        solid = _closed_solid(v - centre, f, params)
        if solid is not None:
            body = manifold3d.Manifold(manifold3d.Mesh64(
                vert_properties=np.ascontiguousarray(mitered_offset(*solid, gap / 2), np.float64),
                tri_verts=np.ascontiguousarray(solid[1], np.uint64),
                face_id=np.arange(first_face, first_face + len(solid[1]), dtype=np.uint64)))
            if body.status() == manifold3d.Error.NoError and not body.is_empty():
                solids.append(body)
                planes.append(_face_planes(*solid))
                first_face += len(solid[1])
                used[e.is_a()] += 1
                continue
        not_closed[e.is_a()] += 1
    if not solids:
        raise MeshError(mesh_id, f"none of its {len(members)} envelope elements is a closed volume "
                                 f"({_counted(not_closed + no_geometry)})")
    united = _united(solids, mesh_id, params.max_seconds, manifold3d)
    if united.status() != manifold3d.Error.NoError or united.is_empty():
        raise MeshError(mesh_id, f"the union of its {len(solids)} elements failed ({united.status().name})")
    # its shells found at once from its mesh (manifold3d's decompose took over 10 minutes for the thousands of shells
    # of a roof of 5,178 beams); manifold3d gives solids that touch vertices of their own
    mesh = united.to_mesh64()
    union_vertices = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    union_faces = np.asarray(mesh.tri_verts, np.int64)
    normals, offsets, plane_of = _plane_groups(planes)
    union_planes = plane_of[np.asarray(mesh.face_id, np.int64)]
    # each shell's vertices carry their index in the union (a 4th column), so its faces' planes are found again
    indexed = np.column_stack([union_vertices, np.arange(len(union_vertices))])
    pieces = vertex_pieces(indexed, union_faces)
    shells = [(v[:, :3], f, signed_volume(v[:, :3], f)) for v, f in pieces]
    shell_of_vertex = np.empty(len(union_vertices), np.int64)
    for k, (v, _) in enumerate(pieces):
        shell_of_vertex[v[:, 3].astype(np.int64)] = k
    shell_of_face = shell_of_vertex[union_faces[:, 0]]
    outer = _outer_shells(shells)
    notes = [f"IFC: the union of {sum(used.values())} elements ({_counted(used)})"]
    if not_closed:
        notes.append(f"IFC: {sum(not_closed.values())} elements that are not closed volumes left out ({_counted(not_closed)})")
    if no_geometry:
        notes.append(f"IFC: {sum(no_geometry.values())} elements without geometry from IfcOpenShell ({_counted(no_geometry)})")
    inner = len(shells) - len(outer)
    if inner:
        notes.append(f"IFC: {inner} shells inside the envelope not kept (rooms, and what stands free in them)")
    envelope_volume = sum(shells[k][2] for k in outer)
    largest_room = max([-vol for _, _, vol in shells if vol < 0], default=0.0)  # rooms face inwards
    envelope_area = sum(_face_planes(shells[k][0], shells[k][1])[2].sum() for k in outer)
    massing = 2 * envelope_volume >= MIN_MASSING_THICKNESS * envelope_area
    if largest_room < MIN_ROOM_VOLUME and massing:
        notes.append(f"IFC: its elements enclose no room but are solid blocks (a massing: {envelope_volume:.4g} m3, "
                     f"{2 * envelope_volume / envelope_area:.3g} m thick on average): the envelope is their union")
    elif largest_room < MIN_ROOM_VOLUME:
        held = (f"{envelope_volume:.4g} m3 of solid (grown by the gap closing), its largest cavity "
                f"{largest_room:.3g} m3")
        if rooms:
            raise MeshError(mesh_id, f"its {sum(used.values())} elements ({_counted(used)}) enclose no room: their "
                                     f"union is {held}, no envelope (a roof, windows or doors not in the file, or "
                                     f"openings and gaps wider than ifc_gap, {1000 * gap:g} mm, lead from outside into "
                                     f"the rooms)")
        notes.append(f"IFC: its elements enclose no room: the envelope is their solids alone ({held}; openings or "
                     f"gaps wider than {1000 * gap:g} mm lead from outside into any rooms)")
    kept = [_shrunk(shells[k][0], shells[k][1], union_planes[shell_of_face == k], normals, offsets, gap / 2, manifold3d)
            for k in outer]
    why = Counter(done for done in kept if isinstance(done, str))
    if why:
        notes.append(f"IFC: {sum(why.values())} of {len(outer)} shells left {1000 * gap / 2:g} mm outside the elements' "
                     f"faces (not moved back onto the elements' planes: {'; '.join(why)})")
    pieces = [shells[k][:2] if isinstance(done, str) else done for k, done in zip(outer, kept)]
    flat = sum(len(f) == 0 for _, f in pieces)
    if flat == len(pieces):
        raise MeshError(mesh_id, f"its {sum(used.values())} elements ({_counted(used)}) have no volume as drawn: "
                                 f"sheets of no thickness, solids only once grown by the gap closing")
    if flat:
        notes.append(f"IFC: {flat} shells of no volume as drawn left out (elements of no thickness)")
        pieces = [piece for piece in pieces if len(piece[1])]
    starts = np.cumsum([0] + [len(v) for v, _ in pieces])
    vertices = np.concatenate([v for v, _ in pieces]) + centre
    faces = np.concatenate([f + starts[j] for j, (_, f) in enumerate(pieces)])
    shell_of = np.repeat(np.arange(len(pieces)), [len(f) for _, f in pieces])
    return vertices, faces, shell_of, notes


def _united(solids: list, mesh_id: str, seconds: float, manifold3d):
    """The union of manifold3d ``solids``, :data:`UNION_BATCH` at a time and then the batches', within ``seconds``
    (:attr:`meshsom.preprocess.PreprocessParams.max_seconds`; 0: no limit): a model of thousands of intersecting
    members (a roof of 5,178 beams) is a rejection saying so, not a read that never ends.

    Raises
    ------
    MeshError
        Past ``seconds``, checked between batches.
    """
    start = time.monotonic()
    while len(solids) > 1:
        merged = []
        for k in range(0, len(solids), UNION_BATCH):
            if seconds and time.monotonic() - start > seconds:
                raise MeshError(mesh_id, f"the union of its elements took more than {seconds:g} s "
                                         f"(preprocess.max_seconds), stopped with {len(solids) - k + len(merged)} "
                                         f"pieces left: too many intersecting elements for one envelope")
            merged.append(manifold3d.Manifold.batch_boolean(solids[k:k + UNION_BATCH], manifold3d.OpType.Add))
            merged[-1].num_tri()  # manifold3d evaluates lazily: the union is made here, where its time is checked
        solids = merged
    return solids[0]


def _face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each face's edge cross product (F, 3) float64: its normal times twice its area (zero for a face of no area,
    where :func:`meshsom.folds.face_normals` would divide by it)."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


def _face_planes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plane of every face: unit normals (F, 3) float64 (zero for a face of no area), offsets (F,)
    float64 (``n . x`` on the plane, metres) and areas (F,) float64."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = _face_cross(vertices, faces)
    double_area = np.linalg.norm(cross, axis=1)
    normals = cross / np.where(double_area > 0, double_area, 1.0)[:, None]
    return normals, np.einsum("ij,ij->i", normals, (a + b + c) / 3), double_area / 2


def _plane_groups(planes: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct planes of the elements' faces (faces on one plane, of one element or of several flush
    ones, share it; told apart at :data:`PLANE_DECIMALS`), each the area-weighted mean of its faces'.

    Parameters
    ----------
    planes : list of ((F_i, 3) float64, (F_i,) float64, (F_i,) float64)
        Each element's :func:`_face_planes`, in the order of the faces' ids.

    Returns
    -------
    normals : (P, 3) float64
        Unit normals; zero for a plane of faces without area (no plane).
    offsets : (P,) float64
    plane_of : (F,) int64
        The plane of every face id.
    """
    from meshsom.preprocess import weld

    if not planes:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)
    normal, offset, area = (np.concatenate(p) for p in zip(*planes))
    distinct, plane_of = weld(np.column_stack([normal, offset]), PLANE_TOLERANCE)
    count = len(distinct)
    weight = np.bincount(plane_of, area, count)
    normals = np.stack([np.bincount(plane_of, area * normal[:, k], count) for k in range(3)], axis=1)
    length = np.linalg.norm(normals, axis=1)
    normals = np.where(length[:, None] > 0, normals / np.where(length > 0, length, 1.0)[:, None], 0.0)
    offsets = np.bincount(plane_of, area * offset, count) / np.where(weight > 0, weight, 1.0)
    return normals, offsets, plane_of


def _shrunk(vertices: np.ndarray, faces: np.ndarray, plane: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
            distance: float, manifold3d) -> tuple[np.ndarray, np.ndarray] | str:
    """A shell of the union of grown elements with every face moved back onto the plane of the element face it
    lies on (the growth undone: the union of the elements as drawn, its gaps narrower than twice ``distance``
    closed), or why not.

    The shell is first simplified by manifold3d (faces of one plane merged, the vertices inside them and on
    straight edges dropped), so that every vertex left is a corner of three or more planes; each moves to the
    least-squares point of its faces' planes as drawn (exact where three meet). Faces that collapse (the
    slivers and chamfers where grown elements meet) are removed by manifold3d.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        Closed, oriented outwards.
    plane : (F,) int64
        Each face's plane, an index into ``normals`` and ``offsets`` (:func:`_plane_groups`).
    normals : (P, 3) float64
    offsets : (P,) float64
    distance : float
        How far the elements were grown (metres).

    Returns
    -------
    ((V', 3) float64, (F', 3) int64) or str
        The shrunk shell (empty where nothing is left: elements drawn flat), or why it was not shrunk.
    """
    from meshsom.preprocess import weld

    if distance == 0:
        return vertices, faces
    shell = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.array(vertices, np.float64, order="C"), tri_verts=np.array(faces, np.uint64, order="C"),
        face_id=np.array(plane, np.uint64, order="C"))).simplify(SIMPLIFY_TOLERANCE)
    mesh = shell.to_mesh64()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int64)
    p = np.asarray(mesh.face_id, np.int64)
    grown_volume, grown_area = shell.volume(), shell.surface_area()
    # a face that does not lie on its plane grown (an element whose mitered offset is not exact) fixes nothing
    off = np.abs(np.einsum("fkj,fj->fk", v[f], normals[p]) - offsets[p][:, None] - distance).max(axis=1)
    on_plane = (off <= PLANE_SLACK * distance) & (np.abs(normals[p]).sum(axis=1) > 0)
    # vertices at one point (manifold3d keeps apart the sheets of a shell that touch there) move as one
    at, point = weld(v, SIMPLIFY_TOLERANCE)
    points = len(at)
    pairs = np.unique(np.column_stack([point[f[on_plane].reshape(-1)], np.repeat(p[on_plane], 3)]), axis=0)
    # (a point of faces none of which lies on its plane has none: it is free, and follows its neighbours)
    n = normals[pairs[:, 1]]
    gap = offsets[pairs[:, 1]] - np.einsum("ij,ij->i", n, at[pairs[:, 0]])
    matrix = np.zeros((points, 3, 3))
    rhs = np.zeros((points, 3))
    np.add.at(matrix, pairs[:, 0], n[:, :, None] * n[:, None, :])
    np.add.at(rhs, pairs[:, 0], n * gap[:, None])
    solve = np.linalg.pinv(matrix, rcond=RCOND_PLANES, hermitian=True)
    fixed = np.einsum("vij,vj->vi", solve, rhs)
    # a point on an edge (two planes) or inside a face (one) that simplification kept is free along them: it
    # follows its neighbours there (so that it stays between the corners that bound it), a few Jacobi sweeps
    free = np.eye(3) - np.einsum("vij,vjk->vik", solve, matrix)
    loose = np.abs(free).max(axis=(1, 2)) > RCOND_PLANES
    move = fixed
    edges = np.unique(np.sort(point[np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])], axis=1), axis=0)
    edges = edges[edges[:, 0] != edges[:, 1]]
    length = np.sqrt(np.sum((at[edges[:, 0]] - at[edges[:, 1]]) ** 2, axis=1))
    if loose.any():
        from scipy import sparse

        # the nearest neighbours weigh most: a point a hair from a corner moves with it
        weight = 1.0 / np.maximum(length, SIMPLIFY_TOLERANCE) ** 2
        adjacency = sparse.coo_matrix((np.concatenate([weight, weight]), (np.concatenate([edges[:, 0], edges[:, 1]]),
                                       np.concatenate([edges[:, 1], edges[:, 0]]))), shape=(points, points)).tocsr()
        degree = np.asarray(adjacency.sum(axis=1)).reshape(-1, 1)
        for _ in range(FREE_SWEEPS):
            mean = adjacency @ move / np.where(degree > 0, degree, 1.0)
            move = np.where(loose[:, None], fixed + np.einsum("vij,vj->vi", free, mean), fixed)
    # where faces turn over, their free points try, round by round: no move along their planes; the place of
    # their nearest corner (the sliver between them collapses); their place in the union. Their corners last
    # stay in the union too: the shell stays grown there alone
    nearest = np.arange(points)
    ends, end_length = np.concatenate([edges, edges[:, ::-1]]), np.tile(length, 2)
    towards_corner = loose[ends[:, 0]] & ~loose[ends[:, 1]]
    ends, end_length = ends[towards_corner], end_length[towards_corner]
    order = np.lexsort((end_length, ends[:, 0]))  # by point, the shortest edge first
    first = order[np.unique(ends[order, 0], return_index=True)[1]]
    nearest[ends[first, 0]] = ends[first, 1]
    tries = [move, fixed, (at[nearest] + move[nearest]) - at, np.zeros_like(move)]
    stage = np.zeros(points, np.int64)  # the try each point is at; past the last, its faces' corners stay too
    before = _face_cross(v, f)
    turned = np.zeros(len(f), bool)
    for _ in range(KEEP_ROUNDS):
        chosen = np.choose(np.minimum(stage, len(tries) - 1)[:, None], tries)
        moved = v + chosen[point]
        turned = _turned_over(before, moved, f, SLIVER_HEIGHT * distance)
        if not turned.any():
            break
        corners = np.unique(point[f[turned].reshape(-1)])
        free_corners = corners[loose[corners] & (stage[corners] < len(tries) - 1)]
        if len(free_corners):
            stage[free_corners] += 1
        else:
            stage[corners] = len(tries) - 1
    else:
        return f"{int(turned.sum())} faces turned over"
    result = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(moved),
                                                   tri_verts=np.ascontiguousarray(f, np.uint64)))
    result = result.simplify(SIMPLIFY_TOLERANCE)
    # to first order the volume lost is the distance times the area; more or less is a shell gone wrong
    if result.status() != manifold3d.Error.NoError:
        return f"manifold3d: {result.status().name}"
    if result.is_empty():  # elements drawn flat (a sheet of no thickness), closed by the growth alone
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    # the growth took about the distance times the area (a thick shell: within VOLUME_SLACK of that), never more
    # than (1 + VOLUME_SLACK) times it, never less than nothing (a thin one: its edges' and corners' share is large)
    taken, expected = grown_volume - result.volume(), distance * grown_area
    thick = expected <= THICK_SHARE * grown_volume
    if not (0 <= taken <= (1 + VOLUME_SLACK) * expected) or (thick and abs(taken - expected) > VOLUME_SLACK * expected):
        return f"its volume {result.volume():.6g} m3, {grown_volume:.6g} m3 grown (about {expected:.3g} m3 less expected)"
    mesh = result.to_mesh64()
    return np.asarray(mesh.vert_properties, np.float64)[:, :3], np.asarray(mesh.tri_verts, np.int64)


def _turned_over(before: np.ndarray, vertices: np.ndarray, faces: np.ndarray, height: float) -> np.ndarray:
    """Faces turned over: their normal against ``before``'s, and higher than ``height`` over their longest side
    (a sliver that collapsed onto a line, its normal whatever rounding made it, is not a fold).

    Parameters
    ----------
    before : (F, 3) float64
        The faces' normals (any length) before the vertices moved.
    vertices : (V, 3) float64
    faces : (F, 3) int64
    height : float

    Returns
    -------
    (F,) bool
    """
    after = _face_cross(vertices, faces)
    longest = np.max([np.linalg.norm(vertices[faces[:, k]] - vertices[faces[:, k - 1]], axis=1) for k in range(3)],
                     axis=0)
    high = np.linalg.norm(after, axis=1) / np.where(longest > 0, longest, 1.0)  # twice the area over the side
    return (np.einsum("ij,ij->i", before, after) < 0) & (high > height)


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
    low = {k: shells[k][0].min(axis=0) for k in positive}
    high = {k: shells[k][0].max(axis=0) for k in positive}
    outer = []
    for k in positive:
        point = shells[k][0][shells[k][1][0]].mean(axis=0)  # a point on its surface
        inside = any(abs(winding_number(point, shells[j][0], shells[j][1])) > 0.5
                     for j in positive if j != k and shells[j][2] > shells[k][2]
                     and (low[j] <= point).all() and (point <= high[j]).all())
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


def _placement(model):
    """Where the file puts its project: (function moving (V, 3) metres of the project's frame into
    metres of a map CRS, note).

    By the map conversion when the file has one (:func:`_by_map_conversion`), else by the site's
    reference latitude and longitude (:func:`_by_site_coordinates`), else left in the project's frame.
    """
    import ifcopenshell.util.unit

    project_m = float(ifcopenshell.util.unit.calculate_unit_scale(model))  # metres per project length unit
    conversion = _map_conversion(model)
    if conversion is not None:
        return _by_map_conversion(conversion, project_m)
    site, why_not = _reference_site(model)
    if site is not None:
        return _by_site_coordinates(model, site, project_m)
    return (lambda v: v), f"IFC: no IfcMapConversion{why_not}: placed in the project's own frame, not in a map CRS"


def _map_conversion(model) -> dict | None:
    """The map conversion's attributes as a dict (None where absent): ``IfcMapConversion`` (and
    ``IfcMapConversionScaled``) of IFC4 and later, IFC2X3's ``ePSet_MapConversion`` on the project
    (buildingSMART's georeferencing guide); with ``crs`` (the target CRS's name) and ``map_unit``
    (an ``IfcNamedUnit``, a unit's name, or None)."""
    import ifcopenshell.util.element

    keys = ("Eastings", "Northings", "OrthogonalHeight", "XAxisAbscissa", "XAxisOrdinate", "Scale",
            "FactorX", "FactorY", "FactorZ")
    if model.schema == "IFC2X3":
        projects = model.by_type("IfcProject")
        found = ifcopenshell.util.element.get_pset(projects[0], "ePSet_MapConversion") if projects else None
        if not found:
            return None
        crs = ifcopenshell.util.element.get_pset(projects[0], "ePSet_ProjectedCRS") or {}
        conversion = {k: found.get(k) for k in keys}
        conversion.update(kind="ePSet_MapConversion", crs=crs.get("Name"), map_unit=crs.get("MapUnit"))
    else:
        found = model.by_type("IfcMapConversion")
        if not found:
            return None
        c = found[0]
        target = getattr(c, "TargetCRS", None)
        conversion = {k: getattr(c, k, None) for k in keys}
        conversion.update(kind=c.is_a(), crs=getattr(target, "Name", None), map_unit=getattr(target, "MapUnit", None))
    if conversion["Eastings"] is None or conversion["Northings"] is None:
        return None
    return conversion


def _map_unit(conversion: dict, project_m: float) -> tuple[float, float, str]:
    """(metres per map unit horizontally, vertically, how it was found) of a map conversion's CRS:
    its ``MapUnit``, else the unit pyproj gives its CRS's name, else metres (the unit of nearly
    every projected CRS buildings are placed in)."""
    import ifcopenshell.util.unit

    unit = conversion["map_unit"]
    if unit is not None and not isinstance(unit, str):
        try:
            metres = float(ifcopenshell.util.unit.get_named_unit_scale(unit))
        except Exception:  # an odd unit entity: try the CRS's name instead
            metres = 0.0
        if metres > 0:
            return metres, metres, f"its MapUnit ({metres:g} m)"
    elif isinstance(unit, str) and unit.strip():
        metres = _unit_named(unit)
        if metres is not None:
            return metres, metres, f"its MapUnit {unit!r}"
    if conversion["crs"]:
        from meshsom.crs import UnknownCRS, coordinate_system

        try:
            system = coordinate_system(str(conversion["crs"]))
        except UnknownCRS:
            system = None
        if system is not None and not system.geographic:
            return system.horizontal_m, system.vertical_m, f"its CRS's unit ({system.unit})"
    return 1.0, 1.0, "metres (assumed: no MapUnit, and pyproj does not know its CRS)"


def _unit_named(name: str) -> float | None:
    """Metres per unit of a length unit's name (``"METRE"``, ``"MILLIMETRE"``, ``"FOOT"``...), or None."""
    text = name.strip().upper().replace("METER", "METRE").replace(" ", "").replace("_", "")
    if "SURVEYF" in text:
        return US_SURVEY_FOOT_M
    if "FOOT" in text or "FEET" in text:
        return FOOT_M
    prefixes = {"MILLIMETRE": 1e-3, "CENTIMETRE": 1e-2, "DECIMETRE": 1e-1, "KILOMETRE": 1e3, "METRE": 1.0}
    return next((m for unit, m in prefixes.items() if text.endswith(unit)), None)


def _by_map_conversion(conversion: dict, project_m: float):
    """Place by a map conversion: ``E = E0 + s (a x - b y)``, ``N = N0 + s (b x + a y)``,
    ``H = H0 + s z`` in map units, (a, b) the x axis's direction in the map, ``s`` its scale
    (and IfcMapConversionScaled's factors per axis).

    Its ``Scale`` should be the ratio of the project's length unit to the map's (0.001 for a
    millimetre project on a metre map) times a grid scale close to 1; many exporters write 1.0 with
    millimetres. The building's own size is taken in metres as IfcOpenShell triangulated it, so
    the grid scale is applied only where ``Scale`` agrees with the units (within
    ``MAX_GRID_SCALE_OFF``), and the disagreement is noted otherwise; eastings, northings and
    height are converted from map units to metres.
    """
    horizontal_m, vertical_m, unit_note = _map_unit(conversion, project_m)
    ratio = project_m / horizontal_m  # the Scale the units ask for
    written = conversion["Scale"]
    notes = []
    grid = 1.0
    if written is not None:
        grid = float(written) / ratio
        if not abs(grid - 1.0) <= MAX_GRID_SCALE_OFF:
            notes.append(f"its Scale {float(written):g} is not the ratio of the project's length unit to the "
                         f"map's ({ratio:g}): the building keeps its size in metres")
            grid = 1.0
    factors = np.array([conversion[k] if conversion[k] is not None else 1.0 for k in ("FactorX", "FactorY", "FactorZ")],
                       np.float64)
    if not (np.isfinite(factors).all() and (factors > 0).all()):
        notes.append(f"its scale factors {factors.tolist()} are not all positive: not applied")
        factors = np.ones(3)
    abscissa, ordinate = conversion["XAxisAbscissa"], conversion["XAxisOrdinate"]
    # both absent (or both 0): the x axis unturned; an abscissa of 0 alone is a quarter turn
    turned = bool(abscissa) or bool(ordinate)
    angle = math.atan2(float(ordinate or 0.0), float(abscissa or 0.0)) if turned else 0.0
    cos, sin = math.cos(angle), math.sin(angle)
    shift = np.array([float(conversion["Eastings"]) * horizontal_m, float(conversion["Northings"]) * horizontal_m,
                      float(conversion["OrthogonalHeight"] or 0.0) * vertical_m], np.float64)
    scale = grid * factors

    def place(v: np.ndarray) -> np.ndarray:
        x, y, z = v[:, 0] * scale[0], v[:, 1] * scale[1], v[:, 2] * scale[2]
        return np.stack([cos * x - sin * y, sin * x + cos * y, z], axis=1) + shift

    crs = conversion["crs"] or "an unnamed CRS"
    return place, (f"IFC: placed by its {conversion['kind']} in {crs} (eastings {float(conversion['Eastings']):g}, "
                   f"northings {float(conversion['Northings']):g}, in {unit_note}; x axis turned "
                   f"{math.degrees(angle):.6g} degrees, grid scale {grid:g})" + "".join(f"; {n}" for n in notes))


def _compound_angle(value) -> float | None:
    """Degrees of an ``IfcCompoundPlaneAngleMeasure`` (degrees, minutes, seconds, millionths of a
    second; negative parts for south and west), or None. Exporters that write only the degrees
    negative are read alike."""
    try:
        parts = [float(p) for p in value]
    except TypeError:
        return None
    if not parts or len(parts) > 4 or not all(math.isfinite(p) for p in parts):
        return None
    sign = -1.0 if any(p < 0 for p in parts) else 1.0
    return sign * sum(abs(p) / unit for p, unit in zip(parts, (1.0, 60.0, 3600.0, 3600e6)))


def _reference_site(model) -> tuple[object | None, str]:
    """The first ``IfcSite`` with a usable reference latitude and longitude, or (None, why not)."""
    why = ""
    for site in model.by_type("IfcSite"):
        lat, lon = _compound_angle(site.RefLatitude), _compound_angle(site.RefLongitude)
        if lat is None or lon is None:
            continue
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            why = f", and IfcSite {site.Name!r}'s latitude and longitude ({lat:g}, {lon:g}) are not on the earth"
        elif lat == 0 and lon == 0:
            why = f", and IfcSite {site.Name!r}'s latitude and longitude are 0, 0 (an exporter's default, not a place)"
        else:
            return site, ""
    return None, why


def _by_site_coordinates(model, site, project_m: float):
    """Place by the site's reference point: its ``ObjectPlacement``'s origin is at
    ``RefLatitude``, ``RefLongitude`` (WGS 84) and ``RefElevation``; the project's true north is the
    model context's ``TrueNorth`` (default: its y axis). Into the UTM zone of that point (WGS 84,
    :func:`meshsom.crs.utm_point`), true north turned onto the grid's north there."""
    import ifcopenshell.util.placement

    from meshsom.crs import utm_point

    lat, lon = _compound_angle(site.RefLatitude), _compound_angle(site.RefLongitude)
    try:
        point = utm_point(lat, lon)
    except ValueError as err:
        return (lambda v: v), f"IFC: no IfcMapConversion, and IfcSite {site.Name!r}: {err}: placed in the project's own frame"
    elevation = float(site.RefElevation or 0.0) * project_m
    origin = np.zeros(3)
    if site.ObjectPlacement is not None:
        origin = np.asarray(ifcopenshell.util.placement.get_local_placement(site.ObjectPlacement),
                            np.float64)[:3, 3] * project_m
    north = (0.0, 1.0)
    for context in model.by_type("IfcGeometricRepresentationContext", include_subtypes=False):
        ratios = getattr(getattr(context, "TrueNorth", None), "DirectionRatios", None)
        if ratios and len(ratios) >= 2 and (ratios[0] or ratios[1]):
            north = (float(ratios[0]), float(ratios[1]))
            if context.ContextType == "Model":
                break
    # the project's y axis is this far clockwise of true north (true north at +y turned counter-clockwise)
    turn = math.atan2(north[1], north[0]) - math.pi / 2

    def place(v: np.ndarray) -> np.ndarray:
        return point.place(v - origin, turn, elevation)

    angle = point.convergence - turn
    return place, (f"IFC: no IfcMapConversion: placed by the reference point of IfcSite {site.Name!r} "
                   f"({lat:.6f}, {lon:.6f}, {elevation:g} m) in WGS 84 / UTM zone {point.zone} (EPSG:{point.epsg}), "
                   f"its x axis turned {math.degrees(angle):.4g} degrees (true north "
                   f"{'from the model context' if north != (0.0, 1.0) else 'its y axis'})")
