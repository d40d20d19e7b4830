"""Reading 3MF packages (``.3mf``): the 3D Manufacturing Format, in which city and building models are sent to 3D
printers (and exported by Blender, PrusaSlicer, Bambu Studio, 3D Builder and CAD tools).

A 3MF file is a zip (Open Packaging Conventions) whose root model part (named by the package's ``_rels/.rels``,
usually ``3D/3dmodel.model``) is XML: ``<resources>`` holds objects, each a ``<mesh>`` (``<vertices>`` and
``<triangles>``, counter-clockwise seen from outside) or ``<components>`` (other objects, each with a transform, in
this part or, by the Production extension's ``p:path``, in another model part of the package); ``<build>`` lists
the items to make, each an object with a transform. Read here with the standard library's XML parser, vertices and
triangles gathered into NumPy arrays:

- **Buildings**: each build item is one building, its object's mesh and components (recursively, each at its
  transform) united, vertices at the same place one vertex; id ``<file>#<item partnumber>``, else
  ``<file>#<object name>``, else ``<file>#object-<id>`` (a name met again: ``<name> (2)``: an object built twice).
- **Placement**: transforms are 3MF's 3 x 4 matrices ``m00 m01 m02 m10 m11 m12 m20 m21 m22 m30 m31 m32``, applied
  to row vectors (``[x y z 1] @ M``), a component's before its object's and the item's; a mirroring transform keeps
  the faces' sides (their order is turned).
- **Units**: the model's ``unit`` (micron, millimeter, centimeter, inch, foot, meter); millimetres where it names
  none, as the specification says, noted.
- **Axes**: z up (the build platform's), read as it is.
- **Left out**: an item whose object is not of type ``model`` (``support``, ``solidsupport``, ``surface``,
  ``other``) is a rejection saying so. Colours, materials, textures, beam lattices and slices are not read.
- **Labels**: ``labels.csv`` beside the file (``file`` ``<name>`` or ``<name>#<id>``), as for OBJ.
- A package that is no zip, has no model part, or whose model part is not XML is a rejection naming the part; an
  item whose triangles name vertices its object has not, or whose components name objects that do not exist (or
  contain themselves), is rejected alone.
"""

from __future__ import annotations

import dataclasses
import io
import xml.etree.ElementTree as ElementTree
import zipfile
import zlib
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: The relationship type of a package's root model part (``_rels/.rels``).
MODEL_RELATIONSHIP = "http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"
#: The root model part where the package's relationships name none.
DEFAULT_MODEL_PART = "3D/3dmodel.model"
#: The relationships part of a package.
RELATIONSHIPS_PART = "_rels/.rels"
#: 3MF's core namespace.
CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
#: The Production extension's namespace (``p:path``: a component's or item's object in another model part).
PRODUCTION = "http://schemas.microsoft.com/3dmanufacturing/production/2015/06"
#: Metres per unit of 3MF's units.
UNIT_METRES = {"micron": 1e-6, "millimeter": 1e-3, "centimeter": 1e-2, "inch": 0.0254, "foot": 0.3048, "meter": 1.0}
#: The unit of a model that names none (the specification's default).
DEFAULT_UNIT = "millimeter"
#: The object type read as (part of) a building; the others are support structures or open surfaces.
BUILDING_TYPE = "model"
#: The deepest nesting of components followed (a deeper one, or one that contains itself, is refused).
MAX_COMPONENT_DEPTH = 64


@dataclasses.dataclass
class _Object:
    """One ``<object>`` of a model part: its type, name, and either its mesh (``vertices (V, 3) float64``,
    ``triangles (F, 3) int64``) or its components ``[(part, object id, matrix (4, 4) float64)]``."""

    type: str
    name: str | None
    vertices: np.ndarray | None = None
    triangles: np.ndarray | None = None
    components: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class _Model:
    """A parsed model part: its unit (None where it names none), objects by id and build items ``[(part, object
    id, matrix (4, 4) float64, partnumber)]``."""

    unit: str | None
    objects: dict
    build: list


