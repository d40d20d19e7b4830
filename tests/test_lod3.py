"""CityGML LoD3 buildings: windows and doors (openings) are not the envelope.

Hand-built houses (a 10 x 6 x 3 m box) whose south wall has a window hole (2 x 1 m, an interior ring) and a door
notch reaching the ground (1 x 2 m, in the wall's exterior ring), with the opening written as LoD3 writers write it:
a pane recessed 10 cm inside with no reveal (SIG3D's FZK house), a window body flush with the wall sharing the
hole's edges (geoRES), a pane recessed behind reveals (KIT's FZK house), in CityGML 2.0 (``bldg:opening`` of a
``bldg:Window``) and 3.0 (``con:fillingSurface`` of a ``con:WindowSurface``), inside the walls or referred to by a
``lod3Solid``. The expected volumes are by hand: the box, less the recess behind the reveals.
"""

from __future__ import annotations

import pytest

from meshsom.io import RawMesh, read_file
from meshsom.preprocess import preprocess

X0, Y0, Z0 = 458875.0, 5438350.0, 112.0
#: The box, and the openings of its south wall (y = 0): the window's hole, the door's notch.
LENGTH, DEPTH, HEIGHT = 10.0, 6.0, 3.0
WINDOW = (2.0, 4.0, 1.0, 2.0)  # x from, x to, z from, z to
DOOR = (6.0, 7.0, 0.0, 2.0)
RECESS = 0.1
BOX = LENGTH * DEPTH * HEIGHT
WINDOW_AREA = (WINDOW[1] - WINDOW[0]) * (WINDOW[3] - WINDOW[2])

NS = {
    "2.0": ('<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:gml="http://www.opengis.net/gml" '
            'xmlns:xlink="http://www.w3.org/1999/xlink" xmlns:bldg="http://www.opengis.net/citygml/building/2.0">',
            "</CityModel>"),
    "3.0": ('<core:CityModel xmlns:core="http://www.opengis.net/citygml/3.0" xmlns:gml="http://www.opengis.net/gml/3.2" '
            'xmlns:xlink="http://www.w3.org/1999/xlink" xmlns:bldg="http://www.opengis.net/citygml/building/3.0" '
            'xmlns:con="http://www.opengis.net/citygml/construction/3.0">', "</core:CityModel>"),
}


def _ring(points) -> str:
    flat = " ".join(f"{X0 + x!r} {Y0 + y!r} {Z0 + z!r}" for x, y, z in (*points, points[0]))
    return f'<gml:LinearRing><gml:posList srsDimension="3">{flat}</gml:posList></gml:LinearRing>'


def _polygon(exterior, interiors=(), pid=None) -> str:
    rings = f"<gml:exterior>{_ring(exterior)}</gml:exterior>" + "".join(
        f"<gml:interior>{_ring(r)}</gml:interior>" for r in interiors)
    return f'<gml:surfaceMember><gml:Polygon{f" gml:id={chr(34)}{pid}{chr(34)}" if pid else ""}>{rings}</gml:Polygon></gml:surfaceMember>'


def _quad_x(x0, x1, y, z0, z1, outward_minus_y=True):
    """A rectangle in the plane y (x0..x1, z0..z1), facing -y (or +y)."""
    ring = [(x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)]
    return ring if outward_minus_y else ring[::-1]


def _reveals(x0, x1, z0, z1, depth):
    """The four sides of a hole from the wall's plane (y = 0) to ``depth`` inside, facing into the hole."""
    return [[(x0, 0, z0), (x0, depth, z0), (x1, depth, z0), (x1, 0, z0)][::-1],  # sill, facing up
            [(x0, 0, z1), (x1, 0, z1), (x1, depth, z1), (x0, depth, z1)][::-1],  # lintel, facing down
            [(x0, 0, z0), (x0, 0, z1), (x0, depth, z1), (x0, depth, z0)][::-1],  # left jamb, facing +x
            [(x1, 0, z0), (x1, depth, z0), (x1, depth, z1), (x1, 0, z1)][::-1]]  # right jamb, facing -x


