"""ACIS solids (DXF 3DSOLID / BODY) tessellated: closed, outward, on their exact geometry, in both encodings.

The solids are written here (tests/acis_solids.py: extruded profiles of lines and arcs, as AutoCAD's
EXTRUDE makes them) in SAT text (ACIS 700, DXF R2000; 20800 with the asm header of R2004-R2010) and
SAB binary (R2013 and later); every figure checked is computed from the profile, not from a mesh.
"""

from __future__ import annotations

import math
from pathlib import Path

import ezdxf
import numpy as np
import pytest
from ezdxf.math import Matrix44

from acis_solids import (add_solid, cone_body, dome_body, extrusion_body, profile_area, ring_fillet_body, sab_bytes,
                         sat_lines, seam_cylinder_body, sphere_body, torus_body, tower_with_window_body)
from meshsom.acis import AcisError, acis_mesh
from meshsom.dxf import FLATTEN_REL, read_dxf
from meshsom.io import RawMesh, ReaderOptions, Rejection
from test_dxf import closed, signed_volume

ENCODINGS = {
    "SAT 700": lambda bodies: sat_lines(bodies, 700),
    "SAT 20800": lambda bodies: sat_lines(bodies, 20800),
    "SAB 21800": sab_bytes,
}
SQUARE = [("line", (10.0, 0.0)), ("line", (10.0, 6.0)), ("line", (0.0, 6.0)), ("line", (0.0, 0.0))]
PROFILES = {
    "box": [SQUARE],
    # a curved facade bulging out (a half circle of radius 4 about (10, 4)) and one cut in
    "convex facade": [[("line", (10.0, 0.0)), ("arc", (10.0, 8.0), (10.0, 4.0)), ("line", (0.0, 8.0)), ("line", (0.0, 0.0))]],
    "concave facade": [[("line", (10.0, 0.0)), ("arc", (10.0, 8.0), (10.0, 4.0), False), ("line", (0.0, 8.0)),
                        ("line", (0.0, 0.0))]],
    "round tower": [[("circle", (3.0, 4.0), 5.0)]],
    # a block with a round courtyard and a square light well
    "courtyards": [[("line", (20.0, 0.0)), ("line", (20.0, 20.0)), ("line", (0.0, 20.0)), ("line", (0.0, 0.0))],
                   [("circle", (10.0, 10.0), 4.0, False)],
                   [("line", (2.0, 5.0)), ("line", (5.0, 5.0)), ("line", (5.0, 2.0)), ("line", (2.0, 2.0))]],
}
#: (centre, radius) of each profile's circular arcs: every point of the side there lies on that cylinder.
ARCS = {"convex facade": [((10.0, 4.0), 4.0)], "concave facade": [((10.0, 4.0), 4.0)],
        "round tower": [((3.0, 4.0), 5.0)], "courtyards": [((10.0, 10.0), 4.0)]}
ARC_LENGTH = {"box": 0.0, "convex facade": 4 * math.pi, "concave facade": 4 * math.pi, "round tower": 10 * math.pi,
              "courtyards": 8 * math.pi}
Z0, Z1 = 2.0, 14.0
#: How closely an encoding keeps coordinates: ezdxf writes SAT numbers to 6 significant digits (AutoCAD to 17), SAB
#: as doubles.
DIGITS = {"SAT 700": 1e-5, "SAT 20800": 1e-5, "SAB 21800": 1e-12}


