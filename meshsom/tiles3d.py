"""Reading buildings from 3D Tiles: batched 3D models (``.b3dm``) and the tilesets that hold them
(``tileset.json``).

City models published for the web (Cesium ion, municipal portals, converters from CityGML such as
3DCityDB's and FME's) come as 3D Tiles: glTF payloads in earth-centred coordinates, each building a
*batch* (the ``_BATCHID`` vertex attribute; ``_FEATURE_ID_0`` in 3D Tiles 1.1 glTF content):

- **A b3dm file**: its header, feature table (``BATCH_LENGTH``, ``RTC_CENTER``) and batch table
  (per-building properties) are read here; its glTF through trimesh, with each node's transform,
  then turned from glTF's y up to 3D Tiles' z up, and moved by ``RTC_CENTER`` (or the glTF's
  ``CESIUM_RTC`` centre). One mesh per batch: ids ``name#<id>``, ``<id>`` the batch's first
  property of :attr:`meshsom.io.ReaderOptions.id_attributes` when those are unique in the batch
  table, else the batch number; labels from :attr:`meshsom.io.ReaderOptions.label_attribute`. In 3D
  Tiles 1.1 glTF content the batches are the features of the ``EXT_mesh_features`` feature-id set (by
  attribute ``_FEATURE_ID_N``, texture or implicit) that names buildings, not their surfaces or parts
  (:mod:`meshsom.feature_ids`), and of ``EXT_instance_features`` (instances sharing an id one building);
  the batch table is the ``EXT_structural_metadata`` property table that set names
  (:func:`property_table`: its string and number columns), its class looked up in the content's schema,
  the file its ``schemaUri`` names, or the tileset's ``schema``.
  Batches that a batch table hierarchy (``3DTILES_batch_table_hierarchy``, the draft's ``HIERARCHY``)
  makes parts of an object without geometry of its own (walls, roofs and doors of a building) are
  that object, one building of parts united in preprocessing (:func:`hierarchy_groups`).
- **A tileset** (a ``.json`` with ``asset`` and ``root``): its tiles are walked with their
  transforms (external tilesets followed, within the tileset's folder), and the contents that
  make the finest level are read: a tile's content when it has no children, or when its
  refinement is ``ADD`` (children add to it; ``REPLACE`` children stand in for it). Ids are
  ``name#<content path>#<id>``. Contents other than b3dm and glb (points, instances, composites)
  are listed as rejections.
- **Coordinates**: earth-centred (ECEF, WGS 84) positions are turned into east-north-up metres
  about each building's centre (:func:`meshsom.crs.east_north_up_of_geocentric`), with a note;
  the mesh's origin stays earth-centred. Positions in a local frame (a b3dm read without the
  tileset whose root transform places it) are read as metres, with a note. A lone content whose z is
  not up (pg2b3dm writes offsets in earth-centred axes from its tileset's root translation: read alone,
  Delaware's buildings lean 51 deg) is turned east-north-up about the up its walls and floors show
  (:func:`earth_axes_up`), with a note; read the tileset to place it.
- **Batches**: a b3dm whose feature table gives no ``BATCH_LENGTH`` (py3dtiles, py3dtilers) has as many
  batches as its batch table's columns have rows (:func:`batch_table_length`); ``BATCH_LENGTH`` 0 with
  ``_BATCHID`` in the glTF (pg2b3dm) is batched by those ids. A batch spread over Draco primitives (one per
  material) that Draco quantized each on its own grid is welded within half a quantum of each
  (:func:`weld_quantized`), so that a building closes again.

Draco- and meshopt-compressed glTF is decompressed first (:mod:`meshsom.gltf_compression`);
implicit tiling (3D Tiles 1.1 quadtrees and octrees named by templates, listed by subtree files) is
walked by :mod:`meshsom.implicit_tiling`. A node that draws its mesh once per instance
(``EXT_mesh_gpu_instancing``: 3D Tiles 1.1's instanced content, gltfpack's ``-mi``) holds one child node per
instance (:func:`instanced_glb`), read as any node (trimesh ignores the extension: the instances were one mesh at the
node's place); so in ``.glb`` and ``.gltf`` files (:func:`meshsom.io.read_trimesh`). Not read: b3dm of the 2016 draft layouts (upgrade with
``3d-tiles-tools upgrade``).
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path, PurePosixPath
from typing import Iterator
from urllib.parse import unquote, urlparse

import numpy as np

from meshsom.errors import InputFileError
from meshsom.feature_ids import INSTANCE_FEATURE, INSTANCE_MARK, NO_SET_ID
from meshsom.gltf_compression import decompress_glb, quantum_in_frame, split_glb
from meshsom.implicit_tiling import implicit_contents

#: File name endings read as 3D Tiles content.
B3DM_SUFFIXES = (".b3dm", ".cmpt")
#: A mesh whose centre lies this far (metres) from the earth's centre, give or take
#: :data:`ECEF_BAND`, is in earth-centred coordinates.
EARTH_RADIUS = 6_371_000.0
ECEF_BAND = 100_000.0
#: glTF is y up; 3D Tiles turn it z up: (x, y, z) -> (x, -z, y).
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
#: Positions beyond this (metres) are refused: the earth is 6.4e6 m across.
MAX_COORDINATE = 1e9
#: Tilesets nested (external tilesets) deeper than this are refused.
MAX_TILESET_DEPTH = 64
_FEATURE_ATTRIBUTES = ("_BATCHID", "_FEATURE_ID_0", "_batchid")
#: The glTF extension that draws a node's mesh once per instance (3D Tiles 1.1's instanced content, gltfpack -mi,
#: Blender's GPU instances), and the most instances expanded.
GPU_INSTANCING = "EXT_mesh_gpu_instancing"
MAX_INSTANCES = 1_000_000
#: glTF accessor component types: NumPy dtype and, for normalized integers, the value that stands for 1.
_COMPONENTS = {5120: ("<i1", 127), 5121: ("<u1", 255), 5122: ("<i2", 32767), 5123: ("<u2", 65535),
               5125: ("<u4", None), 5126: ("<f4", None)}


def is_tileset(document) -> bool:
    """Whether a parsed JSON document is a 3D Tiles tileset."""
    return isinstance(document, dict) and isinstance(document.get("asset"), dict) and isinstance(document.get("root"), dict)


def parse_b3dm(data: bytes, where: str) -> tuple[dict, dict, bytes, bytes]:
    """The parts of a b3dm.

    Returns
    -------
    feature_table : dict
    batch_table : dict
        JSON properties, one list per property (binary batch-table properties are left out).
    glb : bytes
    feature_binary : bytes
        The feature table's binary body (``RTC_CENTER`` may point into it).

    Raises
    ------
    InputFileError
        Not a b3dm, a draft (2016) layout, or lengths that do not fit the file.
    """
    if len(data) < 28 or data[:4] != b"b3dm":
        raise InputFileError(where, f"is not a b3dm (magic {bytes(data[:4])!r}; expected b'b3dm')")
    _, version, length, ft_json, ft_bin, bt_json, bt_bin = struct.unpack_from("<4sIIIIII", data)
    if version != 1:
        raise InputFileError(where, f"is b3dm version {version}; expected 1")
    if bt_json >= 570425344 or bt_bin >= 570425344:  # a draft header: the JSON's '{"' read as a length
        raise InputFileError(where, "has a b3dm header of the 2016 draft layout (upgrade it: 3d-tiles-tools upgrade)")
    end = 28 + ft_json + ft_bin + bt_json + bt_bin
    if length > len(data) or end > min(length, len(data)):
        raise InputFileError(where, f"is cut short: its header says {length} bytes and parts ending at byte {end}; "
                                    f"the file has {len(data)}")
    pos = 28

    def table(size: int) -> dict:
        nonlocal pos
        text = bytes(data[pos:pos + size]).rstrip(b" \0")
        pos += size
        if not text:
            return {}
        try:
            value = json.loads(text)
        except ValueError as err:
            raise InputFileError(where, f"has a feature or batch table that is not JSON ({err})") from None
        if not isinstance(value, dict):
            raise InputFileError(where, "has a feature or batch table that is not a JSON object")
        return value

    feature_table = table(ft_json)
    feature_binary = bytes(data[pos:pos + ft_bin])
    pos += ft_bin
    batch_table = table(bt_json)
    pos += bt_bin
    return feature_table, batch_table, bytes(data[pos:length]), feature_binary


def _rtc_centre(feature_table: dict, feature_binary: bytes, where: str) -> np.ndarray:
    centre = feature_table.get("RTC_CENTER")
    if centre is None:
        return np.zeros(3)
    if isinstance(centre, dict) and "byteOffset" in centre:  # in the binary body
        offset = int(centre["byteOffset"])
        if offset < 0 or offset + 12 > len(feature_binary):
            raise InputFileError(where, "has an RTC_CENTER beyond its feature table")
        return np.array(struct.unpack_from("<3f", feature_binary, offset), np.float64)
    try:
        value = np.asarray(centre, np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InputFileError(where, f"has an RTC_CENTER that is not 3 numbers: {str(centre)[:60]}") from None
    if not np.isfinite(value).all():
        raise InputFileError(where, "has an RTC_CENTER that is not finite")
    return value


#: Largest distance from a whole number at which a batch id is read as that number: Draco's quantization of the
#: generic attribute that holds the ids (12 bits over 275 batches: up to 0.034 off; loaders.gl's New York tile).
QUANTIZED_ID_TOL = 0.25


def is_tile_content(glb: bytes, where: str) -> bool:
    """Whether a GLB (or a glTF JSON file) is 3D Tiles content (saved as a ``.glb`` by 3d-tiles-tools' ``b3dmToGlb``, or 3D Tiles 1.1 content
    copied out): it has a ``CESIUM_RTC`` centre, or its primitives carry batch or feature ids
    (:data:`_FEATURE_ATTRIBUTES`). Such a file is read as its tile is (:func:`content_meshes`): a building per batch,
    moved by its centre; trimesh alone would give a building per primitive, in the centre's frame. So is a glTF
    whose primitives carry ``EXT_mesh_features`` sets or whose instances ``EXT_instance_features``
    (:mod:`meshsom.feature_ids`)."""
    try:
        gltf = split_glb(glb, where)[0] if glb[:4] == b"glTF" else json.loads(glb)  # a GLB, or glTF JSON
    except (InputFileError, ValueError):
        return False  # its reading says why
    if not isinstance(gltf, dict):
        return False
    if "CESIUM_RTC" in (gltf.get("extensions") or {}):
        return True
    from meshsom.feature_ids import has_features

    if has_features(gltf):  # 3D Tiles 1.1: feature ids of any set (attribute, texture, implicit) or of instances
        return True
    meshes = gltf.get("meshes") if isinstance(gltf.get("meshes"), list) else []
    return any(isinstance(p, dict) and isinstance(p.get("attributes"), dict)
               and any(a in p["attributes"] for a in _FEATURE_ATTRIBUTES)
               for m in meshes if isinstance(m, dict) for p in (m.get("primitives") or []))


def declares_instancing(gltf: dict) -> bool:
    """Whether a glTF document uses :data:`GPU_INSTANCING`."""
    return any(isinstance(names, list) and GPU_INSTANCING in names
               for names in (gltf.get("extensionsUsed"), gltf.get("extensionsRequired")))


def instanced_glb(glb: bytes, where: str) -> tuple[bytes, int]:
    """A GLB whose nodes that draw their mesh once per instance (:data:`GPU_INSTANCING`) hold it in one child node per
    instance instead, each moved by its instance's translation, rotation and scale (in the node's frame, as the
    extension says), so that each instance is read as a node is: a building where it stands. trimesh ignores the
    extension: a city of repeated houses was one house at the node's place.

    Returns
    -------
    glb : bytes
        The same bytes where no node uses the extension.
    instances : int

    Raises
    ------
    InputFileError
        Instance attributes that are no accessors of the GLB's binary chunk, of other types or counts than the
        extension allows, or more than :data:`MAX_INSTANCES` instances.
    """
    gltf, binary = split_glb(glb, where)
    if not declares_instancing(gltf) and not any(
            isinstance(n, dict) and isinstance(n.get("extensions"), dict) and GPU_INSTANCING in n["extensions"]
            for n in (gltf.get("nodes") if isinstance(gltf.get("nodes"), list) else [])):
        return glb, 0
    try:
        return _instanced(gltf, binary, where)
    except (AttributeError, TypeError, ValueError, KeyError, IndexError) as err:
        raise InputFileError(where, f"holds {GPU_INSTANCING} laid out otherwise than its specification says "
                                    f"({type(err).__name__}: {err})") from None


def _instanced(gltf: dict, binary: bytes, where: str) -> tuple[bytes, int]:
    """The work of :func:`instanced_glb` on a document that uses the extension."""
    from meshsom.gltf_compression import join_glb

    nodes = gltf.get("nodes") if isinstance(gltf.get("nodes"), list) else []
    total = 0
    for k, node in enumerate(list(nodes)):
        extension = ((node.get("extensions") or {}) if isinstance(node, dict) else {}).get(GPU_INSTANCING)
        if not isinstance(extension, dict):
            continue
        attributes = extension.get("attributes") if isinstance(extension.get("attributes"), dict) else {}
        trs = {key: _accessor(gltf, binary, attributes[key], where, f"{GPU_INSTANCING} {key} of node {k}", kind)
               for key, kind in (("TRANSLATION", "VEC3"), ("ROTATION", "VEC4"), ("SCALE", "VEC3")) if key in attributes}
        counts = {len(a) for a in trs.values()}
        if len(counts) > 1:
            raise InputFileError(where, f"holds node {k} whose {GPU_INSTANCING} attributes count {sorted(counts)} instances")
        count = counts.pop() if counts else 0
        total += count
        if total > MAX_INSTANCES:
            raise InputFileError(where, f"holds more than {MAX_INSTANCES:,} instances ({GPU_INSTANCING})")
        del node["extensions"][GPU_INSTANCING]
        if "mesh" not in node or not count:
            continue
        matrices = _instance_matrices(count, trs.get("TRANSLATION"), trs.get("ROTATION"), trs.get("SCALE"))
        name = str(node.get("name") or f"node {k}")
        children = list(range(len(nodes), len(nodes) + count))
        features = [{}] * count
        if isinstance(node.get("extras"), dict) and node["extras"].get(INSTANCE_MARK) and "_FEATURE_ID_0" in attributes:
            ids = _accessor(gltf, binary, attributes["_FEATURE_ID_0"], where, f"{GPU_INSTANCING} _FEATURE_ID_0 of node {k}",
                            "SCALAR")[:, 0]
            if len(ids) != count:
                raise InputFileError(where, f"holds node {k} whose instances' feature ids count {len(ids)} for {count} "
                                            "instances")
            ok = np.isfinite(ids) & (ids >= 0) & (ids == np.rint(ids))
            features = [{"extras": {INSTANCE_FEATURE: int(i) if good else -1}} for i, good in zip(ids, ok)]
        nodes.extend({"name": f"{name} instance {i + 1}", "mesh": node["mesh"], "matrix": m.T.reshape(-1).tolist(),
                      **feature} for i, (m, feature) in enumerate(zip(matrices, features)))
        del node["mesh"]
        node["children"] = list(node.get("children") or []) + children
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in gltf:
            gltf[key] = [e for e in gltf[key] if e != GPU_INSTANCING]
    return join_glb(gltf, binary), total


def instanced_gltf(content: bytes, file_type: str, resolver, where: str) -> tuple[bytes, str, int]:
    """A ``.glb`` or ``.gltf`` file's bytes with its instances expanded (:func:`instanced_glb`; a glTF JSON file that
    uses the extension packed into a GLB first, its buffers found by ``resolver``): ``(content, file type, instances)``,
    the same content and type where it has none."""
    if file_type == "gltf":
        try:
            document = json.loads(bytes(content).decode("utf-8-sig"))
        except (ValueError, UnicodeDecodeError):
            return content, file_type, 0  # trimesh says what is wrong
        if not isinstance(document, dict) or not declares_instancing(document):
            return content, file_type, 0
        from meshsom.gltf_compression import pack_gltf

        content, file_type = pack_gltf(bytes(content), resolver, where), "glb"
    expanded, instances = instanced_glb(bytes(content), where)
    return expanded, file_type, instances


def _accessor(gltf: dict, binary: bytes, index, where: str, what: str, kind: str) -> np.ndarray:
    """An accessor's values ``(count, width) float64`` (width 1 to 4 for ``kind`` SCALAR to VEC4; normalized integers as
    the fractions they stand for), from the GLB's binary chunk."""
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[kind]
    accessors, views = gltf.get("accessors") or [], gltf.get("bufferViews") or []
    accessor = accessors[index] if isinstance(index, int) and 0 <= index < len(accessors) else None
    if not isinstance(accessor, dict) or accessor.get("type") != kind or accessor.get("componentType") not in _COMPONENTS \
            or "sparse" in accessor or not isinstance(accessor.get("count"), int) or accessor["count"] < 0:
        raise InputFileError(where, f"holds {what} that is no dense {kind} accessor ({index!r})")
    dtype, top = _COMPONENTS[accessor["componentType"]]
    count, size = accessor["count"], np.dtype(dtype).itemsize
    view = views[accessor.get("bufferView")] if isinstance(accessor.get("bufferView"), int) and \
        0 <= accessor["bufferView"] < len(views) else None
    if not isinstance(view, dict) or view.get("buffer", 0) != 0 or ((gltf.get("buffers") or [{}])[0] or {}).get("uri"):
        raise InputFileError(where, f"holds {what} outside the GLB's binary chunk")
    stride = view.get("byteStride") or width * size
    start = int(view.get("byteOffset", 0)) + int(accessor.get("byteOffset", 0))
    end = start + ((count - 1) * stride + width * size if count else 0)
    if start < 0 or end > len(binary):
        raise InputFileError(where, f"holds {what} at bytes {start}..{end}, beyond its {len(binary)}-byte binary chunk")
    values = np.ndarray((count, width), dtype, binary, start, (stride, size)).astype(np.float64) if count else \
        np.zeros((0, width))
    if accessor.get("normalized") and top:
        values = np.maximum(values / top, -1.0)
    return values


