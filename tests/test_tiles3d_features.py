"""3D Tiles 1.1 glTF content whose buildings are named by any of its feature-id sets (``EXT_mesh_features``), and
instances that carry feature ids (``EXT_instance_features``).

Converters of CityGML write several feature-id sets: one per building, one per surface (walls, roof, ground). Only
``_FEATURE_ID_0`` was read, so content whose set 0 is per surface came out as one "building" per wall, and sets by
texture or implicit ids (the vertex index) were not read at all; instances sharing a feature id were each a building.
The fixtures here are two boxes written with known surfaces and building ids; the expected volumes are the boxes'
(hand values, checked against trimesh), the expected grouping the ids written.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import trimesh
from PIL import Image

from meshsom.gltf_compression import join_glb, split_glb
from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file
from meshsom.preprocess import preprocess

#: Two boxes (glTF, y up) 100 m apart; their CityGML-like ids and families.
SIZES = [(10, 4, 6), (8, 30, 8)]
OFFSETS = [(0, 0, 0), (100, 0, 0)]
BUILDINGS = ["DEBY_LOD2_4906970", "DEBY_LOD2_4906971"]
FAMILIES = ["house", "tower"]
#: Each box's six planes, a surface each; their CityGML classes by the plane's normal.
PLANES = ["WallSurface", "WallSurface", "RoofSurface", "GroundSurface", "WallSurface", "WallSurface"]


def boxes() -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
    """The two boxes in one mesh of unshared vertices (a vertex per triangle corner), the building ``(F,)`` and the
    surface ``(F,)`` of each triangle (surfaces numbered 0..11, six a box, by the plane's outward normal)."""
    meshes = []
    for size, offset in zip(SIZES, OFFSETS):
        box = trimesh.creation.box(extents=size)
        box.apply_translation(offset)
        box.unmerge_vertices()
        meshes.append(box)
    mesh = trimesh.util.concatenate(meshes)
    building = np.repeat(np.arange(len(meshes)), [len(m.faces) for m in meshes])
    normals = np.asarray(mesh.face_normals)
    axis = np.abs(normals).argmax(axis=1)
    plane = 2 * axis + (normals[np.arange(len(normals)), axis] > 0)  # -x, +x, -y, +y (roof), -z, +z
    return mesh, building, 6 * building + np.array([0, 1, 3, 2, 4, 5])[plane]


class Writer:
    """A GLB of one mesh, its vertex attributes, feature-id sets and property tables, written by hand."""

    def __init__(self, mesh: trimesh.Trimesh):
        glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh))
        self.gltf, binary = split_glb(glb, "boxes")
        self.gltf["asset"] = {"version": "2.0", "generator": "meshsom tests"}  # not trimesh's: y up
        self.binary = bytearray(binary + b"\0" * (-len(binary) % 8))
        self.primitive = self.gltf["meshes"][0]["primitives"][0]
        self.tables, self.classes = [], {}

    def view(self, data: bytes) -> int:
        self.gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(self.binary), "byteLength": len(data)})
        self.binary.extend(data + b"\0" * (-len(data) % 8))
        return len(self.gltf["bufferViews"]) - 1

    def attribute(self, name: str, values: np.ndarray, component: int = 5125, kind: str = "SCALAR") -> None:
        self.gltf["accessors"].append({"bufferView": self.view(np.ascontiguousarray(values).tobytes()),
                                       "componentType": component, "count": len(values), "type": kind})
        self.primitive["attributes"][name] = len(self.gltf["accessors"]) - 1

    def table(self, cls: str, columns: dict, name: str | None = None) -> int:
        """A property table of ``cls``: columns of strings (lists of str) or UINT32 numbers (lists of int)."""
        properties, declared = {}, {}
        for key, values in columns.items():
            if isinstance(values[0], str):
                data = [v.encode() for v in values]
                offsets = np.concatenate([[0], np.cumsum([len(d) for d in data])]).astype("<u4")
                properties[key] = {"values": self.view(b"".join(data)), "stringOffsets": self.view(offsets.tobytes())}
                declared[key] = {"type": "STRING"}
            else:
                properties[key] = {"values": self.view(np.asarray(values, "<u4").tobytes())}
                declared[key] = {"type": "SCALAR", "componentType": "UINT32"}
        self.classes[cls] = {"properties": declared}
        self.tables.append({"class": cls, "count": len(next(iter(columns.values()))), "properties": properties,
                            **({"name": name} if name else {})})
        return len(self.tables) - 1

    def write(self, path, sets: list[dict], schema: str = "inline") -> bytes:
        """The GLB with ``sets`` as the primitive's EXT_mesh_features; the schema ``inline``, ``uri`` (a file
        ``schema.json`` beside it, named by schemaUri) or ``none`` (the tileset's)."""
        self.primitive["extensions"] = {"EXT_mesh_features": {"featureIds": sets}}
        used = ["EXT_mesh_features"]
        if self.tables:
            metadata = {"propertyTables": self.tables}
            document = {"id": "buildings", "classes": self.classes}
            if schema == "inline":
                metadata["schema"] = document
            elif schema == "uri":
                metadata["schemaUri"] = "schema.json"
                (path.parent / "schema.json").write_text(json.dumps(document))
            self.gltf["extensions"] = {**self.gltf.get("extensions", {}), "EXT_structural_metadata": metadata}
            used.append("EXT_structural_metadata")
        self.gltf["extensionsUsed"] = used
        self.gltf["buffers"] = [{"byteLength": len(self.binary)}]
        data = join_glb(self.gltf, bytes(self.binary))
        path.write_bytes(data)
        return data


