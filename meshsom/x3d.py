"""Reading X3D (``.x3d``, XML encoding; ``.x3dv``, classic encoding) and VRML97 (``.wrl``) scenes: old city models,
and the X3D that CityGML converters write.

Both encodings are parsed here into one tree of :class:`Node` (a node's type, its fields, its child nodes in order):
the XML one by the standard library's parser, the classic one (VRML97's curly-brace syntax) by a small scanner whose
number arrays (``point [ ... ]``, ``coordIndex [ ... ]``) are read by NumPy in one step each. ``DEF`` names a node,
``USE`` repeats it (the same node again, where the scene puts it).

- **Buildings**: each top-level node of the scene that holds geometry (a ``Transform``, ``Group``, ``Shape``,
  ``Inline``, ...) is one building, its shapes united, as a glTF scene's nodes are; id ``<file>#<DEF name>``, else
  ``<file>#<node type>-<k>`` (k: its place among the scene's top-level nodes, from 1; a name met again gets
  ``(2)``). A top-level node of lights, viewpoints or other nodes without geometry is not a building. A city in one
  top-level group (CityGML2X writes a whole city so, in CityGML's z-up coordinates) is one building as read:
  ``--split-components`` cuts it into its buildings, ``--up z`` keeps its axes.
- **Geometry**: ``IndexedFaceSet`` (``coordIndex`` polygons between ``-1``, triangulated in their own plane: L-shaped
  faces too), ``IndexedTriangleSet``, ``TriangleSet``, ``IndexedQuadSet``, ``QuadSet`` (on ``Coordinate`` or
  ``CoordinateDouble`` points), ``Box`` and ``Extrusion`` (its cross-section swept along its spine, scaled and
  oriented at each spine point, with its caps: walls and floors of old VRML models); ``ccw FALSE`` turns the faces.
  Other geometry (``ElevationGrid``, spheres, cylinders, cones, strips and fans, ``GeoCoordinate``) is noted as left
  out; a building of only that is a rejection saying so.
- **Placement**: ``Transform`` (``translation``, ``rotation`` axis-angle, ``scale``, ``scaleOrientation``,
  ``center``) composed from the root down as the specification says, ``T C R SR S -SR -C``; a mirroring transform
  keeps the faces' sides. ``Switch`` reads its chosen child only (none where ``whichChoice`` is -1, noted), ``LOD``
  its first (most detailed) level, ``Group``, ``StaticGroup``, ``Collision``, ``Anchor``, ``Billboard`` their
  children.
- **Inline**: the first ``url`` that is a file beside the scene (in its folder or below, never outside it nor on the
  network) is read as part of the node that inlines it; one that cannot be is a rejection of its building.
- **Units**: metres, as both specifications say (X3D's ``UNIT length`` / ``<unit category="length">`` scales them).
- **Axes**: y up by both specifications: turned a quarter about x to z up, (x, y, z) -> (x, -z, y), noted, as glTF
  is (``corpus.reader.up_axis: z``, or ``--up z``, reads it as it is).
- **Labels**: ``labels.csv`` beside the file (``file`` ``<name>`` or ``<name>#<id>``), as for OBJ.
- PROTO and EXTERNPROTO instances are not expanded (noted); VRML 1.0 is refused (another syntax).
"""

from __future__ import annotations

import dataclasses
import re
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: The first line of a VRML97 file, and of an X3D file in the classic encoding.
VRML_HEADER = re.compile(rb"^\s*#(?:VRML V2\.0|X3D V[34]\.\d)\b")
#: The first line of a VRML 1.0 file (another syntax, not read).
VRML1_HEADER = re.compile(rb"^\s*#VRML V1\.0")
#: Grouping nodes whose children are all drawn.
GROUPS = ("Transform", "Group", "StaticGroup", "Collision", "Anchor", "Billboard", "CADAssembly", "CADLayer",
          "CADPart", "CADFace")
#: Geometry nodes read, and their vertex-list nodes.
GEOMETRY = ("IndexedFaceSet", "IndexedTriangleSet", "TriangleSet", "IndexedQuadSet", "QuadSet", "Box", "Extrusion")
COORDINATES = ("Coordinate", "CoordinateDouble")
#: Geometry nodes not read (noted, or a rejection of a building of only these).
UNREAD_GEOMETRY = ("ElevationGrid", "Sphere", "Cylinder", "Cone", "IndexedTriangleFanSet",
                   "IndexedTriangleStripSet", "TriangleFanSet", "TriangleStripSet", "GeoElevationGrid",
                   "NurbsPatchSurface", "NurbsTrimmedSurface", "Text", "Arc2D", "Rectangle2D", "Disk2D",
                   "PointSet", "IndexedLineSet", "LineSet")