def _instance_matrices(count: int, translation, rotation, scale) -> np.ndarray:
    """``(count, 4, 4)`` float64 matrices T R S of instances' translations ``(count, 3)``, unit quaternions
    ``(count, 4)`` (x, y, z, w) and scales ``(count, 3)`` (None: none)."""
    m = np.tile(np.eye(4), (count, 1, 1))
    if rotation is not None:
        q = rotation / np.maximum(np.linalg.norm(rotation, axis=1, keepdims=True), 1e-300)
        x, y, z, w = q.T
        m[:, :3, :3] = np.stack([
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1)], axis=1)
    if scale is not None:
        m[:, :3, :3] = m[:, :3, :3] * scale[:, None, :]
    if translation is not None:
        m[:, :3, 3] = translation
    return m


def batched_meshes(glb: bytes, where: str, said: list | None = None, by_node: bool = False,
                   node_names: dict | None = None, y_up: bool = True) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The triangles of a glTF content split by batch (feature) id, in 3D Tiles' z-up frame.

    Parameters
    ----------
    glb : bytes
    where : str

    Returns
    -------
    list of (batch, vertices (V, 3) float64, faces (F, 3) int64)
        Sorted by batch; positions after each node's transform and the y-up to z-up turn, before
        any RTC centre or tile transform. A glTF without batch ids is batch 0; triangles whose
        batch id is not a whole number from 0 are batch -1. Ids all within :data:`QUANTIZED_ID_TOL`
        of whole numbers (a compression's quantization) are rounded, and ``said`` (a list) gets a
        note that says so. With ``by_node``, the triangles of nodes without batch ids are each
        node's own batch (0, 1, ... in node order; a mesh's primitives together) and ``node_names``
        (a dict) gets each such batch's node name. ``y_up`` false: the glTF is z up already (a tileset's
        ``asset.gltfUpAxis`` "Z"), not turned.
    """
    import trimesh

    glb = decompress_glb(glb, where)  # Draco, meshopt: plain accessors (meshsom.gltf_compression)
    glb, instances = instanced_glb(glb, where)  # EXT_mesh_gpu_instancing: a node per instance
    if instances and said is not None:
        said.append(f"{instances} instances of {GPU_INSTANCING} each read as a glTF node")
    try:
        scene = trimesh.load(io.BytesIO(glb), file_type="glb", process=False, force="scene", skip_materials=True)
    except Exception as err:  # trimesh raises many types for corrupt files
        raise InputFileError(where, f"holds a glTF that cannot be read ({type(err).__name__}: {err})") from None
    parts: dict[int, list] = {}
    nodes = list(scene.graph.nodes_geometry)
    batch_of: dict[str, int] = {}  # node name -> its batch, for content without batch ids
    for node in nodes:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        v = trimesh.transformations.transform_points(np.asarray(geom.vertices, np.float64),
                                                     (Y_UP_TO_Z_UP if y_up else np.eye(4)) @ transform)
        faces = np.asarray(geom.faces, np.int64)
        if faces.min() < 0 or faces.max() >= len(v):
            raise InputFileError(where, f"holds glTF triangles whose indices go beyond its {len(v)} vertices")
        attrs = getattr(geom, "vertex_attributes", {}) or {}
        ids = next((np.asarray(attrs[a]) for a in _FEATURE_ATTRIBUTES if a in attrs), None)
        instance = _instance_feature(scene, node)
        if instance is not None:  # EXT_instance_features: the instance's id is its triangles'
            ids = np.full(len(v), float(instance))
        if ids is not None:
            if len(ids) != len(v) or ids.size % max(len(v), 1):
                raise InputFileError(where, f"holds a batch-id attribute of {len(ids)} values for {len(v)} vertices")
            ids = ids.reshape(len(v), -1)[:, 0]
        if ids is None:
            face_batch = np.zeros(len(faces), np.int64)
            if by_node:  # no batch ids in the content: its nodes, each a building (named by the node)
                node_name = scene.graph.transforms.parents.get(node, node) if geom.metadata.get("from_gltf_primitive") else node
                batch = batch_of.setdefault(str(node_name), len(batch_of))
                face_batch = np.full(len(faces), batch, np.int64)
        else:  # a batch id that is not a whole number in range is -1: listed as not read
            value = np.asarray(ids[faces[:, 0]], np.float64)
            off = np.abs(value - np.rint(value))
            if len(value) and np.isfinite(value).all() and 0 < off.max() <= QUANTIZED_ID_TOL:
                value = np.rint(value)
                if said is not None:
                    said.append(f"batch ids rounded to whole numbers (up to {off.max():.3g} off: quantized by the "
                                f"content's compression)")
            ok = np.isfinite(value) & (value >= 0) & (value < 2**31) & (value == np.rint(value))
            face_batch = np.where(ok, np.rint(np.where(ok, value, 0)), -1).astype(np.int64)
        quantum = quantum_in_frame(attrs, (Y_UP_TO_Z_UP if y_up else np.eye(4)) @ transform)  # in the tile's frame
        for batch in np.unique(face_batch):
            f = faces[face_batch == batch]
            used_v, inverse = np.unique(f, return_inverse=True)
            parts.setdefault(int(batch), []).append((v[used_v], inverse.reshape(-1, 3), quantum))
    out, welds = [], [0, 0]
    for batch in sorted(parts):
        v, f, merged = joined_welded(parts[batch])
        welds[0] += merged > 0
        welds[1] += merged
        out.append((batch, v, f))
    if welds[0] and said is not None:
        said.append(DRACO_WELD_NOTE.format(joined=f"{welds[1]} vertices of {welds[0]} batches"))
    if node_names is not None:
        node_names.update({batch: node for node, batch in batch_of.items()})
    return out


#: The note on a building (or a tile's batches) whose Draco primitives were welded; ``joined`` says how many vertices.
DRACO_WELD_NOTE = "its Draco primitives (quantized each on its own grid) welded within half a quantum of each: {joined} joined"


def joined_welded(pieces: list) -> tuple[np.ndarray, np.ndarray, int]:
    """Pieces of one building, ``[(vertices (V_i, 3), faces (F_i, 3) into them, quantum or None), ...]`` (a glTF
    primitive each), as one mesh ``(vertices (V, 3) float64, faces (F, 3) int64)``; where any piece is a Draco
    primitive (a quantum), the vertices of different pieces are welded (:func:`weld_quantized`). Also returns the
    number of vertices so joined."""
    offsets = np.cumsum([0] + [len(p[0]) for p in pieces])[:-1]
    v = np.concatenate([np.asarray(p[0], np.float64) for p in pieces])
    f = np.concatenate([np.asarray(p[1], np.int64) + o for p, o in zip(pieces, offsets)])
    if len(pieces) < 2 or all(p[2] is None for p in pieces):
        return v, f, 0
    return weld_quantized(v, f, np.repeat(np.arange(len(pieces)), [len(p[0]) for p in pieces]),
                          np.array([p[2] or 0.0 for p in pieces]))


#: How far (in quanta) two vertices of one building's Draco primitives may lie apart and still be one point: Draco
#: moves each by up to half its primitive's quantum (per axis), so one point of two primitives of quanta ``q1``, ``q2``
#: is read at most ``(q1 + q2) / 2`` apart; this factor on that bound leaves room for float32 rounding.
WELD_QUANTA = 1.0 + 1e-3


def weld_quantized(vertices: np.ndarray, faces: np.ndarray, piece: np.ndarray, quanta: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """The vertices of a building's pieces that Draco quantized each on its own grid welded back: a vertex of one
    piece and one of another whose coordinates all differ by at most ``WELD_QUANTA * (q_i + q_j) / 2`` (half a
    quantum of each; pieces of quantum 0 are not quantized) are one point, placed at their mean; vertices of one
    piece are joined only where they coincide. Triangles that lose a corner so are dropped.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    piece : (V,) int64
        The piece each vertex belongs to.
    quanta : (P,) float64
        Each piece's quantum (metres; 0 where none).

    Returns
    -------
    vertices : (W, 3) float64
    faces : (G, 3) int64
    merged : int
        Vertices joined to another (V - W).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    reach = WELD_QUANTA * float(quanta.max(initial=0.0))
    pairs = cKDTree(vertices).query_pairs(reach, p=np.inf, output_type="ndarray") if reach > 0 else np.zeros((0, 2), int)
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        apart = np.abs(vertices[a] - vertices[b]).max(axis=1)
        bound = WELD_QUANTA * (quanta[piece[a]] + quanta[piece[b]]) / 2
        keep = (apart == 0) | ((piece[a] != piece[b]) & (quanta[piece[a]] > 0) & (quanta[piece[b]] > 0) & (apart <= bound))
        pairs = pairs[keep]
    n = len(vertices)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    sums = np.zeros((count, 3))
    np.add.at(sums, label, vertices)
    welded = sums / np.bincount(label, minlength=count)[:, None]
    f = label[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    return welded, f.astype(np.int64), n - count


def _instance_feature(scene, node: str) -> int | None:
    """The feature id :func:`instanced_glb` gave the instance a scene node draws (``EXT_instance_features``; -1 for an
    id that is not a whole number from 0), None for a node of no such instance."""
    edges = scene.graph.transforms.edge_data
    at = node
    for _ in range(2):  # the instance's node, or the primitive's node under it
        parent = scene.graph.transforms.parents.get(at)
        metadata = (edges.get((parent, at)) or {}).get("metadata") if parent is not None else None
        if isinstance(metadata, dict) and INSTANCE_FEATURE in metadata:
            return int(metadata[INSTANCE_FEATURE])
        if parent is None:
            return None
        at = parent
    return None


def property_table(gltf: dict, binary: bytes, names, where: str, table: int | None = None,
                   schema: dict | None = None) -> tuple[dict, int | None]:
    """The columns ``names`` (those it has, of strings or numbers) of an ``EXT_structural_metadata`` property table
    (3D Tiles 1.1's batch table), as lists of its row count, and that count; ``({}, None)`` without one. The table is
    ``table``, by default the one of the first feature-id set read from ``_FEATURE_ID_0`` (``EXT_mesh_features``); its
    class is looked up in ``schema``, by default the content's own. Columns of other types (arrays, vectors, enums),
    and any the binary chunk does not hold, are left out."""
    try:
        return _property_table(gltf, binary, names, table, schema)
    except (AttributeError, TypeError, ValueError, KeyError):  # metadata laid out otherwise than the specification
        return {}, None  # says: no ids, no labels (the geometry is read as it is)


def _property_table(gltf: dict, binary: bytes, names, chosen: int | None, schema: dict | None
                    ) -> tuple[dict, int | None]:
    """The work of :func:`property_table`, which answers for what it raises."""
    metadata = (gltf.get("extensions") or {}).get("EXT_structural_metadata")
    tables = metadata.get("propertyTables") if isinstance(metadata, dict) else None
    if not isinstance(tables, list):
        return {}, None
    for mesh in (gltf.get("meshes") or []) if chosen is None else []:
        for primitive in (mesh.get("primitives") or []) if isinstance(mesh, dict) else []:
            sets = (((primitive.get("extensions") or {}).get("EXT_mesh_features") or {}).get("featureIds") or []) \
                if isinstance(primitive, dict) else []
            chosen = next((f.get("propertyTable") for f in sets if isinstance(f, dict) and f.get("attribute") == 0
                           and isinstance(f.get("propertyTable"), int)), chosen)
    table = tables[chosen] if isinstance(chosen, int) and 0 <= chosen < len(tables) else None
    if not isinstance(table, dict) or not isinstance(table.get("count"), int) or table["count"] < 1:
        return {}, None
    count = table["count"]
    schema = schema if isinstance(schema, dict) else metadata.get("schema")
    classes = (schema.get("classes") or {}) if isinstance(schema, dict) else {}
    declared = ((classes.get(table.get("class")) or {}).get("properties") or {}) if isinstance(classes, dict) else {}
    columns = {}
    for name in dict.fromkeys(n for n in names if n):
        column, kind = (table.get("properties") or {}).get(name), declared.get(name)
        if not isinstance(column, dict) or not isinstance(kind, dict) or kind.get("array") or "arrayOffsets" in column:
            continue
        try:
            if kind.get("type") == "STRING":
                ends = _view_array(gltf, binary, column.get("stringOffsets"),
                                   _OFFSET_TYPES.get(column.get("stringOffsetType", "UINT32")), count + 1)
                data = _view_bytes(gltf, binary, column.get("values"))
                if ends is not None and data is not None and np.all(np.diff(ends) >= 0) and ends[-1] <= len(data):
                    columns[name] = [data[int(a):int(b)].decode("utf-8", "replace") for a, b in zip(ends[:-1], ends[1:])]
            elif kind.get("type") == "SCALAR":
                values = _view_array(gltf, binary, column.get("values"), _SCALAR_TYPES.get(kind.get("componentType")), count)
                if values is not None:
                    columns[name] = [v.item() for v in values]
        except (TypeError, ValueError):
            continue  # a column laid out otherwise than the specification says: not an id, not a label
    return columns, count


#: EXT_structural_metadata's offset and scalar component types, as NumPy dtypes.
_OFFSET_TYPES = {"UINT8": "<u1", "UINT16": "<u2", "UINT32": "<u4", "UINT64": "<u8"}
_SCALAR_TYPES = {**_OFFSET_TYPES, "INT8": "<i1", "INT16": "<i2", "INT32": "<i4", "INT64": "<i8", "FLOAT32": "<f4",
                 "FLOAT64": "<f8"}


def _view_bytes(gltf: dict, binary: bytes, index) -> bytes | None:
    """A buffer view's bytes in the GLB's binary chunk; None where it lies elsewhere or beyond it."""
    views = gltf.get("bufferViews") or []
    view = views[index] if isinstance(index, int) and 0 <= index < len(views) else None
    if not isinstance(view, dict) or view.get("buffer", 0) != 0:
        return None
    start, length = view.get("byteOffset", 0), view.get("byteLength")
    if not (isinstance(start, int) and isinstance(length, int) and 0 <= start and start + length <= len(binary)):
        return None
    return bytes(binary[start:start + length])


def _view_array(gltf: dict, binary: bytes, index, dtype: str | None, count: int) -> np.ndarray | None:
    data = _view_bytes(gltf, binary, index)
    if dtype is None or data is None or len(data) < count * np.dtype(dtype).itemsize:
        return None
    return np.frombuffer(data, dtype, count)


def hierarchy_groups(batch_table: dict, batch_binary: bytes, length: int, where: str) -> dict[int, str] | None:
    """The building each batch belongs to by the batch table's ``3DTILES_batch_table_hierarchy`` (or the draft's
    ``HIERARCHY``: what converters of CityGML write where each batch is a wall, a roof or a door of a building that
    has no geometry of its own), as ``{batch: name}`` for the batches that belong to one; None without a hierarchy
    (or one without parents). A batch's building is its first ancestor (first parents, up) that is no batch of
    geometry itself and whose class is named a building, not a part; else its nearest such ancestor. Names are
    ``<class> <instance's index in its class>``, or the instance's ``name``/``id`` where its class gives one."""
    hierarchy = (batch_table.get("extensions") or {}).get("3DTILES_batch_table_hierarchy") \
        if isinstance(batch_table.get("extensions"), dict) else None
    hierarchy = hierarchy if isinstance(hierarchy, dict) else batch_table.get("HIERARCHY")
    if not isinstance(hierarchy, dict):
        return None
    n, classes = hierarchy.get("instancesLength"), hierarchy.get("classes")
    if not isinstance(n, int) or n < length or not isinstance(classes, list) or "parentIds" not in hierarchy:
        return None
    class_ids = _hierarchy_column(hierarchy.get("classIds"), n, batch_binary, where, "classIds")
    counts = _hierarchy_column(hierarchy.get("parentCounts"), n, batch_binary, where, "parentCounts") \
        if "parentCounts" in hierarchy else np.ones(n, np.int64)
    parents = _hierarchy_column(hierarchy.get("parentIds"), int(counts.sum()), batch_binary, where, "parentIds")
    if class_ids.min(initial=0) < 0 or class_ids.max(initial=0) >= len(classes):
        raise InputFileError(where, f"has a batch table hierarchy whose class ids go beyond its {len(classes)} classes")
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    parent = np.where(counts > 0, parents[np.minimum(first, max(len(parents) - 1, 0))] if len(parents) else 0,
                      np.arange(n))
    index_in_class = np.zeros(n, np.int64)
    for c in np.unique(class_ids):
        index_in_class[class_ids == c] = np.arange(int((class_ids == c).sum()))

    def name(instance: int) -> str:
        cls = classes[int(class_ids[instance])] if isinstance(classes[int(class_ids[instance])], dict) else {}
        instances = cls.get("instances") if isinstance(cls.get("instances"), dict) else {}
        for key, values in instances.items():
            if key.lower() in ("id", "gml_id", "name") or key.lower().endswith("_name"):
                if isinstance(values, list) and index_in_class[instance] < len(values):
                    return str(values[index_in_class[instance]])
        return f"{cls.get('name', 'class %d' % class_ids[instance])} {index_in_class[instance]}"

    def is_building(instance: int) -> bool:
        cls = classes[int(class_ids[instance])]
        word = str(cls.get("name", "") if isinstance(cls, dict) else "").lower()
        return ("building" in word or "bldg" in word) and "part" not in word

    groups = {}
    for batch in range(length):
        chain, at = [], batch
        for _ in range(n):  # a cycle stops where it comes round
            up = int(parent[at])
            if up == at or not 0 <= up < n or up in chain:
                break
            chain.append(up)
            at = up
        above = [a for a in chain if a >= length]  # instances without geometry: the objects batches make up
        chosen = next((a for a in above if is_building(a)), above[0] if above else None)
        if chosen is not None:
            groups[batch] = name(chosen)
    return groups or None


def _hierarchy_column(values, count: int, binary: bytes, where: str, what: str) -> np.ndarray:
    """A hierarchy column (a JSON list, or a reference into the batch table's binary body: ``byteOffset`` and
    ``componentType``, UNSIGNED_SHORT by default) as ``(count,)`` int64."""
    if isinstance(values, dict):
        dtype = {"UNSIGNED_BYTE": "<u1", "UNSIGNED_SHORT": "<u2", "UNSIGNED_INT": "<u4"}.get(
            values.get("componentType", "UNSIGNED_SHORT"))
        offset = values.get("byteOffset")
        if dtype is None or not isinstance(offset, int) or offset < 0 or \
                offset + count * np.dtype(dtype).itemsize > len(binary):
            raise InputFileError(where, f"has a batch table hierarchy whose {what} lie beyond its binary body")
        return np.frombuffer(binary, dtype, count, offset).astype(np.int64)
    if not isinstance(values, list) or len(values) != count or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in values):
        raise InputFileError(where, f"has a batch table hierarchy whose {what} are not {count} whole numbers")
    return np.asarray(values, np.int64)


