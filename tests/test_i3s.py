"""Esri scene layer packages (I3S 3D object layers): New York's DoITT buildings as ArcGIS Pro packs
them, and packages written here by the specification (1.7 node pages, 1.6 node index documents,
geographic and projected layers), checked against PROJ's own conversions."""

from __future__ import annotations

import gzip
import json
import struct
import zipfile

import numpy as np
import pytest

from conftest import DATA, box
from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, read_file

NYC = DATA / "nyc-i3s-da12" / "DA12_subset.slpk"


def _topocentric(lon, lat, h, origin):
    """East-north-up metres about ``origin`` (lon, lat, h) by PROJ's topocentric conversion."""
    import pyproj

    lon0, lat0, h0 = origin
    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x0, y0, z0 = to_ecef.transform(lon0, lat0, h0)
    topo = pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 +X_0={x0} +Y_0={y0} +Z_0={z0}")
    return np.column_stack(topo.transform(lon, lat, h))


def test_new_york_package_gives_every_feature_of_its_leaves_in_metres():
    """The 158 buildings of the DA12 package, one mesh each, with every triangle of the leaves; a
    building decoded here by hand from its node's buffer (its node page's centre, float32 degree
    offsets) and put in metres by PROJ is the reader's mesh within a millimetre."""
    from scipy.spatial import cKDTree

    items = list(read_file(NYC))
    assert all(isinstance(i, RawMesh) for i in items) and len(items) == 158
    assert len({i.id for i in items}) == 158 and items[0].id.startswith("DA12_subset.slpk#")
    with zipfile.ZipFile(NYC) as z:
        page = json.loads(gzip.decompress(z.read("nodepages/0.json.gz")))
        leaves = [n for n in page["nodes"] if not n.get("children")]
        assert sum(n["mesh"]["geometry"]["vertexCount"] for n in leaves) // 3 == sum(len(i.faces) for i in items) == 26907
        node = next(n for n in leaves if n["mesh"]["geometry"]["resource"] == 3)  # one feature, 156
        data = gzip.decompress(z.read("nodes/3/geometries/0.bin.gz"))
    count, features = struct.unpack_from("<II", data)
    assert (count, features) == (node["mesh"]["geometry"]["vertexCount"], 1)
    offsets = np.frombuffer(data, "<f4", 3 * count, 8).reshape(-1, 3).astype(float)
    world = offsets + node["obb"]["center"]
    mesh = next(i for i in items if i.id == "DA12_subset.slpk#156")
    expected = _topocentric(world[:, 0], world[:, 1], world[:, 2], mesh.origin)
    assert len(mesh.faces) == count // 3
    for a, b in ((mesh.vertices, expected), (expected, mesh.vertices)):
        assert cKDTree(b).query(a)[0].max() < 1e-3
    assert 140 < np.ptp(mesh.vertices[:, 2]) < 160  # a Lower Manhattan tower of about 150 m
    assert any("WGS 84" in n and "east-north-up" in n for n in mesh.notes)


def test_new_york_package_through_ingest(tmp_path):
    """`meshsom ingest` on the package: every building accounted for, 157 of 158 closed."""
    from meshsom.store import read_manifest
    from pipelines.cli import main

    main(["ingest", str(NYC), "--out", str(tmp_path / "nyc.zarr")])
    records = read_manifest(tmp_path / "nyc.zarr")["records"]
    assert len(records) == 158 and sum(r["status"] == "accepted" for r in records) == 157


# ----------------------------------------------------------------------------- packages written here


def _buffer(features: list[tuple[int, np.ndarray]], centre: np.ndarray) -> bytes:
    """An uncompressed I3S geometry buffer: header, position, normal, uv0, color, featureId, faceRange."""
    triangles = np.concatenate([t for _, t in features])
    n = 3 * len(triangles)
    out = struct.pack("<II", n, len(features))
    out += (triangles.reshape(-1, 3) - centre).astype("<f4").tobytes()
    out += np.zeros((n, 3), "<f4").tobytes() + np.zeros((n, 2), "<f4").tobytes() + np.full((n, 4), 255, "u1").tobytes()
    out += np.array([fid for fid, _ in features], "<u8").tobytes()
    first = np.cumsum([0] + [len(t) for _, t in features])
    out += np.array([[a, b - 1] for a, b in zip(first[:-1], first[1:])], "<u4").tobytes()
    return out