#: An Extrusion's fields where the node gives none (X3D's defaults: a 2 x 2 square swept 1 along y).
EXTRUSION_DEFAULTS = {"crossSection": (1, 1, 1, -1, -1, -1, -1, 1, 1, 1), "spine": (0, 0, 0, 0, 1, 0),
                      "scale": (1, 1), "orientation": (0, 0, 1, 0)}
#: Spine directions and cross products shorter than this (relative to the spine's extent) are taken for zero.
SPINE_TOL = 1e-12
#: The size of a Box with no ``size`` field (metres).
DEFAULT_BOX_SIZE = (2.0, 2.0, 2.0)
#: A quarter turn about x: y up -> z up (a proper rotation: faces keep their side).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: The note on a scene turned to z up.
Y_UP_NOTE = ("X3D and VRML are y up by their specifications: turned to z up (corpus.reader.up_axis: z, or --up z, "
             "reads it as it is)")
#: The deepest nesting of Inline files followed (a deeper one, or one that inlines itself, is refused).
MAX_INLINE_DEPTH = 16
#: A token of the classic encoding: a string, a bracket or brace, or a word or number (commas are blanks).
_TOKEN = re.compile(r'[\s,]*(?:("(?:[^"\\]|\\.)*")|([{}\[\]])|([^\s,{}\[\]"]+))', re.S)
_COMMENT_OR_STRING = re.compile(r'"(?:[^"\\]|\\.)*"|#[^\n\r]*', re.S)
_NUMBER_START = re.compile(r"[\s,]*[-+.0-9\]]")
#: Classic-encoding statements at the head of an X3D file, each with the number of tokens after its keyword.
_HEAD_STATEMENTS = {"PROFILE": 1, "COMPONENT": 1, "META": 2, "UNIT": 3}


@dataclasses.dataclass(eq=False)
class Node:
    """One node of a scene: its ``type``, its DEF ``name`` (or None), its ``fields`` (field name -> value: a
    string (XML attribute), an array of numbers, a list of strings, or a word), and its ``children``, every node it
    holds in order (grouping nodes' children, a Shape's appearance and geometry, a geometry's coordinates)."""

    type: str
    name: str | None = None
    fields: dict = dataclasses.field(default_factory=dict)
    children: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class Scene:
    """A parsed file: its top-level nodes, metres per length unit, and notes."""

    nodes: list
    metres: float = 1.0
    notes: list = dataclasses.field(default_factory=list)


def read_x3d(path: Path, options, name: str | None = None) -> Iterator:
    """The buildings of an X3D or VRML97 scene: a RawMesh per top-level node with geometry (or a Rejection), as the
    module says; ``name`` starts the ids (default: the file name).

    Raises
    ------
    InputFileError
        The file is larger than ``options.max_bytes``, cannot be parsed, or holds no geometry.
    """
    from meshsom.fbx import _united
    from meshsom.io import (
        FolderResolver, Rejection, _labels_beside, building_meshes, file_crs, free_id, read_input_bytes,
    )

    try:
        scene = parse_scene(bytes(read_input_bytes(path, options)), str(path))
    except RecursionError:
        raise InputFileError(str(path), "nests nodes deeper than Python's recursion limit") from None
    turn = None if options.up_axis == "z" else Y_UP_TO_Z_UP
    notes = list(scene.notes) + ([Y_UP_NOTE] if turn is not None and options.up_axis == "auto" else [])
    labels = _labels_beside(path)
    label = labels.get(path.name)
    name = name or path.name
    crs = file_crs(None, options)
    resolver = FolderResolver(path.parent, str(path))
    taken: set[str] = set()
    found = False
    for k, node in enumerate(scene.nodes, 1):
        key = node.name or f"{node.type}-{k}"
        pieces, unread, node_notes = [], {}, {}
        try:
            _gather(node, np.eye(4), pieces, unread, node_notes, resolver, str(path), options, 0)
        except (InputFileError, RecursionError) as err:  # a node that USEs itself nests without end
            problem = err.problem if isinstance(err, InputFileError) else (
                "nests nodes deeper than Python's recursion limit (a node that USEs itself, or Inline files?)")
            key = free_id(key, taken) if key in taken else key
            taken.add(key)
            found = True
            yield Rejection(f"{name}#{key}", str(path), problem, 0, labels.get(f"{path.name}#{key}", label))
            continue
        if not pieces and not unread:
            continue  # a light, a viewpoint, world info: no building
        key = free_id(key, taken) if key in taken else key
        taken.add(key)
        found = True
        mesh_id = f"{name}#{key}"
        item_label = labels.get(f"{path.name}#{key}", label)
        kinds = ", ".join(f"{n} {t}" for t, n in unread.items())
        if not pieces:
            yield Rejection(mesh_id, str(path), f"holds no geometry that is read (only {kinds}; read: "
                                                f"{', '.join(GEOMETRY)})", 0, item_label)
            continue
        vertices, faces = _united(pieces)
        vertices = vertices * scene.metres
        if turn is not None:
            vertices = vertices @ turn.T
        item_notes = notes + list(node_notes) + ([f"left out: {kinds} (geometry that is not read)"] if unread else [])
        yield from building_meshes(mesh_id, str(path), vertices, faces, item_label, crs, tuple(item_notes), options)
    if not found:
        raise InputFileError(str(path), "holds no geometry (no Shape in its scene)")