def _box_quads(x0, x1, y0, y1, z0, z1):
    """A closed box's six faces, outward."""
    return [[(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)], [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)],
            [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)], [(x1, y1, z0), (x0, y1, z0), (x0, y1, z1), (x1, y1, z1)],
            [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)], [(x0, y1, z0), (x0, y0, z0), (x0, y0, z1), (x0, y1, z1)]]


def _opening_geometry(kind: str, rect):
    """The polygons of an opening of the south wall written as ``kind``, and the reveals its wall gets."""
    x0, x1, z0, z1 = rect
    if kind == "recessed":  # a pane 10 cm inside, no reveal (SIG3D's FZK house LoD3)
        return [_quad_x(x0, x1, RECESS, z0, z1)], []
    if kind == "flush body":  # a window body whose front is the hole, sharing its edges (geoRES)
        return _box_quads(x0, x1, 0.0, 0.05, z0, z1), []
    if kind == "reveal":  # a pane behind reveals of the wall (KIT's FZK house LoD3)
        sides = _reveals(x0, x1, z0, z1, RECESS)
        return [_quad_x(x0, x1, RECESS, z0, z1)], sides if z0 > 0 else sides[1:]
    raise ValueError(kind)


def house_surfaces(kind: str) -> list[tuple[str, str, list, list]]:
    """The house's thematic surfaces with its window and door written as ``kind``: (CityGML name, id prefix, polygons
    as (exterior, interiors), openings as (name, exteriors)), shared by the CityGML fixtures here and the CityJSON
    ones (tests/test_cityjson_lod3.py)."""
    window, window_reveals = _opening_geometry(kind, WINDOW)
    door, door_reveals = _opening_geometry(kind, DOOR)
    dx0, dx1, _, dz1 = DOOR
    south = [(0, 0, 0), (dx0, 0, 0), (dx0, 0, dz1), (dx1, 0, dz1), (dx1, 0, 0), (LENGTH, 0, 0), (LENGTH, 0, HEIGHT), (0, 0, HEIGHT)]
    wx0, wx1, wz0, wz1 = WINDOW
    hole = [(wx0, 0, wz0), (wx0, 0, wz1), (wx1, 0, wz1), (wx1, 0, wz0)]
    ground = [(0, 0, 0), (0, DEPTH, 0), (LENGTH, DEPTH, 0), (LENGTH, 0, 0)]
    if door_reveals:  # the ground follows the door's recess
        ground += [(dx1, 0, 0), (dx1, RECESS, 0), (dx0, RECESS, 0), (dx0, 0, 0)]
    return [
        ("GroundSurface", "ground", [(ground, [])], []),
        ("RoofSurface", "roof", [([(0, 0, HEIGHT), (LENGTH, 0, HEIGHT), (LENGTH, DEPTH, HEIGHT), (0, DEPTH, HEIGHT)], [])], []),
        ("WallSurface", "south", [(south, [hole])] + [(r, []) for r in window_reveals + door_reveals],
         [("Window", window), ("Door", door)]),
        ("WallSurface", "north", [(_quad_x(0, LENGTH, DEPTH, 0, HEIGHT, False), [])], []),
        ("WallSurface", "east", [([(LENGTH, 0, 0), (LENGTH, DEPTH, 0), (LENGTH, DEPTH, HEIGHT), (LENGTH, 0, HEIGHT)], [])], []),
        ("WallSurface", "west", [([(0, DEPTH, 0), (0, 0, 0), (0, 0, HEIGHT), (0, DEPTH, HEIGHT)], [])], []),
    ]