def two_sets(path, surface_class="surface", building_class="building", parent=False, building_set=True,
             id_column="gml_id"):
    """Two boxes, set 0 per surface (``_FEATURE_ID_0``, 12 surfaces, a table of ids (``id_column``), and
    ``building_id`` with ``parent``), set 1 per building (``_FEATURE_ID_1``, a table of ids and families), as CityGML
    converters write."""
    mesh, building, surface = boxes()
    writer = Writer(mesh)
    writer.attribute("_FEATURE_ID_0", np.repeat(surface, 3).astype("<u2"), 5123)
    writer.attribute("_FEATURE_ID_1", np.repeat(building, 3).astype("<u1"), 5121)
    surfaces = {id_column: [f"{BUILDINGS[s // 6]}_{PLANES[s % 6]}_{s % 6}" for s in range(12)],
                "surface_type": [PLANES[s % 6] for s in range(12)]}
    if parent:
        surfaces["building_id"] = [BUILDINGS[s // 6] for s in range(12)]
    sets = [{"featureCount": 12, "attribute": 0, "propertyTable": writer.table(surface_class, surfaces)}]
    if building_set:
        sets.append({"featureCount": 2, "attribute": 1,
                     "propertyTable": writer.table(building_class, {id_column: BUILDINGS, "family": FAMILIES})})
    writer.write(path, sets)
    return path


def _volumes_by_id(items) -> dict:
    return {m.id.rsplit("#", 1)[1]: preprocess(m.vertices, m.faces).volume_out for m in items if isinstance(m, RawMesh)}


def test_hand_volumes_match_trimesh():
    """The boxes' volumes by hand are trimesh's (the independent check the other tests lean on)."""
    for size, offset in zip(SIZES, OFFSETS):
        box = trimesh.creation.box(extents=size)
        assert box.volume == pytest.approx(float(np.prod(size)))


@pytest.mark.parametrize("classes", [("surface", "building"), ("bldg:WallSurface", "bldg:Building"),
                                     ("thematic_surfaces", "Gebaeude")])
def test_the_set_that_names_buildings_is_read_not_the_surfaces(tmp_path, classes):
    """Set 0 per surface, set 1 per building: the buildings are set 1's (ids and labels from its table), never a
    building split into its walls and roof."""
    two_sets(tmp_path / "city.glb", *classes)
    items = list(read_file(tmp_path / "city.glb"))
    assert all(isinstance(m, RawMesh) for m in items), items
    assert _volumes_by_id(items) == pytest.approx(dict(zip(BUILDINGS, [float(np.prod(s)) for s in SIZES])))
    by_id = {m.id.rsplit("#", 1)[1]: m for m in items}
    assert [by_id[b].label for b in BUILDINGS] == FAMILIES
    assert all(len(m.faces) == 12 for m in items)
    assert any("set 1" in n and "read as the buildings" in n for n in items[0].notes), items[0].notes


@pytest.mark.parametrize("parent", [False, True])
def test_unnamed_sets_fewest_features_that_split(tmp_path, parent):
    """Neither set's class names buildings or parts ("classA", "classB"), nor their columns ("code"): the set of the
    fewest features that still splits the content (the 2 buildings, not the 12 surfaces) is read. So too where the
    surfaces' table has a column naming their building (``building_id``: a property naming buildings, but in a
    table of more features than another set that splits the content)."""
    two_sets(tmp_path / "city.glb", "classA", "classB", id_column="code", parent=parent)
    items = list(read_file(tmp_path / "city.glb", ReaderOptions(id_attributes=("code",))))
    assert sorted(_volumes_by_id(items)) == sorted(BUILDINGS), items
    assert any("fewest features that splits" in n for n in items[0].notes)


def test_surfaces_grouped_by_their_building_column(tmp_path):
    """Only a per-surface set, whose table says each surface's building (``building_id``): the surfaces of one
    building are one building of parts (the surfaces' gml ids), its volume the box's."""
    two_sets(tmp_path / "city.glb", parent=True, building_set=False)
    items = list(read_file(tmp_path / "city.glb"))
    meshes = {m.id.rsplit("#", 1)[1]: m for m in items if isinstance(m, RawMesh)}
    assert sorted(meshes) == sorted(BUILDINGS), items
    for k, b in enumerate(BUILDINGS):
        mesh = meshes[b]
        assert len(mesh.parts) == 6 and all(p.startswith(b) for p in mesh.parts)
        assert np.bincount(mesh.face_part).tolist() == [2] * 6
        assert preprocess(mesh.vertices, mesh.faces).volume_out == pytest.approx(float(np.prod(SIZES[k])))


def test_surfaces_without_their_building_are_not_split(tmp_path):
    """Only a per-surface set and nothing saying which building: not one building per wall; the node is one building
    (the content's one node: both boxes), with a note that says why."""
    two_sets(tmp_path / "city.glb", building_set=False)
    items = list(read_file(tmp_path / "city.glb"))
    assert len(items) == 1 and isinstance(items[0], RawMesh), items
    assert len(items[0].faces) == 24
    assert any("name parts of buildings" in n for n in items[0].notes), items[0].notes


def test_implicit_ids_are_the_vertex_index(tmp_path):
    """An implicit set (no attribute, no texture): a triangle's feature is its first vertex's index. The two boxes
    of 36 unshared vertices each: triangles 0, 3, 6, ... are features 0, 3, 6, ... (one triangle each)."""
    mesh, _, _ = boxes()
    Writer(mesh).write(tmp_path / "implicit.glb", [{"featureCount": 72}])
    items = list(read_file(tmp_path / "implicit.glb"))
    assert sorted(int(m.id.rsplit("#", 1)[1]) for m in items) == list(range(0, 72, 3))
    assert all(isinstance(m, RawMesh) and len(m.faces) == 1 for m in items)


def texture_glb(path, channels=(0, 1), merged=False, transform=None, swap=False):
    """The two boxes, their feature ids in a 2 x 1 texture (RGBA: left texel (7, 1, 0, 255): id 7 + 256 = 263 by
    channels 0 and 1; right (9, 0, 0, 255): 9), each box's texture coordinates in its texel. ``merged``: one box of
    8 shared vertices instead, u from its x (left half: texel 0), so that triangles of both features share vertices."""
    if merged:
        mesh = trimesh.creation.box(extents=(10, 4, 6))
        u = np.where(mesh.vertices[:, 0] < 0, 0.1, 0.9)
    else:
        mesh, building, _ = boxes()
        u = np.where(np.repeat(building, 3) == 0, 0.25, 0.75)
    writer = Writer(mesh)
    uv = np.column_stack([u, np.full(len(u), 0.5)])
    writer.attribute("TEXCOORD_0", (uv[:, ::-1] if swap else uv).astype("<f4"), 5126, "VEC2")
    png = io.BytesIO()
    Image.fromarray(np.array([[[7, 1, 0, 255], [9, 0, 0, 255]]], np.uint8), "RGBA").save(png, "PNG")
    writer.gltf["images"] = [{"bufferView": writer.view(png.getvalue()), "mimeType": "image/png"}]
    writer.gltf["samplers"] = [{"magFilter": 9728, "minFilter": 9728}]
    writer.gltf["textures"] = [{"source": 0, "sampler": 0}]
    texture = {"index": 0, "texCoord": 0, "channels": list(channels)}
    if transform:
        texture["extensions"] = {"KHR_texture_transform": transform}
    writer.write(path, [{"featureCount": 2, "texture": texture}])
    return mesh


def test_texture_ids_by_their_channels(tmp_path):
    """A feature-id texture: each triangle's id is the texel at its texture coordinates, channels 0 and 1 the id's
    low and high bytes (263 and 9); each box a building of its 12 triangles and volume."""
    texture_glb(tmp_path / "texture.glb")
    volumes = _volumes_by_id(read_file(tmp_path / "texture.glb"))
    assert volumes == pytest.approx({"263": float(np.prod(SIZES[0])), "9": float(np.prod(SIZES[1]))})


@pytest.mark.parametrize("transform, swap", [({"offset": [0.5, 0]}, False), ({"scale": [-1, 1]}, False),
                                             ({"rotation": float(np.pi), "offset": [0, 1]}, False),
                                             ({"rotation": float(np.pi / 2)}, True)])
def test_texture_transform_moves_the_ids(tmp_path, transform, swap):
    """KHR_texture_transform on the feature-id texture: u moved by half the texture (u 0.25 -> 0.75, 0.75 -> 1.25,
    which repeats to 0.25), mirrored (-0.25 -> 0.75 and -0.75 -> 0.25 by REPEAT), turned half a turn about the
    origin and moved up one (u, v) -> (-u, 1 - v), or (the boxes' coordinates in v instead) turned a quarter turn
    counter-clockwise, (u, v) -> (-v, u) (the specification's GLSL matrices): each box reads the other texel's id."""
    texture_glb(tmp_path / "texture.glb", transform=transform, swap=swap)
    volumes = _volumes_by_id(read_file(tmp_path / "texture.glb"))
    assert volumes == pytest.approx({"9": float(np.prod(SIZES[0])), "263": float(np.prod(SIZES[1]))})


def test_texture_ids_split_shared_vertices(tmp_path):
    """Triangles of two features sharing vertices: each feature gets its own copies; its triangles are those whose
    centre's u (the mean of its corners', worked out here from the box) lies in its texel."""
    mesh = texture_glb(tmp_path / "texture.glb", channels=(0,), merged=True)
    u = np.where(mesh.vertices[:, 0] < 0, 0.1, 0.9)[mesh.faces].mean(axis=1)
    expected = {"7": int((u < 0.5).sum()), "9": int((u >= 0.5).sum())}
    items = list(read_file(tmp_path / "texture.glb"))
    assert {m.id.rsplit("#", 1)[1]: len(m.faces) for m in items} == expected
    for m in items:  # each feature's vertices are only those its triangles use
        assert len(m.vertices) == len(np.unique(m.faces))


@pytest.mark.parametrize("schema", ["uri", "tileset", "tileset uri"])
def test_schema_outside_the_content(tmp_path, schema):
    """The property tables' classes in a schema file the content names (``schemaUri``), or, where the content names
    none, in the tileset's ``schema`` (or the file its ``schemaUri`` names): the building set is still found by its
    class and its ids read."""
    mesh, building, surface = boxes()
    writer = Writer(mesh)
    writer.attribute("_FEATURE_ID_0", np.repeat(surface, 3).astype("<u2"), 5123)
    writer.attribute("_FEATURE_ID_1", np.repeat(building, 3).astype("<u1"), 5121)
    sets = [{"featureCount": 12, "attribute": 0, "propertyTable": writer.table("roofs", {"gml_id": [
        f"s{k}" for k in range(12)]})},
            {"featureCount": 2, "attribute": 1, "propertyTable": writer.table("buildings", {"gml_id": BUILDINGS})}]
    writer.write(tmp_path / "city.glb", sets, schema="uri" if schema == "uri" else "none")
    document = {"asset": {"version": "1.1"}, "geometricError": 100,
                "root": {"boundingVolume": {"box": [0, 0, 0, 200, 0, 0, 0, 200, 0, 0, 0, 50]}, "geometricError": 0,
                         "refine": "ADD", "content": {"uri": "city.glb"}}}
    if schema == "tileset":
        document["schema"] = {"id": "buildings", "classes": writer.classes}
    elif schema == "tileset uri":
        (tmp_path / "meta").mkdir()
        (tmp_path / "meta" / "tileset-schema.json").write_text(json.dumps({"id": "b", "classes": writer.classes}))
        document["schemaUri"] = "meta/tileset-schema.json"
    (tmp_path / "tileset.json").write_text(json.dumps(document))
    assert sorted(_volumes_by_id(read_file(tmp_path / "tileset.json"))) == sorted(BUILDINGS)


def test_schema_file_missing_is_said(tmp_path):
    """A schemaUri naming no file: the content is read (by feature numbers) and its buildings' notes say why there
    are no ids."""
    two_sets(tmp_path / "city.glb")
    gltf, binary = split_glb((tmp_path / "city.glb").read_bytes(), "city")
    metadata = gltf["extensions"]["EXT_structural_metadata"]
    metadata["schemaUri"] = "missing.json"
    del metadata["schema"]
    (tmp_path / "city.glb").write_bytes(join_glb(gltf, binary))
    items = list(read_file(tmp_path / "city.glb"))
    assert items and all(isinstance(m, RawMesh) for m in items)
    assert any("'missing.json'" in n and "cannot be read" in n for n in items[0].notes), items[0].notes


def test_instances_sharing_a_feature_are_one_building(tmp_path):
    """EXT_instance_features: three instances, feature ids 0, 1, 0 in the instancing attribute ``_FEATURE_ID_1``
    (set 0 of the extension names attribute 1), a property table of ids: instances 1 and 3 are one building (volume
    240 + 960 m3, the boxes of tests/test_gltf_instancing.py), instance 2 another (240)."""
    from test_gltf_instancing import EXPECTED, instanced_houses

    glb, _ = instanced_houses(tmp_path)
    gltf, binary = split_glb(glb.read_bytes(), "houses")
    binary = bytearray(binary)
    features = np.array([0, 1, 0], "<u2").tobytes()
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(features)})
    binary.extend(features + b"\0\0")
    gltf["accessors"].append({"bufferView": len(gltf["bufferViews"]) - 1, "componentType": 5123, "count": 3,
                              "type": "SCALAR"})
    names = b"NL.IMBAG.Pand.1NL.IMBAG.Pand.2"
    for data in (names, np.array([0, 15, 30], "<u4").tobytes()):
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)})
        binary.extend(data + b"\0" * (-len(data) % 4))
    node = next(n for n in gltf["nodes"] if "extensions" in n)
    node["extensions"]["EXT_mesh_gpu_instancing"]["attributes"]["_FEATURE_ID_1"] = len(gltf["accessors"]) - 1
    node["extensions"]["EXT_instance_features"] = {"featureIds": [{"featureCount": 2, "attribute": 1,
                                                                   "propertyTable": 0}]}
    views = len(gltf["bufferViews"])
    gltf["extensions"] = {"EXT_structural_metadata": {
        "schema": {"id": "s", "classes": {"pand": {"properties": {"id": {"type": "STRING"}}}}},
        "propertyTables": [{"class": "pand", "count": 2, "properties": {
            "id": {"values": views - 2, "stringOffsets": views - 1}}}]}}
    gltf["extensionsUsed"] += ["EXT_instance_features", "EXT_structural_metadata"]
    gltf["buffers"] = [{"byteLength": len(binary)}]
    (tmp_path / "pand.glb").write_bytes(join_glb(gltf, bytes(binary)))
    items = list(read_file(tmp_path / "pand.glb"))
    assert all(isinstance(m, RawMesh) for m in items), items
    volumes = _volumes_by_id(items)
    assert volumes == pytest.approx({"NL.IMBAG.Pand.1": EXPECTED[0][2] + EXPECTED[2][2],
                                     "NL.IMBAG.Pand.2": EXPECTED[1][2]})


