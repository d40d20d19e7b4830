"""X3D (XML and classic encodings) and VRML97 scenes read as the buildings they place (meshsom.x3d).

The scenes are written here in each encoding as converters write them (Transforms with every field, Groups, DEF and
USE, IndexedFaceSet polygons with an L-shaped roof and floor as one polygon each, IndexedTriangleSet, Box, Inline,
Switch, units). Every expected coordinate is worked out here: the Transform's matrix from its fields with SciPy's
rotations (not the reader's Rodrigues formula), the turn from y up to z up by hand, every volume and area from the
footprint.
"""

from __future__ import annotations

import gzip

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, input_kind, read_file
from mesh_checks import HEIGHT, L_AREA, L_PERIMETER, l_prism_polygons, same_points, signed_volume, unsigned_area

#: y up -> z up: (x, y, z) -> (x, -z, y).
TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


def l_prism() -> tuple[np.ndarray, list[list[int]]]:
    """The L-prism in the file's y-up frame (ground x, -z; up y): points (12, 3) and polygons turned outwards,
    counter-clockwise seen from outside (X3D's ccw TRUE)."""
    points, polygons = l_prism_polygons()
    return points @ TO_Z_UP, polygons  # the inverse turn (orthogonal): z up -> the file's y up


#: The Transform of the test: every field (translation, rotation, scale, scaleOrientation, center).
FIELDS = {"translation": (100.0, 2.0, -30.0), "rotation": (0.0, 1.0, 0.0, 0.6), "scale": (2.0, 2.0, 2.0),
          "scaleOrientation": (0.0, 0.0, 1.0, 0.3), "center": (1.0, 0.0, 1.0)}


def expected_matrix(fields: dict) -> np.ndarray:
    """``T C R SR S -SR -C`` of X3D's Transform, with SciPy's rotations (column vectors)."""
    def affine(linear=np.eye(3), shift=(0.0, 0.0, 0.0)):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = linear, shift
        return m

    def rotation(axis_angle):
        axis = np.asarray(axis_angle[:3], float)
        return Rotation.from_rotvec(axis / np.linalg.norm(axis) * axis_angle[3]).as_matrix()

    r, so = rotation(fields["rotation"]), rotation(fields["scaleOrientation"])
    c = np.asarray(fields["center"])
    return (affine(shift=fields["translation"]) @ affine(shift=c) @ affine(r) @ affine(so)
            @ affine(np.diag(fields["scale"])) @ affine(so.T) @ affine(shift=-c))