LAYOUT = {"offset": 8, "position": {"type": "Float32", "component": 3}, "normal": {"type": "Float32", "component": 3},
          "uv0": {"type": "Float32", "component": 2}, "color": {"type": "UInt8", "component": 4},
          "featureId": {"type": "UInt64", "component": 1, "binding": "per-feature"},
          "faceRange": {"type": "UInt32", "component": 2, "binding": "per-feature"}}
LEGACY = {"geometryType": "triangles", "header": [{"property": "vertexCount", "type": "UInt32"},
                                                  {"property": "featureCount", "type": "UInt32"}],
          "ordering": ["position", "normal", "uv0", "color"],
          "vertexAttributes": {"position": {"valueType": "Float32", "valuesPerElement": 3},
                               "normal": {"valueType": "Float32", "valuesPerElement": 3},
                               "uv0": {"valueType": "Float32", "valuesPerElement": 2},
                               "color": {"valueType": "UInt8", "valuesPerElement": 4}},
          "featureAttributeOrder": ["id", "faceRange"],
          "featureAttributes": {"id": {"valueType": "UInt64", "valuesPerElement": 1},
                                "faceRange": {"valueType": "UInt32", "valuesPerElement": 2}}}


#: ArcGIS Pro's i3s-scale_x and i3s-scale_y for a geographic layer: degrees per equatorial metre.
I3S_SCALE = 1 / 111319.49079327357
DRACO_ONLY = [{"compressedAttributes": {"encoding": "draco", "attributes": ["position", "feature-index"]}}]


def _varint(n: int) -> bytes:
    out = b""
    while True:
        out += bytes([(n & 0x7F) | (0x80 if n > 0x7F else 0)])
        n >>= 7
        if not n:
            return out


def _metadata(entries: dict[str, bytes]) -> bytes:
    """One Draco metadata as Draco's MetadataEncoder writes it: entries, then no sub-metadata."""
    out = _varint(len(entries))
    for key, value in entries.items():
        out += bytes([len(key)]) + key.encode() + _varint(len(value)) + value
    return out + _varint(0)


def draco_with_metadata(points, faces, generic: dict[int, np.ndarray], position_entries: dict[str, bytes],
                        attribute_entries: dict[int, dict[str, bytes]], geometry_entries=None) -> bytes:
    """A Draco mesh encoded by Google's encoder (DracoPy, edgebreaker, 20 bits) with the given
    metadata written in after its header, as Draco's encoder places it (DracoPy can write
    attribute names only). ``generic`` and ``attribute_entries`` are keyed by unique id."""
    import DracoPy

    plain = DracoPy.encode(np.asarray(points, np.float32), np.asarray(faces, np.uint32), quantization_bits=20,
                           generic_attributes=generic)
    assert plain[:5] == b"DRACO" and int.from_bytes(plain[9:11], "little") == 0, plain[:11]
    (position,) = [a["unique_id"] for a in DracoPy.decode(plain).attributes if a["attribute_type"] == 0]
    by_attribute = {position: position_entries, **attribute_entries}
    section = _varint(len(by_attribute)) + b"".join(_varint(k) + _metadata(v) for k, v in by_attribute.items())
    section += _metadata(geometry_entries or {})
    return plain[:9] + (0x8000).to_bytes(2, "little") + section + plain[11:]


def _draco_buffer(features: list[tuple[int, np.ndarray]], centre: np.ndarray, geographic: bool) -> bytes:
    """A Draco geometry buffer as ArcGIS Pro writes one: positions about the node's centre (x and y
    divided by ``i3s-scale_x``/``_y`` where geographic), a feature index per vertex, the ids in its metadata."""
    triangles = np.concatenate([t for _, t in features]).reshape(-1, 3) - centre
    scale = I3S_SCALE if geographic else 1.0
    triangles[:, :2] /= scale
    index = np.repeat(np.arange(len(features), dtype=np.uint32), [3 * len(t) for _, t in features])[:, None]
    return draco_with_metadata(
        triangles, np.arange(len(triangles)).reshape(-1, 3), {5: index},
        {"i3s-scale_x": struct.pack("<d", scale), "i3s-scale_y": struct.pack("<d", scale)},
        {5: {"i3s-feature-ids": np.array([f for f, _ in features], "<i4").tobytes(), "i3s-attribute-type": b"feature-index"}})


