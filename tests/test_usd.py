"""USD stages read as the buildings they place (meshsom.usd).

The stages are built here with Pixar's own ``pxr`` as ArcGIS Pro, Omniverse and USDZ writers lay them out: meshes of
polygons (an L-shaped roof and floor as one n-gon each), transforms, instanceable references, a PointInstancer,
kinds, purposes and visibility, in centimetres and metres, y up and z up. Every expected coordinate is worked out
here from the vertices, the transforms and the turn to z up by hand, every volume and area from the footprint.
"""

from __future__ import annotations

import gzip
import zipfile

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdUtils, Vt  # noqa: E402

from meshsom.io import RawMesh, Rejection, expand_inputs, input_kind, read_file  # noqa: E402
from mesh_checks import (  # noqa: E402
    HEIGHT, L_AREA, L_PERIMETER, L_SHAPE, l_prism_polygons, rotation_z, signed_volume, unsigned_area,
)
from mesh_checks import same_points as _same_points  # noqa: E402

#: z up -> a file's axes (the inverse of the turn to z up; orthogonal): a y-up file's (x, y, z) is z up's (x, z, -y).
FROM_Z_UP = {"Z": np.eye(3), "Y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])}


def l_prism() -> tuple[np.ndarray, list[int], list[int]]:
    """The L-prism in metres, z up: points (12, 3), faceVertexCounts, faceVertexIndices (USD's rightHanded)."""
    points, polygons = l_prism_polygons()
    return points, [len(p) for p in polygons], [i for p in polygons for i in p]


def same_points(got: RawMesh, expected: np.ndarray) -> None:
    """The world vertices are the expected points, to the float32 precision of USD's points."""
    _same_points(got, expected, decimals=3, atol=2e-3)


def define_mesh(stage, path: str, points_m: np.ndarray, counts, indices, metres: float, up: str):
    """A UsdGeom.Mesh of z-up metre points written in the stage's unit and axes."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy((points_m @ FROM_Z_UP[up].T / metres).astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(indices)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return mesh


def new_stage(path, metres: float | None, up: str | None):
    stage = Usd.Stage.CreateNew(str(path))
    if metres is not None:
        UsdGeom.SetStageMetersPerUnit(stage, metres)
    if up is not None:
        UsdGeom.SetStageUpAxis(stage, up)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    return stage










@pytest.mark.parametrize("up", ["Z", "Y", None])
@pytest.mark.parametrize("metres", [0.01, 1.0, None])
def test_a_placed_l_prism_in_metres_z_up(tmp_path, metres, up):
    """A mesh under a transformed Xform is a building at its transform's place (rotated about the up axis, scaled,
    translated), in metres by metersPerUnit (0.01 where the stage authors none) and z up by upAxis (Y where none);
    its concave L roof and floor triangulated in their plane (the unsigned area: no fold), its volume the
    footprint's times the height times the scale cubed."""
    path = tmp_path / "house.usda"
    file_metres, file_up = metres or 0.01, up or "Y"
    stage = new_stage(path, metres, up)
    house = UsdGeom.Xform.Define(stage, "/World/House")
    shift = np.array([250.0, -40.0, 3.0])  # metres, z up
    house.AddTranslateOp().Set(Gf.Vec3d(*(FROM_Z_UP[file_up] @ shift / file_metres)))
    house.AddRotateXYZOp().Set(Gf.Vec3f(*(30.0 * FROM_Z_UP[file_up] @ [0, 0, 1])))  # 30 degrees about the up axis
    house.AddScaleOp().Set(Gf.Vec3f(2.0, 2.0, 2.0))
    points, counts, indices = l_prism()
    define_mesh(stage, "/World/House/Geom", points, counts, indices, file_metres, file_up)
    stage.Save()
    assert input_kind(path) == "usd"
    (got,) = read_file(path)
    assert isinstance(got, RawMesh) and got.id == "house.usda#World/House" and got.source == str(path)
    same_points(got, points @ (2.0 * rotation_z(30.0)).T + shift)
    assert signed_volume(got) == pytest.approx(L_AREA * HEIGHT * 8, rel=1e-5)
    assert unsigned_area(got) == pytest.approx((2 * L_AREA + L_PERIMETER * HEIGHT) * 4, rel=1e-5)
    assert ("upAxis Y: turned to z up" in got.notes) == (file_up == "Y")
    assert any("no metersPerUnit" in n for n in got.notes) == (metres is None)
    assert any("no upAxis" in n for n in got.notes) == (up is None)


