from pathlib import Path

import numpy as np
import pytest
import trimesh

from cityjson_samples import CUBE_VERTS, HEXAGON_MM, cube_solid, doc, two_buildings, write
from meshsom.errors import InputFileError
from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, read_file


def _read(path, **opts):
    out = list(read_file(path, ReaderOptions(**opts)))
    return [r for r in out if isinstance(r, RawMesh)], [r for r in out if isinstance(r, Rejection)]


def _volume(m):
    return trimesh.Trimesh(m.vertices, m.faces, process=True).volume


def test_cityjson_buildings_parts_merged_lod_highest(tmp_path):
    path = write(tmp_path / "two.city.json", two_buildings())
    ok, rej = _read(path)
    assert rej == []
    assert [m.id for m in ok] == ["two.city.json#A", "two.city.json#B"]  # the Road is not a building
    a, b = ok
    assert a.lod == "2" and _volume(a) == pytest.approx(2.0)
    assert b.lod == "1" and _volume(b) == pytest.approx(2.0)  # two unit cubes merged
    assert a.label == "cube" and b.label == "pair"


def test_cityjson_lod_choice_and_missing_lod(tmp_path):
    path = write(tmp_path / "two.city.json", two_buildings())
    ok, _ = _read(path, lod="lowest")
    assert _volume(ok[0]) == pytest.approx(1.0)
    ok, rej = _read(path, lod="2")
    assert [m.id for m in ok] == ["two.city.json#A"]
    assert rej[0].id == "two.city.json#B" and "no geometry at LoD 2 (available: 1)" in rej[0].reason


def test_cityjson_parts_kept_apart(tmp_path):
    path = write(tmp_path / "two.city.json", two_buildings())
    ok, rej = _read(path, parts="separate")
    assert [m.id for m in ok] == ["two.city.json#A", "two.city.json#B1", "two.city.json#B2"]
    assert rej == []


def test_buildings_in_a_cityobjectgroup_and_the_3d_bags_footprints_are_read_as_buildings(tmp_path):
    """A CityObjectGroup's members name it among their "parents" (cjval's and the CityJSON corpus' files): they are
    buildings of their own, not parts, in every parts mode. With parts kept apart, a Building whose own geometry is
    a LoD 0 footprint beside its parts' solids (the 3D BAG) is its parts, not a rejected footprint."""
    d = two_buildings()
    d["CityObjects"]["grp"] = {"type": "CityObjectGroup", "children": ["A", "B"]}
    for oid in ("A", "B"):
        d["CityObjects"][oid]["parents"] = ["grp"]
    path = write(tmp_path / "grouped.city.json", d)
    ok, rej = _read(path)
    assert [m.id for m in ok] == ["grouped.city.json#A", "grouped.city.json#B"] and rej == []
    assert _volume(ok[1]) == pytest.approx(2.0)  # B's two parts still merged into it
    ok, rej = _read(path, parts="separate")
    assert [m.id for m in ok] == ["grouped.city.json#A", "grouped.city.json#B1", "grouped.city.json#B2"] and rej == []
    d = two_buildings()
    d["vertices"] += [[0, 0, 0], [5000, 0, 0], [5000, 1000, 0], [0, 1000, 0]]
    n = len(d["vertices"])
    d["CityObjects"]["B"]["geometry"] = [{"type": "MultiSurface", "lod": "0", "boundaries": [[[n - 4, n - 3, n - 2, n - 1]]]}]
    path = write(tmp_path / "bag.city.json", d)
    ok, rej = _read(path, parts="separate")
    assert [m.id for m in ok] == ["bag.city.json#A", "bag.city.json#B1", "bag.city.json#B2"] and rej == []
    ok, rej = _read(path, parts="separate", lod="0")  # asked for by name: the footprint is read
    assert [r.id for r in ok + rej if r.id.endswith("#B")] == ["bag.city.json#B"]


def test_recentring_keeps_millimetres_at_lv95_offsets(tmp_path):
    d = doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, [[x + 123, y + 7, z] for x, y, z in CUBE_VERTS])
    path = write(tmp_path / "lv95.city.json", d)
    (m,), _ = _read(path)
    world = m.vertices + m.origin
    expected = np.array(CUBE_VERTS, float) / 1000 + [2600000.123, 1200000.007, 400.0]
    assert np.abs(np.sort(world, axis=0) - np.sort(expected, axis=0)).max() < 1e-6
    # Local float32 coordinates still resolve a millimetre exactly.
    local32 = m.vertices.astype(np.float32).astype(np.float64)
    assert np.abs(local32 * 1000 - np.round(local32 * 1000)).max() < 1e-3
    assert np.abs(m.vertices).max() <= 0.5 + 1e-12


def test_polygon_with_hole_and_multisurface(tmp_path):
    # A flat square with a square hole, as a MultiSurface (open, but the reader only triangulates).
    verts = [[0, 0, 0], [4000, 0, 0], [4000, 4000, 0], [0, 4000, 0], [1000, 1000, 0], [1000, 3000, 0], [3000, 3000, 0], [3000, 1000, 0]]
    geom = {"type": "MultiSurface", "lod": "2", "boundaries": [[[0, 1, 2, 3], [4, 5, 6, 7]]]}
    path = write(tmp_path / "hole.city.json", doc({"H": {"type": "Building", "geometry": [geom]}}, verts))
    (m,), _ = _read(path)
    assert len(m.faces) == 8
    area = trimesh.Trimesh(m.vertices, m.faces, process=False).area
    assert area == pytest.approx(16 - 4)


