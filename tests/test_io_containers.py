"""The same buildings in other containers: CityJSONSeq (``.city.jsonl``), gzip (``.city.json.gz``, the
form the 3D BAG serves its tiles in, ``.obj.gz``) and the 3D BAG's Building / BuildingPart layout.

Each container is written from the bundled real files by an independent converter
(``cityjson_samples.to_cityjsonseq``, ``to_3dbag_layout``, ``gzip.compress``), and the reader must
give exactly the meshes (ids, coordinates, origins, faces, parts, notes) and rejections it gives
for the original file.
"""

from __future__ import annotations

import gzip
import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import trimesh

from conftest import box
from cityjson_samples import CUBE_VERTS, cube_solid, doc, instanced_box_doc, to_3dbag_layout, to_cityjsonseq, write, write_lines
from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, read_file
from meshsom.store import read_manifest
from pipelines.cli import main

DATA = Path(__file__).resolve().parents[1] / "data" / "real"
REAL = [("3dbag-multilod", "multi_lod.city.json"), ("delft-lod1-3dfier", "delft.city.json"),
        ("zurich-lod2-subset", "zurich_subset_lod2.city.json")]


def _items(path, **opts):
    return list(read_file(path, ReaderOptions(**opts)))


def _strip_line(reason: str) -> str:
    return reason.split(": ", 1)[1] if reason.startswith("line ") else reason


def assert_same_items(got, expected, exact: bool = True):
    """Same meshes and rejections, by id (a CityJSONSeq rejection's reason starts with its line);
    ``exact``: the same vertex arrays and faces, else the same triangles in any vertex order.
    The order of the items does not count (``parts="separate"`` lists a file's objects in file
    order, a CityJSONSeq file's by feature)."""
    got, expected = sorted(got, key=lambda i: i.id), sorted(expected, key=lambda i: i.id)
    assert [(type(i).__name__, i.id) for i in got] == [(type(i).__name__, i.id) for i in expected]
    for g, e in zip(got, expected):
        if isinstance(e, Rejection):
            assert _strip_line(g.reason) == e.reason and g.label == e.label
            continue
        assert (g.id, g.label, g.lod, g.parts, g.notes) == (e.id, e.label, e.lod, e.parts, e.notes), g.id
        np.testing.assert_array_equal(g.origin, e.origin)
        assert (g.face_part is None) == (e.face_part is None)
        if exact:
            np.testing.assert_array_equal(g.vertices, e.vertices)
            np.testing.assert_array_equal(g.faces, e.faces)
            if e.face_part is not None:
                np.testing.assert_array_equal(g.face_part, e.face_part)
        else:
            assert _triangles(g) == _triangles(e), g.id


def _triangles(mesh) -> list:
    """The mesh's triangles as coordinates, each from its smallest corner (orientation kept), sorted,
    with the part each comes from: what a container that orders vertices differently must keep."""
    out = []
    for k, face in enumerate(mesh.faces):
        corners = [tuple(mesh.vertices[i]) for i in face]
        first = corners.index(min(corners))
        part = -1 if mesh.face_part is None else int(mesh.face_part[k])
        out.append((part, *corners[first:], *corners[:first]))
    return sorted(out)


def _real(folder, name) -> Path:
    path = DATA / folder / name
    if not path.exists():
        pytest.skip(f"{path} not bundled")
    return path


# ----------------------------------------------------------------------------- CityJSONSeq and gzip


@pytest.mark.parametrize("folder,name", REAL)
@pytest.mark.parametrize("parts", ["merge", "separate"])
def test_cityjsonseq_and_gzip_read_as_the_original(tmp_path, folder, name, parts):
    original = _real(folder, name)
    expected = _items(original, parts=parts)
    assert sum(isinstance(i, RawMesh) for i in expected) >= 10
    document = json.loads(original.read_text())
    stem = name.removesuffix(".city.json")
    # vertices in the file's order (exactly the same arrays), or renumbered as they first appear
    # (cjseq's order: the same triangles, their vertices listed in another order)
    seq = write_lines(tmp_path / f"{stem}.city.jsonl", to_cityjsonseq(document, keep_order=True))
    seq_gz = write_lines(tmp_path / f"{stem}.city.jsonl.gz", to_cityjsonseq(document), compress=True)
    tile_gz = tmp_path / f"{stem}.city.json.gz"
    tile_gz.write_bytes(gzip.compress(original.read_bytes(), mtime=0))
    for path, exact in ((seq, True), (seq_gz, False), (tile_gz, True)):
        got = _items(path, parts=parts)
        assert_same_items([_renamed(i, name) for i in got], expected, exact)


def _renamed(item, name: str):
    """``item`` with the id prefix of the original file (the container's name differs)."""
    import dataclasses

    return dataclasses.replace(item, id=name + "#" + item.id.split("#", 1)[1], source="")


def test_mesh_ids_name_the_container_file(tmp_path):
    original = _real(*REAL[0])
    seq = write_lines(tmp_path / "tile.city.jsonl.gz", to_cityjsonseq(json.loads(original.read_text())), compress=True)
    ids = [i.id for i in read_file(seq, ReaderOptions(), "sub/tile.city.jsonl.gz")]
    assert ids and all(i.startswith("sub/tile.city.jsonl.gz#") for i in ids)
    assert [i.split("#")[1] for i in ids] == list(json.loads(original.read_text())["CityObjects"])


def test_gzip_data_is_recognised_by_its_content(tmp_path):
    """A gzipped tile saved without its .gz (a browser that kept the encoded body) reads the same."""
    original = _real(*REAL[0])
    disguised = tmp_path / "tile.city.json"
    disguised.write_bytes(gzip.compress(original.read_bytes()))
    assert_same_items([_renamed(i, original.name) for i in _items(disguised)], _items(original))
    plain = tmp_path / "plain.city.json.gz"  # named .gz, not compressed: read as it is
    plain.write_bytes(original.read_bytes())
    assert_same_items([_renamed(i, original.name) for i in _items(plain)], _items(original))


def test_gzipped_mesh_files_read_as_the_plain_ones(tmp_path):
    box = trimesh.creation.box((3.0, 4.0, 5.0))
    for fmt in ("obj", "ply", "stl", "off", "glb"):
        plain = tmp_path / f"box.{fmt}"
        box.export(str(plain))
        packed = tmp_path / f"packed.{fmt}.gz"
        packed.write_bytes(gzip.compress(plain.read_bytes()))
        (e,), (g,) = _items(plain), _items(packed)
        np.testing.assert_array_equal(g.vertices, e.vertices)
        np.testing.assert_array_equal(g.faces, e.faces)
        np.testing.assert_array_equal(g.origin, e.origin)
        assert g.id == e.id.replace(f"box.{fmt}", f"packed.{fmt}.gz")


def test_a_page_of_a_cityjson_features_api_reads_as_its_cityjsonseq(tmp_path):
    """An OGC API - Features page of CityJSON (the 3D BAG API's items: a FeatureCollection of
    CityJSONFeatures, the header's transform in its metadata), saved as a .json, reads as the
    CityJSONSeq it stands for; so does one feature that carries its transform; one without is a
    rejection that says where the transform is."""
    document = json.loads(_real(*REAL[0]).read_text())
    header, *features = to_cityjsonseq(document, keep_order=True)
    seq = write_lines(tmp_path / "page.city.jsonl", [header] + features)
    page = {"type": "FeatureCollection", "numberMatched": len(features), "links": [],
            "metadata": {"transform": header["transform"], **header.get("metadata", {})}, "features": features}
    (tmp_path / "page.json").write_text(json.dumps(page))
    want, got = _items(seq), _items(tmp_path / "page.json")
    assert [i.id.replace("page.city.jsonl", "page.json") for i in want] == [i.id for i in got]
    assert sum(isinstance(i, RawMesh) for i in got) >= 10
    for a, b in zip(want, got):
        if isinstance(a, RawMesh):
            assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces) and a.lod == b.lod
    one = dict(features[0], transform=header["transform"])
    (tmp_path / "one.json").write_text(json.dumps(one))
    assert [i.id.split("#")[1] for i in _items(tmp_path / "one.json")] == [i.id.split("#")[1] for i in want if
                                                                          i.id.split("#")[1] in one["CityObjects"]]
    (tmp_path / "bare.json").write_text(json.dumps(features[0]))
    (bare,) = _items(tmp_path / "bare.json")
    assert isinstance(bare, Rejection) and "without the transform of their CityJSON header" in bare.reason


