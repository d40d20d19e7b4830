"""Buildings from 3D Tiles (meshsom.tiles3d): b3dm files and tilesets.

The fixtures are written here as the 3D Tiles 1.0 specification lays them out: buildings of the
bundled Delft file, drawn in metres, placed on the WGS 84 ellipsoid by PROJ (independent of
meshsom's geodesy) as earth-centred coordinates, turned y up for glTF, batched by ``_BATCHID``.
Each must read back as the same building moved rigidly: the same volume and distances, to the
float32 precision of glTF positions.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyproj
import pytest
import trimesh

from meshsom.crs import WGS84, east_north_up_of_geocentric, geodetic
from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, read_file

DELFT = Path(__file__).resolve().parents[1] / "data/real/delft-lod1-3dfier/delft.city.json"
CENTRE = (52.0116, 4.3571, 0.0)  # latitude, longitude, height of the local frame's origin


def _ecef(enu):
    """ECEF of points given east-north-up about CENTRE (PROJ)."""
    lat0, lon0, h0 = CENTRE
    t = pyproj.Transformer.from_pipeline(f"+proj=topocentric +lat_0={lat0} +lon_0={lon0} +h_0={h0} +ellps=WGS84")
    x, y, z = t.transform(enu[:, 0], enu[:, 1], enu[:, 2], direction="INVERSE")
    return np.column_stack([x, y, z])


def _buildings(n=12):
    """(id, local vertices in metres about the district's centre, faces) of Delft buildings."""
    meshes = [m for m in read_file(DELFT) if isinstance(m, RawMesh)][:n]
    centre = np.mean([m.origin for m in meshes], axis=0)
    return [(m.id.split("#", 1)[1], m.vertices + m.origin - centre, m.faces) for m in meshes]


def _pad(data: bytes, fill: bytes = b" ") -> bytes:
    return data + fill * (-len(data) % 8)


def b3dm(buildings, positions, rtc=None, extra_gltf=None, batch_table=None, glb_only=False, id_bits=None):
    """A b3dm of one glTF mesh whose vertices carry their building's ``_BATCHID``.

    ``positions(vertices)`` gives each building's z-up positions (before ``rtc``) in the tile;
    ``glb_only``: 3D Tiles 1.1 glTF content instead, the ids in ``_FEATURE_ID_0``; ``id_bits``: the ids as
    Draco's quantization of a generic attribute to that many bits decodes them (the range in 2^bits - 1 steps)."""
    vertices, faces, batch = [], [], []
    offset = 0
    for k, (_, v, f) in enumerate(buildings):
        p = positions(v)
        vertices.append(p)
        faces.append(f + offset)
        batch.append(np.full(len(p), k, np.float32))
        offset += len(p)
    v = np.concatenate(vertices)
    if rtc is not None:
        v = v - rtc
    y_up = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]])  # z up -> glTF's y up
    mesh = trimesh.Trimesh(y_up, np.concatenate(faces), process=False)
    ids = np.concatenate(batch)
    if id_bits is not None:
        step = np.float32((len(buildings) - 1) / (2 ** id_bits - 1))
        ids = (np.rint(ids / step) * step).astype(np.float32)
    mesh.vertex_attributes["_FEATURE_ID_0" if glb_only else "_BATCHID"] = ids
    glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh), include_normals=False)
    if glb_only:
        return glb
    if extra_gltf:  # rewrite the glTF JSON chunk (e.g. to declare an extension)
        size = struct.unpack_from("<I", glb, 12)[0]
        doc = json.loads(glb[20:20 + size]) | extra_gltf
        chunk = _pad(json.dumps(doc).encode())
        rest = glb[20 + size:]
        glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(chunk) + len(rest)) + struct.pack("<I4s", len(chunk), b"JSON") + chunk + rest
    feature = {"BATCH_LENGTH": len(buildings)}
    if rtc is not None:
        feature["RTC_CENTER"] = [float(c) for c in rtc]
    ft = _pad(json.dumps(feature).encode())
    bt = _pad(json.dumps(batch_table if batch_table is not None else
                         {"id": [b[0] for b in buildings], "family": [f"f{k % 3}" for k in range(len(buildings))]}).encode())
    body = ft + bt + glb
    return b"b3dm" + struct.pack("<6I", 1, 28 + len(body), len(ft), 0, len(bt), 0) + body