def check_solid(vertices: np.ndarray, triangles: np.ndarray, exact_volume: float, arc_length: float, extent: float,
                height: float = Z1 - Z0):
    """Closed (each edge twice, once each way), outward, and of the exact volume within what chords can lose: the
    arcs' length x the chords' largest distance (``FLATTEN_REL`` x extent) x the height."""
    assert closed(triangles)
    volume = signed_volume(vertices, triangles)
    assert volume > 0
    assert abs(volume - exact_volume) <= arc_length * FLATTEN_REL * extent * height + 1e-9 * exact_volume
    return volume


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("name", PROFILES)
def test_extruded_profiles_are_closed_outward_and_exact(name, encoding):
    profile = PROFILES[name]
    mesh = acis_mesh(ENCODINGS[encoding]([extrusion_body(profile, Z0, Z1)]), FLATTEN_REL)
    pts = np.array([seg[1] for loop in profile for seg in loop if seg[0] != "circle"]
                   + [np.add(seg[1], seg[2]) for loop in profile for seg in loop if seg[0] == "circle"])
    extent = float(np.linalg.norm(np.append(np.ptp(pts, axis=0) + 10.0, Z1 - Z0)))  # above the solid's box
    check_solid(mesh.vertices, mesh.triangles, profile_area(profile) * (Z1 - Z0), ARC_LENGTH[name], extent)
    assert set(np.unique(mesh.vertices[:, 2])) == {Z0, Z1}  # nothing made up between the caps
    curved = mesh.faces.get("cylindrical", 0)
    assert curved == len(ARCS.get(name, []))
    assert mesh.faces["plane"] == 2 + sum(len(loop) for loop in profile if loop[0][0] != "circle") - curved + sum(
        1 for loop in profile if loop[0][0] == "circle")
    for (cx, cy), r in ARCS.get(name, []):
        off = np.abs(np.hypot(mesh.vertices[:, 0] - cx, mesh.vertices[:, 1] - cy) - r)
        on = off < 1e-6
        assert on.sum() >= 2 * 8  # arcs sampled, on the cylinder to rounding
        assert off[on].max() < 1e-12 * 100


def test_arcs_are_sampled_within_the_tolerance_and_shared_by_both_faces():
    """The tower's circles: chords within FLATTEN_REL of the extent, and each circle's points are the cap's and the wall's."""
    mesh = acis_mesh(sat_lines([extrusion_body(PROFILES["round tower"], Z0, Z1)], 700), FLATTEN_REL)
    v = mesh.vertices
    bottom = np.flatnonzero(v[:, 2] == Z0)
    angles = np.sort(np.arctan2(v[bottom, 1] - 4.0, v[bottom, 0] - 3.0))
    gaps = np.diff(np.append(angles, angles[0] + 2 * math.pi))
    sagitta = 5.0 * (1 - np.cos(gaps.max() / 2))
    extent = np.linalg.norm([10.0, 10.0, Z1 - Z0])  # the solid's box
    assert sagitta <= FLATTEN_REL * extent * (1 + 1e-9)
    assert np.ptp(gaps) < 1e-9  # equal angles
    walls = mesh.triangles[np.ptp(v[mesh.triangles][:, :, 2], axis=1) > 0]
    caps = mesh.triangles[np.ptp(v[mesh.triangles][:, :, 2], axis=1) == 0]
    assert set(np.unique(walls)) == set(np.unique(caps))  # one set of points: watertight by construction


@pytest.mark.parametrize("window", [(0.5, 1.2, 5.0, 9.0), (-0.3, 0.4, 5.0, 9.0)], ids=["window", "window across 0"])
@pytest.mark.parametrize("encoding", ["SAT 700", "SAB 21800"])
def test_a_wall_going_round_with_a_hole_is_cut_along_a_seam_and_stays_on_its_cylinder(window, encoding):
    """Two wrapping loops and a hole (the patch filling it another face of the same cylinder): no triangle cuts
    through the tower (each is within the chord tolerance of the cylinder), and the volume is the tower's."""
    r = 5.0
    mesh = acis_mesh(ENCODINGS[encoding]([tower_with_window_body((3.0, 4.0), r, Z0, Z1, window)]), FLATTEN_REL)
    assert mesh.faces == {"plane": 2, "cylindrical": 2}
    extent = float(np.linalg.norm([2 * r, 2 * r, Z1 - Z0]))
    check_solid(mesh.vertices, mesh.triangles, math.pi * r * r * (Z1 - Z0), 2 * math.pi * r * 4, extent)
    tri = mesh.vertices[mesh.triangles]
    side = np.ptp(tri[:, :, 2], axis=1) > 0
    centroid = tri[side].mean(axis=1)
    depth = r - np.hypot(centroid[:, 0] - 3.0, centroid[:, 1] - 4.0)
    assert depth.max() <= 4 * FLATTEN_REL * extent  # INSIDE_SPAN_STEPS ** 2 x the arcs' tolerance
    assert np.abs(np.hypot(mesh.vertices[:, 0] - 3.0, mesh.vertices[:, 1] - 4.0)[
        (mesh.vertices[:, 2] > Z0) & (mesh.vertices[:, 2] < Z1)] - r).max() < DIGITS[encoding] * 10