def test_up_axis_option_where_the_stage_authors_none(tmp_path):
    """A stage without upAxis is read as corpus.reader.up_axis says where it says one."""
    from meshsom.io import ReaderOptions

    path = tmp_path / "house.usda"
    stage = new_stage(path, 1.0, None)
    points, counts, indices = l_prism()
    define_mesh(stage, "/World/House", points, counts, indices, 1.0, "Z")
    stage.Save()
    (got,) = read_file(path, ReaderOptions(up_axis="z"))
    same_points(got, points)
    assert got.notes == ()


def write_box(stage, path: str, size: float, metres: float = 1.0):
    """A cube of ``size`` metres from the origin as a UsdGeom.Mesh of six quads, turned outwards."""
    corners = np.array([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.float64) * size
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    return define_mesh(stage, path, corners, [4] * 6, [i for q in quads for i in q], metres, "Z")


def test_instances_and_point_instancer(tmp_path):
    """Instanceable references are read through their proxies, one building each where it stands; a
    PointInstancer's instances each one building, placed by position, orientation and scale after their prototype
    root's own transform; an instance its invisibleIds hide left out; the prototypes under the instancer are not
    buildings of their own."""
    path = tmp_path / "instances.usdc"
    stage = new_stage(path, 1.0, "Z")
    proto = UsdGeom.Xform.Define(stage, "/Prototypes/House")
    stage.GetPrimAtPath("/Prototypes").SetSpecifier(Sdf.SpecifierClass)
    points, counts, indices = l_prism()
    define_mesh(stage, "/Prototypes/House/Geom", points, counts, indices, 1.0, "Z")
    shifts = [np.array([100.0, 0, 0]), np.array([0.0, 100.0, 0])]
    for k, shift in enumerate(shifts):
        ref = UsdGeom.Xform.Define(stage, f"/World/Row/House{k}")
        ref.AddTranslateOp().Set(Gf.Vec3d(*shift))
        ref.GetPrim().GetReferences().AddInternalReference(proto.GetPath())
        ref.GetPrim().SetInstanceable(True)
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    instancer.AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    box = UsdGeom.Xform.Define(stage, "/World/Scatter/Prototypes/Box")
    box.AddTranslateOp().Set(Gf.Vec3d(1, 0, 0))  # the prototype root's own transform: applied first
    write_box(stage, "/World/Scatter/Prototypes/Box/Geom", 3.0)
    instancer.CreatePrototypesRel().SetTargets([box.GetPath()])
    instancer.CreateProtoIndicesAttr([0, 0, 0])
    positions = np.array([[-50.0, 0, 0], [-80.0, 0, 0], [-110.0, 0, 0]])
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
    half = np.sqrt(0.5)
    instancer.CreateOrientationsfAttr([Gf.Quatf(1, 0, 0, 0), Gf.Quatf(half, 0, 0, half), Gf.Quatf(1, 0, 0, 0)])
    instancer.CreateScalesAttr([Gf.Vec3f(1, 1, 1), Gf.Vec3f(2, 2, 2), Gf.Vec3f(1, 1, 1)])
    instancer.CreateInvisibleIdsAttr([2])
    stage.Save()
    got = {m.id: m for m in read_file(path)}
    assert sorted(got) == ["instances.usdc#World/Row/House0",
                           "instances.usdc#World/Row/House1", "instances.usdc#World/Scatter[0]",
                           "instances.usdc#World/Scatter[1]"]
    for k, shift in enumerate(shifts):
        mesh = got[f"instances.usdc#World/Row/House{k}"]
        same_points(mesh, points + shift)
        assert signed_volume(mesh) == pytest.approx(L_AREA * HEIGHT, rel=1e-6)
    cube = np.array([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.float64) * 3.0
    # instance 0: the box moved by its root (1, 0, 0), then the position, then the instancer's (0, 0, 10)
    same_points(got["instances.usdc#World/Scatter[0]"], cube + [1, 0, 0] + positions[0] + [0, 0, 10])
    # instance 1: scaled by 2 and turned 90 degrees about z after the root's shift, then placed
    same_points(got["instances.usdc#World/Scatter[1]"],
                (cube + [1, 0, 0]) @ (2 * rotation_z(90)).T + positions[1] + [0, 0, 10])
    assert signed_volume(got["instances.usdc#World/Scatter[1]"]) == pytest.approx(27 * 8, rel=1e-6)


def test_buildings_by_kind_and_by_the_prim_that_holds_them(tmp_path):
    """A component model is one building, its meshes (walls and roof, each under an Xform of its own) united; in a
    stage without kinds the prim holding meshes is one building, and a mesh right under the default prim is one."""
    path = tmp_path / "city.usda"
    stage = new_stage(path, 1.0, "Z")
    Usd.ModelAPI(UsdGeom.Xform.Define(stage, "/World/City").GetPrim()).SetKind(Kind.Tokens.assembly)
    Usd.ModelAPI(UsdGeom.Xform.Define(stage, "/World/City/B1").GetPrim()).SetKind(Kind.Tokens.component)
    points, counts, indices = l_prism()
    n = len(L_SHAPE)
    walls = [c for c in range(2, len(counts))]
    offsets = np.cumsum([0] + counts)
    roof_floor = indices[:offsets[2]]
    define_mesh(stage, "/World/City/B1/Roof/Geom", points, counts[:2], roof_floor, 1.0, "Z")
    define_mesh(stage, "/World/City/B1/Walls/Geom", points, [4] * len(walls), indices[offsets[2]:], 1.0, "Z")
    define_mesh(stage, "/World/Kiosk", points / 2, counts, indices, 1.0, "Z")
    holder = UsdGeom.Xform.Define(stage, "/World/Plain")
    holder.AddTranslateOp().Set(Gf.Vec3d(50, 0, 0))
    write_box(stage, "/World/Plain/Part1", 2.0)
    part2 = write_box(stage, "/World/Plain/Part2", 2.0)
    part2.AddTranslateOp().Set(Gf.Vec3d(2, 0, 0))  # beside Part1: one 4 x 2 x 2 block of two boxes
    stage.Save()
    got = {m.id: m for m in read_file(path)}
    assert sorted(got) == ["city.usda#World/City/B1", "city.usda#World/Kiosk", "city.usda#World/Plain"]
    assert len(got["city.usda#World/City/B1"].vertices) == 2 * n  # the walls' and roof's corners joined
    assert signed_volume(got["city.usda#World/City/B1"]) == pytest.approx(L_AREA * HEIGHT)
    assert signed_volume(got["city.usda#World/Kiosk"]) == pytest.approx(L_AREA * HEIGHT / 8)
    assert signed_volume(got["city.usda#World/Plain"]) == pytest.approx(16.0)
    same_points(got["city.usda#World/Plain"], np.array([(x, y, z) for x in (50, 52, 54) for y in (0, 2)
                                                        for z in (0, 2)], np.float64))


def test_invisible_guide_and_proxy_left_out(tmp_path):
    """Invisible prims and guides are left out; a building's proxy mesh is left out where it has a render one (its
    full-detail mesh), noted; a proxy alone is read."""
    path = tmp_path / "purposes.usda"
    stage = new_stage(path, 1.0, "Z")
    UsdGeom.Xform.Define(stage, "/World/Hidden").CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    write_box(stage, "/World/Hidden/Geom", 1.0)
    write_box(stage, "/World/Both/Render", 2.0).CreatePurposeAttr(UsdGeom.Tokens.render)
    write_box(stage, "/World/Both/Proxy", 1.0).CreatePurposeAttr(UsdGeom.Tokens.proxy)
    write_box(stage, "/World/Both/Guide", 5.0).CreatePurposeAttr(UsdGeom.Tokens.guide)
    write_box(stage, "/World/ProxyOnly/Geom", 3.0).CreatePurposeAttr(UsdGeom.Tokens.proxy)
    stage.Save()
    got = {m.id: m for m in read_file(path)}
    assert sorted(got) == ["purposes.usda#World/Both", "purposes.usda#World/ProxyOnly"]
    assert signed_volume(got["purposes.usda#World/Both"]) == pytest.approx(8.0)
    assert any("proxy-purpose" in n for n in got["purposes.usda#World/Both"].notes)
    assert any("1 invisible prims" in n for n in got["purposes.usda#World/Both"].notes)
    assert signed_volume(got["purposes.usda#World/ProxyOnly"]) == pytest.approx(27.0)


def test_usdz_and_gzip_read_as_the_stage_they_hold(tmp_path):
    """A USDZ package (a zip of a crate file) and a gzipped .usda are read as the stage inside."""
    plain = tmp_path / "house.usdc"
    stage = new_stage(plain, 0.01, "Y")
    points, counts, indices = l_prism()
    define_mesh(stage, "/World/House", points, counts, indices, 0.01, "Y")
    stage.Save()
    packed = tmp_path / "house.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(plain)), str(packed))
    assert zipfile.is_zipfile(packed) and input_kind(packed) == "usd"
    text = tmp_path / "house.usda"
    Usd.Stage.Open(str(plain)).Export(str(text))
    gz = tmp_path / "house.usda.gz"
    gz.write_bytes(gzip.compress(text.read_bytes()))
    for path in (packed, gz):
        (got,) = read_file(path)
        assert isinstance(got, RawMesh) and got.id == f"{path.name}#World/House" and got.source == str(path)
        same_points(got, points)
        assert signed_volume(got) == pytest.approx(L_AREA * HEIGHT, rel=1e-5)


def test_damaged_files_and_unread_geometry_are_rejections_naming_them(tmp_path):
    """A file USD cannot open, a mesh whose indices name points it has not, and a building of only a NURBS patch
    are rejections saying so, naming the file (and the mesh); the other buildings are read."""
    broken = tmp_path / "broken.usdc"
    broken.write_bytes(b"PXR-USDC" + bytes(range(256)) * 4)
    text = tmp_path / "broken.usda"
    text.write_text("#usda 1.0\ndef Mesh \"House\" {\n  point3f[] points = [(0, 0, 0), (1, 0\n")
    for path in (broken, text):
        (got,) = read_file(path)
        assert isinstance(got, Rejection) and got.source == str(path) and got.id == str(path)
        assert "cannot be read as USD" in got.reason
    path = tmp_path / "mixed.usda"
    stage = new_stage(path, 1.0, "Z")
    write_box(stage, "/World/Good", 1.0)
    bad = UsdGeom.Mesh.Define(stage, "/World/Bad/Geom")
    bad.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    bad.CreateFaceVertexCountsAttr([3])
    bad.CreateFaceVertexIndicesAttr([0, 1, 7])
    stage.Save()
    got = {m.id: m for m in read_file(path)}
    assert isinstance(got["mixed.usda#World/Good"], RawMesh)
    bad = got["mixed.usda#World/Bad"]
    assert isinstance(bad, Rejection) and "/World/Bad/Geom" in bad.reason and str(path) in bad.reason
    assert "refers to point 7, and the mesh has 3 points" in bad.reason


def test_nurbs_only_building_is_a_rejection(tmp_path):
    path = tmp_path / "nurbs.usda"
    stage = new_stage(path, 1.0, "Z")
    write_box(stage, "/World/Good", 1.0)
    UsdGeom.NurbsPatch.Define(stage, "/World/Dome/Surface")
    stage.Save()
    got = {m.id: m for m in read_file(path)}
    assert isinstance(got["nurbs.usda#World/Good"], RawMesh)
    assert isinstance(got["nurbs.usda#World/Dome"], Rejection) and "1 NurbsPatch" in got["nurbs.usda#World/Dome"].reason


def test_folder_walk_finds_every_usd_suffix(tmp_path):
    for suffix in (".usd", ".usda", ".usdc"):
        stage = new_stage(tmp_path / f"h{suffix}", 1.0, "Z")
        write_box(stage, "/World/Box", 1.0)
        stage.Save()
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(tmp_path / "h.usdc")), str(tmp_path / "z.usdz"))
    skipped = []
    files, rejected = expand_inputs([tmp_path], skipped)
    assert sorted(f.name for f in files) == ["h.usd", "h.usda", "h.usdc", "z.usdz"] and not rejected and not skipped


