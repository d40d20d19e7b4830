"""FBX scenes and 3DS files read as the buildings they place (meshsom.fbx, meshsom.three_ds).

The files are written by tests/scene_files.py as exporters write them (FBX binary and ASCII, z up as 3ds Max and
PLATEAU write it or y up as Blender and Maya do, in metres or centimetres; 3DS chunks). Every expected coordinate
is worked out here from the objects' vertices and transforms, with the FBX axis systems turned to z up by hand,
and every volume from the footprint's area.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
import trimesh

from meshsom.errors import InputFileError
from meshsom.fbx import unit_scale
from meshsom.io import RawMesh, Rejection, input_kind, read_file
from scene_files import fbx_document, write_3ds, write_fbx_ascii, write_fbx_binary

#: An L-shaped footprint (metres) and its area.
L_SHAPE = [(0.0, 0.0), (12.0, 0.0), (12.0, 4.0), (4.0, 4.0), (4.0, 10.0), (0.0, 10.0)]
L_AREA = 12 * 4 + 4 * 6
HEIGHT = 7.0
#: File axes to z up (proper rotations): a z-up file is as it is; a y-up file's (x, y, z) is (x, -z, y).
TO_Z_UP = {"z-up": np.eye(3), "y-up": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])}


def l_prism(axes: str):
    """The L-prism's vertices in the file's axes and its polygons: the floor and roof as one concave n-gon each,
    the walls as quads, all turned outwards."""
    n = len(L_SHAPE)
    z_up = np.array([(x, y, 0.0) for x, y in L_SHAPE] + [(x, y, HEIGHT) for x, y in L_SHAPE])
    vertices = z_up @ TO_Z_UP[axes]  # the inverse of the turn to z up (orthogonal): the file's own coordinates
    polygons = [list(range(n))[::-1], list(range(n, 2 * n))]
    polygons += [[i, (i + 1) % n, (i + 1) % n + n, i + n] for i in range(n)]
    return vertices, polygons


def rotation_xyz(degrees) -> np.ndarray:
    """FBX's Euler rotation (XYZ order: about x first, then y, then z)."""
    rx, ry, rz = np.radians(degrees)
    x = np.array([[1, 0, 0], [0, np.cos(rx), -np.sin(rx)], [0, np.sin(rx), np.cos(rx)]])
    y = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    z = np.array([[np.cos(rz), -np.sin(rz), 0], [np.sin(rz), np.cos(rz), 0], [0, 0, 1]])
    return z @ y @ x


def signed_volume(mesh) -> float:
    corners = (mesh.vertices + mesh.origin)[mesh.faces]
    return float(np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6)


def _placements(axes):
    """(name, translation, rotation, scaling) of the scene's objects, in the file's axes and units."""
    up = {"z-up": (0, 0, 1), "y-up": (0, 1, 0)}[axes]
    return [("house-a", (300.0, 150.0, 2.0), tuple(30.0 * np.array(up)), (1, 1, 1)),
            ("house-b", (0.0, 0.0, 0.0), (0, 0, 0), (2, 2, 2)),
            ("house-a", (-40.0, 20.0, 0.0), (0, 0, 0), (1, 1, 1)),  # a name met again
            ("mirrored", (60.0, 0.0, 0.0), (0, 0, 0), (-1, 1, 1))]


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
@pytest.mark.parametrize("axes", ["z-up", "y-up"])
@pytest.mark.parametrize("unit", [100.0, 1.0, 2.54])
def test_fbx_objects_stand_where_the_scene_places_them_in_metres_z_up(tmp_path, encoding, axes, unit):
    """Each object is a building named as its node, at its translation, rotation and scaling, turned to z up and
    scaled from the file's unit to metres; concave n-gons and quads are triangulated (the L's volume); a mirrored
    object keeps its faces outwards; a repeated name gets ``(2)``."""
    vertices, polygons = l_prism(axes)
    cm = 100.0 / unit  # file units per metre
    objects = [(n, vertices * cm, polygons, np.array(t) * cm, r, s) for n, t, r, s in _placements(axes)]
    path = tmp_path / "city.fbx"
    (write_fbx_binary if encoding == "binary" else write_fbx_ascii)(path, fbx_document(objects, axes, unit))
    assert input_kind(path) == "fbx" and unit_scale(path.read_bytes()) == pytest.approx(unit)
    got = list(read_file(path))
    assert [m.id for m in got] == ["city.fbx#house-a", "city.fbx#house-b", "city.fbx#house-a (2)", "city.fbx#mirrored"]
    for mesh, (_, t, r, s) in zip(got, _placements(axes)):
        assert isinstance(mesh, RawMesh) and mesh.source == str(path) and mesh.notes == ()
        transform = rotation_xyz(r) @ np.diag(s)
        want = (vertices @ transform.T + np.array(t)) @ TO_Z_UP[axes].T  # metres, z up
        world = mesh.vertices + mesh.origin
        assert len(world) == len(want)
        # assimp computes in single precision: a part in ten million of the coordinates' size
        assert np.allclose(np.sort(world, axis=0), np.sort(want, axis=0), rtol=1e-6, atol=1e-5), mesh.id
        assert signed_volume(mesh) == pytest.approx(L_AREA * HEIGHT * abs(np.prod(s)), rel=1e-6), mesh.id


