"""glTF's EXT_mesh_gpu_instancing (3D Tiles 1.1's instanced content, gltfpack -mi, Blender's GPU instances): a node's
mesh drawn once per instance. trimesh ignores the extension, so a file of three houses was read as one, at the
node's place. Each instance is now a building where its translation, rotation and scale put it (worked out here by
hand), in .glb and .gltf files and as tile content."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from meshsom.gltf_compression import join_glb, split_glb
from meshsom.io import RawMesh, Rejection, read_file
from meshsom.preprocess import preprocess

#: A 10 x 4 x 6 m box (glTF: y up, 4 m tall), drawn three times: as it is; 100 m along x and turned 90 degrees about
#: the vertical; 50 m along -z (north, once z up) and scaled 2 in plan.
SIN45 = np.sin(np.pi / 4)
TRANSLATIONS = [(0, 0, 0), (100, 0, 0), (0, 0, -50)]
ROTATIONS = [(0, 0, 0, 1), (0, SIN45, 0, SIN45), (0, 0, 0, 1)]
SCALES = [(1, 1, 1), (1, 1, 1), (2, 1, 2)]
#: Each instance's centre and extent once z up ((x, y, z) -> (x, -z, y)), and its volume.
EXPECTED = [((0, 0, 0), (10, 6, 4), 240.0), ((100, 0, 0), (6, 10, 4), 240.0), ((0, 50, 0), (20, 12, 4), 960.0)]


def instanced_houses(folder: Path, rotation_accessor: dict | None = None) -> tuple[Path, Path]:
    """``houses.glb`` and ``houses.gltf`` (its buffer a data URI): one box mesh, one node, three instances (rotations
    as normalized shorts, as gltfpack writes them)."""
    glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(trimesh.creation.box(extents=(10, 4, 6))))
    gltf, binary = split_glb(glb, "box")
    gltf["asset"] = {"version": "2.0", "generator": "a test"}  # not trimesh's: y up, as the specification says
    binary = bytearray(binary + b"\0" * (-len(binary) % 4))

    def add(values, dtype, component, kind, normalized=False):
        data = np.asarray(values, dtype).tobytes()
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)})
        binary.extend(data + b"\0" * (-len(data) % 4))
        gltf["accessors"].append({"bufferView": len(gltf["bufferViews"]) - 1, "componentType": component,
                                  "count": len(values), "type": kind, **({"normalized": True} if normalized else {})})
        return len(gltf["accessors"]) - 1

    attributes = {"TRANSLATION": add(TRANSLATIONS, "<f4", 5126, "VEC3"),
                  "ROTATION": add(np.rint(np.array(ROTATIONS) * 32767), "<i2", 5122, "VEC4", True),
                  "SCALE": add(SCALES, "<f4", 5126, "VEC3")}
    if rotation_accessor is not None:
        gltf["accessors"][attributes["ROTATION"]].update(rotation_accessor)
    node = next(n for n in gltf["nodes"] if "mesh" in n)
    node["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": attributes}}
    gltf["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    gltf["buffers"] = [{"byteLength": len(binary)}]
    (folder / "houses.glb").write_bytes(join_glb(gltf, bytes(binary)))
    gltf["buffers"] = [{"byteLength": len(binary),
                        "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(binary)).decode()}]
    (folder / "houses.gltf").write_text(json.dumps(gltf))
    return folder / "houses.glb", folder / "houses.gltf"


@pytest.mark.parametrize("form", ["houses.glb", "houses.gltf", "tileset.json"])
def test_each_instance_is_a_building_where_it_stands(tmp_path, form):
    instanced_houses(tmp_path)
    (tmp_path / "tileset.json").write_text(json.dumps({
        "asset": {"version": "1.1"}, "geometricError": 100,
        "root": {"boundingVolume": {"box": [0, 0, 0, 200, 0, 0, 0, 200, 0, 0, 0, 50]}, "geometricError": 0,
                 "refine": "ADD", "content": {"uri": "houses.glb"}}}))
    items = list(read_file(tmp_path / form))
    assert len(items) == 3 and all(isinstance(m, RawMesh) for m in items), items
    got = sorted(((m.vertices.mean(axis=0) + m.origin).round(6).tolist(), np.ptp(m.vertices, axis=0).round(6).tolist(),
                  preprocess(m.vertices, m.faces).volume_out) for m in items)
    for (centre, extent, volume), (c, e, v) in zip(got, sorted(EXPECTED)):
        assert centre == pytest.approx(c, abs=1e-4) and extent == pytest.approx(e, abs=1e-4), (centre, extent)
        assert volume == pytest.approx(v, rel=1e-6)
    assert len({m.id for m in items}) == 3


def test_instances_outside_the_binary_chunk_are_a_rejection(tmp_path):
    """A ROTATION accessor of 3 instances whose bytes lie beyond the binary chunk: the file's rejection says so."""
    glb, _ = instanced_houses(tmp_path, rotation_accessor={"byteOffset": 1 << 20})
    (item,) = read_file(glb)
    assert isinstance(item, Rejection) and "ROTATION of node 0" in item.reason and "beyond" in item.reason, item


def test_instancing_laid_out_otherwise_is_a_rejection(tmp_path):
    """An instanced node whose children are a number, not a list (found by mutating the JSON): the file's rejection
    names the extension (a TypeError stopped the read)."""
    glb, _ = instanced_houses(tmp_path)
    gltf, binary = split_glb(glb.read_bytes(), "houses")
    node = next(n for n in gltf["nodes"] if "extensions" in n)
    node["children"] = 5
    (tmp_path / "odd.glb").write_bytes(join_glb(gltf, binary))
    (item,) = read_file(tmp_path / "odd.glb")
    assert isinstance(item, Rejection) and "EXT_mesh_gpu_instancing" in item.reason, item