@pytest.mark.parametrize("encoding", ["SAT 700", "SAB 21800"])
@pytest.mark.parametrize("kind", ["cylinder with a seam", "cone closing in its apex", "cone with a seam to its apex"])
def test_periodic_faces_as_autocad_makes_them(kind, encoding):
    """AutoCAD's CYLINDER and CONE: a wall of one loop running up a seam edge and back down (to an apex vertex for the
    cone), or a cone face bounded by its base circle alone (its apex where the surface closes, from its half angle)."""
    r, centre = 5.0, (3.0, 4.0)
    if kind.startswith("cylinder"):
        body, exact, cone = seam_cylinder_body(centre, r, Z0, Z1), math.pi * r * r * (Z1 - Z0), False
    else:
        body, exact, cone = cone_body(centre, r, Z0, Z1, seam="seam" in kind), math.pi * r * r * (Z1 - Z0) / 3, True
    mesh = acis_mesh(ENCODINGS[encoding]([body]), FLATTEN_REL)
    assert mesh.faces == ({"plane": 1, "conical": 1} if cone else {"plane": 2, "cylindrical": 1})
    extent = float(np.linalg.norm([2 * r, 2 * r, Z1 - Z0]))
    check_solid(mesh.vertices, mesh.triangles, exact, 2 * math.pi * r * (1 if cone else 2), extent)
    v = mesh.vertices
    radius = np.hypot(v[:, 0] - centre[0], v[:, 1] - centre[1])
    expected = r * (Z1 - v[:, 2]) / (Z1 - Z0) if cone else np.full(len(v), r)
    side = (v[:, 2] > Z0) | ~cone
    if cone:  # one apex, on the axis at the top (from the half angle: to the writer's digits)
        top = np.flatnonzero(v[:, 2] > Z0 + 1e-9)
        assert len(top) == 1 and np.allclose(v[top[0]], [*centre, Z1], atol=DIGITS[encoding] * 10)
    assert np.abs(radius - expected)[side & (v[:, 2] < Z1 - 1e-6)].max() < 1e-9


#: A round tower (radius 4 about (2, 3), 9 m high) as AutoCAD 2013 and later write a CYLINDER in SAT text (ASM 227):
#: the asm header, history attributes on every face, edges with their parameter ranges and convexity, the wall one
#: loop with a seam, the base circle's major axis pointing to -x, and ASM's end marker.
AUTOCAD_CYLINDER = """20800 33 2 0
16 Autodesk AutoCAD 20 ASM 227.0.0.65535 NT 0
1 9.999999999999999547e-07 1.000000000000000036e-10
asmheader $-1 -1 @13 227.0.0.65535 #
body $-1 -1 $-1 $2 $-1 $3 #
lump $-1 -1 $-1 $-1 $4 $1 #
transform $-1 -1 1 0 0 0 1 0 0 0 1 2 3 0 1 no_rotate no_reflect no_shear #
shell $-1 -1 $-1 $-1 $-1 $5 $-1 $2 #
face $6 -1 $-1 $7 $8 $4 $-1 $9 forward single #
persubent-acadSolidHistory-attrib $-1 -1 $-1 $-1 $5 1 1 1000000000 1001 #
face $10 -1 $-1 $11 $12 $4 $-1 $13 forward single #
loop $-1 -1 $-1 $-1 $14 $5 #
cone-surface $-1 -1 $-1 0 0 0 0 0 1 -4 0 0 1 I I 0 1 4 forward I I I I #
persubent-acadSolidHistory-attrib $-1 -1 $-1 $-1 $7 1 1 1000000000 1002 #
face $15 -1 $-1 $-1 $16 $4 $-1 $17 reversed single #
loop $-1 -1 $-1 $-1 $18 $7 #
plane-surface $-1 -1 $-1 0 0 9 0 0 1 1 0 0 forward_v I I I I #
coedge $-1 -1 $-1 $19 $20 $21 $22 forward $8 $-1 #
persubent-acadSolidHistory-attrib $-1 -1 $-1 $-1 $11 1 1 1000000000 1003 #
loop $-1 -1 $-1 $-1 $21 $11 #
plane-surface $-1 -1 $-1 0 0 0 0 0 1 1 0 0 forward_v I I I I #
coedge $-1 -1 $-1 $18 $18 $23 $24 forward $12 $-1 #
coedge $-1 -1 $-1 $23 $14 $20 $25 forward $8 $-1 #
coedge $-1 -1 $-1 $14 $23 $19 $25 reversed $8 $-1 #
coedge $-1 -1 $-1 $21 $21 $14 $22 reversed $16 $-1 #
edge $-1 -1 $-1 $26 -3.141592653589793 $26 3.141592653589793 $14 $27 forward @7 unknown #
coedge $-1 -1 $-1 $20 $19 $18 $24 reversed $8 $-1 #
edge $-1 -1 $-1 $28 -3.141592653589793 $28 3.141592653589793 $23 $29 forward @7 unknown #
edge $-1 -1 $-1 $26 0 $28 9 $19 $30 forward @7 tangent #
vertex $-1 -1 $-1 $22 $31 #
ellipse-curve $-1 -1 $-1 0 0 0 0 0 1 -4 0 0 1 I I #
vertex $-1 -1 $-1 $25 $32 #
ellipse-curve $-1 -1 $-1 0 0 9 0 0 1 -4 0 0 1 I I #
straight-curve $-1 -1 $-1 4 0 0 0 0 1 I I #
point $-1 -1 $-1 4 0 0 #
point $-1 -1 $-1 4 0 9 #
End-of-ASM-data
"""