def parse_scene(data: bytes, where: str) -> Scene:
    """The scene of a file's bytes, by its content: the classic encoding (``#VRML V2.0`` or ``#X3D`` first) or
    XML."""
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if VRML1_HEADER.match(data):
        raise InputFileError(where, "is VRML 1.0, which is not read (another syntax): convert it to VRML97 or X3D")
    if VRML_HEADER.match(data):
        return _classic_scene(data.decode("utf-8", "replace"), where)
    if data.lstrip()[:1] == b"<":
        return _xml_scene(data, where)
    raise InputFileError(where, "is neither X3D (XML) nor VRML97 / classic X3D (a '#VRML V2.0' or '#X3D' first "
                                "line)")


# -- the XML encoding ------------------------------------------------------------------------------------------------


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _xml_scene(data: bytes, where: str) -> Scene:
    try:
        root = ElementTree.fromstring(data)
    except ElementTree.ParseError as err:
        raise InputFileError(where, f"cannot be read as X3D (XML: {err})") from None
    except (LookupError, ValueError) as err:  # the XML declaration names an encoding Python does not know
        raise InputFileError(where, f"cannot be read as X3D (XML: {err})") from None
    if _local(root.tag) != "X3D":
        raise InputFileError(where, f"holds <{_local(root.tag)}>, expected an <X3D> document")
    scene = next((e for e in root if _local(e.tag) == "Scene"), None)
    if scene is None:
        raise InputFileError(where, "has no <Scene>")
    metres = 1.0
    for unit in root.iter():
        if _local(unit.tag) == "unit" and unit.get("category") == "length":
            metres = _unit_factor(unit.get("conversionFactor"), where)
    defined: dict[str, Node] = {}
    return Scene([_xml_node(e, defined, where) for e in scene if _local(e.tag) not in ("ROUTE", "IMPORT", "EXPORT")],
                 metres, [f"UNIT length: {metres:g} m per unit"] if metres != 1.0 else [])


def _xml_node(element, defined: dict, where: str) -> Node:
    use = element.get("USE")
    if use is not None:
        if use not in defined:
            raise InputFileError(where, f"<{_local(element.tag)} USE={use!r}> names no node DEF'd before it")
        return defined[use]
    node = Node(_local(element.tag), element.get("DEF"), {k: v for k, v in element.attrib.items()
                                                          if k not in ("DEF", "USE", "containerField")})
    if node.name is not None:
        defined[node.name] = node
    node.children = [_xml_node(e, defined, where) for e in element if isinstance(e.tag, str)]
    return node


def _unit_factor(text, where: str) -> float:
    try:
        factor = float(text)
    except (TypeError, ValueError):
        factor = float("nan")
    if not (np.isfinite(factor) and factor > 0):
        raise InputFileError(where, f"its length unit's conversion factor is {text!r}, expected a number > 0")
    return factor


# -- the classic encoding (VRML97, .x3dv) ----------------------------------------------------------------------------


