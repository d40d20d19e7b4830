"""Rhino models (.3dm) as computational designers save them: polysurfaces, extrusions, meshes, groups
and block instances, in millimetres, feet or metres, written here by openNURBS (rhino3dm) and
checked against volumes, extents and transformations computed in the tests."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from meshsom.errors import InputFileError
from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, read_file

r = pytest.importorskip("rhino3dm")


def _volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume by the divergence theorem (positive for outward faces)."""
    t = vertices[faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


def _welded_edges_twice(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Every edge, corners equal within 1e-9 merged, is used by exactly two faces (a closed surface)."""
    _, index = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    f = index.reshape(-1)[faces]
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool((counts == 2).all())


def _box(x0, y0, z0, x1, y1, z1):
    return r.Brep.CreateFromBox(r.Box(r.BoundingBox(x0, y0, z0, x1, y1, z1)))


def _polyline_curve(points):
    line = r.Polyline()
    for x, y in list(points) + [points[0]]:
        line.Add(x, y, 0)
    return line.ToPolylineCurve()


def _massing(path, unit=None):
    """A massing model in millimetres: a named tower with user text, an L-shaped extrusion, a
    group of two volumes, a rotated block instance of a shed, and a line."""
    model = r.File3dm()
    model.Settings.ModelUnitSystem = unit or r.UnitSystem.Millimeters
    layer = r.Layer()
    layer.Name = "buildings"
    model.Layers.Add(layer)
    tower = r.ObjectAttributes()
    tower.Name = "tower"
    tower.SetUserString("family", "office")
    tower.LayerIndex = 0
    model.Objects.AddBrep(_box(0, 0, 0, 10000, 6000, 4000), tower)
    model.Objects.AddExtrusion(r.Extrusion.Create(
        _polyline_curve([(20000, 0), (30000, 0), (30000, 5000), (25000, 5000), (25000, 10000), (20000, 10000)]), 7000, True))
    group = r.Group()
    group.Name = "house"
    model.Groups.Add(group)
    for bounds in [(0, 20000, 0, 8000, 28000, 3000), (8000, 20000, 0, 12000, 24000, 6000)]:
        member = r.ObjectAttributes()
        member.AddToGroup(0)
        model.Objects.AddBrep(_box(*bounds), member)
    index = model.InstanceDefinitions.Add("shed", "", "", "", r.Point3d(0, 0, 0), (_box(0, 0, 0, 2000, 3000, 2500),),
                                          (r.ObjectAttributes(),))
    turn = r.Transform.Multiply(r.Transform.Translation(50000, 50000, 1000),
                                r.Transform.Rotation(math.radians(30), r.Vector3d(0, 0, 1), r.Point3d(0, 0, 0)))
    model.Objects.AddInstanceObject(r.InstanceReference(model.InstanceDefinitions[index].Id, turn))
    model.Objects.AddLine(r.Point3d(0, 0, 0), r.Point3d(1, 1, 1))
    assert model.Write(str(path), 8)
    return path


def test_a_massing_model_reads_one_building_per_object_in_metres(tmp_path):
    """Each solid object one building, scaled from millimetres; volumes and extents as modelled;
    the line noted; the tower labelled by its user text."""
    items = {i.id.split("#")[1]: i for i in read_file(_massing(tmp_path / "m.3dm"))}
    assert all(isinstance(i, RawMesh) for i in items.values()), items
    tower = items["tower"]
    assert tower.label == "office" and len(tower.faces) == 12
    np.testing.assert_allclose(np.ptp(tower.vertices, axis=0), [10, 6, 4], atol=1e-12)
    np.testing.assert_allclose(tower.origin, [5, 3, 2], atol=1e-12)
    assert _volume(tower.vertices, tower.faces) == pytest.approx(240, rel=1e-12)
    assert any("millimeters, scaled to metres" in n for n in tower.notes)
    assert any("Curve x 1" in n for n in tower.notes)
    (extrusion,) = [i for k, i in items.items() if k not in ("tower", "house") and "shed" not in " ".join(i.notes)]
    assert _volume(extrusion.vertices, extrusion.faces) == pytest.approx((10 * 5 + 5 * 5) * 7, rel=1e-12)
    assert _welded_edges_twice(extrusion.vertices, extrusion.faces)
    np.testing.assert_allclose(np.ptp(extrusion.vertices, axis=0), [10, 10, 7], atol=1e-12)


def test_a_block_instance_is_placed_by_its_transformation(tmp_path):
    """The shed (2 x 3 x 2.5 m at the origin of its block) turned 30 degrees about z and moved to
    (50, 50, 1) m: its corners are the block's corners under that motion, computed here."""
    items = list(read_file(_massing(tmp_path / "m.3dm")))
    (shed,) = [i for i in items if any("block instance of 'shed'" in n for n in i.notes)]
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    corners = np.array([[x, y, z] for x in (0, 2) for y in (0, 3) for z in (0, 2.5)])
    expected = corners @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + [50, 50, 1]
    got = np.unique(np.round(shed.vertices + shed.origin, 9), axis=0)
    np.testing.assert_allclose(np.sort(got, axis=0), np.sort(expected, axis=0), atol=1e-9)
    assert _volume(shed.vertices, shed.faces) == pytest.approx(15, rel=1e-9)


def test_a_group_is_one_building_whose_parts_are_united(tmp_path):
    """The two grouped volumes (8 x 8 x 3 and 4 x 4 x 6 m, touching along a wall) are one building
    of two parts; preprocessing unites them into one closed solid of 192 + 96 m^3."""
    from meshsom.preprocess import PreprocessParams
    from pipelines.ingest import process_one

    items = {i.id.split("#")[1]: i for i in read_file(_massing(tmp_path / "m.3dm"))}
    house = items["house"]
    assert len(house.parts) == 2 and house.face_part.tolist() == [0] * 12 + [1] * 12
    assert any("2 objects of one group" in n for n in house.notes)
    record, clean = process_one(house, PreprocessParams())
    assert record["status"] == "accepted", record
    assert record["union"]["parts"] == 2
    assert _volume(clean.vertices, clean.faces) == pytest.approx(288, rel=1e-9)


def test_a_courtyard_block_keeps_its_hole(tmp_path):
    """An extrusion of a 30 x 20 m block around a 10 x 6 m courtyard, 12 m high: its faces keep
    the hole (trims of an inner loop), the surface is closed, the volume (600 - 60) x 12."""
    outer = _polyline_curve([(0, 0), (30, 0), (30, 20), (0, 20)])
    inner = _polyline_curve([(10, 7), (20, 7), (20, 13), (10, 13)])
    extrusion = r.Extrusion.Create(outer, 12, True)
    assert extrusion.AddInnerProfile(inner)
    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Meters
    model.Objects.AddExtrusion(extrusion)
    assert model.Write(str(tmp_path / "c.3dm"), 8)
    (item,) = read_file(tmp_path / "c.3dm")
    assert _volume(item.vertices, item.faces) == pytest.approx(540 * 12, rel=1e-12)
    assert _welded_edges_twice(item.vertices, item.faces)
    assert not any("scaled" in n for n in item.notes)


def test_meshes_and_mirrored_blocks_keep_their_outward_side(tmp_path):
    """A box as a Rhino mesh of quads, and a block instance mirrored in x: both outward (positive
    volume) after the quads are split and the mirror is undone on the faces."""
    mesh = r.Mesh()
    for x, y, z in [(0, 0, 0), (4, 0, 0), (4, 3, 0), (0, 3, 0), (0, 0, 2), (4, 0, 2), (4, 3, 2), (0, 3, 2)]:
        mesh.Vertices.Add(x, y, z)
    for quad in [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]:
        mesh.Faces.AddFace(*quad)
    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Meters
    named = r.ObjectAttributes()
    named.Name = "mesh"
    model.Objects.AddMesh(mesh, named)
    index = model.InstanceDefinitions.Add("box", "", "", "", r.Point3d(0, 0, 0), (_box(0, 0, 0, 1, 2, 3),), (r.ObjectAttributes(),))
    mirror = r.Transform.Mirror(r.Point3d(0, 0, 0), r.Vector3d(1, 0, 0))
    model.Objects.AddInstanceObject(r.InstanceReference(model.InstanceDefinitions[index].Id, mirror))
    assert model.Write(str(tmp_path / "x.3dm"), 8)
    items = {i.id.split("#")[1]: i for i in read_file(tmp_path / "x.3dm")}
    assert len(items["mesh"].faces) == 12 and _volume(items["mesh"].vertices, items["mesh"].faces) == pytest.approx(24)
    (block,) = [i for k, i in items.items() if k != "mesh"]
    assert np.ptp(block.vertices, axis=0).tolist() == pytest.approx([1, 2, 3])
    assert (block.vertices + block.origin)[:, 0].max() == pytest.approx(0)  # mirrored to x <= 0
    assert _volume(block.vertices, block.faces) == pytest.approx(6)


#: Writes a round tower (a capped cylinder, r = 3 m, h = 9 m) with the render meshes Rhino saves
#: for it (32 segments, shared edges alike) to argv[1]. In its own process: rhino3dm crashes on exit
#: after a face's render mesh is set from Python.
TOWER = textwrap.dedent("""
    import math, os, sys
    import rhino3dm as r
    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Meters
    brep = r.Brep.CreateFromCylinder(r.Cylinder(r.Circle(r.Point3d(0, 0, 0), 3), 9), True, True)
    n, keep = 32, []
    ring = [(3 * math.cos(2 * math.pi * k / n), 3 * math.sin(2 * math.pi * k / n)) for k in range(n)]
    for k in range(len(brep.Faces)):
        face, mesh = brep.Faces[k], r.Mesh()
        if face.IsPlanar():
            z = face.GetBoundingBox().Min.Z
            for x, y in ring:
                mesh.Vertices.Add(x, y, z)
            mesh.Vertices.Add(0, 0, z)
            for i in range(n):
                mesh.Faces.AddFace(n, i, (i + 1) % n) if z > 1 else mesh.Faces.AddFace(n, (i + 1) % n, i)
        else:
            for z in (0, 9):
                for x, y in ring:
                    mesh.Vertices.Add(x, y, z)
            for i in range(n):
                mesh.Faces.AddFace(i, (i + 1) % n, n + (i + 1) % n, n + i)
        keep.append(mesh)
        assert face.SetMesh(mesh, r.MeshType.Render)
    if sys.argv[2] == "meshed":
        model.Objects.AddBrep(brep)
    else:
        model.Objects.AddBrep(r.Brep.CreateFromCylinder(r.Cylinder(r.Circle(r.Point3d(0, 0, 0), 3), 9), True, True))
    assert model.Write(sys.argv[1], 8)
    sys.stdout.flush()
    os._exit(0)
""")


def test_a_curved_polysurface_is_read_from_its_render_meshes(tmp_path):
    """A round tower saved with render meshes reads as their closed union, the volume of the
    32-sided prism they make; saved without them it is tessellated here, closed, the same prism."""
    for kind in ("meshed", "bare"):
        subprocess.run([sys.executable, "-c", TOWER, str(tmp_path / f"{kind}.3dm"), kind], check=True, timeout=60)
    (meshed,) = read_file(tmp_path / "meshed.3dm")
    prism = 0.5 * 32 * 3**2 * math.sin(2 * math.pi / 32) * 9
    assert isinstance(meshed, RawMesh) and _volume(meshed.vertices, meshed.faces) == pytest.approx(prism, rel=1e-6)  # float32 mesh vertices
    assert _welded_edges_twice(meshed.vertices, meshed.faces)
    (bare,) = read_file(tmp_path / "bare.3dm")  # tessellated here: the same 32 segments on its circles
    assert isinstance(bare, RawMesh) and _volume(bare.vertices, bare.faces) == pytest.approx(prism, rel=1e-9), bare
    assert _welded_edges_twice(bare.vertices, bare.faces)


def test_units_and_layer_labels(tmp_path):
    """Feet are scaled to metres; a model of no unit is read as metres, noted; ``label_attribute:
    layer`` labels by the layer's full path."""
    import dataclasses

    _massing(tmp_path / "ft.3dm", unit=r.UnitSystem.Feet)
    tower = next(i for i in read_file(tmp_path / "ft.3dm") if i.id.endswith("#tower"))
    np.testing.assert_allclose(np.ptp(tower.vertices, axis=0), np.array([10000, 6000, 4000]) * 0.3048)
    _massing(tmp_path / "none.3dm", unit=r.UnitSystem.None_ if hasattr(r.UnitSystem, "None_") else getattr(r.UnitSystem, "None"))
    options = dataclasses.replace(ReaderOptions(), label_attribute="layer")
    tower = next(i for i in read_file(tmp_path / "none.3dm", options) if i.id.endswith("#tower"))
    assert any("unit system is None: read as metres" in n for n in tower.notes)
    assert tower.label == "buildings"


def test_files_that_are_no_buildings_say_why(tmp_path):
    from meshsom.rhino import read_3dm

    model = r.File3dm()
    model.Objects.AddLine(r.Point3d(0, 0, 0), r.Point3d(1, 1, 1))
    model.Objects.AddPoint(r.Point3d(2, 2, 2))
    assert model.Write(str(tmp_path / "lines.3dm"), 8)
    with pytest.raises(InputFileError, match=r"holds no polysurface, extrusion, mesh or block instance in model space: "
                                             r"Curve x 1, Point x 1"):
        list(read_3dm(tmp_path / "lines.3dm", ReaderOptions()))
    (tmp_path / "fake.3dm").write_bytes(b"solid cube\nendsolid\n")
    (item,) = read_file(tmp_path / "fake.3dm")
    assert isinstance(item, Rejection) and "is not a Rhino model (starts b'solid cube" in item.reason


def test_a_damaged_model_is_refused_before_opennurbs_searches_it(tmp_path):
    """A model cut short, one whose object table claims more bytes than the file has, and one
    ending without its end-of-file chunk: each refused from its top-level chunks, saying where
    (openNURBS would search such a file byte by byte for its tables, for tens of seconds)."""
    import struct

    data = _massing(tmp_path / "m.3dm").read_bytes()
    at = 32  # the object table's chunk (type 0x10000013): walk the top-level chunks to it
    while struct.unpack_from("<I", data, at)[0] != 0x10000013:
        at += 12 + struct.unpack_from("<q", data, at + 4)[0]
    claims = data[:at + 4] + struct.pack("<q", 10**9) + data[at + 12:]
    end = len(data) - 20  # the end-of-file chunk: type, length 8, the file's length
    assert struct.unpack_from("<I", data, end)[0] == 0x7FFF
    cases = {"cut": (data[:at + 100], f"the chunk of type 0x10000013 at byte {at:,} claims"),
             "claims": (claims, "claims 1,000,000,000 bytes"),
             "no end": (data[:end], "without its end-of-file chunk (truncated?)")}
    for key, (content, says) in cases.items():
        (tmp_path / "bad.3dm").write_bytes(content)
        (item,) = read_file(tmp_path / "bad.3dm")
        assert isinstance(item, Rejection) and "is a damaged Rhino model: " in item.reason and says in item.reason, (key, item)


@pytest.mark.parametrize("version", [2, 3, 4, 5, 6, 7, 8])
def test_models_of_every_rhino_version_are_read(tmp_path, version):
    """openNURBS writes the massing model as Rhino 2 to 8 would (chunk lengths of 4 bytes before
    version 50, 8 since): each reads the same tower."""
    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Meters
    model.Objects.AddBrep(_box(0, 0, 0, 10, 6, 4))
    assert model.Write(str(tmp_path / "v.3dm"), version)
    (item,) = read_file(tmp_path / "v.3dm")
    assert isinstance(item, RawMesh) and _volume(item.vertices, item.faces) == pytest.approx(240, rel=1e-12), item


def test_a_folder_and_a_gzipped_model_are_read(tmp_path):
    import gzip

    (tmp_path / "in").mkdir()
    data = _massing(tmp_path / "m.3dm").read_bytes()
    (tmp_path / "in" / "a.3dm.gz").write_bytes(gzip.compress(data))
    files, rejected = expand_inputs([tmp_path / "in"])
    assert [f.name for f in files] == ["a.3dm.gz"] and not rejected
    items = list(read_file(files[0].path, ReaderOptions(), files[0].name))
    assert len(items) == 4 and all(isinstance(i, RawMesh) for i in items)
    assert "a.3dm.gz#tower" in {i.id for i in items}


#: Writes a round tower as a Rhino extrusion (a capped cylinder, r = 3 m, h = 9 m) to argv[1], with
#: the render mesh Rhino keeps on the extrusion (32 segments) where argv[2] is "meshed". In its own
#: process: rhino3dm crashes on exit after a render mesh is set from Python.
EXTRUSION = textwrap.dedent("""
    import math, os, sys
    import rhino3dm as r
    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Meters
    tower = r.Extrusion.CreateCylinderExtrusion(r.Cylinder(r.Circle(r.Point3d(0, 0, 0), 3), 9), True, True)
    mesh, n = r.Mesh(), 32
    for z in (0, 9):
        for k in range(n):
            mesh.Vertices.Add(3 * math.cos(2 * math.pi * k / n), 3 * math.sin(2 * math.pi * k / n), z)
    bottom, top = mesh.Vertices.Add(0, 0, 0), mesh.Vertices.Add(0, 0, 9)
    for i in range(n):
        mesh.Faces.AddFace(i, (i + 1) % n, n + (i + 1) % n, n + i)
        mesh.Faces.AddFace(bottom, (i + 1) % n, i)
        mesh.Faces.AddFace(top, n + i, n + (i + 1) % n)
    if sys.argv[2] == "meshed":
        assert tower.SetMesh(mesh, r.MeshType.Render)
    model.Objects.AddExtrusion(tower)
    assert model.Write(sys.argv[1], 8)
    sys.stdout.flush()
    os._exit(0)
""")


def test_a_curved_extrusion_is_read_from_the_render_mesh_kept_on_it(tmp_path):
    """Rhino keeps an extrusion's render mesh on the extrusion, not on the faces of its polysurface
    form: a round tower saved so reads as that mesh (the 32-sided prism's volume); without it, it
    is tessellated here, closed, within 0.1 % of the 32-sided prism."""
    for kind in ("meshed", "bare"):
        subprocess.run([sys.executable, "-c", EXTRUSION, str(tmp_path / f"{kind}.3dm"), kind], check=True, timeout=60)
    (meshed,) = read_file(tmp_path / "meshed.3dm")
    prism = 0.5 * 32 * 3**2 * math.sin(2 * math.pi / 32) * 9
    assert isinstance(meshed, RawMesh) and _volume(meshed.vertices, meshed.faces) == pytest.approx(prism, rel=1e-6), meshed
    (bare,) = read_file(tmp_path / "bare.3dm")  # tessellated here: its NURBS circles at 32 points, not evenly spread
    assert isinstance(bare, RawMesh) and 0.999 * prism < _volume(bare.vertices, bare.faces) < math.pi * 9 * 9, bare
    assert _welded_edges_twice(bare.vertices, bare.faces)


def test_curved_polysurfaces_without_render_meshes_are_tessellated_watertight(tmp_path):
    """Written by a script (no render meshes): a D-shaped tower (an extrusion of a rectangle ended
    by a half circle: flat walls, a curved wall, caps whose arcs it shares) reads closed, with a
    volume (between that of the half circle in 16 even segments, within 1e-4, and the round one's);
    a cylinder turned inside out (Flip) has the prism's volume negative; a sphere (two poles, a
    seam) is closed after preprocessing, its volume between that of
    the ball its facets keep out of (cos 11.25 degrees) and the sphere's."""
    from meshsom.preprocess import PreprocessParams
    from pipelines.ingest import process_one

    outline = r.PolyCurve()
    outline.Append(r.LineCurve(r.Point3d(0, 0, 0), r.Point3d(10, 0, 0)))
    outline.Append(r.Arc(r.Point3d(10, 0, 0), r.Point3d(14, 4, 0), r.Point3d(10, 8, 0)))
    outline.Append(r.LineCurve(r.Point3d(10, 8, 0), r.Point3d(0, 8, 0)))
    outline.Append(r.LineCurve(r.Point3d(0, 8, 0), r.Point3d(0, 0, 0)))
    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Meters
    tower = r.ObjectAttributes()
    tower.Name = "d"
    model.Objects.AddExtrusion(r.Extrusion.Create(outline, 12, True), tower)
    inside_out = r.Brep.CreateFromCylinder(r.Cylinder(r.Circle(r.Point3d(80, 0, 0), 3), 9), True, True)
    inside_out.Flip()  # every face reversed: the faces turn with it
    flipped = r.ObjectAttributes()
    flipped.Name = "flipped"
    model.Objects.AddBrep(inside_out, flipped)
    ball = r.ObjectAttributes()
    ball.Name = "ball"
    model.Objects.AddBrep(r.Brep.CreateFromSphere(r.Sphere(r.Point3d(40, 0, 0), 5)), ball)
    assert model.Write(str(tmp_path / "s.3dm"), 8)
    items = {i.id.split("#")[1]: i for i in read_file(tmp_path / "s.3dm")}
    d = items["d"]
    half = 0.5 * 16 * 4**2 * math.sin(math.pi / 16)  # half of a 32-gon of radius 4
    assert (80 + half) * 12 * 0.9999 < _volume(d.vertices, d.faces) < (80 + math.pi * 16 / 2) * 12  # 16 arc points, not evenly spread
    assert _welded_edges_twice(d.vertices, d.faces)
    prism = 0.5 * 32 * 3**2 * math.sin(2 * math.pi / 32) * 9
    assert _volume(items["flipped"].vertices, items["flipped"].faces) == pytest.approx(-prism, rel=1e-9)
    record, clean = process_one(items["ball"], PreprocessParams())
    assert record["status"] == "accepted" and "envelope" not in record, record
    sphere = 4 / 3 * math.pi * 5**3
    assert sphere * math.cos(math.radians(11.25)) ** 3 < _volume(clean.vertices, clean.faces) < sphere


def test_a_crs_in_feet_is_not_applied_twice(tmp_path):
    """A model in feet read with a CRS in US survey feet (EPSG:2263): the CRS scales, the model's
    unit is not applied as well."""
    import dataclasses

    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Feet
    model.Objects.AddBrep(_box(980000, 200000, 30, 980030, 200020, 42))
    assert model.Write(str(tmp_path / "ny.3dm"), 8)
    (item,) = read_file(tmp_path / "ny.3dm", dataclasses.replace(ReaderOptions(), crs="EPSG:2263"))
    assert np.ptp(item.vertices, axis=0) == pytest.approx(np.array([30, 20, 12]) * 1200 / 3937, rel=1e-9)
    assert any("model units (feet) not applied" in n for n in item.notes), item.notes


def test_a_district_in_one_mesh_object_is_split_on_request(tmp_path):
    """A district exported to Rhino as one mesh object of two boxes: one building as it is, two
    with ``split_components``, each a box's volume."""
    import dataclasses

    mesh = r.Mesh()
    for dx in (0, 30):
        base = len(mesh.Vertices)
        for x, y, z in [(0, 0, 0), (4, 0, 0), (4, 3, 0), (0, 3, 0), (0, 0, 2), (4, 0, 2), (4, 3, 2), (0, 3, 2)]:
            mesh.Vertices.Add(x + dx, y, z)
        for quad in [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]:
            mesh.Faces.AddFace(*[base + k for k in quad])
    model = r.File3dm()
    model.Settings.ModelUnitSystem = r.UnitSystem.Meters
    named = r.ObjectAttributes()
    named.Name = "district"
    model.Objects.AddMesh(mesh, named)
    assert model.Write(str(tmp_path / "d.3dm"), 8)
    (whole,) = read_file(tmp_path / "d.3dm")
    assert whole.id == "d.3dm#district" and _volume(whole.vertices, whole.faces) == pytest.approx(48)
    pieces = list(read_file(tmp_path / "d.3dm", dataclasses.replace(ReaderOptions(), split_components=True)))
    assert [p.id for p in pieces] == ["d.3dm#district#c1", "d.3dm#district#c2"]
    assert all(_volume(p.vertices, p.faces) == pytest.approx(24) for p in pieces)