def _signed_volume(v, f):
    """The signed volume the triangles enclose (divergence theorem), repairs aside."""
    a, b, c = (v[f[:, k]] - v.mean(axis=0) for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def _distances(v):
    return np.linalg.norm(v[:, None] - v[None], axis=2)


def _same_building(got, want_vertices, want_faces, atol=2e-3):
    """Rigidly the same: volumes, vertex distances and height (z up). (Not preprocessed: its repairs
    of these LoD1 meshes may decide otherwise on float32 positions.)"""
    assert got.faces.shape == want_faces.shape
    assert _signed_volume(got.vertices, got.faces) == pytest.approx(_signed_volume(want_vertices, want_faces), rel=1e-5)
    assert np.allclose(_distances(got.vertices), _distances(want_vertices), atol=atol)
    assert np.ptp(got.vertices[:, 2]) == pytest.approx(np.ptp(want_vertices[:, 2]), abs=1e-2)


def test_geodesy_against_proj():
    rng = np.random.default_rng(3)
    for lat, lon, h in [(52.0116, 4.3571, 45.0), (-33.87, 151.21, 800.0), (64.1, -21.9, 10.0), (0.1, 179.95, -20.0)]:
        centre = np.array(pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978").transform(lat, lon, h))
        assert geodetic(centre[None], *WGS84)[0] == pytest.approx([lat, lon, h], abs=1e-9)
        points = centre + rng.uniform(-300, 300, (50, 3))
        t = pyproj.Transformer.from_pipeline(f"+proj=topocentric +X_0={centre[0]} +Y_0={centre[1]} +Z_0={centre[2]} +ellps=WGS84")
        want = np.column_stack(t.transform(points[:, 0], points[:, 1], points[:, 2]))
        assert np.allclose(east_north_up_of_geocentric(points, centre), want, atol=1e-6)


def test_b3dm_in_earth_centred_coordinates(tmp_path):
    buildings = _buildings()
    ecef = [_ecef(v) for _, v, _ in buildings]
    rtc = np.mean(np.concatenate(ecef), axis=0)
    lookup = {id(v): e for (_, v, _), e in zip(buildings, ecef)}
    (tmp_path / "tile.b3dm").write_bytes(b3dm(buildings, lambda v: lookup[id(v)], rtc=rtc))
    got = {m.id: m for m in read_file(tmp_path / "tile.b3dm")}
    assert list(got) == [f"tile.b3dm#{b[0]}" for b in buildings]
    for k, (bid, v, f) in enumerate(buildings):
        m = got[f"tile.b3dm#{bid}"]
        assert m.label == f"f{k % 3}" and "earth-centred" in m.notes[0]
        _same_building(m, v, f)
        assert np.linalg.norm(m.origin - ecef[k].mean(axis=0)) < 50  # its world position: earth-centred


def test_tileset_walks_transforms_refinement_and_external_tilesets(tmp_path):
    """As Cesium tilesets are laid out: the root's transform places an east-north-up frame on the
    earth; a coarse tile is replaced by its children, an ADD tile's content is kept, an external
    tileset is followed with the transforms above it; point clouds and links outside are listed."""
    buildings = _buildings(9)
    lat0, lon0, h0 = CENTRE
    origin = _ecef(np.zeros((1, 3)))[0]
    lat, lon = np.radians(lat0), np.radians(lon0)
    enu_to_ecef = np.eye(4)
    enu_to_ecef[:3, :3] = np.array([[-np.sin(lon), -np.sin(lat) * np.cos(lon), np.cos(lat) * np.cos(lon)],
                                    [np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat) * np.sin(lon)],
                                    [0.0, np.cos(lat), np.sin(lat)]])
    enu_to_ecef[:3, 3] = origin
    shift = np.eye(4)
    shift[:3, 3] = [100.0, 0.0, 0.0]  # a child tile moved 100 m east in the frame
    local = lambda v: v  # noqa: E731 (the tiles hold the frame's metres)
    (tmp_path / "sub").mkdir()
    (tmp_path / "coarse.b3dm").write_bytes(b3dm(buildings[:1], local))
    (tmp_path / "a.b3dm").write_bytes(b3dm(buildings[:3], local))
    (tmp_path / "b.b3dm").write_bytes(b3dm(buildings[3:6], local))
    (tmp_path / "sub" / "c.b3dm").write_bytes(b3dm(buildings[6:], local))
    (tmp_path / "p.pnts").write_bytes(b"pnts")
    (tmp_path / "sub" / "tileset.json").write_text(json.dumps(
        {"asset": {"version": "1.0"}, "geometricError": 0, "root": {"geometricError": 0, "content": {"uri": "c.b3dm"}}}))
    tileset = {"asset": {"version": "1.0"}, "geometricError": 100, "root": {
        "transform": enu_to_ecef.T.reshape(-1).tolist(), "geometricError": 100, "refine": "REPLACE",
        "content": {"uri": "coarse.b3dm"},
        "children": [
            {"geometricError": 0, "content": {"uri": "a.b3dm"}},
            {"geometricError": 10, "refine": "ADD", "transform": shift.T.reshape(-1).tolist(), "content": {"uri": "b.b3dm"},
             "children": [{"geometricError": 0, "content": {"uri": "sub/tileset.json"}}]},
            {"geometricError": 0, "content": {"uri": "p.pnts"}},
            {"geometricError": 0, "content": {"uri": "../outside.b3dm"}},
        ]}}
    (tmp_path / "tileset.json").write_text(json.dumps(tileset))
    items = list(read_file(tmp_path / "tileset.json"))
    got = {m.id: m for m in items}
    ids = [f"tileset.json#a.b3dm#{b[0]}" for b in buildings[:3]] + [f"tileset.json#b.b3dm#{b[0]}" for b in buildings[3:6]] + [
        f"tileset.json#sub/c.b3dm#{b[0]}" for b in buildings[6:]]
    assert sorted(m.id for m in items if isinstance(m, RawMesh)) == sorted(ids)  # no coarse.b3dm: replaced
    assert "only batched models" in got["tileset.json#p.pnts"].reason and ".pnts" in got["tileset.json#p.pnts"].reason
    assert "outside the tileset's folder" in got["tileset.json#../outside.b3dm"].reason
    for bid, v, f in buildings:
        (m,) = [m for m in items if m.id.endswith(f"#{bid}")]
        _same_building(m, v, f)
        assert "earth-centred" in m.notes[0]
    # the shifted tile's buildings lie 100 m east of where the frame puts them
    bid, v, _ = buildings[4]
    where = _ecef(v.mean(axis=0)[None] + [100.0, 0, 0])[0]
    assert np.linalg.norm(got[f"tileset.json#b.b3dm#{bid}"].origin - where) < 20
    # alone, a tile of the frame's metres is read as metres, with a note
    (lone,) = [m for m in read_file(tmp_path / "a.b3dm") if m.id.endswith(buildings[0][0])]
    assert "not earth-centred" in lone.notes[0]
    # a folder: the tileset is the input, its tiles are read through it
    skipped = []
    files, _ = expand_inputs([tmp_path], skipped)
    assert [f.name for f in files] == ["tileset.json"]
    assert {Path(p).name for p, why in skipped if "read through it" in why} == {
        "coarse.b3dm", "a.b3dm", "b.b3dm", "c.b3dm", "p.pnts", "tileset.json"}


def test_tiles_1_1_gltf_content_and_implicit_tiling(tmp_path):
    """3D Tiles 1.1: glTF content whose features are ``_FEATURE_ID_0``; an implicit tileset without its subtree is listed."""
    buildings = _buildings(3)
    ecef = {id(v): _ecef(v) for _, v, _ in buildings}
    rtc = _ecef(np.zeros((1, 3)))[0]
    (tmp_path / "t.glb").write_bytes(b3dm(buildings, lambda v: ecef[id(v)] - rtc, glb_only=True))
    move = np.eye(4)
    move[:3, 3] = rtc
    (tmp_path / "tileset.json").write_text(json.dumps({"asset": {"version": "1.1"}, "geometricError": 0, "root": {
        "geometricError": 0, "transform": move.T.reshape(-1).tolist(), "content": {"uri": "t.glb"}}}))
    got = list(read_file(tmp_path / "tileset.json"))
    assert [m.id for m in got] == [f"tileset.json#t.glb#{k}" for k in range(3)]  # no batch table: feature numbers
    for m, (_, v, f) in zip(got, buildings):
        _same_building(m, v, f)
    (tmp_path / "implicit.json").write_text(json.dumps({"asset": {"version": "1.1"}, "geometricError": 1, "root": {
        "geometricError": 1, "content": {"uri": "c/{level}_{x}_{y}.glb"},
        "implicitTiling": {"subdivisionScheme": "QUADTREE", "subtreeLevels": 2, "availableLevels": 2,
                           "subtrees": {"uri": "s/{level}.subtree"}}}}))
    (item,) = read_file(tmp_path / "implicit.json")  # its subtree is missing (implicit tiles: test_implicit_tiling.py)
    assert isinstance(item, Rejection) and item.id == "implicit.json#implicit tiling" and "s/0.subtree" in item.reason


def test_damaged_and_unreadable_tiles(tmp_path):
    buildings = _buildings(2)
    good = b3dm(buildings, lambda v: v)
    draco = b3dm(buildings, lambda v: v, extra_gltf={"extensionsUsed": ["KHR_draco_mesh_compression"]})
    draft = good[:20] + struct.pack("<II", 570425344, 0) + good[28:]
    # Draco declared, no primitive compressed: read as it is (compressed tiles: tests/test_gltf_compression.py)
    (tmp_path / "draco.b3dm").write_bytes(draco)
    assert [type(m).__name__ for m in read_file(tmp_path / "draco.b3dm")] == ["RawMesh", "RawMesh"]
    cases = {"cut.b3dm": (good[:-100], "cut short"),
             "draft.b3dm": (draft, "2016 draft"), "notb3dm.b3dm": (b"glTF" + good[4:], "is not a b3dm"),
             "badtable.b3dm": (good[:28] + b"#" + good[29:], "not JSON")}
    for name, (data, problem) in cases.items():
        (tmp_path / name).write_bytes(data)
        (item,) = list(read_file(tmp_path / name))
        assert isinstance(item, Rejection) and problem in item.reason, (name, item)
    # ids: repeated batch-table ids fall back to batch numbers
    (tmp_path / "same.b3dm").write_bytes(b3dm(buildings, lambda v: v, batch_table={"id": ["x", "x"]}))
    assert [m.id for m in read_file(tmp_path / "same.b3dm")] == ["same.b3dm#0", "same.b3dm#1"]
    # BATCH_LENGTH 0: one model, not batched (3D Tiles' sample building); batch ids beyond it are listed
    (tmp_path / "one.b3dm").write_bytes(b3dm(buildings[:1], lambda v: v, batch_table={}).replace(b'"BATCH_LENGTH": 1', b'"BATCH_LENGTH": 0'))
    (one,) = read_file(tmp_path / "one.b3dm")
    assert isinstance(one, RawMesh) and one.id == "one.b3dm#0"
    (tmp_path / "beyond.b3dm").write_bytes(b3dm(buildings, lambda v: v).replace(b'"BATCH_LENGTH": 2', b'"BATCH_LENGTH": 1'))
    first, beyond = read_file(tmp_path / "beyond.b3dm")
    assert isinstance(first, RawMesh) and "beyond BATCH_LENGTH 1" in beyond.reason


def test_tileset_through_meshsom_ingest(tmp_path):
    buildings = _buildings(4)
    folder = tmp_path / "tiles"
    folder.mkdir()
    ecef = {id(v): _ecef(v) for _, v, _ in buildings}
    (folder / "t.b3dm").write_bytes(b3dm(buildings, lambda v: ecef[id(v)], rtc=_ecef(np.zeros((1, 3)))[0]))
    (folder / "tileset.json").write_text(json.dumps(
        {"asset": {"version": "1.0"}, "geometricError": 0, "root": {"geometricError": 0, "content": {"uri": "t.b3dm"}}}))
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(folder), "--out", str(tmp_path / "t.zarr")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "4 meshes: 4 accepted, 0 rejected" in out.stdout, out.stdout


def _aligned(tile: bytes) -> bytes:
    """A tile padded to 8 bytes, its byteLength (bytes 8-12 of every tile's header) saying so."""
    tile = _pad(tile, b"\0")
    return tile[:8] + struct.pack("<I", len(tile)) + tile[12:]


def _composite(tiles: list[bytes]) -> bytes:
    body = b"".join(_aligned(t) for t in tiles)
    return b"cmpt" + struct.pack("<III", 1, 16 + len(body), len(tiles)) + body


def test_composite_tiles_read_their_batched_models(tmp_path):
    """A composite tile (cmpt: b3dm, i3dm and glb inside, a composite in it): its batched models are
    read (it was refused whole as "points, instances or a composite"), each instanced model is a
    rejection that says so; through a tileset and as a file."""
    buildings = _buildings(4)
    i3dm = b"i3dm" + struct.pack("<7I", 1, 40, 0, 0, 0, 0, 0) + b"\0" * 4
    composite = _composite([b3dm(buildings[:2], lambda v: v), i3dm,
                            _composite([b3dm(buildings[2:], lambda v: v, glb_only=True)])])
    (tmp_path / "c.cmpt").write_bytes(composite)
    (tmp_path / "tileset.json").write_text(json.dumps({"asset": {"version": "1.0"}, "geometricError": 0, "root": {
        "geometricError": 0, "content": {"uri": "c.cmpt"}}}))
    for path, prefix in ((tmp_path / "tileset.json", "tileset.json#c.cmpt#"), (tmp_path / "c.cmpt", "c.cmpt#")):
        got = list(read_file(path))
        assert [m.id for m in got] == [f"{prefix}0#{buildings[0][0]}", f"{prefix}0#{buildings[1][0]}", f"{prefix}1",
                                       f"{prefix}2#0", f"{prefix}2#1"]
        assert isinstance(got[2], Rejection) and "of type i3dm (points or instances)" in got[2].reason
        for m, (_, v, f) in zip(got[:2] + got[3:], buildings):
            _same_building(m, v, f)
    # glTF 1.0 (a GLB of version 1: 3d-tiles-tools' samples): its inner tile a rejection that says so, the others read
    old = bytearray(b3dm(buildings[:2], lambda v: v))
    at = bytes(old).index(b"glTF")
    old[at + 4:at + 8] = struct.pack("<I", 1)
    (tmp_path / "old.cmpt").write_bytes(_composite([bytes(old), i3dm, b3dm(buildings[2:], lambda v: v)]))
    got = list(read_file(tmp_path / "old.cmpt"))
    assert [m.id for m in got] == ["old.cmpt#0", "old.cmpt#1", f"old.cmpt#2#{buildings[2][0]}", f"old.cmpt#2#{buildings[3][0]}"]
    assert "holds glTF 1.0 (a GLB of version 1" in got[0].reason and "upgrade it to glTF 2.0" in got[0].reason
    assert all(isinstance(m, RawMesh) for m in got[2:])
    # a composite whose inner tile runs past its end is a rejection that says where
    cut = composite[:-200]
    (tmp_path / "cut.cmpt").write_bytes(cut[:8] + struct.pack("<I", len(cut)) + cut[12:])
    (item,) = read_file(tmp_path / "cut.cmpt")
    assert isinstance(item, Rejection) and "inner tile 3 of 3" in item.reason, item.reason


def test_batch_ids_quantized_by_compression_are_rounded(tmp_path):
    """Draco quantizes the generic attribute that holds the batch ids: loaders.gl's New York tile (275 buildings,
    12 bits) decodes them up to 0.034 off whole numbers, and all but 2 of its buildings were listed as "batch ids not
    whole numbers". Ids within 1/4 of whole numbers are rounded, with a note: every building, its own triangles. Ids
    that far off (6 bits over 40 batches: a step of 0.63) are not guessed."""
    buildings = _buildings(40)
    (tmp_path / "q.b3dm").write_bytes(b3dm(buildings, lambda v: v, id_bits=10))
    items = list(read_file(tmp_path / "q.b3dm"))
    assert all(isinstance(m, RawMesh) for m in items), [m.reason for m in items if not isinstance(m, RawMesh)]
    assert sorted(m.id.split("#", 1)[1] for m in items) == sorted(b[0] for b in buildings)
    by_id = {m.id.split("#", 1)[1]: m for m in items}
    for name, v, f in buildings:
        assert len(by_id[name].faces) == len(f)
        assert abs(_signed_volume(by_id[name].vertices, by_id[name].faces)) == pytest.approx(abs(_signed_volume(v, f)), rel=1e-5)
    assert any("batch ids rounded to whole numbers" in n for n in items[0].notes), items[0].notes
    (tmp_path / "coarse.b3dm").write_bytes(b3dm(buildings, lambda v: v, id_bits=6))
    assert any(isinstance(m, Rejection) and "not whole numbers" in m.reason for m in read_file(tmp_path / "coarse.b3dm"))


def _no_batch_b3dm(scene) -> bytes:
    """A b3dm of one model (BATCH_LENGTH 0, no batch table, no batch ids) around a trimesh scene's GLB."""
    glb = trimesh.exchange.gltf.export_glb(scene, include_normals=False)
    ft = _pad(json.dumps({"BATCH_LENGTH": 0}).encode())
    body = ft + glb
    return b"b3dm" + struct.pack("<6I", 1, 28 + len(body), len(ft), 0, 0, 0) + body


def test_content_without_batch_ids_is_read_by_node_or_by_piece(tmp_path):
    """A b3dm without batch ids (BATCH_LENGTH 0: assimp's export of Berlin, a node per building, named by its id) gave
    one model of all its buildings, open where they touched: each node is a building now, its id the node's name.
    A single node holding several buildings (CesiumJS's BatchedNoBatchIds) stays one model, noted, and
    --split-components reads each connected piece as a building (it was ignored for 3D Tiles)."""
    a = trimesh.creation.box(bounds=[[0, 0, 0], [10, 6, 8]])  # glTF y up: 10 x 8 x 6 m
    b = trimesh.creation.box(bounds=[[20, 0, 0], [24, 3, 5]])
    scene = trimesh.Scene()
    scene.add_geometry(a, node_name="bldg_1001", geom_name="g1")
    scene.add_geometry(b, node_name="bldg_1002", geom_name="g2")
    (tmp_path / "nodes.b3dm").write_bytes(_no_batch_b3dm(scene))
    items = {m.id.split("#", 1)[1]: m for m in read_file(tmp_path / "nodes.b3dm")}
    assert sorted(items) == ["bldg_1001", "bldg_1002"], items
    assert abs(_signed_volume(items["bldg_1001"].vertices, items["bldg_1001"].faces)) == pytest.approx(480)
    assert abs(_signed_volume(items["bldg_1002"].vertices, items["bldg_1002"].faces)) == pytest.approx(60)
    assert any("each of its 2 glTF nodes read as a building" in n for n in items["bldg_1001"].notes)

    (tmp_path / "one.b3dm").write_bytes(_no_batch_b3dm(trimesh.Scene(trimesh.util.concatenate([a, b]))))
    (whole,) = read_file(tmp_path / "one.b3dm")
    assert any("--split-components" in n for n in whole.notes), whole.notes
    pieces = list(read_file(tmp_path / "one.b3dm", ReaderOptions(split_components=True)))
    assert sorted(round(abs(_signed_volume(m.vertices, m.faces)), 6) for m in pieces) == [60, 480]
    assert all(m.id.endswith(("#c1", "#c2")) for m in pieces)


def test_tile_content_saved_as_a_glb_file_reads_as_its_tile(tmp_path):
    """A b3dm's glTF saved as a .glb (3d-tiles-tools' b3dmToGlb; loaders.gl's cesium-rtc-extension tile): its
    CESIUM_RTC centre and batch ids make it 3D Tiles content, read as its tile is, a building per batch, placed on
    the earth; trimesh alone gave a building per primitive, clusters of buildings tilted in the centre's frame."""
    from meshsom.tiles3d import parse_b3dm

    buildings = _buildings(5)
    ecef = [_ecef(v) for _, v, _ in buildings]
    rtc = np.mean(np.concatenate(ecef), axis=0)
    lookup = {id(v): e - rtc for (_, v, _), e in zip(buildings, ecef)}
    tile = b3dm(buildings, lambda v: lookup[id(v)], extra_gltf={
        "extensionsUsed": ["CESIUM_RTC"], "extensions": {"CESIUM_RTC": {"center": [float(c) for c in rtc]}}})
    glb = parse_b3dm(tile, "tile.b3dm")[2]
    (tmp_path / "tile.glb").write_bytes(glb)
    got = list(read_file(tmp_path / "tile.glb"))
    assert [m.id for m in got] == [f"tile.glb#{k}" for k in range(5)]
    for m, (bid, v, f), e in zip(got, buildings, ecef):
        assert "earth-centred" in m.notes[0]
        _same_building(m, v, f)
        assert np.linalg.norm(m.origin - e.mean(axis=0)) < 50


def test_a_tileset_whose_gltf_is_z_up_says_so(tmp_path):
    """3D Tiles 1.0's asset.gltfUpAxis "Z" (fanvanzh/3dtiles, CesiumLab): the glTF content is z up already and is not
    turned (its buildings lay on their side: 13.4 m tall became 13.4 m deep); without it, y up as the spec says."""
    buildings = _buildings(3)
    z_up = lambda v: np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])  # noqa: E731 (b3dm() turns z up to y up: undone)
    (tmp_path / "t.b3dm").write_bytes(b3dm(buildings, z_up))
    for axis, upright in (("Z", True), ("Y", False)):
        (tmp_path / "tileset.json").write_text(json.dumps({
            "asset": {"version": "1.0", "gltfUpAxis": axis}, "geometricError": 0,
            "root": {"boundingVolume": {"sphere": [0, 0, 0, 1000]}, "geometricError": 0, "content": {"uri": "t.b3dm"}}}))
        got = list(read_file(tmp_path / "tileset.json"))
        assert len(got) == 3
        for m, (_, v, f) in zip(got, buildings):
            same = np.allclose(np.ptp(m.vertices, axis=0), np.ptp(v, axis=0), atol=1e-4)
            assert same == upright, (axis, np.ptp(m.vertices, axis=0), np.ptp(v, axis=0))
            if upright:
                _same_building(m, v, f)