def placed(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Points placed by a 4 x 4 matrix and turned to z up."""
    return (points @ matrix[:3, :3].T + matrix[:3, 3]) @ TO_Z_UP.T


def classic(header: str, points: np.ndarray, polygons, fields: dict) -> str:
    """The test scene in the classic encoding: a placed house (DEF'd), its geometry USE'd again in a Group moved by
    a second Transform, and a Box."""
    point_text = ", ".join(" ".join(f"{v:.10g}" for v in p) for p in points)
    index_text = " -1 ".join(" ".join(map(str, p)) for p in polygons)
    field_text = " ".join(f"{k} {' '.join(f'{v:.10g}' for v in value)}" for k, value in fields.items())
    return f"""{header}
# written by a converter
WorldInfo {{ title "city" info [ "test" ] }}
NavigationInfo {{ type [ "EXAMINE", "ANY" ] }}
DEF House Transform {{ {field_text}
  children [
    Shape {{
      appearance Appearance {{ material Material {{ diffuseColor 0.8 0.8 0.8 }} }}
      geometry DEF HouseGeometry IndexedFaceSet {{ solid TRUE convex FALSE
        coord Coordinate {{ point [ {point_text} ] }}
        coordIndex [ {index_text} ] }}
    }}
  ]
}}
ROUTE Clock.fraction_changed TO House.set_translation
Group {{ children [ Transform {{ translation 0 0 50 children [ Shape {{ geometry USE HouseGeometry }} ] }} ] }}
DEF Kiosk Transform {{ translation -20 1.5 0 children Shape {{ geometry Box {{ size 2 3 4 }} }} }}
"""


def xml(points: np.ndarray, polygons, fields: dict, head: str = "") -> str:
    point_text = ", ".join(" ".join(f"{v:.10g}" for v in p) for p in points)
    index_text = " -1 ".join(" ".join(map(str, p)) for p in polygons) + " -1"
    field_text = " ".join(f"{k}='{' '.join(f'{v:.10g}' for v in value)}'" for k, value in fields.items())
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<!DOCTYPE X3D PUBLIC "ISO//Web3D//DTD X3D 3.3//EN" "https://www.web3d.org/specifications/x3d-3.3.dtd">
<X3D profile='Interchange' version='3.3' xmlns:xsd='http://www.w3.org/2001/XMLSchema-instance'>
  <head><meta name='generator' content='test'/>{head}</head>
  <Scene>
    <WorldInfo title='city'/>
    <NavigationInfo type='"EXAMINE" "ANY"'/>
    <Transform DEF='House' {field_text}>
      <Shape><Appearance><Material diffuseColor='0.8 0.8 0.8'/></Appearance>
        <IndexedFaceSet DEF='HouseGeometry' convex='false' coordIndex='{index_text}'>
          <Coordinate point='{point_text}'/>
        </IndexedFaceSet>
      </Shape>
    </Transform>
    <Group><Transform translation='0 0 50'><Shape><IndexedFaceSet USE='HouseGeometry'/></Shape></Transform></Group>
    <Transform DEF='Kiosk' translation='-20 1.5 0'><Shape><Box size='2 3 4'/></Shape></Transform>
  </Scene>
</X3D>
"""








@pytest.mark.parametrize("encoding", ["vrml97", "x3d-xml", "x3d-classic"])
def test_top_level_nodes_placed_in_metres_z_up(tmp_path, encoding):
    """Each top-level node with geometry is a building (named by DEF, else by type and place), placed by its
    Transform's every field, turned to z up (noted); the L's concave polygons triangulated in their plane (the
    unsigned area: no fold), USE repeating the geometry where the second Transform puts it, a Box of its size."""
    points, polygons = l_prism()
    suffix, text = {"vrml97": (".wrl", classic("#VRML V2.0 utf8", points, polygons, FIELDS)),
                    "x3d-xml": (".x3d", xml(points, polygons, FIELDS)),
                    "x3d-classic": (".x3dv", classic("#X3D V3.3 utf8\nPROFILE Interchange\nMETA \"generator\" \"t\"",
                                                     points, polygons, FIELDS))}[encoding]
    path = tmp_path / f"city{suffix}"
    path.write_text(text)
    assert input_kind(path) == "x3d"
    got = {m.id: m for m in read_file(path)}
    name = path.name
    assert sorted(got) == sorted([f"{name}#House", f"{name}#Group-4", f"{name}#Kiosk"])
    house = got[f"{name}#House"]
    same_points(house, placed(points, expected_matrix(FIELDS)))
    assert signed_volume(house) == pytest.approx(L_AREA * HEIGHT * 8, rel=1e-9)
    assert unsigned_area(house) == pytest.approx((2 * L_AREA + L_PERIMETER * HEIGHT) * 4, rel=1e-9)
    assert any("y up" in n for n in house.notes)
    moved = np.eye(4)
    moved[:3, 3] = (0, 0, 50)
    same_points(got[f"{name}#Group-4"], placed(points, moved))
    kiosk = got[f"{name}#Kiosk"]
    corners = np.array([(x, y, z) for x in (-1, 1) for y in (-1.5, 1.5) for z in (-2, 2)]) + (-20, 1.5, 0)
    same_points(kiosk, corners @ TO_Z_UP.T)
    assert signed_volume(kiosk) == pytest.approx(24.0)


def test_triangle_sets_clockwise_faces_and_z_up_option(tmp_path):
    """An IndexedTriangleSet with ccw FALSE is turned (a positive volume); up_axis z reads the coordinates as they
    are, without the note."""
    cube = np.array([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)], float) * 3
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]  # outwards, z up
    clockwise = [t[::-1] for q in quads for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]])]
    path = tmp_path / "box.x3d"
    index = " ".join(str(i) for t in clockwise for i in t)
    point = " ".join(f"{v:g}" for v in cube.reshape(-1))
    path.write_text(f"<X3D><Scene><Shape><IndexedTriangleSet ccw='false' index='{index}'><Coordinate point='{point}'/>"
                    f"</IndexedTriangleSet></Shape></Scene></X3D>")
    (got,) = read_file(path, ReaderOptions(up_axis="z"))
    assert got.id == "box.x3d#Shape-1" and got.notes == ()
    same_points(got, cube)
    assert signed_volume(got) == pytest.approx(27.0)