def write_slpk(path, leaves, version="1.7", wkid=4326, height_unit="meter", layer_type="3DObject", buffers=None):
    """A scene layer package of a root and one leaf per item of ``leaves`` (each a list of
    ``(feature id, triangles (T, 3, 3) in the CRS's units)``), laid out as ArcGIS Pro writes I3S
    ``version`` (1.7: node pages; 1.6: node index documents and the default geometry schema).
    With ``buffers=DRACO_ONLY`` each leaf's geometry is one Draco buffer (``geometries/0``)."""
    def gz(obj):
        return gzip.compress(json.dumps(obj).encode() if not isinstance(obj, bytes) else obj)

    layer = {"layerType": layer_type, "spatialReference": {"wkid": wkid}, "heightModelInfo": {"heightUnit": height_unit},
             "store": {"version": version, "rootNode": "./nodes/root"}}
    if version == "1.7":
        layer["geometryDefinitions"] = [{"geometryBuffers": buffers if buffers is not None else [
            LAYOUT, {"compressedAttributes": {"encoding": "draco", "attributes": ["position"]}}]}]
    else:
        layer["store"]["defaultGeometrySchema"] = LEGACY
    centres = [np.concatenate([t for _, t in leaf]).reshape(-1, 3).mean(axis=0) for leaf in leaves]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        z.writestr("3dSceneLayer.json.gz", gz(layer))
        z.writestr("metadata.json", json.dumps({"I3SVersion": version}))
        if version == "1.7":
            nodes = [{"index": 0, "obb": {"center": np.mean(centres, axis=0).tolist()}, "children": list(range(1, len(leaves) + 1))}]
            nodes += [{"index": k + 1, "parentIndex": 0, "obb": {"center": c.tolist(), "halfSize": [1, 1, 1], "quaternion": [0, 0, 0, 1]},
                       "mesh": {"geometry": {"definition": 0, "resource": k, "vertexCount": 0, "featureCount": 0}}}
                      for k, c in enumerate(centres)]
            z.writestr("nodepages/0.json.gz", gz({"nodes": nodes}))
        else:
            z.writestr("nodes/root/3dNodeIndexDocument.json.gz", gz(
                {"id": "root", "mbs": [*np.mean(centres, axis=0), 100.0],
                 "children": [{"id": str(k), "href": f"../{k}"} for k in range(len(leaves))]}))
        for k, (leaf, c) in enumerate(zip(leaves, centres)):
            if version != "1.7":
                z.writestr(f"nodes/{k}/3dNodeIndexDocument.json.gz", gz(
                    {"id": str(k), "mbs": [*c, 50.0], "geometryData": [{"href": "./geometries/0"}]}))
            data = _draco_buffer(leaf, c, wkid == 4326) if buffers is DRACO_ONLY else _buffer(leaf, c)
            z.writestr(f"nodes/{k}/geometries/0.bin.gz", gz(data))


def _box_triangles(sx, sy, sz, at=(0.0, 0.0, 0.0)) -> np.ndarray:
    v, f = box(sx, sy, sz)
    return (v + at)[f]  # (12, 3, 3)


def _to_degrees(enu: np.ndarray, origin) -> np.ndarray:
    """East-north-up metres about ``origin`` (lon, lat, h) as lon, lat, h, by PROJ."""
    import pyproj

    lon0, lat0, h0 = origin
    x0, y0, z0 = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(lon0, lat0, h0)
    topo = pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 +X_0={x0} +Y_0={y0} +Z_0={z0}")
    flat = enu.reshape(-1, 3)
    return np.column_stack(topo.transform(*flat.T, direction="INVERSE")).reshape(enu.shape)