def _hierarchy_tile(hierarchy_key="extensions"):
    """Two houses of a wall block (10 x 10 x 6 m) and a roof block on it (10 x 10 x 2 m), each block a batch, 50 m
    apart; the batch table's hierarchy makes the blocks parts of two buildings (instances without geometry) of one
    zone, as converters of CityGML write thematic surfaces under their building."""
    blocks = []
    for x in (0.0, 50.0):
        for z0, z1 in ((0.0, 6.0), (6.0, 8.0)):
            box = trimesh.creation.box(bounds=[(x, 0, z0), (x + 10, 10, z1)])
            blocks.append((f"b{len(blocks)}", np.asarray(box.vertices), np.asarray(box.faces)))
    hierarchy = {"instancesLength": 7, "classIds": [0, 1, 0, 1, 2, 2, 3], "parentIds": [4, 4, 5, 5, 6, 6, 6],
                 "classes": [{"name": "WallSurface", "length": 2, "instances": {"kind": ["wall", "wall"]}},
                             {"name": "RoofSurface", "length": 2, "instances": {"kind": ["roof", "roof"]}},
                             {"name": "Building", "length": 2, "instances": {"building_name": ["A-house", "B-house"]}},
                             {"name": "zone", "length": 1, "instances": {"zone_name": ["zone0"]}}]}
    table = {"family": ["wall", "roof", "wall", "roof"]}
    if hierarchy_key == "extensions":
        table["extensions"] = {"3DTILES_batch_table_hierarchy": hierarchy}
    elif hierarchy_key == "HIERARCHY":  # the draft's form
        table["HIERARCHY"] = hierarchy
    return b3dm(blocks, lambda v: v, batch_table=table)