def test_an_fbx_file_without_a_unit_is_in_centimetres_and_labels_come_from_beside(tmp_path):
    vertices, polygons = l_prism("z-up")
    nodes = fbx_document([("a", vertices * 100, polygons, (0, 0, 0), (0, 0, 0), (1, 1, 1)),
                          ("b", vertices * 100, polygons, (5000, 0, 0), (0, 0, 0), (1, 1, 1))])
    settings = dict((n[0], n) for n in nodes)["GlobalSettings"][2][1][2]
    settings[:] = [p for p in settings if "UnitScaleFactor" not in p[1][0]]  # a file naming no unit
    write_fbx_binary(tmp_path / "s.fbx", nodes)
    (tmp_path / "labels.csv").write_text("file,label\ns.fbx,tower\ns.fbx#b,hall\n")
    a, b = read_file(tmp_path / "s.fbx")
    assert signed_volume(a) == pytest.approx(L_AREA * HEIGHT, rel=1e-6) and (a.label, b.label) == ("tower", "hall")
    assert (b.vertices + b.origin)[:, 0].min() == pytest.approx(50.0) and "centimetres" in a.notes[0]


def test_gzipped_and_bad_fbx_files(tmp_path):
    vertices, polygons = l_prism("y-up")
    write_fbx_binary(tmp_path / "s.fbx", fbx_document([("a", vertices, polygons, (0, 0, 0), (0, 0, 0), (1, 1, 1))],
                                                       "y-up", 100.0))
    (tmp_path / "z.fbx.gz").write_bytes(gzip.compress((tmp_path / "s.fbx").read_bytes()))
    (m,) = read_file(tmp_path / "z.fbx.gz")
    assert m.id == "z.fbx.gz#a" and m.source == str(tmp_path / "z.fbx.gz") and signed_volume(m) == pytest.approx(504, rel=1e-6)
    (tmp_path / "cut.fbx").write_bytes((tmp_path / "s.fbx").read_bytes()[:300])
    (tmp_path / "text.fbx").write_text("not an FBX file\n")
    for bad in ("cut.fbx", "text.fbx"):
        (r,) = read_file(tmp_path / bad)
        assert isinstance(r, Rejection) and r.reason.startswith("cannot be read as FBX ("), r
    empty = fbx_document([])
    write_fbx_binary(tmp_path / "empty.fbx", empty)
    (r,) = read_file(tmp_path / "empty.fbx")
    assert isinstance(r, Rejection) and "holds no mesh" in r.reason or "cannot be read" in r.reason, r


def test_unit_scale_of_binary_and_ascii_heads():
    assert unit_scale(b'P: "UnitScaleFactor", "double", "Number", "",100.0\n') == 100.0
    assert unit_scale(b'P: "UnitScaleFactor", "double", "Number", "",-1\n') is None
    assert unit_scale(b"; FBX 7.4.0 project file\n") is None


# ----------------------------------------------------------------------------- 3DS


def test_3ds_objects_are_buildings_by_name(tmp_path):
    """Each 3DS object with a triangle mesh is a building named as the object, at its world coordinates (z up,
    read as metres), outward as written; a repeated name gets ``(2)``; an object whose faces name missing
    vertices is rejected alone; labels come from ``labels.csv``."""
    import trimesh

    box = trimesh.creation.box([10.0, 6.0, 4.0])
    prism = trimesh.creation.extrude_polygon(__import__("shapely").geometry.Polygon(L_SHAPE), HEIGHT)
    objects = [("Haus 1", box.vertices + [390000.5, 5820000.25, 36.0], box.faces),
               ("Haus 2", prism.vertices + [20.0, 0.0, 0.0], prism.faces),
               ("Haus 1", box.vertices, box.faces),
               ("broken", box.vertices[:4], box.faces)]
    path = tmp_path / "berlin.3ds"
    write_3ds(path, objects)
    (tmp_path / "labels.csv").write_text("file,label\nberlin.3ds#Haus 2,school\n")
    assert input_kind(path) == "3ds"
    got = list(read_file(path))
    assert [m.id for m in got] == ["berlin.3ds#Haus 1", "berlin.3ds#Haus 2", "berlin.3ds#Haus 1 (2)", "berlin.3ds#broken"]
    a, b, c, broken = got
    assert isinstance(broken, Rejection) and "refers to vertex" in broken.reason
    assert signed_volume(a) == pytest.approx(240.0, rel=1e-6) and signed_volume(b) == pytest.approx(L_AREA * HEIGHT)
    assert np.allclose(a.vertices + a.origin, (box.vertices + [390000.5, 5820000.25, 36.0]).astype(np.float32), atol=1e-9)
    assert b.label == "school" and a.label is None