@pytest.mark.parametrize("version", ["1.7", "1.6"])
def test_a_package_written_by_the_specification_reads_back_in_metres(tmp_path, version):
    """Boxes of 10 x 6 x 4 m (offsets in float32 degrees about their node's centre) read back as
    10 x 6 x 4 m; a feature whose triangles lie in two leaves is one mesh, noted; the root's
    coarser copy is not read."""
    origin = (-74.0105, 40.7128, 5.0)
    a = _to_degrees(_box_triangles(10, 6, 4), origin)
    b = _to_degrees(_box_triangles(10, 6, 4, at=(40.0, 0, 0)), origin)
    leaves = [[(7, a), (9, b[:6])], [(9, b[6:])]]
    write_slpk(tmp_path / "two.slpk", leaves, version=version)
    items = list(read_file(tmp_path / "two.slpk"))
    assert [i.id for i in items] == ["two.slpk#7", "two.slpk#9"] and all(isinstance(i, RawMesh) for i in items)
    for item in items:
        assert len(item.faces) == 12 and len(item.vertices) == 8
        np.testing.assert_allclose(np.ptp(item.vertices, axis=0), [10, 6, 4], atol=1e-3)
    assert any("2 leaf nodes" in n for n in items[1].notes) and not any("leaf nodes" in n for n in items[0].notes)


def test_a_projected_package_in_feet_is_scaled_to_metres(tmp_path):
    """New York's State Plane in US survey feet (EPSG:2263) with heights in feet: a box of
    30 x 20 x 12 ft reads as 9.144 x 6.096 x 3.658 m (the survey foot: 1200/3937 m)."""
    at = (980000.0, 200000.0, 30.0)
    write_slpk(tmp_path / "ft.slpk", [[(1, _box_triangles(30, 20, 12, at))]], wkid=2263, height_unit="us-foot")
    (item,) = read_file(tmp_path / "ft.slpk")
    np.testing.assert_allclose(np.ptp(item.vertices, axis=0), np.array([30, 20, 12]) * 1200 / 3937, rtol=1e-6)
    np.testing.assert_allclose(item.origin, np.array(at) + [15, 10, 6], rtol=1e-9)


@pytest.mark.parametrize("change, says", [
    ({"layer_type": "IntegratedMesh"}, "an integrated mesh is one surface"),
    ({"layer_type": "Building"}, "building scene layer"),
    ({"buffers": [{"compressedAttributes": {"encoding": "lepcc-xyz", "attributes": ["position"]}}]},
     "compressed as lepcc-xyz only; expected an uncompressed geometry buffer or a Draco-compressed one"),
    ({"height_unit": "furlong"}, "heights are in 'furlong'"),
    ({"wkid": 999999}, "not known to pyproj"),
])
def test_a_package_that_cannot_be_read_says_why(tmp_path, change, says):
    write_slpk(tmp_path / "x.slpk", [[(1, _to_degrees(_box_triangles(10, 6, 4), (4.35, 52.0, 0.0)))]], **change)
    items = list(read_file(tmp_path / "x.slpk"))
    assert len(items) == 1 and isinstance(items[0], Rejection) and says in items[0].reason, items
    assert items[0].source == str(tmp_path / "x.slpk")


def test_a_corrupt_package_is_a_rejection_naming_the_resource(tmp_path):
    """A faceRange beyond the buffer's triangles, a truncated buffer (each a rejection of its node,
    the other nodes read), and a file that is no zip."""
    triangles = _to_degrees(_box_triangles(10, 6, 4), (4.35, 52.0, 0.0))
    write_slpk(tmp_path / "ok.slpk", [[(1, triangles)]])
    with zipfile.ZipFile(tmp_path / "ok.slpk") as z:
        members = {n: z.read(n) for n in z.namelist()}
    data = bytearray(gzip.decompress(members["nodes/0/geometries/0.bin.gz"]))
    for name, broken in (("range", data[:-4] + struct.pack("<I", 99)), ("short", data[:100])):
        with zipfile.ZipFile(tmp_path / f"{name}.slpk", "w") as z:
            for n, content in members.items():
                z.writestr(n, gzip.compress(bytes(broken)) if n == "nodes/0/geometries/0.bin.gz" else content)
    (tmp_path / "not.slpk").write_bytes(b"PK but not really")
    reasons = {p: next(read_file(tmp_path / f"{p}.slpk")).reason for p in ("range", "short", "not")}
    assert "nodes/0/geometries/0: feature 1's faceRange [0, 99] is outside its 12 triangles" in reasons["range"], reasons
    assert "nodes/0/geometries/0" in reasons["short"] and "ends before its" in reasons["short"], reasons
    assert "cannot be read as a scene layer package" in reasons["not"]
    write_slpk(tmp_path / "two.slpk", [[(1, triangles)], [(2, triangles + [0.001, 0, 0])]])
    with zipfile.ZipFile(tmp_path / "two.slpk") as z:
        members = {n: z.read(n) for n in z.namelist() if n != "nodes/1/geometries/0.bin.gz"}
    with zipfile.ZipFile(tmp_path / "lost.slpk", "w") as z:
        for n, content in members.items():
            z.writestr(n, content)
    lost, kept = read_file(tmp_path / "lost.slpk")
    assert lost.id == "lost.slpk#node 1" and "does not hold nodes/1/geometries/0" in lost.reason, lost
    assert isinstance(kept, RawMesh) and kept.id == "lost.slpk#1"