def test_draco_feature_ids_of_any_set(tmp_path):
    """A Draco-compressed primitive whose feature ids are ``_FEATURE_ID_1`` (set 0 of EXT_mesh_features names
    attribute 1): read by building, as the plain one is (volumes within 0.5 % of the uncompressed buildings':
    Draco's 16-bit quantization over the tile moves corners by millimetres)."""
    from test_gltf_compression import draco_glb
    from test_tiles3d import _buildings

    buildings = _buildings(3)
    doc, stream = split_glb(draco_glb(buildings, feature="_FEATURE_ID_1", bits=16, with_normals=False), "d")
    doc["meshes"][0]["primitives"][0]["extensions"]["EXT_mesh_features"] = {"featureIds": [
        {"featureCount": 3, "attribute": 1}]}
    (tmp_path / "d.glb").write_bytes(join_glb(doc, stream))
    items = list(read_file(tmp_path / "d.glb"))
    assert sorted(m.id.rsplit("#", 1)[1] for m in items) == ["0", "1", "2"], items
    for (_, vertices, faces), m in zip(buildings, sorted(items, key=lambda m: m.id)):
        expected = abs(trimesh.Trimesh(vertices, faces, process=False).volume)
        assert preprocess(m.vertices, m.faces).volume_out == pytest.approx(expected, rel=5e-3)


