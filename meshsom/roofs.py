"""Roof shapes on footprints, as OpenStreetMap's Simple 3D Buildings scheme (S3DB) tags them.

A footprint with a height is a flat-roofed block; S3DB adds ``roof:shape``, ``roof:height`` (else
``roof:levels`` or ``roof:angle``) and ``roof:direction`` / ``roof:orientation``. The fold encoding
sees a gabled house and a flat block as different shapes, so the commonest shapes are built:

- ``pyramidal``: walls to the eaves, a triangle from each wall's top to an apex over the
  footprint's centroid (star-shaped footprints: convex ones, and most others);
- ``skillion``: one sloping plane, lowest at the side ``roof:direction`` (degrees clockwise from
  north, the way the roof faces) points to, the walls up to it;
- ``gabled`` and ``hipped`` (four-cornered convex footprints): a ridge along the longer sides
  (across them with ``roof:orientation=across``) between the short sides' midpoints, gable walls
  of five corners; a hipped roof's ridge is shortened by half the short side at each end (a
  pyramid where that leaves none);
- ``half-hipped`` (the same footprints, and wings, below): a gabled roof whose gables are hipped
  above :data:`HALF_HIP_SHARE` of the roof's height, the hips at the roof's pitch;
- ``hipped`` on any other simple footprint (an L, a T, a courtyard-less block of many corners): the
  straight skeleton's roof (every face rising from its wall at one pitch; py-straight-skeleton),
  checked (each face holds its wall's edge, lies in the plane through it at the pitch, and the faces
  tile the footprint) and modelled flat where the skeleton fails that;
- ``gabled``, ``gambrel``, ``round`` and ``half-hipped`` on a footprint with courtyards (a perimeter
  block: no wing end to hold a gable): the skeleton's ridges round the courtyards with the shape's
  profile (gabled and half-hipped: the hipped roof);
- ``mansard`` on any simple footprint, courtyards included: the hipped roof with the gambrel's
  bend (:data:`MANSARD`: steep from the walls to three quarters of the height half way in, shallow
  above), each skeleton face cut where its height's profile bends;
- ``gabled``, ``gambrel``, ``round`` and ``half-hipped`` on any other simple footprint with wings
  (an L, a T, a U, a stepped block, traced not quite square): the hipped roof with a gable at the
  end of each wing (the hip's apex moved out along the ridge onto the end wall, the wall rising to
  it; half-hipped: to half its height, a hip above), the valleys where wings meet kept, the height
  the shape's profile of the way in to the ridge (:func:`_half_profile`; faces cut where it
  bends); wing ends not square to their sides keep their hips;
- the same on a footprint without wing ends (a round or many-sided one), and ``saltbox`` on any: a
  roof whose height is a profile across one ridge line (along the footprint's minimum rotated
  rectangle, across it with ``roof:orientation=across``), the footprint cut into strips where the
  profile bends, each strip one plane, the walls rising to the profile (OSM2World's reading of a
  gable on a footprint that is not a rectangle);
- ``dome`` and ``onion`` (star-shaped footprints, as ``pyramidal``): rings of the footprint scaled
  about its centroid up a quarter circle (an onion's bulb: out, then in to its tip).

The functions take a footprint ring in any planar coordinates (longitude and latitude included:
every point they place is an affine combination of the corners, computed in those coordinates) and
the metres per unit of each axis, for the lengths and directions that decide the shape.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ALIASES", "OVERTURE", "SHAPES", "UNBUILT", "roof_faces", "roof_height", "roof_tags"]

#: The roof shapes built (others are modelled flat by the caller).
SHAPES = ("pyramidal", "skillion", "gabled", "hipped", "half-hipped", "gambrel", "saltbox", "round", "dome", "onion",
          "mansard")
#: Starts of the outer ring a straight skeleton is tried from before a roof is modelled flat (:func:`_skeleton_hipped`),
#: on footprints of at most this many corners.
SKELETON_TRIES = 8
SKELETON_RETRY_CORNERS = 200
#: The shapes built on a footprint with courtyards (their straight skeleton's; the others need a simple polygon). A
#: perimeter block has no wing end to hold a gable: gabled, gambrel, round and half-hipped are the skeleton's ridges
#: round the courtyards with the shape's profile (:data:`RIDGED_ROUND_COURTYARDS`; gabled and half-hipped: hipped).
ROUND_COURTYARDS = ("hipped", "mansard", "gabled", "gambrel", "round", "half-hipped")
#: Of those, the shapes whose gables a courtyard block has no place for (said in the building's notes).
RIDGED_ROUND_COURTYARDS = ("gabled", "gambrel", "round", "half-hipped")
#: The most corners (courtyards' included) a hipped roof's straight skeleton is computed for: it takes about
#: n^2 time in Python (256 corners 0.4 s, 1,000 corners 6 s); beyond, the roof is modelled flat.
MAX_SKELETON_CORNERS = 400
#: Other spellings of the shapes in the wild (OpenStreetMap's variants, Overture's underscores), read as the shape;
#: a cone (a round tower's roof) is a pyramid over its many corners.
ALIASES = {"half_hipped": "half-hipped", "halfhipped": "half-hipped", "half hipped": "half-hipped",
           "gable": "gabled", "hip": "hipped", "pyramid": "pyramidal", "cone": "pyramidal", "conical": "pyramidal",
           "domed": "dome", "barrel": "round", "arched": "round", "lean_to": "skillion", "lean-to": "skillion",
           "mono-pitched": "skillion", "monopitch": "skillion"}
#: Overture Maps' columns (and GeoJSON properties) for the S3DB roof tags: its buildings carry ``roof_shape``,
#: ``roof_height``, ``roof_direction`` and ``roof_orientation``; the others are read too where a data set spells
#: the S3DB keys so.
OVERTURE = {"roof_shape": "roof:shape", "roof_height": "roof:height", "roof_levels": "roof:levels",
            "roof_angle": "roof:angle", "roof_direction": "roof:direction", "roof_orientation": "roof:orientation"}
#: Why :func:`roof_faces` gives None for a shape on a footprint, for the caller's note.
UNBUILT = {
    "pyramidal": "its apex over the corners' mean does not see every wall",
    "dome": "its tip over the corners' mean does not see every wall",
    "onion": "its tip over the corners' mean does not see every wall",
    "skillion": "a footprint of no area",
    "gabled": "not a simple polygon, or its cut into strips failed its check",
    "gambrel": "not a simple polygon, or its cut into strips failed its check",
    "saltbox": "not a simple polygon, or its cut into strips failed its check",
    "round": "not a simple polygon, or its cut into strips failed its check",
    "hipped": f"its straight skeleton could not be computed or failed its check, or more than {MAX_SKELETON_CORNERS} "
              "corners",
    "half-hipped": "no wing end square to its sides (four convex corners, or the straight skeleton's wings)",
}
UNBUILT["mansard"] = UNBUILT["hipped"]
#: The pitch of a roof whose height is not tagged (degrees): a common pitched roof.
DEFAULT_PITCH_DEG = 30.0
#: Corners of the footprints a gabled or hipped roof is built on by its short sides' midpoints.
QUAD = 4
#: A hip becomes a gable (gabled, gambrel and round roofs on wings) where its wall is within this many degrees of
#: square to the walls beside it: a wing's end as traced footprints draw it, not a corner cut at 45 degrees.
GABLE_SQUARE_DEG = 20.0
#: The share of a half-hipped roof's height its hips take (the gable walls rise to the rest).
HALF_HIP_SHARE = 0.5
#: Profiles across the ridge line: (distance from the ridge line as a fraction of the farthest
#: corner's, signed; height as a fraction of the roof's), knots in order, eaves at 0 on both sides.
#: A gambrel bends at half the half-width, three quarters up (a barn); a saltbox's ridge stands a
#: third of the width from one side.
PROFILES = {
    "gabled": ((-1.0, 0.0), (0.0, 1.0), (1.0, 0.0)),
    "gambrel": ((-1.0, 0.0), (-0.5, 0.75), (0.0, 1.0), (0.5, 0.75), (1.0, 0.0)),
    "saltbox": ((-1.0, 0.0), (-1.0 / 3.0, 1.0), (1.0, 0.0)),
}
#: A mansard roof's profile: (distance in from the walls as a fraction of the farthest, the straight skeleton's
#: greatest time; height as a fraction of the roof's), knots in order: the gambrel's half, from the eaves to the top.
MANSARD = ((0.0, 0.0), (0.5, 0.75), (1.0, 1.0))
#: Segments of a round (barrel) roof's half circle, and of a dome's or onion's quarter circle.
CURVE_SEGMENTS = 8
#: An onion dome's outline: (scale of the footprint about its centroid, height as a fraction of the
#: roof's), from the eaves up to the tip (a bulb a third wider than its drum at a quarter height).
ONION = ((1.0, 0.0), (1.25, 0.12), (1.33, 0.25), (1.25, 0.38), (1.0, 0.5), (0.68, 0.62), (0.4, 0.74), (0.18, 0.86),
         (0.0, 1.0))
#: How far (in the ridge's frame, whose unit is the footprint's half-width) a corner may lie from a knot's line to be
#: on it, and a point cut by the profile from the ring with its cuts to be that point; beyond, the cut failed and the
#: roof is modelled flat.
SNAP_REL = 1e-7
#: A footprint's corner less than this many metres off the line through its neighbours is on it (and dropped before a
#: roof is built): OpenStreetMap keeps 1e-7 degrees (about 1 cm), and a row house's wall holds the corners of the
#: houses next door. A round tower drawn with more corners than that needs keeps fewer (a circle of 20 m radius in
#: 400 corners, 2.4 mm off, in 100: the roof 1 cm off the circle at most).
STRAIGHT_M = 0.01
#: Numerical tolerance of the roofs' checks: heights and areas (relative to the footprint's extent and area).
CHECK_REL = 1e-6


def roof_tags(props: dict) -> dict:
    """A feature's roof attributes under their S3DB keys (``roof:shape``, ``roof:height``, ...):
    OpenStreetMap's own, else Overture's (:data:`OVERTURE`), else one spelled otherwise in case and
    punctuation alone (``ROOF_SHAPE``, ``roofShape``: :func:`meshsom.geojson.folded_key`); values as
    given, None-valued ones (a GeoParquet column's nulls) left out."""
    from meshsom.geojson import folded_key

    found = {key: props[key] for key in OVERTURE.values() if props.get(key) is not None}
    for column, key in OVERTURE.items():
        if key not in found and props.get(column) is not None:
            found[key] = props[column]
    if len(found) < len(OVERTURE):
        folded = {}
        for k, v in props.items():
            if v is not None:
                folded.setdefault(folded_key(k), v)
        for key in OVERTURE.values():
            if key not in found and folded_key(key) in folded:
                found[key] = folded[folded_key(key)]
    return found


def roof_height(shape: str, ring: np.ndarray, scale: tuple[float, float], tags: dict, storey_height: float,
                number, length=None) -> float:
    """The roof's height (metres from eaves to top): ``roof:height``, else ``roof:levels`` x
    ``storey_height`` (where above 0: no storey in the roof is no flat roof), else the height of a roof pitched at
    ``roof:angle`` (else
    :data:`DEFAULT_PITCH_DEG`) over half the footprint's width (its whole width for a skillion; a
    dome and a round roof: half the width, a half circle; an onion: the width).

    Parameters
    ----------
    ring : (K, 2) float64
        The footprint, not closed.
    scale : (2,)
        Metres per unit of x and y.
    number : callable
        Reads a tag value as a number (``meshsom.geojson._number``), None where it is none.
    length : callable, optional
        Reads ``roof:height`` in the height's unit (:class:`meshsom.geojson.HeightUnits`); default ``number``.
    """
    height = _loosely(length or number, tags.get("roof:height"))
    if height is not None:
        return max(float(height), 0.0)
    levels = _loosely(number, tags.get("roof:levels"))
    if levels is not None and levels > 0:  # roof:levels=0 (no storey in the roof, common) says nothing of its height
        return float(levels) * storey_height
    metric = ring * np.asarray(scale, np.float64)
    width = _width(metric)
    if shape in ("dome", "round"):  # a half circle across it
        return width / 2
    if shape == "onion":
        return width
    angle = _loosely(number, tags.get("roof:angle"))
    pitch = math.radians(float(angle) if angle is not None and 0 < angle < 90 else DEFAULT_PITCH_DEG)
    return math.tan(pitch) * (width if shape == "skillion" else width / 2)


def _loosely(read, value) -> float | None:
    """A tag's number as ``read`` reads it, else as an estimate (:func:`meshsom.geojson.loose_number`: ``~3``,
    ``ca. 30``, ``2-4``: its middle) with each number read by ``read``; None where it is neither."""
    from meshsom.geojson import loose_number

    number = read(value)
    if number is None:
        loose = loose_number(value, read)
        number = None if loose is None else loose[0]
    return number


#: What a roof tag left unread stands for, said after its value (:func:`roof_readings`).
UNREAD = {"roof:height": "the roof's default height", "roof:levels": "the roof's default height",
          "roof:angle": f"the default pitch, {DEFAULT_PITCH_DEG:g} degrees",
          "roof:direction": "the default direction, down towards the longest wall"}


def roof_readings(tags: dict) -> list[str]:
    """Notes on how :func:`roof_height` and :func:`roof_direction` read a roof's tags (:func:`roof_tags`): each given
    as an estimate (``roof:height = '~3' is approximate: read as 3``), and each that is no number, named with what
    stands in for it (``roof:height = 'abc' is not a number: the roof's default height``); none for a flat roof."""
    from meshsom.geojson import _number, loose_number

    tagged = str(tags.get("roof:shape", "flat")).strip().lower()
    if ALIASES.get(tagged, tagged) in ("flat", ""):
        return []
    notes = []
    for key, said in UNREAD.items():
        value = tags.get(key)
        if not isinstance(value, str) or not value.strip() or _number(value) is not None:
            continue
        if key == "roof:direction" and value.strip().upper() in _cardinal():
            continue
        loose = loose_number(value, _number)
        notes.append(f"{key} = {value!r} {loose[1]}" if loose is not None else f"{key} = {value!r} is not a number"
                     + (" or a compass point" if key == "roof:direction" else "") + f": {said}")
    return notes


def _cardinal() -> dict:
    from meshsom.geojson import CARDINAL

    return CARDINAL


def roof_direction(value) -> float | None:
    """``roof:direction`` in degrees clockwise from north: a compass point (``NNE``), a number (``45``) or an estimate
    of one (``~90``, ``80-100``: :func:`meshsom.geojson.loose_number`); None where it is none of these."""
    from meshsom.geojson import _number

    if value is None:
        return None
    degrees = _cardinal().get(str(value).strip().upper())
    return degrees if degrees is not None else _loosely(_number, value)


def _width(metric: np.ndarray) -> float:
    """The footprint's width: its extent across the direction of its longest edge (metres)."""
    edges = np.roll(metric, -1, axis=0) - metric
    longest = edges[np.argmax(np.linalg.norm(edges, axis=1))]
    across = np.array([-longest[1], longest[0]]) / max(float(np.linalg.norm(longest)), 1e-12)
    return float(np.ptp(metric @ across))


def roof_faces(ring: np.ndarray, z0: float, z_eaves: float, z_top: float, shape: str, scale: tuple[float, float],
               direction_deg: float | None = None, across: bool = False,
               holes: tuple | list = ()) -> list[np.ndarray] | None:
    """The faces of a block of footprint ``ring`` from ``z0`` to its eaves with a roof of ``shape``
    up to ``z_top``: each (n, 3) float64, counter-clockwise seen from outside; None where the shape
    cannot be built on this footprint (the caller models it flat).

    Parameters
    ----------
    ring : (K, 2) float64
        The footprint's outer ring, not closed, either orientation, no holes.
    z0, z_eaves, z_top : float
        Its base, eaves and top, ``z0 < z_eaves <= z_top``.
    shape : str
        One of :data:`SHAPES`.
    scale : (2,)
        Metres per unit of x and y.
    direction_deg : float, optional
        Skillion: the way the roof faces, degrees clockwise from north (default: across the
        longest edge, down towards it).
    across : bool
        Gabled, hipped, half-hipped, gambrel, saltbox, round: the ridge across the longer sides (four convex corners;
        on wings, gabled, gambrel and round are then cut in strips across one ridge: the wings decide the ridges).
    holes : sequence of (H, 2) float64
        Courtyards, each a ring (not closed, either orientation): the shapes of :data:`ROUND_COURTYARDS` are built
        round them (the skeleton of the footprint with its holes); the other shapes are not (None).
    """
    import shapely

    ring = _tidy(ring, scale)
    if ring is None or not z0 < z_eaves <= z_top:
        return None
    holes = [_tidy(hole, scale) for hole in holes]
    if any(hole is None for hole in holes):
        return None
    metric = ring * np.asarray(scale, np.float64)
    if not shapely.Polygon(metric, [hole * np.asarray(scale, np.float64) for hole in holes]).is_valid:
        return None  # crossing itself (a bow tie), or courtyards crossing it
    area = 0.5 * float(np.sum(metric[:, 0] * np.roll(metric[:, 1], -1) - np.roll(metric[:, 0], -1) * metric[:, 1]))
    if area == 0:
        return None
    if area < 0:  # counter-clockwise seen from above
        ring, metric = ring[::-1].copy(), metric[::-1].copy()
    if len(holes):
        inner = []
        for hole in holes:
            m = hole * np.asarray(scale, np.float64)
            clockwise = np.sum(m[:, 0] * np.roll(m[:, 1], -1) - np.roll(m[:, 0], -1) * m[:, 1]) < 0
            inner.append(hole if clockwise else hole[::-1].copy())
        if shape not in ROUND_COURTYARDS:
            return None
        profile = MANSARD if shape == "mansard" else _half_profile(shape) if shape in ("gambrel", "round") else None
        return _skeleton_hipped([ring] + inner, scale, z0, z_eaves, z_top, profile)
    if shape == "skillion":
        return _skillion(ring, metric, z0, z_eaves, z_top, direction_deg)
    if shape == "pyramidal":
        return _pyramid(ring, metric, z0, z_eaves, z_top)
    if shape in ("gabled", "hipped", "half-hipped") and len(ring) == QUAD and _convex(metric):
        hip = {"gabled": 0.0, "hipped": 1.0, "half-hipped": HALF_HIP_SHARE}[shape]
        return _ridged(ring, metric, z0, z_eaves, z_top, hip, across)
    if shape == "hipped":
        return _skeleton_hipped([ring], scale, z0, z_eaves, z_top)
    if shape == "half-hipped":  # (across: the ridge's way is the wings')
        return _skeleton_hipped([ring], scale, z0, z_eaves, z_top, gables=True, hip=HALF_HIP_SHARE)
    if shape in ("gabled", "gambrel", "round") and not (len(ring) == QUAD and _convex(metric)) and not across:
        gabled = _skeleton_hipped([ring], scale, z0, z_eaves, z_top, _half_profile(shape), gables=True)
        if gabled is not None:
            return gabled
    if shape == "mansard":
        return _skeleton_hipped([ring], scale, z0, z_eaves, z_top, MANSARD)
    if shape in PROFILES:
        return _profiled(ring, metric, z0, z_eaves, z_top, np.array(PROFILES[shape]), across)
    if shape == "round":
        angle = np.linspace(np.pi, 0.0, CURVE_SEGMENTS + 1)
        return _profiled(ring, metric, z0, z_eaves, z_top, np.column_stack([np.cos(angle), np.sin(angle)]), across)
    if shape in ("dome", "onion"):
        if shape == "dome":
            angle = np.linspace(0.0, np.pi / 2, CURVE_SEGMENTS + 1)
            outline = np.column_stack([np.cos(angle), np.sin(angle)])
        else:
            outline = np.array(ONION)
        return _domed(ring, metric, z0, z_eaves, z_top, outline)
    return None


def _tidy(ring, scale) -> np.ndarray | None:
    """A footprint ring (or courtyard) without what real data adds to it: the closing point, points repeated, corners
    less than :data:`STRAIGHT_M` off the line through their neighbours (nodes shared with a row house next door), and
    spikes out and back (their tip's neighbours within :data:`STRAIGHT_M`); (K, 2) in the ring's units, None where fewer than 3 corners are left. One corner at
    a time (never two neighbours in one pass), until none is left to drop."""
    ring = np.asarray(ring, np.float64)[:, :2]
    if len(ring) >= 2 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]
    metric = ring * np.asarray(scale, np.float64)
    keep = np.arange(len(ring))
    while len(keep) >= 3:
        p = metric[keep]
        before, after = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
        chord = after - before
        length = np.linalg.norm(chord, axis=1)
        offset = np.abs((p[:, 0] - before[:, 0]) * chord[:, 1] - (p[:, 1] - before[:, 1]) * chord[:, 0])
        repeated = np.linalg.norm(p - before, axis=1) <= STRAIGHT_M
        drop = repeated | (length <= STRAIGHT_M) | (offset <= STRAIGHT_M * np.maximum(length, 1e-300))
        if not drop.any():
            break
        chosen = np.zeros(len(keep), bool)
        for i in np.flatnonzero(drop):  # never two neighbours at once
            if not chosen[i - 1] and not (i == len(keep) - 1 and chosen[0]):
                chosen[i] = True
        keep = keep[~chosen]
    return ring[keep] if len(keep) >= 3 else None


