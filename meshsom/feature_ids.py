"""Which feature ids of 3D Tiles 1.1 glTF content are its buildings (``EXT_mesh_features``,
``EXT_instance_features``).

A primitive's ``EXT_mesh_features.featureIds`` is a list of *feature-id sets*: each names its ids
by a vertex attribute (``attribute: N``: ``_FEATURE_ID_N``), by a texture (``texture``: an id per
texel, read at each triangle's texture coordinates through the texture's ``channels``), or by
neither (implicit: the id is the vertex index); with ``featureCount``, optional ``nullFeatureId``
(the id of no feature), ``label`` and ``propertyTable`` (the ``EXT_structural_metadata`` table
whose rows the ids index). Converters of CityGML write several sets: one per building and one per
surface (wall, roof) or part. The set read as the buildings is, in this order
(:func:`building_ids`):

1. a set whose label, property table name, class id or class name names buildings
   (:data:`BUILDING_WORDS`) and no parts (:data:`PART_WORDS`: ``BuildingPart``, ``roof``,
   ``buildingComponents``...);
2. else a set, not named for parts, whose class has a property that names buildings
   (``building_id``, ``BuildingID``, ``bldg``, ``gml_id``), unless another such set, or an unnamed
   one, has fewer features that still split the content (a part's table may name its building);
3. else, of the sets not named for parts, the one of the fewest features present that still splits
   the content (two or more), ties to the lower index; the first where none splits;
4. else (every set names parts): the parts grouped into buildings by a property of their table
   that names their building (:func:`parent_column`: ``building_id``, ``parent``...); without one
   the feature ids are not used: each glTF node a building, so that no building is split into its
   surfaces.

Sets are matched across a content's primitives by their index in the list (as the tools that
write several sets write them). The chosen set's ids are rewritten as the primitive's
``_FEATURE_ID_0`` (the attribute :func:`meshsom.tiles3d.batched_meshes` reads); a texture set's
triangles get their vertices split where two features share one. Each note says which set was
read and why.

``EXT_instance_features`` (on a node drawn once per instance, ``EXT_mesh_gpu_instancing``) gives
each instance a feature id the same way (``_FEATURE_ID_N`` of the instancing attributes, or the
instance index); instances that share an id are one building. The chosen ids are left in the
node's instancing attribute ``_FEATURE_ID_0`` and the node marked (:data:`INSTANCE_MARK`) for
:func:`meshsom.tiles3d.instanced_glb`, which gives each instance's node its id
(:data:`INSTANCE_FEATURE`).
"""

from __future__ import annotations

import base64
import io
import json
import re
from dataclasses import dataclass, field

import numpy as np

from meshsom.errors import InputFileError
from meshsom.gltf_compression import _Binary, join_glb, split_glb

MESH_FEATURES = "EXT_mesh_features"
INSTANCE_FEATURES = "EXT_instance_features"
METADATA = "EXT_structural_metadata"
#: Words (of a set's label, its property table's name, class id or class name) that name buildings: CityGML's
#: Building and its module prefix, the Dutch BAG's pand, German, French, Spanish, English.
BUILDING_WORDS = frozenset({"building", "buildings", "bldg", "pand", "panden", "gebaeude", "gebäude", "batiment",
                            "bâtiment", "batiments", "edificio", "edificios", "house", "houses"})
#: Words that name parts of a building: a set so named is never read as the buildings (CityGML's BuildingPart and
#: its boundary surfaces, openings and installations; the 3D Tiles samples' buildingComponents).
PART_WORDS = frozenset({"part", "parts", "surface", "surfaces", "wall", "walls", "roof", "roofs", "ground", "floor",
                        "ceiling", "window", "windows", "door", "doors", "opening", "openings", "component",
                        "components", "face", "faces", "installation", "installations", "closure", "boundary",
                        "semantic", "semantics", "element", "elements"})