def test_inline_switch_unit_and_unread_geometry(tmp_path):
    """An Inline reads the file beside it (in its unit) where it stands; one naming a file outside the folder or
    none is a rejection of its building; a Switch draws its chosen child; a building of only a Sphere is a rejection
    naming it; the X3D length unit scales the scene."""
    points, polygons = l_prism()
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "house.wrl").write_text(classic("#VRML V2.0 utf8", points, polygons, {"scale": (1, 1, 1)}))
    (tmp_path / "outside.wrl").write_text("#VRML V2.0 utf8\nShape { geometry Box { } }\n")
    city = tmp_path / "city" / "city.x3d"
    city.parent.mkdir()
    (city.parent / "house.wrl").write_text(classic("#VRML V2.0 utf8", points, polygons, {"scale": (1, 1, 1)}))
    city.write_text("""<X3D><head><unit category='length' name='centimetre' conversionFactor='0.01'/></head><Scene>
      <Transform DEF='A' translation='1000 0 0'><Inline url='"missing.wrl" "house.wrl"'/></Transform>
      <Transform DEF='B'><Inline url='"../outside.wrl"'/></Transform>
      <Switch DEF='C' whichChoice='1'>
        <Shape><Box size='100 100 100'/></Shape><Shape><Box size='200 200 200'/></Shape></Switch>
      <Transform DEF='D'><Shape><Sphere radius='3'/></Shape></Transform>
    </Scene></X3D>""")
    got = {m.id: m for m in read_file(city)}
    assert sorted(got) == ["city.x3d#A", "city.x3d#B", "city.x3d#C", "city.x3d#D"]
    a = got["city.x3d#A"]
    assert isinstance(a, RawMesh)
    # the inlined scene: House (the L, scale 1), the USE'd copy 50 along z, the Kiosk box; all times 0.01, moved 10 m
    assert signed_volume(a) == pytest.approx((2 * L_AREA * HEIGHT + 24.0) * 1e-6, rel=1e-9)
    assert (a.vertices + a.origin)[:, 0].min() == pytest.approx(10.0 - 0.21)
    assert isinstance(got["city.x3d#B"], Rejection) and "outside its own folder" in got["city.x3d#B"].reason
    assert signed_volume(got["city.x3d#C"]) == pytest.approx(8.0)
    assert isinstance(got["city.x3d#D"], Rejection) and "1 Sphere" in got["city.x3d#D"].reason


def test_damaged_files_are_rejections_naming_them(tmp_path):
    """A brace never closed, VRML 1.0, an XML file that is not X3D, and a face naming a point its Coordinate has
    not (that building alone) are rejections saying so."""
    cases = {"open.wrl": "#VRML V2.0 utf8\nTransform { children [ Shape { geometry Box { } }\n",
             "old.wrl": "#VRML V1.0 ascii\nSeparator { Cube { } }\n",
             "other.x3d": "<COLLADA><asset/></COLLADA>",
             "text.wrl": "just some text\n"}
    for file_name, text in cases.items():
        (tmp_path / file_name).write_text(text)
        (got,) = read_file(tmp_path / file_name)
        assert isinstance(got, Rejection) and got.source == str(tmp_path / file_name)
    reasons = {n: next(iter(read_file(tmp_path / n))).reason for n in cases}
    assert "missing" in reasons["open.wrl"] and "VRML 1.0" in reasons["old.wrl"]
    assert "expected an <X3D> document" in reasons["other.x3d"] and "neither X3D" in reasons["text.wrl"]
    path = tmp_path / "mixed.wrl"
    path.write_text("#VRML V2.0 utf8\nDEF Good Shape { geometry Box { } }\nDEF Bad Shape { geometry IndexedFaceSet {"
                    " coord Coordinate { point [ 0 0 0, 1 0 0, 0 1 0 ] } coordIndex [ 0 1 5 -1 ] } }\n")
    got = {m.id: m for m in read_file(path)}
    assert isinstance(got["mixed.wrl#Good"], RawMesh)
    assert "refers to point 5, and its Coordinate has 3 points" in got["mixed.wrl#Bad"].reason


def test_gzipped_scenes_and_folder_walk(tmp_path):
    points, polygons = l_prism()
    text = classic("#VRML V2.0 utf8", points, polygons, {"scale": (1, 1, 1)})
    (tmp_path / "a.wrl.gz").write_bytes(gzip.compress(text.encode()))
    (tmp_path / "b.wrz").write_bytes(gzip.compress(text.encode()))
    (tmp_path / "c.x3d").write_text(xml(points, polygons, {"scale": (1, 1, 1)}))
    files, rejected = expand_inputs([tmp_path])
    assert sorted(f.name for f in files) == ["a.wrl.gz", "b.wrz", "c.x3d"] and not rejected
    for name in ("a.wrl.gz", "b.wrz"):
        got = {m.id: m for m in read_file(tmp_path / name)}
        assert signed_volume(got[f"{name}#House"]) == pytest.approx(L_AREA * HEIGHT)