def test_a_folder_reads_its_packages(tmp_path):
    (tmp_path / "in").mkdir()
    write_slpk(tmp_path / "in" / "a.slpk", [[(1, _to_degrees(_box_triangles(10, 6, 4), (4.35, 52.0, 0.0)))]])
    files, rejected = expand_inputs([tmp_path / "in"])
    assert [f.name for f in files] == ["a.slpk"] and not rejected
    (item,) = read_file(files[0].path, ReaderOptions(), files[0].name)
    assert item.id == "a.slpk#1"


def test_labels_come_from_the_layers_attribute_buffers():
    """``label_attribute`` names a stored attribute: OBJECTID, stored apart from the geometry, is
    every feature's id (the buffers agree on the features' order); BIN is New York's building
    number (seven digits, 1 for Manhattan); SOURCE_ID is a Float64 written whole."""
    import dataclasses

    for attribute in ("OBJECTID", "BIN", "SOURCE_ID"):
        items = list(read_file(NYC, dataclasses.replace(ReaderOptions(), label_attribute=attribute)))
        assert len(items) == 158 and all(i.label is not None for i in items)
        if attribute == "OBJECTID":
            assert all(i.label == i.id.split("#")[1] for i in items)
        elif attribute == "BIN":
            assert all(len(i.label) == 7 and i.label.startswith("1") for i in items), [i.label for i in items][:5]
        else:
            assert all(i.label.isdigit() for i in items), [i.label for i in items][:5]
    assert all(i.label is None for i in read_file(NYC))  # the default, "family", is not stored


def test_string_labels_are_read_after_their_byte_counts(tmp_path):
    """A String attribute (I3S: a count, each value's byte count, then the values, each ended by a
    zero byte) labels the features of its node in the geometry's order."""
    triangles = _to_degrees(_box_triangles(10, 6, 4), (4.35, 52.0, 0.0))
    write_slpk(tmp_path / "s.slpk", [[(5, triangles), (8, triangles + [0.001, 0, 0])]])
    names = [b"h\xc3\xb4tel\0", b"school\0"]
    buffer = struct.pack("<I", 2) + struct.pack("<2I", *map(len, names)) + b"".join(names)
    with zipfile.ZipFile(tmp_path / "s.slpk") as z:
        members = {n: z.read(n) for n in z.namelist()}
    layer = json.loads(gzip.decompress(members["3dSceneLayer.json.gz"]))
    layer["attributeStorageInfo"] = [{"key": "f_0", "name": "family", "header": [{"property": "count", "valueType": "UInt32"}],
                                      "ordering": ["attributeByteCounts", "attributeValues"],
                                      "attributeByteCounts": {"valueType": "UInt32", "valuesPerElement": 1},
                                      "attributeValues": {"valueType": "String", "valuesPerElement": 1}}]
    members["3dSceneLayer.json.gz"] = gzip.compress(json.dumps(layer).encode())
    members["nodes/0/attributes/f_0/0.bin.gz"] = gzip.compress(buffer)
    with zipfile.ZipFile(tmp_path / "s.slpk", "w") as z:
        for n, content in members.items():
            z.writestr(n, content)
    assert [(i.id, i.label) for i in read_file(tmp_path / "s.slpk")] == [("s.slpk#5", "h\u00f4tel"), ("s.slpk#8", "school")]