@pytest.mark.parametrize("form", ["extensions", "HIERARCHY"])
def test_batches_that_a_hierarchy_makes_parts_of_a_building_are_one_building(tmp_path, form):
    """3DTILES_batch_table_hierarchy: each batch a wall or roof block of a building that has no geometry of its own
    (Cesium's BatchTableHierarchy sample: 30 batches of doorknobs, doors, roofs and walls of 3 buildings, each read
    as a building, doorknobs of 0.056 m3 accepted). Read as the buildings, each its batches united: 10 x 10 x 8 m =
    800 m3 by hand, named by the building's name."""
    from meshsom.union import union_parts

    (tmp_path / "tile.b3dm").write_bytes(_hierarchy_tile(form))
    items = {m.id.split("#", 1)[1]: m for m in read_file(tmp_path / "tile.b3dm")}
    assert sorted(items) == ["A-house", "B-house"] and all(isinstance(m, RawMesh) for m in items.values()), items
    for mesh in items.values():
        assert len(mesh.parts) == 2 and mesh.label == "wall"
        assert any("parts of 2 objects by the batch table's hierarchy" in n for n in mesh.notes), mesh.notes
        assert union_parts(mesh.vertices, mesh.faces, mesh.face_part).volume_out == pytest.approx(800.0, rel=1e-6)