def test_autocad_2013_sat_text_of_a_cylinder_is_read():
    mesh = acis_mesh(AUTOCAD_CYLINDER.splitlines(), FLATTEN_REL)
    assert mesh.faces == {"plane": 2, "cylindrical": 1}
    extent = float(np.linalg.norm([8.0, 8.0, 9.0]))
    check_solid(mesh.vertices, mesh.triangles, math.pi * 16.0 * 9.0, 2 * 2 * math.pi * 4.0, extent, height=9.0)
    v = mesh.vertices
    assert np.abs(np.hypot(v[:, 0] - 2.0, v[:, 1] - 3.0) - 4.0).max() < 1e-12  # the transformation's move applied
    assert set(np.unique(v[:, 2])) == {0.0, 9.0}


def test_an_elliptical_tower_with_a_window_stays_on_its_ellipse():
    """An elliptical cylinder (ratio 0.5): arcs sampled where the ellipse bends most, the points added inside the wall
    on the ellipse, the volume pi a b h."""
    a, ratio = 6.0, 0.5
    body = tower_with_window_body((0.0, 0.0), a, Z0, Z1, (0.3, 1.4, 5.0, 9.0), ratio)
    mesh = acis_mesh(sab_bytes([body]), FLATTEN_REL)
    extent = float(np.linalg.norm([2 * a, 2 * a * ratio, Z1 - Z0]))
    check_solid(mesh.vertices, mesh.triangles, math.pi * a * a * ratio * (Z1 - Z0), 2 * math.pi * a * 4, extent)
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    wall = (mesh.vertices[:, 2] > Z0) & (mesh.vertices[:, 2] < Z1)
    assert wall.sum() > 8 and np.abs((x / a) ** 2 + (y / (a * ratio)) ** 2 - 1.0)[wall].max() < 1e-9
    tri = mesh.vertices[mesh.triangles]
    centroid = tri[np.ptp(tri[:, :, 2], axis=1) > 0].mean(axis=1)
    inside = 1.0 - np.sqrt((centroid[:, 0] / a) ** 2 + (centroid[:, 1] / (a * ratio)) ** 2)  # relative depth
    assert inside.max() * a <= 4 * FLATTEN_REL * extent
    bottom = mesh.vertices[mesh.vertices[:, 2] == Z0]
    t = np.sort(np.arctan2(bottom[:, 1] / ratio, bottom[:, 0]))
    chord_mid = 0.5 * (np.stack([np.cos(t), ratio * np.sin(t)], 1) + np.stack([np.cos(np.roll(t, -1)), ratio * np.sin(
        np.roll(t, -1))], 1)) * a
    assert (1.0 - np.sqrt((chord_mid[:, 0] / a) ** 2 + (chord_mid[:, 1] / (a * ratio)) ** 2)).max() * a <= (
        FLATTEN_REL * extent)


@pytest.mark.parametrize("encoding", ["SAT 700", "SAB 21800"])
@pytest.mark.parametrize("drum, seam", [(0.0, False), (0.0, True), (6.0, False), (6.0, True)],
                         ids=["dome on the ground", "dome with a seam to its pole", "dome on a drum",
                              "dome on a drum, seam"])