def read_3mf(path: Path, options, name: str | None = None) -> Iterator:
    """The buildings of a 3MF package: a RawMesh per build item (or a Rejection), as the module says; ``name`` starts
    the ids (default: the file name).

    Raises
    ------
    InputFileError
        The file is no zip, is larger than ``options.max_bytes`` (or a zip bomb), has no model part, its model part
        is not 3MF XML, or it builds nothing.
    """
    from meshsom.archives import _check_sizes
    from meshsom.fbx import _united
    from meshsom.io import Rejection, _labels_beside, building_meshes, file_crs, free_id, read_input_bytes

    data = read_input_bytes(path, options)  # a .3mf.gz too
    try:
        package = zipfile.ZipFile(io.BytesIO(bytes(data)))
    except (zipfile.BadZipFile, ValueError) as err:
        raise InputFileError(str(path), f"cannot be read as 3MF, a zip package ({type(err).__name__}: {err})") from None
    with package:
        _check_sizes(path, [m for m in package.infolist() if not m.is_dir()], options)
        parts: dict[str, _Model] = {}
        root = _root_part(package, path)
        model = _model(package, root, path, parts)
        if not model.build:
            raise InputFileError(str(path), f"builds nothing (its model part {root} has no <build> item)")
        unit = model.unit or DEFAULT_UNIT
        notes = () if model.unit else ("the model names no unit: read in millimetres, 3MF's default",)
        metres = UNIT_METRES[unit]
        labels = _labels_beside(path)
        label = labels.get(path.name)
        name = name or path.name
        crs = file_crs(None, options)
        taken: set[str] = set()
        for item_part, object_id, matrix, partnumber in model.build:
            try:
                item, problem = _item_object(package, path, parts, item_part, object_id), None
            except InputFileError as err:  # its part or object is missing or damaged: this item alone is rejected
                item, problem = None, err.problem
            key = partnumber or (item.name if item is not None and item.name else f"object-{object_id}")
            key = free_id(key, taken) if key in taken else key
            taken.add(key)
            mesh_id = f"{name}#{key}"
            item_label = labels.get(f"{path.name}#{key}", label)
            try:
                if problem is not None:
                    raise InputFileError(str(path), problem)
                if item.type != BUILDING_TYPE:
                    raise InputFileError(str(path), f"builds object {object_id}, a 3MF {item.type!r} object (a "
                                                    f"support structure or an open surface), not a {BUILDING_TYPE!r}")
                pieces = _pieces(package, path, parts, item_part, object_id, matrix, 0)
            except InputFileError as err:
                yield Rejection(mesh_id, str(path), err.problem, 0, item_label)
                continue
            vertices, faces = _united(pieces)  # components meeting at their edges: one vertex where they meet
            vertices = vertices * metres
            yield from building_meshes(mesh_id, str(path), vertices, faces, item_label, crs, notes, options)


def _root_part(package, path: Path) -> str:
    """The name of the package's root model part: the target of its 3D-model relationship, else
    :data:`DEFAULT_MODEL_PART`."""
    names = set(package.namelist())
    if RELATIONSHIPS_PART in names:
        try:
            rels = ElementTree.fromstring(_part_bytes(package, RELATIONSHIPS_PART, path))
        except ElementTree.ParseError as err:
            raise InputFileError(str(path), f"its {RELATIONSHIPS_PART} is not XML ({err})") from None
        for rel in rels.iter():
            if rel.get("Type") == MODEL_RELATIONSHIP and rel.get("Target"):
                target = rel.get("Target").lstrip("/")
                if target in names:
                    return target
                raise InputFileError(str(path), f"its {RELATIONSHIPS_PART} names the model part /{target}, which the "
                                                f"package does not hold")
    if DEFAULT_MODEL_PART in names:
        return DEFAULT_MODEL_PART
    raise InputFileError(str(path), f"holds no 3MF model part (no 3D-model relationship in {RELATIONSHIPS_PART}, "
                                    f"no {DEFAULT_MODEL_PART}): not a 3MF package")


def _part_bytes(package, part: str, path: Path) -> bytes:
    """The bytes of a part of the package; InputFileError where its entry is damaged (a bad header, deflate data or
    checksum: the zip's directory can be whole where an entry is not), encrypted or of a compression zip cannot undo."""
    try:
        return package.read(part)
    except (zipfile.BadZipFile, zlib.error, EOFError, RuntimeError, NotImplementedError, ValueError) as err:
        raise InputFileError(str(path), f"its part /{part} cannot be read from the zip package "
                                        f"({type(err).__name__}: {err})") from None


def _matrix(text: str | None, where: str) -> np.ndarray:
    """A 3MF transform (12 numbers, row-vector convention) as a 4 x 4 matrix; the identity where none is given."""
    matrix = np.eye(4)
    if text is None:
        return matrix
    try:
        values = np.array(text.split(), np.float64)
    except ValueError:
        values = np.zeros(0)
    if len(values) != 12 or not np.isfinite(values).all():
        raise InputFileError(where, f"transform {text!r} is not 12 numbers")
    matrix[:, :3] = values.reshape(4, 3)
    return matrix