#: Property names that name the building of a row: ``gml_id`` (CityGML's object ids, as converters keep them).
BUILDING_PROPERTIES = frozenset({"gml_id", "gmlid"})
#: Words a property of a part's table is made of where it names the part's building (with a building word or
#: "parent": ``building_id``, ``BuildingID``, ``parent_gml_id``, ``bldg_ref``).
PARENT_WORDS = frozenset({"parent"})
ID_WORDS = frozenset({"id", "ids", "gml", "ref", "key", "name", "uuid", "guid", "identifier", "identificatie"})
#: Node extras set by :func:`building_ids` on a node whose instancing attribute ``_FEATURE_ID_0`` holds the chosen
#: instance feature ids; and the child-node extras (:func:`meshsom.tiles3d.instanced_glb`) of each instance's id.
INSTANCE_MARK = "meshsom_instance_features"
INSTANCE_FEATURE = "meshsom_feature"
#: The feature id given the triangles of a primitive that lacks the set read as buildings (a set's index is its place in
#: each primitive's list; a primitive may have fewer): listed as not read, never merged into a feature's building.
NO_SET_ID = 2**31 - 1
#: The extension that moves, turns and scales a texture's coordinates (honoured on feature-id textures).
TEXTURE_TRANSFORM = "KHR_texture_transform"
#: glTF sampler wrap modes (REPEAT by default).
_REPEAT, _CLAMP, _MIRROR = 10497, 33071, 33648
_TRIANGLES = 4
_UINT, _FLOAT = 5125, 5126


@dataclass
class FeatureChoice:
    """The feature ids read as a content's buildings (:func:`building_ids`).

    Attributes
    ----------
    table : int or None
        The ``EXT_structural_metadata`` property table that the ids index (ids, labels).
    null_id : int or None
        The chosen set's ``nullFeatureId``: triangles of no feature.
    parent_column : str or None
        A column of ``table`` naming each part's building (every set names parts): features grouped by it.
    by_node : bool
        The feature ids are not used (every set names parts, none says their building): each glTF node a building.
    set_index : int or None
        The set read, where some primitive lacks it (its triangles carry :data:`NO_SET_ID`).
    notes : list of str
    """

    table: int | None = None
    null_id: int | None = None
    parent_column: str | None = None
    by_node: bool = False
    set_index: int | None = None
    notes: list = field(default_factory=list)


def has_features(gltf: dict) -> bool:
    """Whether a glTF document's primitives carry ``EXT_mesh_features`` feature-id sets, or its nodes
    ``EXT_instance_features``."""
    return bool(_primitives(gltf)) or bool(_instance_nodes(gltf))


def _words(text) -> list[str]:
    """A name's words, lower case: camelCase, snake_case, ``bldg:Building`` and spaces split."""
    text = re.sub(r"([a-z0-9])([A-Z])", r"\1 \2", str(text))
    return [w for w in re.split(r"[^0-9a-zA-Zäöüéèâ]+", text.lower()) if w]


def _primitives(gltf: dict) -> list[dict]:
    """The primitives with a list of ``EXT_mesh_features`` sets."""
    out = []
    for mesh in gltf.get("meshes") if isinstance(gltf.get("meshes"), list) else []:
        for primitive in (mesh.get("primitives") or []) if isinstance(mesh, dict) else []:
            ext = ((primitive.get("extensions") or {}) if isinstance(primitive, dict) else {}).get(MESH_FEATURES)
            if isinstance(ext, dict) and isinstance(ext.get("featureIds"), list) and ext["featureIds"]:
                out.append(primitive)
    return out


def _instance_nodes(gltf: dict) -> list[dict]:
    """The nodes drawn once per instance whose instances carry ``EXT_instance_features`` sets."""
    from meshsom.tiles3d import GPU_INSTANCING

    out = []
    for node in gltf.get("nodes") if isinstance(gltf.get("nodes"), list) else []:
        ext = (node.get("extensions") or {}) if isinstance(node, dict) else {}
        if isinstance(ext.get(GPU_INSTANCING), dict) and isinstance(ext.get(INSTANCE_FEATURES), dict) and \
                isinstance(ext[INSTANCE_FEATURES].get("featureIds"), list) and ext[INSTANCE_FEATURES]["featureIds"]:
            out.append(node)
    return out


