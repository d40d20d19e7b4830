"""A Building's parts become one outer surface: boxes whose union is known by hand."""

import numpy as np
import pytest

from cityjson_samples import CUBE_QUADS, box_solid, building_of_parts, doc, write
from meshsom.io import RawMesh, ReaderOptions, read_file
from meshsom.preprocess import PreprocessParams, validate
from meshsom.union import union_parts
from pipelines.ingest import process_one


def _area_volume(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cross = np.cross(b - a, c - a)
    return 0.5 * np.linalg.norm(cross, axis=1).sum(), np.einsum("ij,ij->i", a, cross).sum() / 6


def _shells(f):
    """Vertex-connected components, by a plain union-find (independent of the library's code)."""
    parent = list(range(f.max() + 1))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b, c in f.tolist():
        parent[find(b)] = find(a)
        parent[find(c)] = find(a)
    return len({find(i) for i in np.unique(f)})


def _box_area(lo, hi):
    d = (np.array(hi) - np.array(lo)) / 1000
    return 2 * (d[0] * d[1] + d[1] * d[2] + d[0] * d[2])


def _ingest(tmp_path, document, **reader):
    path = write(tmp_path / "b.city.json", document)
    (raw,) = read_file(path, ReaderOptions(**reader))
    assert isinstance(raw, RawMesh), raw
    return raw, *process_one(raw, PreprocessParams())


M = 1000  # millimetres per metre
CASES = {
    # name: (boxes, union volume m3, union area m2, vertices, faces, shells)
    "two boxes sharing a wall": ([((0, 0, 0), (10 * M, 8 * M, 6 * M)), ((10 * M, 0, 0), (16 * M, 8 * M, 6 * M))],
                                 16 * 8 * 6, 2 * (16 * 8 + 16 * 6 + 8 * 6), 8, 12, 1),
    "tower on a podium": ([((0, 0, 0), (20 * M, 20 * M, 4 * M)), ((5 * M, 5 * M, 4 * M), (10 * M, 10 * M, 30 * M))],
                          20 * 20 * 4 + 5 * 5 * 26, 1120 - 25 + 4 * 5 * 26 + 25, 16, 28, 1),
    "tower through a podium": ([((0, 0, 0), (20 * M, 20 * M, 4 * M)), ((5 * M, 5 * M, 0), (10 * M, 10 * M, 30 * M))],
                               20 * 20 * 4 + 5 * 5 * 26, 1120 - 25 + 4 * 5 * 26 + 25, 16, 28, 1),
    "part enclosed in another": ([((0, 0, 0), (10 * M, 10 * M, 10 * M)), ((2 * M, 2 * M, 2 * M), (4 * M, 4 * M, 4 * M))],
                                 1000, 600, 8, 12, 1),
    "coplanar overlap": ([((0, 0, 0), (10 * M, 8 * M, 6 * M)), ((5 * M, 0, 0), (15 * M, 8 * M, 6 * M))],
                         15 * 8 * 6, 2 * (15 * 8 + 15 * 6 + 8 * 6), 8, 12, 1),
    "parts that do not touch": ([((0, 0, 0), (10 * M, 10 * M, 5 * M)), ((20 * M, 0, 0), (30 * M, 10 * M, 5 * M))],
                                1000, 800, 16, 24, 2),
}


@pytest.mark.parametrize("name", list(CASES))
def test_parts_united_into_outer_surface(tmp_path, name):
    boxes, volume, area, n_vertices, n_faces, n_shells = CASES[name]
    raw, record, mesh = _ingest(tmp_path, building_of_parts(boxes))
    assert sorted(raw.parts) == ["P0", "P1"] and len(raw.face_part) == len(raw.faces)
    assert record["status"] == "accepted", record
    v, f = mesh.vertices, mesh.faces
    assert validate(v, f) is None
    got_area, got_volume = _area_volume(v, f)
    assert got_volume == pytest.approx(volume, rel=1e-9)
    assert got_area == pytest.approx(area, rel=1e-9)
    assert (len(v), len(f), _shells(f)) == (n_vertices, n_faces, n_shells)
    u = record["union"]
    parts_area = sum(_box_area(lo, hi) for lo, hi in boxes)
    assert (u["status"], u["parts"], u["shells_before"], u["shells_after"]) == ("united", 2, 2, n_shells)
    assert u["area_in"] == pytest.approx(parts_area, rel=1e-9)
    assert u["area_removed"] == pytest.approx(parts_area - area, rel=1e-9, abs=1e-9)
    assert u["volume_out"] == pytest.approx(volume, rel=1e-9)
    assert any(r.startswith("united 2 parts") for r in record["repairs"])


def test_separate_parts_are_not_united(tmp_path):
    boxes = CASES["two boxes sharing a wall"][0]
    path = write(tmp_path / "b.city.json", building_of_parts(boxes))
    meshes = list(read_file(path, ReaderOptions(parts="separate")))
    assert [m.id for m in meshes] == ["b.city.json#P0", "b.city.json#P1"]
    for m, (lo, hi) in zip(meshes, boxes):
        record, clean = process_one(m, PreprocessParams())
        assert "union" not in record and m.parts == ()
        assert _area_volume(clean.vertices, clean.faces)[0] == pytest.approx(_box_area(lo, hi))


def test_union_at_national_grid_offsets_keeps_precision():
    """RD New-sized coordinates (85,000 / 447,000 m): the union is computed about a local origin."""
    import trimesh

    a = trimesh.creation.box(bounds=[[0, 0, 0], [10.001, 8, 6]])
    b = trimesh.creation.box(bounds=[[10.001, 0, 0], [16.003, 8, 6]])
    offset = np.array([85_000.123, 447_000.456, 2.0])
    v = np.concatenate([a.vertices, b.vertices]) + offset
    f = np.concatenate([a.faces, b.faces + len(a.vertices)])
    part = np.repeat([0, 1], [len(a.faces), len(b.faces)])
    u = union_parts(v, f, part)
    (sv, sf), = u.shells
    area, volume = _area_volume(sv - offset, sf)
    assert volume == pytest.approx(16.003 * 8 * 6, rel=1e-12)
    assert area == pytest.approx(2 * (16.003 * 8 + 16.003 * 6 + 8 * 6), rel=1e-12)
    # The corners come back exactly where they were (to far below a millimetre).
    corners = np.array([[x, y, z] for x in (0, 16.003) for y in (0, 8) for z in (0, 6)]) + offset
    nearest = np.abs(sv[:, None] - corners[None]).max(axis=2).min(axis=0)
    assert nearest.max() < 1e-9


def test_failed_union_says_so_and_falls_back(tmp_path):
    """A part that is open (only two walls: a hole across four planes, not capped) cannot be united."""
    corners, solid = box_solid((0, 0, 0), (10 * M, 10 * M, 5 * M), 0)
    solid["boundaries"][0] = solid["boundaries"][0][2:4]  # two adjacent walls: no floor, roof or other walls
    corners2, solid2 = box_solid((20 * M, 0, 0), (30 * M, 10 * M, 5 * M), 8)
    objects = {"B": {"type": "Building", "children": ["P0", "P1"]},
               "P0": {"type": "BuildingPart", "parents": ["B"], "geometry": [solid]},
               "P1": {"type": "BuildingPart", "parents": ["B"], "geometry": [solid2]}}
    raw, record, mesh = _ingest(tmp_path, doc(objects, corners + corners2))
    assert mesh is None and record["status"] == "rejected"
    assert record["union"]["status"] == "failed" and "part P0 is not a closed volume" in record["union"]["reason"]
    assert record["reason"].startswith("open boundary") and "the union of its parts failed too" in record["reason"]


def test_open_because_the_reader_dropped_a_self_crossing_quad(tmp_path):
    """A twisted (self-crossing) wall quad is dropped by the reader; the rejection says so."""
    corners, solid = box_solid((0, 0, 0), (10 * M, 10 * M, 5 * M), 0)
    walls = solid["boundaries"][0]
    q = walls[2][0]
    walls[2] = [[q[0], q[1], q[3], q[2]]]  # bowtie: the ring crosses itself
    # and the roof and the next two walls are missing: a hole across four planes, not capped
    del walls[3:5]
    del walls[1]
    raw, record, mesh = _ingest(tmp_path, doc({"X": {"type": "Building", "geometry": [solid]}}, corners))
    assert any("dropped 1 polygon" in n and "self-crossing" in n for n in raw.notes)
    assert mesh is None and record["reason"].startswith("open boundary")
    assert "dropped 1 polygon(s)" in record["reason"] and "self-crossing" in record["reason"]
    assert record["notes"] == list(raw.notes)


def test_cube_quads_fixture_is_outward():
    """The box fixture itself: CUBE_QUADS are counter-clockwise seen from outside (positive volume)."""
    corners, solid = box_solid((0, 0, 0), (M, M, M), 0)
    v = np.array(corners, float) / M
    f = np.array([[q[0], q[i], q[i + 1]] for q in CUBE_QUADS for i in (1, 2)])
    assert _area_volume(v, f) == pytest.approx((6.0, 1.0))


@pytest.mark.parametrize("off", [0.0009, 0.003, -0.002])
@pytest.mark.parametrize("height", [6.0, 10.0, 14.0])
def test_a_part_drawn_a_little_off_its_buildings_wall_is_snapped_onto_it(off, height):
    """A part whose corner was drawn millimetres off its building's wall (OpenStreetMap parts and outlines share
    one corner, the next is a hair off the line) meets that wall in a wedge a hundredth of a degree wide: the
    union kept the part a shell of its own (outside) or cut a notch into the wall. Snapped onto the wall, the two
    are one shell whose volume is that of the footprints as meant: area by shapely x heights."""
    import shapely

    from meshsom.polygons import extrude_polygon
    from meshsom.union import preprocess_shells, snap_to_walls

    hall = np.array([[0, 0], [12, 0], [12, 8], [0, 8]], float)
    part = np.array([[0, 0], [0, -5], [3.6, -5], [3.6, -off]], float)  # meant: its top edge on the hall's y = 0
    vb, fb = extrude_polygon(hall, [], 0, 10)
    va, fa = extrude_polygon(part, [], 0, height)
    v = np.concatenate([vb, va])
    f = np.concatenate([fb, fa + len(vb)])
    face_part = np.repeat([0, 1], [len(fb), len(fa)])
    meant = shapely.Polygon(hall).area * 10 + shapely.Polygon(np.where(part == -off, 0, part)).area * height

    snapped, moved, _ = snap_to_walls([(vb, fb), (va, fa)], 0.01, 5.0)
    assert moved == 2  # the corner (3.6, -off) at its foot and at its eaves
    assert np.allclose(snapped[1][np.isclose(va[:, 0], 3.6) & (va[:, 1] > -1)][:, :2], [3.6, 0], atol=1e-12)
    assert np.array_equal(snapped[0], vb)  # the hall's corners are all farther than 1 cm from the part's walls
    united = union_parts(v, f, face_part, PreprocessParams())
    assert united.shells_after == 1
    assert any("moved 2 corners" in r for r in united.repairs), united.repairs
    result = preprocess_shells(united.shells, PreprocessParams())
    assert validate(result.vertices, result.faces) is None
    assert result.volume_out == pytest.approx(meant, rel=1e-9)
    off_united = union_parts(v, f, face_part, PreprocessParams(union_snap_tol=0))
    if off > 0:  # outside the wall: without the snap the part stays a shell of its own
        assert off_united.shells_after == 2


def test_parts_farther_apart_than_the_snap_tolerance_stay_apart():
    from meshsom.polygons import extrude_polygon
    from meshsom.union import snap_to_walls

    a = extrude_polygon(np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float), [], 0, 5)
    b = extrude_polygon(np.array([[10.02, 2], [15, 2], [15, 8], [10.02, 8]], float), [], 0, 5)
    snapped, moved, _ = snap_to_walls([a, b], 0.01, 5.0)
    assert moved == 0 and np.array_equal(snapped[0], a[0]) and np.array_equal(snapped[1], b[0])
    snapped, moved, _ = snap_to_walls([a, b], 0.05, 5.0)
    assert moved == 4 and np.allclose(snapped[1][np.isclose(b[0][:, 0], 10.02), 0], 10.0)