def test_a_set_naming_a_missing_attribute_is_a_rejection(tmp_path):
    """A set that names ``_FEATURE_ID_3``, which the primitive does not have: the file's rejection says so."""
    mesh, _, _ = boxes()
    Writer(mesh).write(tmp_path / "odd.glb", [{"featureCount": 2, "attribute": 3}])
    (item,) = read_file(tmp_path / "odd.glb")
    assert isinstance(item, Rejection) and "_FEATURE_ID_3" in item.reason, item


def test_options_ids(tmp_path):
    """The building table's ids follow ``id_attributes``: a column the options do not name leaves feature numbers."""
    two_sets(tmp_path / "city.glb")
    items = list(read_file(tmp_path / "city.glb", ReaderOptions(id_attributes=("nothing",))))
    assert sorted(_volumes_by_id(items)) == ["0", "1"]


# --- CesiumGS/3d-tiles-samples (tests/data/3d-tiles-samples/SOURCE.md: CC0) -------------------------------------------

SAMPLES = __import__("pathlib").Path(__file__).parent / "data" / "3d-tiles-samples"


def _sample_arrays(name: str, view: int, dtype: str, width: int) -> np.ndarray:
    """A buffer view of a sample's glTF JSON (its buffers data URIs), decoded here with json and base64 alone."""
    import base64

    gltf = json.loads((SAMPLES / name).read_text())
    v = gltf["bufferViews"][view]
    data = base64.b64decode(gltf["buffers"][v["buffer"]]["uri"].partition(",")[2])
    return np.frombuffer(data, dtype, v["byteLength"] // np.dtype(dtype).itemsize, v.get("byteOffset", 0)).reshape(
        -1, width)