def house(kind: str, version: str = "2.0", solid: bool = False) -> str:
    """The house as CityGML ``version`` with its window and door written as ``kind``; ``solid``: a ``lod3Solid``
    referring (``xlink:href``) to every polygon, the openings' too, as KIT's FZK house LoD3 does."""
    three = version == "3.0"
    lod = "core:lod3MultiSurface" if three else "bldg:lod3MultiSurface"
    ids: list[str] = []

    def polys(polygons, prefix):
        out = ""
        for k, (exterior, interiors) in enumerate(polygons):
            ids.append(f"{prefix}{k}")
            out += _polygon(exterior, interiors, f"{prefix}{k}")
        return f"<{lod}><gml:MultiSurface>{out}</gml:MultiSurface></{lod}>"

    def opening(name, rings):
        if three:
            return (f'<con:fillingSurface><con:{name}Surface gml:id="{name}">{polys([(r, []) for r in rings], name)}'
                    f"</con:{name}Surface></con:fillingSurface>")
        return f'<bldg:opening><bldg:{name} gml:id="{name}">{polys([(r, []) for r in rings], name)}</bldg:{name}></bldg:opening>'

    surfaces = [(name, polys(polygons, prefix), "".join(opening(o, rings) for o, rings in openings))
                for name, prefix, polygons, openings in house_surfaces(kind)]
    boundary = "core:boundary" if three else "bldg:boundedBy"
    thematic = "con" if three else "bldg"
    body = "".join(f"<{boundary}><{thematic}:{name}>{geometry}{openings}</{thematic}:{name}></{boundary}>"
                   for name, geometry, openings in surfaces)
    if solid:
        refs = "".join(f'<gml:surfaceMember xlink:href="#{pid}"/>' for pid in ids)
        prop = "core:lod3Solid" if three else "bldg:lod3Solid"
        shell = "gml:Shell" if three else "gml:CompositeSurface"
        body += f"<{prop}><gml:Solid><gml:exterior><{shell}>{refs}</{shell}></gml:exterior></gml:Solid></{prop}>"
    head, tail = NS[version]
    member = "core:cityObjectMember" if three else "cityObjectMember"
    return f'{head}<{member}><bldg:Building gml:id="house">{body}</bldg:Building></{member}>{tail}'


def _read(tmp_path, xml: str) -> RawMesh:
    (tmp_path / "house.gml").write_text(xml)
    (mesh,) = read_file(tmp_path / "house.gml")
    assert isinstance(mesh, RawMesh) and mesh.lod == "3"
    return mesh