def test_parts_keep_their_shape_for_the_union():
    """Two parts meeting along a wall with a 5 cm jog (Vienna's LoD 2 parts have such): collapsing each part's jog
    alone (max_fold_v: its volume kept, its wall moved) made the parts overlap, and the union lost 20 m3 of a
    22,678 m3 building. The parts are united as they are (the union's shells are cleaned afterwards): the union is
    the two blocks' 20 x 10 x 10 m exactly."""
    from meshsom.polygons import extrude_polygon

    west = np.array([(0, 0), (10, 0), (10, 5), (10.05, 5), (10.05, 10), (0, 10)], float)
    east = np.array([(10, 0), (20, 0), (20, 10), (10.05, 10), (10.05, 5), (10, 5)], float)
    va, fa = extrude_polygon(west, [], 0, 10)
    vb, fb = extrude_polygon(east, [], 0, 10)
    v = np.concatenate([va, vb])
    f = np.concatenate([fa, fb + len(va)])
    united = union_parts(v, f, np.repeat([0, 1], [len(fa), len(fb)]), PreprocessParams())
    assert united.volume_out == pytest.approx(2000.0, rel=1e-12) and united.shells_after == 1
    assert not any("collapsed" in r for r in united.repairs), united.repairs


@pytest.fixture(scope="module")
def bolshoi():
    """The Bolshoi Theatre (data/real/osm-s3db-bolshoi, OpenStreetMap, 127 S3DB parts, flat roofs), as read."""
    from pathlib import Path

    from meshsom.io import ReaderOptions

    path = Path(__file__).resolve().parents[1] / "data" / "real" / "osm-s3db-bolshoi" / "bolshoi_theater.osm"
    (theatre,) = [m for m in read_file(path, ReaderOptions(roofs=False)) if isinstance(m, RawMesh)]
    return theatre


