"""Reading buildings from GeoJSON and JSON-FG (``.geojson``, ``.fg.json``, any ``.json`` holding a
``Feature`` or ``FeatureCollection``; plain or gzipped).

Footprints with a height are the most common open building data (OpenStreetMap, Overture Maps,
national footprint layers); JSON-FG, OGC's extension of GeoJSON, adds solids. Each feature becomes
the objects the CityJSON reader works on (:func:`meshsom.io._object_meshes`), so LoD choice,
triangulation, CRS handling and rejections behave as for CityJSON:

- **Building parts** (:func:`building_parts`): footprints tagged ``building:part`` (not
  ``building``: an Overpass turbo or osmtogeojson export of buildings and their parts), and
  Overture's ``building_part`` features (``building_id`` naming a footprint of the collection),
  are read as OpenStreetMap extracts read them (:func:`meshsom.osm.building_meshes`): a building
  with parts is its parts (BuildingParts, united in preprocessing), a part without a height takes
  its building's, a part inside no outline is a building of its own, noted. Overture's parts
  downloaded to a file of their own: :mod:`meshsom.part_files`.
- **JSON-FG solids**: a feature's ``place`` of type ``Polyhedron`` (shells of polygons) or
  ``MultiPolyhedron`` is a Solid or MultiSolid (LoD ``"2"``); a ``Prism`` (a ``Polygon`` or
  ``MultiPolygon`` base extruded from ``lower``, default 0, to ``upper``) is a Solid (LoD ``"1"``).
- **GeoJSON footprints**: a ``Polygon`` or ``MultiPolygon`` (``place``, else ``geometry``) with a
  height property (:attr:`meshsom.io.ReaderOptions.height_attributes`: ``height``,
  ``measuredHeight``, ``building:height``; numbers or text such as ``"12.5 m"``; an estimate, ``~10``, ``>10``,
  ``10-12``, is read as its number, its bound, the range's middle, noted: :func:`loose_number`; text that is no number
  is named with its value where the footprint is refused) is extruded, as
  OpenStreetMap's and Overture's buildings mean it, from ground + ``min_height`` (else storeys below it,
  ``building:min_level`` or ``min_floor``, times its walls' own storey height where a height, a storey count and its
  roof's height give it, :func:`meshsom.osm.level_base`, else ``storey_height``; 0 when absent) to
  ground + height, the ground being the footprint's lowest z (0 for a 2D footprint) (LoD ``"1"``);
  without a height, a storey count (``building:levels``, ``num_floors``) times ``storey_height``
  (3 m) is used, with a note; without either, :attr:`meshsom.io.ReaderOptions.default_height`
  where it is set (else a rejection).
- **Roofs**: a footprint whose properties give a roof shape (OpenStreetMap's ``roof:shape``,
  ``roof:height``, ...; Overture's ``roof_shape``, ``roof_height``, ...; osmtogeojson's tags nested
  under ``tags`` read as properties) gets it up to its height (:func:`roofed_solid`,
  :mod:`meshsom.roofs`; LoD ``"2"``), unless :attr:`meshsom.io.ReaderOptions.roofs` is off.
- A 3D ``Polygon`` / ``MultiPolygon`` without any height is read as a MultiSurface (LoD ``"2"``):
  a solid written as its faces.
- **CRS** (:mod:`meshsom.crs`): ``place`` is in the JSON-FG ``coordRefSys`` (the feature's, else the
  collection's); ``geometry`` is WGS 84 longitude, latitude (RFC 7946: ``OGC:CRS84h``) unless an
  old-style ``crs`` member names another, or its coordinates go beyond +/-180 (projected data
  written without one: then :attr:`meshsom.io.ReaderOptions.crs`, else metres).
- Ids are ``name#<feature id>`` (``name#feature-<N>``, N counted from 1, for a feature without
  one); a label is the property :attr:`meshsom.io.ReaderOptions.label_attribute`.
- Any other feature (a road's LineString, no geometry) is a rejection that says what it holds.
"""

from __future__ import annotations

import functools
import math
import re
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: Coordinates beyond this (in any CRS unit) are refused: no building lies there, and float64
#: sums of such values lose their metres.
MAX_COORDINATE = 1e12
#: The CRS of GeoJSON ``geometry`` (RFC 7946): longitude, latitude, ellipsoidal height.
GEOJSON_CRS = "OGC:CRS84h"
#: A number and what follows it: a unit (letters, a degree sign, an inch mark), a full stop, and after a ``;`` or ``|``
#: further values (OpenStreetMap's lists: the first is read).
_NUMBER = re.compile(r"""^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z\u00b0"']*)\.?\s*(?:[;|].*)?$""")
#: A length in feet (and inches), as OpenStreetMap allows it: 40', 40 ft, 12'6", 12' 6".
_FEET = re.compile(r"""^\s*(\d+(?:\.\d+)?)\s*(?:'|ft\b|feet\b|foot\b)\s*(?:(\d+(?:\.\d+)?)\s*(?:"|''|in\b|inch(?:es)?\b))?\s*$""", re.I)
#: A decimal comma (12,5: common in European OpenStreetMap data, though its wiki asks for a point).
_DECIMAL_COMMA = re.compile(r"^\s*([-+]?\d+),(\d+)\s*(?:m\b.*)?$")
#: Signs and words before a number that say it is approximate (``~10``, ``ca. 10``, ``approx 10``): read as the
#: number, noted (:func:`loose_number`).
APPROXIMATE = re.compile(r"^\s*(?:~|\u2248|ca\.?|circa|c\.|approx\.?|approximately|about|around|env\.?|etwa)\s*(?=[\d.])",
                         re.I)
#: Signs before a number that say it is a bound (``>10``, ``<=12``): read as the bound, noted.
BOUND = re.compile(r"^\s*(>=|<=|\u2265|\u2264|>|<)\s*(?=[\d.])")
#: A range of two numbers (``10-12``, ``10 - 12 m``, ``10\u201312``, ``10 to 12``, ``10..12``), the first perhaps with a
#: unit of its own (else the second's): read as its middle, noted.
RANGE = re.compile(r"^\s*(\d+(?:[.,]\d+)?)\s*([a-zA-Z]*)\s*(?:-|\u2013|\u2014|to\b|\.\.)\s*(\d+(?:[.,]\d+)?)\s*([a-zA-Z]*\.?)\s*$",
                   re.I)
#: How a height or storey count that is none of these is said in a rejection or a note (:func:`unread_numbers`).
NOT_A_NUMBER = "is not a number"
#: Attribute names whose folded form (:func:`folded_key`) is remembered: a layer's columns, many times over.
FOLDED_KEYS_CACHED = 4096
#: Metres per foot and per inch.
FOOT, INCH = 0.3048, 0.0254
#: The units a number may be written with (lower case), as the factor that makes it metres (lengths) or leaves it
#: as it is (degrees, and no unit); any other word after a number (``3 storeys``) makes it no length.
UNIT_FACTORS = {"": 1.0, "m": 1.0, "metre": 1.0, "metres": 1.0, "meter": 1.0, "meters": 1.0, "cm": 0.01, "mm": 0.001,
                "km": 1000.0, "in": INCH, "inch": INCH, "inches": INCH, '"': INCH, "''": INCH, "yd": 0.9144,
                "yard": 0.9144, "yards": 0.9144, "\u00b0": 1.0, "deg": 1.0, "degree": 1.0, "degrees": 1.0}
#: Properties that say a footprint lies underground (OpenStreetMap's ``location``, Overture's ``is_underground``), and
#: their values that say so (lower case).
UNDERGROUND = {"location": ("underground",), "is_underground": ("true", "1", "yes")}
#: The most storeys a storey count (``building:levels``, ``building:min_level``, ``num_floors``) may give: the tallest
#: building, the Burj Khalifa, has 163 above the ground (the Jeddah Tower is planned with 167). A count above it
#: (``building:levels=1e3``, a typo or a count of flats: a 3 km tower) is refused, naming its value.
MAX_STOREYS = 200
#: The largest share of a building's height its roof takes where the roof is lower than the height (the walls keep
#: the rest, at least 5 %: no sliver of a wall), the roof cut to it, noted; a roof as high as the height, or higher,
#: takes all of it, no walls (a roof storey on the part below it: :func:`roofed_solid`).
MAX_ROOF_SHARE = 0.95
#: A roof's height within this share of its footprint's height is the height (a base and a top written to 6 digits).
WHOLE_HEIGHT_REL = 1e-6
#: Words in a property's name (lower case, letters only) that say it may hold a building's height, in the languages of
#: national footprint layers (:func:`height_candidates`), and a storey count.
HEIGHT_WORDS = ("height", "hgt", "hoehe", "hohe", "hauteur", "altezza", "altura", "hoogte", "wysokosc", "korkeus", "hojd",
                "hojde", "hoyde")
