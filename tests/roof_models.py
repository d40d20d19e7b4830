"""LoD2 roof models as city GIS offices publish them: surfaces, not solids, with their defects.

Each function returns a CityJSON document (MultiSurface, coordinates on a millimetre grid, a
national-grid offset) and the volume of the solid under its roofs down to its lowest vertex,
computed by hand from the shapes (not by the library). Every model stands on uneven terrain with
no ground surface, as the Stadt Zürich "Dachmodell" does: the walls stop at the terrain, so the
bottom is open and not planar, and no planar cap closes it. On top of that:

- :func:`gable_on_terrain` nothing else;
- :func:`parts_with_offset_wall` two BuildingParts whose walls overlap a millimetre apart;
- :func:`dormer_through_roof` a dormer whose walls pass through the roof (no shared edges);
- :func:`overhang_with_soffit` a roof slab overhanging the walls, its underside modelled;
- :func:`ridge_a_millimetre_apart` two roof halves whose ridges were rounded apart;
- :func:`courtyard_block` a flat roof with a courtyard (a polygon with a hole), walls inside and out;
- :func:`crossing_shed_roofs` two shed roofs on either side of one edge, one rising and one falling
  along it, so that their heights cross halfway;
- :func:`wall_foot_outside_the_eave` a wall whose foot stands 10 cm outside the eave above it;
- :func:`barrel_vault` a hall under a half-cylinder vault of 24 strips, whose springing strips
  (within 5 degrees of vertical) are walls, not roofs.

:func:`part_without_a_roof` (an annex whose roof is missing) is refused rather than rebuilt.
"""

from __future__ import annotations

from cityjson_samples import doc

#: The terrain under a model: z (m) = A x + B y + C x y, a twisted surface (not a plane).
TERRAIN = (0.05, 0.03, 0.004)
#: Building footprint: L (x) by W (y), metres; eave and ridge heights above z = 0.
L, W, EAVE, RIDGE = 12.0, 8.0, 6.0, 9.0


def terrain(x: float, y: float) -> float:
    a, b, c = TERRAIN
    return a * x + b * y + c * x * y


class _Model:
    """Vertices (metres, rounded to the millimetre grid on output) and polygons per object."""

    def __init__(self):
        self.vertices: list[list[int]] = []
        self.objects: dict = {}

    def vertex(self, x: float, y: float, z: float) -> int:
        self.vertices.append([round(x * 1000), round(y * 1000), round(z * 1000)])
        return len(self.vertices) - 1

    def polygon(self, name: str, rings: list[list[tuple[float, float, float]]]) -> None:
        """One polygon (outer ring, then holes) of object ``name``'s MultiSurface."""
        geometry = self.objects[name]["geometry"][0]
        geometry["boundaries"].append([[self.vertex(*p) for p in ring] for ring in rings])

    def add(self, name: str, kind: str = "Building", parent: str | None = None) -> None:
        self.objects[name] = {"type": kind, "geometry": [{"type": "MultiSurface", "lod": "2.2", "boundaries": []}]}
        if parent is not None:
            self.objects[name]["parents"] = [parent]
            self.objects[parent].setdefault("children", []).append(name)

    def document(self) -> dict:
        return doc(self.objects, self.vertices)


def _walls_to_terrain(model: _Model, name: str, ring: list[tuple[float, float]], tops) -> None:
    """Vertical walls under ``ring`` (counter-clockwise seen from above), from the terrain up to
    ``tops`` (per wall: the height of its level top, or the (x, y, z) points along its top from
    this corner to the next)."""
    n = len(ring)
    for i in range(n):
        (x0, y0), (x1, y1) = ring[i], ring[(i + 1) % n]
        top = tops[i] if isinstance(tops[i], list) else [(x0, y0, tops[i]), (x1, y1, tops[i])]
        model.polygon(name, [[(x0, y0, terrain(x0, y0)), (x1, y1, terrain(x1, y1)), *top[::-1]]])