def _trimesh_volume(result) -> float:
    import trimesh

    mesh = trimesh.Trimesh(result.vertices, result.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    return float(mesh.volume)


#: The envelope's volume, by hand: openings closed in the wall's plane; behind reveals, at the pane (the recess
#: of the window, and of the door's three sides above the ground, outside the envelope).
EXPECTED = {"recessed": BOX, "flush body": BOX,
            "reveal": BOX - WINDOW_AREA * RECESS - (DOOR[1] - DOOR[0]) * (DOOR[3] - DOOR[2]) * RECESS}


@pytest.mark.parametrize("version", ["2.0", "3.0"])
@pytest.mark.parametrize("kind", list(EXPECTED))
@pytest.mark.parametrize("solid", [False, True])
def test_openings_are_left_out_and_their_holes_closed(tmp_path, kind, version, solid):
    """Each way of writing a window and a door gives the closed envelope, the openings' geometry left out and
    counted. Before, the recessed pane left the hole open and the pane loose (rejected, or rebuilt under the roof),
    the flush window body made the hole's edges non-manifold."""
    mesh = _read(tmp_path, house(kind, version, solid))
    n_polygons = {"recessed": 2, "flush body": 12, "reveal": 2}[kind]
    assert f"left out the geometry of 2 opening(s) (windows, doors: {n_polygons} polygon(s))" in " ".join(mesh.notes)
    result = preprocess(mesh.vertices, mesh.faces)
    assert result.volume_out == pytest.approx(EXPECTED[kind], rel=1e-9)
    assert _trimesh_volume(result) == pytest.approx(EXPECTED[kind], rel=1e-9)
    assert any("capped 2 open planar loop(s)" in r for r in result.repairs), result.repairs


def test_the_reveal_s_recess_is_what_the_pane_leaves_out(tmp_path):
    """Independent of meshsom's closing: the box less the two recesses' prisms, united and cut by manifold3d, is
    the volume of the envelope read with reveals."""
    import manifold3d

    box = manifold3d.Manifold.cube([LENGTH, DEPTH, HEIGHT])
    for x0, x1, z0, z1 in (WINDOW, DOOR):
        box = box - manifold3d.Manifold.cube([x1 - x0, RECESS, z1 - z0 + (1 if z0 == 0 else 0)]).translate(
            [x0, 0, z0 - (1 if z0 == 0 else 0)])
    result = preprocess(*(lambda m: (m.vertices, m.faces))(_read(tmp_path, house("reveal"))))
    assert result.volume_out == pytest.approx(box.volume(), rel=1e-9)


def test_a_lod3_house_without_openings_reads_as_before(tmp_path):
    """Walls whose holes hold no opening (none written) are closed the same way, with no note of openings."""
    xml = house("recessed")
    for name in ("Window", "Door"):
        start = xml.index(f"<bldg:opening><bldg:{name}")
        xml = xml[:start] + xml[xml.index("</bldg:opening>", start) + len("</bldg:opening>"):]
    mesh = _read(tmp_path, xml)
    assert not any("opening" in n for n in mesh.notes)
    assert preprocess(mesh.vertices, mesh.faces).volume_out == pytest.approx(BOX, rel=1e-9)


def test_a_flush_window_body_read_as_shell_was_the_rejection(tmp_path):
    """What the reader gave before (the openings read as shell): a window body flush with its wall shares the
    hole's edges with the wall (three faces and more an edge), which preprocessing rejects as non-manifold. (A pane
    recessed with no reveal was dropped as a loose sheet and its hole capped already.)"""
    from meshsom.errors import MeshError

    mesh = _read(tmp_path, house("flush body"))
    xml = house("flush body").replace("bldg:opening", "bldg:boundedBy").replace("bldg:Window", "bldg:WallSurface").replace(
        "bldg:Door", "bldg:WallSurface")
    as_shell = _read(tmp_path, xml)
    assert len(as_shell.faces) > len(mesh.faces)
    with pytest.raises(MeshError, match="non-manifold"):
        preprocess(as_shell.vertices, as_shell.faces)


def test_citygml_0_4_namespace_is_citygml_not_an_ade(tmp_path):
    """CityGML 0.4 (``http://www.citygml.org/citygml/1/0/0``, citygml4j's LoD3 sample of 2010) is read as CityGML,
    where every element of it was taken for an ADE's and the building had no geometry; an ADE under
    ``http://www.citygml.org/ade/`` is still left out."""
    xml = house("recessed").replace("http://www.opengis.net/citygml/2.0", "http://www.citygml.org/citygml/1/0/0").replace(
        "http://www.opengis.net/citygml/building/2.0", "http://www.citygml.org/citygml/1/0/0")
    mesh = _read(tmp_path, xml)
    assert preprocess(mesh.vertices, mesh.faces).volume_out == pytest.approx(BOX, rel=1e-9)
    ade = house("recessed").replace("</bldg:Building>", '<test:unit xmlns:test="http://www.citygml.org/ade/TestADE/1.0">'
                                    '<bldg:lod3MultiSurface><gml:MultiSurface>'
                                    + _polygon([(20, 0, 0), (21, 0, 0), (21, 0, 1)]) + "</gml:MultiSurface>"
                                    "</bldg:lod3MultiSurface></test:unit></bldg:Building>")
    assert len(_read(tmp_path, ade).faces) == len(mesh.faces)