def test_composite_solid_and_version_1_0_float_vertices(tmp_path):
    verts = [[x / 1000, y / 1000, z / 1000] for x, y, z in CUBE_VERTS]
    geom = {"type": "CompositeSolid", "lod": 1, "boundaries": [cube_solid()["boundaries"]]}
    d = doc({"C": {"type": "Building", "geometry": [geom]}}, verts, version="1.0", transform=False)
    (m,), rej = _read(write(tmp_path / "v10.json", d))
    assert rej == [] and _volume(m) == pytest.approx(1.0)


@pytest.mark.parametrize("kind, version, transform", [
    ("CityModel", "http://www.cityjson.org/version/0.1", False),  # the Munich sample of the specification
    ("CityModel", None, True),  # its "compressed" copy: no version, a transform
    ("CityJSON", "0.6", False),  # the Montreal sample
    ("CityJSON", "0.9", True),
])
def test_cityjson_drafts_are_read_as_1_0(tmp_path, kind, version, transform):
    """CityJSON's drafts (2017-2019) encode geometry as 1.0 does; up to 0.2 their type was "CityModel",
    their version a URL, their semantics a list of names and their LoD a number."""
    verts = [[x / 1000 + 4424648.79, y / 1000 + 5482614.69, z / 1000 + 310.19] for x, y, z in CUBE_VERTS]
    if transform:
        verts = CUBE_VERTS
    geom = {**cube_solid(lod=2), "semantics": [["Wall"] * 6]}
    d = doc({"DEBY_LOD2_1": {"type": "Building", "geometry": [geom]}}, verts, transform=transform)
    d["type"] = kind
    if version is None:
        del d["version"]
    else:
        d["version"] = version
    (m,), rej = _read(write(tmp_path / "draft.json", d))
    assert rej == [] and _volume(m) == pytest.approx(1.0) and m.lod == "2"


def test_cityjson_1_1_upgrade_path_reads_real_zurich(data_dir):
    ok, rej = _read(data_dir / "zurich-lod2-subset" / "zurich_subset_lod2.city.json")
    assert len(ok) + len(rej) == 49 and len(ok) == 49
    assert all(m.lod == "2" for m in ok)


def test_extrusion_from_lod2_gives_closed_blocks(data_dir):
    ok, rej = _read(data_dir / "zurich-lod2-subset" / "zurich_subset_lod2.city.json", extrude_lod1=True)
    assert len(ok) == 49 and rej == []
    for m in ok:
        t = trimesh.Trimesh(m.vertices, m.faces, process=True)
        assert t.is_watertight and t.volume > 0, m.id
        assert m.lod.startswith("1 (extruded")


# ---------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "name, content, reason",
    [
        ("empty.city.json", b"", "file is empty"),
        ("trunc.city.json", b'{"type": "CityJSON", "version": "2.0", "vert', "invalid JSON at line 1"),
        ("bin.city.json", b"\xff\xfe\x00garbage", "is not UTF-8 text"),
        ("notcj.json", b'{"type": "Topology", "objects": {}}', "not CityJSON"),
        ("list.city.json", b'[1, 2]', "is JSON but not CityJSON (expected \"type\": \"CityJSON\", found 'list')"),
        ("nofeatures.geojson", b'{"type": "FeatureCollection"}', "without a \"features\" list"),
        ("empty.geojson", b'{"type": "FeatureCollection", "features": []}', "of no features"),
        ("new.city.json", b'{"type": "CityJSON", "version": "3.0", "CityObjects": {}, "vertices": []}',
         "version '3.0' is not supported; expected one of 1.0, 1.1, 2.0 (or a draft, 0.1-0.9)"),
        ("oldseq.city.jsonl", b'{"type": "CityModel", "version": "0.9", "CityObjects": {}, "vertices": []}', "not a CityJSON header"),
        ("noverts.city.json", b'{"type": "CityJSON", "version": "2.0", "CityObjects": {}}', 'no "vertices"'),
        ("empty.obj", b"", "file is empty"),
        ("corrupt.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 99\nproperty float x\nend_header\n\x00\x01", "cannot be read as .ply"),
        ("nofaces.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "holds a PointCloud, expected a triangle mesh"),
    ],
)
def test_bad_files_are_rejected_with_reason(tmp_path, name, content, reason):
    path = tmp_path / name
    path.write_bytes(content)
    ok, rej = _read(path)
    assert ok == []
    assert len(rej) == 1 and rej[0].id == str(path)
    assert reason in rej[0].reason


@pytest.mark.parametrize("version", ["1.1", "2.0"])
def test_missing_transform_reads_vertices_as_coordinates(tmp_path, version):
    """1.1 and 2.0 require a transform, but files without one exist (cjio's test data): their
    vertices are coordinates, as in 1.0; integers or not, they are not scaled."""
    verts = [[x / 1000 + 85000.25, y / 1000 + 446000.5, z / 1000] for x, y, z in CUBE_VERTS]
    d = doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, verts, version=version, transform=False)
    (m,), rej = _read(write(tmp_path / "t.city.json", d))
    assert rej == []
    np.testing.assert_allclose(m.origin, [85000.75, 446001.0, 0.5])
    np.testing.assert_allclose(np.ptp(m.vertices, axis=0), [1, 1, 1])


def test_out_of_range_vertex_index_rejects_that_building_only(tmp_path):
    bad = cube_solid()
    bad["boundaries"][0][0][0][0] = 99
    d = doc({"bad": {"type": "Building", "geometry": [bad]}, "good": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS)
    ok, rej = _read(write(tmp_path / "idx.city.json", d))
    assert [m.id for m in ok] == ["idx.city.json#good"]
    assert rej[0].id == "idx.city.json#bad"
    assert rej[0].reason == "vertex index 99 out of range (the file has 8 vertices)"


def test_too_many_vertices_refused_before_reading_geometry(tmp_path):
    d = doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS)
    _, (rej,) = _read(write(tmp_path / "big.city.json", d), max_vertices=4)
    assert "declares 8 vertices, more than the limit of 4" in rej.reason


