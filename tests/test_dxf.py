"""DXF reader (meshsom.dxf): drawings built with ezdxf, read back, checked against numbers computed here."""

from __future__ import annotations

import dataclasses
import math

import ezdxf
import numpy as np
import pytest
from ezdxf import units

from meshsom.dxf import read_dxf
from meshsom.errors import InputFileError
from meshsom.io import RawMesh, ReaderOptions, Rejection

SIZE = np.array([10.0, 6.0, 4.0])
#: The box's corners: corner i has x, y, z from bits 0, 1, 2 of i.
UNIT_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], float)
#: Its faces, counter-clockwise seen from outside.
QUADS = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])
TRIANGLES = QUADS[:, [[0, 1, 2], [0, 2, 3]]].reshape(-1, 3)
VOLUME = float(np.prod(SIZE))


def box_corners(size=SIZE, at=(0.0, 0.0, 0.0)) -> np.ndarray:
    return UNIT_CORNERS * np.asarray(size, float) + np.asarray(at, float)


def signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    """Divergence theorem: the sum over triangles of a . (b x c) / 6."""
    a, b, c = (v[f[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def closed(f: np.ndarray) -> bool:
    """Every edge used by exactly two triangles, once each way."""
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    undirected, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    return bool((counts == 2).all()) and len(np.unique(directed, axis=0)) == len(directed)


def add_box_faces(layout, corners, layer="0", triangles=False):
    for face in (TRIANGLES if triangles else QUADS):
        layout.add_3dface([tuple(p) for p in corners[face]], dxfattribs={"layer": layer})


def read(path, **options) -> list:
    return list(read_dxf(path, dataclasses.replace(ReaderOptions(), **options)))


def meshes(items) -> list[RawMesh]:
    return [m for m in items if isinstance(m, RawMesh)]


def new_doc(unit=units.M):
    doc = ezdxf.new("R2010")
    doc.units = unit
    return doc, doc.modelspace()


@pytest.mark.parametrize("triangles", [False, True], ids=["6 quads", "12 triangles"])
def test_box_of_3dfaces_is_one_closed_mesh(tmp_path, triangles):
    doc, msp = new_doc()
    add_box_faces(msp, box_corners(at=(100.0, 200.0, 5.0)), layer="Gebaeude", triangles=triangles)
    doc.saveas(tmp_path / "box.dxf")
    (m,) = read(tmp_path / "box.dxf")
    assert m.id == "box.dxf#Gebaeude/c1" and m.label is None
    assert m.vertices.shape == (8, 3) and m.faces.shape == (12, 3) and m.faces.dtype == np.int64
    assert len(np.unique(m.vertices, axis=0)) == 8
    assert np.allclose(np.ptp(m.vertices, axis=0), SIZE)
    assert np.allclose(m.vertices.min(axis=0) + m.origin, [100.0, 200.0, 5.0])
    assert signed_volume(m.vertices, m.faces) == pytest.approx(VOLUME, rel=1e-12)
    assert closed(m.faces)
    assert "drawing units: metres" in m.notes


def test_separate_boxes_of_one_layer_are_pieces_and_layers_name_them(tmp_path):
    doc, msp = new_doc()
    add_box_faces(msp, box_corners(), layer="A")
    add_box_faces(msp, box_corners(size=(2.0, 3.0, 5.0), at=(50.0, 0.0, 0.0)), layer="A")
    add_box_faces(msp, box_corners(size=(1.0, 1.0, 1.0), at=(0.0, 80.0, 0.0)), layer="B", triangles=True)
    doc.saveas(tmp_path / "city.dxf")
    items = read(tmp_path / "city.dxf")
    assert [m.id for m in items] == ["city.dxf#A/c1", "city.dxf#A/c2", "city.dxf#B/c1"]
    assert [signed_volume(m.vertices, m.faces) for m in items] == pytest.approx([VOLUME, 30.0, 1.0], rel=1e-12)
    assert [len(m.vertices) for m in items] == [8, 8, 8]
    assert np.allclose(items[1].origin, [51.0, 1.5, 2.5])


def test_polyface_mesh_and_polygon_mesh_hold_the_same_box(tmp_path):
    doc, msp = new_doc()
    corners = box_corners()
    polyface = msp.add_polyface()
    for q in QUADS:
        polyface.append_face([tuple(p) for p in corners[q]])
    polyface.optimize()  # shared vertices, as CAD programs write them
    mesh = msp.add_mesh()
    with mesh.edit_data() as data:
        data.vertices = [tuple(p) for p in corners]
        data.faces = [tuple(int(i) for i in q) for q in QUADS]
    # an M x N polygon mesh closed in N: the floor's centre (4 times), the floor's corners, the roof's,
    # the roof's centre; its 4 x 4 quads (the first and last row's collapse to triangles) are the box
    ring = corners[[0, 1, 3, 2]]  # counter-clockwise seen from above
    centre = np.repeat(ring[:, :2].mean(axis=0, keepdims=True), 4, 0)
    rows = [centre, ring[:, :2], ring[:, :2], centre]
    grid = np.stack([np.column_stack([r, np.full(4, z)]) for r, z in zip(rows, (0.0, 0.0, 4.0, 4.0))])
    polymesh = msp.add_polymesh(size=(4, 4))
    for i in range(4):
        for j in range(4):
            polymesh.set_mesh_vertex((i, j), tuple(grid[i, j]))
    polymesh.close(m_close=False, n_close=True)
    doc.saveas(tmp_path / "meshes.dxf")
    items = read(tmp_path / "meshes.dxf")
    handles = [e.dxf.handle for e in (polyface, mesh, polymesh)]
    assert [m.id for m in items] == [f"meshes.dxf#{h}" for h in handles]
    for m in items:
        assert np.allclose(np.ptp(m.vertices, axis=0), SIZE)
        assert closed(m.faces)
    volumes = [signed_volume(m.vertices, m.faces) for m in items]
    # the polygon mesh turns clockwise from its floor's centre outwards: inside out, as drawn
    assert np.abs(volumes) == pytest.approx([VOLUME] * 3, rel=1e-12)
    assert [len(m.faces) for m in items] == [12, 12, 4 + 8 + 4]
    assert len(items[2].vertices) == 10


def rotation_z(degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def assert_same_points(got: np.ndarray, expected: np.ndarray, tol: float):
    assert len(got) == len(expected)
    d = np.linalg.norm(got[:, None, :] - expected[None, :, :], axis=2)
    assert d.min(axis=1).max() < tol and d.min(axis=0).max() < tol


def test_block_reference_at_swiss_coordinates_rotated_and_scaled(tmp_path):
    doc, msp = new_doc()
    base = np.array([5.0, 3.0, 0.0])
    block = doc.blocks.new("HAUS", base_point=tuple(base))
    add_box_faces(block, box_corners())
    at = np.array([2_683_000.0, 1_248_000.0, 400.0])
    insert = msp.add_blockref("HAUS", tuple(at), dxfattribs={"rotation": 30, "xscale": 2, "yscale": 2, "zscale": 2})
    insert.add_attrib("FAMILY", "Wohnhaus", (0, 0))
    doc.saveas(tmp_path / "lv95.dxf")
    (m,) = read(tmp_path / "lv95.dxf")
    assert m.id == f"lv95.dxf#HAUS@{insert.dxf.handle}" and m.label == "Wohnhaus"
    expected = 2.0 * (box_corners() - base) @ rotation_z(30).T + at
    assert_same_points(m.vertices + m.origin, expected, 1e-6)
    assert np.abs(m.vertices).max() < 20  # re-centred: local coordinates are small
    assert signed_volume(m.vertices, m.faces) == pytest.approx(VOLUME * 8, rel=1e-9)
    assert read(tmp_path / "lv95.dxf", label_attribute="FaMiLy")[0].label == "Wohnhaus"  # tags without case
    assert read(tmp_path / "lv95.dxf", label_attribute="usage")[0].label is None


def test_nested_mirrored_and_array_references(tmp_path):
    doc, msp = new_doc()
    box = doc.blocks.new("BOX")
    add_box_faces(box, box_corners())
    row = doc.blocks.new("ROW")
    row.add_blockref("BOX", (0.0, 0.0, 0.0))
    row.add_blockref("BOX", (20.0, 0.0, 0.0), dxfattribs={"rotation": 90})
    nested = msp.add_blockref("ROW", (1000.0, 2000.0, 0.0), dxfattribs={"rotation": 90})
    mirrored = msp.add_blockref("BOX", (0.0, 0.0, 0.0), dxfattribs={"xscale": -1})
    grid = msp.add_blockref("BOX", (0.0, 500.0, 0.0))
    grid.grid(size=(2, 3), spacing=(100.0, 40.0))  # 2 rows 100 apart, 3 columns 40 apart
    doc.saveas(tmp_path / "refs.dxf")
    items = read(tmp_path / "refs.dxf")
    ids = [m.id for m in items]
    assert ids[:2] == [f"refs.dxf#ROW@{nested.dxf.handle}", f"refs.dxf#BOX@{mirrored.dxf.handle}"]
    assert ids[2:] == [f"refs.dxf#BOX@{grid.dxf.handle}/r{r}c{c}" for r in (1, 2) for c in (1, 2, 3)]
    # ROW: a box at the origin and one turned 90 degrees at x = 20, then all turned 90 degrees
    inner = np.concatenate([box_corners(), box_corners() @ rotation_z(90).T + [20.0, 0.0, 0.0]])
    assert_same_points(items[0].vertices + items[0].origin, inner @ rotation_z(90).T + [1000.0, 2000.0, 0.0], 1e-9)
    assert signed_volume(items[0].vertices, items[0].faces) == pytest.approx(2 * VOLUME, rel=1e-12)
    # mirrored in x, its faces reversed: still outward
    assert_same_points(items[1].vertices + items[1].origin, box_corners() * [-1.0, 1.0, 1.0], 1e-12)
    assert signed_volume(items[1].vertices, items[1].faces) == pytest.approx(VOLUME, rel=1e-12)
    lows = np.array([(m.vertices + m.origin).min(axis=0) for m in items[2:]])
    assert np.allclose(lows, [[40.0 * c, 500.0 + 100.0 * r, 0.0] for r in range(2) for c in range(3)])


def test_drawing_units_scale_to_metres(tmp_path):
    doc, msp = new_doc(units.MM)
    add_box_faces(msp, box_corners(size=SIZE * 1000))
    doc.saveas(tmp_path / "mm.dxf")
    (m,) = read(tmp_path / "mm.dxf")
    assert np.allclose(np.ptp(m.vertices, axis=0), SIZE, rtol=1e-12)
    assert signed_volume(m.vertices, m.faces) == pytest.approx(VOLUME, rel=1e-12)
    assert "drawing units: millimetres, scaled to metres" in m.notes
    doc.units = units.FT
    doc.saveas(tmp_path / "ft.dxf")
    (m,) = read(tmp_path / "ft.dxf")
    assert np.allclose(np.ptp(m.vertices, axis=0), SIZE * 1000 * 0.3048, rtol=1e-12)
    doc.units = 0
    doc.saveas(tmp_path / "none.dxf")
    (m,) = read(tmp_path / "none.dxf")
    assert np.allclose(np.ptp(m.vertices, axis=0), SIZE * 1000)
    assert any("not declared" in n and "read as metres" in n for n in m.notes)


def test_labels_from_the_layer(tmp_path):
    doc, msp = new_doc()
    add_box_faces(msp, box_corners(), layer="Dach")
    doc.blocks.new("B").add_3dface([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    msp.add_blockref("B", (50.0, 0.0, 0.0), dxfattribs={"layer": "Nebengebaeude"})
    doc.saveas(tmp_path / "layers.dxf")
    by_layer = read(tmp_path / "layers.dxf", label_attribute="layer")
    assert sorted(m.label for m in by_layer) == ["Dach", "Nebengebaeude"]
    assert [m.label for m in read(tmp_path / "layers.dxf")] == [None, None]


def test_an_empty_solid_and_a_region_are_rejected_saying_why_and_the_rest_read(tmp_path):
    doc, msp = new_doc()
    solid = msp.add_3dsolid()
    solid.sat = ["700 0 1 0", "@33 Open Design Alliance ACIS Builder @12 ACIS 219.0 @24 Thu Jan  1 00:00:00 2025",
                 "1000 9.9999999999999995e-07 1e-10", "End-of-ACIS-data"]  # ezdxf writes no ACIS entity without data
    region = msp.add_region()
    region.sat = list(solid.sat)
    add_box_faces(msp, box_corners())
    msp.add_line((0, 0), (1, 1))
    doc.saveas(tmp_path / "solid.dxf")
    items = read(tmp_path / "solid.dxf")
    empty, sheet = [r for r in items if isinstance(r, Rejection)]
    assert empty.id == f"solid.dxf#{solid.dxf.handle}"
    assert empty.reason == "an ACIS solid (3DSOLID) that holds no ACIS body"
    assert sheet.id == f"solid.dxf#{region.dxf.handle}" and "ACIS region (REGION)" in sheet.reason
    assert "not a solid" in sheet.reason and "THICKEN" in sheet.reason
    (m,) = meshes(items)
    assert "2D drawing entities (not buildings) not read: LINE x 1" in m.notes


def test_a_drawing_of_2d_entities_only_is_refused_saying_what_it_holds(tmp_path):
    doc, msp = new_doc()
    for i in range(40):
        msp.add_line((i, 0), (i, 1))
    for i in range(3):
        msp.add_text(f"Parzelle {i}")
    tree = doc.blocks.new("BAUM")
    tree.add_circle((0, 0), 2.0)
    msp.add_blockref("BAUM", (5, 5))
    doc.saveas(tmp_path / "plan.dxf")
    with pytest.raises(InputFileError, match=r"holds no 3D faces .*: only 2D drawing entities "
                                             r"\(LINE x 40, TEXT x 3, INSERT \(of a 2D block\) x 1\)"):
        list(read_dxf(tmp_path / "plan.dxf", ReaderOptions()))


def test_a_file_that_is_not_dxf_or_too_large_is_refused(tmp_path):
    garbage = tmp_path / "garbage.dxf"
    garbage.write_bytes(bytes(np.random.default_rng(7).integers(0, 256, 4000, dtype=np.uint8)))
    with pytest.raises(InputFileError, match="cannot be read as DXF"):
        list(read_dxf(garbage, ReaderOptions()))
    doc, msp = new_doc()
    add_box_faces(msp, box_corners())
    doc.saveas(tmp_path / "box.dxf")
    with pytest.raises(InputFileError, match=r"larger than 100 bytes \(ReaderOptions.max_bytes\)"):
        list(read_dxf(tmp_path / "box.dxf", dataclasses.replace(ReaderOptions(), max_bytes=100)))


def test_zero_area_faces_dropped_and_noted(tmp_path):
    doc, msp = new_doc()
    add_box_faces(msp, box_corners())
    msp.add_3dface([(0, 0, 0), (5, 0, 0), (10, 0, 0)])  # corners on a line
    msp.add_3dface([(0, 0, 9), (0, 0, 9), (0, 0, 9)], dxfattribs={"layer": "Punkte"})  # a point
    polyface = msp.add_polyface()
    for q in QUADS:
        polyface.append_face([tuple(p) for p in box_corners(at=(30.0, 0.0, 0.0))[q]])
    polyface.append_face([(30.0, 0.0, 0.0), (31.0, 0.0, 0.0), (32.0, 0.0, 0.0)])
    doc.saveas(tmp_path / "slivers.dxf")
    items = read(tmp_path / "slivers.dxf")
    assert [type(m).__name__ for m in items] == ["RawMesh", "Rejection", "RawMesh"]
    pf, points, faces = items
    assert pf.id == f"slivers.dxf#{polyface.dxf.handle}" and len(pf.faces) == 12
    assert "1 of its 7 faces have zero area, dropped" in pf.notes
    assert points.id == "slivers.dxf#Punkte" and "zero area" in points.reason
    assert faces.id == "slivers.dxf#0/c1" and len(faces.faces) == 12
    assert "1 3DFACE entities of zero area on layer '0' dropped" in faces.notes


def test_too_many_vertices_and_a_broken_polyface_are_rejected_alone(tmp_path):
    doc, msp = new_doc()
    add_box_faces(msp, box_corners(), layer="A")
    polyface = msp.add_polyface()
    polyface.append_face([(0, 0, 10), (1, 0, 10), (0, 1, 10)])
    next(f for f in polyface.vertices if not f.is_poly_face_mesh_vertex).dxf.vtx2 = 99  # no vertex 99
    doc.saveas(tmp_path / "broken.dxf")
    items = read(tmp_path / "broken.dxf")
    assert isinstance(items[0], Rejection) and items[0].id == f"broken.dxf#{polyface.dxf.handle}"
    assert "cannot be read" in items[0].reason and "99" in items[0].reason
    assert isinstance(items[1], RawMesh)
    rejected = read(tmp_path / "broken.dxf", max_vertices=7)[1]
    assert isinstance(rejected, Rejection) and rejected.id == "broken.dxf#A/c1"
    assert "has 8 vertices, more than 7" in rejected.reason


def test_degrees_without_a_crs_are_rejected(tmp_path):
    doc, msp = new_doc(0)
    add_box_faces(msp, box_corners(size=(1e-4, 1e-4, 12.0), at=(8.54, 47.37, 400.0)))
    doc.saveas(tmp_path / "wgs84.dxf")
    (r,) = read(tmp_path / "wgs84.dxf")
    assert isinstance(r, Rejection) and "degrees" in r.reason


def test_a_box_of_3dfaces_preprocesses_to_a_closed_mesh(tmp_path):
    from meshsom.preprocess import preprocess, validate

    doc, msp = new_doc(units.CM)
    corners = box_corners(size=SIZE * 100, at=(268_300_000.0, 124_800_000.0, 40_000.0))
    add_box_faces(msp, corners, triangles=True)
    doc.saveas(tmp_path / "cm.dxf")
    (m,) = read(tmp_path / "cm.dxf")
    r = preprocess(m.vertices, m.faces, source=m.id)
    assert validate(r.vertices, r.faces) is None
    assert signed_volume(r.vertices, r.faces) == pytest.approx(VOLUME, rel=1e-9)
    assert np.allclose(m.origin, [2_683_005.0, 1_248_003.0, 402.0])


def test_mesh_entity_of_pentagons_is_triangulated(tmp_path):
    doc, msp = new_doc()
    angles = np.radians(72.0 * np.arange(5) + 10.0)
    ring = np.column_stack([5.0 * np.cos(angles), 5.0 * np.sin(angles)]) + [2_600_000.0, 1_200_000.0]
    corners = np.concatenate([np.column_stack([ring, np.zeros(5)]), np.column_stack([ring, np.full(5, 3.0)])])
    faces = [(4, 3, 2, 1, 0), (5, 6, 7, 8, 9)] + [(k, (k + 1) % 5, 5 + (k + 1) % 5, 5 + k) for k in range(5)]
    mesh = msp.add_mesh()
    with mesh.edit_data() as data:
        data.vertices = [tuple(p) for p in corners]
        data.faces = faces
    doc.saveas(tmp_path / "prism.dxf")
    (m,) = read(tmp_path / "prism.dxf")
    area = 2.5 * 25.0 * math.sin(math.radians(72.0))  # a regular pentagon of circumradius 5
    assert len(m.faces) == 3 + 3 + 10 and len(m.vertices) == 10 and closed(m.faces)
    assert signed_volume(m.vertices, m.faces) == pytest.approx(3.0 * area, rel=1e-9)


def test_blocks_of_solids_and_external_references(tmp_path):
    doc, msp = new_doc()
    solids = doc.blocks.new("SOLIDS")
    solids.add_3dsolid().sat = ["700 0 1 0", "End-of-ACIS-data"]
    mixed = doc.blocks.new("MIXED")
    add_box_faces(mixed, box_corners())
    mixed.add_3dsolid().sat = ["700 0 1 0", "End-of-ACIS-data"]
    mixed.add_line((0, 0), (10, 0))
    doc.add_xref_def("nachbar.dxf", "NACHBAR")
    refs = [msp.add_blockref(b, (0.0, 0.0, 0.0)) for b in ("SOLIDS", "MIXED", "NACHBAR")]
    doc.saveas(tmp_path / "blocks.dxf")
    items = read(tmp_path / "blocks.dxf")
    assert [m.id for m in items] == [f"blocks.dxf#{b}@{r.dxf.handle}" for b, r in zip(("SOLIDS", "MIXED", "NACHBAR"), refs)]
    assert isinstance(items[0], Rejection)
    assert items[0].reason.startswith("its block 'SOLIDS' holds no faces that can be read: 1 ACIS solid that has ACIS "
                                      "data that cannot be read (")
    assert isinstance(items[1], RawMesh) and signed_volume(items[1].vertices, items[1].faces) == pytest.approx(VOLUME)
    assert any(n.startswith("ACIS entities in its block not read: 1 ACIS solid that has ACIS data that cannot be read")
               for n in items[1].notes)
    assert any("(2D drawing) not read: LINE x 1" in n for n in items[1].notes)
    assert isinstance(items[2], Rejection) and "external drawing" in items[2].reason and "nachbar.dxf" in items[2].reason


def test_concave_quads_split_inside_and_float_noise_welded(tmp_path):
    doc, msp = new_doc()
    # an arrowhead: its corner 2 is reflex, so only the longer diagonal 0-2 splits it inside
    floor = np.array([[-10.0, 0.0], [0.0, -1.0], [-1.0, 0.0], [0.0, 1.0]]) + [2_683_000.0, 1_248_000.0]
    low, high = np.column_stack([floor, np.full(4, 400.0)]), np.column_stack([floor, np.full(4, 403.0)])
    noise = np.array([0.0, 3e-9, 0.0])  # a few units in the last place at LV95: the same corner, written again
    msp.add_3dface([tuple(p) for p in low[::-1]])
    msp.add_3dface([tuple(p) for p in high])
    for k in range(4):
        j = (k + 1) % 4
        msp.add_3dface([tuple(low[k] + noise), tuple(low[j]), tuple(high[j]), tuple(high[k] + noise)])
    doc.saveas(tmp_path / "arrow.dxf")
    (m,) = read(tmp_path / "arrow.dxf")
    assert len(m.vertices) == 8 and closed(m.faces)
    area = 9.0  # shoelace
    perimeter = float(np.linalg.norm(floor - np.roll(floor, -1, axis=0), axis=1).sum())
    a, b, c = (m.vertices[m.faces[:, i]] for i in range(3))
    surface = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()  # a triangle turned over adds, not cancels
    assert surface == pytest.approx(2 * area + 3.0 * perimeter, rel=1e-9)
    assert signed_volume(m.vertices, m.faces) == pytest.approx(3.0 * area, rel=1e-9)


def test_closed_outlines_with_a_thickness_are_prisms(tmp_path):
    """2.5D block models: a closed L-shaped LWPOLYLINE 12 m thick at an elevation of 400 m, a
    CIRCLE (a round tower), an outline with a bulge (a half-round end), one drawn in a mirrored OCS
    (extrusion (0, 0, -1): x mirrored, extruded downwards), a closed old-style 2D POLYLINE, and the
    same in a block, each the closed prism it draws, with the volume computed here; an open
    polyline with a thickness (a wall, a fence) and a closed one without are 2D, noted."""
    doc, msp = new_doc()
    msp.add_lwpolyline([(0, 0), (20, 0), (20, 10), (10, 10), (10, 20), (0, 20)], close=True,
                       dxfattribs={"thickness": 12, "elevation": 400})
    msp.add_circle((100, 0), 5, dxfattribs={"thickness": 20})
    msp.add_lwpolyline([(300, 0, 0), (320, 0, 1), (320, 10, 0), (300, 10, 0)], format="xyb", close=True,
                       dxfattribs={"thickness": 3})
    msp.add_lwpolyline([(200, 0), (210, 0), (210, 10), (200, 10)], close=True,
                       dxfattribs={"thickness": 6, "extrusion": (0, 0, -1)})
    msp.add_polyline2d([(500, 0), (504, 0), (504, 3), (500, 3)], close=True, dxfattribs={"thickness": 5})
    block = doc.blocks.new("tower")
    block.add_circle((0, 0), 2, dxfattribs={"thickness": 30})
    msp.add_blockref("tower", (600, 0, 10))
    msp.add_lwpolyline([(400, 0), (410, 0)], dxfattribs={"thickness": 3})
    msp.add_lwpolyline([(700, 0), (710, 0), (710, 5)], close=True)
    doc.saveas(tmp_path / "blocks.dxf")
    items = read(tmp_path / "blocks.dxf")
    assert all(isinstance(i, RawMesh) for i in items) and len(items) == 6, items
    by_x = {round(float(i.origin[0])): i for i in items}
    expected = {10: (300 * 12, [20, 20, 12], 406), 100: (math.pi * 25 * 20, [10, 10, 20], 10),
                312: (200 * 3 + math.pi * 25 / 2 * 3, [25, 10, 3], 1.5), -205: (600, [10, 10, 6], -3),
                502: (4 * 3 * 5, [4, 3, 5], 2.5), 600: (math.pi * 4 * 30, [4, 4, 30], 25)}
    for x, (volume, size, z) in expected.items():
        mesh = by_x[x]
        assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(volume, rel=2e-3), x  # arcs flattened to 1e-4
        assert np.ptp(mesh.vertices, axis=0) == pytest.approx(size, rel=1e-3), x
        assert mesh.origin[2] == pytest.approx(z, abs=1e-6) and closed(mesh.faces), x
        assert any("with a thickness, read as the prism it draws (2.5D)" in n for n in mesh.notes), x
    assert any("LWPOLYLINE x 2" in n for n in items[0].notes), items[0].notes


def test_rings_not_flagged_closed_and_solids_with_a_thickness_are_prisms(tmp_path):
    """A GIS export writes a ring as a polyline that ends where it starts, without the closed flag; AutoCAD draws a
    SOLID or TRACE (a filled quadrilateral or triangle) with a thickness as a prism. All were counted as 2D drawing
    and not read: an LWPOLYLINE and a 2D POLYLINE ending at their start, a SOLID quad (corners in DXF's 1-2-4-3
    order), a SOLID triangle and a TRACE, each with a thickness, are the prisms they draw (volumes and extents by
    hand); a polyline that does not end at its start stays 2D, and so does a SOLID without a thickness."""
    doc, msp = new_doc()
    msp.add_lwpolyline([(0, 0), (20, 0), (20, 10), (0, 10), (0, 0)], dxfattribs={"thickness": 12, "elevation": 40})
    msp.add_polyline2d([(100, 0), (104, 0), (104, 3), (100, 3), (100, 0)], dxfattribs={"thickness": 5})
    msp.add_solid([(200, 0), (210, 0), (200, 8), (210, 8)], dxfattribs={"thickness": 7})
    msp.add_solid([(300, 0), (306, 0), (300, 4)], dxfattribs={"thickness": 10})
    msp.add_trace([(400, 0), (405, 0), (400, 2), (405, 2)], dxfattribs={"thickness": 3})
    msp.add_lwpolyline([(500, 0), (510, 0), (510, 10), (500, 10)], dxfattribs={"thickness": 3})
    msp.add_solid([(600, 0), (610, 0), (600, 8), (610, 8)])
    doc.saveas(tmp_path / "rings.dxf")
    items = read(tmp_path / "rings.dxf")
    assert all(isinstance(i, RawMesh) for i in items) and len(items) == 5, items
    by_x = {round(float(i.vertices[:, 0].min() + i.origin[0])): i for i in items}
    expected = {0: (200 * 12, [20, 10, 12], 46), 100: (12 * 5, [4, 3, 5], 2.5), 200: (80 * 7, [10, 8, 7], 3.5),
                300: (12 * 10, [6, 4, 10], 5), 400: (10 * 3, [5, 2, 3], 1.5)}
    for x, (volume, size, z) in expected.items():
        mesh = by_x[x]
        assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(volume, rel=1e-9), x
        assert np.ptp(mesh.vertices, axis=0) == pytest.approx(size, rel=1e-9), x
        assert mesh.origin[2] == pytest.approx(z, abs=1e-6) and closed(mesh.faces), x
    assert any("LWPOLYLINE x 1, SOLID x 1" in n for n in items[0].notes), items[0].notes


def test_a_crs_in_feet_is_not_applied_twice(tmp_path):
    """A drawing in feet ($INSUNITS 2) of New York's State Plane (EPSG:2263, US survey feet), read
    with that CRS: the CRS scales the coordinates, the drawing's unit is not applied as well."""
    doc, msp = new_doc(units.FT)
    add_box_faces(msp, box_corners((30, 20, 12), at=(980000, 200000, 30)))
    doc.saveas(tmp_path / "ny.dxf")
    (mesh,) = meshes(read(tmp_path / "ny.dxf", crs="EPSG:2263"))
    assert np.ptp(mesh.vertices, axis=0) == pytest.approx(np.array([30, 20, 12]) * 1200 / 3937, rel=1e-9)
    assert any("drawing units: feet not applied" in n for n in mesh.notes), mesh.notes
    (plain,) = meshes(read(tmp_path / "ny.dxf"))
    assert np.ptp(plain.vertices, axis=0) == pytest.approx(np.array([30, 20, 12]) * 0.3048, rel=1e-9)


def test_a_file_the_plain_loader_refuses_is_recovered(tmp_path):
    """A drawing cut before its EOF marker: ezdxf's plain loader refuses it, its recovering reader
    reads it, and the box is there."""
    import io

    from meshsom.dxf import _plain

    doc, msp = new_doc()
    add_box_faces(msp, box_corners())
    text = io.StringIO()
    doc.write(text)
    cut = text.getvalue().rsplit("  0\nEOF", 1)[0].encode()
    with pytest.raises(Exception):
        _plain(cut)
    (tmp_path / "cut.dxf").write_bytes(cut)
    (mesh,) = meshes(read(tmp_path / "cut.dxf"))
    assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(VOLUME)


def test_a_district_in_one_polyface_is_split_on_request(tmp_path):
    """Two boxes in one POLYFACE (a district exported as one mesh): one building as it is, two with
    ``split_components`` (``#<handle>#c1``, ``#c2``), each the box's volume."""
    doc, msp = new_doc()
    polyface = msp.add_polyface()
    for at in ((0, 0, 0), (30, 0, 0)):
        corners = box_corners(at=at)
        polyface.append_faces([[tuple(p) for p in corners[q]] for q in QUADS])
    polyface.optimize()
    doc.saveas(tmp_path / "district.dxf")
    (whole,) = meshes(read(tmp_path / "district.dxf"))
    assert signed_volume(whole.vertices, whole.faces) == pytest.approx(2 * VOLUME)
    pieces = meshes(read(tmp_path / "district.dxf", split_components=True))
    assert [p.id for p in pieces] == [f"{whole.id}#c1", f"{whole.id}#c2"]
    for piece in pieces:
        assert signed_volume(piece.vertices, piece.faces) == pytest.approx(VOLUME) and closed(piece.faces)
        assert any("one of 2 connected pieces" in n for n in piece.notes)