def test_sample_gpu_instances_metadata():
    """Cesium's GpuInstancesMetadata: 10 unit cubes, instance i carrying feature 9 - i. Each building is its feature
    (ids 0..9), labelled by its row of the property table (``example_STRING``: "zero".."nine"), its volume its
    instance's scale product (the SCALE accessor, read here), its corner nearest the origin its instance's
    translation turned z up. Before: ten buildings "node 0 instance N", without labels."""
    import trimesh.transformations as tf

    items = list(read_file(SAMPLES / "GpuInstancesMetadata.gltf", ReaderOptions(label_attribute="example_STRING")))
    translation = _sample_arrays("GpuInstancesMetadata.gltf", 3, "<f4", 3)
    rotation = _sample_arrays("GpuInstancesMetadata.gltf", 4, "<f4", 4)
    scale = _sample_arrays("GpuInstancesMetadata.gltf", 5, "<f4", 3)
    feature = _sample_arrays("GpuInstancesMetadata.gltf", 6, "<u2", 1)[:, 0]
    words = ["zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine"]
    by_id = {m.id.rsplit("#", 1)[1]: m for m in items}
    assert sorted(by_id, key=int) == [str(k) for k in range(10)], items
    for i in range(10):
        mesh = by_id[str(int(feature[i]))]
        assert mesh.label == words[feature[i]]
        assert preprocess(mesh.vertices, mesh.faces).volume_out == pytest.approx(float(np.prod(scale[i])), rel=1e-5)
        x, y, z, w = rotation[i]
        m = tf.quaternion_matrix([w, x, y, z]) @ np.diag([*scale[i], 1.0])
        m[:3, 3] = translation[i]
        corners = tf.transform_points(np.array(np.meshgrid([0, 1], [0, 1], [0, 1])).reshape(3, -1).T, m)
        z_up = np.column_stack([corners[:, 0], -corners[:, 2], corners[:, 1]])
        got = mesh.vertices + mesh.origin
        assert np.sort(got.round(4), axis=0)[[0, -1]] == pytest.approx(np.sort(z_up, axis=0)[[0, -1]], abs=1e-4)