# ----------------------------------------------------------------------------- Draco-compressed geometry


def _draco_only_copy(source, target):
    """``source`` as a package of Draco geometry only: its Draco buffers (``geometries/1``, as ArcGIS
    Pro wrote them) become each node's only geometry (``geometries/0``) and the layer declares only them."""
    with zipfile.ZipFile(source) as z, zipfile.ZipFile(target, "w", zipfile.ZIP_STORED) as out:
        for name in z.namelist():
            if "/geometries/0" in name:
                continue
            data = z.read(name)
            if name == "3dSceneLayer.json.gz":
                layer = json.loads(gzip.decompress(data))
                (definition,) = layer["geometryDefinitions"]
                definition["geometryBuffers"] = [b for b in definition["geometryBuffers"] if "compressedAttributes" in b]
                assert definition["geometryBuffers"][0]["compressedAttributes"]["encoding"] == "draco"
                data = gzip.compress(json.dumps(layer).encode())
            out.writestr(name.replace("/geometries/1", "/geometries/0"), data)


def test_new_york_package_read_from_its_draco_buffers_alone(tmp_path):
    """ArcGIS Pro wrote DA12 with each node's geometry twice, plain and Draco-compressed. Read from
    the Draco buffers alone (positions scaled by their i3s-scale metadata, triangles to features by
    the feature-index attribute and i3s-feature-ids), every building has the triangles of its plain
    read, every corner within a millimetre of it, and the stored OBJECTIDs still label each feature."""
    import dataclasses

    from scipy.spatial import cKDTree

    _draco_only_copy(NYC, tmp_path / "DA12_subset.slpk")
    options = dataclasses.replace(ReaderOptions(), label_attribute="OBJECTID")
    plain = {i.id: i for i in read_file(NYC, options)}
    draco = {i.id: i for i in read_file(tmp_path / "DA12_subset.slpk", options)}
    assert len(draco) == 158 and set(draco) == set(plain) and all(isinstance(i, RawMesh) for i in draco.values())
    for key, a in plain.items():
        b = draco[key]
        assert len(b.faces) == len(a.faces) and b.label == a.label == key.split("#")[1]
        assert (abs(b.origin - a.origin) < [1e-8, 1e-8, 1e-3]).all(), (b.origin, a.origin)  # degrees, degrees, metres
        for x, y in ((a.vertices, b.vertices), (b.vertices, a.vertices)):
            assert cKDTree(y).query(x)[0].max() < 1e-3, key
        area = lambda m: np.linalg.norm(np.cross(*(m.vertices[m.faces[:, 1:]] - m.vertices[m.faces[:, :1]]).transpose(1, 0, 2)), axis=1).sum()
        assert abs(area(b) - area(a)) < 1e-4 * area(a), key
        assert any("Draco-compressed" in n for n in b.notes) and not any("Draco" in n for n in a.notes)


def test_a_node_without_its_plain_buffer_is_read_from_its_draco_buffer(tmp_path):
    """A package whose layer declares both buffers but one node holds only the Draco one: that node
    is decoded, the others read plain."""
    with zipfile.ZipFile(NYC) as z, zipfile.ZipFile(tmp_path / "mixed.slpk", "w") as out:
        for name in z.namelist():
            if name != "nodes/3/geometries/0.bin.gz":
                out.writestr(name, z.read(name))
    items = {i.id: i for i in read_file(tmp_path / "mixed.slpk")}
    assert len(items) == 158
    decoded = [k for k, i in items.items() if any("Draco" in n for n in i.notes)]
    assert decoded == ["mixed.slpk#156"]  # node 3's one feature