def test_domes_are_closed_outward_and_on_their_sphere(drum, seam, encoding):
    """A hemispherical dome (bounded by its springing circle alone, or also by a meridian seam up to a pole vertex as
    AutoCAD writes one): every point added inside on the sphere, no triangle sinking in deeper than the chords'
    tolerance allows, the volume 2/3 pi r^3 (+ the drum's)."""
    r, centre = 4.0, (3.0, -2.0)
    mesh = acis_mesh(ENCODINGS[encoding]([dome_body(centre, r, Z0, drum, seam)]), FLATTEN_REL)
    assert mesh.faces == ({"plane": 1, "spherical": 1, "cylindrical": 1} if drum else {"plane": 1, "spherical": 1})
    # the extent the tolerance is relative to: its edges' box (the pole's height counts only where a vertex is there)
    extent = float(np.linalg.norm([2 * r, 2 * r, drum + (r if seam else 0.0)]))
    spring = Z0 + drum
    exact = 2.0 / 3.0 * math.pi * r ** 3 + math.pi * r * r * drum
    area = 2 * math.pi * r * r + 2 * math.pi * r * drum + math.pi * r * r
    # what the chords lose: the surface's area x how deep a triangle may sink (INSIDE_SPAN_STEPS ** 2 x the tolerance)
    check_solid(mesh.vertices, mesh.triangles, exact, 4 * area / (r + drum), extent, height=r + drum)
    v = mesh.vertices
    d = v - [*centre, spring]
    on_dome = v[:, 2] > spring + 1e-9
    assert on_dome.sum() > 50 and np.abs(np.linalg.norm(d[on_dome], axis=1) - r).max() < DIGITS[encoding] * 10
    top = v[np.argmax(v[:, 2])]
    assert top[2] > spring + r - FLATTEN_REL * extent  # it reaches up to its pole
    tri = v[mesh.triangles]
    above = tri[:, :, 2].min(axis=1) >= spring - 1e-9
    above &= np.ptp(tri[:, :, 2], axis=1) > 0
    depth = r - np.linalg.norm(tri[above].mean(axis=1) - [*centre, spring], axis=1)
    # chords of INSIDE_SPAN_STEPS (2) arcs' steps sag 4 x the tolerance; a triangle of three such edges sinks at most
    # its circumradius (L / sqrt 3) squared over 2r below the sphere: 4/3 of that
    assert depth.max() <= 16 / 3 * FLATTEN_REL * extent
    assert 500 < len(v) < 20_000


@pytest.mark.parametrize("encoding", ["SAT 700", "SAB 21800"])
def test_the_bodys_transformation_is_applied_and_a_mirror_keeps_it_outward(encoding):
    profile = PROFILES["convex facade"]
    exact = profile_area(profile) * (Z1 - Z0)
    # a quarter turn: its coefficients survive the writer's 6 digits (ezdxf writes a transform's numbers so)
    turn = Matrix44.chain(Matrix44.z_rotate(math.radians(90.0)), Matrix44.translate(2_600_000.0, 1_200_000.0, 400.0))
    mesh = acis_mesh(ENCODINGS[encoding]([extrusion_body(profile, Z0, Z1, turn)]), FLATTEN_REL)
    plain = acis_mesh(ENCODINGS[encoding]([extrusion_body(profile, Z0, Z1)]), FLATTEN_REL)
    expected = np.array(list(turn.transform_vertices(plain.vertices.tolist())))
    assert np.abs(mesh.vertices - expected).max() < DIGITS[encoding] * 30.0  # the solid's size
    assert signed_volume(mesh.vertices - mesh.vertices.mean(axis=0), mesh.triangles) == pytest.approx(
        signed_volume(plain.vertices, plain.triangles), rel=1e-6)
    mirrored = acis_mesh(ENCODINGS[encoding]([extrusion_body(profile, Z0, Z1, Matrix44.scale(-1, 1, 1))]), FLATTEN_REL)
    assert np.allclose(mirrored.vertices[:, 0], -plain.vertices[:, 0])
    assert closed(mirrored.triangles) and signed_volume(mirrored.vertices, mirrored.triangles) == pytest.approx(
        signed_volume(plain.vertices, plain.triangles), rel=1e-12)
    assert abs(signed_volume(plain.vertices, plain.triangles) - exact) < 0.01 * exact