def test_a_node_that_uses_itself_and_deep_nesting_are_rejections(tmp_path):
    """A Group that USEs itself (an endless scene) is a rejection of its building, and a file nested deeper than
    the recursion limit a rejection of the file; neither crashes the reader."""
    path = tmp_path / "loop.x3d"
    path.write_text("<X3D><Scene><Shape DEF='ok'><Box/></Shape><Group DEF='a'><Shape><Box/></Shape><Group USE='a'/>"
                    "</Group></Scene></X3D>")
    got = {m.id: m for m in read_file(path)}
    assert isinstance(got["loop.x3d#ok"], RawMesh) and "USEs itself" in got["loop.x3d#a"].reason
    deep = tmp_path / "deep.wrl"
    deep.write_text("#VRML V2.0 utf8\n" + "Group { children [ " * 5000 + "Shape { geometry Box { } }" + " ] }" * 5000)
    (got,) = read_file(deep)
    assert isinstance(got, Rejection) and "recursion limit" in got.reason


def test_binary_x3d_is_refused_naming_the_encodings_read(tmp_path):
    path = tmp_path / "city.x3db"
    path.write_bytes(b"\x00\x01binary")
    (got,) = read_file(path)
    assert got.reason.startswith("unknown file type '.x3db' (binary X3D: not read; save it in the XML (.x3d)")
    assert ".x3d, .x3dv, .wrl" in got.reason