def _model(package, part: str, path: Path, parts: dict) -> _Model:
    """The parsed model part ``part`` (kept in ``parts``)."""
    if part in parts:
        return parts[part]
    where = f"{path}!/{part}"
    if part not in package.namelist():
        raise InputFileError(str(path), f"names the model part /{part}, which the package does not hold")
    try:
        root = ElementTree.fromstring(_part_bytes(package, part, path))
    except ElementTree.ParseError as err:
        raise InputFileError(str(path), f"its model part /{part} is not XML ({err})") from None
    if root.tag != f"{{{CORE}}}model":
        raise InputFileError(str(path), f"its model part /{part} holds <{root.tag}>, expected a 3MF <model> of "
                                        f"namespace {CORE}")
    unit = root.get("unit")
    if unit is not None and unit not in UNIT_METRES:
        raise InputFileError(str(path), f"its model's unit is {unit!r}, expected one of {', '.join(UNIT_METRES)}")
    objects = {}
    for obj in root.iter(f"{{{CORE}}}object"):
        object_id = obj.get("id")
        entry = _Object(obj.get("type", BUILDING_TYPE), obj.get("name"))
        mesh = obj.find(f"{{{CORE}}}mesh")
        if mesh is not None:
            entry.vertices, entry.triangles = _mesh(mesh, f"{where}: object {object_id}")
        for component in obj.iter(f"{{{CORE}}}component"):
            other = component.get(f"{{{PRODUCTION}}}path", "/" + part).lstrip("/")
            entry.components.append((other, component.get("objectid"),
                                     _matrix(component.get("transform"), f"{where}: object {object_id}")))
        objects[object_id] = entry
    build = []
    for item in root.iter(f"{{{CORE}}}item"):
        other = item.get(f"{{{PRODUCTION}}}path", "/" + part).lstrip("/")
        build.append((other, item.get("objectid"), _matrix(item.get("transform"), f"{where}: build item"),
                      item.get("partnumber")))
    parts[part] = _Model(unit, objects, build)
    return parts[part]


def _mesh(mesh, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3) float64, triangles (F, 3) int64)`` of a ``<mesh>`` element."""
    vertices_el = mesh.find(f"{{{CORE}}}vertices")
    triangles_el = mesh.find(f"{{{CORE}}}triangles")
    try:
        vertices = np.array([(v.get("x"), v.get("y"), v.get("z")) for v in (vertices_el if vertices_el is not None
                                                                              else ())], np.float64).reshape(-1, 3)
        triangles = np.array([(t.get("v1"), t.get("v2"), t.get("v3")) for t in (triangles_el if triangles_el is not None
                                                                                 else ())], np.int64).reshape(-1, 3)
    except (TypeError, ValueError) as err:
        raise InputFileError(where, f"has a vertex or triangle whose coordinates or indices are missing or not "
                                    f"numbers ({err})") from None
    if not np.isfinite(vertices).all():
        raise InputFileError(where, "has vertices that are not finite numbers")
    return vertices, triangles


def _item_object(package, path: Path, parts: dict, part: str, object_id: str) -> _Object:
    """The object ``object_id`` of model part ``part``; InputFileError where there is none."""
    found = _model(package, part, path, parts).objects.get(object_id)
    if found is None:
        raise InputFileError(str(path), f"names object {object_id} of /{part}, which has no such object")
    return found


def _pieces(package, path: Path, parts: dict, part: str, object_id: str, matrix: np.ndarray, depth: int) -> list:
    """The triangles of an object at ``matrix`` (4 x 4, row vectors), its components' included:
    ``[(vertices (V, 3) float64, faces (F, 3) int64)]``."""
    if depth > MAX_COMPONENT_DEPTH:
        raise InputFileError(str(path), f"object {object_id} of /{part} nests components more than "
                                        f"{MAX_COMPONENT_DEPTH} deep (does it contain itself?)")
    obj = _item_object(package, path, parts, part, object_id)
    out = []
    if obj.vertices is not None:
        faces = obj.triangles
        if len(faces) and (faces.min() < 0 or faces.max() >= len(obj.vertices)):
            bad = int(faces[(faces < 0) | (faces >= len(obj.vertices))][0])
            raise InputFileError(str(path), f"object {object_id} of /{part}: a triangle refers to vertex {bad}, and "
                                            f"the object has {len(obj.vertices)} vertices")
        if np.linalg.det(matrix[:3, :3]) < 0:  # mirrored: the faces' order turned so that they keep their side
            faces = faces[:, ::-1]
        out.append((obj.vertices @ matrix[:3, :3] + matrix[3, :3], np.ascontiguousarray(faces)))
    for other, child, child_matrix in obj.components:
        out.extend(_pieces(package, path, parts, other, child, child_matrix @ matrix, depth + 1))
    if not out:
        raise InputFileError(str(path), f"object {object_id} of /{part} holds neither a mesh nor components")
    return out
