"""INSPIRE Buildings 2D (GML): the footprints Europe's cadastres publish (Spain's Catastro for the whole country).

An INSPIRE building file is GML whose features are ``bu-core2d`` / ``bu-ext2d`` ``Building`` or
``BuildingPart`` elements (a footprint ``gml:Surface``, ``numberOfFloorsAboveGround``, ...), not
CityGML. It is read as a GIS file (:mod:`meshsom.gis`, GDAL's GML driver; no ``.gfs`` file is
written beside it):

- **Heights**: a ``heightAboveGround`` to the building's top (:data:`TOP_REFERENCES`; GDAL gives it as
  ``heightReference`` and ``value``: :func:`inspire_properties`), else ``numberOfFloorsAboveGround``
  times :attr:`meshsom.io.ReaderOptions.storey_height` (among the default
  :attr:`~meshsom.io.ReaderOptions.levels_attributes`).
- **Building parts**: Spain's Catastro publishes its buildings' heights on their parts, in a file of
  their own (``A.ES.SDGC.BU.<municipality>.buildingpart.gml``), each part's ``gml:id`` its
  building's with ``_part<N>`` after it (:data:`PART_ID`). The parts of one building are read as
  one building of parts (BuildingParts united in preprocessing, as OpenStreetMap's are), its id its
  building's ``gml:id``; a building of a building file whose parts are among the inputs
  (:func:`meshsom.part_files.pair`) is read from them, not again from its footprint. Other producers link
  a ``Building`` to its parts by ``bu-core2d:parts`` ``xlink:href`` (:func:`part_links`; the link's id
  after its last ``#``, ``/`` or ``:`` naming a part's ``gml:id`` or ``localId``), the parts in the
  building's file or in another: such a building is read as its parts, with its id and its
  attributes (a part with neither a height nor storeys takes its building's). Parts neither linked nor naming a building go, in a
  file of both, to the Building whose outline holds them (:func:`meshsom.gis.part_grouping`). Others again write the
  parts inside their ``Building`` (``bu-core2d:parts`` holding a ``BuildingPart``), which GDAL's GML driver flattens
  into list columns of the building, their footprints lost: those are taken out of the file (:func:`inline_parts`:
  one pass of ElementTree's parser), read by GDAL as a file of parts of their own, and the building is read as them,
  as a linking one is.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

#: Namespaces of INSPIRE's Buildings application schemas (2D) as files declare them (INSPIRE's
#: registry, the JRC's older location).
NAMESPACES = (re.compile(rb"inspire[.a-z]*\.europa\.eu/schemas/bu-(core2d|ext2d|base)/"),)
#: GDAL's own GML namespace (``ogr2ogr -f GML`` writes footprints under ``ogr:FeatureCollection``): simple features,
#: read through GDAL as INSPIRE's are.
OGR_NAMESPACE = re.compile(rb"xmlns:ogr=[\"']http://ogr\.maptools\.org/")
#: A CityGML namespace: a file that declares one is CityGML (INSPIRE's 3D profiles extend it).
CITYGML = re.compile(rb"opengis\.net/citygml/")
#: A building part's id naming its building: ``<building id>_part<N>`` (Catastro).
PART_ID = re.compile(r"^(?P<building>.+)_part\d+$")
#: A building part's element, as INSPIRE names it.
PART_ELEMENT = re.compile(rb"<[A-Za-z0-9_-]+:BuildingPart[\s>]")
#: Bytes of a file looked through for its namespaces and first features.
SNIFF_BYTES = 1 << 16


#: INSPIRE's ElevationReferenceValue codes that mark a building's top: a ``heightAboveGround`` of one of these is its
#: height (GDAL's GML driver flattens the element to ``heightReference`` and ``value``).
TOP_REFERENCES = ("top", "topOfConstruction", "highestPoint", "generalRoof", "highestRoofEdge")


def inspire_properties(props: dict) -> dict:
    """A feature's properties with its ``heightAboveGround`` to its top (:data:`TOP_REFERENCES`), as GDAL gives it
    (``heightReference``, ``value``, ``value_uom`` in metres), as its ``height`` where it has none."""
    reference = str(props.get("heightReference") or "").strip()
    if reference in TOP_REFERENCES and props.get("value") is not None and props.get("height") is None and (
            str(props.get("value_uom") or "m").strip().lower() in ("m", "metre", "meter", "urn:ogc:def:uom:epsg::9001")):
        return {**props, "height": props["value"]}
    return props


def _head(path: Path) -> bytes:
    """The first :data:`SNIFF_BYTES` of a file (gzip data decompressed); nothing where it cannot be read (its reader
    says why)."""
    from meshsom.errors import InputFileError
    from meshsom.io import open_input

    try:
        with open_input(Path(path)) as stream:
            return stream.read(SNIFF_BYTES)
    except (OSError, InputFileError):
        return b""


def is_inspire(path: Path) -> bool:
    """Whether a GML file (plain or gzipped) holds INSPIRE Buildings 2D: it declares their namespace and no
    CityGML's, in its first :data:`SNIFF_BYTES`."""
    head = _head(Path(path))
    return any(ns.search(head) for ns in NAMESPACES) and not CITYGML.search(head)