class _Scanner:
    """Tokens of a classic-encoding text (comments removed), with number arrays read whole."""

    def __init__(self, text: str, where: str):
        self.text = _COMMENT_OR_STRING.sub(lambda m: m.group(0) if m.group(0).startswith('"') else " ", text)
        self.at = 0
        self.where = where
        self.defined: dict[str, Node] = {}
        self.protos: set[str] = set()

    def peek(self) -> str | None:
        m = _TOKEN.match(self.text, self.at)
        return None if m is None else m.group(m.lastindex)

    def next(self) -> str:
        m = _TOKEN.match(self.text, self.at)
        if m is None:
            raise InputFileError(self.where, f"ends early (at character {self.at}): a '}}' or ']' is missing")
        self.at = m.end()
        return m.group(m.lastindex)

    def expect(self, token: str) -> None:
        got = self.next()
        if got != token:
            raise InputFileError(self.where, f"has {got!r} at character {self.at}, expected {token!r}")

    def numbers(self) -> np.ndarray | None:
        """After a ``[``: the numbers up to its ``]`` as one array, or None (and nothing read) where the list holds
        anything else."""
        if not _NUMBER_START.match(self.text, self.at):
            return None
        end = self.text.find("]", self.at)
        if end < 0:
            raise InputFileError(self.where, f"has a '[' before character {self.at} that is never closed")
        try:
            values = np.array(self.text[self.at:end].replace(",", " ").split(), np.float64)
        except ValueError:
            return None
        self.at = end + 1
        return values


def _classic_scene(text: str, where: str) -> Scene:
    scan = _Scanner(text, where)
    nodes, metres, notes = [], 1.0, []
    while scan.peek() is not None:
        token = scan.peek()
        if token in _HEAD_STATEMENTS:
            scan.next()
            args = [scan.next() for _ in range(_HEAD_STATEMENTS[token])]
            if token == "UNIT" and args[0] == "length":
                metres = _unit_factor(args[2], where)
                notes.append(f"UNIT length: {metres:g} m per unit")
        elif token == "ROUTE":
            for _ in range(4):  # ROUTE a.out TO b.in
                scan.next()
        elif token in ("IMPORT", "EXPORT"):
            _skip_statement(scan)
        elif token in ("PROTO", "EXTERNPROTO"):
            _skip_proto(scan)
        else:
            nodes.append(_classic_node(scan))
    if scan.protos:
        notes.append(f"PROTO instances not expanded: {', '.join(sorted(scan.protos))}")
    return Scene(nodes, metres, notes)


def _skip_statement(scan: _Scanner) -> None:
    scan.next()
    scan.next()
    if scan.peek() == "AS":
        scan.next()
        scan.next()


def _skip_proto(scan: _Scanner) -> None:
    """Pass over a PROTO (name, interface, body) or EXTERNPROTO (name, interface, url)."""
    keyword = scan.next()
    scan.protos.add(scan.next())
    _skip_brackets(scan, "[", "]")
    if keyword == "PROTO":
        _skip_brackets(scan, "{", "}")
    elif scan.peek() == "[":
        _skip_brackets(scan, "[", "]")
    else:
        scan.next()  # one url string


def _skip_brackets(scan: _Scanner, opening: str, closing: str) -> None:
    scan.expect(opening)
    depth = 1
    while depth:
        token = scan.next()
        depth += (token == opening) - (token == closing)


def _classic_node(scan: _Scanner) -> Node:
    token = scan.next()
    if token == "USE":
        name = scan.next()
        if name not in scan.defined:
            raise InputFileError(scan.where, f"USE {name} names no node DEF'd before it")
        return scan.defined[name]
    name = None
    if token == "DEF":
        name, token = scan.next(), scan.next()
    node = Node(token, name)
    if name is not None:
        scan.defined[name] = node
    scan.expect("{")
    while scan.peek() != "}":
        if scan.peek() is None:
            raise InputFileError(scan.where, f"ends inside the {token} node: a '}}' is missing")
        field = scan.next()
        if field == "ROUTE":  # ROUTE a.out TO b.in
            for _ in range(3):
                scan.next()
            continue
        node.fields[field] = _classic_value(scan, node)
    scan.next()
    if token in scan.protos:
        node.children = []  # an instance of a PROTO: its fields are the PROTO's, not drawn here
    return node