def test_a_batch_table_without_a_hierarchy_keeps_a_building_per_batch(tmp_path):
    (tmp_path / "tile.b3dm").write_bytes(_hierarchy_tile(None))
    assert len([m for m in read_file(tmp_path / "tile.b3dm") if isinstance(m, RawMesh)]) == 4


def test_a_hierarchy_of_building_parts_makes_one_building(tmp_path):
    """Surfaces under BuildingParts under their Building: the batches are the Building's (the class named a
    building, not a part), whatever the building's own name says ("Apartment block"): one building of 4 batches,
    800 + 800 m3 by hand."""
    from meshsom.union import union_parts

    tile = _hierarchy_tile(None)
    blocks_table = {"family": ["wall", "roof", "wall", "roof"], "extensions": {"3DTILES_batch_table_hierarchy": {
        "instancesLength": 7, "classIds": [0, 0, 0, 0, 1, 1, 2], "parentIds": [4, 4, 5, 5, 6, 6, 6],
        "classes": [{"name": "Surface", "length": 4, "instances": {}},
                    {"name": "BuildingPart", "length": 2, "instances": {"gml_id": ["p1", "p2"]}},
                    {"name": "Building", "length": 1, "instances": {"gml_id": ["Apartment block"]}}]}}}
    ft, bt = struct.unpack_from("<II", tile, 12), struct.unpack_from("<I", tile, 20)[0]
    table = _pad(json.dumps(blocks_table).encode())
    body = tile[28:28 + ft[0]] + table + tile[28 + ft[0] + bt:]
    (tmp_path / "tile.b3dm").write_bytes(b"b3dm" + struct.pack("<6I", 1, 28 + len(body), ft[0], 0, len(table), 0) + body)
    (mesh,) = read_file(tmp_path / "tile.b3dm")
    assert isinstance(mesh, RawMesh) and mesh.id == "tile.b3dm#Apartment block" and len(mesh.parts) == 4, mesh
    assert union_parts(mesh.vertices, mesh.faces, mesh.face_part).volume_out == pytest.approx(1600.0, rel=1e-6)