def _batch_binary(data: bytes) -> bytes:
    """A b3dm's batch table binary body (its header read by :func:`parse_b3dm` already)."""
    _, _, _, ft_json, ft_bin, bt_json, bt_bin = struct.unpack_from("<4sIIIIII", data)
    start = 28 + ft_json + ft_bin + bt_json
    return bytes(data[start:start + bt_bin])


#: Batch-table keys that are no per-batch column (the hierarchy, extensions, extras).
_NOT_COLUMNS = ("HIERARCHY", "extensions", "extras")


def batch_table_length(batch_table: dict, batches: list[int]) -> tuple[int | None, str]:
    """The number of batches of a b3dm whose feature table gives no ``BATCH_LENGTH`` (py3dtiles, py3dtilers): the
    length its batch table's JSON columns share, where every batch id the glTF holds (``batches``, -1 for ids that are
    not whole numbers) lies below it; else None. Returns it with a note saying so, or why the table is not read.
    Binary columns (``byteOffset``) count nothing: their length is the one sought."""
    lengths = {len(v) for k, v in batch_table.items() if k not in _NOT_COLUMNS and isinstance(v, list)}
    top = max((b for b in batches if b >= 0), default=-1)
    if len(lengths) != 1:
        return None, (f"no BATCH_LENGTH in its feature table, and its batch table's columns count "
                      f"{sorted(lengths) or 'no'} rows: batches read by number, not by the table")
    count = lengths.pop()
    if top >= count:
        return None, (f"no BATCH_LENGTH in its feature table, and its batch ids go to {top}, beyond its batch table's "
                      f"{count} rows: batches read by number, not by the table")
    return count, f"no BATCH_LENGTH in its feature table: {count} batches by its batch table's columns"