def test_sample_multiple_feature_ids():
    """Cesium's MultipleFeatureIdsAndProperties: two sets of 4 features each (neither names buildings): set 0, the
    first of the fewest that split, is read. Feature k is the quad of vertices 4k..4k+3 (the sample's README table),
    compared with the positions decoded here; the note names both sets."""
    items = list(read_file(SAMPLES / "MultipleFeatureIdsAndProperties.gltf",
                           ReaderOptions(label_attribute="example_STRING")))
    positions = _sample_arrays("MultipleFeatureIdsAndProperties.gltf", 1, "<f4", 3).astype(np.float64)
    z_up = np.column_stack([positions[:, 0], -positions[:, 2], positions[:, 1]])
    assert sorted(m.id.rsplit("#", 1)[1] for m in items) == ["0", "1", "2", "3"]
    for m in items:
        k = int(m.id.rsplit("#", 1)[1])
        assert len(m.faces) == 2
        assert np.sort(m.vertices + m.origin, axis=0) == pytest.approx(np.sort(z_up[4 * k:4 * k + 4], axis=0), abs=1e-6)
    assert any("set 0" in n and "set 1" in n for n in items[0].notes), items[0].notes


def test_sample_feature_id_texture():
    """Cesium's FeatureIdTexture: a quad of 2 triangles, its ids in a 16 x 16 texture (channel 0). Each triangle's
    feature is the texel at the mean of its corners' texture coordinates, worked out here from the PNG (PIL) and the
    TEXCOORD_0 accessor: both are feature 0, so one building of 2 triangles."""
    import base64

    gltf = json.loads((SAMPLES / "FeatureIdTexture.gltf").read_text())
    pixels = np.asarray(Image.open(io.BytesIO(base64.b64decode(gltf["images"][1]["uri"].partition(",")[2]))))
    uv = _sample_arrays("FeatureIdTexture.gltf", 3, "<f4", 2)
    faces = _sample_arrays("FeatureIdTexture.gltf", 0, "<u2", 3)
    centre = uv[faces].mean(axis=1)
    texel = pixels[(centre[:, 1] * 16).astype(int), (centre[:, 0] * 16).astype(int), 0]
    items = list(read_file(SAMPLES / "FeatureIdTexture.gltf"))
    assert {m.id.rsplit("#", 1)[1]: len(m.faces) for m in items} == {
        str(t): int((texel == t).sum()) for t in np.unique(texel)}
    assert any("ids by texture" in n for n in items[0].notes)