def resolve_schema(gltf: dict, resolve, fallback: dict | None, where: str) -> tuple[dict | None, str | None]:
    """The ``EXT_structural_metadata`` schema of a glTF content: its own ``schema``, else the file its ``schemaUri``
    names (``resolve(uri)`` gives its bytes), else ``fallback`` (the tileset's ``schema``, for content that names
    none); and a note where the named file cannot be read."""
    metadata = (gltf.get("extensions") or {}).get(METADATA) if isinstance(gltf.get("extensions"), dict) else None
    if not isinstance(metadata, dict):
        return None, None
    if isinstance(metadata.get("schema"), dict):
        return metadata["schema"], None
    uri = metadata.get("schemaUri")
    if isinstance(uri, str) and resolve is not None:
        try:
            schema = json.loads(bytes(resolve(uri)).decode("utf-8-sig"))
        except (InputFileError, OSError, ValueError, UnicodeDecodeError) as err:
            return fallback, f"its metadata schema {uri!r} (EXT_structural_metadata schemaUri) cannot be read " \
                             f"({getattr(err, 'problem', None) or err}): no ids or labels from its property table"
        if isinstance(schema, dict):
            return schema, None
    return fallback, None


def _classify(schema: dict | None, tables: list, fset: dict) -> str | None:
    """``"building"`` where a set's names name buildings (and no parts), ``"part"`` where they name parts,
    ``"building property"`` where its class has a property naming buildings, None otherwise."""
    table = tables[fset["propertyTable"]] if isinstance(fset.get("propertyTable"), int) and \
        0 <= fset["propertyTable"] < len(tables) and isinstance(tables[fset["propertyTable"]], dict) else {}
    classes = (schema or {}).get("classes") if isinstance((schema or {}).get("classes"), dict) else {}
    cls = classes.get(table.get("class")) if isinstance(classes.get(table.get("class")), dict) else {}
    words = set()
    for text in (fset.get("label"), table.get("name"), table.get("class"), cls.get("name")):
        if isinstance(text, str):
            words.update(_words(text))
    if words & PART_WORDS:
        return "part"
    if words & BUILDING_WORDS:
        return "building"
    names = list((cls.get("properties") or {}) if isinstance(cls.get("properties"), dict) else {}) + \
        list((table.get("properties") or {}) if isinstance(table.get("properties"), dict) else {})
    if any(n.lower() in BUILDING_PROPERTIES or set(_words(n)) & BUILDING_WORDS for n in names):
        return "building property"
    return None


def parent_column(schema: dict | None, table: dict) -> str | None:
    """The property of a parts' table (string or integer scalar) whose name says each part's building: its words all
    among :data:`BUILDING_WORDS`, :data:`PARENT_WORDS` and :data:`ID_WORDS`, one of the first two."""
    classes = (schema or {}).get("classes") if isinstance((schema or {}).get("classes"), dict) else {}
    cls = classes.get(table.get("class")) if isinstance(classes.get(table.get("class")), dict) else {}
    properties = cls.get("properties") if isinstance(cls.get("properties"), dict) else {}
    for name, kind in properties.items():
        words = set(_words(name))
        if not isinstance(kind, dict) or kind.get("array") or kind.get("type") not in ("STRING", "SCALAR") or \
                (kind.get("type") == "SCALAR" and not str(kind.get("componentType", "")).startswith(("INT", "UINT"))):
            continue
        if words and words <= BUILDING_WORDS | PARENT_WORDS | ID_WORDS and words & (BUILDING_WORDS | PARENT_WORDS):
            return name
    return None