def _batch_ids(batch_table: dict, length: int | None, options) -> list[str] | None:
    """The batches' ids: the first property of ``options.id_attributes`` that names the
    ``length`` batches uniquely; None (batch numbers) otherwise."""
    if not length:
        return None
    for name in options.id_attributes:
        values = batch_table.get(name)
        if isinstance(values, list) and len(values) >= length:
            names = [str(v) for v in values[:length]]
            if all(v not in (None, "") for v in values[:length]) and len(set(names)) == length:
                return names
    return None


def composite_inner_tiles(data: bytes, where: str, depth: int = 0) -> list[tuple[str, bytes]]:
    """The inner tiles of a composite tile (``cmpt``, 3D Tiles 1.0), composites inside it unpacked:
    ``(magic, bytes)`` in order (b3dm, i3dm, pnts...).

    Raises
    ------
    InputFileError
        Not a composite, another version, nested more than :data:`MAX_TILESET_DEPTH`, or lengths
        that do not fit the file.
    """
    if len(data) < 16 or data[:4] != b"cmpt":
        raise InputFileError(where, f"is not a composite tile (magic {bytes(data[:4])!r}; expected b'cmpt')")
    _, version, length, count = struct.unpack_from("<4sIII", data)
    if version != 1:
        raise InputFileError(where, f"is cmpt version {version}; expected 1")
    if depth > MAX_TILESET_DEPTH:
        raise InputFileError(where, f"nests composite tiles deeper than {MAX_TILESET_DEPTH}")
    if length > len(data):
        raise InputFileError(where, f"is cut short: its header says {length} bytes; the file has {len(data)}")
    out, pos = [], 16
    for k in range(count):
        if pos + 12 > length:
            raise InputFileError(where, f"is cut short: inner tile {k + 1} of {count} starts at byte {pos} of {length}")
        magic = bytes(data[pos:pos + 4])
        size = struct.unpack_from("<I", data, pos + 8)[0]
        if size < 12 or pos + size > length:
            raise InputFileError(where, f"has inner tile {k + 1} of {count} ({magic!r}) of {size} bytes at byte {pos}, "
                                        f"beyond its {length}")
        inner = bytes(data[pos:pos + size])
        if magic == b"cmpt":
            out += composite_inner_tiles(inner, where, depth + 1)
        else:
            out.append((magic.decode("ascii", "replace"), inner))
        pos += size
    return out