def test_damaged_3ds_files_are_rejections_naming_the_problem(tmp_path):
    import trimesh

    box = trimesh.creation.box([10.0, 6.0, 4.0])
    write_3ds(tmp_path / "ok.3ds", [("a", box.vertices, box.faces), ("b", box.vertices + 20, box.faces)])
    data = (tmp_path / "ok.3ds").read_bytes()
    (tmp_path / "cut.3ds").write_bytes(data[:-50])
    (tmp_path / "other.3ds").write_bytes(b"\x00\x01" + data[2:])
    got = list(read_file(tmp_path / "cut.3ds"))
    assert isinstance(got[-1], Rejection) and "claims" in got[-1].reason and "truncated or damaged" in got[-1].reason
    (r,) = read_file(tmp_path / "other.3ds")
    assert isinstance(r, Rejection) and "is not a 3DS file" in r.reason
    with pytest.raises(InputFileError, match="expected one of"):
        input_kind(tmp_path / "x.max")


def test_fbx_pivots_and_offsets_place_a_model_as_fbx_composes_them(tmp_path):
    """3ds Max writes pivots and offsets beside a model's transform: FBX places it at T Rp Rpre R Rp^-1 Tg (rotation
    pivot, pre-rotation, geometric translation), worked out here for the box's centre; assimp's helper nodes for
    them leave the building its model's name."""
    import trimesh

    box = trimesh.creation.box([10.0, 6.0, 4.0])
    nodes = fbx_document([("house", box.vertices, box.faces.tolist(), (100.0, 200.0, 2.0), (0, 0, 30.0), (1, 1, 1))])
    model = dict((n[0], n) for n in nodes)["Objects"][2][1]
    properties = dict((c[0], c) for c in model[2])["Properties70"][2]
    properties += [("P", ["GeometricTranslation", "Vector3D", "Vector", "", 5.0, 0.0, 0.0], []),
                   ("P", ["RotationPivot", "Vector3D", "Vector", "", 1.0, 1.0, 0.0], []),
                   ("P", ["PreRotation", "Vector3D", "Vector", "", 0.0, 0.0, 10.0], [])]
    write_fbx_binary(tmp_path / "pivots.fbx", nodes)
    (m,) = read_file(tmp_path / "pivots.fbx")
    pivot, offset = np.array([1.0, 1.0, 0.0]), np.array([5.0, 0.0, 0.0])
    centre = np.array([100.0, 200.0, 2.0]) + pivot + rotation_xyz((0, 0, 40.0)) @ (offset - pivot)
    assert m.id == "pivots.fbx#house"
    assert np.allclose((m.vertices + m.origin).mean(axis=0), centre, atol=1e-5)


