"""3D Tiles 1.1 content keeps its batch table as glTF metadata (``EXT_structural_metadata``'s property table, named by
``EXT_mesh_features``' feature ids, as pg2b3dm and Cesium ion write it). Its ids and labels were not read: the
buildings came out as feature numbers 0, 1, ... without labels, where a 1.0 b3dm gave their gml ids. Read as a batch
table is: ids from the first of ``id_attributes`` that names every feature once, labels from ``label_attribute``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from meshsom.gltf_compression import join_glb, split_glb
from meshsom.io import RawMesh, read_file
from meshsom.preprocess import preprocess

IDS = ["NL.IMBAG.Pand.0503100000030264", "NL.IMBAG.Pand.0503100000004493"]
FAMILIES = ["house", "tower"]
SIZES = [(10, 4, 6), (8, 30, 8)]  # glTF: y up


def houses_with_metadata(path, ids=IDS, ground=False, null=True):
    """Two boxes 100 m apart in one primitive, ``_FEATURE_ID_0`` 0 and 1, a property table of ``id`` and ``family``
    (strings: UTF-8 bytes and UINT32 offsets) and ``height`` (FLOAT32); ``ground``: and a slab of ground whose
    vertices carry feature id 65535, the set's ``nullFeatureId`` (with ``null``): no feature's."""
    boxes = [trimesh.creation.box(extents=size) for size in SIZES] + ([trimesh.creation.box(extents=(300, 1, 300))]
                                                                      if ground else [])
    boxes[1].apply_translation((100, 0, 0))
    glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(trimesh.util.concatenate(boxes)))
    gltf, binary = split_glb(glb, "boxes")
    gltf["asset"] = {"version": "2.0", "generator": "a test"}
    binary = bytearray(binary + b"\0" * (-len(binary) % 4))

    def view(data: bytes) -> int:
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)})
        binary.extend(data + b"\0" * (-len(data) % 8))
        return len(gltf["bufferViews"]) - 1

    def strings(values):
        data = [v.encode() for v in values]
        offsets = np.concatenate([[0], np.cumsum([len(d) for d in data])]).astype("<u4")
        return {"values": view(b"".join(data)), "stringOffsets": view(offsets.tobytes())}

    feature = np.repeat([0.0, 1.0, 65535.0][:len(boxes)], [len(b.vertices) for b in boxes]).astype("<f4")
    gltf["accessors"].append({"bufferView": view(feature.tobytes()), "componentType": 5126, "count": len(feature),
                              "type": "SCALAR"})
    primitive = gltf["meshes"][0]["primitives"][0]
    primitive["attributes"]["_FEATURE_ID_0"] = len(gltf["accessors"]) - 1
    primitive["extensions"] = {"EXT_mesh_features": {"featureIds": [{"featureCount": 2, "attribute": 0,
                                                                     "propertyTable": 0,
                                                                     **({"nullFeatureId": 65535} if null else {})}]}}
    gltf["extensions"] = {"EXT_structural_metadata": {
        "schema": {"id": "buildings", "classes": {"building": {"properties": {
            "id": {"type": "STRING"}, "family": {"type": "STRING"},
            "height": {"type": "SCALAR", "componentType": "FLOAT32"}}}}},
        "propertyTables": [{"class": "building", "count": 2, "properties": {
            "id": strings(ids), "family": strings(FAMILIES),
            "height": {"values": view(np.array([4, 30], "<f4").tobytes())}}}]}}
    gltf["extensionsUsed"] = ["EXT_mesh_features", "EXT_structural_metadata"]
    gltf["buffers"] = [{"byteLength": len(binary)}]
    path.write_bytes(join_glb(gltf, bytes(binary)))
    return path


@pytest.mark.parametrize("form", ["houses.glb", "tileset.json"])
def test_ids_and_labels_from_the_property_table(tmp_path, form):
    houses_with_metadata(tmp_path / "houses.glb")
    (tmp_path / "tileset.json").write_text(json.dumps({
        "asset": {"version": "1.1"}, "geometricError": 100,
        "root": {"boundingVolume": {"box": [0, 0, 0, 200, 0, 0, 0, 200, 0, 0, 0, 50]}, "geometricError": 0,
                 "refine": "ADD", "content": {"uri": "houses.glb"}}}))
    items = {m.id.rsplit("#", 1)[1]: m for m in read_file(tmp_path / form)}
    assert sorted(items) == sorted(IDS) and all(isinstance(m, RawMesh) for m in items.values()), items
    for k, (size, family) in enumerate(zip(SIZES, FAMILIES)):
        mesh = items[IDS[k]]
        assert mesh.label == family
        assert preprocess(mesh.vertices, mesh.faces).volume_out == pytest.approx(float(np.prod(size)), rel=1e-6)


def test_ids_that_repeat_are_left_for_feature_numbers(tmp_path):
    """An id column that names two features alike is no id (as for a b3dm's batch table): feature numbers instead,
    the labels still read."""
    houses_with_metadata(tmp_path / "houses.glb", ids=["same", "same"])
    items = {m.id.rsplit("#", 1)[1]: m for m in read_file(tmp_path / "houses.glb")}
    assert sorted(items) == ["0", "1"] and [items["0"].label, items["1"].label] == FAMILIES


def test_the_null_feature_id_is_no_building(tmp_path):
    """Vertices whose feature id is the set's ``nullFeatureId`` belong to no feature (EXT_mesh_features): the ground
    slab they make was read as a building of its own; it is a rejection saying so, the two houses read."""
    houses_with_metadata(tmp_path / "houses.glb", ground=True)
    items = list(read_file(tmp_path / "houses.glb"))
    assert sorted(m.id.rsplit("#", 1)[1] for m in items if isinstance(m, RawMesh)) == sorted(IDS)
    (ground,) = [m for m in items if not isinstance(m, RawMesh)]
    assert "null feature id 65535 (EXT_mesh_features nullFeatureId)" in ground.reason, ground


def test_a_feature_beyond_the_property_table_keeps_its_number(tmp_path):
    """Feature ids beyond the property table's rows (no null id declared): that feature is read under its number
    (an index beyond the ids raised IndexError out of the reader)."""
    houses_with_metadata(tmp_path / "houses.glb", ground=True, null=False)
    items = list(read_file(tmp_path / "houses.glb"))
    assert sorted(m.id.rsplit("#", 1)[1] for m in items) == sorted([*IDS, "65535"]), items


def test_metadata_laid_out_otherwise_leaves_feature_numbers(tmp_path):
    """A property table whose properties are a list, not an object (found by mutating the JSON): no ids, no labels,
    the buildings read under their feature numbers (an AttributeError stopped the read)."""
    from meshsom.tiles3d import property_table

    glb = houses_with_metadata(tmp_path / "houses.glb").read_bytes()
    gltf, binary = split_glb(glb, "houses")
    gltf["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["properties"] = ["id", "family"]
    assert property_table(gltf, binary, ("id", "family"), "houses") == ({}, None)
    (tmp_path / "odd.glb").write_bytes(join_glb(gltf, binary))
    assert sorted(m.id.rsplit("#", 1)[1] for m in read_file(tmp_path / "odd.glb")) == ["0", "1"]