def _classic_value(scan: _Scanner, node: Node):
    """A field's value: an array of numbers, a list of strings or words, a node (kept among ``node.children``
    too), a list of nodes, or a single word or string."""
    token = scan.peek()
    if token == "[":
        scan.next()
        values = scan.numbers()
        if values is not None:
            return values
        items = []
        while scan.peek() != "]":
            if scan.peek() is None:
                raise InputFileError(scan.where, "ends inside a '[' list: a ']' is missing")
            if scan.peek() == "ROUTE":  # among a node's children: ROUTE a.out TO b.in
                for _ in range(4):
                    scan.next()
                continue
            items.append(_classic_item(scan, node))
        scan.next()
        return items
    if token == "IS":
        scan.next()
        return scan.next()
    if token == "NULL":
        scan.next()
        return None
    if token is not None and _is_node_start(scan, token):
        return _classic_item(scan, node)
    values = []
    while True:
        token = scan.peek()
        if token is None or not (token.startswith('"') or token in ("TRUE", "FALSE") or _is_number(token)):
            break
        values.append(scan.next())
    if not values:
        raise InputFileError(scan.where, f"has {token!r} at character {scan.at} where a field value was expected")
    if all(_is_number(v) for v in values):
        return np.array(values, np.float64)
    return values[0] if len(values) == 1 else values


def _classic_item(scan: _Scanner, node: Node):
    token = scan.peek()
    if _is_node_start(scan, token):
        child = _classic_node(scan)
        node.children.append(child)
        return child
    return scan.next()


def _is_node_start(scan: _Scanner, token: str) -> bool:
    if token in ("DEF", "USE"):
        return True
    m = _TOKEN.match(scan.text, scan.at)
    after = _TOKEN.match(scan.text, m.end()) if m else None
    return after is not None and after.group(after.lastindex) == "{"


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


# -- geometry --------------------------------------------------------------------------------------------------------


def _numbers(value, default=None) -> np.ndarray | None:
    """A field's numbers (an array already, or an XML attribute's text) as float64; ``default`` where absent."""
    if value is None:
        return None if default is None else np.asarray(default, np.float64)
    if isinstance(value, np.ndarray):
        return value.astype(np.float64)
    if isinstance(value, list):
        value = " ".join(str(v) for v in value)
    try:
        return np.array(str(value).replace(",", " ").split(), np.float64)
    except ValueError:
        raise InputFileError("", f"has a field value {str(value)[:60]!r} where numbers are expected") from None


def _indices(node: Node, field: str, where: str) -> np.ndarray:
    """A node's index field ``(N,) int64``; InputFileError where a value is no integer (``1.5``, ``nan``, ``1e30``)."""
    values = _numbers(node.fields.get(field), ())
    whole = np.isfinite(values) & (values == np.round(values)) & (np.abs(values) < 2**62)
    if not whole.all():
        raise InputFileError(where, f"{node.type} {node.name or ''}: its {field} holds {values[~whole][0]!r}, "
                                    f"expected point numbers (whole numbers, -1 between faces)")
    return values.astype(np.int64)


def _flag(value, default: bool) -> bool:
    if value is None:
        return default
    return str(value).strip().strip('"').lower() == "true"


def _axis_angle(values: np.ndarray) -> np.ndarray:
    """The 3 x 3 rotation of an X3D ``rotation`` (axis x y z, angle in radians; Rodrigues' formula)."""
    axis, angle = values[:3], values[3]
    length = np.linalg.norm(axis)
    if not length > 0:
        return np.eye(3)
    x, y, z = axis / length
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def transform_matrix(node: Node) -> np.ndarray:
    """The 4 x 4 matrix (column vectors) of a Transform: ``T C R SR S -SR -C``."""
    def affine(linear=np.eye(3), shift=np.zeros(3)):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = linear, shift
        return m

    translation = _numbers(node.fields.get("translation"), (0, 0, 0))[:3]
    center = _numbers(node.fields.get("center"), (0, 0, 0))[:3]
    rotation = _axis_angle(_numbers(node.fields.get("rotation"), (0, 0, 1, 0)))
    scale = _numbers(node.fields.get("scale"), (1, 1, 1))[:3]
    orientation = _axis_angle(_numbers(node.fields.get("scaleOrientation"), (0, 0, 1, 0)))
    return (affine(shift=translation) @ affine(shift=center) @ affine(rotation) @ affine(orientation)
            @ affine(np.diag(scale)) @ affine(orientation.T) @ affine(shift=-center))