def test_a_pretty_printed_document_named_jsonl_reads_as_the_document(tmp_path):
    """One CityJSON object written across lines but named .city.jsonl reads as the .city.json it
    is; a sequence whose header line is broken is still the sequence's error."""
    original = _real(*REAL[1])
    (tmp_path / "pretty.city.jsonl").write_text(json.dumps(json.loads(original.read_text()), indent=2))
    want, got = _items(original), _items(tmp_path / "pretty.city.jsonl")
    assert [i.id.split("#")[1] for i in got] == [i.id.split("#")[1] for i in want] and len(got) >= 10
    (tmp_path / "broken.city.jsonl").write_text('{"type": "CityJSON",\n{"type": "CityJSONFeature"}\n')
    (broken,) = _items(tmp_path / "broken.city.jsonl")
    assert isinstance(broken, Rejection) and "invalid JSON" in broken.reason


def test_folders_find_compressed_and_sequence_files(tmp_path):
    (tmp_path / "in" / "sub").mkdir(parents=True)
    for name in ("a.city.json.gz", "sub/b.city.jsonl", "sub/c.city.jsonl.gz", "d.obj.gz", "e.json.gz"):
        (tmp_path / "in" / name).write_bytes(b"x")
    (tmp_path / "in" / "notes.txt.gz").write_bytes(b"x")
    skipped = []
    files, rejected = expand_inputs([tmp_path / "in"], skipped)
    assert sorted(f.name for f in files) == ["a.city.json.gz", "d.obj.gz", "e.json.gz", "sub/b.city.jsonl", "sub/c.city.jsonl.gz"]
    assert rejected == [] and [Path(p).name for p, _ in skipped] == ["notes.txt.gz"]
    assert ".gz" in skipped[0][1]


# ----------------------------------------------------------------------------- the 3D BAG layout


def test_3dbag_layout_reads_its_solids_not_its_lod0_footprint(tmp_path):
    """3D BAG tiles: a Building with a LoD 0 footprint, its solids (1.2, 1.3, 2.2) on a BuildingPart."""
    original = _real(*REAL[0])
    document = json.loads(original.read_text())
    bag = write(tmp_path / "bag.city.json", to_3dbag_layout(document))
    for lod, expected_lod in (("highest", "2.2"), ("lowest", "1.2"), ("1.3", "1.3")):
        expected = _items(original, lod=lod)
        got = _items(bag, lod=lod)
        assert len(got) == 10 and all(isinstance(i, RawMesh) and i.lod == expected_lod for i in got)
        assert_same_items([_renamed(i, original.name) for i in got], expected)
        seq = write_lines(tmp_path / "bag.city.jsonl.gz", to_cityjsonseq(to_3dbag_layout(document)), compress=True)
        assert_same_items([_renamed(i, original.name) for i in _items(seq, lod=lod)], expected, exact=False)
    # the footprint itself when asked for by name: open, so preprocessing rejects it (not the reader)
    footprints = _items(bag, lod="0")
    assert len(footprints) == 10 and all(isinstance(i, RawMesh) and i.lod == "0" for i in footprints)


def test_lod0_only_building_is_extruded_by_its_height_or_rejected_or_read_as_asked(tmp_path):
    d = doc({"B": {"type": "Building", "geometry": [{"type": "MultiSurface", "lod": "0", "boundaries": [[[0, 1, 2, 3]]]}]}},
            [[0, 0, 0], [1000, 0, 0], [1000, 1000, 0], [0, 1000, 0]])
    (r,) = _items(write(tmp_path / "f.city.json", d), lod="highest")
    assert isinstance(r, Rejection) and "has only a LoD 0 footprint" in r.reason  # a footprint is no volume
    (m,) = _items(tmp_path / "f.city.json", lod="0")  # asked for by name: the footprint as it is
    assert m.lod == "0" and len(m.faces) == 2
    d["CityObjects"]["B"]["attributes"] = {"measuredHeight": "4 m"}
    (m,) = _items(write(tmp_path / "h.city.json", d), lod="highest")
    assert m.lod == "1 (extruded from 0)" and len(m.faces) == 12 and np.ptp(m.vertices[:, 2]) == 4


# ----------------------------------------------------------------------------- bad lines, bad headers


def _cube_feature(fid, dx=0):
    verts = [[x + dx, y, z] for x, y, z in CUBE_VERTS]
    return {"type": "CityJSONFeature", "id": fid, "CityObjects": {fid: {"type": "Building", "geometry": [cube_solid()]}},
            "vertices": verts}


def _header(**extra):
    return {"type": "CityJSON", "version": "2.0", "transform": {"scale": [0.001] * 3, "translate": [85000.0, 446000.0, 0.0]},
            "CityObjects": {}, "vertices": [], **extra}


def test_bad_lines_are_rejected_by_line_and_the_rest_is_read(tmp_path):
    lines = [json.dumps(_header()), json.dumps(_cube_feature("a")), "", "{not json",
             json.dumps({"type": "CityJSON", "id": "x"}), json.dumps({**_cube_feature("v"), "vertices": [[0, 0]]}),
             json.dumps(_cube_feature("a", dx=5000)), json.dumps(_cube_feature("b", dx=9000)),
             json.dumps({"type": "CityJSONFeature", "id": "r", "CityObjects": {"r": {"type": "Road"}}, "vertices": []})]
    path = tmp_path / "t.city.jsonl"
    path.write_text("\n".join(lines) + "\n")
    items = _items(path)
    got = {(type(i).__name__, i.id): getattr(i, "reason", None) for i in items}
    assert set(got) == {("RawMesh", "t.city.jsonl#a"), ("Rejection", "t.city.jsonl:line 4"), ("Rejection", "t.city.jsonl#x"),
                        ("Rejection", "t.city.jsonl#v"), ("Rejection", "t.city.jsonl#a (2)"), ("RawMesh", "t.city.jsonl#b")}
    assert got["Rejection", "t.city.jsonl:line 4"].startswith("line 4: invalid JSON")
    assert got["Rejection", "t.city.jsonl#x"] == "line 5: is not a CityJSONFeature (\"type\": 'CityJSON')"
    assert got["Rejection", "t.city.jsonl#v"].startswith("line 6: \"vertices\" must be a list of [x, y, z] integers")
    assert got["Rejection", "t.city.jsonl#a (2)"] == "line 7: object id repeated (first on line 2); the later one is not read"
    (b,) = [i for i in items if i.id.endswith("#b")]
    np.testing.assert_allclose(b.origin, [85000.0 + 9.5, 446000.5, 0.5])  # the header's transform applied


def test_object_rejections_in_a_sequence_name_their_line(tmp_path):
    bad = _cube_feature("c")
    bad["CityObjects"]["c"]["geometry"][0]["boundaries"][0][0][0] = [0, 1, 99]
    path = write_lines(tmp_path / "t.city.jsonl", [_header(), _cube_feature("a"), bad])
    (ok, rej) = _items(path)
    assert isinstance(ok, RawMesh) and isinstance(rej, Rejection) and rej.id == "t.city.jsonl#c"
    assert rej.reason == "line 3: vertex index 99 out of range (the file has 8 vertices)"