def test_a_city_in_one_group_split_into_its_buildings(tmp_path):
    """CityGML2X writes a whole city as one top-level Group of Shapes (one IndexedFaceSet each, z up as CityGML
    gave it): one building as read, its buildings with split_components, z up with up_axis z."""
    cube = np.array([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    index = " ".join(" ".join(map(str, q)) + " -1" for q in quads)
    points = [" ".join(f"{v:.10g}" for v in (cube * (2, 3, 10) + offset).reshape(-1))
              for offset in ((2600000, 1200000, 400), (2600010, 1200000, 400))]
    shapes = "".join(f"<Shape><IndexedFaceSet solid='false' convex='false' coordIndex='{index}'>"
                     f"<Coordinate point='{p}'/></IndexedFaceSet></Shape>" for p in points)
    path = tmp_path / "output.x3d"
    path.write_text(f"<X3D profile='Interchange' version='3.3'><Scene><Group>{shapes}</Group></Scene></X3D>")
    (whole,) = read_file(path, ReaderOptions(up_axis="z"))
    assert whole.id == "output.x3d#Group-1" and signed_volume(whole) == pytest.approx(120.0)
    pieces = list(read_file(path, ReaderOptions(up_axis="z", split_components=True)))
    assert [m.id for m in pieces] == ["output.x3d#Group-1#c1", "output.x3d#Group-1#c2"]
    same_points(pieces[1], cube * (2, 3, 10) + (2600010, 1200000, 400))


def test_extrusions_swept_along_their_spines(tmp_path):
    """Extrusions by the specification's defaults (a 2 x 2 square swept 1 along y: 4 m3), an L cross-section with
    its caps (the footprint's area times the height; the caps triangulated in their plane: the unsigned area), a
    spine along (3, 0, 4) (20 m3, its end cap centred on the spine's end), a frustum by scale (the frustum formula)
    and one without caps (the sides alone); faces outwards (positive volumes)."""
    section = " ".join(f"{x:g} {z:g}" for x, z in [(12, 4), (12, 0), (0, 0), (0, 10), (4, 10), (4, 4), (12, 4)])
    path = tmp_path / "extrusions.x3d"
    path.write_text(f"""<X3D><Scene>
      <Shape DEF='default'><Extrusion/></Shape>
      <Shape DEF='L'><Extrusion crossSection='{section}' spine='0 0 0 0 7 0' convex='false'/></Shape>
      <Shape DEF='tilted'><Extrusion spine='0 0 0 3 0 4'/></Shape>
      <Shape DEF='frustum'><Extrusion scale='1 1 2 2' orientation='0 1 0 0.5'/></Shape>
      <Shape DEF='open'><Extrusion beginCap='false' endCap='false'/></Shape>
    </Scene></X3D>""")
    got = {m.id.split("#")[1]: m for m in read_file(path, ReaderOptions(up_axis="z"))}
    assert signed_volume(got["default"]) == pytest.approx(4.0)
    same_points(got["default"], np.array([(x, y, z) for x in (-1, 1) for y in (0, 1) for z in (-1, 1)], float))
    assert signed_volume(got["L"]) == pytest.approx(L_AREA * HEIGHT)
    assert unsigned_area(got["L"]) == pytest.approx(2 * L_AREA + L_PERIMETER * HEIGHT)
    assert signed_volume(got["tilted"]) == pytest.approx(20.0)
    end = got["tilted"].vertices + got["tilted"].origin
    far = end[np.argsort(end @ np.array([3, 0, 4]))[-4:]]  # the end cap: the 4 corners farthest along the spine
    np.testing.assert_allclose(far.mean(axis=0), [3, 0, 4], atol=1e-9)
    np.testing.assert_allclose((far - [3, 0, 4]) @ np.array([0.6, 0, 0.8]), 0, atol=1e-9)
    assert signed_volume(got["frustum"]) == pytest.approx((4 + 16 + 8) / 3)
    assert len(got["open"].faces) == 8


def test_a_closed_extrusion_faces_outwards_whichever_way_its_section_runs(tmp_path):
    """A wall swept around a closed square spine (no caps: the spine closes it) whose cross-section runs the other
    way round from the specification's default still encloses a positive volume; reversing the section gives the
    same volume."""
    walls = "0.5 0 0.5 3 -0.5 3 -0.5 0 0.5 0"
    reverse = "0.5 0 -0.5 0 -0.5 3 0.5 3 0.5 0"
    spine = "0 0 0 10 0 0 10 0 10 0 0 10 0 0 0"
    path = tmp_path / "ring.wrl"
    shapes = [f"DEF {name} Shape {{ geometry Extrusion {{ crossSection [ {section} ] spine [ {spine} ] }} }}"
              for name, section in (("A", walls), ("B", reverse))]
    path.write_text("#VRML V2.0 utf8\n" + "\n".join(shapes) + "\n")
    a, b = read_file(path)
    assert signed_volume(a) > 0 and signed_volume(a) == pytest.approx(signed_volume(b))


def test_folder_walk_reads_inlined_scenes_through_their_scene(tmp_path):
    """A folder of a city scene and the house scenes it inlines (and a roof the house inlines) reads the city once:
    each inlined file is listed as skipped, read through the scene, not read again as a scene of its own (its
    buildings would count twice). Scenes that inline each other are each read (the loop is their reading's
    rejection), never both skipped; a scene nobody inlines is read as it is."""
    (tmp_path / "roof.wrl").write_text("#VRML V2.0 utf8\nShape { geometry Box { size 1 1 1 } }\n")
    (tmp_path / "house.wrl").write_text("#VRML V2.0 utf8\nShape { geometry Box { } }\nInline { url \"roof.wrl\" }\n")
    (tmp_path / "city.x3d").write_text("<X3D><Scene><Transform DEF='H1'><Inline url='\"house.wrl\"'/></Transform>"
                                       "<Transform DEF='H2' translation='10 0 0'><Inline url='\"house.wrl\"'/>"
                                       "</Transform></Scene></X3D>")
    (tmp_path / "loop").mkdir()
    (tmp_path / "loop" / "a.wrl").write_text("#VRML V2.0 utf8\nInline { url \"b.wrl\" }\n")
    (tmp_path / "loop" / "b.wrl").write_text("#VRML V2.0 utf8\nInline { url \"a.wrl\" }\n")
    (tmp_path / "alone.wrl").write_text("#VRML V2.0 utf8\nDEF Kiosk Shape { geometry Box { size 1 2 3 } }\n")
    skipped = []
    files, rejected = expand_inputs([tmp_path], skipped)
    assert sorted(f.name for f in files) == ["alone.wrl", "city.x3d", "loop/a.wrl", "loop/b.wrl"] and not rejected
    reasons = dict(skipped)
    assert reasons[str(tmp_path / "house.wrl")] == f"inlined by the scene {tmp_path / 'city.x3d'}, read through it"
    assert reasons[str(tmp_path / "roof.wrl")].startswith("inlined by the scene ")
    got = {m.id: m for f in files for m in read_file(f.path, name=f.name)}
    # each house: a 2 m box and the 1 m roof box inlined in it (the two overlap; the volume is the sum of shells)
    assert signed_volume(got["city.x3d#H1"]) == pytest.approx(8.0 + 1.0)
    assert signed_volume(got["city.x3d#H2"]) == pytest.approx(8.0 + 1.0)
    assert signed_volume(got["alone.wrl#Kiosk"]) == pytest.approx(6.0)
    assert all(isinstance(m, Rejection) for k, m in got.items() if k.startswith("loop/"))
    assert not any(k.startswith(("house.wrl", "roof.wrl")) for k in got)