def composite_meshes(data: bytes, source: str, prefix: str, options, transform: np.ndarray | None = None,
                     y_up: bool = True, schema: dict | None = None, resolve=None) -> Iterator:
    """RawMesh / Rejection items of a composite tile's batched models (b3dm, glb: :func:`content_meshes`,
    ids ``prefix`` + ``N#`` + batch, N its inner tile from 0); each instanced model or point cloud a
    Rejection that says so."""
    from meshsom.io import Rejection

    for k, (magic, inner) in enumerate(composite_inner_tiles(data, source)):
        if magic in ("b3dm", "glTF"):
            try:  # one inner tile that cannot be read is its rejection; the others are read (or listed) still
                yield from content_meshes(inner, source, f"{prefix}{k}#", options, transform, b3dm=magic == "b3dm",
                                          y_up=y_up, schema=schema, resolve=resolve)
            except InputFileError as err:
                yield Rejection(f"{prefix}{k}", source, f"is inner tile {k} of a composite, a {magic} that {err.problem}")
        else:
            yield Rejection(f"{prefix}{k}", source, f"is inner tile {k} of a composite, of type {magic} (points or "
                                                    f"instances); only batched models (b3dm, glb) are read")


def content_meshes(data: bytes, source: str, prefix: str, options, transform: np.ndarray | None = None,
                   b3dm: bool = True, y_up: bool = True, schema: dict | None = None, resolve=None) -> Iterator:
    """RawMesh / Rejection items of one b3dm (or, ``b3dm`` false, glb) content (``prefix`` starts
    the ids; ``transform`` the tile's, column vectors, 4 x 4). 3D Tiles 1.1 feature ids: the set that is the
    buildings (:func:`meshsom.feature_ids.building_ids`), its property table's class looked up in the content's
    ``EXT_structural_metadata`` schema, the file its ``schemaUri`` names (``resolve(uri)`` gives its bytes; by default
    a file beside ``source``), or else ``schema`` (the tileset's)."""
    from meshsom.feature_ids import building_ids, resolve_schema
    from meshsom.io import RawMesh, Rejection, extent_problem, recentre

    if b3dm:
        feature_table, batch_table, glb, feature_binary = parse_b3dm(data, source)
        rtc = _rtc_centre(feature_table, feature_binary, source)
    else:
        feature_table, batch_table, glb, rtc = {}, {}, bytes(data), np.zeros(3)
    glb = decompress_glb(glb, source)  # Draco, meshopt: plain accessors (meshsom.gltf_compression)
    gltf = split_glb(glb, source)[0]
    content_schema, schema_note = resolve_schema(gltf, resolve or _beside(source, options), schema, source)
    glb, choice = building_ids(glb, source, content_schema)
    null_id = choice.null_id
    if "EXT_structural_metadata" in (gltf.get("extensions") or {}):
        table, rows = property_table(*split_glb(glb, source), (*options.id_attributes, options.label_attribute,
                                                                choice.parent_column), source, choice.table,
                                     content_schema)
    else:
        table, rows = {}, None
    cesium_rtc = (gltf.get("extensions") or {}).get("CESIUM_RTC", {}).get("center")
    if cesium_rtc is not None:
        rtc = rtc + np.asarray(cesium_rtc, np.float64).reshape(3)
    said: list[str] = [*choice.notes, *([schema_note] if schema_note else [])]
    declared = feature_table.get("BATCH_LENGTH")
    length = declared if isinstance(declared, int) and not isinstance(declared, bool) and declared > 0 else None  # 0: one model
    node_names: dict[int, str] = {}
    batches = batched_meshes(glb, source, said, by_node=length is None, node_names=node_names, y_up=y_up)
    if len(node_names) > 1:  # no batch ids: each node a building (assimp's b3dm of a city, a node per building)
        said.append(f"its content has no batch ids: each of its {len(node_names)} glTF nodes read as a building")
    elif node_names and not getattr(options, "split_components", False):
        said.append("its content has no batch ids: read as one model (--split-components, or "
                    "corpus.reader.split_components, reads each connected piece as a building)")
    said = list(dict.fromkeys(said))
    if rows and not batch_table:  # 3D Tiles 1.1: the property table that the feature ids name
        batch_table = table
    counted = length
    if b3dm and length is None and batch_table:  # no BATCH_LENGTH (py3dtiles): the batch table's columns count them
        counted, note = batch_table_length(batch_table, [batch for batch, _, _ in batches])
        said.append(note)
    ids = _batch_ids(batch_table, counted or rows, options)
    labels = batch_table.get(options.label_attribute)
    groups = hierarchy_groups(batch_table, _batch_binary(data), counted, source) if b3dm and counted else None
    parents = table.get(choice.parent_column) if choice.parent_column else None
    if isinstance(parents, list):  # EXT_mesh_features sets of parts only: the parts of one building together
        groups = {batch: str(parents[batch]) for batch, _, _ in batches if 0 <= batch < len(parents)
                  and batch != null_id and parents[batch] not in (None, "")}
    elif choice.parent_column:
        said.append(f"its parts' column {choice.parent_column!r} cannot be read: each part read as a building")
    entries = _grouped(batches, groups or {}, ids)
    if groups and isinstance(parents, list):
        said.append(f"its {len(groups)} parts make {len(set(groups.values()))} buildings by their property table's "
                    f"{choice.parent_column!r} (EXT_structural_metadata): each read as a building of its parts")
    elif groups:
        said.append(f"its {len(groups)} batches are parts of {len(set(groups.values()))} objects by the batch table's "
                    f"hierarchy (3DTILES_batch_table_hierarchy): each object read as a building of its parts")
    tilt = None
    if transform is None:  # a lone content: in earth-centred axes about a centre its tileset holds (pg2b3dm)?
        tilt = earth_axes_up(batches, rtc)
        if tilt is not None:
            said.append(f"not earth-centred, but z is not up: its axes read as earth-centred ones (pg2b3dm writes "
                        f"offsets from its tileset's root translation) and turned east-north-up about the up its walls "
                        f"and floors show, {tilt[1]:.1f} deg from its z (read the tileset to place it)")
    for batch, key, v, f, parts, face_part in entries:
        if choice.set_index is not None and batch == NO_SET_ID:
            yield Rejection(f"{prefix}(no feature-id set)", source, f"{len(f)} triangles of primitives without "
                                                                    f"EXT_mesh_features set {choice.set_index}, the set "
                                                                    "read as the buildings: not read")
            continue
        if null_id is not None and batch == null_id:  # EXT_mesh_features: the triangles of no feature
            yield Rejection(f"{prefix}(feature id {batch})", source, f"{len(f)} triangles carry the null feature id "
                                                                     f"{batch} (EXT_mesh_features nullFeatureId): "
                                                                     "no feature's, not read")
            continue
        if batch < 0 or (length is not None and batch >= length):
            what = "not whole numbers from 0" if batch < 0 else f"{batch}, beyond BATCH_LENGTH {length}"
            yield Rejection(f"{prefix}(batch {batch})", source, f"{len(f)} triangles carry batch ids {what}; not read")
            continue
        mesh_id = f"{prefix}{key if key is not None else ids[batch] if ids and batch < len(ids) else node_names.get(batch, batch) if len(node_names) > 1 else batch}"
        label = labels[batch] if isinstance(labels, list) and 0 <= batch < len(labels) else None
        label = None if label is None else str(label)
        world = v + rtc
        if transform is not None:
            world = world @ transform[:3, :3].T + transform[:3, 3]
        if not (np.isfinite(world).all() and np.abs(world).max(initial=0) < MAX_COORDINATE):
            yield Rejection(mesh_id, source, f"has coordinates that are not finite numbers of magnitude below {MAX_COORDINATE:g}",
                            0, label)
            continue
        if tilt is not None:
            world = _turned_up(world, tilt[0])
        local, origin = recentre(world)
        if tilt is not None:
            note = "read in east-north-up metres of the up its walls and floors show"
        elif abs(np.linalg.norm(origin) - EARTH_RADIUS) < ECEF_BAND:
            from meshsom.crs import east_north_up_of_geocentric

            local = east_north_up_of_geocentric(world, origin)
            note = "converted to metres from earth-centred coordinates (3D Tiles, WGS 84), east-north-up about the building's centre"
        else:
            note = ("not earth-centred: read as metres in the tile's own frame (a tile read without the tileset transform "
                    "that places it, or a tileset without one)")
        if len(f) == 0:
            yield Rejection(mesh_id, source, "holds no faces", 0, label)
            continue
        if getattr(options, "split_components", False):  # a feature of several buildings (one model, no batches)
            from meshsom.io import _connected_pieces

            for piece_id, pv, pf, _ in _connected_pieces(mesh_id, local, f, label):  # about the feature's origin
                problem = extent_problem(pv, False, options)
                yield (Rejection(piece_id, source, problem, len(pf), label) if problem else
                       RawMesh(piece_id, source, pv, pf, origin, label, None, notes=(note, *said)))
            continue
        problem = extent_problem(local, False, options)  # 3D Tiles are metres; --unit does not apply to them
        if problem:
            yield Rejection(mesh_id, source, problem, len(f), label)
            continue
        yield RawMesh(mesh_id, source, local, f, origin, label, None, parts, face_part, notes=(note, *said))