def is_ogr_gml(path: Path) -> bool:
    """Whether a GML file (plain or gzipped) is GDAL's own (:data:`OGR_NAMESPACE`, no CityGML namespace); its head
    read once per version of the file (asked for each of its features)."""
    try:
        st = Path(path).stat()
    except OSError:
        return False
    return _is_ogr_gml(str(path), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=256)
def _is_ogr_gml(path: str, size: int, mtime_ns: int) -> bool:
    head = _head(Path(path))
    return bool(OGR_NAMESPACE.search(head)) and not CITYGML.search(head)


def holds_parts(path: Path) -> bool:
    """Whether an INSPIRE file's features are ``BuildingPart`` elements."""
    return is_inspire(path) and bool(PART_ELEMENT.search(_head(Path(path))))


def part_building(oid: str) -> str | None:
    """The id of the building a part's id names (:data:`PART_ID`), else None."""
    found = PART_ID.match(str(oid))
    return found.group("building") if found else None


#: GDAL's field for a ``Building``'s ``parts`` links (its GML driver with XML attributes read as fields).
PARTS_HREF = "parts_href"
#: A ``parts`` element with a link, as a file holds it (looked for before the buildings are read for their links).
PARTS_LINK = re.compile(rb"<[A-Za-z0-9_.-]+:parts\s[^>]*href")
#: Bytes read at a time when looking through a file for :data:`PARTS_LINK`.
SCAN_BYTES = 1 << 22


def linked_id(href: str) -> str:
    """The id an ``xlink:href`` names: its text after the last ``#``, ``/`` or ``:`` (``#DE.P1``, ``urn:adv:oid:DE.P1``,
    ``https://.../BuildingPart/DE.P1`` all name ``DE.P1``; an XML id holds none of them)."""
    return re.split(r"[#/:]", str(href).strip())[-1]


def part_links(path: Path) -> dict[str, str]:
    """The parts an INSPIRE file's ``Building`` features link (``bu-core2d:parts``, :func:`linked_id`) -> the linking
    building's ``gml:id``; empty where it links none. Read once per process and file (its size and time of change in
    the key)."""
    return dict(_linking(path)[0])


def linking_buildings(path: Path) -> dict[str, dict]:
    """The properties (:func:`inspire_properties`) of an INSPIRE file's ``Building`` features that link parts, by
    ``gml:id``: what their parts inherit (a height, storeys) where the parts are read apart from them."""
    return _linking(path)[1]


def _linking(path: Path) -> tuple[tuple, dict]:
    try:
        st = Path(path).stat()
    except OSError:
        return (), {}
    return _part_links(str(path), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=8)
def _part_links(path: str, size: int, mtime: int) -> tuple[tuple, dict]:
    import fiona

    from meshsom.io import holds_match

    from meshsom.gis import _gdal_errors, _source

    if not holds_match(Path(path), PARTS_LINK, SCAN_BYTES):  # most files link no parts, and are not read again for it
        return (), {}
    links, buildings = [], {}
    try:
        with fiona.Env(GML_ATTRIBUTES_TO_OGR_FIELDS="YES"), fiona.open(
                _source(Path(path)), layer="Building", WRITE_GFS="NO", ignore_geometry=True) as found:
            if PARTS_HREF not in found.schema["properties"]:
                return (), {}
            for feature in found:
                props = dict(feature.properties)
                hrefs, building = props.pop(PARTS_HREF, None), props.get("gml_id")
                if building is None or not hrefs:
                    continue
                links += [(linked_id(href), str(building)) for href in ([hrefs] if isinstance(hrefs, str) else hrefs)]
                buildings[str(building)] = inspire_properties(props)
    except _gdal_errors():  # no Building layer, or unreadable: its reader says why
        return (), {}
    return tuple(links), buildings


def building_of(props: dict, links: dict[str, str]) -> str | None:
    """The ``gml:id`` of the building a ``BuildingPart``'s properties belong to: the building that links it (by its
    ``gml:id`` or ``localId``), else the one its id names (:func:`part_building`), else None."""
    for key in (props.get("gml_id"), props.get("localId")):
        if key is not None and str(key) in links:
            return links[str(key)]
    return part_building(str(props.get("gml_id") or ""))