@pytest.mark.parametrize("first,reason", [
    ({"type": "CityJSONFeature", "id": "a"}, "line 1: its first line is not a CityJSON header (expected \"type\": \"CityJSON\", found 'CityJSONFeature')"),
    ({"type": "CityJSON", "version": "2.0", "transform": {"scale": [0, 1, 1], "translate": [0, 0, 0]}},
     "line 1: \"transform\" has invalid values"),
    ({"type": "CityJSON", "version": "3.0", "transform": {"scale": [1, 1, 1], "translate": [0, 0, 0]}}, "line 1: CityJSON version '3.0' is not supported"),
])
def test_a_bad_header_rejects_the_file_naming_it(tmp_path, first, reason):
    path = write_lines(tmp_path / "t.city.jsonl", [first, _cube_feature("a")])
    (rej,) = _items(path)
    assert isinstance(rej, Rejection) and rej.id == str(path)
    assert rej.reason.startswith(reason.split(": ", 1)[1]), rej.reason


def test_files_with_no_buildings_are_rejected_naming_what_they_hold(tmp_path):
    d = doc({"R": {"type": "Road", "geometry": []}, "T": {"type": "TINRelief", "geometry": []}}, [])
    (rej,) = _items(write(tmp_path / "terrain.city.json", d))
    assert rej.reason == "holds no Building object (found Road, TINRelief)"
    seq = write_lines(tmp_path / "terrain.city.jsonl", [_header(), {"type": "CityJSONFeature", "id": "R",
                                                                     "CityObjects": {"R": {"type": "Road"}}, "vertices": []}])
    (rej,) = _items(seq)
    assert rej.reason == "holds no Building object (found Road)"
    blank = tmp_path / "blank.city.jsonl"
    blank.write_text("\n\n")
    (rej,) = _items(blank)
    assert "only blank lines" in rej.reason


# ----------------------------------------------------------------------------- size guards


def test_gzip_bomb_is_refused_having_allocated_little(tmp_path):
    bomb = tmp_path / "bomb.city.json.gz"
    with gzip.open(bomb, "wb", compresslevel=9) as fh:
        for _ in range(256):
            fh.write(b" " * (1 << 20))  # 256 MB of spaces: a valid JSON prefix, ~1000x compressed
    assert bomb.stat().st_size < (1 << 20)
    for name in ("bomb.city.json.gz", "bomb.city.jsonl.gz", "bomb.obj.gz", "bomb.gml.gz"):
        path = bomb.rename(tmp_path / name)
        bomb = path
        tracemalloc.start()
        try:
            (rej,) = _items(path)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert isinstance(rej, Rejection) and "decompression bomb" in rej.reason and "max_expansion" in rej.reason, rej
        # what the expansion rule lets through (a sequence: one line's worth), not the 256 MB
        bound = 1.25 * ReaderOptions().max_expansion * path.stat().st_size + (8 << 20)  # with bytearray growth
        assert peak < bound, f"{path.name}: peak {peak / 2**20:.0f} MB"


def test_max_bytes_bounds_plain_files_and_sequence_lines(tmp_path):
    original = _real(*REAL[0])
    (rej,) = _items(original, max_bytes=1000)
    assert rej.reason == ("content is larger than 1,000 bytes (ReaderOptions.max_bytes); CityJSONSeq (.city.jsonl, "
                          "e.g. from `cjseq cat`) is read a line at a time")
    seq = write_lines(tmp_path / "t.city.jsonl", to_cityjsonseq(json.loads(original.read_text())))
    longest = max(len(line) for line in seq.read_bytes().splitlines(keepends=True))
    assert sum(isinstance(i, RawMesh) for i in _items(seq, max_bytes=longest)) == 10
    items = _items(seq, max_bytes=longest - 1)  # the longest line alone is rejected
    (rej,) = [i for i in items if isinstance(i, Rejection)]
    assert len(items) == 10 and rej.id.startswith("t.city.jsonl:line ")
    assert rej.reason.endswith(f"is longer than {longest - 1:,} bytes (ReaderOptions.max_bytes); not read")