#: The Bolshoi's parts united, a slab-by-slab union of their prisms (libosmium's areas in a transverse Mercator,
#: shapely's areas x the slabs' heights), m3; manifold3d's union of the parts as read gives 226,216.96.
BOLSHOI_UNION = 226216.0


def _flat_prisms(parts):
    """Flat-roofed prisms of ``parts`` [(plan (N, 2), height)] from z = 0, as one mesh with a part per face, and the
    volume of their union by shapely (slab by slab: the union of the plans standing in each slab x its height)."""
    import shapely

    from meshsom.polygons import extrude_polygon

    meshes = [extrude_polygon(np.asarray(plan, float), [], 0, height) for plan, height in parts]
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    v = np.concatenate([v for v, _ in meshes])
    f = np.concatenate([f + offsets[k] for k, (_, f) in enumerate(meshes)])
    face_part = np.repeat(np.arange(len(parts)), [len(f) for _, f in meshes])
    tops = sorted({0.0, *(h for _, h in parts)})
    volume = sum(shapely.union_all([shapely.Polygon(p) for p, h in parts if h >= z1]).area * (z1 - z0)
                 for z0, z1 in zip(tops, tops[1:]))
    return v, f, face_part, volume


def test_parts_keep_the_corners_their_neighbours_meet():
    """A tower 100 m tall whose south wall bends by millimetres at two corners (at x = 20 m, 6 mm out; at 60 m, 10 mm
    in), where three lower wings meet it, sharing those corners (OpenStreetMap's parts share their nodes). The
    tower's preprocessing alone dropped both corners as collinear (within planar_dist x its 111 m diagonal), so its
    wall no longer met its wings': the union held wedges a hundredth of a degree wide that no repair closed, and
    preprocessing refused it (as the Moscow International House of Music's 195 parts). The parts keep their corners;
    the union is one shell, of the volume shapely gives the footprints slab by slab."""
    from meshsom.union import unite

    tower = [(0, 0), (20, 0.006), (60, -0.01), (100, 0), (100, 50), (0, 50)]
    west = [(-10, 0), (0, 0), (20, 0.006), (20, -20), (-10, -20)]
    middle = [(20, 0.006), (60, -0.01), (60, -20), (20, -20)]
    east = [(60, -0.01), (100, 0), (110, 0), (110, -20), (60, -20)]
    v, f, face_part, volume = _flat_prisms([(tower, 100.0), (west, 30.0), (middle, 14.0), (east, 30.0)])
    united, result = unite(v, f, face_part, PreprocessParams())
    assert united.shells_after == 1 and united.volume_out == pytest.approx(volume, rel=1e-9)
    assert validate(result.vertices, result.faces) is None
    # The united shells are cleaned as any mesh: the tower's bends above its wings may go (within volume_rtol).
    assert result.volume_out == pytest.approx(volume, rel=1e-5)


