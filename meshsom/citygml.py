"""Reading the buildings of CityGML files (1.0, 2.0 and 3.0; ``.gml``, plain or gzipped).

CityGML is the XML form of the city models CityJSON encodes (most national LoD1 and LoD2 building
data: Germany's, Japan's PLATEAU, New York's, Berlin's). Each ``Building`` becomes the same
objects the CityJSON reader works on (:func:`meshsom.io._object_meshes`): the Building and its
``BuildingPart``s, each with one MultiSurface per LoD made of every ``gml:Polygon`` under its
``lod{N}...`` properties, so merging parts, choosing the LoD, triangulating polygons with holes and
rejecting what cannot be read work exactly as for CityJSON.

Details of the encoding:

- Elements are matched by local name, so the namespaces of CityGML 1.0, 2.0 and 3.0 all read.
- A polygon's LoD is that of the nearest enclosing property named ``lod<N>...`` (``lod2Solid``,
  ``lod2MultiSurface``, ``lod1Solid``, ``lod0FootPrint``...). A polygon appears once however
  often it is referenced: a Solid usually refers (``xlink:href="#id"``) to the polygons of the
  Wall/Roof/GroundSurfaces it is bounded by. Installations (chimneys, dormers as
  BuildingInstallation) and rooms are left out, as the CityJSON reader leaves them out.
- Where an object has a solid at a LoD, that LoD is the solid's polygons alone: the thematic
  surfaces beside it may hold what is not shell (roof overhangs, recessed windows). Without a
  solid, every surface at the LoD is read.
- The shells of an object's solids at a LoD (each ``gml:Solid``'s exterior and interiors, those of a
  ``gml:CompositeSolid`` or ``gml:MultiSolid``) are kept apart where there are several: the LoD is then a
  MultiSolid of one shell per solid, whose shells that are no cavity are united as CityJSON's are
  (:func:`meshsom.io._parts`).
- ``gml:OrientableSurface orientation="-"`` is its base surface reversed: a party wall that a
  Building and its BuildingPart share is written once and referred to so by the second.
- Planar pieces are ``gml:Polygon`` and the patches of ``gml:Surface`` (``PolygonPatch``,
  ``Rectangle``) and ``gml:TriangulatedSurface`` (``Triangle``).
- The CRS is the ``srsName`` of the building's geometry, else of the model's envelope
  (:mod:`meshsom.crs`: latitude and longitude, as Japan's PLATEAU gives them, are read in metres).
- Rings are ``gml:posList`` (``srsDimension`` 3), a sequence of ``gml:pos``, or GML 2
  ``gml:coordinates``; the closing point is dropped; equal coordinates of one building are one
  vertex.
- A label comes from a generic attribute (``gen:stringAttribute`` and the like; 3.0's
  ``core:genericAttribute``) named :attr:`meshsom.io.ReaderOptions.label_attribute`.
- Heights: ``measuredHeight`` and ``storeysAboveGround``; 3.0's ``con:height`` from the ground to
  the top as a ``measuredHeight`` (:func:`_heights`).
- Parsing streams (``xml.etree.ElementTree.iterparse`` on :func:`meshsom.io.open_input`: gzip
  decompressed as it is read), each building cleared once read; no DTD or external entity is
  fetched.
- A large file (a city's, a WFS answer) is read in ranges of whole members by tasks of their own
  (:func:`citygml_ranges`: one pass over its bytes finds each ``cityObjectMember``, ``gml:featureMember``
  or ``wfs:member``; each range is parsed as the file's head, its members and the file's tail), each
  Building where a whole read puts it: its id (by ordinal where it has no ``gml:id``), source and
  errors' line numbers.
- A prefix used without a namespace declaration (an ADE's ``energy:`` or ``uro:`` element, an
  ``xlink:href`` in a file that forgot ``xmlns:xlink``: not well-formed XML, which a parser refuses
  at the first use) is declared on the root element and the file read again from the start, the
  buildings already read passed over (:data:`UNDECLARED_PREFIXES` of them at most); the buildings
  read after the first such prefix carry a note naming them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: Local names of the objects taken as parts of a Building.
PART_NAMES = ("BuildingPart",)
#: Local names of what a Building holds that is not its outer surface (as the CityJSON reader
#: leaves out BuildingInstallations and rooms, which are objects of their own there).
NOT_SHELL = ("BuildingInstallation", "IntBuildingInstallation", "Room", "BuildingRoom", "BuildingFurniture",
             "BuildingConstructiveElement", "interiorRoom", "interiorFurniture", "outerBuildingInstallation",
             "interiorBuildingInstallation", "buildingInstallation", "buildingRoom", "buildingFurniture",
             "buildingConstructiveElement",
             # the surfaces of a building's inside (CityGML 2.0 LoD4 rooms; 3.0 at any LoD: the storeys
             # of a parking garage): not its outer shell
             "FloorSurface", "CeilingSurface", "InteriorWallSurface",
             # 3.0's subdivisions of a building (and the ADEs' of 2.0, as citygml4j's test ADE): storeys and
             # units (apartments, shops) are volumes inside the shell, often solids of their own
             "buildingSubdivision", "Storey", "storey", "BuildingUnit", "buildingUnit")
#: Local names of the openings of a wall or roof: CityGML 1.0 / 2.0's ``bldg:Window`` and ``bldg:Door`` (under
#: ``bldg:opening``), 3.0's ``con:WindowSurface`` and ``con:DoorSurface`` (under ``con:fillingSurface``). Their
#: geometry (frames, glass, sills, recessed panes; a window written flush, sharing the edges of its hole) is not the
#: building's envelope: it is left out, counted in a note, and the hole it fills is closed where the remaining
#: surfaces leave it open (:func:`meshsom.preprocess.close_surface`'s planar caps: in the wall's plane where the wall
#: has no reveal, at the reveal's inner end where it has).
OPENING_NAMES = ("Window", "Door", "WindowSurface", "DoorSurface")
#: Local names of the planar pieces a surface is made of: polygons, and the patches of a
#: ``gml:Surface`` / ``gml:TriangulatedSurface`` (all have an exterior ring and may have interiors).
POLYGON_NAMES = ("Polygon", "PolygonPatch", "Triangle", "Rectangle")
#: Local names of the GML solids: where an object has one at a LoD, it is that LoD's shell.
SOLID_NAMES = ("Solid", "CompositeSolid", "MultiSolid")
#: Local names of the GML elements whose ``srsName`` is the CRS of a building's surfaces (not a Point's: an
#: ``Address`` may locate its entrance in another CRS, WGS 84 beside a national grid).
SURFACE_GEOMETRY_NAMES = POLYGON_NAMES + SOLID_NAMES + (
    "MultiSurface", "CompositeSurface", "Surface", "TriangulatedSurface", "Tin", "OrientableSurface", "Shell",
    "LinearRing", "posList", "Envelope")
_LOD = re.compile(r"^lod(\d)")
_XLINK_HREF = "{http://www.w3.org/1999/xlink}href"
#: The namespaces given to prefixes that a file uses without declaring them, where the reader looks
#: attributes up by their namespace (``xlink:href``); any other prefix gets a namespace of its own
#: (elements are matched by local name).
KNOWN_PREFIXES = {"xlink": "http://www.w3.org/1999/xlink", "gml": "http://www.opengis.net/gml",
                  "xsi": "http://www.w3.org/2001/XMLSchema-instance"}
#: How many undeclared prefixes a file may use before it is refused as not XML (each one costs a
#: reading of the file up to its first use).
UNDECLARED_PREFIXES = 16
#: How far into a file its root element's start tag is looked for, to declare prefixes on it.
ROOT_TAG_SEARCH_BYTES = 1 << 20
_PREFIXED_NAME = re.compile(r"(?:<|\s)/?([A-Za-z_][\w.\-]*):[A-Za-z_][\w.\-]*")
#: Bytes of a CityGML file looked at per step of :func:`citygml_ranges`' scan.
SCAN_BYTES = 8 << 20
#: Bytes at the end of a step looked at again in the next (a member's or a Building's tag cut by the step's end).
TAG_MARGIN = 4096
#: The longest comment or CDATA section the scan carries from one step to the next; a file with a longer one is read
#: whole, by one task.
CARRY_LIMIT = 64 << 20
#: Local names of the elements that hold a model's features, a feature each (CityGML's ``cityObjectMember``; a WFS
#: FeatureCollection's ``gml:featureMember`` or ``wfs:member``): a file is split between them.
MEMBER_NAMES = (b"cityObjectMember", b"featureMember", b"member")
#: What the scan looks at: comments and CDATA sections (passed over), and the start and end tags of members and of
#: Buildings (groups: the end tag's slash, the qualified name, its local name, a self-closing tag's slash).
_SCAN_TOKEN = re.compile(rb"<!--.*?-->|<!\[CDATA\[.*?\]\]>|<(/?)((?:[A-Za-z_][\w.\-]*:)?("
                         + b"|".join(MEMBER_NAMES) + rb"|Building))(?=[\s/>])[^<>]*?(/?)>", re.S)


@functools.lru_cache(maxsize=4096)
def _local(tag) -> str:
    """An element's name without its namespace (a file holds few distinct tags: cached)."""
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