def test_unknown_extension_and_missing_path(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    files, rej = expand_inputs([tmp_path / "notes.txt", tmp_path / "missing.obj", tmp_path])
    assert files == []
    reasons = [r.reason for r in rej]
    assert "unknown file type '.txt'" in reasons[0]
    assert reasons[1] == "no such file or folder"
    assert reasons[2] == "folder holds no readable mesh or CityJSON file"


def test_trimesh_formats_and_labels_csv(tmp_path, cube):
    v, f = cube
    for ext in ("obj", "ply", "stl", "off", "glb"):
        trimesh.Trimesh(v + [2.6e6, 1.2e6, 400], f, process=False).export(tmp_path / f"c.{ext}")
    (tmp_path / "labels.csv").write_text("file,label\nc.obj,box\n")
    files, _ = expand_inputs([tmp_path])
    assert sorted(f.path.suffix for f in files) == [".glb", ".obj", ".off", ".ply", ".stl"]
    assert sorted(f.name for f in files) == ["c.glb", "c.obj", "c.off", "c.ply", "c.stl"]
    for p in (f.path for f in files):
        (m,) = [r for r in read_file(p) if isinstance(r, RawMesh)]
        assert _volume(m) == pytest.approx(1.0), p
        assert np.allclose(m.origin, [2.6e6 + 0.5, 1.2e6 + 0.5, 400.5]), p
        assert m.label == ("box" if p.suffix == ".obj" else None)


@pytest.mark.parametrize("ext", ["glb", "obj"])
def test_y_up_mesh_files_are_turned_z_up(tmp_path, ext):
    """A house 4 m wide, 6 m deep and 9 m tall written y-up (glTF's axes; Blender's OBJ export): with
    up_axis "y" it stands 9 m tall in z, the same volume, outward; the default reads it as given."""
    box = trimesh.creation.box(bounds=[[0, 0, 0], [4, 9, 6]])  # y is the up axis here: 9 m
    box.export(tmp_path / f"house.{ext}")
    (as_given,) = read_file(tmp_path / f"house.{ext}")
    (turned,) = read_file(tmp_path / f"house.{ext}", ReaderOptions(up_axis="y"))
    assert np.ptp(as_given.vertices, axis=0) == pytest.approx([4, 9, 6])
    assert np.ptp(turned.vertices, axis=0) == pytest.approx([4, 6, 9])
    assert _volume(turned) == pytest.approx(_volume(as_given)) == pytest.approx(4 * 9 * 6)
    np.testing.assert_allclose(turned.origin, [2, -3, 4.5])  # (x, -z, y) of the centre (2, 4.5, 3)
    with pytest.raises(ValueError, match="up_axis must be one of auto, z, y"):
        ReaderOptions(up_axis="x")


@pytest.mark.parametrize("ext", ["glb", "gltf"])
def test_a_gltf_file_is_y_up_as_its_specification_says_unless_trimesh_wrote_it(tmp_path, ext):
    """glTF's axes are y up: a house (4 m wide, 9 m tall, 6 m deep) that Blender's exporter wrote stands 9 m tall in
    z by default, noted, and as given with up_axis "z"; one trimesh wrote (trimesh writes the coordinates it is
    given, as the tests' files are) is read as given; an OBJ file is read as given."""
    box = trimesh.creation.box(bounds=[[0, 0, 0], [4, 9, 6]])
    if ext == "glb":
        data = box.export(file_type="glb")
    else:  # one file, its buffer embedded
        data = trimesh.exchange.gltf.export_gltf(trimesh.Scene(box), embed_buffers=True)["model.gltf"]
    trimesh_name, blender = b"https://github.com/mikedh/trimesh", b"Khronos glTF Blender I/O v4.2.69"
    assert trimesh_name in data
    (tmp_path / f"trimesh.{ext}").write_bytes(data)
    (tmp_path / f"blender.{ext}").write_bytes(data.replace(trimesh_name, blender.ljust(len(trimesh_name))))
    (default,) = read_file(tmp_path / f"blender.{ext}")
    (as_given,) = read_file(tmp_path / f"blender.{ext}", ReaderOptions(up_axis="z"))
    (by_trimesh,) = read_file(tmp_path / f"trimesh.{ext}")
    assert np.ptp(default.vertices, axis=0) == pytest.approx([4, 6, 9]) and "y up by its specification" in default.notes[0]
    assert np.ptp(as_given.vertices, axis=0) == pytest.approx([4, 9, 6]) and as_given.notes == ()
    assert np.ptp(by_trimesh.vertices, axis=0) == pytest.approx([4, 9, 6]) and by_trimesh.notes == ()
    assert _volume(default) == pytest.approx(4 * 9 * 6)


# ---------------------------------------------------------------------------- --extrude-lod1 footprints


def _footprint_building(tmp_path, rings, z0=0, z1=6000, name="f.city.json"):
    """One Building whose BuildingParts are LoD2 prisms (MultiSurface, no floor) over the rings (mm)."""
    from cityjson_samples import prism_surfaces

    verts, objects = [], {"B": {"type": "Building", "children": [f"P{k}" for k in range(len(rings))]}}
    for k, ring in enumerate(rings):
        v, polys = prism_surfaces(ring, z0, z1, len(verts), floor=False)
        verts += v
        objects[f"P{k}"] = {"type": "BuildingPart", "parents": ["B"],
                            "geometry": [{"type": "MultiSurface", "lod": "2", "boundaries": polys}]}
    return write(tmp_path / name, doc(objects, verts))


def _extruded(path):
    ok, rej = _read(path, extrude_lod1=True)
    assert rej == [] and len(ok) == 1
    m = ok[0]
    t = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert t.is_watertight and t.is_winding_consistent
    return m, t


def _shapely_footprint(rings):
    import shapely

    return shapely.union_all([shapely.Polygon(np.array(r, float) / 1000) for r in rings])


@pytest.mark.parametrize(
    "rings",
    [
        [[[0, 0], [1000, 0], [1000, 2000], [0, 2000]]],  # a 2 m2 shed
        [HEXAGON_MM],  # a real 83.6 m2 block the old buffer trick emptied
        [[[0, 0], [10000, 0], [10000, 8000], [0, 8000]], [[10000, 0], [16000, 0], [16000, 8000], [10000, 8000]]],
    ],
    ids=["2 m2", "hexagon", "two parts sharing a wall"],
)
def test_extruded_footprint_is_the_union_of_all_parts(tmp_path, rings):
    m, t = _extruded(_footprint_building(tmp_path, rings))
    fp = _shapely_footprint(rings)
    assert fp.geom_type == "Polygon"
    assert t.volume == pytest.approx(fp.area * 6, rel=1e-9)
    assert t.area == pytest.approx(2 * fp.area + fp.length * 6, rel=1e-9)
    assert len(t.vertices) == 2 * len(fp.simplify(0).exterior.coords[:-1])
    assert m.notes == () and m.parts == () and m.face_part is None


def test_footprint_of_disjoint_polygons_is_extruded_whole(tmp_path):
    ell = [[0, 0], [12000, 0], [12000, 4000], [4000, 4000], [4000, 9000], [0, 9000]]
    tri = [[30000, 0], [35000, 0], [30000, 3000]]  # 7.5 m2, far from the L
    m, t = _extruded(_footprint_building(tmp_path, [ell, tri], 1000, 7000))
    fp = _shapely_footprint([ell, tri])
    assert fp.geom_type == "MultiPolygon" and len(fp.geoms) == 2
    assert t.volume == pytest.approx(fp.area * 6, rel=1e-9)  # both polygons: nothing lost
    assert t.area == pytest.approx(2 * fp.area + fp.length * 6, rel=1e-9)
    assert len(t.split(only_watertight=True)) == 2
    assert any("footprint of 2 disjoint polygons" in n for n in m.notes)


def test_footprint_seams_are_filled_but_courtyards_kept(tmp_path):
    """Two roofs that miss each other by up to 1 mm leave a seam (filled); a 4 x 4 m courtyard stays."""
    a = [[0, 0], [10000, 0], [10000, 10000], [0, 10000]]
    b = [[10000, 0], [20000, 0], [20000, 10000], [10000, 10000], [10000, 6000], [10001, 5000], [10000, 4000]]  # 1 mm kink
    m, t = _extruded(_footprint_building(tmp_path, [a, b]))
    assert t.volume == pytest.approx(200 * 6, rel=1e-9)
    assert m.notes == ("filled 1 seam(s) between roof polygons in the footprint",)
    roof = [[0, 1, 2, 3], [4, 7, 6, 5]]  # 20 x 20 m roof with a 4 x 4 m courtyard, at 6 m
    wall = [[0, 8, 9, 1]]  # one wall down to the ground gives the z-range
    verts = [[0, 0, 6000], [20000, 0, 6000], [20000, 20000, 6000], [0, 20000, 6000],
             [8000, 8000, 6000], [12000, 8000, 6000], [12000, 12000, 6000], [8000, 12000, 6000],
             [0, 0, 0], [20000, 0, 0]]
    court = doc({"C": {"type": "Building", "geometry": [{"type": "MultiSurface", "lod": "2", "boundaries": [roof, wall]}]}}, verts)
    m2, t2 = _extruded(write(tmp_path / "court.city.json", court))
    assert t2.volume == pytest.approx((400 - 16) * 6, rel=1e-9)
    assert t2.area == pytest.approx(2 * 384 + (80 + 16) * 6, rel=1e-9)


# ---------------------------------------------------------------------------- ids


def test_same_file_name_in_two_folders_gives_distinct_ids(tmp_path):
    for sub in ("north", "south/deep"):
        (tmp_path / "in" / sub).mkdir(parents=True)
        write(tmp_path / "in" / sub / "tile.city.json", doc({"A": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS))
    files, rej = expand_inputs([tmp_path / "in"])
    assert rej == [] and [f.name for f in files] == ["north/tile.city.json", "south/deep/tile.city.json"]
    ids = [m.id for f in files for m in read_file(f.path, ReaderOptions(), f.name)]
    assert ids == ["north/tile.city.json#A", "south/deep/tile.city.json#A"]
    with pytest.raises(InputFileError) as err:  # the two files given by themselves: both named tile.city.json
        expand_inputs([tmp_path / "in" / "north" / "tile.city.json", tmp_path / "in" / "south" / "deep" / "tile.city.json"])
    assert "north" in str(err.value) and "deep" in str(err.value) and "'tile.city.json'" in str(err.value)


CUBE_OBJ = "".join(f"v {x} {y} {z}\n" for x, y, z in [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)])


@pytest.mark.parametrize("name,text,reason", [
    # val3dity's test file: a face of a cube refers to a ninth vertex
    ("index901.obj", CUBE_OBJ + "f 1 4 3 2\nf 5 6 7 8\nf 1 2 9 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n",
     "the face on line 11 refers to vertex 9, and the file has 8 vertices before it"),
    ("zero.obj", CUBE_OBJ + "f 1 4 3 2\nf 0 5 6\n", "the face on line 10 refers to vertex 0, and the file has 8 vertices"),
    ("back.obj", CUBE_OBJ + "f -1 -2 -9\n", "the face on line 9 refers to vertex -9, and the file has 8 vertices"),
    ("bad.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 7\n3 0 3 2\n",
     "the face on line 9 refers to vertex 7, and the file has 4 vertices (OFF counts from 0)"),
])
def test_a_face_referring_to_a_missing_vertex_is_said_with_its_line(tmp_path, name, text, reason):
    """Where trimesh raised IndexError ("index 8 is out of bounds for axis 0 with size 8"), the
    rejection says which face (its line) refers to which vertex, and how many there are."""
    (tmp_path / name).write_text(text)
    (item,) = read_file(tmp_path / name)
    assert isinstance(item, Rejection) and item.reason.startswith(reason), item.reason


def test_a_0_based_obj_export_is_refused_not_misread(tmp_path):
    """An OBJ written with 0-based indices (a common exporter bug): trimesh took vertex 0 for the
    last one and read a wrong mesh; it is a rejection naming the face and the likely cause."""
    faces = [(0, 3, 2), (0, 2, 1), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5), (2, 3, 7),
             (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    (tmp_path / "zero.obj").write_text(CUBE_OBJ + "".join(f"f {a} {b} {c}\n" for a, b, c in faces))
    (item,) = read_file(tmp_path / "zero.obj")
    assert isinstance(item, Rejection)
    assert item.reason == ("the face on line 9 refers to vertex 0, and the file has 8 vertices before it (OBJ counts "
                           "from 1; negative: back from the last) (a 0-based export?)"), item.reason
    (tmp_path / "one.obj").write_text(CUBE_OBJ + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    (cube,) = read_file(tmp_path / "one.obj")
    assert isinstance(cube, RawMesh) and len(cube.faces) == 12


def test_a_byte_order_mark_before_json_or_mesh_text_is_read(tmp_path):
    """A UTF-8 byte order mark before the text (Windows tools write one): CityJSON was "invalid JSON
    at line 1, column 1: Unexpected UTF-8 BOM", and an OBJ lost its first vertex line. Each reads
    as the same file without it."""
    import json
    from pathlib import Path

    delft = (Path(__file__).resolve().parents[1] / "data" / "real" / "delft-lod1-3dfier" / "delft.city.json").read_bytes()
    document = json.loads(delft)
    header = {k: v for k, v in document.items() if k not in ("CityObjects", "vertices")} | {"CityObjects": {}, "vertices": []}
    features = [json.dumps({"type": "CityJSONFeature", "id": oid, "CityObjects": {oid: obj}, "vertices": document["vertices"]})
                for oid, obj in document["CityObjects"].items() if obj["type"] == "Building"][:3]
    footprints = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"height": 9}, "geometry": {
        "type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 8], [0, 8], [0, 0]]]}}]}
    texts = {"city.city.json": delft, "seq.city.jsonl": "\n".join([json.dumps(header), *features]).encode(),
             "blocks.geojson": json.dumps(footprints).encode(), "cube.obj": CUBE_OBJ.encode() + b"".join(
                 f"f {a} {b} {c}\n".encode() for a, b, c in [(1, 4, 3), (1, 3, 2), (5, 6, 7), (5, 7, 8), (1, 2, 6), (1, 6, 5),
                                                          (2, 3, 7), (2, 7, 6), (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8)])}
    for name, text in texts.items():
        (tmp_path / "plain").mkdir(exist_ok=True)
        (tmp_path / "bom").mkdir(exist_ok=True)
        (tmp_path / "plain" / name).write_bytes(text)
        (tmp_path / "bom" / name).write_bytes(b"\xef\xbb\xbf" + text)
        plain = list(read_file(tmp_path / "plain" / name))
        marked = list(read_file(tmp_path / "bom" / name))
        assert all(isinstance(m, RawMesh) for m in plain + marked) and len(marked) == len(plain) >= 1, (name, marked[:1])
        for a, b in zip(plain, marked):
            np.testing.assert_array_equal(a.vertices + a.origin, b.vertices + b.origin)
            np.testing.assert_array_equal(a.faces, b.faces)


@pytest.mark.parametrize("name,way", [("plan.dwg", "DWG"), ("city.skp", "export it as OBJ"),
                                      ("scan.laz", "point cloud"), ("house.ifcXML", "export the model as .ifc"),
                                      ("notes.txt", None)])
def test_a_building_format_meshsom_does_not_read_says_the_way_in(tmp_path, name, way):
    """DWG, SketchUp, point clouds...: the rejection names the conversion that leads into
    meshsom (and still lists what is read); other unknown types just the list."""
    (tmp_path / name).write_text("x")
    (item,) = read_file(tmp_path / name)
    assert isinstance(item, Rejection) and item.reason.startswith(f"unknown file type '{name[name.index('.'):].lower()}'")
    assert "expected one of .obj" in item.reason
    assert (way in item.reason) if way else ("(" not in item.reason.split(";")[0]), item.reason


@pytest.mark.parametrize("header,turned", [(b"# Blender 4.1.1\n# www.blender.org\n", True),
                                           (b"# Blender v2.93.1 OBJ File: ''\n# www.blender.org\n", True),
                                           (b"# Alias OBJ Model File\n# Exported from SketchUp, (c) 2000-2012 Trimble\n", True),
                                           (b"# https://github.com/mikedh/trimesh\n", False), (b"", False)])
def test_an_obj_file_blender_or_sketchup_wrote_is_y_up_by_default(tmp_path, header, turned):
    """Blender's and SketchUp's OBJ exporters write y up by default (Forward -Z, Up Y; "Swap YZ"): such a file (its
    header comment says who wrote it) is turned to z up by default, noted, and read as given with up_axis "z"; an
    OBJ file of another writer is read as given."""
    box = trimesh.creation.box(bounds=[[0, 0, 0], [4, 9, 6]])  # y up: 9 m tall
    text = box.export(file_type="obj")
    body = "\n".join(line for line in text.splitlines() if not line.startswith("#")) + "\n"
    (tmp_path / "house.obj").write_bytes(header + body.encode())
    (default,) = read_file(tmp_path / "house.obj")
    (as_given,) = read_file(tmp_path / "house.obj", ReaderOptions(up_axis="z"))
    assert np.ptp(default.vertices, axis=0) == pytest.approx([4, 6, 9] if turned else [4, 9, 6])
    assert any("y up, as its exporter writes by default" in n for n in default.notes) == turned
    assert np.ptp(as_given.vertices, axis=0) == pytest.approx([4, 9, 6]) and as_given.notes == ()
    assert _volume(default) == pytest.approx(4 * 9 * 6)


def test_a_3dfier_tile_gives_its_buildings_and_lists_its_land(tmp_path):
    """3dfier's OBJ tiles (its example's testarea.obj: 160 buildings among 570 objects) hold terrain, roads, water,
    forest, bridges and separations as objects beside the buildings, each class a material (``usemtl Terrain``,
    ``BuildingWall``): those are rejections naming their class, not buildings; an OBJ of other materials is as before."""
    cube = [(x, y, z) for z in (0, 3) for y in (0, 4) for x in (0, 5)]
    quads = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (2, 4, 8, 6), (4, 3, 7, 8), (3, 1, 5, 7)]
    lines = ["mtllib ./3dfier.mtl", *(f"v {x + 85000} {y + 447000} {z}" for x, y, z in cube),
             "v 85010 447000 0", "v 85020 447000 0", "v 85020 447010 0",
             "o b1", "usemtl Building", *(f"f {' '.join(map(str, q))}" for q in quads[:2]),
             "usemtl BuildingWall", *(f"f {' '.join(map(str, q))}" for q in quads[2:]),
             "o t1", "usemtl Terrain", "f 9 10 11", "o r1", "usemtl Road", "f 9 10 11"]
    (tmp_path / "tile.obj").write_text("\n".join(lines) + "\n")
    got = {i.id: i for i in read_file(tmp_path / "tile.obj")}
    assert sorted(got) == ["tile.obj#b1", "tile.obj#r1", "tile.obj#t1"]
    assert isinstance(got["tile.obj#b1"], RawMesh) and _volume(got["tile.obj#b1"]) == pytest.approx(60)
    assert got["tile.obj#t1"].reason == "is a 3dfier Terrain object (its material says so), not a building"
    assert "3dfier Road object" in got["tile.obj#r1"].reason
    (tmp_path / "cad.obj").write_text("\n".join(lines).replace("usemtl Terrain", "usemtl Concrete") + "\n")
    assert all(isinstance(i, RawMesh) for i in read_file(tmp_path / "cad.obj"))


def test_a_gltf_mesh_of_several_materials_is_one_building(tmp_path):
    """A glTF node's mesh of two primitives (walls in one material, roof and floor in another: how Blender and SketchUp
    write a house) is one building, the node's; trimesh makes each primitive a geometry of its own, and each was read
    as a building (two of 480 m3: walls capped, roof and floor rebuilt under the roof). A second node reusing the mesh
    is a second building, moved by its transform."""
    from meshsom.gltf_compression import join_glb

    box = trimesh.creation.box(bounds=[[0, 0, 0], [10, 6, 8]])  # 10 x 8 x 6 m, glTF's y up
    v = np.asarray(box.vertices, np.float32)
    f = np.asarray(box.faces, np.uint32)
    normals = np.asarray(box.face_normals)
    walls, caps = f[np.abs(normals[:, 1]) < 0.5], f[np.abs(normals[:, 1]) >= 0.5]
    binary = v.tobytes() + walls.tobytes() + caps.tobytes()
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": v.nbytes},
             {"buffer": 0, "byteOffset": v.nbytes, "byteLength": walls.nbytes},
             {"buffer": 0, "byteOffset": v.nbytes + walls.nbytes, "byteLength": caps.nbytes}]
    accessors = [{"bufferView": 0, "componentType": 5126, "count": len(v), "type": "VEC3",
                  "min": v.min(0).tolist(), "max": v.max(0).tolist()},
                 {"bufferView": 1, "componentType": 5125, "count": walls.size, "type": "SCALAR"},
                 {"bufferView": 2, "componentType": 5125, "count": caps.size, "type": "SCALAR"}]
    doc = {"asset": {"version": "2.0", "generator": "Khronos glTF Blender I/O"}, "scene": 0,
           "scenes": [{"nodes": [0, 1]}],
           "nodes": [{"mesh": 0, "name": "house"}, {"mesh": 0, "name": "neighbour", "translation": [30, 0, 0]}],
           "meshes": [{"name": "house", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0},
                                                       {"attributes": {"POSITION": 0}, "indices": 2, "material": 1}]}],
           "materials": [{"name": "walls"}, {"name": "roof"}],
           "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(binary)}]}
    (tmp_path / "houses.glb").write_bytes(join_glb(doc, binary))
    items = list(read_file(tmp_path / "houses.glb"))
    assert [type(m).__name__ for m in items] == ["RawMesh", "RawMesh"], items
    assert sorted(m.id.split("#")[1] for m in items) == ["house", "neighbour"]
    for m in items:
        assert len(m.faces) == 12 and _volume(m) == pytest.approx(480.0)
    origins = sorted(m.origin[0] for m in items)
    assert origins[1] - origins[0] == pytest.approx(30.0)


