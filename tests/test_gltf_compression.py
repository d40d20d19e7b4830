"""Draco- and meshopt-compressed glTF, as web-tiled city models come (Cesium ion and gltf-pipeline:
Draco in b3dm and glb tiles; gltfpack and gltf-transform: meshopt), read as their plain glTF.

The fixtures compress real buildings (Delft, 3dfier LoD 1.2) the way those tools lay the data out,
by the specifications (KHR_draco_mesh_compression: the primitive's accessors keep their counts and
lose their buffer views, the Draco stream carries the feature ids as a generic attribute;
EXT_meshopt_compression: each buffer view keeps its place in a fallback buffer without data and
points to its compressed bytes in the GLB's binary chunk), with the libraries' encoders; the
expected meshes come from the uncompressed tiles read by the same readers (trimesh underneath).
"""

from __future__ import annotations

import json
import struct

import DracoPy
import meshopt
import numpy as np
import pytest
import trimesh

from meshsom.errors import InputFileError
from meshsom.gltf_compression import compression_used, decompress_glb, join_glb, split_glb
from meshsom.io import RawMesh, Rejection, read_file
from tests.test_tiles3d import _buildings, b3dm

FLOAT, USHORT, UINT = 5126, 5123, 5125


def _plain(buildings):
    """(y-up positions float32, triangles uint32, feature id per vertex) of the buildings in one mesh."""
    v, f, ids, offset = [], [], [], 0
    for k, (_, vertices, faces) in enumerate(buildings):
        v.append(vertices)
        f.append(faces + offset)
        ids.append(np.full(len(vertices), k))
        offset += len(vertices)
    v = np.concatenate(v)
    y_up = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]).astype(np.float32)
    return y_up, np.concatenate(f).astype(np.uint32), np.concatenate(ids)


def _document(extensions, accessors, views, buffers, attributes, indices, primitive_extensions=None):
    primitive = {"attributes": attributes, "indices": indices, "mode": 4}
    if primitive_extensions:
        primitive["extensions"] = primitive_extensions
    return {"asset": {"version": "2.0", "generator": "meshsom tests"}, "extensionsUsed": extensions,
            "extensionsRequired": extensions, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [primitive]}], "accessors": accessors, "bufferViews": views, "buffers": buffers}