def test_a_building_of_many_parts_unites_into_one_closed_shell(bolshoi):
    """The Bolshoi's parts, each keeping its corners, unite into one shell that preprocesses; before, its union held
    wedges where parts' corners had been dropped, preprocessing refused it, and the building was rebuilt under its
    roofs with 8 % less volume. Its volume is the parts' union (:data:`BOLSHOI_UNION`) within 0.01 %."""
    from meshsom.union import unite

    united, result = unite(bolshoi.vertices, bolshoi.faces, bolshoi.face_part, PreprocessParams(), bolshoi.id,
                           bolshoi.parts)
    assert united.shells_after == 1
    assert validate(result.vertices, result.faces) is None
    assert result.volume_out == pytest.approx(BOLSHOI_UNION, rel=1e-4)


def test_flat_sheets_the_union_leaves_are_dropped(bolshoi):
    """The Bolshoi's parts as a cleaning that drops corners collinear within planar_dist leaves them (what each part's
    preprocessing did before it kept them): manifold3d's union of these leaves flat sheets besides the building (both
    sides of faces of parts touching face to face), each a shell of no volume that preprocessing refused as "zero
    volume: it is flat". They are dropped, said in the repairs; the union's volume is the parts' union
    (:data:`BOLSHOI_UNION`) within 0.1 %."""
    from meshsom.preprocess import preprocess, signed_volume

    params = PreprocessParams(max_fold_v=0.0)
    cleaned = [preprocess(bolshoi.vertices, bolshoi.faces[bolshoi.face_part == k], params) for k in range(len(bolshoi.parts))]
    offsets = np.cumsum([0] + [len(c.vertices) for c in cleaned])
    v = np.concatenate([c.vertices for c in cleaned])
    f = np.concatenate([c.faces + offsets[k] for k, c in enumerate(cleaned)])
    face_part = np.repeat(np.arange(len(cleaned)), [len(c.faces) for c in cleaned])
    united = union_parts(v, f, face_part, PreprocessParams())
    assert any("flat sheet(s) the union left" in r for r in united.repairs), united.repairs
    for v, f in united.shells:
        assert abs(signed_volume(v, f)) > 1.0
    assert united.volume_out == pytest.approx(BOLSHOI_UNION, rel=1e-3)