@pytest.mark.parametrize("damage,reason", [
    (lambda b: b[: len(b) // 2], "gzip data ends early (a truncated download?)"),
    (lambda b: b[:10] + bytes(x ^ 0x5A for x in b[10:40]) + b[40:], "is not valid gzip data"),
])
def test_damaged_gzip_is_a_rejection(tmp_path, damage, reason):
    original = _real(*REAL[1])
    for suffix in (".city.json.gz", ".city.jsonl.gz"):
        data = gzip.compress(original.read_bytes() if suffix == ".city.json.gz" else b"".join(
            json.dumps(line).encode() + b"\n" for line in to_cityjsonseq(json.loads(original.read_text()))))
        path = tmp_path / f"d{suffix}"
        path.write_bytes(damage(data))
        items = _items(path)
        assert isinstance(items[-1], Rejection) and items[-1].id == str(path)
        assert items[-1].reason.startswith(reason), items[-1].reason


# ----------------------------------------------------------------------------- the command line


def test_ingest_of_a_3dbag_style_folder(tmp_path, data_dir):
    """`meshsom ingest` on a folder of a gzipped 3D BAG tile and its CityJSONSeq: every building of
    both accepted, with the same preprocessed triangles as the plain file."""
    original = _real(*REAL[0])
    document = to_3dbag_layout(json.loads(original.read_text()))
    (tmp_path / "tiles").mkdir()
    (tmp_path / "tiles" / "10-284-556.city.json.gz").write_bytes(gzip.compress(json.dumps(document).encode()))
    write_lines(tmp_path / "tiles" / "10-284-556.city.jsonl", to_cityjsonseq(document))
    assert main(["ingest", str(tmp_path / "tiles"), "--out", str(tmp_path / "bag.zarr")]) == 0
    assert main(["ingest", str(original), "--out", str(tmp_path / "plain.zarr")]) == 0
    records = read_manifest(tmp_path / "bag.zarr")["records"]
    faces = {r["id"].split("#")[1]: r["faces_out"] for r in read_manifest(tmp_path / "plain.zarr")["records"]}
    assert len(records) == 20 and all(r["status"] == "accepted" for r in records)
    assert sorted({r["id"].split("#")[0] for r in records}) == ["10-284-556.city.json.gz", "10-284-556.city.jsonl"]
    for r in records:
        assert r["faces_out"] == faces[r["id"].split("#")[1]] > 0, r["id"]


# ----------------------------------------------------------------------------- geometry templates


def test_geometry_instances_are_placed_as_the_specification_says(tmp_path):
    path = write(tmp_path / "t.city.json", instanced_box_doc({}))
    t, s = _items(path)
    assert isinstance(t, RawMesh) and isinstance(s, RawMesh) and t.lod == "2"
    np.testing.assert_array_equal(t.origin, s.origin)
    assert _triangles(t) == _triangles(s)
    # CityJSONSeq: the templates on the header line, the reference point among the feature's vertices
    seq = write_lines(tmp_path / "t.city.jsonl", to_cityjsonseq(instanced_box_doc({})))
    t2, s2 = _items(seq)
    assert (t2.id, s2.id) == ("t.city.jsonl#T", "t.city.jsonl#S")
    assert _triangles(t2) == _triangles(t) and _triangles(s2) == _triangles(s)


@pytest.mark.parametrize("instance,with_templates,reason", [
    ({}, False, "has GeometryInstance geometry but the file has no \"geometry-templates\""),
    ({"template": 3}, True, "GeometryInstance template 3 is not one of the file's 1 templates"),
    ({"boundaries": [99]}, True, "GeometryInstance boundaries must be [index of the reference point] (one of 9 vertices)"),
    ({"transformationMatrix": [1, 0, 0]}, True, "GeometryInstance transformationMatrix must be 16 finite numbers"),
])
def test_bad_geometry_instances_are_rejected_with_the_reason(tmp_path, instance, with_templates, reason):
    t, s = _items(write(tmp_path / "t.city.json", instanced_box_doc(instance, with_templates)))
    assert isinstance(t, Rejection) and t.id == "t.city.json#T" and t.reason.startswith(reason), t.reason
    assert isinstance(s, RawMesh)


# ----------------------------------------------------------------------------- OBJ of a city


def _city_obj(meshes, empty: str | None = None) -> str:
    """An OBJ file with one object ("o") per mesh, world coordinates, roof and wall materials mixed
    within each object (as 3D BAG and 3dfier OBJ exports are)."""
    lines, base = ["mtllib city.mtl"], 1
    for m in meshes:
        lines.append(f"o {m.id.split('#', 1)[1]}")
        lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in (m.vertices + m.origin).tolist()]
        for k, face in enumerate(m.faces.tolist()):
            if k % 3 == 0:
                lines.append(f"usemtl {'roof' if k % 2 else 'wall'}")
            lines.append("f " + " ".join(str(i + base) for i in face))
        base += len(m.vertices)
    if empty:
        lines += [f"o {empty}", "v 0 0 0", "v 1 0 0", f"l {base} {base + 1}"]
    return "\n".join(lines) + "\n"


def test_an_obj_of_a_city_gives_one_mesh_per_object(tmp_path):
    meshes = [i for i in _items(_real(*REAL[0])) if isinstance(i, RawMesh)]
    (tmp_path / "tile.obj").write_text(_city_obj(meshes, empty="a_line"))
    first = meshes[0].id.split("#", 1)[1]
    (tmp_path / "labels.csv").write_text(f"file,label\ntile.obj,row\ntile.obj#{first},detached\n")
    items = _items(tmp_path / "tile.obj")
    got = {i.id: i for i in items}
    assert set(got) == {"tile.obj#" + m.id.split("#", 1)[1] for m in meshes} | {"tile.obj#a_line"}
    assert isinstance(got["tile.obj#a_line"], Rejection) and got["tile.obj#a_line"].reason == "holds no faces"
    for m in meshes:
        g = got["tile.obj#" + m.id.split("#", 1)[1]]
        world = np.sort(np.round((g.vertices + g.origin)[g.faces].reshape(-1, 3), 6), axis=0)
        np.testing.assert_allclose(world, np.sort(np.round((m.vertices + m.origin)[m.faces].reshape(-1, 3), 6), axis=0))
        assert len(g.faces) == len(m.faces)
        assert g.label == ("detached" if m.id.endswith("#" + first) else "row")


# ----------------------------------------------------------------------------- the library's writers


@pytest.mark.parametrize("fmt,out", [("cityjson", "c.city.json"), ("cityjson", "c.city.json.gz"), ("cityjsonseq", "c.city.jsonl"),
                                     ("cityjsonseq", "c.city.jsonl.gz"), ("citygml", "c.gml"), ("citygml", "c.gml.gz")])
def test_generate_writes_every_container_and_reads_back_the_blocks(tmp_path, fmt, out):
    """`meshsom generate --format F` read back: every block, its label, its triangles (to the
    writers' millimetre grid; CityGML keeps full precision)."""
    from meshsom.generate import BLOCK_FAMILIES, ROOF_FAMILIES, GeneratorParams, generate_corpus

    assert main(["generate", "--out", str(tmp_path / out), "-n", "5", "--seed", "4", "--roofs", "--format", fmt,
                 "--origin", "2600000", "1200000", "400"]) == 0
    blocks = generate_corpus(GeneratorParams(n_blocks=5, seed=4, origin=(2600000.0, 1200000.0, 400.0),
                                             families=BLOCK_FAMILIES + ROOF_FAMILIES))
    got = {i.id.split("#", 1)[1]: i for i in _items(tmp_path / out)}
    assert sorted(got) == sorted(b.id for b in blocks)
    for b in blocks:
        g = got[b.id]
        assert isinstance(g, RawMesh) and g.label == b.label
        world = np.sort((g.vertices + g.origin)[g.faces].reshape(-1, 3), axis=0)
        np.testing.assert_allclose(world, np.sort(b.vertices[b.faces].reshape(-1, 3), axis=0), atol=6e-4, rtol=0)


def _prism_obj(ring, height, relative: bool) -> str:
    """A prism over ``ring`` (counter-clockwise, 2D) as OBJ with its floor and roof one polygon each
    and quad walls, references as v/vt/vn (``relative``: negative, counted back from the last vertex)."""
    n = len(ring)
    lines = ["o prism", "vt 0 0", "vn 0 0 1"] + [f"v {x} {y} 0" for x, y in ring] + [f"v {x} {y} {height}" for x, y in ring]

    def ref(i):  # i: 0-based vertex of this prism
        return f"{i - 2 * n}/1/1" if relative else f"{i + 1}/1/1"

    lines.append("f " + " ".join(ref(i) for i in reversed(range(n))))
    lines.append("f " + " ".join(ref(n + i) for i in range(n)))
    for i in range(n):
        j = (i + 1) % n
        lines.append(f"f {ref(i)} {ref(j)} {ref(n + j)} {ref(n + i)}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("relative", [False, True])
@pytest.mark.parametrize("ring", [
    [(0, 0), (5, 0), (5, 3), (4, 3), (4, 1), (3, 1), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)],  # a comb
    [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)],  # an L
    [(0, 0), (4, 0), (4, 4), (0, 4)],  # convex: left to trimesh
])
def test_obj_polygons_that_are_not_convex_are_triangulated_in_their_plane(tmp_path, ring, relative):
    """CAD and Blender exports keep an L- or U-shaped roof as one polygon; a fan from its first
    vertex folds over itself (the comb was rejected as open)."""
    from meshsom.preprocess import preprocess

    (tmp_path / "p.obj").write_text(_prism_obj(ring, 2.5, relative))
    (m,) = _items(tmp_path / "p.obj")
    area = 0.5 * abs(sum(x1 * y2 - x2 * y1 for (x1, y1), (x2, y2) in zip(ring, ring[1:] + ring[:1])))
    v = m.vertices + m.origin
    tri = v[m.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    roof = np.isclose(tri[:, :, 2], 2.5).all(axis=1)
    assert len(m.faces) == 2 * (len(ring) - 2) + 2 * len(ring)
    assert (n[roof, 2] > 0).all() and 0.5 * n[roof, 2].sum() == pytest.approx(area)  # no triangle folds back
    r = preprocess(m.vertices, m.faces)
    assert r.volume_out == pytest.approx(area * 2.5, rel=1e-12) and r.repairs == []


def _check_prism(m, ring, height):
    """A prism of a footprint ring read whole: its polygons triangulated in their plane (no roof
    triangle folds back), closed with the footprint's area x height and no repairs."""
    from meshsom.preprocess import preprocess

    assert isinstance(m, RawMesh), m
    area = 0.5 * abs(sum(x1 * y2 - x2 * y1 for (x1, y1), (x2, y2) in zip(ring, ring[1:] + ring[:1])))
    tri = (m.vertices + m.origin)[m.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    roof = np.isclose(tri[:, :, 2], height).all(axis=1)
    assert len(m.faces) == 2 * (len(ring) - 2) + 2 * len(ring)
    assert (normal[roof, 2] > 0).all() and 0.5 * normal[roof, 2].sum() == pytest.approx(area)
    r = preprocess(m.vertices, m.faces)
    assert r.volume_out == pytest.approx(area * height, rel=1e-12) and r.repairs == []


def _prism_off(ring, height, style: str) -> str:
    """The prism of :func:`_prism_obj` as OFF, in the styles writers use: ``plain``; ``val3dity``
    (comments, blank lines, a blank after every face line: trimesh's reader fails on those);
    ``coff`` (vertex and face colours); ``glued`` (ModelNet's counts glued to the header)."""
    n = len(ring)
    verts = [(x, y, 0.0) for x, y in ring] + [(x, y, float(height)) for x, y in ring]
    faces = [list(reversed(range(n))), [n + i for i in range(n)]]
    faces += [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    colour = " 200 30 30 255" if style == "coff" else ""
    blank = " " if style == "val3dity" else ""
    head = {"plain": ["OFF", f"{2 * n} {len(faces)} 0"], "val3dity": ["OFF", "# a prism", f"{2 * n} {len(faces)} 0", ""],
            "coff": ["COFF", f"{2 * n} {len(faces)} 0"], "glued": [f"OFF{2 * n} {len(faces)} 0"]}[style]
    lines = head + [f"{x} {y} {z}{colour}" for x, y, z in verts]
    lines += [f"{len(f)} " + " ".join(map(str, f)) + colour + blank for f in faces]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("style", ["plain", "val3dity", "coff", "glued"])
@pytest.mark.parametrize("ring", [
    [(0, 0), (5, 0), (5, 3), (4, 3), (4, 1), (3, 1), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)],  # a comb
    [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)],  # an L
    [(0, 0), (4, 0), (4, 4), (0, 4)],
])
def test_off_polygons_are_triangulated_in_their_plane(tmp_path, ring, style):
    """OFF keeps polygons too (val3dity's and CGAL's files, ModelNet): triangulated in their plane,
    and read whatever the blanks, comments and colours around them."""
    (tmp_path / "p.off").write_text(_prism_off(ring, 2.5, style))
    (m,) = _items(tmp_path / "p.off")
    _check_prism(m, ring, 2.5)


@pytest.mark.parametrize("style", ["ascii", "binary_little_endian", "binary_big_endian", "colours"])
@pytest.mark.parametrize("ring", [
    [(0, 0), (5, 0), (5, 3), (4, 3), (4, 1), (3, 1), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)],  # a comb
    [(2, 0), (2, 1), (1, 1), (1, 2), (0, 2), (0, 0)],  # an L, from a corner that does not see it all
    [(0, 0), (4, 0), (4, 4), (0, 4)],
])
def test_ply_polygons_are_triangulated_in_their_plane(tmp_path, ring, style):
    """PLY keeps polygons too (MeshLab, CloudCompare and CAD exports): triangulated in their plane,
    written by plyfile as ASCII or binary of either byte order, with colours beside (the layouts
    read without parsing the faces, and one that needs the full parse)."""
    from plyfile import PlyData, PlyElement

    n = len(ring)
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8")] + ([("red", "u1")] if style == "colours" else [])
    verts = np.zeros(2 * n, fields)
    verts["x"], verts["y"] = np.tile(np.asarray(ring, float).T, 2)
    verts["z"][n:] = 2.5
    polygons = [list(reversed(range(n))), [n + i for i in range(n)]] + [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    faces = np.empty(len(polygons), [("vertex_indices", "O")] + ([("red", "u1")] if style == "colours" else []))
    faces["vertex_indices"] = [np.asarray(f, np.int32) for f in polygons]
    order = {"binary_big_endian": ">"}.get(style, "<")
    PlyData([PlyElement.describe(verts, "vertex"), PlyElement.describe(faces, "face")], text=style == "ascii",
            byte_order=order).write(str(tmp_path / "p.ply"))
    (m,) = _items(tmp_path / "p.ply")
    _check_prism(m, ring, 2.5)


@pytest.mark.parametrize("text,reason", [
    ("OFF\n8 6 0\n0 0 0\n", "cannot be read as .off"),  # fewer vertices than declared
    # an index beyond the vertices: which face and vertex
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2 7\n", "the face on line 6 refers to vertex 7, and the file has 3 vertices"),
])
def test_bad_off_files_are_still_rejections(tmp_path, text, reason):
    (tmp_path / "bad.off").write_text(text)
    (r,) = _items(tmp_path / "bad.off")
    assert isinstance(r, Rejection) and reason in r.reason, r


def test_obj_groups_are_buildings_only_when_each_is_closed(tmp_path):
    """No objects, a group (g) per building, as SketchUp exports a district: one mesh per group.
    A single building whose roof and walls are groups of their own stays one mesh."""
    meshes = [i for i in _items(_real(*REAL[0])) if isinstance(i, RawMesh)]
    (tmp_path / "district.obj").write_text(_city_obj(meshes).replace("\no ", "\ng "))
    got = _items(tmp_path / "district.obj")
    assert sorted(i.id for i in got) == sorted("district.obj#" + m.id.split("#", 1)[1] for m in meshes)
    assert all(isinstance(i, RawMesh) for i in got)
    v, f = box(2.0, 3.0, 4.0)
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    for k, (a, b, c) in enumerate(f.tolist()):
        lines += [f"g side{k // 2}", f"f {a + 1} {b + 1} {c + 1}"]
    (tmp_path / "house.obj").write_text("\n".join(lines) + "\n")
    (m,) = _items(tmp_path / "house.obj")
    assert m.id == "house.obj" and len(m.faces) == 12


def test_ingest_groups_rejections_by_kind_with_what_to_try(tmp_path, capsys):
    """`meshsom ingest` of a city's worth of rejections lists their kinds, counted, with a hint;
    the whole reasons stay in the manifest."""
    objects, vertices = {}, []
    for k in range(3):  # boxes missing half their roof and a wall triangle beside it: a bent hole,
        v, f = box(2.0 + k, 3.0, 4.0)  # not guessed at (nor rebuilt under the half roof)
        keep = f[[0, 1, 2, 4, 5, 6, 7, 8, 10, 11]]
        base = len(vertices)
        vertices += (np.round(v * 1000).astype(int) + [10000 * k, 0, 0]).tolist()
        objects[f"open{k}"] = {"type": "Building", "geometry": [{"type": "MultiSurface", "lod": "2",
                                                                 "boundaries": [[[int(i) + base for i in t]] for t in keep]}]}
    (tmp_path / "in").mkdir()
    write(tmp_path / "in" / "city.city.json", doc(objects, vertices))
    write(tmp_path / "in" / "terrain.city.json", doc({"T": {"type": "TINRelief", "geometry": []}}, []))
    assert main(["ingest", str(tmp_path / "in"), "--out", str(tmp_path / "s.zarr")]) == 1
    out = capsys.readouterr().out
    assert "4 meshes: 0 accepted, 4 rejected" in out
    assert "     3 x open boundary: N edges have only one face (a hole that is not planar)" in out
    assert "hint: --repair fills holes with pymeshlab" in out
    assert "     1 x holds no Building object\n" in out
    reasons = [r["reason"] for r in read_manifest(tmp_path / "s.zarr")["records"]]
    assert sum(r.startswith("open boundary: ") and r[15].isdigit() for r in reasons) == 3


def test_a_repeat_takes_an_id_no_earlier_item_has(tmp_path):
    """A repeat's id is the next free "<id> (k)": an object whose own id is "a (2)", coming after a
    repeated "a", does not collide with it (the assembly would stop the run on a collision)."""
    lines = [_header(), _cube_feature("a"), _cube_feature("a", dx=5000), _cube_feature("a (2)", dx=9000),
             _cube_feature("a", dx=12000)]
    path = tmp_path / "t.city.jsonl"
    path.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    got = [(type(i).__name__, i.id.split("#", 1)[1]) for i in _items(path)]
    assert got == [("RawMesh", "a"), ("Rejection", "a (2)"), ("Rejection", "a (2) (2)"), ("Rejection", "a (3)")]
    assert len({i for _, i in got}) == len(got)


def test_run_prints_the_commonest_kinds_of_rejection_in_80_columns(capsys):
    from pipelines.run import RUN_KINDS_SHOWN, _print_rejection_kinds

    records = [{"status": "accepted"}] * 3 + [
        {"status": "rejected", "reason": f"open boundary: {n} edges have only one face (a hole that is not planar)"}
        for n in (4, 9, 17)] + [{"status": "rejected", "reason": f"kind {k} " + "x" * 100} for k in "abc"]
    _print_rejection_kinds(records)
    lines = capsys.readouterr().out.splitlines()
    assert all(len(line) <= 80 for line in lines)
    assert lines[0].startswith("            3 x open boundary: N edges have only one face")
    assert len(lines) == RUN_KINDS_SHOWN + 1 and lines[-1] == "        (1 more kinds: meshsom inspect)"


def test_run_prints_the_commonest_notes_of_the_reader_in_80_columns(capsys):
    from pipelines.run import _print_note_kinds

    crs = "converted to metres from geographic coordinates (JGD2011 + JGD2011 (vertical) height), east-north-up about the building's centre"
    records = [{"status": "accepted", "notes": [crs]}] * 5 + [
        {"status": "accepted", "notes": [crs, f"height from building:levels = {n} storeys x 3 m"]} for n in (2, 7)]
    _print_note_kinds(records)
    lines = capsys.readouterr().out.splitlines()
    assert all(len(line) <= 80 for line in lines) and len(lines) == 2
    assert lines[0].startswith("            7 x read: converted to metres from geographic coordinates (JGD2011")
    assert lines[1] == "            2 x read: height from building:levels = N storeys x N m"


def test_unknown_compressed_files_name_both_suffixes(tmp_path):
    (tmp_path / "notes.txt.gz").write_bytes(b"x")
    (rej,) = read_file(tmp_path / "notes.txt.gz")
    assert rej.reason.startswith("unknown file type '.txt.gz'; expected one of .obj")


# ----------------------------------------------------------------------------- byte ranges


def _same_items(got, expected):
    assert [(type(i).__name__, i.id) for i in got] == [(type(i).__name__, i.id) for i in expected]
    for g, e in zip(got, expected):
        if isinstance(e, Rejection):
            assert g.reason == e.reason
        else:
            np.testing.assert_array_equal(g.vertices, e.vertices)
            np.testing.assert_array_equal(g.faces, e.faces)
            np.testing.assert_array_equal(g.origin, e.origin)


@pytest.mark.parametrize("target", [1, 700, 5000, 40_000])
def test_byte_ranges_of_a_cityjsonseq_file_read_as_the_whole_file(tmp_path, target):
    """A city in one CityJSONSeq file is read by several tasks, each a range of whole lines: the
    ranges cover every feature once, in order, with its line number (blank lines and bad lines
    included), and together give what one reader of the whole file gives."""
    from meshsom.io import cityjsonseq_ranges

    document = json.loads(_real(*REAL[1]).read_text())
    lines = [json.dumps(x) for x in to_cityjsonseq(document)]
    lines[5:5] = ["", "{not json", "   "]
    lines.insert(40, lines[12])  # a feature repeated (its second copy is rejected by line number)
    path = tmp_path / "city.city.jsonl"
    path.write_text("\n".join(lines) + "\n")
    expected = _items(path)
    ranges = cityjsonseq_ranges(path, target)
    assert ranges is not None and ranges[0][0] == len(lines[0]) + 1 and ranges[0][2] == 2
    assert ranges[-1][1] == path.stat().st_size
    assert all(a[1] == b[0] for a, b in zip(ranges, ranges[1:]))  # contiguous, no line twice
    text = path.read_bytes()
    assert all(text[a - 1:a] == b"\n" and text[:a].count(b"\n") + 1 == n for a, _, n in ranges)  # line starts, numbered
    if target == 1:
        assert len(ranges) == len(lines) - 1  # every line its own range
    got = [i for r in ranges for i in read_file(path, ReaderOptions(), None, r)]
    # the repeat is found by the whole-file reader; across ranges that is the pipeline's work
    repeat = next(i for i in expected if i.id.endswith(" (2)"))
    assert repeat.reason.startswith("line 41: object id repeated (first on line 13)")
    ids = [i.id for i in got]
    if len(set(ids)) < len(ids):  # the repeat fell in another range than its first copy: read as a mesh
        second = [k for k, i in enumerate(ids) if i == repeat.id[:-4]][1]
        assert isinstance(got[second], RawMesh)
        del got[second]
        expected.remove(repeat)
    _same_items(got, expected)


def test_small_or_gzipped_cityjsonseq_files_are_not_split(tmp_path):
    from meshsom.io import cityjsonseq_ranges

    lines = to_cityjsonseq(json.loads(_real(*REAL[1]).read_text()))
    write_lines(tmp_path / "a.city.jsonl", lines)
    write_lines(tmp_path / "b.city.jsonl", lines, compress=True)
    size = (tmp_path / "a.city.jsonl").stat().st_size
    assert cityjsonseq_ranges(tmp_path / "a.city.jsonl", size // 2 + 1) is None
    assert len(cityjsonseq_ranges(tmp_path / "a.city.jsonl", size // 2)) == 2
    assert cityjsonseq_ranges(tmp_path / "b.city.jsonl", 10) is None


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".glb"])
def test_a_district_exported_as_one_mesh_is_split_into_its_buildings_on_request(tmp_path, suffix, capsys):
    """A city exported as one mesh (an STL or PLY of a district, one glTF node): with
    split_components (--split-components) each connected piece is a building, numbered in the
    order of its first face, each closed with its own volume; by default the file is one mesh."""
    from meshsom.preprocess import preprocess
    from pipelines.cli import main

    sizes = [(10, 8, 6), (4, 4, 12), (7, 5, 3)]
    parts = []
    for k, size in enumerate(sizes):
        v, f = box(*size)
        parts.append(trimesh.Trimesh(v + [30.0 * k, 5.0 * k, 0], f, process=False))
    trimesh.util.concatenate(parts).export(tmp_path / f"district{suffix}")
    (whole,) = read_file(tmp_path / f"district{suffix}")
    assert isinstance(whole, RawMesh) and len(whole.faces) == 36
    pieces = list(read_file(tmp_path / f"district{suffix}", ReaderOptions(split_components=True)))
    base = whole.id
    assert [m.id for m in pieces] == [f"{base}#c1", f"{base}#c2", f"{base}#c3"]
    for m, (x, y, z) in zip(pieces, sizes):
        assert len(m.faces) == 12
        assert preprocess(m.vertices, m.faces).volume_out == pytest.approx(x * y * z, rel=1e-9)
        np.testing.assert_allclose((m.vertices + m.origin).max(axis=0) - (m.vertices + m.origin).min(axis=0), [x, y, z])
    assert main(["ingest", str(tmp_path / f"district{suffix}"), "--split-components", "--out", str(tmp_path / "s.zarr")]) == 0
    assert "3 meshes: 3 accepted, 0 rejected" in capsys.readouterr().out


def _collada(unit: float | None, up: str | None, vertices: np.ndarray, faces: np.ndarray) -> str:
    """A COLLADA document of one triangle mesh, as SketchUp (inches, Z_UP) or other tools write it."""
    asset = (f'<unit meter="{unit}" name="u"/>' if unit is not None else "") + (f"<up_axis>{up}_UP</up_axis>" if up else "")
    floats = " ".join(repr(float(x)) for x in vertices.reshape(-1))
    tris = " ".join(str(int(i)) for i in faces.reshape(-1))
    return f"""<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><contributor><authoring_tool>test</authoring_tool></contributor>{asset}</asset>
  <library_geometries><geometry id="g"><mesh>
    <source id="p"><float_array id="pa" count="{vertices.size}">{floats}</float_array>
      <technique_common><accessor source="#pa" count="{len(vertices)}" stride="3">
        <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
      </accessor></technique_common></source>
    <vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
    <triangles count="{len(faces)}"><input semantic="VERTEX" source="#v" offset="0"/><p>{tris}</p></triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="s"><node id="house" name="house">
    <instance_geometry url="#g"/></node></visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>
"""


@pytest.mark.parametrize("unit,up", [(None, None), (0.0254, "Z"), (1.0, "Y"), (0.001, "X")])
def test_collada_models_are_read_in_metres_with_z_up(tmp_path, unit, up):
    """COLLADA (.dae: SketchUp's and Google Earth's building models) says its unit and up axis;
    the house is read in metres with z up whatever they are (10 m x 6 m, 4 m tall)."""
    from meshsom.preprocess import preprocess

    v, f = box(10.0, 6.0, 4.0)
    scale = 1.0 / (unit or 1.0)
    turn = {None: np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), "Y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
            "Z": np.eye(3), "X": np.array([[0, 0, 1.0], [0, 1, 0], [-1, 0, 0]])}[up]  # z up -> the file's axis
    (tmp_path / "house.dae").write_text(_collada(unit, up, (v * scale) @ turn.T, f))
    (m,) = read_file(tmp_path / "house.dae")
    assert isinstance(m, RawMesh), m
    world = m.vertices + m.origin
    np.testing.assert_allclose(world.max(axis=0) - world.min(axis=0), [10, 6, 4], atol=1e-5)  # pycollada: float32
    assert preprocess(m.vertices, m.faces).volume_out == pytest.approx(240, rel=1e-6)


KML = """<?xml version="1.0" encoding="UTF-8"?>
<kml xmlns="http://www.opengis.net/kml/2.2"><Document>
 <Placemark><name>town hall</name><Model id="m1">
  <altitudeMode>absolute</altitudeMode>
  <Location><longitude>{lon}</longitude><latitude>{lat}</latitude><altitude>12.5</altitude></Location>
  <Orientation><heading>{heading}</heading><tilt>0</tilt><roll>0</roll></Orientation>
  <Scale><x>2</x><y>2</y><z>2</z></Scale>
  <Link><href>models/a.dae</href></Link></Model></Placemark>
 <Placemark><name>lost</name><Model><Location><longitude>4</longitude><latitude>52</latitude></Location>
  <Link><href>./models/c.dae</href></Link></Model></Placemark>
</Document></kml>"""


def _kmz_members(lat, lon, heading) -> dict[str, str]:
    """A KMZ's members as SketchUp writes them: doc.kml placing models/a.dae (inches, z up) and a
    missing c.dae; models/b.dae (y up) is placed by no Model."""
    v, f = box(10.0, 6.0, 4.0)  # from the origin: x 0..10, y 0..6, z 0..4
    return {"doc.kml": KML.format(lat=lat, lon=lon, heading=heading),
            "models/a.dae": _collada(0.0254, "Z", v / 0.0254, f),
            "models/b.dae": _collada(None, "Y", v[:, [0, 2, 1]] * [1, 1, -1], f)}


@pytest.mark.parametrize("form", ["kmz", "folder", "kml"])
@pytest.mark.parametrize("lat, lon, heading", [(52.0116, 4.3571, 30.0), (-33.92, 18.42, -75.0)])
def test_a_kmz_places_its_collada_models_where_its_kml_says(tmp_path, lat, lon, heading, form):
    """A KMZ (Google Earth, SketchUp, 3D Warehouse: a KML and the COLLADA models it places, in a
    zip), the same unzipped into a folder, or its KML named by itself: a model linked by a KML Model
    is moved to its location in WGS 84's UTM zone (the model's origin at the projected point),
    turned by its heading (clockwise from true north) and the meridian convergence (pyproj's),
    scaled, at its absolute altitude. A model no Model links stays in its own frame (noted in a
    KMZ); a Model linking a model that is not there is a rejection."""
    import zipfile

    import pyproj

    v, f = box(10.0, 6.0, 4.0)
    members = _kmz_members(lat, lon, heading)
    if form == "kmz":
        with zipfile.ZipFile(tmp_path / "town.kmz", "w") as z:
            for member, text in members.items():
                z.writestr(member, text)
        items, prefix = list(read_file(tmp_path / "town.kmz")), "town.kmz/"
    else:
        for member, text in members.items():
            (tmp_path / "town" / member).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / "town" / member).write_text(text)
        skipped = []
        files, rejected = expand_inputs([tmp_path / "town" / "doc.kml" if form == "kml" else tmp_path / "town"], skipped)
        assert not rejected
        assert sorted(x.name for x in files) == (["doc.kml"] if form == "kml" else ["doc.kml", "models/b.dae"])
        if form == "folder":  # a.dae is read through the KML only, once
            assert skipped == [(str(tmp_path / "town/models/a.dae"), f"placed by a KML Model of {tmp_path / 'town/doc.kml'}, "
                                                                       "read through it")], skipped
        items, prefix = [i for x in files for i in read_file(x.path, ReaderOptions(), x.name)], ""
        if form == "kml":  # the model no Model places is not read
            items.append(next(read_file(tmp_path / "town/models/b.dae", ReaderOptions(), "models/b.dae")))
    assert sorted(i.id for i in items) == [f"{prefix}models/a.dae#g", f"{prefix}models/b.dae#g", f"{prefix}models/c.dae"]
    placed, unplaced, lost = sorted(items, key=lambda i: i.id)
    assert isinstance(lost, Rejection) and "does not hold it" in lost.reason, lost
    zone = int((lon + 180) // 6) + 1
    epsg = (32600 if lat > 0 else 32700) + zone
    east, north = pyproj.Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform(lon, lat)
    turn = np.radians(pyproj.Proj(f"EPSG:{epsg}").get_factors(lon, lat).meridian_convergence - heading)
    rotation = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    expected = (2.0 * v) @ rotation.T + [east, north, 12.5]
    world = placed.vertices + placed.origin
    from scipy.spatial import cKDTree

    for a, b in ((world, expected), (expected, world)):  # the same corners (pycollada: float32)
        assert cKDTree(b).query(a)[0].max() < 1e-3
    assert any(f"(EPSG:{epsg})" in n and "'town hall'" in n and "scaled by 2, 2, 2" in n for n in placed.notes), placed.notes
    world = unplaced.vertices + unplaced.origin
    np.testing.assert_allclose(world.max(axis=0) - world.min(axis=0), [10, 6, 4], atol=1e-5)
    assert any("no Model of the archive's KML places it" in n for n in unplaced.notes) == (form == "kmz"), unplaced.notes


def test_a_kmz_whose_kml_cannot_place_its_models_lists_why(tmp_path):
    """A KML that is not XML, a Model without a location, one off the earth, one with a negative
    scale: each listed as a rejection saying why; the models are read in their own frames."""
    import zipfile

    v, f = box(10.0, 6.0, 4.0)
    models = "".join(f"<Placemark><name>m{k}</name><Model>{body}<Link><href>{k}.dae</href></Link></Model></Placemark>"
                     for k, body in enumerate(["", "<Location><longitude>200</longitude><latitude>52</latitude></Location>",
                                               "<Location><longitude>4</longitude><latitude>52</latitude></Location>"
                                               "<Scale><x>-1</x></Scale>"]))
    with zipfile.ZipFile(tmp_path / "bad.kmz", "w") as z:
        z.writestr("doc.kml", f"<kml><Document>{models}</Document></kml>")
        z.writestr("broken.kml", "<kml><Placemark>")
        for k in range(3):
            z.writestr(f"{k}.dae", _collada(None, "Z", v, f))
    items = list(read_file(tmp_path / "bad.kmz"))
    reasons = {i.id: i.reason for i in items if isinstance(i, Rejection)}
    assert "not XML" in reasons["bad.kmz/broken.kml"]
    assert "Model 1 ('m0') of doc.kml (0.dae): no <Location>" in reasons["bad.kmz/doc.kml#Model1"], reasons
    assert "are not on the earth" in reasons["bad.kmz/doc.kml#Model2"]
    assert "is not positive" in reasons["bad.kmz/doc.kml#Model3"]
    meshes = [i for i in items if isinstance(i, RawMesh)]
    assert len(meshes) == 3 and all(any("in its own frame" in n for n in m.notes) for m in meshes)


def test_a_kml_that_places_nothing_it_may_read_says_why(tmp_path):
    """A KML whose Model links a model outside the KML's folder (not followed, as a link out of a
    folder is not), or whose polygon has no ring, is a rejection naming the file and the problem; one of points
    only says it holds no building; the model outside is not read."""
    v, f = box(10.0, 6.0, 4.0)
    (tmp_path / "elsewhere.dae").write_text(_collada(None, "Z", v, f))
    (tmp_path / "town").mkdir()
    (tmp_path / "town/doc.kml").write_text(
        "<kml><Document><Placemark><Model><Location><longitude>4</longitude><latitude>52</latitude></Location>"
        "<Link><href>../elsewhere.dae</href></Link></Model></Placemark></Document></kml>")
    (tmp_path / "town/outlines.kml").write_text(
        "<kml><Document><Placemark><Polygon><extrude>1</extrude></Polygon></Placemark></Document></kml>")
    (tmp_path / "town/pins.kml").write_text(
        "<kml><Document><Placemark><Point><coordinates>4,52,0</coordinates></Point></Placemark></Document></kml>")
    files, rejected = expand_inputs([tmp_path / "town"])
    assert not rejected and [x.name for x in files] == ["doc.kml", "outlines.kml", "pins.kml"]
    items = [i for x in files for i in read_file(x.path, ReaderOptions(), x.name)]
    assert all(isinstance(i, Rejection) for i in items) and [i.id for i in items] == [
        "doc.kml#../elsewhere.dae", "outlines.kml#Placemark1", "pins.kml"]
    assert "links '../elsewhere.dae', outside its folder; not followed" in items[0].reason
    assert items[1].source == str(tmp_path / "town/outlines.kml") and "its Polygon cannot be read" in items[1].reason
    assert "holds no KML <Model> linking a 3D model and no Polygon extruded from the ground" in items[2].reason


def _kml_polygon(ring_m, altitude, mode="relativeToGround", extrude=1, dx=0.0) -> str:
    from footprints import closed, lonlat

    coordinates = " ".join(f"{lon:.9f},{lat:.9f},{altitude}" for lon, lat in closed(lonlat([(x + dx, y) for x, y in ring_m])))
    return (f"<Polygon><extrude>{extrude}</extrude><altitudeMode>{mode}</altitudeMode><outerBoundaryIs><LinearRing>"
            f"<coordinates>{coordinates}</coordinates></LinearRing></outerBoundaryIs></Polygon>")


@pytest.mark.parametrize("form", ["kml", "kmz"])
def test_buildings_drawn_in_kml_as_extruded_polygons(tmp_path, form):
    """Google Earth's buildings and ArcGIS' Layer To KML: a Polygon extruded to 12 m above the ground is a 12 m block
    (volume by hand); a MultiGeometry of blocks at 6 and 15 m one building of two parts; absolute altitudes with an
    ExtendedData height read by it, without one refused saying why; a polygon not extruded refused as a flat area."""
    import zipfile

    from footprints import rectangle
    from meshsom.preprocess import PreprocessParams
    from pipelines.ingest import process_one

    a, b = rectangle(0, 0, 10, 8), rectangle(10, 0, 6, 8)
    placemarks = [
        f'<Placemark id="tower"><name>Tower</name>{_kml_polygon(a, 12)}</Placemark>',
        f"<Placemark><name>Two</name><MultiGeometry>{_kml_polygon(a, 6, dx=40)}{_kml_polygon(b, 15, dx=40)}"
        "</MultiGeometry></Placemark>",
        f'<Placemark id="abs"><ExtendedData><SchemaData schemaUrl="#s"><SimpleData name="height">9</SimpleData>'
        f'</SchemaData></ExtendedData>{_kml_polygon(a, 430, mode="absolute", dx=80)}</Placemark>',
        f'<Placemark id="absnone">{_kml_polygon(a, 430, mode="absolute", dx=120)}</Placemark>',
        f'<Placemark id="lawn">{_kml_polygon(a, 0, mode="clampToGround", extrude=0, dx=160)}</Placemark>',
        '<Placemark id="cut"><Polygon><extrude>1</extrude><altitudeMode>relativeToGround</altitudeMode><outerBoundaryIs>'
        '<LinearRing><coordinates>4.3,52.0,10 4.4 4.3,52.1,10 4.3,52.0,10</coordinates></LinearRing></outerBoundaryIs>'
        '</Polygon></Placemark>',
    ]
    text = ('<?xml version="1.0" encoding="UTF-8"?><kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            + "".join(placemarks) + "</Document></kml>")
    if form == "kml":
        path = tmp_path / "town.kml"
        path.write_text(text)
    else:
        path = tmp_path / "town.kmz"
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("doc.kml", text)
    items = {i.id.split("#")[1]: i for i in read_file(path)}
    assert sorted(items) == ["Placemark2", "abs", "absnone", "cut", "lawn", "tower"], sorted(items)
    assert items["cut"].reason == ("KML: its Polygon cannot be read (a position that is not 2 or 3 finite numbers "
                                   "(lon,lat[,alt]))")

    def volume(item):
        record, _ = process_one(item, PreprocessParams())
        assert record["status"] == "accepted", record
        return record["volume"]

    assert volume(items["tower"]) == pytest.approx(80 * 12, rel=1e-5)
    assert len(items["Placemark2"].parts) == 2 and volume(items["Placemark2"]) == pytest.approx(80 * 6 + 48 * 15, rel=1e-5)
    assert volume(items["abs"]) == pytest.approx(80 * 9, rel=1e-5)
    assert isinstance(items["absnone"], Rejection) and items["absnone"].reason.endswith(
        "its altitudes are absolute: the ground beneath is not in KML (export it relative to the ground)")
    assert isinstance(items["lawn"], Rejection) and "a flat area, not a building" in items["lawn"].reason


def test_a_collada_geometry_of_several_materials_is_one_building(tmp_path):
    """SketchUp writes a COLLADA geometry's faces as one <triangles> per material (Macky Auditorium's KMZ in Google's
    KML samples: 12 geometries, 52 material primitives); trimesh makes each primitive a geometry (id, id_1, ...),
    and each was read as a building, open where the materials met. A geometry is one building, its id the
    geometry's: the box (walls one material, roof and floor another) is one of 10 x 6 x 4 m."""
    v, f = box(10.0, 6.0, 4.0)
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    walls, caps = f[np.abs(normals[:, 2]) < 1e-9], f[np.abs(normals[:, 2]) >= 1e-9]
    doc = _collada(None, "Z", v, walls)
    second = (f'<triangles count="{len(caps)}"><input semantic="VERTEX" source="#v" offset="0"/>'
              f'<p>{" ".join(str(int(i)) for i in caps.reshape(-1))}</p></triangles>')
    doc = doc.replace("</triangles>\n  </mesh>", "</triangles>" + second + "\n  </mesh>")
    assert doc.count("<triangles") == 2
    (tmp_path / "house.dae").write_text(doc)
    items = list(read_file(tmp_path / "house.dae"))
    assert [type(m).__name__ for m in items] == ["RawMesh"], items
    (m,) = items
    assert m.id == "house.dae#g" and len(m.faces) == len(f)
    t = m.vertices[m.faces]
    assert abs(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6) == pytest.approx(240.0)