def _half_profile(shape: str) -> np.ndarray | None:
    """A symmetric profile's half from the eaves to the ridge as (share of the way in, height as a fraction of the
    roof's) knots, the profile of a skeleton roof with gables (None: a gabled roof's straight slopes)."""
    if shape == "gabled":
        return None
    if shape == "round":
        angle = np.linspace(np.pi, np.pi / 2, CURVE_SEGMENTS // 2 + 1)
        return np.column_stack([1.0 + np.cos(angle), np.sin(angle)])
    knots = np.array(PROFILES[shape])
    knots = knots[knots[:, 0] <= 0]
    return np.column_stack([knots[:, 0] + 1.0, knots[:, 1]])


def _floor_and_walls(ring: np.ndarray, z0: float, tops: np.ndarray) -> list[np.ndarray]:
    """The floor (facing down) and a wall under each edge up to the corners' ``tops``."""
    n = len(ring)
    faces = [np.column_stack([ring[::-1], np.full(n, z0)])]
    for i in range(n):
        j = (i + 1) % n
        faces.append(np.array([[*ring[i], z0], [*ring[j], z0], [*ring[j], tops[j]], [*ring[i], tops[i]]]))
    return faces


def _convex(metric: np.ndarray) -> bool:
    d = np.roll(metric, -1, axis=0) - metric
    cross = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
    return bool((cross > 0).all())


def _pyramid(ring, metric, z0, z_eaves, z_top) -> list[np.ndarray] | None:
    return _domed(ring, metric, z0, z_eaves, z_top, np.array([[1.0, 0.0], [0.0, 1.0]]))


def _skillion(ring, metric, z0, z_eaves, z_top, direction_deg) -> list[np.ndarray]:
    if direction_deg is None:  # down towards the longest edge, across it
        d = np.roll(metric, -1, axis=0) - metric
        k = int(np.argmax(np.linalg.norm(d, axis=1)))
        down = np.array([d[k, 1], -d[k, 0]])  # outward of a counter-clockwise ring
    else:
        angle = math.radians(direction_deg)
        down = np.array([math.sin(angle), math.cos(angle)])
    down = down / max(float(np.linalg.norm(down)), 1e-12)
    along = metric @ down
    span = float(np.ptp(along))
    tops = z_top - (z_top - z_eaves) * ((along - along.min()) / span if span > 0 else 0.0)
    faces = _floor_and_walls(ring, z0, tops)
    faces.append(np.column_stack([ring, tops]))
    return faces


def _ridged(ring, metric, z0, z_eaves, z_top, hip: float, across: bool) -> list[np.ndarray]:
    """A ridge between the short sides' midpoints; ``hip`` the share of the roof's height hipped at each end (0:
    gabled, 1: hipped, between: half-hipped, the gable walls up to where the hips start)."""
    lengths = np.linalg.norm(np.roll(metric, -1, axis=0) - metric, axis=1)
    short_first = lengths[0] + lengths[2] <= lengths[1] + lengths[3]  # edges 0-1 and 2-3 are the short sides
    if across:
        short_first = not short_first
    k = 0 if short_first else 1  # the short sides are edges k and k + 2
    order = [(k + i) % QUAD for i in range(QUAD)]
    c, m = ring[order], metric[order]  # short sides c0-c1 and c2-c3
    r0, r1 = (c[0] + c[1]) / 2, (c[2] + c[3]) / 2
    walls = _floor_and_walls(c, z0, np.full(QUAD, z_eaves))
    if hip == 0.0:  # gabled: the short walls rise to the ridge (five corners); the roof is two planes
        floor, w0, w1, w2, w3 = walls
        w0 = np.array([[*c[0], z0], [*c[1], z0], [*c[1], z_eaves], [*r0, z_top], [*c[0], z_eaves]])
        w2 = np.array([[*c[2], z0], [*c[3], z0], [*c[3], z_eaves], [*r1, z_top], [*c[2], z_eaves]])
        roof = [np.array([[*c[1], z_eaves], [*c[2], z_eaves], [*r1, z_top], [*r0, z_top]]),
                np.array([[*c[3], z_eaves], [*c[0], z_eaves], [*r0, z_top], [*r1, z_top]])]
        return [floor, w0, w1, w2, w3] + roof
    m0, m1 = (m[0] + m[1]) / 2, (m[2] + m[3]) / 2
    run = float(np.linalg.norm(m1 - m0))
    inset = hip * 0.5 * float(np.linalg.norm(m[1] - m[0]) + np.linalg.norm(m[3] - m[2])) / 2
    if run <= 2 * inset * (1.0 + CHECK_REL):  # the hips meet (a square, to rounding): a pyramid, no ridge
        return _pyramid(c, m, z0, z_eaves, z_top)
    t = inset / run
    a, b = r0 + t * (r1 - r0), r1 - t * (r1 - r0)
    if hip == 1.0:
        roof = [np.array([[*c[0], z_eaves], [*c[1], z_eaves], [*a, z_top]]),
                np.array([[*c[1], z_eaves], [*c[2], z_eaves], [*b, z_top], [*a, z_top]]),
                np.array([[*c[2], z_eaves], [*c[3], z_eaves], [*b, z_top]]),
                np.array([[*c[3], z_eaves], [*c[0], z_eaves], [*a, z_top], [*b, z_top]])]
        return walls + roof
    # half-hipped: the gable walls to where the hips start, on the lines from the eaves' corners to the ridge's ends
    z_mid = z_top - hip * (z_top - z_eaves)
    q = [c[0] + (1 - hip) * (r0 - c[0]), c[1] + (1 - hip) * (r0 - c[1]),
         c[2] + (1 - hip) * (r1 - c[2]), c[3] + (1 - hip) * (r1 - c[3])]
    floor, w0, w1, w2, w3 = walls
    w0 = np.array([[*c[0], z0], [*c[1], z0], [*c[1], z_eaves], [*q[1], z_mid], [*q[0], z_mid], [*c[0], z_eaves]])
    w2 = np.array([[*c[2], z0], [*c[3], z0], [*c[3], z_eaves], [*q[3], z_mid], [*q[2], z_mid], [*c[2], z_eaves]])
    roof = [np.array([[*c[1], z_eaves], [*c[2], z_eaves], [*q[2], z_mid], [*b, z_top], [*a, z_top], [*q[1], z_mid]]),
            np.array([[*c[3], z_eaves], [*c[0], z_eaves], [*q[0], z_mid], [*a, z_top], [*b, z_top], [*q[3], z_mid]]),
            np.array([[*q[0], z_mid], [*q[1], z_mid], [*a, z_top]]),
            np.array([[*q[2], z_mid], [*q[3], z_mid], [*b, z_top]])]
    return [floor, w0, w1, w2, w3] + roof

def _domed(ring, metric, z0, z_eaves, z_top, outline: np.ndarray) -> list[np.ndarray] | None:
    """Rings of the footprint scaled about its centre by ``outline`` (K, 2) (scale, height fraction), from the
    eaves (scale 1) to a tip (scale 0): a trapezoid between two rings under each wall, triangles at the tip (a
    pyramid: the outline (1, 0), (0, 1)). None where the centre (the corners' mean) does not see every wall."""
    m_centre = metric.mean(axis=0)
    d = np.roll(metric, -1, axis=0) - metric
    if not ((d[:, 0] * (m_centre[1] - metric[:, 1]) - d[:, 1] * (m_centre[0] - metric[:, 0])) > 0).all():
        return None
    c = ring.mean(axis=0)
    n = len(ring)
    rings = [ring] + [c + s * (ring - c) for s in outline[1:-1, 0]]  # the eaves exactly the walls' tops
    heights = z_eaves + outline[:, 1] * (z_top - z_eaves)
    faces = _floor_and_walls(ring, z0, np.full(n, z_eaves))
    for k in range(len(rings) - 1):
        a, b, za, zb = rings[k], rings[k + 1], heights[k], heights[k + 1]
        faces += [np.array([[*a[i], za], [*a[(i + 1) % n], za], [*b[(i + 1) % n], zb], [*b[i], zb]]) for i in range(n)]
    last, z_last = rings[-1], heights[-2]
    faces += [np.array([[*last[i], z_last], [*last[(i + 1) % n], z_last], [*c, z_top]]) for i in range(n)]
    return faces


def _skeleton_hipped(rings: list, scale, z0, z_eaves, z_top, profile=None, gables: bool = False, hip: float = 0.0
                     ) -> list[np.ndarray] | None:
    """:func:`_skeleton_roof` of ``rings``, tried again from other corners of the outer ring where the straight
    skeleton fails (py-straight-skeleton's event order depends on where the ring starts: a union of rectangles whose
    skeleton fails from one corner builds from another), at most :data:`SKELETON_TRIES` times, and only up to
    :data:`SKELETON_RETRY_CORNERS` corners (each try takes about n^2 time)."""
    n = len(rings[0])
    tries = SKELETON_TRIES if sum(len(r) for r in rings) <= SKELETON_RETRY_CORNERS else 1
    for shift in list(dict.fromkeys([0] + [n * k // tries for k in range(1, tries)]))[:tries]:
        built = _skeleton_roof([np.roll(rings[0], -shift, axis=0)] + list(rings[1:]), scale, z0, z_eaves, z_top, profile,
                               gables, hip)
        if built is not None:
            return built
    return None


def _skeleton_roof(rings: list, scale, z0, z_eaves, z_top, profile=None, gables: bool = False, hip: float = 0.0
                   ) -> list[np.ndarray] | None:
    """A hipped roof on any footprint, courtyards included: its straight skeleton lifted (a node's height its time,
    the distance the walls' lines moved in to meet there, scaled so the highest is ``z_top``). None where the
    skeleton cannot be computed or fails its check (a face per wall, each holding its wall's edge, each node at its
    time's height above the line of its face's wall, the faces tiling the footprint).

    ``profile``: (time as a fraction of the greatest, height as a fraction of the roof's) knots (a mansard's,
    :data:`MANSARD`): the height is the profile of the time, each face cut where the profile bends (:func:`_bent`).

    ``gables``: a gabled roof: every hip that ends a wing (a triangle over its wall, its apex a node of three faces)
    becomes a gable, the apex moved out along the ridge onto the wall's line and the wall rising to it. Along the
    ridge the apex stays as far from the two side walls' lines as from each other's, so the faces beside the hip stay
    planes, exactly, on a wing whose end is not quite square to its sides or whose sides are not quite parallel (as
    traced footprints are: the ridge then rises or falls a little to the end, the highest point still the top). Hips
    that cannot are kept (a corner cut at 45 degrees keeps its small hip); None where a footprint without courtyards
    has no end that can (the caller cuts the footprint in strips instead).

    ``hip`` (with ``gables``): a half-hipped roof: each gable wall rises to ``1 - hip`` of its height, and a hip from
    there meets the ridge at the roof's pitch (a wing too short for it keeps its whole gable).

    ``rings``: the outer ring counter-clockwise, then the courtyards clockwise ((K, 2) each, ring units), so the
    footprint lies left of every edge. With courtyards the floor is the roof's faces seen from below. None, too,
    beyond :data:`MAX_SKELETON_CORNERS`."""
    from py_straight_skeleton import compute_skeleton

    scale = np.asarray(scale, np.float64)
    ring = np.concatenate(rings)
    n = len(ring)
    if n > MAX_SKELETON_CORNERS:
        return None
    starts = np.cumsum([0] + [len(r) for r in rings])
    following = np.concatenate([np.roll(np.arange(a, b), -1) for a, b in zip(starts[:-1], starts[1:])])
    metric = ring * scale
    origin = metric.mean(axis=0)
    local = metric - origin
    extent = float(np.linalg.norm(np.ptp(local, axis=0)))
    tol = CHECK_REL * extent
    try:
        skeleton = compute_skeleton(exterior=local[: starts[1]].tolist(),
                                    holes=[local[a:b].tolist() for a, b in zip(starts[1:-1], starts[2:])])
        faces = skeleton.get_faces()
        nodes = skeleton.nodes
    except Exception:  # the library fails on degenerate events in several ways (RuntimeError, ZeroDivisionError, ...)
        return None
    where = np.array([[node.position.x, node.position.y] for node in nodes], np.float64)
    time = np.array([node.time for node in nodes], np.float64)
    if len(faces) != n or not np.isfinite(where).all() or not np.isfinite(time).all() or time.max() <= 0:
        return None
    corner = np.full(len(nodes), -1, np.int64)  # each ring corner's node
    at_eaves = np.flatnonzero(np.abs(time) <= tol)
    for k in at_eaves:
        distance = np.linalg.norm(local - where[k], axis=1)
        if distance.min() > tol:
            return None
        corner[k] = int(np.argmin(distance))
    if sorted(corner[at_eaves].tolist()) != list(range(n)):
        return None
    edges = local[following] - local
    inward = np.column_stack([-edges[:, 1], edges[:, 0]]) / np.linalg.norm(edges, axis=1)[:, None]
    covered = 0.0
    rise = (z_top - z_eaves) / float(time.max())
    points = (where + origin) / scale  # back in the ring's units, its corners exactly
    points[corner >= 0] = ring[corner[corner >= 0]]
    roof, below, kept, face_walls = [], [], [], []
    seen = set()
    for face in faces:
        face = [int(i) for i in face]
        if len(face) > 1 and face[0] == face[-1]:  # closed: its first node repeated
            face = face[:-1]
        on_ring = {int(corner[i]) for i in face if corner[i] >= 0}
        wall = next((i for i in on_ring if int(following[i]) in on_ring), None)
        if wall is None or wall in seen:
            return None
        seen.add(wall)
        p = where[face]
        if np.abs((p - local[wall]) @ inward[wall] - time[face]).max() > tol:  # on its wall's plane at the pitch
            return None
        area = 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
        if area <= 0:
            return None
        covered += area
        z = z_eaves + rise * np.where(corner[face] >= 0, 0.0, time[face])
        roof.append(np.column_stack([points[face], z]))
        kept.append(face)
        face_walls.append(wall)
        below.append(np.column_stack([points[face][::-1], np.full(len(face), z0)]))
    footprint = sum(0.5 * float(np.sum(r[:, 0] * np.roll(r[:, 1], -1) - np.roll(r[:, 0], -1) * r[:, 1]))
                    for r in (local[a:b] for a, b in zip(starts[:-1], starts[1:])))
    if abs(covered - footprint) > CHECK_REL * footprint:
        return None
    walls = [w for r in rings for w in _floor_and_walls(r, z0, np.full(len(r), z_eaves))[1:]]
    if gables:
        holding = np.bincount(np.concatenate([np.asarray(face) for face in kept]), minlength=len(nodes))
        node_of = np.full(n, -1, np.int64)
        node_of[corner[corner >= 0]] = np.flatnonzero(corner >= 0)
        gabled, ends = [], []
        for k, (face, wall) in enumerate(zip(kept, face_walls)):
            apex = [i for i in face if corner[i] < 0]
            if len(face) != 3 or len(apex) != 1 or holding[apex[0]] != 3:
                continue
            c, a, b = apex[0], wall, int(following[wall])
            beside = [w for f, w in zip(kept, face_walls) if c in f and w != wall]
            ridge = [i for f in kept for i in f if c in f and i not in (a, b, c) and corner[i] < 0]
            if len(beside) != 2:
                continue
            # along the ridge (as far from the one side's wall line as from the other's: both faces stay planes) out
            # to the end wall's line: x = a + s (b - a) with d1(x) = d2(x), each d linear in s
            ab = local[b] - local[a]
            d_a = [float((local[a] - local[w]) @ inward[w]) for w in beside]
            d_ab = [float(ab @ inward[w]) for w in beside]
            if min(abs(d) for d in d_ab) < math.cos(math.radians(GABLE_SQUARE_DEG)) * float(np.linalg.norm(ab)):
                continue  # not a wing's end: a corner cut at an angle keeps its hip
            if abs(d_ab[0] - d_ab[1]) <= CHECK_REL * float(np.linalg.norm(ab)):
                continue
            along = (d_a[1] - d_a[0]) / (d_ab[0] - d_ab[1])
            moved = local[a] + along * ab
            height = d_a[0] + along * d_ab[0]
            out = [float((moved - where[c]) @ (where[c] - where[r])) for r in set(ridge)]
            if not 0 < along < 1 or not height > 0 or any(o < -tol * tol for o in out):
                continue
            points[c] = ring[a] + along * (ring[b] - ring[a])  # the same affine point, in the ring's units
            where[c], time[c] = moved, height
            gabled.append(k)
            ends.append((wall, int(node_of[a]), c, int(node_of[b])))
        rise = (z_top - z_eaves) / float(time.max())  # a ridge rising to a wider end: the top stays the top
        for wall, _, c, _ in ends:
            walls[wall] = np.insert(walls[wall], 3, [*points[c], z_eaves + rise * time[c]], axis=0)  # a0 b0 b c a
        if not gabled and len(rings) == 1:
            return None
        kept = [face for k, face in enumerate(kept) if k not in gabled]
        if hip > 0:  # half-hipped: each gable wall up to (1 - hip) of its height, a hip at the roof's pitch above
            fresh = len(time)
            points, where = np.vstack([points, np.zeros((3 * len(ends), 2))]), np.vstack([where, np.zeros((3 * len(ends), 2))])
            time, corner = np.concatenate([time, np.zeros(3 * len(ends))]), np.concatenate([corner, np.full(3 * len(ends), -1)])
            for wall, na, c, nb in ends:
                side_a = next(f for f in kept if c in f and na in f)  # c follows a in it, and precedes b in the other
                side_b = next(f for f in kept if c in f and nb in f)
                i = side_a.index(c)
                r = side_a[(i + 1) % len(side_a)]  # the ridge's next node
                low = (1.0 - hip) * time[c]
                d_c, d_r = ((where[[c, r]] - local[wall]) @ inward[wall]).tolist()
                t = (low + d_c - time[c]) / ((time[r] - time[c]) - (d_r - d_c))  # where the hip meets the ridge
                if not 0 < t < 1:
                    continue  # a wing too short for its hip: its gable kept
                qa, qb, top = fresh, fresh + 1, fresh + 2
                fresh += 3
                for node, (u, v, f) in ((qa, (na, c, 1.0 - hip)), (qb, (nb, c, 1.0 - hip)), (top, (c, r, t))):
                    points[node] = points[u] + f * (points[v] - points[u])
                    where[node] = where[u] + f * (where[v] - where[u])
                    time[node] = (time[u] if corner[u] < 0 else 0.0) + f * (time[v] - (time[u] if corner[u] < 0 else 0.0))
                side_a[i:i + 1] = [qa, top]
                j = side_b.index(c)
                side_b[j:j + 1] = [top, qb]
                kept.append([qa, qb, top])
                walls[wall] = np.concatenate([walls[wall][:3], [[*points[qb], z_eaves + rise * time[qb]],
                                                                [*points[qa], z_eaves + rise * time[qa]]], walls[wall][-1:]])
        roof = [np.column_stack([points[face], z_eaves + rise * np.where(corner[face] >= 0, 0.0, time[face])])
                for face in kept]
    if profile is not None:
        knots = np.asarray(profile, np.float64)
        share = np.where(corner >= 0, 0.0, time / float(time.max()))
        roof = _bent(kept, points, where, share, knots, z_eaves, z_top)
        if roof is None:
            return None
        for wall, a, c, b in (ends if gables else []):  # a gable's top through the cuts of the roof's edges up to it
            rising = [bend for bend in knots[1:-1, 0] if bend + CHECK_REL < share[c]]
            top = ([[*_cut_point(points, share, b, c, bend), _lift(bend, knots, z_eaves, z_top)] for bend in rising]
                   + [[*points[c], _lift(share[c], knots, z_eaves, z_top)]]
                   + [[*_cut_point(points, share, a, c, bend), _lift(bend, knots, z_eaves, z_top)] for bend in rising[::-1]])
            walls[wall] = np.concatenate([walls[wall][:3], np.array(top), walls[wall][-1:]])
    floor = below if len(rings) > 1 else [np.column_stack([rings[0][::-1], np.full(len(rings[0]), z0)])]
    return floor + walls + roof


def _lift(share, knots: np.ndarray, z_eaves: float, z_top: float):
    """The height of a profile (``knots``: share, height as a fraction of the roof's) at ``share``."""
    return z_eaves + (z_top - z_eaves) * np.interp(share, knots[:, 0], knots[:, 1])


def _cut_point(points: np.ndarray, share: np.ndarray, a: int, b: int, level: float) -> np.ndarray:
    """The point of the edge between nodes ``a`` and ``b`` at ``share`` ``level``, computed from the lower-numbered
    node: every face (and gable wall) holding the edge gets the same floats."""
    a, b = min(a, b), max(a, b)
    f = (level - share[a]) / (share[b] - share[a])
    return points[a] + f * (points[b] - points[a])


def _bent(faces: list, points: np.ndarray, local: np.ndarray, share: np.ndarray, knots: np.ndarray, z_eaves: float,
          z_top: float) -> list[np.ndarray] | None:
    """Roof faces over skeleton faces whose height is a profile of the nodes' ``share`` of the greatest time.

    Parameters
    ----------
    faces : list of lists of int
        Each face's nodes, counter-clockwise seen from above.
    points : (N, 2) float64
        The nodes in the ring's units; ``local`` the same in metres (for the triangulation).
    share : (N,) float64
        Each node's time as a fraction of the greatest: on a face, an affine function of the position.
    knots : (K, 2) float64
        (share, height as a fraction of the roof's), shares rising from 0 to 1.

    Returns
    -------
    list of (n, 3) float64, or None
        A face lying within one stretch of the profile is kept whole, lifted; one across a bend is triangulated and
        each triangle cut at the bends into planar pieces. A cut point on an edge is computed from its end nodes in
        one order, so the faces (and triangles) sharing the edge share it exactly: the roof stays closed. None where a
        face cannot be triangulated on its own corners.
    """
    from meshsom.polygons import triangulate_polygon_2d

    bends = knots[1:-1, 0]
    tol = CHECK_REL

    def lift(s):
        return _lift(s, knots, z_eaves, z_top)

    cut: dict = {}

    def vertex(key):  # a node (a,), or the cut at bend k of the edge between nodes a < b: (a, b, k)
        if len(key) == 1:
            return points[key[0]], share[key[0]]
        if key not in cut:
            cut[key] = (_cut_point(points, share, key[0], key[1], bends[key[2]]), bends[key[2]])
        return cut[key]

    def on_edge(p, q):  # the nodes of the triangle edge that piece corners p and q lie on
        nodes = sorted(set(p[:2] if len(p) == 3 else p) | set(q[:2] if len(q) == 3 else q))
        return nodes if len(nodes) == 2 else None

    out = []
    for face in faces:
        s = share[face]
        if not any(((s < b - tol).any() and (s > b + tol).any()) for b in bends):
            out.append(np.column_stack([points[face], lift(s)]))
            continue
        _, triangles = triangulate_polygon_2d(local[face])
        if len(triangles) != len(face) - 2 or (triangles >= len(face)).any():
            return None
        for triangle in triangles:
            pieces = [[(face[i],) for i in triangle]]
            for k, b in enumerate(bends):
                split = []
                for piece in pieces:
                    lower, upper = [], []
                    for i, p in enumerate(piece):
                        q = piece[(i + 1) % len(piece)]
                        sp, sq = vertex(p)[1], vertex(q)[1]
                        if sp <= b + tol:
                            lower.append(p)
                        if sp >= b - tol:
                            upper.append(p)
                        if (sp < b - tol and sq > b + tol) or (sp > b + tol and sq < b - tol):
                            nodes = on_edge(p, q)
                            if nodes is None:  # a cut segment is level: it never crosses another bend
                                return None
                            lower.append((*nodes, k))
                            upper.append((*nodes, k))
                    split += [part for part in (lower, upper) if len(part) >= 3]
                pieces = split
            for piece in pieces:
                corners = [vertex(key) for key in piece]
                out.append(np.array([[*xy, float(lift(s))] for xy, s in corners]))
    return out


def _profiled(ring, metric, z0, z_eaves, z_top, knots: np.ndarray, across: bool) -> list[np.ndarray] | None:
    """A roof whose height is a piecewise linear profile across a ridge line on any simple footprint.

    The ridge runs through the centre of the footprint's minimum rotated rectangle along its longer side (its
    shorter one with ``across``); ``knots`` (K, 2) are (signed distance from it over the farthest corner's, height
    fraction). The footprint is cut at each knot's line into strips, each strip lifted as one plane, and every wall
    rises to the profile, bending where a knot's line crosses it. The cutting (shapely) works in the ridge's frame,
    the knots' lines exactly at their abscissae and the corners within :data:`SNAP_REL` of one on it, so a wall along
    a knot's line is cut along, not across; each piece's corners are then matched to the ring's, its crossings
    included. None where a piece has a corner the ring does not (the roof is modelled flat).
    """
    import shapely
    from scipy.spatial import cKDTree

    n = len(ring)
    rectangle = np.asarray(shapely.minimum_rotated_rectangle(shapely.Polygon(metric)).exterior.coords)[:4]
    sides = np.diff(np.vstack([rectangle, rectangle[:1]]), axis=0)[:2]
    long_side = int(np.argmax(np.linalg.norm(sides, axis=1)))
    along = sides[1 - long_side if across else long_side]
    along = along / np.linalg.norm(along)
    normal = np.array([-along[1], along[0]])
    centre = rectangle.mean(axis=0)
    d = (metric - centre) @ normal
    half = float(np.abs(d).max())
    if not half > 0:
        return None
    cuts, levels = knots[:, 0], z_eaves + knots[:, 1] * (z_top - z_eaves)
    u, v = d / half, -((metric - centre) @ along) / half  # the ridge's frame in half-widths (turned, not mirrored)
    nearest = np.argmin(np.abs(u[:, None] - cuts[None, :]), axis=1)
    on_cut = np.abs(u - cuts[nearest]) <= SNAP_REL
    u[on_cut] = cuts[nearest[on_cut]]  # a corner on a knot's line is on it: no crossing a rounding away

    # the ring with every crossing of a knot's line inserted: ring units, frame, heights; per edge, the top's bends
    pts, frame, zs, tops = [], [], [], []
    for i in range(n):
        j = (i + 1) % n
        pts.append(ring[i]); frame.append((u[i], v[i])); zs.append(float(np.interp(u[i], cuts, levels)))
        lo, hi = sorted((u[i], u[j]))
        inner = np.array([k for k in range(len(cuts)) if lo < cuts[k] < hi], np.int64)
        t = (cuts[inner] - u[i]) / (u[j] - u[i])
        bends = []
        for k, tk in zip(inner[np.argsort(t)], np.sort(t)):
            bends.append(len(pts))
            pts.append(ring[i] + tk * (ring[j] - ring[i])); frame.append((cuts[k], v[i] + tk * (v[j] - v[i])))
            zs.append(float(levels[k]))
        tops.append(bends)
    pts, frame, zs = np.array(pts), np.array(frame), np.array(zs)
    corner_at = np.cumsum([0] + [1 + len(b) for b in tops])[:-1]
    faces = [np.column_stack([ring[::-1], np.full(n, z0)])]
    for i in range(n):
        j = (i + 1) % n
        top = [corner_at[j]] + tops[i][::-1] + [corner_at[i]]
        faces.append(np.vstack([[*ring[i], z0], [*ring[j], z0], np.column_stack([pts[top], zs[top]])]))
    footprint = shapely.Polygon(frame)
    if not footprint.is_valid:
        return None
    tree = cKDTree(frame)
    span = 2.0 * float(np.abs(frame).max()) + 1.0
    covered = 0.0
    for k in range(len(cuts) - 1):  # the outermost strips reach beyond the footprint (no cut along its farthest walls)
        a = cuts[k] if k > 0 else -span
        b = cuts[k + 1] if k < len(cuts) - 2 else span
        strip = shapely.box(a, -span, b, span)
        for piece in shapely.get_parts(shapely.intersection(footprint, strip)):
            if piece.geom_type != "Polygon" or piece.area <= 0:
                continue
            distance, index = tree.query(np.asarray(piece.exterior.coords)[:-1])
            if distance.max() > SNAP_REL * span:
                return None
            index = _without_backtracks(index, frame)
            if len(index) < 3:
                continue
            p = frame[index]
            area = 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
            if area < 0:
                index, area = index[::-1], -area
            covered += area
            faces.append(np.column_stack([pts[index], zs[index]]))
    if abs(covered - footprint.area) > CHECK_REL * footprint.area:
        return None
    return faces


def _without_backtracks(index: np.ndarray, points: np.ndarray) -> np.ndarray:
    """A ring of point indices without repeats and without the spikes overlay leaves along a cut: a corner whose next
    edge runs back along its previous one (zero area) is dropped, until none is."""
    ring = [int(i) for i in index]
    changed = True
    while changed and len(ring) >= 3:
        changed = False
        for k in range(len(ring)):
            a, b, c = points[ring[k - 1]], points[ring[k]], points[ring[(k + 1) % len(ring)]]
            ab, bc = b - a, c - b
            if ring[k] == ring[k - 1] or (abs(ab[0] * bc[1] - ab[1] * bc[0]) <= SNAP_REL * max(1.0, float(
                    np.abs(points).max())) ** 2 and float(ab @ bc) < 0):
                del ring[k]
                changed = True
                break
    return np.asarray(ring, np.int64)