STOREY_WORDS = ("storey", "stories", "floors", "levels", "etages", "geschoss", "plantas", "piani", "bouwlagen",
                "kondygnac", "verdieping", "kerros")
#: ... and those that say it is some other height: a roof's own, a base's, one below the ground, a count of flats.
NOT_HEIGHT_STARTS = ("roof", "min", "base", "ground")
NOT_HEIGHT_WORDS = ("bg", "below", "under", "unter", "sous", "minimum")
#: The endings of a height's name that say it is in a unit :attr:`meshsom.io.ReaderOptions.height_unit` has not.
UNIT_ENDINGS = {"cm": "centimetres", "mm": "millimetres", "dm": "decimetres"}
#: A footprint whose outer rings enclose at most (this x its extent)^2 encloses no area (:func:`_encloses_area`).
FLAT_FOOTPRINT_REL = 1e-9
#: How deep GeometryCollections may nest in a feature's geometry (deeper members are left out, noted).
MAX_COLLECTION_DEPTH = 16
#: The share of the area of a footprint's polygons that may be covered twice before they are read as their union
#: (:func:`valid_footprint`): parts that share a wall overlap by rounding only.
OVERLAP_REL = 1e-6
#: Shapes built as another where they cannot be built on a footprint (a half-hipped roof on one without a square wing
#: end: the hipped roof, which its hips make it most like), noted; others are flat there.
FALLBACK = {"half-hipped": "hipped"}
#: A roof's direction given as a compass point, in degrees clockwise from north.
CARDINAL = {k: 22.5 * i for i, k in enumerate(("N", "NNE", "NE", "ENE", "E", "ESE", "SE", "SSE", "S", "SSW", "SW", "WSW",
                                                 "W", "WNW", "NW", "NNW"))}


def is_esri_json(document) -> bool:
    """Whether a parsed JSON document is an Esri JSON feature set (an ArcGIS REST query's ``f=json``: features of
    ``attributes`` and ``rings``), read through GDAL's ESRIJSON driver (:func:`meshsom.gis.read_gis`)."""
    return (isinstance(document, dict) and isinstance(document.get("features"), list)
            and ("geometryType" in document or "spatialReference" in document or any(
                isinstance(f, dict) and "attributes" in f for f in document["features"][:1])))


def is_geojson(document) -> bool:
    """Whether a parsed JSON document is a GeoJSON / JSON-FG Feature or FeatureCollection."""
    return isinstance(document, dict) and document.get("type") in ("Feature", "FeatureCollection")


def _reference(value) -> str | None:
    """A CRS reference of a ``coordRefSys`` (a URI, or ``{"type": "Reference", "href": ...}``) or of
    an old GeoJSON ``crs`` member (``{"type": "name", "properties": {"name": ...}}``)."""
    if isinstance(value, str):
        return value
    if isinstance(value, dict):
        if isinstance(value.get("href"), str):
            return value["href"]
        props = value.get("properties")
        if isinstance(props, dict) and isinstance(props.get("name"), str):
            return props["name"]
    return None