def _gather(node: Node, matrix: np.ndarray, pieces: list, unread: dict, notes: dict, resolver, where: str, options,
            depth: int) -> None:
    """Add the placed triangles ``(vertices (V, 3), faces (F, 3))`` of ``node`` and all it holds to ``pieces``;
    count the geometry not read in ``unread``."""
    kind = node.type
    if kind == "Transform":
        matrix = matrix @ transform_matrix(node)
    if kind in GROUPS or kind in ("Shape", "Inline", "Switch", "LOD"):
        pass
    elif kind in GEOMETRY:
        vertices, faces = _geometry(node, where)
        if len(faces):
            placed = vertices @ matrix[:3, :3].T + matrix[:3, 3]
            if np.linalg.det(matrix[:3, :3]) < 0:
                faces = faces[:, ::-1]
            pieces.append((placed, np.ascontiguousarray(faces)))
        return
    elif kind in UNREAD_GEOMETRY or kind.startswith("Geo"):
        unread[kind] = unread.get(kind, 0) + 1
        return
    elif kind == "ProtoInstance":  # the XML encoding's PROTO instance
        notes[f"PROTO instances not expanded: {node.fields.get('name')}"] = None
        return
    else:
        return  # appearance, lights, viewpoints, sensors, scripts: nothing to draw
    children = node.children
    if kind == "Switch":
        choice = int(_numbers(node.fields.get("whichChoice"), (-1,))[0])
        children = children[choice:choice + 1] if choice >= 0 else []
        if choice < 0:
            notes["a Switch shows none of its children (whichChoice -1): left out"] = None
    elif kind == "LOD":
        children = children[:1]
    elif kind == "Shape":
        children = [c for c in children if c.type in GEOMETRY or c.type in UNREAD_GEOMETRY or c.type.startswith("Geo")]
    elif kind == "Inline":
        children, resolver, where = _inlined(node, resolver, where, options, depth, notes)
        depth += 1
    for child in children:
        _gather(child, matrix, pieces, unread, notes, resolver, where, options, depth)


#: The word that tells a scene inlines other files (scanned for before the scene is parsed to find them).
_INLINE_WORD = re.compile(rb"\bInline\b")


def inlined_files(path: Path, options) -> list[Path]:
    """The files beside an X3D or VRML scene that its ``Inline`` nodes name (followed as :func:`read_x3d` follows
    them, to :data:`MAX_INLINE_DEPTH`), resolved: a folder's walk reads them through the scene, not again as
    scenes of their own. A scene that cannot be read names none (its reading says why)."""
    from meshsom.io import FolderResolver, read_input_bytes

    found: list[Path] = []
    todo = [(path, 0)]
    while todo:
        scene_path, depth = todo.pop()
        try:
            data = bytes(read_input_bytes(scene_path, options))
            if depth >= MAX_INLINE_DEPTH or not _INLINE_WORD.search(data):
                continue
            scene = parse_scene(data, str(scene_path))
        except (InputFileError, RecursionError, OSError):
            continue
        resolver = FolderResolver(scene_path.parent, str(scene_path))
        nodes, seen = list(scene.nodes), set()
        while nodes:
            node = nodes.pop()
            if id(node) in seen:  # a USE of a node met before
                continue
            seen.add(id(node))
            nodes.extend(node.children)
            for url in _urls(node) if node.type == "Inline" else ():
                try:
                    target = resolver._path(url).resolve()
                except InputFileError:
                    continue
                if target.is_file() and target not in found:
                    found.append(target)
                    todo.append((target, depth + 1))
                break  # the first url that names a file is the one read
    return found


def _urls(node: Node) -> list[str]:
    """An Inline's ``url`` values in order: an XML attribute ('"a.x3d" "b.x3d"'), one classic string, or a list."""
    urls = node.fields.get("url")
    if isinstance(urls, str):
        return re.findall(r'"((?:[^"\\]|\\.)*)"', urls) or urls.split()
    return [u.strip('"') for u in (urls or [])]


def _inlined(node: Node, resolver, where: str, options, depth: int, notes: dict) -> tuple[list, object, str]:
    """The first ``url`` of an Inline that is a file beside the file that inlines it (in its folder or below): its
    top-level nodes (scaled by its unit, through a Transform), the resolver of its folder and its path."""
    from meshsom.io import FolderResolver, read_input_bytes

    if depth >= MAX_INLINE_DEPTH:
        raise InputFileError(where, f"nests Inline files more than {MAX_INLINE_DEPTH} deep (does one inline itself?)")
    tried = []
    for url in _urls(node):
        try:
            path = resolver._path(url)
        except InputFileError as err:
            tried.append(err.problem)
            continue
        scene = parse_scene(bytes(read_input_bytes(path, options)), str(path))
        notes.update(dict.fromkeys(f"Inline {url}: {n}" for n in scene.notes))
        inner = Node("Transform", fields={"scale": np.full(3, scene.metres)}, children=scene.nodes)
        return [inner], FolderResolver(path.parent, str(path)), str(path)
    raise InputFileError(where, f"has an Inline whose url names no file beside it ({'; '.join(tried) or 'no url'})")