def _gable_walls_and_roof(model: _Model, name: str, ridge_north: float = W / 2, ridge_south: float = W / 2) -> None:
    """A gable house over [0, L] x [0, W], ridge along x at y = W / 2 (each roof half's ridge at
    its own y, for rounding defects), walls down to the terrain."""
    ring = [(0.0, 0.0), (L, 0.0), (L, W), (0.0, W)]
    tops = [
        EAVE,  # south wall: (0,0) -> (L,0) at the eave
        [(L, 0.0, EAVE), (L, W / 2, RIDGE), (L, W, EAVE)],  # east gable
        EAVE,  # north wall
        [(0.0, W, EAVE), (0.0, W / 2, RIDGE), (0.0, 0.0, EAVE)],  # west gable
    ]
    _walls_to_terrain(model, name, ring, tops)
    model.polygon(name, [[(0.0, 0.0, EAVE), (L, 0.0, EAVE), (L, ridge_south, RIDGE), (0.0, ridge_south, RIDGE)]])
    model.polygon(name, [[(0.0, W, EAVE), (0.0, ridge_north, RIDGE), (L, ridge_north, RIDGE), (L, W, EAVE)]])


def _base(*xy: tuple[float, float]) -> float:
    return min(round(terrain(x, y) * 1000) / 1000 for x, y in xy)


def gable_on_terrain() -> tuple[dict, float]:
    """A gable house, walls down to uneven terrain, no ground surface."""
    model = _Model()
    model.add("house")
    _gable_walls_and_roof(model, "house")
    base = _base((0, 0), (L, 0), (L, W), (0, W))
    return model.document(), L * W * (EAVE - base) + L * W * (RIDGE - EAVE) / 2


def ridge_a_millimetre_apart() -> tuple[dict, float]:
    """The gable house whose north roof half has its ridge 1 mm north of the south half's."""
    model = _Model()
    model.add("house")
    _gable_walls_and_roof(model, "house", ridge_north=W / 2 + 0.001)
    base = _base((0, 0), (L, 0), (L, W), (0, W))
    # the 1 mm strip between the ridges is snapped shut (the north half moved onto the south ridge)
    return model.document(), L * W * (EAVE - base) + L * W * (RIDGE - EAVE) / 2


def dormer_through_roof() -> tuple[dict, float]:
    """The gable house with a flat-roofed dormer on its south slope whose walls start inside the
    attic (z = 5) and pass through the roof: they share no edge with it."""
    model = _Model()
    model.add("house")
    _gable_walls_and_roof(model, "house")
    x0, x1, y0, y1, zd, z_in = 4.0, 7.0, 0.5, 3.0, 8.5, 5.0
    ring = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    for (ax, ay), (bx, by) in zip(ring, ring[1:] + ring[:1]):
        model.polygon("house", [[(ax, ay, z_in), (bx, by, z_in), (bx, by, zd), (ax, ay, zd)]])
    model.polygon("house", [[(x, y, zd) for x, y in ring]])
    base = _base((0, 0), (L, 0), (L, W), (0, W))
    slope = (RIDGE - EAVE) / (W / 2)  # the south roof: z = EAVE + slope * y
    above = (x1 - x0) * ((zd - EAVE) * (y1 - y0) - slope * (y1**2 - y0**2) / 2)
    return model.document(), L * W * (EAVE - base) + L * W * (RIDGE - EAVE) / 2 + above


def parts_with_offset_wall() -> tuple[dict, float]:
    """A Building of two BuildingParts: a flat-roofed block [0, 10] x [0, 8] (roof at 6 m) and a
    taller annex east of it (roof at 9 m) whose west wall stands 1 mm east of the block's east
    wall, overlapping it (a rounding of the annex's own survey)."""
    model = _Model()
    model.add("B")
    model.add("block", "BuildingPart", "B")
    model.add("annex", "BuildingPart", "B")
    block = [(0.0, 0.0), (10.0, 0.0), (10.0, 8.0), (0.0, 8.0)]
    annex = [(10.001, 2.0), (16.0, 2.0), (16.0, 6.0), (10.001, 6.0)]
    _walls_to_terrain(model, "block", block, [6.0] * 4)
    model.polygon("block", [[(x, y, 6.0) for x, y in block]])
    _walls_to_terrain(model, "annex", annex, [9.0] * 4)
    model.polygon("annex", [[(x, y, 9.0) for x, y in annex]])
    base = _base(*block, *annex)
    # the annex's roof corners split the block's roof edge: the block's prism reaches x = 10.001
    # between y = 2 and 6 (a triangle of 1 mm x 2 m at each end, a strip of 1 mm x 4 m between)
    sliver = 0.001 * (1.0 + 4.0 + 1.0) * (6.0 - base)
    return model.document(), 80 * (6.0 - base) + (16.0 - 10.001) * 4.0 * (9.0 - base) + sliver


