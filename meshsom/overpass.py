"""Reading the Overpass API's JSON answers (``[out:json]``): OpenStreetMap data as Overpass turbo's "raw data"
export, OSMnx's cache and most scripts that query Overpass save it.

Such an answer is OpenStreetMap's elements as JSON: ``{"version": 0.6, "generator": "Overpass API ...", "elements":
[{"type": "node", "id": ..., "lat": ..., "lon": ...}, {"type": "way", "id": ..., "nodes": [...], "tags": {...}},
{"type": "relation", ..., "members": [...]}]}``. It is written out as the OSM XML it stands for (nodes, then ways,
then relations, as OpenStreetMap orders them; Overpass writes ways before their nodes with ``>``) into a temporary
folder and read as an extract is (:func:`meshsom.osm.read_osm`: S3DB's buildings, parts, building relations and
roofs), the items naming the JSON file. The answers of ``out geom`` (each way's corners in a ``geometry`` list, and
each relation member's) are read too: a way's nodes are made from its corners (with its node ids, else ids past
every id of the answer).

An answer whose query stopped early says so in its ``remark`` (``runtime error: Query timed out ...``), its elements
then incomplete: every item's notes give the remark.

A building way whose corners the answer does not hold (``out tags``, ``out center``, ``out ids``, or ``out body``
without ``>``, the recursion to its nodes) has no outline to build: each is a rejection saying which query gives
them, so that every building of the answer is either read or listed.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tempfile
from pathlib import Path
from typing import Iterator
from xml.sax.saxutils import quoteattr

from meshsom.errors import InputFileError

#: What a rejection of a building way without corners says to do.
ASK_FOR_GEOMETRY = ("the Overpass answer holds neither its nodes nor its geometry: query with `out geom;`, or "
                    "`(._;>;); out body;`")
#: Characters of an Overpass answer's ``remark`` (a runtime error: the query timed out) given in the items' notes.
REMARK_SHOWN = 300
#: A note on every item read from an Overpass answer.
NOTE = "read from an Overpass API JSON answer, as the OpenStreetMap extract it stands for"


def is_overpass_json(document) -> bool:
    """Whether a parsed JSON document is an Overpass API answer: an object with an ``elements`` list, and an
    ``osm3s`` member, a ``generator`` naming Overpass, or OpenStreetMap's ``version`` 0.6."""
    return (isinstance(document, dict) and isinstance(document.get("elements"), list)
            and ("osm3s" in document or "overpass" in str(document.get("generator", "")).lower()
                 or str(document.get("version")) == "0.6"))


def read_overpass(document: dict, path: Path, options, name: str | None = None) -> Iterator:
    """Read every building of an Overpass API answer (as the module says): RawMesh or Rejection items, their source
    the JSON file.

    Raises
    ------
    InputFileError
        No building among its elements, or elements that are not OpenStreetMap's (naming the first).
    """
    from meshsom.io import Rejection
    from meshsom.osm import read_osm

    name = name or Path(path).name
    remark = document.get("remark")
    with tempfile.TemporaryDirectory(prefix="meshsom-overpass-") as folder:
        extract = Path(folder) / "answer.osm"
        with open(extract, "w", encoding="utf-8") as out:
            unbuilt = overpass_xml(document, str(path), out)
        try:
            items = list(read_osm(extract, options, name))
        except InputFileError as err:
            if not unbuilt:
                raise InputFileError(str(path), err.problem + (f"; the Overpass answer's remark: {str(remark)[:REMARK_SHOWN]}"
                                                               if remark else "")) from None
            items = []
    said = (NOTE,)
    if remark:  # Overpass's word that the query stopped (a timeout, memory): the answer may lack buildings
        said += (f"the Overpass answer's remark: {str(remark)[:REMARK_SHOWN]} (its elements may be incomplete)",)
    for item in items:
        notes = {"notes": said + item.notes} if hasattr(item, "notes") else {}
        yield dataclasses.replace(item, source=str(path), **notes)
    for oid, kind, label in unbuilt:
        what = "way" if oid.startswith("way/") else "multipolygon with ways"
        yield Rejection(f"{name}#{oid}", str(path), f"a {kind} {what} without corners: {ASK_FOR_GEOMETRY}", 0,
                        None if label is None else str(label))


#: Characters XML 1.0 does not allow (C0 controls but tab, newline and carriage return; unpaired surrogates;
#: U+FFFE, U+FFFF): one in a tag's key or value made the whole answer unreadable as OSM XML.
NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def xml_text(text: str) -> str:
    """``text`` with each character XML 1.0 does not allow (:data:`NOT_XML`) replaced by U+FFFD: a JSON string may
    hold any character, OSM XML (what GDAL and libosmium read) not."""
    return NOT_XML.sub("\ufffd", text)


def _whole(value) -> bool:
    """Whether a JSON value is a whole number (not a boolean)."""
    return isinstance(value, int) and not isinstance(value, bool)