def _triangles(gltf: dict, binary: bytes, primitive: dict, count: int, where: str) -> np.ndarray | None:
    """A triangle primitive's ``(F, 3) int64`` vertex indices; None for strips, fans, lines, points."""
    from meshsom.tiles3d import _accessor

    if primitive.get("mode", _TRIANGLES) != _TRIANGLES:
        return None
    if "indices" in primitive:
        index = _accessor(gltf, binary, primitive["indices"], where, "triangle indices", "SCALAR")[:, 0]
    else:
        index = np.arange(count, dtype=np.float64)
    faces = index[:len(index) // 3 * 3].astype(np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= count):
        raise InputFileError(where, f"holds triangles whose indices go beyond their {count} vertices")
    return faces


def _image(gltf: dict, binary: bytes, texture_index, where: str, cache: dict) -> np.ndarray:
    """The pixels ``(H, W, C)`` of a texture's image (in the binary chunk, or a ``data:`` URI), decoded once."""
    from PIL import Image

    from meshsom.tiles3d import _view_bytes

    if texture_index in cache:
        return cache[texture_index]
    textures, images = gltf.get("textures") or [], gltf.get("images") or []
    texture = textures[texture_index] if isinstance(texture_index, int) and 0 <= texture_index < len(textures) else None
    source = texture.get("source") if isinstance(texture, dict) else None
    image = images[source] if isinstance(source, int) and 0 <= source < len(images) else None
    if not isinstance(image, dict):
        raise InputFileError(where, f"holds a feature-id texture {texture_index!r} without an image")
    if isinstance(image.get("uri"), str) and image["uri"].startswith("data:"):
        data = base64.b64decode(image["uri"].partition(",")[2])
    else:
        data = _view_bytes(gltf, binary, image.get("bufferView"))
    if data is None:
        raise InputFileError(where, f"holds a feature-id texture {texture_index!r} whose image is not in the file "
                                    f"({str(image.get('uri', image.get('bufferView')))[:60]})")
    try:
        with Image.open(io.BytesIO(data)) as img:
            pixels = np.asarray(img.convert("RGBA") if img.mode in ("P", "PA", "1", "CMYK", "YCbCr") else img)
    except Exception as err:  # PIL raises many types for corrupt images
        raise InputFileError(where, f"holds a feature-id texture {texture_index!r} whose image cannot be decoded "
                                    f"({type(err).__name__}: {err})") from None
    cache[texture_index] = pixels if pixels.ndim == 3 else pixels[:, :, None]
    return cache[texture_index]


def _wrap(t: np.ndarray, size: int, mode) -> np.ndarray:
    """Texel indices ``(N,) int64`` of texture coordinates ``t`` (N,) along an axis of ``size`` texels, nearest
    sampling, by the sampler's wrap mode."""
    x = np.floor(t * size)
    if mode == _CLAMP:
        return np.clip(x, 0, size - 1).astype(np.int64)
    if mode == _MIRROR:
        x = np.mod(x, 2 * size)
        return np.where(x >= size, 2 * size - 1 - x, x).astype(np.int64)
    return np.mod(x, size).astype(np.int64)


def _texture_ids(gltf: dict, binary: bytes, primitive: dict, info: dict, faces: np.ndarray, where: str,
                 cache: dict) -> np.ndarray:
    """Each triangle's feature id ``(F,) float64`` from a feature-id texture: the texel (nearest) at the mean of the
    triangle's texture coordinates (moved by the texture's :data:`TEXTURE_TRANSFORM`), its ``channels`` (default
    ``[0]``) read as the id's bytes, least significant first."""
    from meshsom.tiles3d import _accessor

    transform = (info.get("extensions") or {}).get(TEXTURE_TRANSFORM) if isinstance(info.get("extensions"), dict) else None
    transform = transform if isinstance(transform, dict) else {}
    semantic = f"TEXCOORD_{transform.get('texCoord', info.get('texCoord', 0))}"
    if semantic not in (primitive.get("attributes") or {}):
        raise InputFileError(where, f"holds a feature-id texture read at {semantic}, which its primitive does not have")
    uv = _accessor(gltf, binary, primitive["attributes"][semantic], where, semantic, "VEC2")
    if transform:  # offset + rotation (counter-clockwise) x scale, as KHR_texture_transform composes them
        (sx, sy), angle = transform.get("scale", (1.0, 1.0)), float(transform.get("rotation", 0.0))
        matrix = np.array([[np.cos(angle) * sx, -np.sin(angle) * sy], [np.sin(angle) * sx, np.cos(angle) * sy]])
        uv = uv @ matrix.T + np.asarray(transform.get("offset", (0.0, 0.0)), np.float64)
    pixels = _image(gltf, binary, info.get("index"), where, cache)
    channels = info.get("channels", [0])
    if not isinstance(channels, list) or not channels or not all(isinstance(c, int) and 0 <= c < pixels.shape[2]
                                                                 for c in channels):
        raise InputFileError(where, f"holds a feature-id texture whose channels {channels!r} its "
                                    f"{pixels.shape[2]}-channel image does not have")
    sampler = {}
    texture = (gltf.get("textures") or [])[info["index"]]
    if isinstance(texture.get("sampler"), int) and 0 <= texture["sampler"] < len(gltf.get("samplers") or []):
        sampler = gltf["samplers"][texture["sampler"]]
    centre = uv[faces].mean(axis=1) if len(faces) else np.zeros((0, 2))
    height, width = pixels.shape[:2]
    x = _wrap(centre[:, 0], width, sampler.get("wrapS", _REPEAT))
    y = _wrap(centre[:, 1], height, sampler.get("wrapT", _REPEAT))  # glTF: v = 0 is the image's first row
    texel = pixels[y, x].astype(np.int64)
    return sum(texel[:, c] << (8 * k) for k, c in enumerate(channels)).astype(np.float64)


@dataclass
class _Set:
    """One feature-id set of one primitive (or instanced node), read."""
    spec: dict
    vertex_ids: np.ndarray | None  # (V,) float64, or None for a texture set
    triangle_ids: np.ndarray  # (F,) float64 (V,) for a node's instances
    accessor: int | None  # the attribute's accessor, where the set is one


def _present(sets: list[_Set]) -> int:
    """How many features a set's triangles (over the primitives) carry: whole numbers from 0, the null id not."""
    found = set()
    for s in sets:
        ids = s.triangle_ids[np.isfinite(s.triangle_ids)]
        ids = np.rint(ids[ids >= 0]).astype(np.int64)
        null = s.spec.get("nullFeatureId")
        found.update(np.unique(ids[ids != null] if isinstance(null, int) else ids).tolist())
    return len(found)


def _choose(schema: dict | None, tables: list, by_position: dict[int, list[_Set]], what: str
            ) -> tuple[int | None, str | None, str]:
    """The position of the set read as buildings (None: none; each node a building), the parts' column naming their
    building, and why, in words (as the module says)."""
    first = {k: sets[0].spec for k, sets in by_position.items()}
    kinds = {k: _classify(schema, tables, spec) for k, spec in first.items()}
    present = {k: _present(sets) for k, sets in by_position.items()}

    def name(k: int) -> str:
        spec, table = first[k], first[k].get("propertyTable")
        said = [f"label {spec['label']!r}"] if isinstance(spec.get("label"), str) else []
        if isinstance(table, int) and 0 <= table < len(tables) and isinstance(tables[table], dict):
            said.append(f"class {tables[table].get('class')!r}")
        kind = "ids by texture" if isinstance(spec.get("texture"), dict) else "ids by attribute" \
            if "attribute" in spec else "implicit ids"
        count = f"{present[k]} feature" + ("s" if present[k] != 1 else "")
        return f"set {k} ({', '.join([*said, kind, count])})"

    def others(k: int) -> str:
        return "; the others: " + ", ".join(name(j) for j in sorted(kinds) if j != k) if len(kinds) > 1 else ""

    named = [k for k in sorted(kinds) if kinds[k] == "building"]
    if named:
        k = min(named, key=lambda j: (present[j], j))
        return k, None, f"its {what} feature ids of {name(k)} read as the buildings: its name names buildings{others(k)}"
    named = [k for k in sorted(kinds) if kinds[k] == "building property"]
    if named:  # unless a set of fewer features splits the content (a part's table names its building too)
        k = min(named, key=lambda j: (present[j], j))
        coarser = [j for j in sorted(kinds) if kinds[j] != "part" and 1 < present[j] < present[k]]
        if not coarser:
            return k, None, f"its {what} feature ids of {name(k)} read as the buildings: a property names buildings" \
                            f"{others(k)}"
    plain = [k for k in sorted(kinds) if kinds[k] in (None, "building property")]
    if plain:
        splitting = [k for k in plain if present[k] > 1]
        k = min(splitting, key=lambda j: (present[j], j)) if splitting else plain[0]
        why = ": the set of the fewest features that splits the content" if splitting and len(plain) > 1 else \
            ": no set splits the content, the first read" if len(plain) > 1 else ""
        return k, None, f"its {what} feature ids of {name(k)} read as the buildings{why}{others(k)}"
    for k in sorted(kinds):
        table = first[k].get("propertyTable")
        column = parent_column(schema, tables[table]) if isinstance(table, int) and 0 <= table < len(tables) and \
            isinstance(tables[table], dict) else None
        if column:
            return k, column, (f"its {what} feature ids of {name(k)} name parts of buildings: the parts of one "
                               f"{column!r} read as one building{others(k)}")
    return None, None, (f"its {what} feature ids ({', '.join(name(k) for k in sorted(kinds))}) name parts of "
                        "buildings, and no property says which building: not read as buildings (each glTF node one)")


def _ids(gltf: dict, binary: bytes, spec, k: int, attributes: dict, count: int, extension: str, where: str
         ) -> tuple[dict, np.ndarray, int | None]:
    """A set of ids by attribute (``_FEATURE_ID_N`` of ``attributes``) or implicit (the index, 0..count-1): its JSON,
    its ids ``(count,) float64`` and its accessor (None for implicit ids)."""
    from meshsom.tiles3d import _accessor

    if not isinstance(spec, dict):
        raise InputFileError(where, f"holds {extension} feature-id set {k} that is not a JSON object")
    if "attribute" not in spec:
        return spec, np.arange(count, dtype=np.float64), None
    semantic = f"_FEATURE_ID_{spec['attribute']}"
    if semantic not in attributes:
        raise InputFileError(where, f"holds {extension} set {k} read from {semantic}, which its attributes do not have")
    ids = _accessor(gltf, binary, attributes[semantic], where, f"{extension} {semantic}", "SCALAR")[:, 0]
    if len(ids) != count:
        raise InputFileError(where, f"holds {extension} {semantic} of {len(ids)} values for {count}")
    return spec, ids, attributes[semantic]


def _mesh_sets(gltf: dict, binary: bytes, primitive: dict, where: str, cache: dict) -> list[_Set | None]:
    """The feature-id sets of a primitive, read (None where a set cannot be read: a texture set of a primitive that is
    not triangles)."""
    attributes = primitive.get("attributes") if isinstance(primitive.get("attributes"), dict) else {}
    if "POSITION" not in attributes:
        raise InputFileError(where, "holds a primitive with feature ids (EXT_mesh_features) and no positions")
    count = (gltf.get("accessors") or [])[attributes["POSITION"]]["count"]
    faces = _triangles(gltf, binary, primitive, count, where)
    out = []
    for k, spec in enumerate(primitive["extensions"][MESH_FEATURES]["featureIds"]):
        if isinstance(spec, dict) and "attribute" not in spec and isinstance(spec.get("texture"), dict):
            out.append(None if faces is None else _Set(
                spec, None, _texture_ids(gltf, binary, primitive, spec["texture"], faces, where, cache), None))
            continue
        spec, vertex, accessor = _ids(gltf, binary, spec, k, attributes, count, MESH_FEATURES, where)
        out.append(_Set(spec, vertex, vertex[faces[:, 0]] if faces is not None else vertex, accessor))
    return out


def _instance_sets(gltf: dict, binary: bytes, node: dict, where: str) -> list[_Set]:
    """The ``EXT_instance_features`` sets of a node drawn once per instance, read: each instance's id."""
    from meshsom.tiles3d import GPU_INSTANCING

    attributes = node["extensions"][GPU_INSTANCING].get("attributes") or {}
    accessors = gltf.get("accessors") or []
    counts = {accessors[attributes[key]]["count"] for key in ("TRANSLATION", "ROTATION", "SCALE") if key in attributes}
    count = counts.pop() if len(counts) == 1 else 0
    out = []
    for k, spec in enumerate(node["extensions"][INSTANCE_FEATURES]["featureIds"]):
        spec, ids, accessor = _ids(gltf, binary, spec, k, attributes, count, INSTANCE_FEATURES, where)
        out.append(_Set(spec, ids, ids, accessor))
    return out


def _by_position(read: list[list[_Set | None]]) -> dict[int, list[_Set]]:
    by_position: dict[int, list[_Set]] = {}
    for sets in read:
        for k, s in enumerate(sets):
            if s is not None:
                by_position.setdefault(k, []).append(s)
    return by_position


def building_ids(glb: bytes, where: str, schema: dict | None = None) -> tuple[bytes, FeatureChoice]:
    """A plain GLB (no compression) with the feature ids that are its buildings made each primitive's
    ``_FEATURE_ID_0`` (and each instanced node's, :data:`INSTANCE_MARK`), as the module says; the same bytes where it
    has no feature-id sets.

    Parameters
    ----------
    glb : bytes
    where : str
    schema : dict or None
        The content's ``EXT_structural_metadata`` schema (:func:`resolve_schema`), whose class names and properties
        say which sets name buildings.

    Returns
    -------
    glb : bytes
    choice : FeatureChoice

    Raises
    ------
    InputFileError
        A set naming an attribute, texture or image that is not there, or laid out otherwise than the specification
        says.
    """
    gltf, binary = split_glb(glb, where)
    try:
        return _building_ids(gltf, binary, where, schema)
    except InputFileError:
        raise
    except (AttributeError, KeyError, IndexError, TypeError, ValueError) as err:
        raise InputFileError(where, f"holds feature ids (EXT_mesh_features, EXT_instance_features) laid out otherwise "
                                    f"than their specification says ({type(err).__name__}: {err})") from None


def _building_ids(gltf: dict, binary: bytes, where: str, schema: dict | None) -> tuple[bytes, FeatureChoice]:
    """The work of :func:`building_ids`, which answers for what it raises."""
    from meshsom.tiles3d import GPU_INSTANCING

    primitives, nodes = _primitives(gltf), _instance_nodes(gltf)
    choice = FeatureChoice()
    if not primitives and not nodes:
        return join_glb(gltf, binary), choice
    metadata = (gltf.get("extensions") or {}).get(METADATA)
    tables = metadata.get("propertyTables") if isinstance(metadata, dict) and \
        isinstance(metadata.get("propertyTables"), list) else []
    out = _Binary(binary)
    views, accessors = gltf.setdefault("bufferViews", []), gltf.setdefault("accessors", [])

    def add(values: np.ndarray, component: int, kind: str = "SCALAR") -> int:
        data = np.ascontiguousarray(values)
        views.append({"buffer": 0, "byteOffset": out.append(data.tobytes()), "byteLength": data.nbytes})
        accessor = {"bufferView": len(views) - 1, "componentType": component, "count": len(data), "type": kind}
        if kind == "VEC3" and len(data):
            accessor["min"], accessor["max"] = data.min(axis=0).tolist(), data.max(axis=0).tolist()
        accessors.append(accessor)
        return len(accessors) - 1

    if nodes:  # instances are the buildings: the meshes' own ids are parts of them
        read = [_instance_sets(gltf, binary, node, where) for node in nodes]
        k, column, note = _choose(schema, tables, _by_position(read), "instances'")
        choice.notes.append(note.replace("(each glTF node one)", "(each instance one)"))
        for node, sets in zip(nodes, read):
            attributes = node["extensions"][GPU_INSTANCING].setdefault("attributes", {})
            chosen = sets[k] if k is not None and k < len(sets) else None
            for name in [a for a in attributes if a.startswith("_FEATURE_ID_")]:
                del attributes[name]
            del node["extensions"][INSTANCE_FEATURES]
            if chosen is None:
                continue
            attributes["_FEATURE_ID_0"] = chosen.accessor if chosen.accessor is not None else \
                add(chosen.vertex_ids.astype("<u4"), _UINT)
            node["extras"] = {**(node["extras"] if isinstance(node.get("extras"), dict) else {}), INSTANCE_MARK: True}
            _chosen_meta(choice, chosen.spec, column)
        if primitives:
            choice.notes.append("its meshes' own feature ids (EXT_mesh_features) not read: the instances are the "
                                "buildings")
        return join_glb(gltf, bytes(out.data)), choice
    if primitives:
        cache: dict = {}
        read = [_mesh_sets(gltf, binary, primitive, where, cache) for primitive in primitives]
        by_position = _by_position(read)
        k, column, note = _choose(schema, tables, by_position, "meshes'")
        if len(by_position) > 1 or k is None or "attribute" not in by_position[k][0].spec:
            choice.notes.append(note)  # not for the one set of ids by attribute that 3D Tiles 1.1 content mostly has
        if k is None:
            choice.by_node = True
        for primitive, sets in zip(primitives, read):
            chosen = sets[k] if k is not None and k < len(sets) else None
            attributes = primitive["attributes"]
            for name in [a for a in attributes if a.startswith("_FEATURE_ID_") or a in ("_BATCHID", "_batchid")]:
                del attributes[name]
            if chosen is None:
                if k is not None:  # a primitive without the set: listed, not merged into another's feature
                    count = gltf["accessors"][attributes["POSITION"]]["count"]
                    attributes["_FEATURE_ID_0"] = add(np.full(count, NO_SET_ID, "<u4"), _UINT)
                    choice.set_index = k
                continue
            _chosen_meta(choice, chosen.spec, column)
            if chosen.accessor is not None:
                attributes["_FEATURE_ID_0"] = chosen.accessor
            elif chosen.vertex_ids is not None:
                attributes["_FEATURE_ID_0"] = add(chosen.vertex_ids.astype("<u4"), _UINT)
            else:  # a texture set: a vertex for each feature of the triangles around it
                _split_by_triangle(gltf, binary, primitive, chosen.triangle_ids, add, where)
    return join_glb(gltf, bytes(out.data)), choice


def _chosen_meta(choice: FeatureChoice, spec: dict, column: str | None) -> None:
    """The chosen set's property table, null id and parts' column, from the first primitive (or node) that has it."""
    if choice.table is None and isinstance(spec.get("propertyTable"), int):
        choice.table = spec["propertyTable"]
    if choice.null_id is None and isinstance(spec.get("nullFeatureId"), int) and spec["nullFeatureId"] >= 0:
        choice.null_id = spec["nullFeatureId"]
    choice.parent_column = choice.parent_column or column


def _split_by_triangle(gltf: dict, binary: bytes, primitive: dict, triangle_ids: np.ndarray, add, where: str) -> None:
    """A triangle primitive rewritten so that each vertex carries one feature id (``_FEATURE_ID_0``): a vertex shared
    by triangles of several features becomes one vertex per feature. Its other attributes are dropped."""
    from meshsom.tiles3d import _accessor

    positions = _accessor(gltf, binary, primitive["attributes"]["POSITION"], where, "POSITION", "VEC3")
    faces = _triangles(gltf, binary, primitive, len(positions), where)
    ids = np.where(np.isfinite(triangle_ids), triangle_ids, -1.0)
    pairs = np.stack([faces.ravel().astype(np.float64), np.repeat(ids, 3)], axis=1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    primitive["attributes"] = {"POSITION": add(positions[unique[:, 0].astype(np.int64)].astype("<f4"), _FLOAT, "VEC3"),
                               "_FEATURE_ID_0": add(unique[:, 1].astype("<f4"), _FLOAT)}
    primitive["indices"] = add(inverse.reshape(-1).astype("<u4"), _UINT)
    primitive.pop("targets", None)