#: A lone content's frame is taken as tilted where faces within :data:`SQUARE_DEG` of vertical or horizontal to its z
#: hold less than :data:`TILTED_SHARE` of its area and those to another direction at least :data:`UPRIGHT_SHARE` (LoD1
#: and LoD2 buildings: walls and floors hold most of it; pg2b3dm's Delaware tile: 2 % to its z, 64 % to the up found),
#: that direction at least :data:`MIN_TILT_DEG` from z. Candidates: the normals and the common perpendiculars of pairs
#: of the :data:`UP_FACES` largest faces (:data:`UP_PAIRS` pairs, drawn with :data:`UP_SEED`).
SQUARE_DEG = 2.0
TILTED_SHARE = 0.25
UPRIGHT_SHARE = 0.5
MIN_TILT_DEG = 5.0
UP_FACES = 2000
UP_PAIRS = 2000
UP_SEED = 0


def _upright_share(up: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """``(K,)`` share of the area whose unit ``normals (F, 3)`` lie within :data:`SQUARE_DEG` of perpendicular or
    parallel to each candidate ``up (K, 3)``."""
    cos = np.abs(up @ normals.T)
    square = (cos < np.sin(np.radians(SQUARE_DEG))) | (cos > np.cos(np.radians(SQUARE_DEG)))
    return square.astype(np.float64) @ areas / max(float(areas.sum()), 1e-300)


def earth_axes_up(batches: list, rtc: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The up of a lone tile content whose z is not up: pg2b3dm writes positions as offsets, in earth-centred axes,
    from the translation of its tileset's root transform, so a tile read alone (no ``RTC_CENTER``, no transform) is
    neither earth-centred nor z up (Delaware, 39 deg N: z 51 deg from up). The up is the direction to which most of the
    buildings' area is square (walls perpendicular, floors and flat roofs parallel: :func:`_upright_share`), its sign
    the one under which the buildings' lowest points spread less than their highest (they stand on one ground; for
    fewer than three buildings, the one pointing to positive z, as in the northern hemisphere).

    Parameters
    ----------
    batches : list of (batch, vertices (V, 3) float64, faces (F, 3) int64)
    rtc : (3,) float64

    Returns
    -------
    (up (3,) float64, degrees from z) or None
        None where the content is earth-centred, z is up (:data:`TILTED_SHARE`), or no direction is clearly up.
    """
    if not batches:
        return None
    allv = np.concatenate([v for _, v, _ in batches])
    if len(allv) == 0 or abs(np.linalg.norm(allv.mean(axis=0) + rtc) - EARTH_RADIUS) < ECEF_BAND:
        return None
    cross = np.concatenate([np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]) for _, v, f in batches])
    areas = np.linalg.norm(cross, axis=1)
    keep = areas > 0
    normals, areas = cross[keep] / areas[keep, None], areas[keep] / 2
    if len(areas) == 0 or _upright_share(np.array([[0.0, 0.0, 1.0]]), normals, areas)[0] >= TILTED_SHARE:
        return None
    largest = np.argsort(-areas)[:UP_FACES]
    rng = np.random.default_rng(UP_SEED)
    pairs = np.cross(normals[rng.choice(largest, UP_PAIRS)], normals[rng.choice(largest, UP_PAIRS)])
    length = np.linalg.norm(pairs, axis=1)
    candidates = np.concatenate([normals[largest], pairs[length > 0.2] / length[length > 0.2, None]])
    share = _upright_share(candidates, normals[largest], areas[largest])
    up = candidates[int(np.argmax(share))]
    cos = normals @ up  # refined: the least square walls, the most square floors
    walls, flats = np.abs(cos) < np.sin(np.radians(SQUARE_DEG)), np.abs(cos) > np.cos(np.radians(SQUARE_DEG))
    scatter = (normals[walls].T * areas[walls]) @ normals[walls] - (normals[flats].T * areas[flats]) @ normals[flats]
    refined = np.linalg.eigh(scatter)[1][:, 0]
    up = refined * np.sign(refined @ up)
    if _upright_share(up[None], normals, areas)[0] < UPRIGHT_SHARE:
        return None
    if len(batches) >= 3:
        low = np.array([(v @ up).min() for _, v, _ in batches])
        high = np.array([(v @ up).max() for _, v, _ in batches])
        up = up if low.std() <= high.std() else -up
    else:
        up = up if up[2] >= 0 else -up
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    return (up, tilt) if tilt >= MIN_TILT_DEG else None


def _turned_up(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``points (V, 3)`` in earth-centred axes turned east-north-up about ``up (3,)``, the ellipsoid's normal at the
    place whose geodetic latitude and longitude it gives (:func:`meshsom.crs.east_north_up_of_geocentric`)."""
    from meshsom.crs import WGS84, east_north_up_of_geocentric, geocentric

    place = np.array([[np.degrees(np.arcsin(np.clip(up[2], -1.0, 1.0))), np.degrees(np.arctan2(up[1], up[0])), 0.0]])
    centre = geocentric(place, *WGS84)[0]
    return east_north_up_of_geocentric(points + centre, centre)


def _beside(source: str, options):
    """A function giving the bytes of a file a content names (its metadata ``schemaUri``), looked up in the content's
    own folder (:class:`meshsom.io.FolderResolver`: nothing outside it is opened)."""
    from meshsom.io import FolderResolver

    resolver = FolderResolver(Path(source).parent, source)
    return lambda uri: resolver.get(unquote(uri))


def _grouped(batches: list, groups: dict[int, str], ids: list[str] | None) -> list:
    """``batches`` (batch, vertices, faces) as ``(first batch, group name or None, vertices, faces, parts,
    face_part)``: the batches of one group (:func:`hierarchy_groups`) one entry of parts (the batches' ids), in the
    order of their first batches; the others as they are."""
    entries, members = [], {}
    for batch, v, f in batches:
        key = groups.get(batch)
        if key is None:
            entries.append((batch, None, v, f, (), None))
            continue
        if key not in members:
            members[key] = []
            entries.append((batch, key, None, None, (), None))
        members[key].append((batch, v, f))
    out = []
    for batch, key, v, f, parts, face_part in entries:
        if key is not None:
            pieces = members[key]
            offsets = np.cumsum([0] + [len(p[1]) for p in pieces])[:-1]
            v = np.concatenate([p[1] for p in pieces])
            f = np.concatenate([p[2] + o for p, o in zip(pieces, offsets)])
            parts = tuple(str(ids[p[0]] if ids else p[0]) for p in pieces)
            face_part = np.repeat(np.arange(len(pieces)), [len(p[2]) for p in pieces]).astype(np.int64)
            if len(pieces) == 1:
                parts, face_part = (), None
        out.append((batch, key, v, f, parts, face_part))
    return out


def read_b3dm(path: Path, options, name: str | None = None) -> Iterator:
    """Read the buildings (batches) of one b3dm file, or of the batched models of a composite
    (``.cmpt``) file (as the module says)."""
    from meshsom.io import read_input_bytes

    data = bytes(read_input_bytes(path, options))
    if path.name.lower().endswith(".cmpt") or data[:4] == b"cmpt":
        yield from composite_meshes(data, str(path), f"{name or path.name}#", options)
    else:
        yield from content_meshes(data, str(path), f"{name or path.name}#", options)


def _matrix(tile: dict, where: str) -> np.ndarray:
    value = tile.get("transform")
    if value is None:
        return np.eye(4)
    try:
        m = np.asarray(value, np.float64).reshape(4, 4).T  # column-major in the tileset
    except (TypeError, ValueError):
        raise InputFileError(where, f"has a tile transform that is not 16 numbers: {str(value)[:60]}") from None
    if not np.isfinite(m).all():
        raise InputFileError(where, "has a tile transform that is not finite")
    return m


def _uris(tile: dict) -> list[str]:
    contents = [tile["content"]] if isinstance(tile.get("content"), dict) else []
    contents += [c for c in tile.get("contents", []) if isinstance(c, dict)]
    return [c.get("uri", c.get("url")) for c in contents if isinstance(c.get("uri", c.get("url")), str)]


def _names_tileset(uri: str) -> bool:
    """Whether a content URI names an external tileset (a .json path, queries aside)."""
    return PurePosixPath(unquote(urlparse(uri).path)).suffix.lower() == ".json"


def read_tileset(document: dict, path: Path, options, name: str | None = None) -> Iterator:
    """Read the buildings of a parsed tileset (as the module says)."""
    from meshsom.io import Rejection, _parse_json, read_input_bytes

    name = name or path.name
    root_folder = path.parent.resolve()
    found = False
    # 3D Tiles 1.0's asset.gltfUpAxis: "Z" where the tiler wrote z-up glTF (fanvanzh/3dtiles, CesiumLab), Y by default
    y_up = str(document["asset"].get("gltfUpAxis", "Y")).strip().upper() != "Z"

    def within(folder: Path):
        """The bytes of a file a content in ``folder`` names (its metadata schemaUri), within the tileset's folder."""
        def read(uri: str) -> bytes:
            parsed = urlparse(uri)
            target = (folder / unquote(parsed.path)).resolve()
            if parsed.scheme or parsed.netloc or not target.is_relative_to(root_folder):
                raise InputFileError(str(path), f"names a file outside the tileset's folder ({uri}); not followed")
            return bytes(read_input_bytes(target, options))
        return read

    # 3D Tiles 1.1's metadata schema (its own, or the file schemaUri names): for content that names no schema
    schema = document.get("schema") if isinstance(document.get("schema"), dict) else None
    if schema is None and isinstance(document.get("schemaUri"), str):
        try:
            schema = _parse_json(within(path.parent)(document["schemaUri"]), str(path))
        except (InputFileError, OSError):
            schema = None  # the contents' own schemas stand; a content that names none says so

    def _content(uri: str, folder: Path, transform: np.ndarray, refine: str, depth: int) -> Iterator:
        """The items of one content: its buildings, or rejections; an external tileset joins the walk."""
        parsed = urlparse(uri)
        target = (folder / unquote(parsed.path)).resolve()
        content_id = f"{name}#{PurePosixPath(target.relative_to(root_folder)).as_posix()}" if target.is_relative_to(
            root_folder) else f"{name}#{uri}"
        if parsed.scheme or parsed.netloc or not target.is_relative_to(root_folder):
            yield Rejection(content_id, str(path), f"names content outside the tileset's folder ({uri}); not followed")
            return
        if _names_tileset(uri):  # an external tileset: its root joins the walk
            try:
                sub = _parse_json(bytes(read_input_bytes(target, options)), str(target))
            except (InputFileError, OSError) as err:
                yield Rejection(content_id, str(target), getattr(err, "problem", str(err)))
                return
            if is_tileset(sub):
                stack.append((sub["root"], transform, refine, target.parent, depth + 1))
            return
        suffix = target.suffix.lower()
        if suffix not in (".b3dm", ".glb", ".gltf", ".cmpt"):
            yield Rejection(content_id, str(target), f"is tile content of type {target.suffix or '(none)'} (points or "
                                                     f"instances); only batched models (.b3dm, .glb, .gltf, in a .cmpt "
                                                     f"too) are read")
            return
        try:
            data = bytes(read_input_bytes(target, options))
            if suffix == ".gltf":  # glTF JSON content (3D Tiles 1.1) and its buffers, as a GLB
                from meshsom.gltf_compression import pack_gltf
                from meshsom.io import FolderResolver

                data, suffix = pack_gltf(data, FolderResolver(target.parent, str(target)), str(target)), ".glb"
            where = {"schema": schema if isinstance(schema, dict) else None, "resolve": within(target.parent)}
            if suffix == ".cmpt":
                yield from composite_meshes(data, str(target), f"{content_id}#", options, transform, y_up=y_up, **where)
            else:
                yield from content_meshes(data, str(target), f"{content_id}#", options, transform, b3dm=suffix == ".b3dm",
                                          y_up=y_up, **where)
        except (InputFileError, OSError) as err:
            yield Rejection(content_id, str(target), getattr(err, "problem", None) or f"cannot be read ({err})")

    # (tile, transform of its parent, refinement inherited, the folder its URIs are relative to, depth)
    stack = [(document["root"], np.eye(4), "REPLACE", path.parent, 0)]
    while stack:
        tile, parent, refine, folder, depth = stack.pop()
        if not isinstance(tile, dict):
            continue
        if depth > MAX_TILESET_DEPTH:
            raise InputFileError(str(path), f"nests tiles or tilesets deeper than {MAX_TILESET_DEPTH}")
        transform = parent @ _matrix(tile, str(path))
        refine = str(tile.get("refine", refine)).upper()
        children = [c for c in tile.get("children", []) if isinstance(c, dict)]
        stack.extend((c, transform, refine, folder, depth + 1) for c in reversed(children))
        extension = (tile.get("extensions") or {}).get("3DTILES_implicit_tiling") if isinstance(tile.get("extensions"), dict) else None
        if not isinstance(tile.get("implicitTiling"), dict) and isinstance(extension, dict):
            tile = {**tile, "implicitTiling": extension}  # 3D Tiles 1.0's extension: the same, as 1.1 took it in
        if isinstance(tile.get("implicitTiling"), dict):  # its tiles named by templates, listed by subtrees
            try:
                implicit = list(implicit_contents(tile, folder, str(path), lambda p: read_input_bytes(p, options),
                                                  _uris(tile)))
            except InputFileError as err:
                found = True
                yield Rejection(f"{name}#implicit tiling", str(path), err.problem)
                continue
            for content in implicit:
                if content.leaf or refine == "ADD":
                    found = True
                    yield from _content(content.uri, folder, transform, refine, depth)
            continue
        for uri in _uris(tile):
            external = _names_tileset(uri)
            if children and refine != "ADD" and not external:
                continue  # a coarser level: its children replace it
            found = found or not external  # an external tileset's content is found when it is read
            yield from _content(uri, folder, transform, refine, depth)
    if not found:
        raise InputFileError(str(path), "is a 3D Tiles tileset without any content")