@pytest.mark.parametrize("mutate", [
    lambda g: g["meshes"][0]["primitives"][0]["extensions"]["EXT_mesh_features"].update(featureIds=[5, "x"]),
    lambda g: g["meshes"][0]["primitives"][0]["extensions"]["EXT_mesh_features"]["featureIds"][0].update(
        texture={"index": 9}),
    lambda g: g["meshes"][0]["primitives"][0]["extensions"]["EXT_mesh_features"]["featureIds"][1].update(
        propertyTable=7, nullFeatureId="none", label=3),
    lambda g: g["extensions"]["EXT_structural_metadata"].update(schema=[1], propertyTables={"a": 1}),
    lambda g: g["meshes"][0]["primitives"][0]["attributes"].update(_FEATURE_ID_1=999),
])
def test_feature_ids_laid_out_otherwise_are_read_or_rejected(tmp_path, mutate):
    """Feature-id sets and metadata of other shapes than the specification's (mutated JSON): each file is read or is
    one rejection naming it, never an exception out of the reader."""
    two_sets(tmp_path / "city.glb")
    gltf, binary = split_glb((tmp_path / "city.glb").read_bytes(), "city")
    mutate(gltf)
    (tmp_path / "odd.glb").write_bytes(join_glb(gltf, binary))
    items = list(read_file(tmp_path / "odd.glb"))
    assert items and all(isinstance(m, (RawMesh, Rejection)) for m in items), items
    assert all(str(tmp_path / "odd.glb") in m.source for m in items)