def _manifold_box(lo, hi):
    import manifold3d

    mesh = manifold3d.Manifold.cube(list(np.subtract(hi, lo))).translate(list(lo)).to_mesh64()
    return np.asarray(mesh.vert_properties, np.float64)[:, :3], np.asarray(mesh.tri_verts, np.int64).reshape(-1, 3)


def test_a_parts_cavity_stays_a_cavity_of_the_union():
    """A 2 m cube with a 1 m cube cavity (one part: its inner shell facing in) beside a 1.5 m cube: manifold3d's union
    decomposes into pieces of 8, -1 and 3.375 m3, and the cavity, preprocessed alone, was turned outward as a solid
    (12.375 m3). Kept with the piece that encloses it, it stays a cavity: 7 + 3.375 m3, as manifold3d's own volume of
    the union of the two parts (the hollow cube as the difference of its cubes)."""
    import manifold3d

    from meshsom.union import unite

    boxes = [_manifold_box((0, 0, 0), (2, 2, 2)), _manifold_box((0.5, 0.5, 0.5), (1.5, 1.5, 1.5)),
             _manifold_box((3, 0, 0), (4.5, 1.5, 1.5))]
    boxes[1] = (boxes[1][0], boxes[1][1][:, ::-1])  # the cavity faces in
    offsets = np.cumsum([0] + [len(v) for v, _ in boxes])
    v = np.concatenate([b[0] for b in boxes])
    f = np.concatenate([b[1] + offsets[k] for k, b in enumerate(boxes)])
    face_part = np.repeat([0, 0, 1], [len(b[1]) for b in boxes])
    cube = manifold3d.Manifold.cube
    independent = ((cube([2, 2, 2]) - cube([1, 1, 1]).translate([0.5, 0.5, 0.5]))
                   + cube([1.5, 1.5, 1.5]).translate([3, 0, 0])).volume()
    assert independent == pytest.approx(10.375)
    united, result = unite(v, f, face_part, PreprocessParams())
    assert united.shells_after == 2 and len(united.shells) == 2
    assert united.volume_out == pytest.approx(independent, rel=1e-12)
    assert result.volume_out == pytest.approx(independent, rel=1e-12)
    assert validate(result.vertices, result.faces) is None