#: A ``BuildingPart`` written inside its building's ``parts`` element (a byte pattern: whitespace between the two).
PARTS_INLINE = re.compile(rb"<[A-Za-z0-9_.-]+:parts\s*>\s*<[A-Za-z0-9_.-]+:BuildingPart[\s>]")
#: GML's geometry elements that a part's footprint can be (given its building's ``srsName`` where it has none).
GEOMETRIES = ("Surface", "Polygon", "MultiSurface", "CompositeSurface", "MultiPolygon")


def inline_parts(path: Path) -> list[tuple[str, str, dict, dict | None]]:
    """The ``BuildingPart`` features an INSPIRE file writes inside its ``Building`` features: (the building's
    ``gml:id``, the part's ``gml:id``, its properties as GDAL reads them (:func:`inspire_properties`), its geometry
    (GeoJSON-like; None where GDAL reads none)), in file order; empty where it writes none. Read once per process and
    file (its size and time of change in the key).

    The parts are written out, as the members of one GML collection, into a temporary folder (their namespaces
    declared, the ``srsName`` of the geometry before each given to its geometry where it names none) and read by GDAL's
    GML driver, as a file of parts is.

    Raises
    ------
    InputFileError
        Where the file is not well-formed XML (naming its line), or GDAL cannot read the parts written out.
    """
    try:
        st = Path(path).stat()
    except OSError:
        return []
    return list(_inline_parts(str(path), st.st_size, st.st_mtime_ns))


@functools.lru_cache(maxsize=8)
def _inline_parts(path: str, size: int, mtime: int) -> tuple:
    import tempfile
    import xml.etree.ElementTree as ET

    import fiona

    from meshsom.errors import InputFileError
    from meshsom.io import holds_match, open_input

    if not holds_match(Path(path), PARTS_INLINE, SCAN_BYTES):  # most files write no parts inside their buildings:
        return ()  # not parsed for them
    local = lambda tag: tag.rsplit("}", 1)[-1]  # noqa: E731
    written, stack, srs = [], [], None
    try:
        with open_input(Path(path)) as stream:
            for event, element in ET.iterparse(stream, events=("start-ns", "start", "end")):
                if event == "start-ns":  # the file's prefixes (gml:, xlink:) kept where a part is written out: GDAL
                    try:  # knows gml:id by its prefix
                        ET.register_namespace(*element)
                    except ValueError:  # a prefix ElementTree keeps for itself (ns0)
                        pass
                    continue
                name = local(element.tag)
                if event == "start":
                    stack.append((name, element))
                    srs = element.get("srsName") or srs
                    continue
                stack.pop()
                if name == "BuildingPart" and len(stack) >= 2 and stack[-1][0] == "parts":
                    building = next((e for n, e in reversed(stack) if n == "Building"), None)
                    ids = [v for k, v in element.attrib.items() if local(k) == "id"]
                    if building is not None and ids:
                        gml = next(k for k in element.attrib if local(k) == "id").split("}")[0].lstrip("{")
                        shapes = [e for e in element.iter() if local(e.tag) in GEOMETRIES]
                        if shapes and srs and not any(e.get("srsName") for e in shapes):
                            shapes[0].set("srsName", srs)
                        building_id = next((v for k, v in building.attrib.items() if local(k) == "id"), None)
                        written.append((building_id, ids[0], gml, ET.tostring(element)))
                    stack[-1][1].remove(element)  # parsed: not held
                elif name == "Building":
                    element.clear()
                if len(stack) == 1:  # a member of the collection, read: not held
                    stack[0][1].remove(element)
    except ET.ParseError as err:
        raise InputFileError(path, f"is not well-formed XML at line {err.position[0]} ({err})") from None
    if not written:
        return ()
    found = []
    with tempfile.TemporaryDirectory(prefix="meshsom-inspire-") as folder:
        parts_file = Path(folder) / "parts.gml"
        with open(parts_file, "wb") as out:
            for k, (_, _, gml, text) in enumerate(written):
                if k == 0:
                    out.write(f'<?xml version="1.0" encoding="UTF-8"?>\n<gml:FeatureCollection xmlns:gml="{gml}">\n'.encode())
                out.write(b"<gml:featureMember>" + text + b"</gml:featureMember>\n")
            out.write(b"</gml:FeatureCollection>\n")
        by_id = {part: building for building, part, _, _ in written}
        try:
            with fiona.open(str(parts_file), layer="BuildingPart", WRITE_GFS="NO") as collection:
                for feature in collection:
                    props = inspire_properties(dict(feature.properties))
                    part = str(props.get("gml_id"))
                    geometry = None if feature.geometry is None else {
                        "type": feature.geometry["type"], "coordinates": feature.geometry["coordinates"]}
                    found.append((by_id.get(part), part, props, geometry))
        except Exception as err:  # fiona's and GDAL's own errors
            raise InputFileError(path, f"its BuildingParts written inside their buildings cannot be read by GDAL "
                                       f"({type(err).__name__}: {err})") from None
    return tuple(found)