def _number(value) -> float | None:
    """A property's number: 12, 12.5, "12.5", "12 m", "12,5" (a decimal comma), "40'" or "40 ft"
    (feet, in metres), "12'6\"" (feet and inches), "3600\"" (inches), "350 cm", "30 yd" (in metres), "45°", "12;15"
    (the first) as OpenStreetMap writes them; None otherwise (``3 storeys``, ``1.2 km high``: not a length)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, str):
        feet = _FEET.match(value)
        if feet:
            return float(feet.group(1)) * FOOT + float(feet.group(2) or 0) * INCH
        comma = _DECIMAL_COMMA.match(value)
        if comma:
            return float(f"{comma.group(1)}.{comma.group(2)}")
        match = _NUMBER.match(value)
        factor = UNIT_FACTORS.get(match.group(2).lower()) if match else None
        if factor is not None and math.isfinite(float(match.group(1))):
            return float(match.group(1)) * factor
    return None


def loose_number(value, read=None) -> tuple[float, str] | None:
    """A value :func:`_number` does not read that is a number all the same, as OpenStreetMap's mappers write an
    estimate: approximate (:data:`APPROXIMATE`: ``~10``, ``ca. 10``, ``approx 10``: the number), a bound
    (:data:`BOUND`: ``>10``, ``<12``: the bound) or a range (:data:`RANGE`: ``10-12``, ``3-4`` storeys: its middle,
    the estimate that is never off by more than half the range), and how it was read, in words; None otherwise.
    ``read`` reads each number (:meth:`HeightUnits.of`; default :func:`_number`)."""
    read = read or _number
    if not isinstance(value, str):
        return None
    for pattern, kind in ((APPROXIMATE, "approximate"), (BOUND, None)):
        match = pattern.match(value)
        if match:
            number = read(value[match.end():])
            if kind is None:
                kind = "a lower bound" if match.group(1) in (">", ">=", "\u2265") else "an upper bound"
            return None if number is None else (number, f"is {kind}: read as {value[match.end():].strip()}")
    match = RANGE.match(value)
    if match:
        unit = match.group(2) or match.group(4)
        numbers = [read(f"{match.group(1)} {unit}".strip()), read(f"{match.group(3)} {match.group(4)}".strip())]
        if None in numbers:
            return None
        low, high = sorted(numbers)
        middle = 0.5 * (low + high)
        said = 0.5 * (_number(match.group(1)) + _number(match.group(3)))
        return middle, f"is a range: read as its middle, {said:g}{' ' + unit if unit else ''}"
    return None


def _keys(props: dict, names) -> Iterator[str]:
    """The keys of ``props`` that ``names`` name, in the order of ``names`` (:func:`first_number`'s matching)."""
    folded = None
    for name in names:
        key = name if name in props else None
        if key is None:
            if folded is None:
                folded = {}
                for k in props:
                    folded.setdefault(folded_key(k), k)
            key = folded.get(folded_key(name))
        if key is not None:
            yield key


def first_reading(props: dict, names) -> tuple[str, float, str | None] | None:
    """As :func:`first_number`, else the first of ``names`` whose property :func:`loose_number` reads: the key, the
    number, and the note that says how it was read (None for a plain number)."""
    found = first_number(props, names)
    if found is not None:
        return found[0], found[1], None
    for key in _keys(props, names):
        loose = loose_number(props[key])
        if loose is not None:
            return key, loose[0], f"{key} = {props[key]!r} {loose[1]}"
    return None


def unread_numbers(props: dict, names) -> list[str]:
    """Notes naming the properties of ``names`` given as text that neither :func:`_number` nor :func:`loose_number`
    reads (``height = 'tall'``), each with its value."""
    return [f"{key} = {props[key]!r} {NOT_A_NUMBER}" for key in _keys(props, names)
            if isinstance(props[key], str) and props[key].strip() and _number(props[key]) is None
            and loose_number(props[key]) is None]


def first_number(props: dict, names) -> tuple[str, float] | None:
    """The first of ``names`` whose property is a number (:func:`_number`): the property's own key
    and its value; None when none is. A name matches a property of its spelling, else one that
    differs only in case and punctuation (:func:`folded_key`: a Shapefile's or an Esri layer's
    ``HEIGHT``, ``Num_Floors``; ``minHeight`` for ``min_height``; ``building_levels`` for
    ``building:levels``, as tools that allow no colon in a column's name write it)."""
    for key in _keys(props, names):
        value = _number(props.get(key))
        if value is not None:
            return key, value
    return None


@functools.lru_cache(maxsize=FOLDED_KEYS_CACHED)
def folded_key(name) -> str:
    """An attribute's name as :func:`first_number` compares it: lower case, letters and digits alone (remembered:
    a footprint's names are folded again for every attribute looked up, a third of a flat footprint's read)."""
    return re.sub(r"[^0-9a-z]", "", str(name).lower())


class FeatureVertices:
    """The vertices of one feature, appended ring by ring; indices for CityJSON-like boundaries."""

    def __init__(self):
        self.parts: list[np.ndarray] = []
        self.count = 0

    def ring(self, coords, where: str, z: float | None = None) -> list[int]:
        try:
            ring = np.asarray(coords, np.float64)
        except (TypeError, ValueError):
            raise InputFileError(where, "a ring's coordinates are not lists of numbers") from None
        if ring.ndim != 2 or ring.shape[1] not in (2, 3) or len(ring) < 3:
            raise InputFileError(where, f"a ring must be 3 or more positions of 2 or 3 numbers; received shape {ring.shape}")
        if np.array_equal(ring[0], ring[-1]):
            ring = ring[:-1]
        if z is not None:
            ring = np.column_stack([ring[:, :2], np.full(len(ring), z)])
        elif ring.shape[1] == 2:
            raise InputFileError(where, "a solid's positions need three coordinates (x, y, z)")
        if not (np.isfinite(ring).all() and np.abs(ring).max() < MAX_COORDINATE):
            raise InputFileError(where, f"coordinates must be finite numbers of magnitude below {MAX_COORDINATE:g}")
        start = self.count
        self.parts.append(ring)
        self.count += len(ring)
        return list(range(start, self.count))

    def array(self) -> np.ndarray:
        """The vertices, (V, 3) float64."""
        return np.concatenate(self.parts).reshape(-1, 3) if self.parts else np.zeros((0, 3))


def _polygons(geometry: dict, where: str) -> list:
    """The polygons (lists of rings of positions) of a Polygon or MultiPolygon."""
    coords = geometry.get("coordinates")
    if not isinstance(coords, list):
        raise InputFileError(where, f"its {geometry.get('type')} has no coordinates")
    return [coords] if geometry.get("type") == "Polygon" else coords


def _signed_area(ring: list[list[float]]) -> float:
    p = np.asarray(ring, np.float64)[:, :2]
    p = p - p.mean(axis=0)
    return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


def _extruded(polygons: list, z0: float, z1: float, where: str, verts: FeatureVertices) -> dict:
    """A Solid of footprint polygons extruded from ``z0`` to ``z1`` (outer rings counter-clockwise,
    holes clockwise, seen from above: the shell faces outward)."""
    if not z1 > z0:
        raise InputFileError(where, f"its extrusion has no height (from {z0:g} to {z1:g})")
    faces = []
    for poly in polygons:
        if not isinstance(poly, list) or not poly:
            raise InputFileError(where, "a polygon has no rings")
        rings = []
        for k, ring in enumerate(poly):
            bottom = verts.ring(ring, where, z0)
            pts = verts.array()[bottom]
            if (_signed_area(pts) > 0) != (k == 0):
                bottom, pts = bottom[::-1], pts[::-1]
            top = verts.ring(pts, where, z1)
            rings.append((bottom, top))
        faces.append([b[::-1] for b, _ in rings])  # the floor, facing down
        faces.append([t for _, t in rings])  # the roof, facing up
        for bottom, top in rings:
            n = len(bottom)
            faces += [[[bottom[i], bottom[(i + 1) % n], top[(i + 1) % n], top[i]]] for i in range(n)]
    return {"type": "Solid", "lod": "1", "boundaries": [faces]}


def no_height(options, notes=(), hint: bool = True, props: dict | None = None) -> str:
    """The reason a footprint without a height is refused (with what :func:`footprint_solid` noted:
    a height given as unknown, or as text that is no number, named with its value; ``hint``: and the options that would read it, naming the properties of ``props``
    that may hold a height or a storey count: :func:`height_candidates`)."""
    names = ", ".join(options.height_attributes + options.levels_attributes)
    if any("no storey above the ground" in n for n in notes):
        hint = False  # a count of 0 storeys is never raised to the default height: the hint would mislead
    found = height_candidates(props) if hint and props else []
    unread = [n for n in notes if n.endswith(NOT_A_NUMBER)]  # given, but not as a number (unread_numbers)
    head = (f"is a footprint without a height it can read ({'; '.join(unread)}; no other property {names} gives one)"
            if unread else f"is a footprint without a height (no property {names} gives one)")
    return (head + "".join(f"; {n}" for n in notes if n not in unread)
            + "".join(f"; its property {key} = {value:g} may be its {what}" for key, value, what in found)
            + ("; --height-attribute NAME names your data's height (--levels-attribute NAME its storey count), "
               "--default-height M (corpus.reader.default_height) extrudes such footprints to M metres" if hint else ""))


def height_candidates(props: dict, most: int = 3) -> list[tuple[str, float, str]]:
    """Properties of a footprint that no height or storey attribute names, whose names say they may hold its height
    or its storey count (:data:`HEIGHT_WORDS`, :data:`STOREY_WORDS`: URBANopt's ``number_of_stories``, the City
    Energy Analyst's ``height_ag``, the IGN's ``HAUTEUR``) and whose values are positive numbers: ``(key, value,
    what it may be and the option that reads it)``, at most ``most``, heights first. A height whose name ends in a
    unit (San Francisco's ``hgt_maxcm``: centimetres) names that unit's ``--height-unit`` too."""
    found = []
    for key, value in props.items():
        folded = re.sub(r"[^a-z]", "", str(key).lower().replace("ö", "oe").replace("ø", "o").replace("å", "a"))
        number = _number(value)
        if number is None or not number > 0 or folded.startswith(NOT_HEIGHT_STARTS) or any(
                w in folded for w in NOT_HEIGHT_WORDS):
            continue
        if any(w in folded for w in HEIGHT_WORDS):
            unit = next((end for end in UNIT_ENDINGS if folded.endswith(end)), None)
            found.append((0, str(key), number, f"height, in {UNIT_ENDINGS[unit]} by its name: --height-attribute {key} "
                                               f"--height-unit {unit}" if unit else f"height: --height-attribute {key}"))
        elif any(w in folded for w in STOREY_WORDS):
            found.append((1, str(key), number, f"storey count: --levels-attribute {key}"))
    return [f[1:] for f in sorted(found, key=lambda f: f[0])[:most]]


def footprint_solid(polygons: list, props: dict, where: str, options, verts: FeatureVertices, flat: bool = True,
                    crs=None) -> tuple[dict | None, list[str]]:
    """Footprint polygons extruded by their height property (LoD ``"1"``), as the module says, with
    the roof their roof attributes describe (:func:`roofed_solid`, LoD ``"2"``) where
    :attr:`meshsom.io.ReaderOptions.roofs` is on.

    Parameters
    ----------
    polygons : list
        Polygons as GeoJSON nests them: lists of rings of positions (2 or 3 numbers).
    props : dict
        The feature's properties.
    where : str
    options : ReaderOptions
    verts : FeatureVertices
        Receives the vertices.
    flat : bool
        Whether the polygons are a footprint (2D, or at one height): only then does
        :attr:`meshsom.io.ReaderOptions.default_height` stand in for a missing height, and is a
        roof built (3D polygons are a solid's faces).
    crs : CoordinateSystem or None
        The polygons' CRS (None: metres), for the lengths that decide a roof's shape.

    Returns
    -------
    solid : dict or None
        The CityJSON-like Solid; None when ``props`` give no height (nothing is added to ``verts``).
    notes : list of str
        Says so where the height came from a storey count, and what became of a roof.

    Raises
    ------
    InputFileError
        Where its properties say it lies underground (:data:`UNDERGROUND`): a footprint of a garage under a square
        is no block above it, whatever height stands in.
    """
    for key, values in UNDERGROUND.items():
        if str(props.get(key)).strip().lower() in values:
            raise InputFileError(where, f"lies underground ({key}={props[key]}): not a building above the ground, "
                                        "not read")
    from meshsom.osm import level_base
    from meshsom.roofs import roof_readings, roof_tags

    props, based = level_base(props, options)  # building:min_level in storeys of its walls' own height (OSM2World)
    notes: list[str] = [based] if based else []
    units = HeightUnits(crs, options)
    height = first_reading(props, options.height_attributes)
    if height is None:
        notes += unread_numbers(props, options.height_attributes)
    elif height[2] is not None:
        notes.append(height[2])
    height = height and height[:2]
    if height is not None and not height[1] > 0:  # Microsoft's footprints write -1 for "not known"
        others = first_number({k: v for k, v in props.items() if (_number(v) or 0) > 0}, options.height_attributes)
        if others is None:
            notes.append(f"{height[0]} = {height[1]:g} read as no height (a height is above 0)")
        height = others
    if height is not None:
        height = (height[0], units.of(props[height[0]]))
    storeys = None  # where the height is a storey count's: the walls' (S3DB: building:levels exclude the roof's)
    if height is None:
        levels = first_reading(props, options.levels_attributes)
        if levels is None:
            notes += unread_numbers(props, options.levels_attributes)
        elif levels[2] is not None:
            notes.append(levels[2])
        _plausible_storeys(levels, props, where)
        if levels is not None and levels[1] > 0:
            height = (levels[0], levels[1] * options.storey_height * units.per_metre)
            storeys = len(notes)
            notes.append(f"height from {levels[0]} = {levels[1]:g} storeys x {options.storey_height:g} m")
        elif levels is not None and levels[1] == 0:  # said to stand nothing above ground (a cellar, a patio, a roof
            notes.append(f"{levels[0]} = 0: no storey above the ground")  # on posts): not the default height
            return None, notes
    if height is None and flat and options.default_height is not None:
        height = ("default_height", float(options.default_height) * units.per_metre)
        notes.append(f"no height or storey count: extruded to the default {options.default_height:g} m (corpus.reader.default_height)")
    if height is None:
        return None, notes
    zs = [p[2] for poly in polygons if isinstance(poly, list) for ring in poly if isinstance(ring, list)
          for p in ring if isinstance(p, list) and len(p) > 2 and _number(p[2]) is not None]
    if flat:
        polygons, said = valid_footprint(polygons, min(zs) if zs else None)
        notes += said
        _encloses_area(polygons, where)
    bottom = first_reading(props, options.base_attributes)  # an estimate too (min_height "~3" was the ground)
    base = (units.of(props[bottom[0]]) or 0.0) if bottom else 0.0
    if bottom is None:
        notes += [f"{said}: the base is the ground" for said in unread_numbers(props, options.base_attributes)]
    below = first_reading(props, options.min_levels_attributes) if bottom is None else None
    for said in (bottom, below):
        if said is not None and said[2]:
            notes.append(said[2])
    _plausible_storeys(below, props, where)
    if below is not None and below[1] > 0:  # storeys below its bottom: a bridge's deck, an overhang
        base = below[1] * options.storey_height * units.per_metre
        notes.append(f"base from {below[0]} = {below[1]:g} storeys x {options.storey_height:g} m")
    ground = min(zs) if zs else 0.0
    z0, z1 = ground + base, ground + height[1]
    if flat and options.roofs and z1 > z0:
        solid, said = roofed_solid(polygons, props, z0, z1, crs, options, where, verts, on_walls=storeys is not None)
        if said:
            notes.append(said)
        if solid is not None:
            notes += roof_readings(roof_tags(props))  # its tags' estimates read, and values that are no number
            if storeys is not None:
                notes[storeys] = notes[storeys].replace("height from", "walls from", 1) + (
                    ", the roof above them (S3DB: storey counts leave out the roof's)")
            return solid, notes
    return _extruded(polygons, z0, z1, where, verts), notes


def _plausible_storeys(found: tuple | None, props: dict, where: str) -> None:
    """Raises where a storey count (:func:`first_reading`'s or :func:`first_number`'s ``(key, count, ...)``) is above
    :data:`MAX_STOREYS`, naming its value."""
    if found is not None and found[1] > MAX_STOREYS:
        raise InputFileError(where, f"{found[0]} = {props[found[0]]!r} is {found[1]:g} storeys, more than any building "
                                    f"has (the tallest has 163; at most {MAX_STOREYS} are read): not read")


def _encloses_area(polygons: list, where: str) -> None:
    """Raises where no outer ring of a footprint encloses any area (its corners on one line, or all one point: a
    sliver a tracer or a model left, a way drawn back on itself); extruded, it was a flat wall refused as 'one planar
    polygon ... 90 degrees from horizontal'."""
    try:
        areas = [abs(_signed_area(poly[0])) for poly in polygons if isinstance(poly, list) and poly]
        extent = max(float(np.ptp(np.asarray(poly[0], np.float64)[:, :2], axis=0).max()) for poly in polygons if poly)
    except (TypeError, ValueError, IndexError):
        return  # not rings of numbers: their reading says so
    if areas and max(areas) <= (FLAT_FOOTPRINT_REL * extent) ** 2:
        corners = sum(len(p[0]) for p in polygons if p)
        raise InputFileError(where, "has a footprint that encloses no area (" + (
            f"its {corners} corners lie on one line, {extent:.3g} units long" if extent > 0 else
            f"its {corners} corners are one point") + "): no building to extrude")


def valid_footprint(polygons: list, z: float | None = None) -> tuple[list, list[str]]:
    """Footprint polygons (GeoJSON's nesting: rings of positions) made valid where a ring crosses itself or a hole
    crosses its shell (a bow-tie way in OpenStreetMap, a spike drawn back across its outline): the areas they
    enclose (shapely's ``make_valid``; with holes, the area inside an odd number of its rings, within the shell, as
    libosmium assembles an OpenStreetMap multipolygon: inner rings that touch are taken out together, where two
    overlap an island stays), each position at ``z`` where given, and a note saying where it crossed.
    Valid polygons, and those that cannot be read as such, are returned as they are (their reading says why).

    Returns
    -------
    polygons : list
    notes : list of str
    """
    import shapely
    from shapely.geometry import Polygon

    fixed, notes, changed = [], [], False
    for poly in polygons:
        try:
            rings = [[(float(p[0]), float(p[1])) for p in ring] for ring in poly]
            if not all(math.isfinite(c) for ring in rings for p in ring for c in p):
                raise ValueError  # NaN or infinite: its reading says so
            shape = Polygon(rings[0], rings[1:])
            reason = None if shape.is_valid else shapely.is_valid_reason(shape)
            made = None
            if reason is not None and len(rings) > 1:  # the rings by the even-odd rule, within the shell (libosmium's)
                shell = shapely.make_valid(Polygon(rings[0]))
                odd = shell
                holes = {frozenset(ring): ring for ring in rings[1:]}  # a hole drawn twice (osm-testdata 795) is one
                for ring in holes.values():  # holes that touch come out together; where two overlap, an island stays
                    odd = odd.symmetric_difference(shapely.make_valid(Polygon(ring)))
                made = odd.intersection(shell)
            elif reason is not None:
                made = shapely.make_valid(shape)
        except (TypeError, ValueError, IndexError, shapely.errors.GEOSException):
            reason = None  # not a polygon of numbers: its reading says so
        if reason is None:
            fixed.append(poly)
            continue
        parts = [g for g in getattr(made, "geoms", [made]) if g.geom_type in ("Polygon", "MultiPolygon")]
        pieces = [q for g in parts for q in (g.geoms if g.geom_type == "MultiPolygon" else [g]) if q.area > 0]
        if not pieces:
            fixed.append(poly)
            continue
        changed = True
        fixed += _nested(pieces, z)
        notes.append(f"its footprint is not a valid polygon ({reason}): read as the {len(pieces)} polygon(s) it "
                     f"encloses (shapely make_valid{'; its rings by the even-odd rule' if len(rings) > 1 else ''})")
    united, said = _united_overlaps(fixed if changed else polygons, z)
    return united, notes + said


def _nested(pieces: list, z: float | None) -> list:
    """Shapely polygons as GeoJSON nests them (rings of positions), each position at ``z`` where given."""
    at = lambda xy: [float(xy[0]), float(xy[1])] + ([z] if z is not None else [])  # noqa: E731
    return [[[at(c) for c in q.exterior.coords]] + [[at(c) for c in r.coords] for r in q.interiors] for q in pieces]


def _united_overlaps(polygons: list, z: float | None) -> tuple[list, list[str]]:
    """A footprint's polygons as their union where they overlap (a MultiPolygon's parts drawn over each other: an
    outline inside another, two halves that cross, a part written twice), each position at ``z`` where given, and a
    note saying how much was covered more than once. Each extruded alone, the overlap was built twice: two prisms
    through each other, its volume counted twice. Polygons that do not overlap (touching, or an island in a
    courtyard) are returned as they are."""
    import shapely
    from shapely.geometry import Polygon

    if len(polygons) < 2:
        return polygons, []
    try:
        shapes = [Polygon([(float(p[0]), float(p[1])) for p in poly[0]],
                          [[(float(p[0]), float(p[1])) for p in ring] for ring in poly[1:]]) for poly in polygons]
        if not all(s.is_valid for s in shapes):
            return polygons, []  # what valid_footprint could not make valid: its reading says why
        total = sum(s.area for s in shapes)
        union = shapely.unary_union(shapes)
    except (TypeError, ValueError, IndexError, shapely.errors.GEOSException):
        return polygons, []
    overlap = total - union.area
    if not overlap > OVERLAP_REL * total:
        return polygons, []
    pieces = [q for q in getattr(union, "geoms", [union]) if q.geom_type == "Polygon" and q.area > 0]
    return _nested(pieces, z), [f"the {len(polygons)} polygons of its footprint overlap ({overlap / total:.2%} of their area "
                    f"covered more than once): read as their union, {len(pieces)} polygon(s)"]


class HeightUnits:
    """A footprint's heights in its coordinates' vertical unit (the CRS's; metres where it is geographic or unknown),
    from attributes in :attr:`meshsom.io.ReaderOptions.height_unit` (else in that vertical unit) and from metres
    (storeys, the default height)."""

    def __init__(self, crs, options):
        from meshsom.io import HEIGHT_UNITS

        self.per_metre = 1.0 / crs.vertical_m if crs is not None else 1.0
        self.per_unit = HEIGHT_UNITS[options.height_unit] * self.per_metre if options.height_unit else 1.0

    def of(self, value) -> float | None:
        """An attribute's value (a number, or text: ``"12"``, ``"12 m"``, ``"40 ft"``) in the vertical unit; None
        where it is not a length."""
        number = _number(value)
        if number is None:  # approximate, a bound, a range: each number in its own unit
            loose = loose_number(value, self.of)
            return None if loose is None else loose[0]
        if isinstance(value, str) and re.search(r"[a-zA-Z'\"]", value):  # written with its unit: read in metres
            return number * self.per_metre
        return number * self.per_unit


def roof_scale(ring: np.ndarray, crs) -> tuple[float, float]:
    """Height units per unit of x and of y of a footprint ``ring`` ((K, 2) in ``crs``; None:
    metres): what :func:`meshsom.roofs.roof_faces` measures the footprint with, so that a pitch is
    a pitch whatever the units (a CRS in feet; degrees: the ellipsoid's meridian and prime vertical
    radii of curvature at the ring's mean latitude, so that a 12 m house is measured to 1e-6; a
    projection that distorts lengths there, Web Mercator: its point scale)."""
    if crs is None:
        return 1.0, 1.0
    if crs.geographic:
        latitude = math.radians(float(ring[:, 0 if crs.latitude_first else 1].mean()))
        e2 = crs.flattening * (2.0 - crs.flattening)
        w = 1.0 - e2 * math.sin(latitude) ** 2
        meridian, prime_vertical = crs.semi_major * (1.0 - e2) / w ** 1.5, crs.semi_major / math.sqrt(w)
        along = (math.radians(meridian), math.radians(prime_vertical) * math.cos(latitude))  # metres per degree
        return tuple(v / crs.vertical_m for v in (along if crs.latitude_first else along[::-1]))
    from meshsom.crs import MAX_SCALE_ERROR, point_scale

    k = point_scale(crs, float(ring[:, 0].mean()), float(ring[:, 1].mean()))  # Web Mercator: read in true metres
    k = k if k is not None and abs(k - 1.0) > MAX_SCALE_ERROR else 1.0  # (meshsom.crs.to_metres)
    return crs.horizontal_m / crs.vertical_m / k, crs.horizontal_m / crs.vertical_m / k


def roofed_solid(polygons: list, props: dict, z0: float, z1: float, crs, options, where: str, verts: FeatureVertices,
                 on_walls: bool = False) -> tuple[dict | None, str | None]:
    """A footprint's block from ``z0`` to ``z1`` with the roof its attributes describe
    (:func:`meshsom.roofs.roof_tags`: OpenStreetMap's S3DB tags or Overture's columns;
    :mod:`meshsom.roofs`) as a Solid over ``verts``, and a note; (None, note or None) where it is
    modelled flat (no roof shape, ``flat``, or a shape not built on this footprint: the note says
    why).

    Parameters
    ----------
    polygons : list
        The footprint's polygons (GeoJSON nesting), in ``crs``.
    z0, z1 : float
        Its base and top (the roof's top; with ``on_walls``, the walls' top, the eaves).
    crs : CoordinateSystem or None
        As :func:`footprint_solid` takes it.
    on_walls : bool
        Whether ``z1`` is the walls' top, the roof standing on them (a height from a storey count: S3DB's
        ``building:levels`` leave out the roof's levels); else the roof's top, the eaves below it by the roof's height
        (S3DB's ``height`` holds the roof). There a roof as high as ``z1 - z0``, or higher, takes all of it, no walls
        (:func:`_without_walls`; a higher one cut to it), and one of :data:`MAX_ROOF_SHARE` to 100 % is cut to that
        share; each noted.
    """
    from meshsom.roofs import (ALIASES, RIDGED_ROUND_COURTYARDS, ROUND_COURTYARDS, SHAPES, UNBUILT, roof_direction,
                               roof_faces, roof_height, roof_tags)

    found = roof_tags(props)
    tagged = str(found.get("roof:shape", "flat")).strip().lower()
    shape = ALIASES.get(tagged, tagged)
    if shape in ("flat", ""):
        return None, None
    if shape not in SHAPES:
        return None, f"roof:shape={shape} not modelled: a flat roof at the height"
    if any(len(polygon) != 1 for polygon in polygons) and shape not in ROUND_COURTYARDS:
        return None, (f"roof:shape={shape} not modelled on a footprint with courtyards ({' and '.join(ROUND_COURTYARDS)} "
                      "are): flat")
    degrees = roof_direction(found.get("roof:direction"))  # a compass point, degrees, or an estimate of them
    across = str(found.get("roof:orientation", "")).strip().lower() == "across"
    built, eaves, tops, fell_back, cut = [], [], [], [], []
    for polygon in polygons:  # several (a building in pieces): each its own roof, of the same tags
        for ring in polygon:
            FeatureVertices().ring(ring, where, z0)  # refused as a flat block's would be
        ring = np.asarray(polygon[0], np.float64)[:, :2]
        if np.array_equal(ring[0], ring[-1]):
            ring = ring[:-1]
        holes = [np.asarray(hole, np.float64)[:, :2] for hole in polygon[1:]]
        scale = roof_scale(ring, crs)
        units = HeightUnits(crs, options)
        rise = roof_height(shape, ring, scale, found, options.storey_height * units.per_metre, _number, units.of)
        whole = z1 - z0
        no_walls = not on_walls and rise >= whole * (1.0 - WHOLE_HEIGHT_REL)
        if no_walls:  # the roof fills its footprint's height (a roof storey on its part's walls): a roof, no walls
            said = (f"a roof of {rise:.4g} m, more than its {whole:.4g} m: cut to it" if rise > whole * (1.0 + WHOLE_HEIGHT_REL)
                    else "the roof fills its whole height") + ", no walls"
            cut.append(said) if said not in cut else None
            rise = whole
        elif not on_walls and rise > MAX_ROOF_SHARE * whole:
            said = (f"a roof of {rise:.4g} m leaves walls under {1 - MAX_ROOF_SHARE:.0%} of its {whole:.4g} m: cut to "
                    f"{MAX_ROOF_SHARE * whole:.4g} m")
            cut.append(said) if said not in cut else None
            rise = MAX_ROOF_SHARE * whole
        if not rise > 0:
            return None, None
        low, top = (z1, z1 + rise) if on_walls else (z1 - rise, z1)
        under = z0 - whole if no_walls else z0  # a block from below its base, its walls then of no height: dropped
        faces = roof_faces(ring, under, low, top, shape, scale, degrees, across=across, holes=holes)
        if faces is None and shape in FALLBACK:  # a half-hipped roof without a wing end to hip: its hipped kin
            faces = roof_faces(ring, under, low, top, FALLBACK[shape], scale, degrees, across=across, holes=holes)
            if faces is not None:
                fell_back.append(f"roof:shape={shape} built as {FALLBACK[shape]} ({UNBUILT[shape]})")
        if faces is not None and holes and shape in RIDGED_ROUND_COURTYARDS:
            fell_back.append(f"roof:shape={shape} built round its courtyards: the ridges of a hipped roof with the "
                             "shape's profile (a perimeter block has no end for a gable)")
        if faces is None:
            which = f" (its polygon {len(built) + 1} of {len(polygons)})" if len(polygons) > 1 else ""
            return None, f"roof:shape={shape} not modelled on this footprint{which} ({UNBUILT[shape]}): flat"
        built += _without_walls(faces, z0) if no_walls else faces
        eaves.append(low - z0)
        tops.append(top - z0)
    solid = {"type": "Solid", "lod": "2", "boundaries": [[[verts.ring(face, where)] for face in built]]}
    read_as = f" (roof:shape={tagged} read as {shape})" if tagged != shape else ""
    low, high = min(eaves), max(eaves)
    if fell_back:
        read_as += f" ({fell_back[0]}" + (f", on {len(fell_back)} of its polygons" if len(polygons) > 1 else "") + ")"
    read_as += "".join(f" ({said})" for said in cut)
    return solid, (f"roof:shape={shape} built (S3DB){read_as}: eaves {low:.3g}"
                   + (f" to {high:.3g}" if high - low > 1e-9 * max(abs(high), 1.0) else "")
                   + f" m, top {max(tops):.3g} m above its base" + (f", on {len(polygons)} polygons" if len(polygons) > 1 else ""))


def _without_walls(faces: list, z0: float) -> list:
    """A roof's faces (:func:`meshsom.roofs.roof_faces`, built on a block from below ``z0``, its eaves at ``z0``)
    with that block's vertices raised to ``z0``: its walls, of no height then, dropped (their corners repeated, no
    area left), its gable ends triangles, its floor at ``z0``.

    Parameters
    ----------
    faces : list of (n, 3) float64
    z0 : float

    Returns
    -------
    list of (m, 3) float64
        The faces that enclose an area, without repeated corners.
    """
    kept = []
    for face in faces:
        face = np.column_stack([face[:, :2], np.maximum(face[:, 2], z0)])
        face = face[np.any(face != np.roll(face, 1, axis=0), axis=1)]  # corners repeated in a row (cyclically)
        if len(face) < 3:
            continue
        centred = face - face.mean(axis=0)
        if np.linalg.norm(np.cross(centred, np.roll(centred, -1, axis=0)).sum(axis=0)) > 0:  # Newell: an area left
            kept.append(face)
    return kept


def surfaces(polygons: list, where: str, verts: FeatureVertices) -> dict:
    """3D polygons (lists of rings of positions) as a MultiSurface (LoD ``"2"``): a solid written
    as its faces, closed (or refused) by preprocessing."""
    return {"type": "MultiSurface", "lod": "2", "boundaries": [[verts.ring(r, where) for r in poly] for poly in polygons]}


def feature_object(feature: dict, where: str, options, crs=None) -> tuple[dict, np.ndarray, str, list[str]]:
    """One feature as a CityJSON-like Building object over its own vertices.

    ``crs`` (a :class:`meshsom.crs.CoordinateSystem`, None: metres) is the CRS of its coordinates,
    for the lengths that decide a footprint's roof.

    Returns
    -------
    obj : dict
        ``{"type": "Building", "geometry": [...], "attributes": {...}}``.
    vertices : (V, 3) float64
    member : str
        ``"place"`` or ``"geometry"``: which member the geometry came from (for the CRS).
    notes : list of str

    Raises
    ------
    InputFileError
        The feature holds no building geometry, or its geometry cannot be read.
    """
    props = properties(feature)
    place, geometry = feature.get("place"), feature.get("geometry")
    member, geom = ("place", place) if isinstance(place, dict) else ("geometry", geometry)
    if not isinstance(geom, dict):
        raise InputFileError(where, "has no geometry (place and geometry are null)")
    kind = geom.get("type")
    verts = FeatureVertices()
    notes: list[str] = []
    if kind == "GeometryCollection":  # a PostGIS ST_Collect, a QGIS "collect geometries": its polygons
        geom, notes = _collected_polygons(geom, where)
        kind = geom["type"]
    if kind == "Polyhedron" or kind == "MultiPolyhedron":
        coords = geom.get("coordinates")
        solids = [coords] if kind == "Polyhedron" else coords
        if not isinstance(solids, list) or not all(isinstance(s, list) for s in solids):
            raise InputFileError(where, f"its {kind} has no coordinates")
        boundaries = [[[[verts.ring(r, where) for r in poly] for poly in shell] for shell in solid] for solid in solids]
        g = {"type": "Solid", "lod": "2", "boundaries": boundaries[0]} if kind == "Polyhedron" else {
            "type": "MultiSolid", "lod": "2", "boundaries": boundaries}
    elif kind == "Prism":
        base = geom.get("base")
        if not isinstance(base, dict) or base.get("type") not in ("Polygon", "MultiPolygon"):
            found = base.get("type") if isinstance(base, dict) else type(base).__name__
            raise InputFileError(where, f"its Prism's base is {found}; expected a Polygon or MultiPolygon")
        lower, upper = _number(geom.get("lower", 0.0)), _number(geom.get("upper"))
        if lower is None or upper is None or max(abs(lower), abs(upper)) >= MAX_COORDINATE:
            raise InputFileError(where, "its Prism needs numbers \"upper\" (and \"lower\", default 0)")
        g = _extruded(_polygons(base, where), lower, upper, where, verts)
    elif kind in ("Polygon", "MultiPolygon"):
        polygons = _polygons(geom, where)
        heights = {_number(p[2]) for poly in polygons if isinstance(poly, list) for ring in poly if isinstance(ring, list)
                   for p in ring if isinstance(p, list) and len(p) > 2}
        collected = notes
        g, notes = footprint_solid(polygons, props, where, options, verts, flat=len(heights) <= 1, crs=crs)
        notes = collected + notes
        if g is None:
            try:
                g = surfaces(polygons, where, verts)
            except InputFileError as err:
                if "three coordinates" not in err.problem:
                    raise
                raise InputFileError(where, no_height(options, notes, props=props)) from None
    else:
        raise InputFileError(where, f"holds a {kind}, not a building's polygons or solid")
    return building(g, props, options), verts.array(), member, notes


def _collected_polygons(collection: dict, where: str) -> tuple[dict, list[str]]:
    """A GeometryCollection's polygons (of its Polygon and MultiPolygon members, nested collections too) as one
    MultiPolygon, with a note naming the members left out (lines, points); a collection without polygons is left
    as it is (refused, naming it)."""
    polygons: list = []
    other: dict[str, int] = {}
    stack = [(collection, 0)]
    while stack:
        g, depth = stack.pop()
        kind = g.get("type") if isinstance(g, dict) else type(g).__name__
        if kind == "GeometryCollection" and depth <= MAX_COLLECTION_DEPTH and isinstance(g.get("geometries"), list):
            stack.extend((member, depth + 1) for member in reversed(g["geometries"]))
        elif kind in ("Polygon", "MultiPolygon"):
            polygons += _polygons(g, where)
        else:
            other[str(kind)] = other.get(str(kind), 0) + 1
    if not polygons:
        return collection, []
    notes = [f"its GeometryCollection read as its {len(polygons)} polygon(s)"
             + (" (left out: " + ", ".join(f"{n} {k}" for k, n in sorted(other.items())) + ")" if other else "")]
    return {"type": "MultiPolygon", "coordinates": polygons}, notes


def properties(feature: dict) -> dict:
    """A feature's properties; OpenStreetMap's tags that osmtogeojson nests under ``tags`` (its
    output without ``flatProperties``), and those of GDAL's ``other_tags`` (``ogr2ogr``'s output of an
    extract, :func:`meshsom.osm.osm_properties`), read as properties too (the feature's own win)."""
    from meshsom.osm import osm_properties

    props = feature.get("properties") if isinstance(feature.get("properties"), dict) else {}
    nested = props.get("tags")
    return osm_properties({**nested, **props} if isinstance(nested, dict) else props)


def _extent(value, depth: int = 0) -> tuple[float, float] | None:
    """The largest magnitudes of any position's x and of any position's y in nested coordinate lists; None where
    there is none (or the nesting is not lists of numbers: the reader says so later)."""
    if not isinstance(value, list) or depth > 6 or not value:
        return None
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return (abs(float(value[0])), abs(float(value[1]))) if len(value) >= 2 else None
    found = [e for e in (_extent(v, depth + 1) for v in value) if e is not None]
    return (max(e[0] for e in found), max(e[1] for e in found)) if found else None


def declared_crs(feature: dict, collection_crs: str | None, old_crs: str | None, options) -> str | None:
    """The CRS a feature's coordinates are in, as the module says: the JSON-FG ``coordRefSys`` of
    its ``place``; else an old-style ``crs`` member; else WGS 84 (``OGC:CRS84h``) where every x
    lies within +/-180 and every y within +/-90 and no :attr:`meshsom.io.ReaderOptions.crs` is set; else None
    (projected data written without one)."""
    if isinstance(feature.get("place"), dict):
        return _reference(feature.get("coordRefSys")) or collection_crs
    if old_crs is not None:
        return old_crs
    geometry = feature.get("geometry")
    extent = _extent(geometry.get("coordinates")) if isinstance(geometry, dict) else None
    lonlat = extent is not None and extent[0] <= 180 and extent[1] <= 90  # a y beyond 90 is no latitude
    return GEOJSON_CRS if lonlat and options.crs is None else None


def _feature_id(feature: dict, index: int) -> str:
    """A feature's id as the mesh ids use it: its OpenStreetMap id where GDAL's OSM driver wrote it
    (:func:`meshsom.osm.osm_row_id`), else its ``id``, else ``feature-<index + 1>``."""
    from meshsom.osm import osm_row_id

    fid = feature.get("id")
    props = feature.get("properties")
    osm = osm_row_id(props) if isinstance(props, dict) else None
    return osm or (str(fid) if isinstance(fid, (str, int)) and not isinstance(fid, bool) else f"feature-{index + 1}")


def _is_part_feature(props: dict) -> bool:
    """OpenStreetMap's tagging of a building part (``building:part``, any value but ``no``, on an area not itself
    tagged ``building``)."""
    from meshsom.osm import _said

    return _said(props, "building:part") and not _said(props, "building")


def building_parts(features: list) -> tuple[set[int], dict[int, list[int]]]:
    """Which footprint features of a collection are parts of another, as OpenStreetMap's Simple 3D Buildings scheme
    and Overture Maps say it.

    A part is a footprint (a ``Polygon`` or ``MultiPolygon`` ``geometry``) tagged ``building:part`` and not
    ``building`` (an Overpass turbo or osmtogeojson export of buildings and their parts), or one whose
    ``building_id`` (Overture's ``building_part``) is the id of another footprint of the collection. It belongs to
    that building, else to the smallest footprint that is not a part holding a point inside it (shapely).

    Returns
    -------
    owned : set of int
        The indices (in ``features``) of the parts that belong to a building of the collection.
    parts_of : dict of int to list of int
        For every building with parts, and every OSM-tagged part inside none (with no parts: read as a building of
        its own, noted), the indices of its parts, in file order.
    """
    from shapely.geometry import shape

    from meshsom.osm import _Area, _owners

    footprints, ids = {}, {}
    for k, feature in enumerate(features):
        if not isinstance(feature, dict) or isinstance(feature.get("place"), dict):
            continue
        geometry = feature.get("geometry")
        if isinstance(geometry, dict) and geometry.get("type") in ("Polygon", "MultiPolygon"):
            footprints[k] = properties(feature)
            for key in (feature.get("id"), footprints[k].get("id")):
                if isinstance(key, (str, int)) and not isinstance(key, bool):
                    ids.setdefault(str(key), k)
    parts = [k for k, props in footprints.items() if _is_part_feature(props) or (
        isinstance(props.get("building_id"), (str, int)) and ids.get(str(props["building_id"]), k) != k)]
    if not parts:
        return set(), {}
    part_set = set(parts)
    owner = {k: ids[str(footprints[k]["building_id"])] for k in parts
             if str(footprints[k].get("building_id")) in ids and ids[str(footprints[k]["building_id"])] not in part_set}

    def readable(k):
        try:
            g = shape(features[k]["geometry"])
            return g.is_valid and g.area > 0
        except Exception:  # malformed coordinates: the feature's own reading says so
            return False

    outlines = [k for k in footprints if k not in part_set and readable(k)]
    loose = [k for k in parts if k not in owner and readable(k)]
    found = _owners([_Area(str(k), {}, features[k]["geometry"]) for k in outlines],
                    [_Area(str(k), {}, features[k]["geometry"]) for k in loose])
    owner.update({k: outlines[b] for k, b in zip(loose, found.tolist()) if b >= 0})
    parts_of: dict[int, list[int]] = {}
    for k in parts:
        if k in owner:
            parts_of.setdefault(owner[k], []).append(k)
        elif _is_part_feature(footprints[k]):
            parts_of.setdefault(k, [])
    return set(owner), parts_of


def building(geometry: dict, props: dict, options) -> dict:
    """A CityJSON-like Building object of one geometry, labelled by the property
    :attr:`meshsom.io.ReaderOptions.label_attribute`."""
    label = props.get(options.label_attribute)
    return {"type": "Building", "geometry": [geometry], "attributes": {} if label is None else {options.label_attribute: label}}


def read_geojson(document: dict, path: Path, options, name: str | None = None, first: int = 0) -> Iterator:
    """The buildings of a parsed GeoJSON / JSON-FG document: RawMesh or Rejection items, as
    :func:`meshsom.io.read_cityjson` gives them (a Rejection per feature that cannot be read).
    ``first``: the place in its file of the document's first feature (a range of a large file:
    :func:`geojson_ranges`), for the ids of features that have none."""
    import dataclasses

    from meshsom.io import Rejection, _object_meshes, file_crs
    from meshsom.osm import area_geometry, osm_row, no_outline, not_a_building
    from meshsom.part_files import Placement

    name = name or path.name
    features = [document] if document.get("type") == "Feature" else document.get("features")
    if not isinstance(features, list):
        raise InputFileError(str(path), "is a FeatureCollection without a \"features\" list")
    collection_crs = _reference(document.get("coordRefSys"))
    old_crs = _reference(document.get("crs"))
    features = [{**f, "geometry": area_geometry(f["geometry"])}  # GDAL's OSM lines layer: its closed ways are areas
                if isinstance(f, dict) and isinstance(f.get("geometry"), dict) and f["geometry"].get("type") == "LineString"
                and osm_row(properties(f)) else f for f in features]
    owned, parts_of = building_parts(features)
    placement = Placement(path, options) if options.part_files else None  # Overture's parts, in files of their own
    for k, feature in enumerate(features, 1):
        if not isinstance(feature, dict) or feature.get("type") != "Feature":
            yield Rejection(f"{name}#feature-{first + k}", str(path), "is not a GeoJSON Feature")
            continue
        if k - 1 in owned:
            continue  # read with its building
        oid = _feature_id(feature, first + k - 1)
        mesh_id = f"{name}#{oid}"
        crs = file_crs(declared_crs(feature, collection_crs, old_crs, options), options)
        props = properties(feature)
        if osm_row(props) and feature.get("geometry") is not None and (
                reason := not_a_building(props) or no_outline(props, feature.get("geometry"))) is not None:
            label = props.get(options.label_attribute)
            yield Rejection(mesh_id, str(path), reason, 0, None if label is None else str(label))
            continue
        if k - 1 in parts_of or (options.part_files or osm_row(props)) and isinstance(feature.get("geometry"), dict):
            from meshsom.osm import STRAY, _Area, building_meshes

            own = [_Area(_feature_id(features[j], j), properties(features[j]), features[j]["geometry"])
                   for j in parts_of.get(k - 1, [])]
            skip, elsewhere, alone = placement.of(props, oid) if placement else (False, [], None)  # Overture's parts
            if skip:
                continue  # read with its building
            own += [part for part in elsewhere if part.oid not in {mine.oid for mine in own}]  # this file's: found
            alone = alone or (STRAY if _is_part_feature(props) and not own else None)
            if own or alone or osm_row(props) and feature["geometry"].get("type") in ("Polygon", "MultiPolygon"):
                yield from building_meshes(_Area(oid, props, feature["geometry"]), own, alone, options, name, str(path),
                                           crs)
                continue
        try:
            try:
                obj, vertices, member, notes = feature_object(feature, mesh_id, options, crs[0])
            except InputFileError:
                raise  # said already (an InputFileError is a ValueError too: not to be wrapped below)
            except (TypeError, ValueError, AttributeError, KeyError, IndexError) as err:  # nesting not as GeoJSON says
                raise InputFileError(mesh_id, f"its geometry is not nested as GeoJSON / JSON-FG says "
                                              f"({type(err).__name__}: {str(err)[:80]})") from None
        except InputFileError as err:
            label = properties(feature).get(options.label_attribute)
            yield Rejection(mesh_id, str(path), err.problem, 0, None if label is None else str(label))
            continue
        for item in _object_meshes({oid: obj}, vertices, None, None, options, name, str(path), crs=crs):
            if notes and not isinstance(item, Rejection):
                item = dataclasses.replace(item, notes=tuple(notes) + item.notes)
            yield item


#: Bytes of a large GeoJSON file looked at at a time when its features are found (:func:`geojson_ranges`).
SCAN_BYTES = 8 << 20
#: Bytes at a JSON file's start looked at before it is scanned (:func:`geojson_ranges`): a CityJSON file says its type
#: there, and is not scanned for features.
HEAD_BYTES = 1 << 16
#: Fewest bytes a feature takes (a small footprint and its properties): a file smaller than twice a range's features
#: this size is read whole, unscanned.
MIN_FEATURE_BYTES = 200
#: What a file that groups parts mentions (OpenStreetMap's and Overture's keys, CityGML's type): it is read whole, so
#: that each building finds its parts.
PART_MARKS = (b'"building:part"', b'"building_id"', b'"BuildingPart"')
_FEATURES_KEY = re.compile(rb'"features"\s*:\s*$')


def geojson_ranges(path: Path, target_features: int, options) -> list[list[int]] | None:
    """Split a large GeoJSON FeatureCollection into ranges of whole features, each for one read task
    (:func:`read_geojson_range`): one pass over its bytes (NumPy, :data:`SCAN_BYTES` at a time) finds where each
    feature of its top-level ``features`` array starts and ends, outside strings.

    Parameters
    ----------
    path : Path
        A GeoJSON file (plain: a gzipped one is not split).
    target_features : int
        Features per read task (``dask.read_features``).
    options : ReaderOptions
        Its ``max_bytes`` bounds the file scanned.

    Returns
    -------
    list of [start, stop, first, open, close] or None
        Byte ranges of whole features (``first``: the place of the range's first feature), and the places of the
        array's ``[`` and ``]``, covering every feature once, in order; None where the file has fewer than twice
        ``target_features`` features, is gzip (not seekable), is CityJSON (by its first :data:`HEAD_BYTES`, not
        scanned), is not a FeatureCollection of a ``features`` array, or mentions building parts (:data:`PART_MARKS`:
        read whole, so that each building finds its parts).
    """
    from meshsom.io import GZIP_MAGIC, _parse_json

    path = Path(path)
    try:
        size = path.stat().st_size
        if target_features < 1 or size < 2 * target_features * MIN_FEATURE_BYTES or size > options.max_bytes:
            return None
        with open(path, "rb") as fh:
            head = fh.read(HEAD_BYTES)
        if head[:2] == GZIP_MAGIC or not head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{") \
                or b'"CityJSON"' in head:
            return None  # gzip, not a JSON object, or CityJSON (its type comes first): no pass over its bytes
        found = _feature_spans(path)
    except OSError:
        return None
    if found is None:
        return None
    opened, closed, starts, ends = found
    if len(starts) != len(ends) or len(starts) < 2 * target_features:
        return None
    with open(path, "rb") as fh:
        head = fh.read(opened + 1)
        fh.seek(closed)
        tail = fh.read()
    try:
        document = _parse_json(head + tail, str(path))
    except InputFileError:
        return None
    if not (isinstance(document, dict) and document.get("type") == "FeatureCollection" and document.get("features") == []):
        return None
    return [[int(starts[a]), int(ends[min(a + target_features, len(ends)) - 1]) + 1, a, opened, closed]
            for a in range(0, len(starts), target_features)]


def _feature_spans(path: Path) -> tuple[int, int, np.ndarray, np.ndarray] | None:
    """The places of a JSON document's top-level ``"features": [`` and its ``]``, and of each member object's ``{``
    and ``}``; None where there is none, the document does not close it, or it mentions :data:`PART_MARKS`."""
    in_string, depth, carried, offset = 0, 0, 0, 0  # carried: a run of backslashes at the end of the last chunk
    opened = closed = None
    starts, ends, tail = [], [], b""
    with open(path, "rb") as fh:
        while chunk := fh.read(SCAN_BYTES):
            seen = tail + chunk
            if any(mark in seen for mark in PART_MARKS):
                return None
            b = np.frombuffer(chunk, np.uint8)
            n = len(b)
            backslash = b == 92
            index = np.arange(n, dtype=np.int32)
            last_other = np.maximum.accumulate(np.where(backslash, np.int32(-1), index))  # the last non-backslash to i
            run = np.empty(n, np.int32)  # backslashes just before i
            run[0] = carried
            run[1:] = index[:-1] - last_other[:-1] + np.where(last_other[:-1] < 0, carried, 0)
            quote = (b == 34) & (run % 2 == 0)
            strings = (np.cumsum(quote, dtype=np.int32) + in_string) % 2  # 1: inside a string after i
            outside = strings == 0
            opener = ((b == 123) | (b == 91)) & outside
            closer = ((b == 125) | (b == 93)) & outside
            after = depth + np.cumsum(opener.astype(np.int32) - closer, dtype=np.int32)
            if opened is None:
                for i in np.flatnonzero((b == 91) & opener & (after == 2)).tolist():
                    if _FEATURES_KEY.search((tail + chunk[max(i - 64, 0):i])[-64:]):
                        opened = offset + i
                        break
            if opened is not None and closed is None:
                within = index > opened - offset
                ends_here = np.flatnonzero((b == 93) & closer & (after == 1) & within)
                if len(ends_here):
                    closed = offset + int(ends_here[0])
                    within &= index < closed - offset
                starts.append(offset + np.flatnonzero((b == 123) & opener & (after == 3) & within).astype(np.int64))
                ends.append(offset + np.flatnonzero((b == 125) & closer & (after == 2) & within).astype(np.int64))
            in_string = int(strings[-1])
            depth = int(after[-1])
            carried = int(n - 1 - last_other[-1]) + (carried if last_other[-1] < 0 else 0)
            tail = seen[-64:]  # the last bytes read, for a mark or a key across chunks
            offset += n
    if opened is None or closed is None or depth != 0 or in_string:
        return None
    return opened, closed, np.concatenate(starts or [np.zeros(0, np.int64)]), np.concatenate(ends or [np.zeros(0, np.int64)])


def read_geojson_range(path: Path, options, name: str | None, feature_range) -> Iterator:
    """The buildings of one range of a large GeoJSON FeatureCollection (:func:`geojson_ranges`): the file's members
    other than its features, with those of the range, read as :func:`read_geojson` reads a document."""
    from meshsom.io import _parse_json

    start, stop, first, opened, closed = (int(v) for v in feature_range)
    with open(path, "rb") as fh:
        head = fh.read(opened + 1)
        fh.seek(start)
        body = fh.read(stop - start)
        fh.seek(closed)
        tail = fh.read()
    document = _parse_json(head + body + tail, str(path))
    if not isinstance(document, dict) or not isinstance(document.get("features"), list):
        raise InputFileError(str(path), f"bytes {start}..{stop} are not features of its \"features\" list (the file "
                                        "changed since it was planned?)")
    yield from read_geojson(document, Path(path), options, name, first)