def test_the_snap_leaves_a_part_it_would_flatten_as_drawn():
    """A pane 6 mm thick 2 mm beside its frame (a 1 m cube), and a 10 m block drawn 3 mm off the frame's other wall:
    the snap onto walls (1 cm) moved both of the pane's faces onto the frame's wall, flattening it (KIT's FZK-Haus
    windows lost 94 % of a pane so). A part whose volume the moves change by more than volume_rtol keeps its corners;
    the block (0.03 %) is still snapped onto the frame. Union: 1 + 10 (block snapped) + 0.006 m3, by hand, in two
    shells (the pane 2 mm apart)."""
    from meshsom.union import snap_to_walls

    boxes = [_manifold_box((0, 0, 0), (1, 1, 1)), _manifold_box((1.002, 0, 0), (1.008, 1, 1)),
             _manifold_box((-10, 0, 0), (-0.003, 1, 1))]
    offsets = np.cumsum([0] + [len(v) for v, _ in boxes])
    v = np.concatenate([b[0] for b in boxes])
    f = np.concatenate([b[1] + offsets[k] for k, b in enumerate(boxes)])
    face_part = np.repeat([0, 1, 2], [len(b[1]) for b in boxes])
    params = PreprocessParams()
    snapped, moved, held = snap_to_walls(boxes, params.union_snap_tol, params.wall_tilt_deg,
                                         volume_rtol=params.volume_rtol)
    assert moved == 4 and np.array_equal(snapped[1], boxes[1][0])  # the block's 4 corners at x = -0.003; no pane's
    assert held.tolist() == [True, True, False]  # the cube too: moved 2 mm onto the pane it grows 0.2 %
    united = union_parts(v, f, face_part, params)
    assert any(r.startswith("left 2 parts unsnapped") for r in united.repairs), united.repairs
    assert united.shells_after == 2 and united.moved == 4
    assert united.volume_out == pytest.approx(11.006, rel=1e-9)
    assert sorted(_area_volume(sv, sf)[1] for sv, sf in united.shells) == pytest.approx([0.006, 11.0], rel=1e-9)
