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
  attributes (a part without a height takes its building's).
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

#: Namespaces of INSPIRE's Buildings application schemas (2D) as files declare them (INSPIRE's
#: registry, the JRC's older location).
NAMESPACES = (re.compile(rb"inspire[.a-z]*\.europa\.eu/schemas/bu-(core2d|ext2d|base)/"),)
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

    from meshsom.errors import InputFileError
    from meshsom.gis import _gdal_errors, _source
    from meshsom.io import open_input

    try:  # a pass over the bytes: most files link no parts, and are not read again for it
        tail = b""
        with open_input(Path(path)) as stream:
            while chunk := stream.read(SCAN_BYTES):
                if PARTS_LINK.search(tail + chunk):
                    break
                tail = chunk[-256:]
            else:
                return (), {}
    except (OSError, InputFileError):
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