#: Namespaces of CityGML, GML and the other OGC schemas a building's own geometry is written in; an element of any other
#: (an Application Domain Extension's) is not the building's shell. CityGML 0.4, before the OGC adopted it, has
#: ``http://www.citygml.org/citygml/1/0/0`` (citygml4j's LoD3 sample of 2010); ``http://www.citygml.org/ade/...`` is
#: an ADE's.
OGC_NAMESPACES = ("http://www.opengis.net/", "https://www.opengis.net/", "http://www.citygml.org/citygml/")


@functools.lru_cache(maxsize=4096)
def _ade(tag) -> bool:
    """Whether an element is an ADE's (a namespace not OGC's): the Energy ADE's thermal zones and thermal boundaries
    (their own LoD 2-3 solids and surfaces), a utility network's pipes, a test ADE's building units. A tag without a
    namespace is taken as CityGML's."""
    return isinstance(tag, str) and tag.startswith("{") and not tag[1:].startswith(OGC_NAMESPACES)


def _gml_id(element) -> str | None:
    for key, value in element.attrib.items():
        if _local(key) == "id":
            return value
    return None


def _numbers(text: str | None, where: str) -> np.ndarray:
    try:
        return np.array((text or "").replace(",", " ").split(), np.float64)
    except ValueError:
        raise InputFileError(where, f"coordinates must be numbers; received {(text or '')[:60]!r}") from None