def overhang_with_soffit() -> tuple[dict, float]:
    """A block [0, 10] x [0, 8] whose walls reach 5 m, under a roof slab 0.3 m thick that overhangs
    them by 1 m on every side; the slab's underside (a soffit, facing down) is modelled."""
    model = _Model()
    model.add("house")
    inner = [(0.0, 0.0), (10.0, 0.0), (10.0, 8.0), (0.0, 8.0)]
    outer = [(-1.0, -1.0), (11.0, -1.0), (11.0, 9.0), (-1.0, 9.0)]
    _walls_to_terrain(model, "house", inner, [5.0] * 4)
    model.polygon("house", [[(x, y, 5.3) for x, y in outer]])  # roof, facing up
    # soffit: the ring between the slab's outline and the walls, facing down (clockwise from above)
    model.polygon("house", [[(x, y, 5.0) for x, y in outer[::-1]], [(x, y, 5.0) for x, y in inner]])
    for (ax, ay), (bx, by) in zip(outer, outer[1:] + outer[:1]):  # the slab's edges
        model.polygon("house", [[(ax, ay, 5.0), (bx, by, 5.0), (bx, by, 5.3), (ax, ay, 5.3)]])
    base = _base(*inner)
    return model.document(), 80 * (5.0 - base) + 12 * 10 * 0.3


def courtyard_block() -> tuple[dict, float]:
    """A perimeter block [0, 20] x [0, 16] around a courtyard [5, 15] x [4, 12], flat roof at 7 m
    (one polygon with a hole), walls outside and around the courtyard down to the terrain."""
    model = _Model()
    model.add("block")
    outer = [(0.0, 0.0), (20.0, 0.0), (20.0, 16.0), (0.0, 16.0)]
    inner = [(5.0, 4.0), (15.0, 4.0), (15.0, 12.0), (5.0, 12.0)]
    _walls_to_terrain(model, "block", outer, [7.0] * 4)
    _walls_to_terrain(model, "block", inner[::-1], [7.0] * 4)  # facing into the courtyard
    model.polygon("block", [[(x, y, 7.0) for x, y in outer], [(x, y, 7.0) for x, y in inner[::-1]]])
    base = _base(*outer)
    return model.document(), (20 * 16 - 10 * 8) * (7.0 - base)


def crossing_shed_roofs() -> tuple[dict, float]:
    """Two shed roofs over [0, L] x [0, W/2] (rising east, 6 to 9 m) and [0, L] x [W/2, W] (falling
    east, 9 to 6 m) sharing their edge along y = W / 2, where they cross at x = L / 2; the wall
    between them is the two triangles of the step."""
    model = _Model()
    model.add("house")
    h = W / 2

    def south(x):
        return EAVE + (RIDGE - EAVE) * x / L

    def north(x):
        return RIDGE - (RIDGE - EAVE) * x / L

    ring = [(0.0, 0.0), (L, 0.0), (L, W), (0.0, W)]
    tops = [
        [(0.0, 0.0, south(0)), (L, 0.0, south(L))],
        [(L, 0.0, south(L)), (L, h, south(L)), (L, h, north(L)), (L, W, north(L))],
        [(L, W, north(L)), (0.0, W, north(0))],
        [(0.0, W, north(0)), (0.0, h, north(0)), (0.0, h, south(0)), (0.0, 0.0, south(0))],
    ]
    _walls_to_terrain(model, "house", ring, tops)
    model.polygon("house", [[(0.0, 0.0, south(0)), (L, 0.0, south(L)), (L, h, south(L)), (0.0, h, south(0))]])
    model.polygon("house", [[(0.0, h, north(0)), (L, h, north(L)), (L, W, north(L)), (0.0, W, north(0))]])
    mid = (L / 2, h, (south(0) + north(0)) / 2)
    model.polygon("house", [[(0.0, h, south(0)), mid, (0.0, h, north(0))]])  # the step, west half
    model.polygon("house", [[(L, h, north(L)), mid, (L, h, south(L))]])  # and east half
    base = _base(*ring)
    return model.document(), L * W * ((EAVE + RIDGE) / 2 - base)


#: How far the foot of the leaning south wall of :func:`wall_foot_outside_the_eave` stands south of
#: the eave, metres.
FOOT = 0.1