def test_without_usd_core_the_rejection_says_what_to_install(tmp_path, monkeypatch):
    path = tmp_path / "house.usda"
    stage = new_stage(path, 1.0, "Z")
    write_box(stage, "/World/Box", 1.0)
    stage.Save()
    monkeypatch.setitem(__import__("sys").modules, "pxr", None)  # import pxr now raises ImportError
    (got,) = read_file(path)
    assert isinstance(got, Rejection) and "needs usd-core (pip install usd-core)" in got.reason


def test_the_l_roof_check_tells_a_fan_from_a_triangulation():
    """The unsigned-area check of the L-prism test fails for a fan from the ring's first vertex (what a reader that
    fans polygons gives), so it does test the triangulation in the polygon's plane."""
    points, counts, indices = l_prism()
    roof = np.array(indices[counts[0]:counts[0] + counts[1]])
    fan = np.stack([np.full(len(roof) - 2, roof[0]), roof[1:-1], roof[2:]], axis=1)
    corners = points[fan]
    area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum() / 2
    assert area > L_AREA * 1.01


def test_cubes_read_and_attributes_of_the_wrong_type_rejected(tmp_path):
    """A UsdGeom.Cube is a box of its size (a massing model); a PointInstancer of a Cube prototype gives a box per
    instance; a mesh whose points attribute is not an array of 3-vectors is a rejection naming it."""
    path = tmp_path / "massing.usda"
    stage = new_stage(path, 1.0, "Z")
    block = UsdGeom.Cube.Define(stage, "/World/Block")
    block.CreateSizeAttr(4.0)
    block.AddTranslateOp().Set(Gf.Vec3d(10, 0, 2))
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Kiosks")
    UsdGeom.Cube.Define(stage, "/World/Kiosks/Prototypes/Box")  # size 2 (USD's fallback)
    instancer.CreatePrototypesRel().SetTargets(["/World/Kiosks/Prototypes/Box"])
    instancer.CreateProtoIndicesAttr([0, 0])
    instancer.CreatePositionsAttr([Gf.Vec3f(0, 0, 1), Gf.Vec3f(5, 0, 1)])
    stage.Save()
    got = {m.id: m for m in read_file(path)}
    assert sorted(got) == ["massing.usda#World/Block", "massing.usda#World/Kiosks[0]", "massing.usda#World/Kiosks[1]"]
    same_points(got["massing.usda#World/Block"],
                np.array([(x, y, z) for x in (8, 12) for y in (-2, 2) for z in (0, 4)], np.float64))
    assert signed_volume(got["massing.usda#World/Block"]) == pytest.approx(64.0)
    same_points(got["massing.usda#World/Kiosks[1]"],
                np.array([(x, y, z) for x in (4, 6) for y in (-1, 1) for z in (0, 2)], np.float64))
    bad = tmp_path / "bad.usda"  # as the usd-wg test assets write a mistyped attribute
    bad.write_text('#usda 1.0\n(\n    upAxis = "Z"\n    metersPerUnit = 1\n)\ndef Xform "World" {\n'
                   '    def Mesh "Bad" {\n        int points = 7\n        int[] faceVertexCounts = [3]\n'
                   '        int[] faceVertexIndices = [0, 1, 2]\n    }\n}\n')
    (got,) = read_file(bad)
    assert isinstance(got, Rejection) and got.id == "bad.usda#World/Bad"
    assert "its points holds '7' (int), expected an array of 3-vectors" in got.reason