def _ring(element, where: str, flat_ok: bool = False) -> np.ndarray:
    """(k, 3) float64 points of a ``gml:LinearRing`` (closing point dropped); ``flat_ok``: a ring of 2D points (a
    footprint's, ``srsDimension="2"``) is read at z = 0."""
    dims = 3
    points = None
    for child in element.iter():
        name = _local(child.tag)
        if name == "posList":
            declared = child.attrib.get("srsDimension", child.attrib.get("dimension", "3"))
            dims = int(declared) if declared.strip().isdigit() else -1
            points = _numbers(child.text, where)
            break
        if name == "coordinates":
            points = _numbers(child.text, where)
            tuples = (child.text or "").split()
            if tuples and all(t.count(",") == 1 for t in tuples):
                dims = 2
            break
    if points is None:
        pos = [_numbers(c.text, where) for c in element.iter() if _local(c.tag) == "pos"]
        if pos and all(len(p) == len(pos[0]) for p in pos):
            dims = len(pos[0])
            points = np.concatenate(pos)
        else:
            points = np.zeros(0)
    if flat_ok and dims == 2 and len(points) % 2 == 0:
        points = np.column_stack([points.reshape(-1, 2), np.zeros(len(points) // 2)]).reshape(-1)
        dims = 3
    if dims != 3 or len(points) % 3:
        raise InputFileError(where, f"a ring's coordinates are not 3D (srsDimension {dims}, {len(points)} numbers)"
                             + ("; 2D rings are read as footprints (LoD 0) alone" if dims == 2 else ""))
    ring = points.reshape(-1, 3)
    if len(ring) > 1 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]
    return ring


def _polygon(element, where: str, flat_ok: bool = False) -> list[np.ndarray]:
    """The rings of a ``gml:Polygon`` (exterior first, then interiors), each (k, 3); ``flat_ok`` as :func:`_ring`."""
    exterior, interiors = [], []
    for child in element:
        name = _local(child.tag)
        if name in ("exterior", "outerBoundaryIs", "interior", "innerBoundaryIs"):
            for ring in child:
                if _local(ring.tag) == "LinearRing":
                    (exterior if name in ("exterior", "outerBoundaryIs") else interiors).append(
                        _ring(ring, where, flat_ok))
    return exterior[:1] + interiors if exterior else []


def openings_note(openings: int, polygons: int) -> str:
    """The note of a building whose openings' geometry (``openings`` windows and doors of ``polygons`` polygons in
    all) was left out of its envelope: CityGML's :data:`OPENING_NAMES`, CityJSON's semantic surfaces of those types
    (:data:`meshsom.io.OPENING_SURFACES`)."""
    return (f"left out the geometry of {openings} opening(s) (windows, doors: {polygons} polygon(s)): not the "
            f"envelope; the holes they fill are closed where they are open")


def _opening_polygons(building) -> dict[int, int]:
    """The polygons of a building's openings (:data:`OPENING_NAMES`): ``{id(polygon): id(opening)}``, so that a solid
    that refers to them (``xlink:href``) leaves them out too."""
    found: dict[int, int] = {}
    for e in building.iter():
        if _local(e.tag) in OPENING_NAMES:
            found.update((id(p), id(e)) for p in e.iter() if _local(p.tag) in POLYGON_NAMES)
    return found


def _object_polygons(obj, where: str, by_id: dict, openings: dict | None = None, left_out: set | None = None
                     ) -> tuple[dict[str, tuple[list, list]], int]:
    """Every polygon of one city object (not of its parts), by LoD, with the shell of a solid each lies in; and the
    count of references (``xlink:href``, to a polygon or to a whole surface or solid) not found in the building.

    The polygons of openings (``openings``, :func:`_opening_polygons`; windows and doors, whether met inside their
    wall or referred to by a solid) are left out, the ids of their openings added to ``left_out``.

    Where the object has a solid at a LoD (``lod2Solid``, a ``gml:Solid``), that LoD's polygons
    are the solid's alone: the solid is the closed shell, while the thematic surfaces at the same
    LoD may hold more (roof overhangs, recessed windows, surfaces of the ground). Otherwise they
    are the polygons of every surface at that LoD. A shell is a ``gml:Solid``'s ``exterior`` or ``interior``
    (the solids of a ``gml:CompositeSolid`` or ``gml:MultiSolid`` each have theirs); a polygon outside any has
    shell None.

    Returns
    -------
    by_lod : dict
        ``{lod: (polygons, shells)}``: the polygons (lists of rings) and each one's shell number (or None).
    missing : int
    """
    by_lod: dict[tuple[str, bool], tuple[list, list]] = {}
    seen: set = set()
    missing = 0
    shells = [0]

    openings = {} if openings is None else openings
    left_out = set() if left_out is None else left_out

    def add(polygon, lod: str, reverse: bool, solid: bool, shell):
        if id(polygon) in openings:
            left_out.add(openings[id(polygon)])
            return
        key = (id(polygon), reverse, solid, shell)
        if key not in seen:
            seen.add(key)
            rings = _polygon(polygon, where, lod == "0")
            polys, of = by_lod.setdefault((lod, solid), ([], []))
            polys.append([r[::-1] for r in rings] if reverse else rings)
            of.append(shell)

    def walk(element, lod: str | None, reverse: bool, solid: bool, roof: bool = False, shell=None):
        nonlocal missing
        for child in element:
            name = _local(child.tag)
            if (name in PART_NAMES or name in ("consistsOfBuildingPart", "buildingPart") or name in NOT_SHELL
                    or _ade(child.tag)):
                continue  # a part's geometry is its own; installations, rooms and an ADE's zones are not the shell
            if name in OPENING_NAMES:
                if any(id(p) in openings for p in child.iter()):
                    left_out.add(id(child))  # a window's or door's own geometry: not the envelope
                continue
            match = _LOD.match(name)
            child_lod = match.group(1) if match else lod
            child_roof = roof or name == "RoofSurface" or name.endswith("RoofEdge")
            # a LoD's solid is preferred to its other surfaces; so is a LoD 0 footprint to the roof
            # edges beside it (the outline of the eaves, metres above the ground): 2.0's lod0FootPrint, 3.0's
            # lod0MultiSurface of the building itself (or of its GroundSurface) beside its RoofSurfaces'
            child_solid = solid or name in SOLID_NAMES or (match is not None and (
                name.endswith(("Solid", "FootPrint")) or (child_lod == "0" and not child_roof)))
            # gml:OrientableSurface orientation="-": its base surface, reversed (a party wall
            # that two parts share is written once and referred to so by the second part)
            child_reverse = reverse != (name == "OrientableSurface" and child.attrib.get("orientation", "+").strip() == "-")
            child_shell = shell
            if name in ("exterior", "interior") and _local(element.tag) == "Solid":  # a solid's shell
                shells[0] += 1
                child_shell = shells[0]
            href = child.attrib.get(_XLINK_HREF)
            if href and child_lod is not None:
                target = by_id.get(href.lstrip("#"))
                if target is None:
                    missing += 1
                elif _local(target.tag) in POLYGON_NAMES:
                    add(target, child_lod, child_reverse, child_solid, child_shell)
                elif (id(target), child_reverse, child_solid, child_shell) not in seen:  # a surface, solid or patch referred to whole
                    seen.add((id(target), child_reverse, child_solid, child_shell))
                    walk(target, child_lod, child_reverse, child_solid or _local(target.tag) in SOLID_NAMES, child_roof,
                         child_shell)
                continue
            if name in POLYGON_NAMES and child_lod is not None:
                add(child, child_lod, child_reverse, child_solid, child_shell)
                continue
            walk(child, child_lod, child_reverse, child_solid, child_roof, child_shell)

    walk(obj, None, False, False)
    lods = dict.fromkeys(lod for lod, _ in by_lod)
    return {lod: by_lod[(lod, True)] if (lod, True) in by_lod else by_lod[(lod, False)] for lod in lods}, missing


def _label(obj, attribute: str) -> str | None:
    """The value of the object's own generic attribute named ``attribute``: CityGML 1.0 / 2.0's
    ``gen:stringAttribute name="..."`` (and its kin, in a ``gen:genericAttributeSet`` too), 3.0's
    ``core:genericAttribute`` holding a ``gen:StringAttribute`` of ``gen:name`` and ``gen:value`` (a
    ``gen:GenericAttributeSet`` too)."""
    for child in obj:
        if not _local(child.tag).endswith(("Attribute", "AttributeSet")):
            continue
        for found in child.iter():
            kind = _local(found.tag)
            if not kind.endswith("Attribute") or kind == "genericAttribute":
                continue
            name = found.attrib.get("name")
            if name is None:  # 3.0: a gen:name element
                name = next((e.text.strip() for e in found if _local(e.tag) == "name" and e.text), None)
            if name == attribute:
                for value in found:
                    if _local(value.tag) == "value" and value.text is not None and value.text.strip():
                        return value.text.strip()
    return None


#: Attributes of a building or part kept (its height and storeys: a footprint of LoD 0 alone is
#: extruded by them, as :func:`meshsom.io._building_mesh` says).
HEIGHT_ELEMENTS = ("measuredHeight", "storeysAboveGround")
#: CityGML 3.0's ``con:Height`` references (its HeightReferenceValue codes) that measure a building from the ground
#: to its top: such a height is read as its ``measuredHeight``.
TOP_REFERENCES = ("highestPoint", "highestRoofEdge", "topOfConstruction", "generalRoof")
GROUND_REFERENCES = ("lowestGroundPoint", "highestGroundPoint", "generalGround", "bottomOfConstruction")
#: Units of a height (``uom``, lower case, without a leading ``#``: the OGC samples write ``#m``) and their length in
#: metres: the metre, the foot, the US survey foot, the centimetre and the millimetre, by symbol, name and EPSG urn.
LENGTH_UNITS = {
    **dict.fromkeys(("m", "metre", "meter", "metres", "meters", "urn:ogc:def:uom:epsg::9001"), 1.0),
    **dict.fromkeys(("ft", "foot", "feet", "urn:ogc:def:uom:epsg::9002"), 0.3048),
    **dict.fromkeys(("us-ft", "ftus", "us survey foot", "urn:ogc:def:uom:epsg::9003"), 1200 / 3937),
    **dict.fromkeys(("cm", "centimetre", "centimeter", "urn:ogc:def:uom:epsg::1033"), 0.01),
    **dict.fromkeys(("mm", "millimetre", "millimeter", "urn:ogc:def:uom:epsg::1025"), 0.001),
}


def _metres(element) -> tuple[str | None, str | None]:
    """A length element's value in metres (as text; its ``uom``, metres where it names none) and a note where it was
    converted or cannot be: (value, note)."""
    text = (element.text or "").strip()
    uom = element.attrib.get("uom", "m").strip()
    key = uom.lower().lstrip("#")
    factor = LENGTH_UNITS.get(key, LENGTH_UNITS.get(re.split(r"[:#/]", key)[-1]))  # urn:adv:uom:m, a URL's #m
    if factor is None:
        return None, f"its {_local(element.tag)} {text} is in a unit not read ({uom!r}; read: m, ft, US survey ft, cm, mm)"
    if factor == 1.0:
        return text, None
    try:
        value = float(text)
    except ValueError:
        return text, None  # not a number: said as such where the height is read
    return repr(value * factor), f"its {_local(element.tag)} {text} {uom} read as {value * factor:.6g} m"


def _heights(obj) -> tuple[dict, list[str]]:
    """The object's own ``measuredHeight`` (in metres: :data:`LENGTH_UNITS`) and ``storeysAboveGround`` (direct
    children), as text; CityGML 3.0's ``con:height`` from the ground to the top (:data:`TOP_REFERENCES`,
    :data:`GROUND_REFERENCES`) as its ``measuredHeight`` where it has none; and notes of the units converted or not
    read."""
    found, notes = {}, []
    for child in obj:
        name = _local(child.tag)
        if name in HEIGHT_ELEMENTS and child.text and child.text.strip():
            value, note = _metres(child) if name == "measuredHeight" else (child.text.strip(), None)
            notes += [note] if note else []
            if value is not None:
                found[name] = value
    if "measuredHeight" not in found:
        for child in obj:
            if _local(child.tag) != "height":
                continue
            for height in child:
                fields = {_local(e.tag): e for e in height}
                high, low, value = (fields.get(k) for k in ("highReference", "lowReference", "value"))
                if (high is not None and (high.text or "").strip() in TOP_REFERENCES and value is not None
                        and (value.text or "").strip()
                        and (low is None or (low.text or "").strip() in GROUND_REFERENCES)):
                    metres, note = _metres(value)
                    notes += [note.replace("its value", "its height")] if note else []
                    if metres is not None:
                        found["measuredHeight"] = metres
                        return found, notes
    return found, notes


def building_objects(building, where: str, label_attribute: str) -> tuple[dict, np.ndarray, list[str], str | None]:
    """One CityGML Building as CityJSON-like objects (the Building and its BuildingParts, each with
    a MultiSurface per LoD) over shared vertices.

    Returns
    -------
    objects : dict
        ``{id: {"type", "geometry", "children" | "parents", "attributes"}}``, the Building first.
    vertices : (V, 3) float64
        Real coordinates (no transform).
    notes : list of str
    srs_name : str or None
        The first ``srsName`` of the building's surface geometry (its CRS; :data:`SURFACE_GEOMETRY_NAMES`), when it
        names one.
    """
    by_id, srs_name = {}, None
    for e in building.iter():  # one pass: the ids that xlink:href refers to, and the CRS
        gml_id = _gml_id(e)
        if gml_id:
            by_id[gml_id] = e
        if srs_name is None and _local(e.tag) in SURFACE_GEOMETRY_NAMES:
            srs_name = e.attrib.get("srsName")
    bid = _gml_id(building)
    members = [(bid, building)] + [(_gml_id(p), p) for p in building.iter() if _local(p.tag) in PART_NAMES
                                   and p is not building]  # (a BuildingPart read as a building: its own parts)
    objects: dict = {}
    rings: list[np.ndarray] = []
    n_points = 0
    missing = 0
    notes: list[str] = []
    openings = _opening_polygons(building)
    left_out: set[int] = set()
    for k, (oid, obj) in enumerate(members):
        oid = oid or (f"{bid}-part{k}" if k else bid)
        by_lod, lost = _object_polygons(obj, where, by_id, openings, left_out)
        missing += lost
        geometry = []
        for lod, (polys, shell_of) in by_lod.items():
            boundaries = []
            for poly in polys:
                indexed = []
                for ring in poly:
                    rings.append(ring)
                    indexed.append(list(range(n_points, n_points + len(ring))))
                    n_points += len(ring)
                boundaries.append(indexed)
            shell_ids = list(dict.fromkeys(shell_of))
            if len(shell_ids) > 1 and None not in shell_ids:  # several shells of solids: each its own, as CityJSON's
                geometry.append({"type": "MultiSolid", "lod": lod, "boundaries": [
                    [[b for b, k in zip(boundaries, shell_of) if k == shell and b]] for shell in shell_ids]})
            else:
                geometry.append({"type": "MultiSurface", "lod": lod, "boundaries": [b for b in boundaries if b]})
        heights, height_notes = _heights(obj)
        notes += [note if k == 0 else f"its part {oid}: {note[4:]}" for note in height_notes]
        entry = {"type": "Building" if k == 0 else "BuildingPart", "geometry": geometry, "attributes": heights}
        if k == 0:
            entry["children"] = []
            label = _label(obj, label_attribute)
            if label is not None:
                entry["attributes"][label_attribute] = label
        else:
            entry["parents"] = [bid]
            objects[bid]["children"].append(oid)
        objects[oid] = entry
    points = np.concatenate(rings) if rings else np.zeros((0, 3))
    vertices, inverse = np.unique(points, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    for entry in objects.values():
        for g in entry["geometry"]:
            polys = g["boundaries"] if g["type"] == "MultiSurface" else [p for solid in g["boundaries"] for p in solid[0]]
            for poly in polys:
                poly[:] = [[int(inverse[i]) for i in ring] for ring in poly]
    if left_out:
        polygons = len({p for p, o in openings.items() if o in left_out})
        notes.append(openings_note(len(left_out), polygons))
    if missing:
        notes.append(f"{missing} polygon reference(s) (xlink:href) outside the building were not read")
    outside = [href for e in building.iter() if _local(e.tag) in ("consistsOfBuildingPart", "buildingPart")
               for href in [e.attrib.get(_XLINK_HREF)] if href and href.lstrip("#") not in by_id]
    if outside:
        notes.append(f"{len(outside)} BuildingPart(s) it refers to by xlink:href outside it ({', '.join(outside[:3])}"
                     f"{', ...' if len(outside) > 3 else ''}) are not merged into it: each is read as a building of its "
                     f"own where the file holds it")
    return objects, vertices, notes, srs_name


def read_citygml(path: Path, options, name: str | None = None, byte_range=None) -> Iterator:
    """Read the buildings of a CityGML file: RawMesh or Rejection items, as :func:`meshsom.io.read_cityjson`.

    The file is parsed as a stream (:func:`meshsom.io.open_input`): only the building being read
    is held.

    Parameters
    ----------
    path : Path
    options : ReaderOptions
    name : str, optional
    byte_range : list of int, optional
        A range of :func:`citygml_ranges`: the Buildings of its members (ids, ordinals and errors' lines as in the
        whole file); a range without Buildings yields nothing.

    Raises
    ------
    InputFileError
        The file is not XML or holds no Building. The root may be a CityModel or anything else
        that holds Buildings (a WFS FeatureCollection, as German LoD2 downloads come).
    """
    import dataclasses

    from meshsom.io import Rejection, open_input

    opener = (lambda: open_input(path, options)) if byte_range is None else (lambda: _range_input(path, byte_range))
    added: dict[str, str] = {}  # prefixes the file uses undeclared -> the namespace given them
    read = 0  # items yielded so far: passed over when the file is read again
    first = None  # the first parse error, in the file as it is
    while True:
        declared: set[str] = set()
        seen = 0
        try:
            with opener() as stream:
                source = _DeclaringStream(stream, added) if added else stream
                for item in _buildings(source, path, name or path.name, options, declared,
                                       0 if byte_range is None else int(byte_range[2]), byte_range is not None):
                    seen += 1
                    if seen <= read:
                        continue
                    read = seen
                    if added and not isinstance(item, Rejection):
                        item = dataclasses.replace(item, notes=item.notes + (_undeclared_note(added),))
                    yield item
            return
        except InputFileError:
            raise
        except ET.ParseError as err:
            line, column = err.position
            problem = f"invalid XML at line {_file_line(path, line, byte_range)}, column {column}: {str(err).split(':')[0]}"
            prefix = _unbound_prefix(opener, line, column, declared, added) \
                if str(err).startswith("unbound prefix") and len(added) < UNDECLARED_PREFIXES else None
            if prefix is None:
                if added:  # the first error (its position in the file as it is), and what declaring led to
                    then = (f"more than {UNDECLARED_PREFIXES} prefixes used undeclared" if len(added) >= UNDECLARED_PREFIXES
                            else f"at line {_file_line(path, line, byte_range)}: {str(err).split(':')[0]}")
                    problem = f"{first}; with {', '.join(f'{p}:' for p in added)} declared, then {then}"
                raise InputFileError(str(path), problem) from None
            first = first or problem
            added[prefix] = KNOWN_PREFIXES.get(prefix, f"urn:meshsom:undeclared:{prefix}")
        except (LookupError, ValueError, RecursionError) as err:  # an unknown encoding, bytes not in it, deep nesting
            raise InputFileError(str(path), f"cannot be parsed as XML ({type(err).__name__}: {err})") from None


def _file_line(path: Path, line: int, byte_range) -> int:
    """The line of the file that a parser's ``line`` of a range's stream (:func:`_range_input`) is on: lines past the
    head's are counted from the range's first."""
    if byte_range is None:
        return line
    head = _head_lines(path, int(byte_range[3]))
    return line if line <= head else line - head - 1 + int(byte_range[5])


def _undeclared_note(added: dict[str, str]) -> str:
    names = ", ".join(f"{p}:" for p in added)
    return (f"the file uses the XML prefix(es) {names} without declaring a namespace for them (not well-formed XML); "
            f"read as if the root element declared them")


def _unbound_prefix(opener, line: int, column: int, declared: set[str], added: dict[str, str]) -> str | None:
    """The prefix of the start tag at ``line``, ``column`` (a parser's error position, its column in
    characters, in the file as parsed: with ``added`` declared) that no declaration binds: of its element's and its
    attributes' prefixes not in ``added``, the first that the file declares nowhere before
    (``declared``), else the first (declared only in another element's scope); None if none."""
    with opener() as stream:
        text = _text_at(_DeclaringStream(stream, added) if added else stream, line, column)
    tag = text.split(">", 1)[0]
    found = [m.group(1) for m in _PREFIXED_NAME.finditer(" " + tag)]
    found = [p for p in found if p not in added and p not in ("xml", "xmlns")]
    return next((p for p in found if p not in declared), found[0] if found else None)


def _text_at(stream, line: int, column: int, size: int = 1 << 16) -> str:
    """Up to ``size`` characters of ``stream`` from character ``column`` of line ``line`` (as the
    parser counts them: lines from 1, columns from 0, in characters), decoded as UTF-8 (a byte that
    is not, of a single-byte encoding, is one character too), read as a stream (a one-line file is
    not held whole)."""
    import codecs

    decoder = codecs.getincrementaldecoder("utf-8")("replace")
    number, skip, out = 1, None, ""
    while True:
        chunk = stream.read(1 << 16)
        if not chunk:
            return out + decoder.decode(b"", final=True) if skip is not None else ""
        if skip is None:
            at = -1
            while number < line:
                at = chunk.find(b"\n", at + 1)
                if at < 0:
                    break
                number += 1
            if number < line:
                continue
            chunk, skip = chunk[at + 1:], column
        text = decoder.decode(chunk)
        if skip >= len(text):
            skip -= len(text)
            continue
        out += text[skip:]
        skip = 0
        if len(out) >= size:
            return out[:size]


class _DeclaringStream:
    """A binary stream whose root element's start tag declares ``added`` prefixes (a mapping of
    prefix to namespace), for :func:`xml.etree.ElementTree.iterparse`. The declarations go inside
    the tag, on its line, so line numbers stay those of the file. Nothing is added to a file
    whose root is not found in its first :data:`ROOT_TAG_SEARCH_BYTES` or that is UTF-16 (the
    parser then fails at the same prefix again and the file is refused)."""

    def __init__(self, stream, added: dict[str, str]):
        self._stream = stream
        self._declarations = "".join(f' xmlns:{p}="{uri}"' for p, uri in added.items()).encode("ascii")
        self._head: bytes | None = None

    def read(self, size: int = -1) -> bytes:
        if self._head is None:
            self._head = self._declare()
        if self._head:
            if size is None or size < 0:
                out, self._head = self._head + self._stream.read(), b""
                return out
            out, self._head = self._head[:size], self._head[size:]
            return out
        return self._stream.read(size)

    def _declare(self) -> bytes:
        head = b""
        while len(head) < ROOT_TAG_SEARCH_BYTES:
            chunk = self._stream.read(1 << 16)
            head += chunk
            at = _root_name_end(head)
            if at is not None:
                return head[:at] + self._declarations + head[at:]
            if not chunk or head[:2] in (b"\xff\xfe", b"\xfe\xff"):
                break
        return head


def _root_name_end(head: bytes) -> int | None:
    """Where the root element's name ends in the first bytes of an XML document (after its
    declaration, comments, processing instructions and doctype), or None if not within them."""
    at = 3 if head.startswith(b"\xef\xbb\xbf") else 0
    while True:
        at = head.find(b"<", at)
        if at < 0 or at + 1 >= len(head):
            return None
        follow = head[at + 1:at + 2]
        if follow in (b"?", b"!"):
            close = b"-->" if head.startswith(b"<!--", at) else b">"
            end = head.find(close, at)
            if end < 0:
                return None
            at = end + len(close)
            continue
        match = re.compile(rb"[^\s/>]+").match(head, at + 1)
        if match is None or match.end() >= len(head):
            return None
        return match.end()


def _buildings(stream, path: Path, name: str, options, declared: set[str], ordinal: int = 0, part: bool = False
               ) -> Iterator:
    """The meshes and rejections of the Buildings parsed from ``stream``, as :func:`read_citygml`;
    the prefixes the file declares are added to ``declared`` as they are met. ``ordinal``: the Buildings before the
    stream's (of a range: ``part``, which may hold none)."""
    import dataclasses

    from meshsom.io import Rejection, _object_meshes

    from meshsom.io import file_crs

    found = part
    root = None
    file_srs = None  # the srsName of the model's own envelope: the CRS of geometry that names none
    held: dict[str, int] = {}  # the objects of the members that are no Building, by local name
    stack: list[str] = []  # local names of the open elements
    for event, element in ET.iterparse(stream, events=("start", "end", "start-ns")):
        if event == "start-ns":
            declared.add(element[0])
            continue
        local = _local(element.tag)
        if event == "start":
            root = root or local
            stack.append(local)
            continue
        stack.pop()
        # a Building; or a BuildingPart outside any Building (a member of its own, which its building may refer to
        # by xlink:href): read as a building of its own, noted, rather than lost
        loose_part = local in PART_NAMES and "Building" not in stack and not any(p in stack for p in PART_NAMES)
        if (local != "Building" or "Building" in stack) and not loose_part:
            if local == "Envelope" and "Building" not in stack and file_srs is None:
                file_srs = element.attrib.get("srsName")
            if len(stack) == 2 and stack[-1].encode() in MEMBER_NAMES:
                held[local] = held.get(local, 0) + 1  # a member's object: named where the file holds no Building
            if len(stack) == 1:
                element.clear()  # a member of the CityModel (or of a WFS FeatureCollection) read: let go
            continue
        ordinal += 1
        element_id = _gml_id(element) or f"building-{ordinal}"
        if _gml_id(element) is None:
            element.set("{http://www.opengis.net/gml}id", element_id)
        mesh_id = f"{name}#{element_id}"
        try:
            objects, vertices, notes, srs = building_objects(element, mesh_id, options.label_attribute)
            if loose_part:
                notes.append(f"a {local} outside any Building (a member of the file of its own): read as a building")
        except InputFileError as err:
            yield Rejection(mesh_id, str(path), err.problem)
        else:
            crs = _gml_axis_order(srs or file_srs, file_crs(srs or file_srs, options), notes)
            for item in _object_meshes(objects, vertices, None, None, options, name, str(path), crs=crs):
                if notes and not isinstance(item, Rejection):
                    item = dataclasses.replace(item, notes=item.notes + tuple(notes))
                yield item
        found = True
        element.clear()
    if not found:
        what = "CityGML" if root == "CityModel" else f"XML with root element {root!r}"
        kinds = ", ".join(f"{n} {k}" for k, n in sorted(held.items(), key=lambda kv: (-kv[1], kv[0]))[:12])
        raise InputFileError(str(path), f"holds no Building (CityGML bldg:Building); it is {what}"
                             + (f" holding {kinds}" if kinds else ""))


#: srsName forms that GML writers (FME, GeoServer's WFS, deegree) write in x/y order, longitude first, whatever the
#: EPSG axis order: ``EPSG:4326`` and ``http://www.opengis.net/gml/srs/epsg.xml#4326`` (GeoServer's axis-order
#: convention). The URN (``urn:ogc:def:crs:EPSG::4326``) and ``http://www.opengis.net/def/crs/EPSG/0/4326`` forms
#: follow EPSG's order: latitude first.
LONGITUDE_FIRST_FORMS = re.compile(r"^\s*(?:EPSG:\d+|https?://www\.opengis\.net/gml/srs/epsg\.xml#\d+)\s*$", re.I)


def _gml_axis_order(srs_name, crs: tuple, notes: list) -> tuple:
    """``crs`` (:func:`meshsom.io.file_crs`'s pair) with a geographic CRS named in a longitude-first form
    (:data:`LONGITUDE_FIRST_FORMS`) read longitude first, noted in ``notes``."""
    system, unknown = crs
    if system is None or not system.geographic or not system.latitude_first or not isinstance(srs_name, str) \
            or not LONGITUDE_FIRST_FORMS.match(srs_name):
        return crs
    notes.append(f"srsName {srs_name.strip()!r} read longitude first, as GML writers write that form (the "
                 f"urn:ogc:def:crs:EPSG:: and opengis.net/def/crs forms are read latitude first, in EPSG's order)")
    return dataclasses.replace(system, latitude_first=False), unknown


def citygml_ranges(path: Path, target_bytes: int, options, url: str | None = None) -> list[list[int]] | None:
    """Split a large CityGML file into ranges of whole members (``cityObjectMember``, a WFS collection's
    ``featureMember`` or ``member``), each for one read task (:func:`read_citygml`'s ``byte_range``).

    One pass over the file's bytes (:data:`SCAN_BYTES` at a time, comments and CDATA sections passed over) finds the
    start and end tag of each member, named as its first member is, and each Building's start tag (the ordinal of a
    Building without ``gml:id`` is its place in the file). A range is read as the file's head (everything before its
    first member: the root's namespaces, the model's envelope and CRS), the range's members and the file's tail.

    Parameters
    ----------
    path : Path
        A CityGML file (plain: a gzipped one is not split).
    target_bytes : int
        About the size of a range (``dask.read_bytes``): a range ends at the first member start past it.
    options : ReaderOptions
        Its ``max_bytes`` bounds the file scanned.
    url : str, optional
        Where the file's bytes are read from where ``path`` is a copy of its head only (an input on object storage,
        :mod:`meshsom.mirror`): streamed from there, never copied whole.

    Returns
    -------
    list of [start, stop, first_building, head_end, tail_start, first_line] or None
        Byte ranges of whole members covering every member once, in order (what lies between two members goes with
        the first); ``first_building``: the Buildings before the range; ``head_end`` and ``tail_start``: where the
        file's first member starts and its last ends; ``first_line``: the line the range starts on (from 1). None
        where the file is under twice ``target_bytes``, gzip (not seekable), over ``options.max_bytes``, or not made
        of members that can be read apart (a Building outside every member, members inside members, fewer than two
        ranges, a comment longer than :data:`CARRY_LIMIT`).
    """
    from meshsom.io import GZIP_MAGIC

    path = Path(path)
    try:
        size = path.stat().st_size
        if target_bytes < 1 or size < 2 * target_bytes or size > options.max_bytes:
            return None
        with open(path, "rb") as fh:
            if fh.read(2) == GZIP_MAGIC:
                return None
        found = _member_spans(url or path)
    except OSError:
        return None
    if found is None:
        return None
    starts, ends, buildings, start_lines = found
    if not len(starts) or len(starts) != len(ends) or np.any(ends < starts) or np.any(starts[1:] < ends[:-1]):
        return None  # unclosed, or members inside members
    if not len(buildings) or buildings[0] < starts[0] or buildings[-1] > ends[-1]:
        return None  # a Building in the head or the tail would be read by every range
    within = np.searchsorted(starts, buildings, side="right") - 1  # the member each Building starts in
    if np.any(buildings >= ends[within]):
        return None  # a Building between members
    firsts = [0]
    while True:
        at = int(np.searchsorted(starts, starts[firsts[-1]] + target_bytes))
        if at >= len(starts):
            break
        firsts.append(at)
    if len(firsts) < 2:
        return None
    offsets = [int(starts[a]) for a in firsts]
    lines = start_lines[firsts].tolist()  # for the reader's errors
    stops = offsets[1:] + [int(ends[-1])]
    before = np.searchsorted(buildings, offsets)
    return [[a, b, int(n), int(starts[0]), int(ends[-1]), line] for a, b, n, line in zip(offsets, stops, before, lines)]


def _member_spans(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Where each member of a CityGML file (a path, or a URL: :func:`meshsom.mirror.open_bytes`) starts and ends (its
    tags' ``<`` and past its end tag's ``>``; a self-closing member's both), named as the first member is, where each
    Building's start tag is, and the line (from 1) each member starts on; None where a comment or CDATA section is
    longer than :data:`CARRY_LIMIT`."""
    from meshsom.mirror import open_bytes

    member = None
    starts, ends, buildings, lines = [], [], [], []
    carry, offset = b"", 0  # carry: the unread end of the last step; offset: where it is in the file
    newlines, counted = 0, 0  # the line ends before ``counted`` (a place in the file)
    with open_bytes(path) as fh:
        while True:
            chunk = fh.read(SCAN_BYTES)
            last = not chunk
            buf = carry + chunk
            limit = len(buf) if last else max(0, len(buf) - TAG_MARGIN)
            for opener, closer in ((b"<!--", b"-->"), (b"<![CDATA[", b"]]>")):  # not yet closed: looked at next step
                at = buf.rfind(opener)
                if not last and at >= 0 and buf.find(closer, at + len(opener)) < 0:
                    limit = min(limit, at)
            done = 0
            for m in _SCAN_TOKEN.finditer(buf, 0, len(buf)):
                if m.start() >= limit:
                    break
                done = m.end()
                qname = m.group(2)
                if qname is None:
                    continue  # a comment or CDATA section
                if m.group(3) == b"Building":
                    if not m.group(1):
                        buildings.append(offset + m.start())
                    continue
                member = member or (None if m.group(1) else qname)
                if qname != member:
                    continue
                if m.group(1):
                    ends.append(offset + m.end())
                else:
                    newlines += buf.count(b"\n", counted - offset, m.start())
                    counted = offset + m.start()
                    starts.append(counted)
                    lines.append(newlines + 1)
                    if m.group(4):
                        ends.append(offset + m.end())
            if last:
                break
            keep = max(done, limit)
            if len(buf) - keep > CARRY_LIMIT:
                return None
            newlines += buf.count(b"\n", counted - offset, keep)
            carry, offset = buf[keep:], offset + keep
            counted = offset
    return (np.asarray(starts, np.int64), np.asarray(ends, np.int64), np.asarray(buildings, np.int64),
            np.asarray(lines, np.int64))


class _PiecesStream(io.RawIOBase):
    """The bytes of a file's ``pieces`` (``(start, stop)`` spans, in order) as one binary stream."""

    def __init__(self, fh, pieces: list[tuple[int, int]]):
        self._fh, self._pieces, self._at = fh, [p for p in pieces if p[1] > p[0]], 0
        if self._pieces:
            fh.seek(self._pieces[0][0])

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        while self._pieces:
            start, stop = self._pieces[0]
            left = stop - start - self._at
            if left > 0:
                n = self._fh.readinto(memoryview(buffer)[:min(len(buffer), left)])
                if not n:
                    return 0
                self._at += n
                return n
            self._pieces.pop(0)
            self._at = 0
            if self._pieces:
                self._fh.seek(self._pieces[0][0])
        return 0


@contextlib.contextmanager
def _range_input(path: Path, byte_range) -> Iterator[io.BufferedIOBase]:
    """A stream of a CityGML file's head, the members of ``byte_range`` (:func:`citygml_ranges`) and its tail."""
    start, stop, _, head_end, tail_start, _ = byte_range
    with open(path, "rb") as fh:
        yield io.BufferedReader(_PiecesStream(fh, [(0, head_end), (start, stop), (tail_start, path.stat().st_size)]))


def _head_lines(path: Path, head_end: int) -> int:
    """The line ends in a file's first ``head_end`` bytes (a CityGML file's head: :func:`citygml_ranges`)."""
    with open(path, "rb") as fh:
        return fh.read(head_end).count(b"\n")


def write_citygml(path, meshes, label_attribute: str = "family") -> None:
    """Write meshes as CityGML 2.0: one ``bldg:Building`` each, with its label as a generic
    attribute and its triangles as a ``lod{N}Solid`` (N the mesh's LoD, 1 when it has none);
    gzip-compressed when ``path`` ends in ``.gz``.

    Parameters
    ----------
    path : path
    meshes : iterable of objects with ``id``, ``vertices (V, 3) float64`` (world coordinates),
        ``faces (F, 3) int64``, ``label`` and ``lod``.
    label_attribute : str
    """
    import gzip
    from xml.sax.saxutils import escape, quoteattr

    opener = gzip.open if str(path).endswith(".gz") else open
    with opener(path, "wt", encoding="utf-8") as fh:
        fh.write('<?xml version="1.0" encoding="UTF-8"?>\n<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" '
                 'xmlns:bldg="http://www.opengis.net/citygml/building/2.0" xmlns:gen="http://www.opengis.net/citygml/generics/2.0" '
                 'xmlns:gml="http://www.opengis.net/gml">\n')
        for m in meshes:
            lod = int(float(m.lod)) if m.lod not in (None, "") else 1
            corners = np.asarray(m.vertices, np.float64)[np.asarray(m.faces)]
            closed = np.concatenate([corners, corners[:, :1]], axis=1).reshape(len(corners), -1)
            members = "".join(
                '<gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing><gml:posList srsDimension="3">'
                + " ".join(repr(float(x)) for x in row) + "</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember>"
                for row in closed)
            label = ("" if m.label is None else f'<gen:stringAttribute name={quoteattr(label_attribute)}>'
                     f"<gen:value>{escape(str(m.label))}</gen:value></gen:stringAttribute>")
            fh.write(f"<core:cityObjectMember><bldg:Building gml:id={quoteattr(str(m.id))}>{label}<bldg:lod{lod}Solid><gml:Solid>"
                     f"<gml:exterior><gml:CompositeSurface>{members}</gml:CompositeSurface></gml:exterior></gml:Solid>"
                     f"</bldg:lod{lod}Solid></bldg:Building></core:cityObjectMember>\n")
        fh.write("</core:CityModel>\n")