def _degrees(value) -> bool:
    """Whether a JSON value is a finite number (a latitude or longitude)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def overpass_xml(document: dict, where: str, out) -> list[tuple[str, str, str | None]]:
    """Write the OSM XML an Overpass answer stands for to ``out`` (a text file), line by line; return its building
    ways (and multipolygons) without corners: (``way/<id>`` or ``relation/<id>``, ``building`` or ``building:part``,
    its ``building`` tag's value).

    A node without a latitude and longitude, a way corner that is not one (outside the query's bounding box, Overpass
    writes null) or a node id that is not a whole number leaves its way without corners.

    Raises
    ------
    InputFileError
        An element that is not an object with a ``type`` of node, way or relation and a whole number ``id``, or whose
        ``tags`` are not an object, or whose ``members`` are not a list of objects (naming the element).
    """
    nodes: dict[int, tuple[float, float, dict]] = {}
    ways: dict[int, tuple[list[int] | None, dict]] = {}
    relations: list[tuple[int, list, dict]] = []
    elements = []
    for index, element in enumerate(document["elements"]):
        kind = element.get("type") if isinstance(element, dict) else None
        number = element.get("id") if isinstance(element, dict) else None
        if kind not in ("node", "way", "relation") or not _whole(number):
            raise InputFileError(where, f"is an Overpass answer whose element {index} is not an OpenStreetMap node, "
                                        f"way or relation with a whole number id (found {str(element)[:120]})")
        tags = element.get("tags") or {}
        members = element.get("members") or []
        if not isinstance(tags, dict) or kind == "relation" and not (
                isinstance(members, list) and all(isinstance(m, dict) for m in members)):
            what = "tags are not an object" if not isinstance(tags, dict) else "members are not a list of objects"
            raise InputFileError(where, f"is an Overpass answer whose element {index} ({kind} {number}): its {what}")
        elements.append((kind, number, element, {str(k): str(v) for k, v in tags.items()}))
    known = [number for kind, number, _, _ in elements if kind == "node"] + [
        n for kind, _, element, _ in elements if kind == "way" and isinstance(element.get("nodes"), list)
        for n in element["nodes"] if _whole(n)]
    made = [max(known + [0])]  # nodes made from corners without ids: past every id of the answer (GDAL's OSM driver
    # reads no negative ids with its fast index)

    def corner_nodes(corners, ids=None) -> list[int] | None:
        if not isinstance(corners, list) or ids is not None and len(ids) != len(corners):
            return None
        refs = []
        for k, corner in enumerate(corners):
            if not isinstance(corner, dict) or not _degrees(corner.get("lat")) or not _degrees(corner.get("lon")):
                return None  # outside the query's bounding box: Overpass writes null
            if ids is None:
                made[0] += 1
            node = ids[k] if ids is not None else made[0]
            nodes.setdefault(node, (float(corner["lat"]), float(corner["lon"]), {}))
            refs.append(node)
        return refs

    for kind, number, element, tags in elements:
        if kind == "node" and _degrees(element.get("lat")) and _degrees(element.get("lon")):
            nodes[number] = (float(element["lat"]), float(element["lon"]), tags)
        elif kind == "relation":
            relations.append((number, element.get("members") or [], tags))
    for kind, number, element, tags in elements:
        if kind != "way":
            continue
        given = element.get("nodes")
        refs = given if isinstance(given, list) and all(_whole(n) for n in given) else None
        if element.get("geometry"):
            refs = corner_nodes(element["geometry"], refs or None)
        ways[number] = (refs, tags)
    for _, members, _ in relations:  # out geom: each way member's corners, where the answer lacks the way
        for member in members:
            ref = member.get("ref")
            if member.get("type") == "way" and _whole(ref) and member.get("geometry") and ref not in ways:
                refs = corner_nodes(member["geometry"])
                if refs:
                    ways[ref] = (refs, {})
    unbuilt = []
    write = lambda line: out.write(line + "\n")  # noqa: E731
    write('<?xml version="1.0" encoding="UTF-8"?>')
    write('<osm version="0.6" generator="meshsom (an Overpass answer)">')
    tag = lambda tags: "".join(f"<tag k={quoteattr(xml_text(k))} v={quoteattr(xml_text(v))}/>"  # noqa: E731
                               for k, v in tags.items())
    built = lambda tags: next((k for k in ("building", "building:part")  # noqa: E731
                               if str(tags.get(k, "no")).strip().lower() != "no"), None)
    for number, (lat, lon, tags) in sorted(nodes.items()):
        write(f'<node id="{number}" version="1" lat="{lat:.7f}" lon="{lon:.7f}">{tag(tags)}</node>')
    written_ways = set()
    for number, (refs, tags) in sorted(ways.items()):
        if not refs or any(r not in nodes for r in refs):
            if built(tags) is not None:
                unbuilt.append((f"way/{number}", built(tags), tags.get("building")))
            continue
        write(f'<way id="{number}" version="1">' + "".join(f'<nd ref="{r}"/>' for r in refs) + f"{tag(tags)}</way>")
        written_ways.add(number)
    for number, members, tags in sorted(relations, key=lambda r: r[0]):
        members = [m for m in members if m.get("type") in ("node", "way", "relation") and _whole(m.get("ref"))]
        if built(tags) is not None and tags.get("type") == "multipolygon" and any(
                m["type"] == "way" and m["ref"] not in written_ways for m in members):
            unbuilt.append((f"relation/{number}", built(tags), tags.get("building")))
            continue
        written = "".join(f"<member type={quoteattr(m['type'])} ref=\"{m['ref']}\" "
                          f"role={quoteattr(str(m.get('role') or ''))}/>" for m in members)
        write(f'<relation id="{number}" version="1">{written}{tag(tags)}</relation>')
    write("</osm>")
    return unbuilt