def test_an_fbx_scene_written_per_surface_is_read_per_building(tmp_path):
    """A scene written per surface (a node per wall, roof and floor under the building's node, named by the surface's
    class or by ids that start with its kind, as PLATEAU's are) is read as one building per building node, its
    surfaces united (the L's volume); buildings grouped under a city node stay buildings of their own, a
    surface-named one among them too (the city node groups buildings, not one's surfaces), and a surface-named node
    with no model above it is one alone."""
    vertices, polygons = l_prism("z-up")
    floor, roof, walls = polygons[:1], polygons[1:2], polygons[2:]
    still = ((0, 0, 0), (0, 0, 0), (1, 1, 1))
    objects = [("City", None, None, *still),
               ("bldg_1", None, None, (100.0, 0, 0), (0, 0, 0), (1, 1, 1), "City"),
               ("wall_bldg_1_0", vertices, walls, *still, "bldg_1"),
               ("RoofSurface_2", vertices, roof, *still, "bldg_1"),
               ("ground_bldg_1", vertices, floor, *still, "bldg_1"),
               ("house-b", vertices, polygons, (0, 50.0, 0), (0, 0, 0), (1, 1, 1), "City"),
               ("roof_terrace_3", vertices, polygons, (0, 75.0, 0), (0, 0, 0), (1, 1, 1), "City"),
               ("roof_alone", vertices, polygons, (0, 100.0, 0), (0, 0, 0), (1, 1, 1))]
    write_fbx_binary(tmp_path / "atomic.fbx", fbx_document(objects))
    got = list(read_file(tmp_path / "atomic.fbx"))
    assert [m.id.split("#")[1] for m in got] == ["bldg_1", "house-b", "roof_terrace_3", "roof_alone"], got
    for m in got:
        assert signed_volume(m) == pytest.approx(L_AREA * HEIGHT, rel=1e-6), m.id
    assert (got[0].vertices + got[0].origin)[:, 0].min() == pytest.approx(100.0)
    assert len(got[0].faces) == len(got[1].faces) and len(got[0].vertices) == len(got[1].vertices) == 12  # welded


def _box(x0, y0, z0, x1, y1, z1):
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0], [x0, y0, z1], [x1, y0, z1], [x1, y1, z1],
                  [x0, y1, z1]], float)
    return v, [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]


@pytest.mark.parametrize("application, expected", [("CityEngine", 2), ("Blender", 5)])
def test_a_cityengine_scene_is_read_as_buildings_of_touching_pieces(tmp_path, application, expected):
    """CityEngine writes a building as root nodes of its generated pieces: a 10 x 8 x 6 m body, a 1 x 1 x 2 m chimney
    standing on its roof (its corners inside the roof face, near no roof vertex), a 1.2 x 0.1 x 1.5 m window frame
    on its front wall, a pane inside the frame's box; and a shed 5 m away, a building of its own. Read as 2
    buildings, the house's four pieces its parts (volumes by hand: 480 + 2 + 0.18 + the pane's 0.0375); any other
    writer's FBX keeps a building per node."""
    objects = [("Body", *_box(0, 0, 0, 10, 8, 6)), ("Chimney", *_box(7, 5, 6, 8, 6, 8)),
               ("WindowFrame", *_box(4, -0.1, 2, 5.2, 0, 3.5)), ("Glass", *_box(4.1, -0.075, 2.1, 5.1, -0.05, 3.4)),
               ("Shed", *_box(15, 0, 0, 18, 3, 2.5))]
    objects = [(name, v, p, (0, 0, 0), (0, 0, 0), (1, 1, 1)) for name, v, p in objects]
    path = tmp_path / "scene.fbx"
    write_fbx_binary(path, fbx_document(objects, "z-up", 100.0, application))
    out = list(read_file(path))
    assert len(out) == expected and all(isinstance(m, RawMesh) for m in out)
    if application != "CityEngine":
        return
    house, shed = out
    assert house.id == "scene.fbx#Body" and house.parts == ("Body", "Chimney", "WindowFrame", "Glass")
    assert np.bincount(house.face_part).tolist() == [12, 12, 12, 12]
    volumes = [trimesh.Trimesh(house.vertices, house.faces[house.face_part == k]).volume for k in range(4)]
    assert volumes == pytest.approx([480, 2, 1.2 * 0.1 * 1.5, 1.0 * 0.025 * 1.3])
    assert "4 root nodes whose meshes touch or overlap" in house.notes[-1]
    assert shed.id == "scene.fbx#Shed" and trimesh.Trimesh(shed.vertices, shed.faces).volume == pytest.approx(22.5)


CITYENGINE_FILE = Path("/tmp/probeH/repro/cityengine_sternwarte.fbx")


@pytest.mark.skipif(not CITYENGINE_FILE.exists(), reason="the probe's CityEngine export (Esri/pyprt-examples, 1.2 MB)")
def test_the_sternwarte_cityengine_export_is_one_building():
    """Esri/pyprt-examples@5a75eb6 data/Sternwarte.fbx (Apache-2.0; not copied: 1.2 MB): one building, 32 x 33 x 19 m
    in LV03 (assimp's reading in the probe: x 683956-683989, y 248050-248083, z 466-485), was 730 buildings."""
    (m,) = list(read_file(CITYENGINE_FILE))
    lo, hi = m.origin + m.vertices.min(axis=0), m.origin + m.vertices.max(axis=0)
    assert lo == pytest.approx([683956, 248050, 466], abs=1) and hi == pytest.approx([683989, 248083, 485], abs=1)
    assert len(m.parts) == 730