def test_several_bodies_of_one_entity_are_one_mesh_of_their_pieces():
    a = extrusion_body([SQUARE], 0.0, 3.0)
    b = extrusion_body(PROFILES["round tower"], 0.0, 9.0, Matrix44.translate(30.0, 0.0, 0.0))
    mesh = acis_mesh(sat_lines([a, b], 700), FLATTEN_REL)
    assert closed(mesh.triangles)
    assert signed_volume(mesh.vertices, mesh.triangles) == pytest.approx(60.0 * 3.0 + math.pi * 25.0 * 9.0, rel=1e-3)


def test_tori_whole_balls_and_damaged_data_raise_saying_what():
    with pytest.raises(AcisError, match=r"^has faces of curved kinds not tessellated here \(1 torus-surface"):
        acis_mesh(sat_lines([ring_fillet_body((0.0, 0.0), 5.0, Z0, Z1)], 700), FLATTEN_REL)
    with pytest.raises(AcisError, match=r"^has faces of curved kinds not tessellated here \(1 torus-surface"):
        acis_mesh(sat_lines([torus_body((0.0, 0.0, 0.0), 5.0, 1.0)], 700), FLATTEN_REL)
    with pytest.raises(AcisError, match=r"^has no edges: a closed surface without a boundary \(a whole sphere"):
        acis_mesh(sat_lines([sphere_body((0.0, 0.0, 0.0), 5.0)], 700), FLATTEN_REL)
    lines = sat_lines([extrusion_body(PROFILES["convex facade"], Z0, Z1)], 700)
    with pytest.raises(AcisError, match=r"^has ACIS data that cannot be read \("):
        acis_mesh(lines[: len(lines) // 2], FLATTEN_REL)
    with pytest.raises(AcisError, match=r"^holds no ACIS body$"):
        acis_mesh(lines[:3], FLATTEN_REL)
    with pytest.raises(AcisError, match=r"^has ACIS data that cannot be read \(ParsingError: not a SAB file"):
        acis_mesh(b"not ACIS at all" * 4, FLATTEN_REL)
    spline = [line.replace("ellipse-curve", "intcurve-curve") for line in lines]
    with pytest.raises(AcisError, match=r"^has edges of kinds not tessellated here \(intcurve-curve"):
        acis_mesh(spline, FLATTEN_REL)


def test_autocad_style_records_of_a_later_acis_version_are_read():
    """AutoCAD 2010's SAT layout: the cone's base ellipse range, sine, cosine, scale and sense after its ratio, and
    tolerant edges and vertices (``tedge``, ``tvertex``, read as plain ones)."""
    lines = sat_lines([extrusion_body(PROFILES["convex facade"], Z0, Z1)], 20800)
    assert any(line.startswith("cone-surface") and " I I 0 1 4 forward I I I I #" in line for line in lines)
    tolerant = [line.replace("edge $", "tedge-edge $", 1) if line.startswith("edge ") else line for line in lines]
    tolerant = [line.replace("vertex $", "tvertex-vertex $", 1) if line.startswith("vertex ") else line for line in tolerant]
    plain = acis_mesh(lines, FLATTEN_REL)
    mesh = acis_mesh(tolerant, FLATTEN_REL)
    assert np.array_equal(mesh.vertices, plain.vertices) and np.array_equal(mesh.triangles, plain.triangles)


# --------------------------------------------------------------------------------------------
# Through the DXF reader and preprocessing
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("version", ["R2010", "R2018"])
def test_solids_in_model_space_and_in_blocks_are_buildings(tmp_path, version):
    from meshsom.preprocess import preprocess, validate

    doc = ezdxf.new(version)
    doc.units = ezdxf.units.M
    msp = doc.modelspace()
    tower = add_solid(msp, [extrusion_body(PROFILES["round tower"], 0.0, 20.0,
                                           Matrix44.translate(2_683_000.0, 1_248_000.0, 410.0))])
    fillet = add_solid(msp, [ring_fillet_body((0.0, 0.0), 5.0, 0.0, 9.0)])
    chapel = add_solid(msp, [dome_body((0.0, 0.0), 4.0, 0.0, drum=6.0, seam=True,
                                       transform=Matrix44.translate(2_683_300.0, 1_248_000.0, 410.0))])
    house = doc.blocks.new("HOUSE")
    add_solid(house, [extrusion_body(PROFILES["convex facade"], 0.0, 9.0)])
    add_solid(house, [ring_fillet_body((5.0, 4.0), 3.0, 12.0, 15.0)])
    turned = msp.add_blockref("HOUSE", (2_683_100.0, 1_248_050.0, 410.0), dxfattribs={"rotation": 30})
    mirrored = msp.add_blockref("HOUSE", (2_683_200.0, 1_248_050.0, 410.0), dxfattribs={"xscale": -1})
    fillets = doc.blocks.new("FILLETS")
    add_solid(fillets, [ring_fillet_body((0.0, 0.0), 2.0, 0.0, 3.0)])
    only_fillet = msp.add_blockref("FILLETS", (0.0, 0.0, 0.0))
    path = tmp_path / f"solids_{version}.dxf"
    doc.saveas(path)
    items = list(read_dxf(path, ReaderOptions()))
    name = path.name
    assert [i.id for i in items] == [f"{name}#{tower.dxf.handle}", f"{name}#{fillet.dxf.handle}",
                                     f"{name}#{chapel.dxf.handle}", f"{name}#HOUSE@{turned.dxf.handle}",
                                     f"{name}#HOUSE@{mirrored.dxf.handle}", f"{name}#FILLETS@{only_fillet.dxf.handle}"]
    assert [type(i) for i in items] == [RawMesh, Rejection, RawMesh, RawMesh, RawMesh, Rejection]
    assert items[1].reason.startswith("an ACIS solid (3DSOLID) that has faces of curved kinds not tessellated here "
                                      "(1 torus-surface") and "MESHSMOOTH" in items[1].reason
    assert items[5].reason.startswith("its block 'FILLETS' holds no faces that can be read: 1 ACIS solid that has faces")
    assert np.allclose(items[0].origin[:2], [2_683_003.0, 1_248_004.0])
    assert any("curved faces of ACIS solids (1 cylindrical) tessellated" in n for n in items[0].notes)
    assert any("curved faces of ACIS solids (1 cylindrical, 1 spherical) tessellated" in n for n in items[2].notes)
    assert any(n.startswith("ACIS entities in its block not read: 1 ACIS solid that has faces of curved kinds")
               for n in items[3].notes)
    house_volume = profile_area(PROFILES["convex facade"]) * 9.0
    chapel_volume = math.pi * 16.0 * 6.0 + 2.0 / 3.0 * math.pi * 64.0
    for item, exact in ((items[0], math.pi * 25.0 * 20.0), (items[2], chapel_volume), (items[3], house_volume),
                        (items[4], house_volume)):
        assert closed(item.faces)
        assert signed_volume(item.vertices, item.faces) == pytest.approx(exact, rel=2e-3)
        r = preprocess(item.vertices, item.faces, source=item.id)
        assert validate(r.vertices, r.faces) is None
        assert signed_volume(r.vertices, r.faces) == pytest.approx(exact, rel=2e-3)
    # the mirrored house is the turned one's mirror image: the same plan area, x reversed about the insert
    assert np.ptp(items[4].vertices, axis=0) == pytest.approx(np.array([14.0, 8.0, 9.0]), abs=1e-6)


def test_a_solid_in_a_drawing_older_than_r2000_cannot_be_there(tmp_path):
    """DXF R12 has no 3DSOLID: ezdxf refuses to add one, so the reader never meets one (a guard, not a path)."""
    doc = ezdxf.new("R12")
    with pytest.raises(ezdxf.DXFVersionError):
        doc.modelspace().add_3dsolid()


def test_a_block_of_solids_is_tessellated_once_for_all_its_references(tmp_path, monkeypatch):
    import meshsom.acis as acis_module

    doc = ezdxf.new("R2018")
    block = doc.blocks.new("TOWER")
    add_solid(block, [extrusion_body(PROFILES["round tower"], 0.0, 20.0)])
    for k in range(12):
        doc.modelspace().add_blockref("TOWER", (30.0 * k, 0.0, 0.0))
    doc.saveas(tmp_path / "towers.dxf")
    calls = []
    real = acis_module.acis_mesh
    monkeypatch.setattr(acis_module, "acis_mesh", lambda *a: calls.append(1) or real(*a))
    items = list(read_dxf(Path(tmp_path / "towers.dxf"), ReaderOptions()))
    assert len(items) == 12 and all(isinstance(i, RawMesh) for i in items) and len(calls) == 1
    origins = np.array([i.origin for i in items])
    assert np.allclose(origins - origins[0], [[30.0 * k, 0.0, 0.0] for k in range(12)], rtol=0.0, atol=1e-9)
    assert all(np.allclose(i.vertices, items[0].vertices, rtol=0.0, atol=1e-9) for i in items)