def _coordinates(node: Node, where: str) -> np.ndarray:
    coord = next((c for c in node.children if c.type in COORDINATES), None)
    if coord is None:
        geo = next((c.type for c in node.children if c.type.startswith("Geo")), None)
        raise InputFileError(where, f"{node.type} {node.name or ''} has " + (
            f"{geo} points, which are not read" if geo else "no Coordinate"))
    points = _numbers(coord.fields.get("point"), ())
    if len(points) % 3 or not np.isfinite(points).all():
        raise InputFileError(where, f"{node.type} {node.name or ''}: its points are not x y z triples of numbers")
    return points.reshape(-1, 3)


def _geometry(node: Node, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3) float64, faces (F, 3) int64)`` of a geometry node, in its own frame."""
    from meshsom.io import polygon_faces

    kind = node.type
    if kind == "Box":
        size = _numbers(node.fields.get("size"), DEFAULT_BOX_SIZE)[:3] / 2
        corners = np.array([(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], np.float64) * size
        quads = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])
        return corners, np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    if kind == "Extrusion":
        points, flat, lengths, closed = _extrusion(node, where)
        faces = polygon_faces(flat, lengths, points)[0] if len(lengths) else np.zeros((0, 3), np.int64)
        if closed:  # a closed surface faces outwards, whichever way its cross-section runs
            corners = (points - points.mean(axis=0))[faces]
            if np.einsum("ij,ij->", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])) < 0:
                faces = faces[:, ::-1]
        elif not _flag(node.fields.get("ccw"), True):
            faces = faces[:, ::-1]
        return points, np.ascontiguousarray(faces, np.int64)
    points = _coordinates(node, where)
    if kind in ("TriangleSet", "QuadSet"):
        index = np.arange(len(points) - len(points) % (3 if kind == "TriangleSet" else 4))
    else:
        index = _indices(node, "coordIndex" if kind == "IndexedFaceSet" else "index", where)
    if kind == "IndexedFaceSet":
        keep = index >= 0
        ring = np.cumsum(~keep)[keep]  # the polygon of every index: -1 separates them
        flat = index[keep]
        lengths = np.unique(ring, return_counts=True)[1]
        big = np.repeat(lengths >= 3, lengths)  # polygons of 1 or 2 vertices are no faces
        flat, lengths = flat[big], lengths[lengths >= 3]
    else:
        size = 4 if "Quad" in kind else 3
        flat = index[: len(index) - len(index) % size]
        lengths = np.full(len(flat) // size, size, np.int64)
    if len(flat) and (flat.min() < 0 or flat.max() >= len(points)):
        bad = int(flat[(flat < 0) | (flat >= len(points))][0])
        raise InputFileError(where, f"{kind} {node.name or ''}: a face refers to point {bad}, and its Coordinate has "
                                    f"{len(points)} points")
    faces = polygon_faces(flat, lengths, points)[0] if len(lengths) else np.zeros((0, 3), np.int64)
    if not _flag(node.fields.get("ccw"), True):
        faces = faces[:, ::-1]
    return points, np.ascontiguousarray(faces, np.int64)


def _spine_frames(spine: np.ndarray) -> np.ndarray:
    """The spine-aligned cross-section planes of an Extrusion (X3D 13.3.5): for each spine point, the 3 x 3 matrix
    of columns X, Y, Z. Y follows the spine (the neighbours' difference), Z is the cross product of the spine's
    two segments at the point (a zero one: the previous point's; turned to agree with it), X = Y x Z; a spine on one
    line has the frame that turns (0, 1, 0) onto it.

    Parameters
    ----------
    spine : (n, 3) float64, n >= 2

    Returns
    -------
    frames : (n, 3, 3) float64
    """
    n = len(spine)
    closed = n > 2 and np.allclose(spine[0], spine[-1])
    extent = max(float(np.ptp(spine, axis=0).max()), 1.0)
    y = np.empty((n, 3))
    y[1:-1] = spine[2:] - spine[:-2]
    y[0] = (spine[1] - spine[-2]) if closed else (spine[1] - spine[0])
    y[-1] = y[0] if closed else (spine[-1] - spine[-2])
    z = np.zeros((n, 3))
    z[1:-1] = np.cross(spine[2:] - spine[1:-1], spine[:-2] - spine[1:-1])
    if closed:
        z[0] = z[-1] = np.cross(spine[1] - spine[0], spine[-2] - spine[0])
    elif n > 2:
        z[0], z[-1] = z[1], z[-2]
    lengths = np.linalg.norm(y, axis=1)
    y = y / np.where(lengths > SPINE_TOL * extent, lengths, 1.0)[:, None]
    flat = np.linalg.norm(z, axis=1) <= SPINE_TOL * extent ** 2
    if flat.all():  # a straight spine: the turn of (0, 1, 0) onto it
        direction = next((v for v in y if np.linalg.norm(v) > 0.5), np.array([0.0, 1.0, 0.0]))
        axis = np.cross([0.0, 1.0, 0.0], direction)
        angle = float(np.arctan2(np.linalg.norm(axis), direction[1]))
        if np.linalg.norm(axis) <= SPINE_TOL:
            axis = np.array([1.0, 0.0, 0.0])
        turn = _axis_angle(np.concatenate([axis, [angle]]))
        return np.repeat((turn @ np.eye(3))[None], n, axis=0)
    for i in range(n):  # a zero Z takes the previous one (the first non-zero one for those before it)
        if flat[i]:
            z[i] = z[i - 1] if i > 0 and not flat[i - 1] else z[np.flatnonzero(~flat)[0]]
            flat[i] = False
        elif i > 0 and z[i] @ z[i - 1] < 0:
            z[i] = -z[i]
    z /= np.linalg.norm(z, axis=1)[:, None]
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=2)


def _extrusion(node: Node, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """An Extrusion's points ``(n * m, 3)``, its polygons (``flat`` indices, ``lengths``: a quad for each spine
    segment and cross-section edge, then the begin and end caps where asked for and the cross-section is closed)
    and whether they close a volume (a closed cross-section with both caps, or along a closed spine)."""
    fields = {k: _numbers(node.fields.get(k), v) for k, v in EXTRUSION_DEFAULTS.items()}
    section, spine = fields["crossSection"], fields["spine"]
    if len(section) % 2 or len(spine) % 3 or len(fields["scale"]) % 2 or len(fields["orientation"]) % 4:
        raise InputFileError(where, f"Extrusion {node.name or ''}: its crossSection, spine, scale or orientation "
                                    f"is not made of 2-, 3-, 2- and 4-number values")
    section, spine = section.reshape(-1, 2), spine.reshape(-1, 3)
    n, m = len(spine), len(section)
    if n < 2 or m < 2:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), False
    scale = fields["scale"].reshape(-1, 2)
    scale = np.repeat(scale[:1], n, axis=0) if len(scale) < n else scale[:n]  # one per spine point, or one for all
    orientation = fields["orientation"].reshape(-1, 4)
    orientation = np.repeat(orientation[:1], n, axis=0) if len(orientation) < n else orientation[:n]
    turns = np.stack([_axis_angle(o) for o in orientation])  # one per spine point, or one for all
    local = np.zeros((n, m, 3))
    local[:, :, 0] = section[None, :, 0] * scale[:, None, 0]
    local[:, :, 2] = section[None, :, 1] * scale[:, None, 1]
    frames = _spine_frames(spine) @ turns  # the cross-section turned by its orientation, then set in its plane
    points = (np.einsum("nij,nmj->nmi", frames, local) + spine[:, None, :]).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(m - 1), indexing="ij")
    at = (i * m + j).reshape(-1)
    sides = np.stack([at, at + 1, at + m + 1, at + m], axis=1)
    flat, lengths = [sides.reshape(-1)], [np.full(len(sides), 4, np.int64)]
    section_closed = m > 3 and np.allclose(section[0], section[-1])
    ring = np.arange(m - 1)
    caps = [_flag(node.fields.get("beginCap"), True), _flag(node.fields.get("endCap"), True)]
    if section_closed and caps[0]:
        flat.append(ring[::-1])
        lengths.append(np.array([len(ring)]))
    if section_closed and caps[1]:
        flat.append(ring + (n - 1) * m)
        lengths.append(np.array([len(ring)]))
    closed = section_closed and (all(caps) or (n > 2 and np.allclose(spine[0], spine[-1])))
    return points, np.concatenate(flat).astype(np.int64), np.concatenate(lengths), closed