def test_null_feature_id_of_the_set_read(tmp_path):
    """The set read (set 1, per building) declares ``nullFeatureId`` 255, carried by the second box: its triangles
    are a rejection saying so, the first box a building; set 0's ids (surfaces, no null id) do not matter."""
    mesh, building, surface = boxes()
    writer = Writer(mesh)
    writer.attribute("_FEATURE_ID_0", np.repeat(surface, 3).astype("<u2"), 5123)
    writer.attribute("_FEATURE_ID_1", np.repeat(np.where(building == 1, 255, building), 3).astype("<u1"), 5121)
    writer.write(tmp_path / "city.glb", [{"featureCount": 12, "attribute": 0, "label": "surfaces"},
                                         {"featureCount": 1, "attribute": 1, "label": "buildings",
                                          "nullFeatureId": 255}])
    items = list(read_file(tmp_path / "city.glb"))
    meshes = [m for m in items if isinstance(m, RawMesh)]
    assert [m.id.rsplit("#", 1)[1] for m in meshes] == ["0"] and len(meshes[0].faces) == 12
    (null,) = [m for m in items if isinstance(m, Rejection)]
    assert "12 triangles carry the null feature id 255" in null.reason, null


def test_a_primitive_without_the_set_read_is_listed(tmp_path):
    """Two primitives: the first has both sets (surfaces, buildings), the second (a third box) only the surfaces'.
    The buildings are set 1's; the second primitive's triangles are a rejection saying they lack set 1, not merged
    into building 0 (as its node's number, 0, would have)."""
    two_sets(tmp_path / "city.glb")
    gltf, binary = split_glb((tmp_path / "city.glb").read_bytes(), "city")
    primitive = gltf["meshes"][0]["primitives"][0]
    other = json.loads(json.dumps(primitive))
    del other["attributes"]["_FEATURE_ID_1"]
    other["extensions"]["EXT_mesh_features"]["featureIds"] = other["extensions"]["EXT_mesh_features"]["featureIds"][:1]
    gltf["meshes"].append({"primitives": [other]})
    gltf["nodes"].append({"mesh": 1, "translation": [0, 0, 500]})
    gltf["scenes"][0]["nodes"].append(len(gltf["nodes"]) - 1)
    (tmp_path / "city.glb").write_bytes(join_glb(gltf, binary))
    items = list(read_file(tmp_path / "city.glb"))
    assert _volumes_by_id(items) == pytest.approx(dict(zip(BUILDINGS, [float(np.prod(s)) for s in SIZES])))
    (rejection,) = [m for m in items if isinstance(m, Rejection)]
    assert "24 triangles of primitives without EXT_mesh_features set 1" in rejection.reason, rejection