def test_primitives_sharing_one_vertex_accessor_keep_only_their_own_vertices(tmp_path):
    """A glTF node of many primitives indexing one shared vertex accessor (Cesium's tiles: 29 primitives of one
    44,268-vertex accessor): trimesh gives each primitive the whole accessor, and joining them into the node's
    building made 1.3 million vertices to weld (95 s, 5.6 GB). Each primitive brings only the vertices it uses:
    20 boxes of 8 corners, one accessor of 160, are 160 vertices, 20 x 48 m3."""
    from meshsom.gltf_compression import join_glb

    boxes = [trimesh.creation.box(bounds=[[12 * k, 0, 0], [12 * k + 4, 3, 4]]) for k in range(20)]
    v = np.concatenate([b.vertices for b in boxes]).astype(np.float32)
    faces = [np.asarray(b.faces, np.uint32) + 8 * k for k, b in enumerate(boxes)]
    binary = v.tobytes() + b"".join(f.tobytes() for f in faces)
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": v.nbytes}]
    accessors = [{"bufferView": 0, "componentType": 5126, "count": len(v), "type": "VEC3",
                  "min": v.min(0).tolist(), "max": v.max(0).tolist()}]
    offset = v.nbytes
    for f in faces:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": f.nbytes})
        accessors.append({"bufferView": len(views) - 1, "componentType": 5125, "count": f.size, "type": "SCALAR"})
        offset += f.nbytes
    doc = {"asset": {"version": "2.0", "generator": "Khronos glTF Blender I/O"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0, "name": "block"}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": k + 1} for k in range(20)]}],
           "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(binary)}]}
    (tmp_path / "block.glb").write_bytes(join_glb(doc, binary))
    (m,) = read_file(tmp_path / "block.glb")
    assert len(m.vertices) == 160 and len(m.faces) == 240
    assert _volume(m) == pytest.approx(20 * 48)


def _shells_building(kind, boxes_mm):
    """One Building "S" whose geometry is a ``kind`` (MultiSolid, CompositeSolid: a solid per box; Solid: the first
    box its exterior shell, the others interior shells) of axis-aligned boxes (mm lo/hi pairs)."""
    from cityjson_samples import box_solid

    verts, shells = [], []
    for lo, hi in boxes_mm:
        corners, solid = box_solid(lo, hi, len(verts))
        verts += corners
        shells.append(solid["boundaries"][0])
    boundaries = [[s] for s in shells] if kind != "Solid" else shells
    return doc({"S": {"type": "Building", "geometry": [{"type": kind, "lod": "2", "boundaries": boundaries}]}}, verts)


@pytest.mark.parametrize("kind, boxes, want", [
    # two solids overlapping by a 1 x 1 x 1 m cube: 2 + 2 - 1
    ("MultiSolid", [((0, 0, 0), (2000, 1000, 1000)), ((1000, 0, 0), (3000, 1000, 1000))], 3.0),
    # a pane half into its frame, 5 cm of 10 (a CompositeSolid's solids drawn to overlap): 0.4 + 0.1 - 0.05
    ("CompositeSolid", [((0, 0, 0), (2000, 100, 2000)), ((500, 50, 500), (1500, 150, 1500))], 0.45),
    # a Solid with an "interior" shell reaching outside its exterior (the pieces of IFC exports' windows): 4 + 4 - 1
    ("Solid", [((0, 0, 0), (2000, 2000, 1000)), ((1000, 500, 0), (3000, 1500, 2000))], 7.0),
])
def test_shells_of_a_solid_geometry_that_touch_or_overlap_are_united(tmp_path, kind, boxes, want):
    """The shells of one geometry that are not cavities are parts of the union, each shell a part: preprocessed
    together, touching faces were fins and walls inside and overlaps counted twice (KIT's AC20-FZK-Haus in
    CityJSON: a window of 7 shells of one solid, 0.0922 m3 against manifold3d's union of them, 0.0738; now 0.0738).
    Volumes by hand."""
    from pipelines.ingest import process_one
    from meshsom.preprocess import PreprocessParams

    (m,), rej = _read(write(tmp_path / "shells.city.json", _shells_building(kind, boxes)))
    assert rej == [] and m.parts == ("S shell 1", "S shell 2")
    record, clean = process_one(m, PreprocessParams())
    assert record["status"] == "accepted" and record["union"]["status"] == "united", record
    assert record["volume"] == pytest.approx(want, rel=1e-9)


def test_a_cavity_shell_keeps_its_solid_one_part(tmp_path):
    """An interior shell wholly inside its exterior is a cavity: the shells stay one part (the union would make the
    cavity a solid of its own), and the cavity counts against the solid: 27 - 1 m3."""
    from pipelines.ingest import process_one
    from meshsom.preprocess import PreprocessParams

    d = _shells_building("Solid", [((0, 0, 0), (3000, 3000, 3000)), ((1000, 1000, 1000), (2000, 2000, 2000))])
    (m,), _ = _read(write(tmp_path / "hollow.city.json", d))
    assert m.parts == () and m.face_part is None
    record, _ = process_one(m, PreprocessParams())
    assert record["volume"] == pytest.approx(26.0, rel=1e-9)


def test_shells_that_the_union_would_flatten_are_parts_left_unsnapped(tmp_path):
    """A pane 6 mm thick, 2 mm beside its frame's wall: the union's snap onto walls (1 cm) flattened it (the
    FZK-Haus' windows of 11 shells lost 12 %), and the reader kept such shells one part; the union now leaves a part
    as drawn where the snap would change its volume by more than volume_rtol, so the shells are parts. Volume: the
    two boxes', by hand."""
    from pipelines.ingest import process_one
    from meshsom.preprocess import PreprocessParams

    d = _shells_building("CompositeSolid", [((0, 0, 0), (1000, 1000, 1000)), ((1002, 0, 0), (1008, 1000, 1000))])
    (m,), _ = _read(write(tmp_path / "pane.city.json", d))
    assert m.parts == ("S shell 1", "S shell 2")
    record, _ = process_one(m, PreprocessParams())
    assert record["status"] == "accepted" and record["union"]["status"] == "united", record
    assert record["volume"] == pytest.approx(1.006, rel=1e-9)


def test_an_object_with_a_cavity_is_split_with_the_cavity_in_its_shells_part(tmp_path):
    """A Solid of a 3 m cube, a 1 m cube cavity in it and an "interior" shell reaching out of it (3 x 0.5 x 0.5 m, a
    quarter of it inside the cube): its shells stayed one part, the overlap counted twice (26 + 0.75 = 26.75 m3).
    Split, the cavity stays in its cube's part and a cavity of the union: 27 - 1 + 0.75 - 0.25 = 26.5 m3 by hand."""
    from pipelines.ingest import process_one
    from meshsom.preprocess import PreprocessParams

    d = _shells_building("Solid", [((0, 0, 0), (3000, 3000, 3000)), ((1000, 1000, 1000), (2000, 2000, 2000)),
                                   ((2000, 0, 0), (5000, 500, 500))])
    (m,), rej = _read(write(tmp_path / "hollow.city.json", d))
    assert rej == [] and m.parts == ("S shell 1", "S shell 3")
    assert np.bincount(m.face_part).tolist() == [24, 12]  # the cube's and its cavity's 12 triangles, the bar's 12
    record, _ = process_one(m, PreprocessParams())
    assert record["status"] == "accepted" and record["union"]["status"] == "united", record
    assert record["volume"] == pytest.approx(26.5, rel=1e-9)


GLTF_1 = b'{"asset": {"generator": "collada2gltf@d78daf1", "profile": {"api": "WebGL", "version": "1.0.2"}, "version": 1}, '\
         b'"accessors": {"accessor_37": {"bufferView": "bufferView_49", "count": 3}}, "meshes": {}, "nodes": {}}'


def test_gltf_1_files_are_refused_in_meshsoms_words(tmp_path):
    """3DCityDB's glTF export (COLLADA2GLTF before 2.0) writes glTF 1.0: its asset says version 1 (its "profile"
    object between), its accessors are a dictionary (without the version: told by those alone)."""
    for name, content in [("a.gltf", GLTF_1), ("b.gltf", GLTF_1.replace(b', "version": 1}', b'}'))]:
        (tmp_path / name).write_bytes(content)
        _, rej = _read(tmp_path / name)
        assert rej[0].reason.startswith("is glTF 1.0, which is not read: convert it to glTF 2.0 (gltf-pipeline"), name


def test_the_gltf_twin_of_a_kml_placed_collada_model_is_listed_as_skipped(tmp_path):
    (tmp_path / "14").mkdir()
    box = trimesh.creation.box(extents=[10, 8, 6])
    (tmp_path / "14" / "B1.dae").write_bytes(trimesh.exchange.dae.export_collada(box))
    (tmp_path / "14" / "B1.gltf").write_bytes(GLTF_1)
    (tmp_path / "tile.kml").write_text(
        '<kml xmlns="http://www.opengis.net/kml/2.2"><Document><Placemark><name>B1</name><Model>'
        '<altitudeMode>relativeToGround</altitudeMode><Location><longitude>13.4</longitude><latitude>52.5</latitude>'
        '<altitude>0</altitude></Location><Link><href>14/B1.dae</href></Link></Model></Placemark></Document></kml>')
    skipped = []
    found, rejected = expand_inputs([tmp_path], skipped=skipped)
    assert [f.path.name for f in found] == ["tile.kml"] and rejected == []
    why = dict((Path(p).name, w) for p, w in skipped)
    assert why["B1.gltf"].startswith(f"the glTF twin of a COLLADA model placed by {tmp_path / 'tile.kml'}")


@pytest.mark.parametrize("name, document, said", [
    ("m.dfjson", {"type": "Model", "buildings": []}, "unknown file type '.dfjson' (a Dragonfly model (Ladybug Tools"),
    ("m.hbjson", {"type": "Model", "rooms": []}, "unknown file type '.hbjson' (a Honeybee model (Ladybug Tools"),
    ("m.json", {"type": "Model", "buildings": []}, "is a Dragonfly model (Ladybug Tools"),
    ("h.json", {"type": "Model", "rooms": []}, "is a Honeybee model (Ladybug Tools"),
    ("o.json", {"type": "Model"}, "is JSON but not CityJSON (expected \"type\": \"CityJSON\", found 'Model')"),
])
def test_ladybug_tools_models_are_refused_naming_the_format_and_the_way_out(tmp_path, name, document, said):
    import json

    (tmp_path / name).write_text(json.dumps(document))
    _, rej = _read(tmp_path / name)
    assert said in rej[0].reason
    if "Ladybug" in said:
        assert "OBJ or IFC" in rej[0].reason