@pytest.mark.parametrize("wkid", [4326, 2263])
def test_a_draco_package_written_by_the_specification_reads_back_in_metres(tmp_path, wkid):
    """Draco buffers written by Google's encoder with I3S's metadata: boxes of 10 x 6 x 4 m (x and y
    scaled by i3s-scale where geographic) read back as such; a feature split across two leaves is one
    closed mesh of 8 corners."""
    if wkid == 4326:
        origin = (-74.0105, 40.7128, 5.0)
        a = _to_degrees(_box_triangles(10, 6, 4), origin)
        b = _to_degrees(_box_triangles(10, 6, 4, at=(40.0, 0, 0)), origin)
        size = [10, 6, 4]
    else:  # New York's State Plane in US survey feet
        a = _box_triangles(10, 6, 4, (980000.0, 200000.0, 30.0))
        b = _box_triangles(10, 6, 4, (980040.0, 200000.0, 30.0))
        size = np.array([10, 6, 4]) * 1200 / 3937
    write_slpk(tmp_path / "d.slpk", [[(7, a), (9, b[:5])], [(9, b[5:])]], wkid=wkid,
               height_unit="meter" if wkid == 4326 else "us-foot", buffers=DRACO_ONLY)
    items = list(read_file(tmp_path / "d.slpk"))
    assert [i.id for i in items] == ["d.slpk#7", "d.slpk#9"] and all(isinstance(i, RawMesh) for i in items), items
    for item in items:
        assert len(item.faces) == 12 and len(item.vertices) == 8
        np.testing.assert_allclose(np.ptp(item.vertices, axis=0), size, atol=1e-3)
    assert any("2 leaf nodes" in n for n in items[1].notes)


def _draco_package(tmp_path, data: bytes):
    """A one-leaf Draco-only package whose geometry is ``data``."""
    triangles = _to_degrees(_box_triangles(10, 6, 4), (4.35, 52.0, 0.0))
    write_slpk(tmp_path / "x.slpk", [[(1, triangles)]], buffers=DRACO_ONLY)
    with zipfile.ZipFile(tmp_path / "x.slpk") as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["nodes/0/geometries/0.bin.gz"] = gzip.compress(data)
    with zipfile.ZipFile(tmp_path / "x.slpk", "w") as z:
        for n, content in members.items():
            z.writestr(n, content)
    return list(read_file(tmp_path / "x.slpk"))


def test_draco_geometry_that_cannot_be_read_is_a_rejection_of_its_node(tmp_path):
    """No feature ids, a feature index beyond them, metadata cut short, bytes that are no Draco:
    each the node's rejection naming its resource and the problem."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    index = {5: np.zeros((4, 1), np.uint32)}
    scale = {"i3s-scale_x": struct.pack("<d", I3S_SCALE), "i3s-scale_y": struct.pack("<d", I3S_SCALE)}
    no_ids = draco_with_metadata(v, f, index, scale, {5: {"i3s-attribute-type": b"feature-index"}})
    beyond = draco_with_metadata(v, f, {5: np.full((4, 1), 3, np.uint32)}, scale,
                                 {5: {"i3s-feature-ids": np.array([1, 2], "<i4").tobytes(), "i3s-attribute-type": b"feature-index"}})
    cut = draco_with_metadata(v, f, index, scale, {5: {"i3s-feature-ids": np.array([1], "<i4").tobytes()}})[:40]
    cases = {"ids": (no_ids, "holds Draco triangles of no feature (no i3s-feature-ids metadata)"),
             "beyond": (beyond, "4 Draco triangles have a feature index outside the 2 i3s-feature-ids (e.g. 3)"),
             "cut": (cut, "the metadata ends inside"),
             "noise": (b"DRACO\x02\x02\x01\x01\x00\x00" + bytes(range(40)), "cannot be decoded by Draco"),
             "other": (b"glTF" + bytes(40), "is not a Draco bitstream")}
    for key, (data, says) in cases.items():
        (item,) = _draco_package(tmp_path, data)
        assert isinstance(item, Rejection) and item.id == "x.slpk#node 0", (key, item)
        assert "nodes/0/geometries/0" in item.reason and says in item.reason, (key, item.reason)
    good = draco_with_metadata(v, f, index, scale, {5: {"i3s-feature-ids": np.array([4], "<i4").tobytes(),
                                                        "i3s-attribute-type": b"feature-index"}})
    (item,) = _draco_package(tmp_path, good)
    assert isinstance(item, RawMesh) and item.id == "x.slpk#4" and len(item.faces) == 4