def draco_glb(buildings, feature="_BATCHID", bits=14, with_normals=True):
    """A GLB as gltf-pipeline writes one: one primitive, its positions, normals and feature ids
    in a Draco stream (quantized to ``bits``), its accessors without buffer views."""
    v, f, ids = _plain(buildings)
    generic = {0: ids.astype(np.float32).reshape(-1, 1)}
    normals = np.asarray(trimesh.Trimesh(v, f, process=False).vertex_normals, np.float64) if with_normals else None
    stream = DracoPy.encode(v, f, quantization_bits=bits, generic_attributes=generic, normals=normals)
    decoded = DracoPy.decode(stream)  # which unique id each attribute got (attribute_type 0: position, 1: normal)
    uid = {a["attribute_type"]: a["unique_id"] for a in decoded.attributes}
    mapping = {"POSITION": uid[0], feature: uid[4]}
    attributes = {"POSITION": 0, feature: 1}
    accessors = [{"componentType": FLOAT, "count": len(v), "type": "VEC3", "min": v.min(0).tolist(), "max": v.max(0).tolist()},
                 {"componentType": FLOAT, "count": len(v), "type": "SCALAR"},
                 {"componentType": UINT, "count": f.size, "type": "SCALAR"}]
    if with_normals:
        mapping["NORMAL"] = uid[1]
        attributes["NORMAL"] = 3
        accessors.append({"componentType": FLOAT, "count": len(v), "type": "VEC3"})
    doc = _document(["KHR_draco_mesh_compression"], accessors, [{"buffer": 0, "byteOffset": 0, "byteLength": len(stream)}],
                    [{"byteLength": len(stream)}], attributes, 2,
                    {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": mapping}})
    return join_glb(doc, stream)


def meshopt_glb(buildings, feature="_FEATURE_ID_0", name="EXT_meshopt_compression"):
    """A GLB as gltfpack writes one: positions (ATTRIBUTES), feature ids as unsigned shorts
    (ATTRIBUTES, stride 4) and triangles (TRIANGLES) meshopt-compressed into the binary chunk, each
    buffer view placed in a fallback buffer that holds no data."""
    v, f, ids = _plain(buildings)
    feature_rows = np.zeros((len(ids), 2), np.uint16)
    feature_rows[:, 0] = ids
    parts = [(v, "ATTRIBUTES", 12, 34962), (feature_rows, "ATTRIBUTES", 4, 34962), (f, "TRIANGLES", 4, 34963)]
    binary, views, fallback = b"", [], 0
    for data, mode, stride, target in parts:
        packed = meshopt.encode_gltf_buffer(data, mode)
        count = len(data) if mode == "ATTRIBUTES" else data.size
        binary += b"\0" * (-len(binary) % 4)
        view = {"buffer": 1, "byteOffset": fallback, "byteLength": count * stride, "target": target,
                "extensions": {name: {"buffer": 0, "byteOffset": len(binary), "byteLength": len(packed),
                                      "byteStride": stride, "count": count, "mode": mode}}}
        if mode == "ATTRIBUTES":
            view["byteStride"] = stride
        views.append(view)
        binary += packed
        fallback += count * stride
    accessors = [{"bufferView": 0, "componentType": FLOAT, "count": len(v), "type": "VEC3",
                  "min": v.min(0).tolist(), "max": v.max(0).tolist()},
                 {"bufferView": 1, "componentType": USHORT, "count": len(v), "type": "SCALAR"},
                 {"bufferView": 2, "componentType": UINT, "count": f.size, "type": "SCALAR"}]
    buffers = [{"byteLength": len(binary)}, {"byteLength": fallback, "extensions": {name: {"fallback": True}}}]
    return join_glb(_document([name], accessors, views, buffers, {"POSITION": 0, feature: 1}, 2), binary)


def as_b3dm(glb: bytes, buildings) -> bytes:
    """A b3dm around a GLB, its batch table naming the buildings (as the uncompressed fixture's)."""
    plain = b3dm(buildings, lambda v: v)
    ft_len, bt_len = struct.unpack_from("<I", plain, 12)[0], struct.unpack_from("<I", plain, 20)[0]
    tables = plain[28:28 + ft_len + bt_len]
    glb += b"\0" * (-len(glb) % 8)
    return b"b3dm" + struct.pack("<6I", 1, 28 + len(tables) + len(glb), ft_len, 0, bt_len, 0) + tables + glb


def _meshes(path):
    items = list(read_file(path))
    assert all(isinstance(m, RawMesh) for m in items), [m for m in items if not isinstance(m, RawMesh)]
    return {m.id.split("#", 1)[1]: m for m in items}


def _world(m):
    return m.vertices + m.origin


@pytest.fixture(scope="module")
def buildings():
    return _buildings(6)


def test_draco_b3dm_reads_as_its_plain_tile(tmp_path, buildings):
    """Cesium ion's layout: a b3dm whose glTF is Draco-compressed with _BATCHID in the stream. The same
    buildings, ids, triangles (Draco reorders vertices and rotates triangles, never flips them) and
    positions to within the quantization (14 bits over a ~300 m tile: about 2 cm)."""
    (tmp_path / "plain.b3dm").write_bytes(b3dm(buildings, lambda v: v))
    (tmp_path / "draco.b3dm").write_bytes(as_b3dm(draco_glb(buildings), buildings))
    plain, draco = _meshes(tmp_path / "plain.b3dm"), _meshes(tmp_path / "draco.b3dm")
    assert list(draco) == list(plain) == [b[0] for b in buildings]
    extent = np.ptp(np.concatenate([_world(m) for m in plain.values()]), axis=0).max()
    step = extent / (2**14 - 1)
    for key, want in plain.items():
        got = draco[key]
        assert got.faces.shape == want.faces.shape
        # every corner within the quantization step of one of the plain tile's
        a, b = _world(got)[got.faces].reshape(-1, 3), _world(want)[want.faces].reshape(-1, 3)
        nearest = np.linalg.norm(a[:, None] - b[None], axis=2).min(axis=1)
        assert nearest.max() <= np.sqrt(3) * step
        # orientation kept: the enclosed volume has the same sign and size
        def volume(m):
            w = _world(m) - _world(m).mean(0)
            t = w[m.faces]
            return np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6
        # ... to within the quantization: each corner moved at most sqrt(3) step, so the volume
        # by at most the surface area times that
        t = _world(want)[want.faces]
        area = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum() / 2
        assert volume(want) > 0 and abs(volume(got) - volume(want)) <= area * np.sqrt(3) * step


def test_meshopt_glb_reads_as_its_plain_tile(tmp_path, buildings):
    """gltfpack's layout (3D Tiles 1.1 glb content, _FEATURE_ID_0 as unsigned shorts): lossless, so
    exactly the plain tile's vertices and triangles (meshopt may rotate a triangle's corners)."""
    (tmp_path / "plain.glb").write_bytes(b3dm(buildings, lambda v: v, glb_only=True))
    for name in ("EXT_meshopt_compression", "KHR_meshopt_compression"):
        (tmp_path / f"{name}.glb").write_bytes(meshopt_glb(buildings, name=name))
        (tmp_path / "tileset.json").write_text(json.dumps({
            "asset": {"version": "1.1"}, "geometricError": 100,
            "root": {"boundingVolume": {"sphere": [0, 0, 0, 1000]}, "geometricError": 0, "refine": "ADD",
                     "children": [{"boundingVolume": {"sphere": [0, 0, 0, 1000]}, "geometricError": 0,
                                   "content": {"uri": uri}} for uri in ("plain.glb", f"{name}.glb")]}}))
        items = [m for m in read_file(tmp_path / "tileset.json")]
        assert all(isinstance(m, RawMesh) for m in items), items
        by_content = {}
        for m in items:
            _, content, building = m.id.split("#")
            by_content.setdefault(content, {})[building] = m
        plain, packed = by_content["plain.glb"], by_content[f"{name}.glb"]
        assert list(packed) == list(plain) and len(plain) == len(buildings)
        for key, want in plain.items():
            got = packed[key]
            assert np.array_equal(_world(got), _world(want))
            rotated = [np.roll(got.faces, r, axis=1) for r in range(3)]
            assert all(any((r[i] == want.faces[i]).all() for r in rotated) for i in range(len(want.faces)))


def test_compressed_glb_through_read_trimesh(tmp_path, buildings):
    """A plain .glb file (no tileset) compressed either way reads like its plain form: its feature ids make it 3D Tiles
    content saved as a file (3d-tiles-tools' b3dmToGlb), a building per feature (it was one mesh per node, all its
    buildings in one); decompress_glb leaves an uncompressed GLB as it is and declares no compression after."""
    plain = b3dm(buildings[:2], lambda v: v, glb_only=True)
    assert decompress_glb(plain, "plain.glb") is plain
    for name, glb in (("draco.glb", draco_glb(buildings[:2])), ("meshopt.glb", meshopt_glb(buildings[:2]))):
        assert compression_used(split_glb(glb, name)[0])
        out = decompress_glb(glb, name)
        assert compression_used(split_glb(out, name)[0]) == []
        (tmp_path / name).write_bytes(glb)
        items = list(read_file(tmp_path / name))
        assert all(isinstance(m, RawMesh) for m in items)
        assert [len(m.faces) for m in items] == [len(b[2]) for b in buildings[:2]]


def test_draco_without_normals_and_with_feature_ids_of_tiles_1_1(tmp_path, buildings):
    (tmp_path / "t.glb").write_bytes(draco_glb(buildings[:3], feature="_FEATURE_ID_0", bits=16, with_normals=False))
    (tmp_path / "tileset.json").write_text(json.dumps({
        "asset": {"version": "1.1"}, "geometricError": 10,
        "root": {"boundingVolume": {"sphere": [0, 0, 0, 1000]}, "geometricError": 0, "content": {"uri": "t.glb"}}}))
    got = [m for m in read_file(tmp_path / "tileset.json")]
    assert [m.id.rsplit("#", 1)[1] for m in got] == ["0", "1", "2"]


def test_corrupt_and_unsupported_compression_is_refused_with_its_reason(tmp_path, buildings):
    """Every bad case ends as a rejection naming the file and the problem, never a crash."""
    good = draco_glb(buildings[:2])
    doc, binary = split_glb(good, "x")
    cut = join_glb(doc, binary[:len(binary) // 3])
    garbage = join_glb(doc, bytes(len(binary)))
    external = json.loads(json.dumps(doc))
    external["buffers"][0]["uri"] = "data.bin"
    packed = meshopt_glb(buildings[:2])
    pdoc, pbin = split_glb(packed, "x")
    bad_mode = json.loads(json.dumps(pdoc))
    bad_mode["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["mode"] = "SPLINES"
    bomb = json.loads(json.dumps(pdoc))
    bomb["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["count"] = 10**12
    cases = {
        "bomb.glb": (join_glb(bomb, pbin), "more than its buffer view's"),
        "cut.b3dm": (as_b3dm(cut, buildings[:2]), "beyond its"),
        "garbage.b3dm": (as_b3dm(garbage, buildings[:2]), "cannot be decoded"),
        "external.b3dm": (as_b3dm(join_glb(external, binary), buildings[:2]), "external buffer"),
        "mode.glb": (join_glb(bad_mode, pbin), "cannot be decoded"),
        "zeros.glb": (join_glb(pdoc, bytes(len(pbin))), "cannot be decoded"),
    }
    for name, (data, problem) in cases.items():
        (tmp_path / name).write_bytes(data)
        (item,) = list(read_file(tmp_path / name))
        assert isinstance(item, Rejection) and problem in item.reason and name in item.source, (name, item)
    with pytest.raises(InputFileError, match="cut.glb"):
        decompress_glb(cut, "cut.glb")
    # a glTF JSON file whose buffer is not there, or too short: said so
    missing = json.loads(json.dumps(doc))
    missing["buffers"][0]["uri"] = "nowhere.bin"
    (tmp_path / "missing.gltf").write_text(json.dumps(missing))
    (item,) = list(read_file(tmp_path / "missing.gltf"))
    assert isinstance(item, Rejection) and "nowhere.bin" in item.reason and "missing.gltf" in item.source, item
    (tmp_path / "short.bin").write_bytes(binary[:10])
    missing["buffers"][0]["uri"] = "short.bin"
    (tmp_path / "short.gltf").write_text(json.dumps(missing))
    (item,) = list(read_file(tmp_path / "short.gltf"))
    assert isinstance(item, Rejection) and "of 10 bytes, fewer than its byteLength" in item.reason, item
    # JSON of another shape than glTF's (buffer views that are numbers): a rejection, not a crash
    odd = {"asset": {"version": "2.0"}, "extensionsUsed": ["KHR_draco_mesh_compression"], "bufferViews": [1, 2],
           "buffers": [{"byteLength": 4, "uri": "data:application/octet-stream;base64,AAAAAA=="}]}
    (tmp_path / "odd.gltf").write_text(json.dumps(odd))
    (item,) = list(read_file(tmp_path / "odd.gltf"))
    assert isinstance(item, Rejection) and "laid out otherwise than its specification says" in item.reason, item


def _as_gltf(glb: bytes, folder, name: str, embed: bool) -> None:
    """A GLB written as a glTF JSON file and its buffer (a .bin beside it, or a base64 data URI)."""
    import base64

    doc, binary = split_glb(glb, name)
    doc["buffers"][0]["uri"] = ("data:application/octet-stream;base64," + base64.b64encode(binary).decode()
                                if embed else f"{name}.bin")
    if not embed:
        (folder / f"{name}.bin").write_bytes(binary)
    (folder / f"{name}.gltf").write_text(json.dumps(doc))


@pytest.mark.parametrize("embed", [False, True])
def test_gltf_json_files_and_content_read_as_their_glb(tmp_path, buildings, embed):
    """A glTF JSON file (its buffer beside it or in a data URI), compressed or not, reads as the same
    GLB: as a file (a compressed one was refused: "convert it with gltf-transform") and as 3D Tiles
    1.1 content (it was refused as "points, instances or a composite")."""
    glbs = {"plain": b3dm(buildings[:3], lambda v: v, glb_only=True), "draco": draco_glb(buildings[:3]),
            "meshopt": meshopt_glb(buildings[:3])}
    for name, glb in glbs.items():
        (tmp_path / f"{name}.glb").write_bytes(glb)
        _as_gltf(glb, tmp_path, name, embed)
        want, got = list(read_file(tmp_path / f"{name}.glb")), list(read_file(tmp_path / f"{name}.gltf"))
        assert len(got) == len(want) >= 1 and all(isinstance(m, RawMesh) for m in got), (name, got[:1])
        for a, b in zip(want, got):
            assert np.array_equal(_world(a), _world(b)) and np.array_equal(a.faces, b.faces), name
        (tmp_path / "tileset.json").write_text(json.dumps({
            "asset": {"version": "1.1"}, "geometricError": 100,
            "root": {"boundingVolume": {"sphere": [0, 0, 0, 1000]}, "geometricError": 0, "refine": "ADD",
                     "children": [{"boundingVolume": {"sphere": [0, 0, 0, 1000]}, "geometricError": 0,
                                   "content": {"uri": uri}} for uri in (f"{name}.glb", f"{name}.gltf")]}}))
        items = list(read_file(tmp_path / "tileset.json"))
        assert all(isinstance(m, RawMesh) for m in items) and len(items) == 6, (name, items[:1])
        by_content = {}
        for m in items:
            _, content, building = m.id.split("#")
            by_content.setdefault(content, {})[building] = m
        assert list(by_content[f"{name}.gltf"]) == list(by_content[f"{name}.glb"])
        for key, a in by_content[f"{name}.glb"].items():
            assert np.array_equal(_world(a), _world(by_content[f"{name}.gltf"][key])), (name, key)


@pytest.mark.parametrize("damage", ["meshes", "primitives", "attributes", "bufferView", "extension", "views"])
def test_malformed_compressed_json_is_an_input_error(buildings, damage):
    """JSON of other shapes than the specifications' (lists where objects belong, missing keys) is an
    InputFileError naming the file, never another exception."""
    doc, binary = split_glb(draco_glb(buildings[:1]), "x")
    primitive = doc["meshes"][0]["primitives"][0]
    if damage == "meshes":
        doc["meshes"] = {"0": doc["meshes"][0]}
    elif damage == "primitives":
        doc["meshes"][0]["primitives"] = [7]
    elif damage == "attributes":
        primitive["extensions"]["KHR_draco_mesh_compression"]["attributes"] = ["POSITION"]
    elif damage == "bufferView":
        primitive["extensions"]["KHR_draco_mesh_compression"]["bufferView"] = 9
    elif damage == "extension":
        primitive["extensions"]["KHR_draco_mesh_compression"] = []
    else:
        doc["bufferViews"] = [None]
    with pytest.raises(InputFileError, match="bad.glb"):
        decompress_glb(join_glb(doc, binary), "bad.glb")


def quantized_glb(buildings, component, normalized):
    """A GLB as gltfpack writes one with its positions quantized (KHR_mesh_quantization): 16-bit integers over the
    mesh's box, interleaved with padding (stride 8), the node's translation and scale taking them back to the
    positions; ``normalized`` (gltfpack -vpn) stores c standing for c / 65535 (unsigned) or c / 32767 (signed),
    else (-vpi) the integers themselves. Returns the GLB and the positions it stands for, float64."""
    v, f, ids = _plain(buildings)
    lo, hi = v.min(0).astype(np.float64), v.max(0).astype(np.float64)
    signed = component == "short"
    top = 32767 if signed else 65535
    unit = (np.arange(3) * 0 + 1) * (hi - lo).max() / (2 * top if signed else top)  # one step, the same on every axis
    origin = (lo + hi) / 2 if signed else lo
    q = np.round((v - origin) / unit).astype(np.int16 if signed else np.uint16)
    rows = np.zeros((len(q), 4), q.dtype)
    rows[:, :3] = q
    scale = unit * (top if normalized else 1)
    binary = rows.tobytes() + f.tobytes()
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": rows.nbytes, "byteStride": 8, "target": 34962},
             {"buffer": 0, "byteOffset": rows.nbytes, "byteLength": f.nbytes, "target": 34963}]
    stored = q.astype(np.float64) / (top if normalized else 1)
    accessors = [{"bufferView": 0, "componentType": 5122 if signed else USHORT, "normalized": normalized,
                  "count": len(q), "type": "VEC3", "min": stored.min(0).tolist(), "max": stored.max(0).tolist()},
                 {"bufferView": 1, "componentType": UINT, "count": f.size, "type": "SCALAR"}]
    doc = _document(["KHR_mesh_quantization"], accessors, views, [{"byteLength": len(binary)}], {"POSITION": 0}, 1)
    doc["nodes"][0].update(translation=origin.tolist(), scale=scale.tolist())
    return join_glb(doc, binary), q.astype(np.float64) * unit + origin


@pytest.mark.parametrize("component,normalized", [("ushort", True), ("short", True), ("ushort", False)])
def test_quantized_positions_read_as_the_positions_they_stand_for(tmp_path, buildings, component, normalized):
    """KHR_mesh_quantization (gltfpack's output for the web): positions as 16-bit integers, normalized or not, the
    node's scale and translation taking them back. Read as a .glb, and as a .gltf with its .bin beside it, the
    vertices are the positions the integers stand for (within float32's rounding) and the buildings keep their
    volume. Before, normalized integers were read as they are: a tile 65,535 times too large."""
    from meshsom.preprocess import preprocess

    glb, expected = quantized_glb(buildings[:3], component, normalized)
    (tmp_path / "q.glb").write_bytes(glb)
    _as_gltf(glb, tmp_path, "q", embed=False)
    plain = trimesh.Trimesh(expected, _plain(buildings[:3])[1], process=False)
    z_up = np.column_stack([expected[:, 0], -expected[:, 2], expected[:, 1]])  # glTF's y up, turned as it is read
    for path in (tmp_path / "q.glb", tmp_path / "q.gltf"):
        (m,) = read_file(path)
        assert isinstance(m, RawMesh), m
        assert np.allclose(_world(m), z_up, atol=1e-3 + 1e-6 * np.abs(expected).max()), path.name
        assert preprocess(m.vertices, m.faces).volume_out == pytest.approx(abs(plain.volume), rel=1e-4), path.name