def wall_foot_outside_the_eave() -> tuple[dict, float]:
    """The gable house whose south wall leans out: its top is the eave (y = 0), its foot on the
    terrain stands :data:`FOOT` further south (a footprint from the cadastre, roofs from lidar). The
    rebuild loses the wedge between the wall and the eave (:func:`foot_wedge`); its floor is the
    lowest vertex, a foot."""
    model = _Model()
    model.add("house")
    _gable_walls_and_roof(model, "house")
    south = model.objects["house"]["geometry"][0]["boundaries"][0]  # the vertical south wall ...
    (x0, y0), (x1, y1) = (0.0, -FOOT), (L, -FOOT)
    south[0] = [model.vertex(x0, y0, terrain(x0, y0)), model.vertex(x1, y1, terrain(x1, y1)),
                model.vertex(L, 0.0, EAVE), model.vertex(0.0, 0.0, EAVE)]  # ... leaning out at its foot
    base = _base((0, -FOOT), (L, -FOOT), (L, 0), (L, W), (0, W), (0, 0))
    return model.document(), L * W * (EAVE - base) + L * W * (RIDGE - EAVE) / 2


def foot_wedge() -> float:
    """The volume between the leaning wall of :func:`wall_foot_outside_the_eave` and the plane of the
    eave: its height along the wall (eave minus the straight foot between the terrain's corners)
    times half the foot's reach."""
    bottom = (_base((0, -FOOT)) + _base((L, -FOOT))) / 2
    return L * (EAVE - bottom) * FOOT / 2


def barrel_vault() -> tuple[dict, float]:
    """A hall [0, 30] x [0, 12] whose walls reach 10 m, under a barrel vault (a half cylinder of
    radius 6 along x, 24 strips across, 6 along): a curved roof, as stations, halls and churches
    have. The strips at the springing rise within 5 degrees of vertical, so they are walls: the
    columns under them (5 cm wide) are lost, and the solid is what lies under the other 22 strips
    (each a trapezoid in cross-section, from the millimetre-rounded coordinates)."""
    import math

    length, width, eave, n, rows = 30.0, 12.0, 10.0, 24, 6
    r = width / 2
    ys = [round(r - r * math.cos(math.pi * k / n), 3) for k in range(n + 1)]
    zs = [round(eave + r * math.sin(math.pi * k / n), 3) for k in range(n + 1)]
    model = _Model()
    model.add("hall")
    ring = [(0.0, 0.0), (length, 0.0), (length, width), (0.0, width)]
    tops = [eave, [(length, y, z) for y, z in zip(ys, zs)], eave, [(0.0, y, z) for y, z in zip(ys, zs)][::-1]]
    _walls_to_terrain(model, "hall", ring, tops)
    xs = [length * j / rows for j in range(rows + 1)]
    for x0, x1 in zip(xs, xs[1:]):
        for k in range(n):
            model.polygon("hall", [[(x0, ys[k], zs[k]), (x1, ys[k], zs[k]), (x1, ys[k + 1], zs[k + 1]), (x0, ys[k + 1], zs[k + 1])]])
    base = _base(*ring)
    steep = math.tan(math.radians(5))
    section = sum((ys[k + 1] - ys[k]) * ((zs[k] + zs[k + 1]) / 2 - base) for k in range(n)
                  if ys[k + 1] - ys[k] > steep * abs(zs[k + 1] - zs[k]))
    return model.document(), length * section


def part_without_a_roof() -> dict:
    """The gable house and, as a BuildingPart of the same Building, an annex [L, L + 4] x [2, 6] east
    of it whose roof is missing: walls 3 m high and nothing on them. Its west wall stands in the
    plane of the house's east wall; the three others stand up to 4 m outside every roof."""
    model = _Model()
    model.add("B")
    model.add("house", "BuildingPart", "B")
    model.add("annex", "BuildingPart", "B")
    _gable_walls_and_roof(model, "house")
    _walls_to_terrain(model, "annex", [(L, 2.0), (L + 4.0, 2.0), (L + 4.0, 6.0), (L, 6.0)], [3.0] * 4)
    return model.document()


#: Every model, by name.
MODELS = {
    "gable_on_terrain": gable_on_terrain,
    "ridge_a_millimetre_apart": ridge_a_millimetre_apart,
    "dormer_through_roof": dormer_through_roof,
    "parts_with_offset_wall": parts_with_offset_wall,
    "overhang_with_soffit": overhang_with_soffit,
    "courtyard_block": courtyard_block,
    "crossing_shed_roofs": crossing_shed_roofs,
    "wall_foot_outside_the_eave": wall_foot_outside_the_eave,
    "barrel_vault": barrel_vault,
}
