"""CityGML buildings read as the same buildings in CityJSON.

The bundled real CityJSON files are written out as CityGML by an independent converter (below):
CityGML 1.0, 2.0 and 3.0 namespaces; solids written out or referring (``xlink:href``) to the
polygons of the boundary surfaces; ``posList``, ``pos`` or GML 2 ``coordinates``; BuildingParts.
The reader must give the triangles (in world coordinates), ids, parts, LoDs and labels the CityJSON
reader gives.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from meshsom.citygml import citygml_ranges
from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file

DATA = Path(__file__).resolve().parents[1] / "data" / "real"
NAMESPACES = {
    "1.0": ("http://www.opengis.net/citygml/1.0", "http://www.opengis.net/citygml/building/1.0", "http://www.opengis.net/citygml/generics/1.0"),
    "2.0": ("http://www.opengis.net/citygml/2.0", "http://www.opengis.net/citygml/building/2.0", "http://www.opengis.net/citygml/generics/2.0"),
    "3.0": ("http://www.opengis.net/citygml/3.0", "http://www.opengis.net/citygml/building/3.0", "http://www.opengis.net/citygml/generics/3.0"),
}


def _coords(points, style: str) -> str:
    flat = " ".join(repr(float(x)) for p in points for x in p)
    if style == "posList":
        return f'<gml:posList srsDimension="3">{flat}</gml:posList>'
    if style == "pos":
        return "".join(f"<gml:pos>{p[0]!r} {p[1]!r} {p[2]!r}</gml:pos>" for p in map(lambda q: [float(x) for x in q], points))
    return "<gml:coordinates>" + " ".join(",".join(repr(float(x)) for x in p) for p in points) + "</gml:coordinates>"


def _polygon(rings, world, style, pid=None) -> str:
    parts = []
    for k, ring in enumerate(rings):
        points = [world[i] for i in ring] + [world[ring[0]]]  # closed, as GML writes rings
        tag = "exterior" if k == 0 else "interior"
        parts.append(f"<gml:{tag}><gml:LinearRing>{_coords(points, style)}</gml:LinearRing></gml:{tag}>")
    return f'<gml:Polygon{f" gml:id={chr(34)}{pid}{chr(34)}" if pid else ""}>{"".join(parts)}</gml:Polygon>'


def to_citygml(document: dict, version: str = "2.0", style: str = "posList", href: bool = False) -> str:
    """A CityJSON document's Buildings (and BuildingParts) as CityGML, each geometry at its integer
    LoD: a Solid as ``lod{N}Solid`` (with ``href``: boundary surfaces holding the polygons and a
    Solid referring to them), a MultiSurface as ``lod{N}MultiSurface``. CityGML 3.0 as 3.0 writes
    it: GML 3.2, the LoD properties and ``boundary`` in the core module, the thematic surfaces in
    the construction module (``con:WallSurface``), a Solid's ``gml:Shell``, ``bldg:buildingPart``,
    ``core:genericAttribute`` holding a ``gen:StringAttribute`` of ``gen:name`` and ``gen:value``."""
    core, bldg, gen = NAMESPACES[version]
    three = version == "3.0"
    lodp = "core" if three else "bldg"  # the prefix of the lod{N}... properties
    shell = "Shell" if three else "CompositeSurface"
    t = document.get("transform")
    world = np.asarray(document["vertices"], float)
    if t:
        world = world * t["scale"] + t["translate"]
    world = world.tolist()
    objects = document["CityObjects"]
    counter = [0]

    def geometry_xml(geoms) -> str:
        out = []
        for g in geoms:
            lod = int(float(g["lod"]))
            if g["type"] == "Solid":
                polys = [p for shell_ in g["boundaries"][:1] for p in shell_]
            elif g["type"] == "MultiSurface":
                polys = g["boundaries"]
            else:
                continue
            if g["type"] == "Solid" and href:
                ids = []
                members = []
                for p in polys:
                    counter[0] += 1
                    ids.append(f"poly{counter[0]}")
                    members.append(f"<gml:surfaceMember>{_polygon(p, world, style, ids[-1])}</gml:surfaceMember>")
                wall = "con:WallSurface" if three else "bldg:WallSurface"
                bounded = "core:boundary" if three else "bldg:boundedBy"
                out.append(f"<{bounded}><{wall}><{lodp}:lod{lod}MultiSurface><gml:MultiSurface>{''.join(members)}"
                           f"</gml:MultiSurface></{lodp}:lod{lod}MultiSurface></{wall}></{bounded}>")
                refs = "".join(f'<gml:surfaceMember xlink:href="#{i}"/>' for i in ids)
                out.append(f"<{lodp}:lod{lod}Solid><gml:Solid><gml:exterior><gml:{shell}>{refs}"
                           f"</gml:{shell}></gml:exterior></gml:Solid></{lodp}:lod{lod}Solid>")
            elif g["type"] == "Solid":
                members = "".join(f"<gml:surfaceMember>{_polygon(p, world, style)}</gml:surfaceMember>" for p in polys)
                out.append(f"<{lodp}:lod{lod}Solid><gml:Solid><gml:exterior><gml:{shell}>{members}"
                           f"</gml:{shell}></gml:exterior></gml:Solid></{lodp}:lod{lod}Solid>")
            else:
                members = "".join(f"<gml:surfaceMember>{_polygon(p, world, style)}</gml:surfaceMember>" for p in polys)
                out.append(f"<{lodp}:lod{lod}MultiSurface><gml:MultiSurface>{members}</gml:MultiSurface>"
                           f"</{lodp}:lod{lod}MultiSurface>")
        return "".join(out)

    def attribute_xml(label) -> str:
        if label is None:
            return ""
        if three:
            return (f"<core:genericAttribute><gen:StringAttribute><gen:name>family</gen:name><gen:value>{label}"
                    f"</gen:value></gen:StringAttribute></core:genericAttribute>")
        return f'<gen:stringAttribute name="family"><gen:value>{label}</gen:value></gen:stringAttribute>'

    part_property = "bldg:buildingPart" if three else "bldg:consistsOfBuildingPart"
    members = []
    for oid, obj in objects.items():
        if obj.get("type") != "Building":
            continue
        attr = attribute_xml((obj.get("attributes") or {}).get("family"))
        parts = "".join(
            f'<{part_property}><bldg:BuildingPart gml:id="{c}">{geometry_xml(objects[c].get("geometry", []))}'
            f"</bldg:BuildingPart></{part_property}>" for c in obj.get("children", []) if c in objects)
        members.append(f'<core:cityObjectMember><bldg:Building gml:id="{oid}">{attr}{geometry_xml(obj.get("geometry", []))}'
                       f"{parts}</bldg:Building></core:cityObjectMember>")
    gml = "http://www.opengis.net/gml/3.2" if three else "http://www.opengis.net/gml"
    con = ' xmlns:con="http://www.opengis.net/citygml/construction/3.0"' if three else ""
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<core:CityModel xmlns:core="{core}" xmlns:bldg="{bldg}"{con} '
            f'xmlns:gen="{gen}" xmlns:gml="{gml}" xmlns:xlink="http://www.w3.org/1999/xlink">\n'
            + "\n".join(members) + "\n</core:CityModel>\n")


def _triangles_world(mesh) -> list:
    out = []
    world = np.round(mesh.vertices + mesh.origin, 4)
    for k, face in enumerate(mesh.faces):
        corners = [tuple(world[i]) for i in face]
        first = corners.index(min(corners))
        part = -1 if mesh.face_part is None else mesh.parts[mesh.face_part[k]]
        out.append((str(part), *corners[first:], *corners[:first]))
    return sorted(out)


def assert_same_buildings(got, expected, name):
    got = {i.id.split("#", 1)[1]: i for i in got}
    expected = {i.id.split("#", 1)[1]: i for i in expected}
    assert set(got) == set(expected)
    for key, e in expected.items():
        g = got[key]
        assert g.id == f"{name}#{key}" and type(g) is type(e), (g, e)
        if isinstance(e, Rejection):
            assert g.reason.split(";")[0].split(" at LoD")[0] == e.reason.split(";")[0].split(" at LoD")[0]
            continue
        assert (g.label, g.lod, g.parts) == (e.label, str(int(float(e.lod))), e.parts), key
        assert _triangles_world(g) == _triangles_world(e), key


REAL = [("delft-lod1-3dfier", "delft.city.json"), ("zurich-lod2-subset", "zurich_subset_lod2.city.json")]


@pytest.mark.parametrize("version,style,href", [("2.0", "posList", False), ("2.0", "posList", True),
                                                ("1.0", "pos", True), ("1.0", "coordinates", False),
                                                ("3.0", "posList", True), ("3.0", "pos", False)])
@pytest.mark.parametrize("folder,name", REAL)
def test_citygml_reads_as_the_same_cityjson(tmp_path, folder, name, version, style, href):
    original = DATA / folder / name
    document = json.loads(original.read_text())
    expected = list(read_file(original, ReaderOptions()))
    path = tmp_path / "city.gml"
    path.write_text(to_citygml(document, version, style, href))
    got = list(read_file(path, ReaderOptions()))
    assert sum(isinstance(i, RawMesh) for i in got) == sum(isinstance(i, RawMesh) for i in expected) > 40
    assert_same_buildings(got, expected, "city.gml")


def test_a_wfs_feature_collection_of_buildings_reads_as_a_citymodel(tmp_path):
    """German LoD2 downloads come from WFS services: the buildings are members of a
    wfs:FeatureCollection, not of a CityModel."""
    original = DATA / REAL[0][0] / REAL[0][1]
    xml = to_citygml(json.loads(original.read_text()))
    xml = xml.replace("<core:CityModel ", '<wfs:FeatureCollection xmlns:wfs="http://www.opengis.net/wfs/2.0" ')
    xml = xml.replace("</core:CityModel>", "</wfs:FeatureCollection>").replace("core:cityObjectMember", "wfs:member")
    (tmp_path / "wfs.gml").write_text(xml)
    expected = list(read_file(original, ReaderOptions()))
    assert_same_buildings(list(read_file(tmp_path / "wfs.gml")), expected, "wfs.gml")


def test_citygml_parts_kept_apart_and_gzipped(tmp_path):
    original = DATA / REAL[1][0] / REAL[1][1]
    document = json.loads(original.read_text())
    path = tmp_path / "city.gml.gz"
    path.write_bytes(gzip.compress(to_citygml(document).encode()))
    expected = list(read_file(original, ReaderOptions(parts="separate")))
    got = list(read_file(path, ReaderOptions(parts="separate")))
    assert len(got) == len(expected) > 100
    assert_same_buildings(got, expected, "city.gml.gz")


def test_citygml_labels_from_generic_attributes(tmp_path):
    from meshsom.generate import GeneratorParams, generate_corpus
    from meshsom.io import write_cityjson

    blocks = generate_corpus(GeneratorParams(n_blocks=3, seed=1))
    write_cityjson(tmp_path / "s.city.json", blocks)
    for version in ("2.0", "3.0"):  # gen:stringAttribute name=...; core:genericAttribute of gen:name, gen:value
        (tmp_path / "s.gml").write_text(to_citygml(json.loads((tmp_path / "s.city.json").read_text()), version))
        got = list(read_file(tmp_path / "s.gml"))
        assert [m.label for m in got] == [b.label for b in blocks] and all(m.label for m in got), version


@pytest.mark.parametrize("text,reason", [
    (b"<html><body/></html>", "holds no Building (CityGML bldg:Building); it is XML with root element 'html'"),
    (b"<CityModel><cityObjectMember><Road/></cityObjectMember></CityModel>", "holds no Building (CityGML bldg:Building); it is CityGML"),
    (b"<CityModel><cityObjectMember><Building", "invalid XML at line 1"),
    (b"not xml", "invalid XML at line 1, column 0"),
])
def test_bad_citygml_files_are_rejections_naming_the_problem(tmp_path, text, reason):
    path = tmp_path / "bad.gml"
    path.write_bytes(text)
    (rej,) = read_file(path)
    assert isinstance(rej, Rejection) and rej.id == str(path) and rej.reason.startswith(reason), rej


def _with_undeclared_prefixes(xml: str, building: int, drop_xlink: bool, one_line: bool) -> str:
    """A CityGML text (:func:`to_citygml`) made not well-formed as real files are: an ADE property
    with a prefix no declaration binds (``energy:``, after Japanese text on its line, as PLATEAU's
    attributes are) in the ``building``-th Building and ``uro:`` in a later one, a comment before
    the root, and optionally no ``xmlns:xlink`` although the Solids refer to polygons by xlink:href."""
    head, rest = xml.split("\n", 1)
    if drop_xlink:
        rest = rest.replace(' xmlns:xlink="http://www.w3.org/1999/xlink"', "", 1)
    members = rest.split("<bldg:Building ")
    ade = ('<gen:stringAttribute name="\u5efa\u7269\u540d"><gen:value>\u6771\u4eac\u99c5</gen:value></gen:stringAttribute>'
           '<energy:isHeated>true</energy:isHeated>')
    members[building] = members[building].replace(">", ">" + ade, 1)
    members[building + 3] = members[building + 3].replace(">", '><uro:key uro:code="2">2</uro:key>', 1)
    text = head + "\n<!-- exported <with> a <CityModel> in a comment -->\n" + "<bldg:Building ".join(members)
    return text.replace("\n", "") if one_line else text


@pytest.mark.parametrize("drop_xlink,one_line,gzipped", [(False, False, False), (False, True, True), (True, True, False)])
def test_prefixes_used_without_a_declaration_are_declared_and_nothing_is_lost(tmp_path, drop_xlink, one_line, gzipped):
    """A prefix used without a namespace declaration (not well-formed XML) no longer loses every
    building after it: the file is read again with the prefix declared on its root, the buildings
    read before are not read twice, and the rest carry a note naming the prefixes."""
    original = DATA / REAL[0][0] / REAL[0][1]  # Delft: Solids, referring to their polygons by xlink:href
    declared = tmp_path / "declared.gml"
    declared.write_text(to_citygml(json.loads(original.read_text()), href=True))
    expected = list(read_file(declared))
    text = _with_undeclared_prefixes(declared.read_text(), 5, drop_xlink, one_line).encode()
    path = tmp_path / ("city.gml.gz" if gzipped else "city.gml")
    path.write_bytes(gzip.compress(text) if gzipped else text)
    got = list(read_file(path))
    assert len(got) == len(expected) > 40
    assert_same_buildings(got, [dataclasses.replace(e, id=e.id.replace("declared.gml", path.name)) for e in expected], path.name)
    noted = [any("XML prefix" in n for n in m.notes) for m in got]
    if drop_xlink:  # the first Solid's first reference: every building is read after the prefix was declared
        assert all(noted) and "prefix(es) xlink: without" in got[0].notes[-1]
        assert "prefix(es) xlink:, energy:, uro: without" in got[-1].notes[-1]  # each note: those known by then
    else:
        assert noted == [False] * 4 + [True] * (len(got) - 4) and "prefix(es) energy:, uro: without" in got[-1].notes[-1]


@pytest.mark.parametrize("text,reason", [
    # more undeclared prefixes than UNDECLARED_PREFIXES: refused as not XML
    ("<CityModel>" + "".join(f"<p{k}:x/>" for k in range(20)) + "</CityModel>",
     "invalid XML at line 1, column 11: unbound prefix; with " + ", ".join(f"p{k}:" for k in range(16))
     + " declared, then more than 16 prefixes used undeclared"),
    # declared, then a mismatched tag: both said
    ("<CityModel>\n<b:x><gml:a/></b:y></CityModel>",
     "invalid XML at line 2, column 0: unbound prefix; with b:, gml: declared, then at line 2: mismatched tag"),
    # declared on the root, yet no Building
    ("<CityModel xmlns:gml='http://www.opengis.net/gml'><gml:a/>\n<b:x/></CityModel>", None),
])
def test_files_that_undeclared_prefixes_do_not_explain_are_still_refused(tmp_path, text, reason):
    path = tmp_path / "bad.gml"
    path.write_text(text)
    (item,) = read_file(path)
    if reason is None:  # b: is declared on the root, the file holds no Building
        assert isinstance(item, Rejection) and item.reason.startswith("holds no Building"), item
    else:
        assert isinstance(item, Rejection) and item.reason == reason, item


def test_a_mismatched_tag_is_not_taken_for_an_undeclared_prefix(tmp_path):
    path = tmp_path / "bad.gml"
    path.write_text("<CityModel xmlns:gml='http://www.opengis.net/gml'>\n<a:b></c:d>\n</CityModel>")
    (item,) = read_file(path)
    assert isinstance(item, Rejection) and item.reason.startswith("invalid XML at line 2, column "), item
    assert "mismatched tag" in item.reason, item


def test_a_building_with_bad_coordinates_is_rejected_alone(tmp_path):
    good = '<gml:posList>0 0 0 1 0 0 1 1 0 0 0 0</gml:posList>'
    xml = ('<CityModel xmlns:gml="http://www.opengis.net/gml"><cityObjectMember><Building gml:id="bad"><lod1MultiSurface>'
           '<gml:Polygon><gml:exterior><gml:LinearRing><gml:posList>0 0 x</gml:posList></gml:LinearRing></gml:exterior>'
           '</gml:Polygon></lod1MultiSurface></Building></cityObjectMember><cityObjectMember><Building gml:id="flat">'
           f'<lod1MultiSurface><gml:Polygon><gml:exterior><gml:LinearRing>{good}</gml:LinearRing></gml:exterior>'
           '</gml:Polygon></lod1MultiSurface></Building></cityObjectMember></CityModel>')
    (tmp_path / "b.gml").write_text(xml)
    bad, flat = read_file(tmp_path / "b.gml")
    assert isinstance(bad, Rejection) and bad.id == "b.gml#bad" and "coordinates must be numbers" in bad.reason
    assert isinstance(flat, RawMesh) and flat.id == "b.gml#flat" and len(flat.faces) == 1


def _poly(pid, *points):
    flat = "\n\t\t".join(" ".join(f"{c:.1f}" for c in p) for p in (*points, points[0]))
    return (f'<bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:Polygon gml:id="{pid}"><gml:exterior>'
            f"<gml:LinearRing><gml:posList>{flat}</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon>"
            f"</gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface>")


def test_a_handwritten_lod2_house_as_tools_write_it(tmp_path):
    """As CityGML editors and the SIG3D examples write a house: the default namespace for core, the
    solid first, referring to polygons defined further down in boundary surfaces, coordinates
    across lines, an address point and ADE properties with links that are not polygons."""
    x0, y0, z0 = 458875.0, 5438350.0, 112.0
    c = {k: (x0 + dx, y0 + dy, z0 + dz) for k, (dx, dy, dz) in {
        "a": (0, 0, 0), "b": (10, 0, 0), "c": (10, 5, 0), "d": (0, 5, 0), "A": (0, 0, 3), "B": (10, 0, 3), "C": (10, 5, 3),
        "D": (0, 5, 3), "r": (0, 2.5, 5), "s": (10, 2.5, 5)}.items()}
    surfaces = {"ground": ("GroundSurface", "adcb"), "south": ("WallSurface", "abBA"), "east": ("WallSurface", "bcCsB"),
                "north": ("WallSurface", "cdDC"), "west": ("WallSurface", "daArD"), "roofs": ("RoofSurface", "ABsr"),
                "roofn": ("RoofSurface", "CDrs")}
    refs = "".join(f'<gml:surfaceMember xlink:href="#{pid}"/>' for pid in surfaces)
    bounded = "".join(f"<bldg:boundedBy><bldg:{kind}><gml:name>{pid}</gml:name>{_poly(pid, *[c[k] for k in corners])}"
                      f'<energy:construction xlink:href="#Construction1"/></bldg:{kind}></bldg:boundedBy>'
                      for pid, (kind, corners) in surfaces.items())
    xml = f"""<?xml version="1.0" encoding="utf-8"?>
<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:gml="http://www.opengis.net/gml"
 xmlns:xlink="http://www.w3.org/1999/xlink" xmlns:bldg="http://www.opengis.net/citygml/building/2.0"
 xmlns:energy="http://www.sig3d.org/citygml/2.0/energy/0.7.0">
 <gml:boundedBy><gml:Envelope srsDimension="3"><gml:lowerCorner>458868 5438343 112</gml:lowerCorner></gml:Envelope></gml:boundedBy>
 <cityObjectMember><bldg:Building gml:id="GML_house"><gml:name>Example</gml:name>
  <bldg:measuredHeight uom="m">5.0</bldg:measuredHeight>
  <bldg:lod2Solid><gml:Solid><gml:exterior><gml:CompositeSurface>{refs}</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod2Solid>
  {bounded}
  <bldg:address><Address><multiPoint><gml:MultiPoint><gml:pointMember><gml:Point><gml:pos srsDimension="3">458880.0 5438352.6 112.0</gml:pos>
  </gml:Point></gml:pointMember></gml:MultiPoint></multiPoint></Address></bldg:address>
  <energy:thermalZone><energy:ThermalZone gml:id="ZONE_1"><energy:delimitsBy xlink:href="#ZONE_1"/></energy:ThermalZone></energy:thermalZone>
 </bldg:Building></cityObjectMember>
</CityModel>
"""
    (tmp_path / "house.gml").write_text(xml)
    (house,) = read_file(tmp_path / "house.gml")
    assert isinstance(house, RawMesh) and house.id == "house.gml#GML_house" and house.lod == "2" and house.notes == ()
    from meshsom.preprocess import preprocess

    r = preprocess(house.vertices, house.faces)
    assert r.volume_out == pytest.approx(10 * 5 * 3 + 0.5 * 5 * 2 * 10, rel=1e-9)
    np.testing.assert_allclose(house.origin, [x0 + 5, y0 + 2.5, z0 + 2.5])


def test_buildings_directly_under_the_root_are_read(tmp_path):
    ring = "0 0 0 1 0 0 1 1 0 0 0 0"
    xml = ('<CityModel xmlns:gml="http://www.opengis.net/gml"><Building gml:id="a"><lod1MultiSurface><gml:Polygon><gml:exterior>'
           f'<gml:LinearRing><gml:posList>{ring}</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon></lod1MultiSurface>'
           '</Building></CityModel>')
    (tmp_path / "r.gml").write_text(xml)
    (m,) = read_file(tmp_path / "r.gml")
    assert isinstance(m, RawMesh) and m.id == "r.gml#a" and len(m.faces) == 1


def _ring_xml(points) -> str:
    flat = " ".join(f"{c:.1f}" for p in (*points, points[0]) for c in p)
    return f"<gml:LinearRing><gml:posList>{flat}</gml:posList></gml:LinearRing>"


def _house_and_garage(patches: bool) -> str:
    """The SIG3D 'building and garage' case: a flat-roofed house (10 x 5 x 3 m) and a garage part
    (4 x 5 x 2.5 m) against its east wall. The party wall is written once, in the house (its
    lower east wall); the garage's solid refers to it as ``gml:OrientableSurface orientation="-"``.
    Each solid refers to polygons defined in boundary surfaces; the house's roof surface also holds
    a 0.5 m overhang that is not in the solid. With ``patches`` the garage's polygons are
    ``gml:Surface`` / ``gml:PolygonPatch`` and the house's ground a ``gml:TriangulatedSurface``."""
    P = {"a": (0, 0, 0), "b": (10, 0, 0), "c": (10, 5, 0), "d": (0, 5, 0), "A": (0, 0, 3), "B": (10, 0, 3),
         "C": (10, 5, 3), "D": (0, 5, 3), "m": (10, 0, 2.5), "n": (10, 5, 2.5),
         "e": (14, 0, 0), "f": (14, 5, 0), "E": (14, 0, 2.5), "F": (14, 5, 2.5)}
    x0, y0 = 513000.0, 5402000.0
    pts = {k: (x0 + x, y0 + y, 100.0 + z) for k, (x, y, z) in P.items()}
    house = {"h_ground": "adcb", "h_south": "abBA", "h_east_low": "bcnm", "h_east_high": "mnCB", "h_north": "cdDC",
             "h_west": "daAD", "h_roof": "ABCD"}
    garage = {"g_ground": "bcfe", "g_south": "beEm", "g_east": "efFE", "g_north": "fcnF", "g_roof": "mEFn"}

    def polygon(pid, corners):
        ring = [pts[k] for k in corners]
        if patches and pid.startswith("g_"):
            return (f'<gml:Surface gml:id="{pid}"><gml:patches><gml:PolygonPatch><gml:exterior>{_ring_xml(ring)}'
                    f"</gml:exterior></gml:PolygonPatch></gml:patches></gml:Surface>")
        if patches and pid == "h_ground":
            tri = [ring[:3], [ring[0], ring[2], ring[3]]]
            return (f'<gml:TriangulatedSurface gml:id="{pid}"><gml:trianglePatches>'
                    + "".join(f"<gml:Triangle><gml:exterior>{_ring_xml(t)}</gml:exterior></gml:Triangle>" for t in tri)
                    + "</gml:trianglePatches></gml:TriangulatedSurface>")
        return f'<gml:Polygon gml:id="{pid}"><gml:exterior>{_ring_xml(ring)}</gml:exterior></gml:Polygon>'

    def bounded(surfaces, extra=""):
        return "".join(f"<bldg:boundedBy><bldg:WallSurface><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>"
                       f"{polygon(pid, corners)}</gml:surfaceMember>{extra if pid == 'h_roof' else ''}</gml:MultiSurface>"
                       f"</bldg:lod2MultiSurface></bldg:WallSurface></bldg:boundedBy>" for pid, corners in surfaces.items())

    (ax, ay, az), (cx, cy, _) = pts["A"], pts["C"]
    overhang = [(ax - 0.5, ay - 0.5, az), (cx + 0.5, ay - 0.5, az), (cx + 0.5, cy + 0.5, az), (ax - 0.5, cy + 0.5, az)]
    roof_ring = [pts[k] for k in "ABCD"]
    overhang_xml = (f"<gml:surfaceMember><gml:Polygon><gml:exterior>{_ring_xml(overhang)}</gml:exterior><gml:interior>"
                    f"{_ring_xml(roof_ring[::-1])}</gml:interior></gml:Polygon></gml:surfaceMember>")
    house_solid = "".join(f'<gml:surfaceMember xlink:href="#{pid}"/>' for pid in house)
    garage_solid = ("".join(f'<gml:surfaceMember xlink:href="#{pid}"/>' for pid in garage)
                    + '<gml:surfaceMember><gml:OrientableSurface orientation="-"><gml:baseSurface xlink:href="#h_east_low"/>'
                      "</gml:OrientableSurface></gml:surfaceMember>")
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0"
 xmlns:gml="http://www.opengis.net/gml" xmlns:xlink="http://www.w3.org/1999/xlink">
<core:cityObjectMember><bldg:Building gml:id="house">
 <bldg:lod2Solid><gml:Solid><gml:exterior><gml:CompositeSurface>{house_solid}</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod2Solid>
 {bounded(house, overhang_xml)}
 <bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id="garage">
  <bldg:lod2Solid><gml:Solid><gml:exterior><gml:CompositeSurface>{garage_solid}</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod2Solid>
  {bounded(garage)}
  <bldg:boundedBy><bldg:WallSurface><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:OrientableSurface orientation="-">
  <gml:baseSurface xlink:href="#h_east_low"/></gml:OrientableSurface></gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface>
  </bldg:WallSurface></bldg:boundedBy>
 </bldg:BuildingPart></bldg:consistsOfBuildingPart>
</bldg:Building></core:cityObjectMember>
</core:CityModel>
"""


@pytest.mark.parametrize("patches", [False, True])
def test_a_party_wall_shared_through_an_orientable_surface(tmp_path, patches):
    """The garage's wall is the house's, reversed: read so, each part is closed on its own, and the
    merged building is exactly both volumes (the overhang outside the solids is not read)."""
    from meshsom.preprocess import preprocess

    (tmp_path / "hg.gml").write_text(_house_and_garage(patches))
    (merged,) = read_file(tmp_path / "hg.gml")
    assert isinstance(merged, RawMesh) and merged.parts == ("house", "garage"), merged
    assert preprocess(merged.vertices, merged.faces).volume_out == pytest.approx(150 + 50, rel=1e-9)
    house, garage = read_file(tmp_path / "hg.gml", ReaderOptions(parts="separate"))
    assert (house.id, garage.id) == ("hg.gml#house", "hg.gml#garage")
    assert preprocess(house.vertices, house.faces).volume_out == pytest.approx(150, rel=1e-9)
    assert preprocess(garage.vertices, garage.faces).volume_out == pytest.approx(50, rel=1e-9)
    # the garage holds the party wall once (its solid and its wall surface both refer to it)
    assert len(garage.faces) == 12


def test_thematic_surfaces_are_used_where_an_object_has_no_solid(tmp_path):
    """Without the solids, the boundary surfaces are the shell (with the overhang: then not closed)."""
    xml = _house_and_garage(False)
    import re

    xml = re.sub(r"<bldg:lod2Solid>.*?</bldg:lod2Solid>", "", xml, flags=re.S)
    (tmp_path / "hg.gml").write_text(xml)
    house, garage = read_file(tmp_path / "hg.gml", ReaderOptions(parts="separate"))
    assert len(house.faces) > 14  # the 7 quads' 14 triangles, and the overhang's
    assert len(garage.faces) == 12


def test_the_surfaces_of_the_inside_are_not_shell(tmp_path):
    """A storey's floor slab (CityGML 3.0 FloorSurface; LoD4 ceilings and interior walls) inside
    a house described by its boundary surfaces alone is left out: the house stays one closed shell."""
    import re

    from meshsom.preprocess import preprocess

    xml = re.sub(r"<bldg:lod2Solid>.*?</bldg:lod2Solid>", "", _house_and_garage(False), flags=re.S)
    xml = re.sub(r"<gml:surfaceMember><gml:Polygon><gml:exterior>.*?</gml:Polygon></gml:surfaceMember>", "", xml, flags=re.S)
    (tmp_path / "plain.gml").write_text(xml)
    slab = [(513000.0 + x, 5402000.0 + y, 101.5) for x, y in [(0, 0), (10, 0), (10, 5), (0, 5)]]
    inside = "".join(
        f"<bldg:boundedBy><bldg:{kind}><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:Polygon>"
        f"<gml:exterior>{_ring_xml(slab)}</gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"
        f"</bldg:lod2MultiSurface></bldg:{kind}></bldg:boundedBy>" for kind in ("FloorSurface", "CeilingSurface"))
    (tmp_path / "storeys.gml").write_text(xml.replace('<bldg:Building gml:id="house">', '<bldg:Building gml:id="house">' + inside))
    plain, _ = read_file(tmp_path / "plain.gml", ReaderOptions(parts="separate"))
    house, _ = read_file(tmp_path / "storeys.gml", ReaderOptions(parts="separate"))
    assert len(house.faces) == len(plain.faces) == 14
    assert preprocess(house.vertices, house.faces).volume_out == pytest.approx(150, rel=1e-9)


def _lod0(bid, footprint, z, height_xml="", roof_edge=None):
    ring = _ring_xml([(x, y, z) for x, y in footprint])
    edge = "" if roof_edge is None else (
        f"<bldg:lod0RoofEdge><gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior>"
        f"{_ring_xml([(x, y, z + 4.0) for x, y in roof_edge])}</gml:exterior></gml:Polygon></gml:surfaceMember>"
        f"</gml:MultiSurface></bldg:lod0RoofEdge>")
    return (f'<cityObjectMember><bldg:Building gml:id="{bid}">{height_xml}<bldg:lod0FootPrint><gml:MultiSurface>'
            f"<gml:surfaceMember><gml:Polygon><gml:exterior>{ring}</gml:exterior></gml:Polygon></gml:surfaceMember>"
            f"</gml:MultiSurface></bldg:lod0FootPrint>{edge}</bldg:Building></cityObjectMember>")


def test_a_lod0_footprint_alone_is_extruded_by_its_height(tmp_path):
    """Footprint-only CityGML (as the SIG3D LoD0 house): extruded from the footprint (not from the
    roof edge, the eaves' outline with overhangs) by measuredHeight, else by storeys x 3 m; with
    neither it is a rejection that says so, not a zero volume, or extruded to the default height where one is
    set; CityJSON LoD 0 likewise."""
    from meshsom.preprocess import preprocess

    L = [(0, 0), (12, 0), (12, 4), (4, 4), (4, 10), (0, 10)]
    area = 12 * 4 + 4 * 6
    xml = ('<CityModel xmlns:gml="http://www.opengis.net/gml" xmlns:bldg="http://www.opengis.net/citygml/building/2.0">'
           + _lod0("h", L, 100.0, '<bldg:measuredHeight uom="m">6.5</bldg:measuredHeight>', roof_edge=[(-1, -1), (13, -1), (13, 11), (-1, 11)])
           + _lod0("s", L, 100.0, "<bldg:storeysAboveGround>3</bldg:storeysAboveGround>")
           + _lod0("n", L, 100.0) + "</CityModel>")
    (tmp_path / "lod0.gml").write_text(xml)
    got = {m.id.split("#")[1]: m for m in read_file(tmp_path / "lod0.gml")}
    assert got["h"].lod == "1 (extruded from 0)" and "measuredHeight = 6.5" in got["h"].notes[0]
    assert preprocess(got["h"].vertices, got["h"].faces).volume_out == pytest.approx(area * 6.5, rel=1e-9)
    z = got["h"].vertices[:, 2] + got["h"].origin[2]
    assert z.min() == pytest.approx(100) and z.max() == pytest.approx(106.5)  # from the ground up
    assert preprocess(got["s"].vertices, got["s"].faces).volume_out == pytest.approx(area * 9.0, rel=1e-9)
    assert isinstance(got["n"], Rejection) and "only a LoD 0 footprint" in got["n"].reason and "measuredHeight" in got["n"].reason
    with_default = {m.id.split("#")[1]: m for m in read_file(tmp_path / "lod0.gml", ReaderOptions(default_height=7.0))}
    assert preprocess(with_default["n"].vertices, with_default["n"].faces).volume_out == pytest.approx(area * 7, rel=1e-9)
    assert "to the default 7 m" in with_default["n"].notes[0]
    (lod0,) = [m for m in read_file(tmp_path / "lod0.gml", ReaderOptions(lod="0")) if m.id.endswith("#h")]
    assert lod0.lod == "0" and np.ptp(lod0.vertices[:, 2]) == 0  # asked for by name: the footprint as it is
    cj = {"type": "CityJSON", "version": "2.0", "transform": {"scale": [0.001] * 3, "translate": [0, 0, 0]},
          "CityObjects": {"b": {"type": "Building", "attributes": {"measuredHeight": 6.5},
                                "geometry": [{"type": "MultiSurface", "lod": "0", "boundaries": [[list(range(6))]]}]}},
          "vertices": [[x * 1000, y * 1000, 0] for x, y in L]}
    (tmp_path / "lod0.city.json").write_text(json.dumps(cj))
    (m,) = read_file(tmp_path / "lod0.city.json")
    assert preprocess(m.vertices, m.faces).volume_out == pytest.approx(area * 6.5, rel=1e-9)


def test_a_citygml3_lod0_footprint_is_extruded_by_its_con_height(tmp_path):
    """CityGML 3.0 has no measuredHeight: a building's heights are ``con:height`` elements, each from a reference to
    another. One from the ground to the highest roof edge (in metres, or in feet, converted) extrudes a LoD 0
    footprint; one to the eaves does not, and storeys do where no such height is given."""
    from meshsom.preprocess import preprocess

    L = [(0, 0), (12, 0), (12, 4), (4, 4), (4, 10), (0, 10)]
    area = 12 * 4 + 4 * 6

    def height(high, value, uom="m", low="lowestGroundPoint"):
        return (f"<con:height><con:Height><con:highReference>{high}</con:highReference><con:lowReference>{low}"
                f"</con:lowReference><con:status>measured</con:status><con:value uom=\"{uom}\">{value}</con:value>"
                f"</con:Height></con:height>")

    def building(bid, inside):
        ring = _ring_xml([(x, y, 50.0) for x, y in L])
        return (f'<core:cityObjectMember><bldg:Building gml:id="{bid}">{inside}<core:lod0MultiSurface><gml:MultiSurface>'
                f"<gml:surfaceMember><gml:Polygon><gml:exterior>{ring}</gml:exterior></gml:Polygon></gml:surfaceMember>"
                f"</gml:MultiSurface></core:lod0MultiSurface></bldg:Building></core:cityObjectMember>")

    core, bldg, _ = NAMESPACES["3.0"]
    xml = (f'<core:CityModel xmlns:core="{core}" xmlns:bldg="{bldg}" xmlns:gml="http://www.opengis.net/gml/3.2" '
           f'xmlns:con="http://www.opengis.net/citygml/construction/3.0">'
           + building("top", height("generalEave", "5.0") + height("highestRoofEdge", "8.5"))
           + building("eaves", height("generalEave", "5.0") + "<bldg:storeysAboveGround>2</bldg:storeysAboveGround>")
           + building("feet", height("highestRoofEdge", "30", uom="ft"))
           + "</core:CityModel>")
    (tmp_path / "lod0.gml").write_text(xml)
    got = {m.id.split("#")[1]: m for m in read_file(tmp_path / "lod0.gml")}
    assert preprocess(got["top"].vertices, got["top"].faces).volume_out == pytest.approx(area * 8.5, rel=1e-9)
    assert preprocess(got["eaves"].vertices, got["eaves"].faces).volume_out == pytest.approx(area * 6.0, rel=1e-9)
    # a height in feet is converted, and says so
    assert preprocess(got["feet"].vertices, got["feet"].faces).volume_out == pytest.approx(area * 30 * 0.3048, rel=1e-9)
    assert any("30 ft read as 9.144 m" in n for n in got["feet"].notes), got["feet"].notes


# ----------------------------------------------------------------------------- what a building holds beside its shell

#: A box's corners (unit cube) and its faces as quads, counter-clockwise seen from outside.
CUBE = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
CUBE_QUADS = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
BLDG2 = ('<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:gml="http://www.opengis.net/gml" '
         'xmlns:xlink="http://www.w3.org/1999/xlink" xmlns:bldg="http://www.opengis.net/citygml/building/2.0">')
BLDG3 = ('<core:CityModel xmlns:core="http://www.opengis.net/citygml/3.0" xmlns:gml="http://www.opengis.net/gml/3.2" '
         'xmlns:xlink="http://www.w3.org/1999/xlink" xmlns:bldg="http://www.opengis.net/citygml/building/3.0" '
         'xmlns:con="http://www.opengis.net/citygml/construction/3.0">')


def _box_polygons(origin, size, inward=False) -> str:
    """A box's six polygons (``gml:surfaceMember``s), outward (or ``inward``: a cavity's shell as GML writes it)."""
    corners = [tuple(o + c * d for o, c, d in zip(origin, corner, size)) for corner in CUBE]
    quads = [q[::-1] if inward else q for q in CUBE_QUADS]
    return "".join(f"<gml:surfaceMember><gml:Polygon><gml:exterior>{_ring_xml([corners[i] for i in q])}</gml:exterior>"
                   f"</gml:Polygon></gml:surfaceMember>" for q in quads)


def _box_solid(prop, origin, size, cavity=None, srs="") -> str:
    """``<prop>`` holding a gml:Solid of a box (and a cavity: ``(origin, size, inward)`` as an interior shell)."""
    inner = "" if cavity is None else (f"<gml:interior><gml:CompositeSurface>{_box_polygons(*cavity)}"
                                       f"</gml:CompositeSurface></gml:interior>")
    return (f"<{prop}><gml:Solid{srs}><gml:exterior><gml:CompositeSurface>{_box_polygons(origin, size)}"
            f"</gml:CompositeSurface></gml:exterior>{inner}</gml:Solid></{prop}>")


@pytest.mark.parametrize("cavity_inward", [True, False])
def test_what_a_building_holds_inside_it_is_not_its_volume(tmp_path, cavity_inward):
    """As the OGC's CityGML 3.0 examples and citygml4j's test ADE hold them: storeys and building units (apartments)
    with solids of their own inside the building are not its shell; a Solid's interior shell (a cavity) counts
    against its volume, however the file orients it (GML: facing into the cavity; some writers: outward)."""
    from meshsom.preprocess import preprocess

    base = (391000.0, 5820000.0, 34.0)
    subdivisions = "".join(
        f'<bldg:buildingSubdivision><bldg:{kind} gml:id="{kind}{k}">{_box_solid("core:lod1Solid", (base[0] + 1, base[1] + 1, base[2] + 3 * k), (8, 6, 2.8))}'
        f"</bldg:{kind}></bldg:buildingSubdivision>" for k, kind in enumerate(("Storey", "BuildingUnit")))
    xml3 = (BLDG3 + '<core:cityObjectMember><bldg:Building gml:id="units">' + _box_solid("core:lod2Solid", base, (10, 8, 6))
            + subdivisions + "</bldg:Building></core:cityObjectMember></core:CityModel>")
    (tmp_path / "units.gml").write_text(xml3)
    (units,) = read_file(tmp_path / "units.gml")
    assert preprocess(units.vertices, units.faces).volume_out == pytest.approx(480, rel=1e-9)
    ade = ('<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:gml="http://www.opengis.net/gml" '
           'xmlns:bldg="http://www.opengis.net/citygml/building/2.0" xmlns:test="http://www.citygml.org/ade/TestADE/1.0">'
           '<cityObjectMember><bldg:Building gml:id="ade">' + _box_solid("bldg:lod2Solid", base, (10, 8, 6))
           + '<test:buildingUnit><test:BuildingUnit gml:id="flat1">' + _box_solid("test:lod2Solid", (base[0] + 1, base[1] + 1, base[2] + 1), (4, 4, 4))
           + "</test:BuildingUnit></test:buildingUnit></bldg:Building></cityObjectMember></CityModel>")
    (tmp_path / "ade.gml").write_text(ade)
    (unit_ade,) = read_file(tmp_path / "ade.gml")
    assert preprocess(unit_ade.vertices, unit_ade.faces).volume_out == pytest.approx(480, rel=1e-9)
    cavity = ((base[0] + 2, base[1] + 2, base[2] + 2), (2, 2, 2), cavity_inward)
    xml = (BLDG2 + '<cityObjectMember><bldg:Building gml:id="hollow">'
           + _box_solid("bldg:lod2Solid", base, (10, 8, 6), cavity=cavity) + "</bldg:Building></cityObjectMember></CityModel>")
    (tmp_path / "hollow.gml").write_text(xml)
    (hollow,) = read_file(tmp_path / "hollow.gml")
    r = preprocess(hollow.vertices, hollow.faces)
    assert r.volume_out == pytest.approx(480 - 8, rel=1e-9)
    assert not cavity_inward or not any("flipped" in rep for rep in r.repairs)  # already as GML has it
    assert cavity_inward or any("1 inner shell(s), cavities, facing in" in rep for rep in r.repairs), r.repairs


def test_an_address_in_another_crs_does_not_set_the_buildings(tmp_path):
    """The OGC's LoD 2 example with attributes: the geometry names no CRS (the model's envelope does: a national
    grid), its address locates the entrance in WGS 84: the building is in the envelope's CRS."""
    from meshsom.preprocess import preprocess

    base = (4468000.0, 5333000.0, 500.0)
    address = ('<bldg:address><core:Address xmlns:core="http://www.opengis.net/citygml/2.0"><core:multiPoint>'
               '<gml:MultiPoint srsName="EPSG:4326"><gml:pointMember><gml:Point><gml:pos>48.1 11.5 500</gml:pos>'
               '</gml:Point></gml:pointMember></gml:MultiPoint></core:multiPoint></core:Address></bldg:address>')
    xml = (BLDG2 + '<gml:boundedBy><gml:Envelope srsName="EPSG:31468" srsDimension="3"><gml:lowerCorner>4468000 5333000 500'
           '</gml:lowerCorner><gml:upperCorner>4468010 5333008 506</gml:upperCorner></gml:Envelope></gml:boundedBy>'
           '<cityObjectMember><bldg:Building gml:id="b">' + address + _box_solid("bldg:lod2Solid", base, (10, 8, 6))
           + "</bldg:Building></cityObjectMember></CityModel>")
    (tmp_path / "addr.gml").write_text(xml)
    (b,) = read_file(tmp_path / "addr.gml")
    assert isinstance(b, RawMesh), b
    assert preprocess(b.vertices, b.faces).volume_out == pytest.approx(480, rel=1e-6)
    np.testing.assert_allclose(b.origin, [4468005, 5333004, 503], atol=1e-6)


def test_lod0_footprints_as_citygml3_and_2d_files_give_them(tmp_path):
    """The OGC's CityGML 3.0 LoD 0 example: the building's footprint (its own lod0MultiSurface) beside its roof's LoD 0
    outline (the eaves, larger), and a con:height of ``uom="#m"``: the footprint extruded by 5 m, not the eaves' outline
    by storeys x 3 m. A 2D footprint (``srsDimension="2"``, as 2D LoD 0 files give it) with a height in feet: read at
    z = 0, the height converted."""
    from meshsom.preprocess import preprocess

    foot = [(0, 0), (10, 0), (10, 5), (0, 5)]
    eaves = [(-0.4, -0.31), (10.4, -0.31), (10.4, 5.31), (-0.4, 5.31)]

    def multi(ring):
        return f"<gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior>{ring}</gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"

    height = ('<con:height><con:Height><con:highReference>highestRoofEdge</con:highReference><con:lowReference>'
              'lowestGroundPoint</con:lowReference><con:status>measured</con:status><con:value uom="#m">5.0</con:value>'
              '</con:Height></con:height>')
    xml = (BLDG3 + '<core:cityObjectMember><bldg:Building gml:id="b">' + height
           + "<bldg:storeysAboveGround>1</bldg:storeysAboveGround>"
           + f"<core:lod0MultiSurface>{multi(_ring_xml([(x, y, 0.0) for x, y in foot]))}</core:lod0MultiSurface>"
           + "<core:boundary><con:RoofSurface><core:lod0MultiSurface>"
           + multi(_ring_xml([(x, y, 5.0) for x, y in eaves])) + "</core:lod0MultiSurface></con:RoofSurface></core:boundary>"
           + "</bldg:Building></core:cityObjectMember></core:CityModel>")
    (tmp_path / "lod0.gml").write_text(xml)
    (b,) = read_file(tmp_path / "lod0.gml")
    assert preprocess(b.vertices, b.faces).volume_out == pytest.approx(250, rel=1e-9), b.notes
    flat = " ".join(f"{x} {y}" for x, y in [*foot, foot[0]])
    xml2 = (BLDG2 + '<cityObjectMember><bldg:Building gml:id="f"><bldg:measuredHeight uom="ft">16.4042</bldg:measuredHeight>'
            '<bldg:lod0FootPrint><gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing>'
            f'<gml:posList srsDimension="2">{flat}</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon>'
            "</gml:surfaceMember></gml:MultiSurface></bldg:lod0FootPrint></bldg:Building></cityObjectMember></CityModel>")
    (tmp_path / "flat.gml").write_text(xml2)
    (f,) = read_file(tmp_path / "flat.gml")
    assert preprocess(f.vertices, f.faces).volume_out == pytest.approx(50 * 16.4042 * 0.3048, rel=1e-9)
    assert any("16.4042 ft read as 5 m" in n for n in f.notes), f.notes
    (tmp_path / "flat2.gml").write_text(xml2.replace("lod0FootPrint", "lod2MultiSurface"))
    (g,) = read_file(tmp_path / "flat2.gml")  # 2D rings are footprints alone
    assert isinstance(g, Rejection) and "not 3D" in g.reason and "LoD 0" in g.reason


def test_parts_and_lods_that_are_not_merged_are_said_and_not_lost(tmp_path):
    """A BuildingPart written as a member of its own that its building refers to (``xlink:href``): read as a
    building of its own, both noted; a part with no geometry at the LoD read: noted; a LoD 3 of a ground polygon
    alone (tum-gis' FZK-Haus): flat, passed over for the LoD 2 solid; a file of no Building names what it holds."""
    from meshsom.preprocess import preprocess

    base = (513000.0, 5402000.0, 100.0)
    xml = (BLDG2 + '<cityObjectMember><bldg:Building gml:id="house">' + _box_solid("bldg:lod2Solid", base, (10, 5, 3))
           + '<bldg:consistsOfBuildingPart xlink:href="#garage"/></bldg:Building></cityObjectMember>'
           + '<cityObjectMember><bldg:BuildingPart gml:id="garage">'
           + _box_solid("bldg:lod2Solid", (base[0] + 10, base[1], base[2]), (4, 5, 2.5))
           + "</bldg:BuildingPart></cityObjectMember></CityModel>")
    (tmp_path / "ref.gml").write_text(xml)
    house, garage = read_file(tmp_path / "ref.gml")
    assert (house.id, garage.id) == ("ref.gml#house", "ref.gml#garage")
    assert any("#garage" in n and "not merged" in n for n in house.notes), house.notes
    assert any("outside any Building" in n for n in garage.notes), garage.notes
    assert preprocess(garage.vertices, garage.faces).volume_out == pytest.approx(50, rel=1e-9)
    lod1_part = xml.replace('<bldg:consistsOfBuildingPart xlink:href="#garage"/></bldg:Building></cityObjectMember>'
                            '<cityObjectMember><bldg:BuildingPart gml:id="garage">',
                            '<bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id="garage">').replace(
        "</bldg:BuildingPart></cityObjectMember>", "</bldg:BuildingPart></bldg:consistsOfBuildingPart></bldg:Building></cityObjectMember>")
    lod1_part = lod1_part.replace("bldg:lod2Solid", "bldg:lod1Solid").replace("bldg:lod1Solid", "bldg:lod2Solid", 2)
    (tmp_path / "lod1part.gml").write_text(lod1_part)
    (merged,) = read_file(tmp_path / "lod1part.gml")
    assert merged.lod == "2" and preprocess(merged.vertices, merged.faces).volume_out == pytest.approx(150, rel=1e-9)
    assert any("1 of its 2 objects (garage) have no geometry at LoD 2" in n for n in merged.notes), merged.notes
    ground = [(base[0] + x, base[1] + y, base[2]) for x, y in [(0, 0), (0, 5), (10, 5), (10, 0)]]
    lod3 = (BLDG2 + '<cityObjectMember><bldg:Building gml:id="fzk">' + _box_solid("bldg:lod2Solid", base, (10, 5, 3))
            + f"<bldg:lod3MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior>{_ring_xml(ground)}"
            + "</gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface></bldg:lod3MultiSurface>"
            + "</bldg:Building></cityObjectMember></CityModel>")
    (tmp_path / "lod3.gml").write_text(lod3)
    (fzk,) = read_file(tmp_path / "lod3.gml")
    assert fzk.lod == "2" and any("LoD 3 geometry is flat" in n for n in fzk.notes), (fzk.lod, fzk.notes)
    assert preprocess(fzk.vertices, fzk.faces).volume_out == pytest.approx(150, rel=1e-9)
    roads = BLDG2 + "".join(f'<cityObjectMember><tran:{k} xmlns:tran="http://www.opengis.net/citygml/transportation/2.0" '
                            f'gml:id="{k}{n}"/></cityObjectMember>' for k in ("Road", "Road", "Square") for n in range(1)) + "</CityModel>"
    (tmp_path / "roads.gml").write_text(roads)
    (rejected,) = read_file(tmp_path / "roads.gml")
    assert isinstance(rejected, Rejection) and rejected.reason.endswith("it is CityGML holding 2 Road, 1 Square"), rejected.reason


# ----------------------------------------------------------------------------- large files read in ranges

GHOST = '<!-- removed: <core:cityObjectMember><bldg:Building gml:id="ghost"></bldg:Building></core:cityObjectMember> -->'
APPEARANCE = ('<app:appearanceMember xmlns:app="http://www.opengis.net/citygml/appearance/2.0"><app:Appearance>'
              '<app:theme>rgb</app:theme></app:Appearance></app:appearanceMember>')


def _as_collection(xml: str, member: str) -> str:
    """:func:`to_citygml`'s text as a WFS answer holds it: a ``wfs:FeatureCollection`` of ``member``s (``wfs:member``
    of WFS 2.0, ``gml:featureMember`` of WFS 1.1), as German LoD 2 downloads come."""
    return (xml.replace("<core:CityModel ", '<wfs:FeatureCollection xmlns:wfs="http://www.opengis.net/wfs/2.0" ', 1)
            .replace("</core:CityModel>", "</wfs:FeatureCollection>")
            .replace("core:cityObjectMember", member))


def _large_citygml(version: str, member: str, every: int = 7) -> str:
    """Delft's buildings as a CityGML text of the kinds a city's large files hold between and in their members: every
    ``every``-th Building without ``gml:id`` (read by its ordinal), appearance members and a comment holding a
    member's and a Building's tags between members, members written on one line or across lines."""
    text = to_citygml(json.loads((DATA / REAL[0][0] / REAL[0][1]).read_text()), version, href=True)
    if member != "core:cityObjectMember":
        text = _as_collection(text, member)
    head, *members = text.split(f"<{member}>")
    out = []
    for k, m in enumerate(members):
        if k % every == 3:
            m = re.sub(r'<bldg:Building gml:id="[^"]*">', "<bldg:Building>", m, count=1)
        between = (APPEARANCE if k % 5 == 1 else "") + (GHOST if k % 9 == 2 else "")
        out.append(between + "\n  " + (m.replace("><", ">\n    <") if k % 2 else m))
    return head + "".join(f"<{member}>" + m for m in out)


@pytest.mark.parametrize("scan_bytes,margin", [(None, None), (1999, 64)])
@pytest.mark.parametrize("version,member", [("2.0", "core:cityObjectMember"), ("3.0", "core:cityObjectMember"),
                                            ("2.0", "wfs:member"), ("1.0", "gml:featureMember")])
def test_a_large_citygml_file_is_read_in_ranges_as_whole(tmp_path, monkeypatch, version, member, scan_bytes, margin):
    """A CityGML file cut into ranges of whole members (scanned in steps down to under 2 kB, comments holding members'
    tags passed over) reads, range by range, as the whole file does: the same ids (a Building without gml:id by its
    place in the file), sources, triangles, parts, labels and notes, each Building once; each range starts at a
    member's start tag and every member lies in one range, as an XML parser finds them."""
    import meshsom.citygml as citygml

    if scan_bytes:
        monkeypatch.setattr(citygml, "SCAN_BYTES", scan_bytes)
        monkeypatch.setattr(citygml, "TAG_MARGIN", margin)
    path = tmp_path / "city.gml"
    path.write_text(_large_citygml(version, member))
    data = path.read_bytes()
    whole = list(read_file(path))
    assert len(whole) > 100 and any("#building-" in m.id for m in whole) and not any("ghost" in m.id for m in whole)
    for target in (1, 30_000, len(data) // 3):
        ranges = citygml.citygml_ranges(path, target, ReaderOptions())
        assert ranges is not None and len(ranges) >= 2
        assert all(data[a:].startswith(f"<{member}>".encode()) for a, *_ in ranges)
        assert [r[1] for r in ranges[:-1]] == [r[0] for r in ranges[1:]]
        local = member.split(":")[1]  # every member of the root, as an XML parser finds them, in one range
        members = [len([c for c in ET.fromstring(text) if c.tag.endswith("}" + local)]) for text in
                   [data] + [data[:r[3]] + data[r[0]:r[1]] + data[r[4]:] for r in ranges]]
        assert sum(members[1:]) == members[0] and all(members[1:])
        assert all(data.count(b"\n", 0, r[0]) + 1 == r[5] for r in ranges)
        got = [item for r in ranges for item in read_file(path, byte_range=r)]
        assert [g.id for g in got] == [w.id for w in whole]
        for g, w in zip(got, whole):
            assert type(g) is type(w) and g.source == w.source and g.notes == w.notes, g.id
            if isinstance(w, RawMesh):
                assert (g.label, g.lod, g.parts) == (w.label, w.lod, w.parts), g.id
                assert np.array_equal(g.faces, w.faces) and np.array_equal(g.vertices + g.origin, w.vertices + w.origin)


def test_citygml_files_that_cannot_be_cut_between_members_are_read_whole(tmp_path):
    """A small file, a gzipped one (gzip cannot be entered mid-stream), one whose Buildings stand in two kinds of
    member (one would be read by every range, or by none), and one holding members inside members, are not split."""
    text = _large_citygml("2.0", "core:cityObjectMember")
    options = ReaderOptions()
    path = tmp_path / "city.gml"
    path.write_text(text)
    assert citygml_ranges(path, 1000, options) is not None
    assert citygml_ranges(path, len(text), options) is None  # under twice the target
    (tmp_path / "city.gml.gz").write_bytes(gzip.compress(text.encode()))
    assert citygml_ranges(tmp_path / "city.gml.gz", 1000, options) is None
    head, rest = text.split("<core:cityObjectMember>", 1)
    mixed = head + "<gml:featureMember>" + rest.split("</core:cityObjectMember>", 1)[0] + "</gml:featureMember>" + \
        "<core:cityObjectMember>" + rest.split("<core:cityObjectMember>", 1)[1]
    (tmp_path / "mixed.gml").write_text(mixed)
    assert len(list(read_file(tmp_path / "mixed.gml"))) == len(list(read_file(path)))
    assert citygml_ranges(tmp_path / "mixed.gml", 1000, options) is None
    nested = text.replace("<bldg:Building gml:id=", "<core:cityObjectMember/><bldg:Building gml:id=", 1).replace(
        "</core:cityObjectMember>", "<core:cityObjectMember>", 1)
    (tmp_path / "nested.gml").write_text(nested)
    assert citygml_ranges(tmp_path / "nested.gml", 1000, options) is None


def test_ranges_of_a_citygml_file_with_undeclared_prefixes_and_an_error_lose_nothing(tmp_path):
    """A range that meets a prefix used without a declaration reads again with it declared, its Buildings from there
    on noted (read whole, every Building after the first use is); ranges without one read as they are. A member that
    is not well-formed rejects its range, naming the line of the file that the whole file's rejection names, and the
    other ranges are read."""
    original = DATA / REAL[0][0] / REAL[0][1]
    declared = to_citygml(json.loads(original.read_text()), href=True).replace("><core:cityObjectMember>",
                                                                              ">\n<core:cityObjectMember>")
    text = _with_undeclared_prefixes(declared, 30, False, False)
    path = tmp_path / "city.gml"
    path.write_text(text)
    whole = list(read_file(path))
    ranges = citygml_ranges(path, 20_000, ReaderOptions())
    assert ranges is not None and len(ranges) > 5
    got = [item for r in ranges for item in read_file(path, byte_range=r)]
    assert [g.id for g in got] == [w.id for w in whole]
    noted = [any("XML prefix" in n for n in g.notes) for g in got]
    assert noted[:29] == [False] * 29 and noted[29] and noted[32] and not noted[-1], noted  # those of its ranges
    lines = declared.split("\n")
    k = next(i for i, line in enumerate(lines) if i > len(lines) // 2 and line.startswith("<core:cityObjectMember>"))
    lines[k] = lines[k].replace("</gml:posList>", "</gml:pos>", 1)
    path.write_text("\n".join(lines))
    *before, rejection = list(read_file(path))  # read whole: the Buildings before the error, and the error
    assert isinstance(rejection, Rejection) and rejection.reason.startswith(f"invalid XML at line {k + 1}, column ")
    items = [item for r in citygml_ranges(path, 20_000, ReaderOptions()) for item in read_file(path, byte_range=r)]
    rejected = [i for i in items if isinstance(i, Rejection)]
    assert len(rejected) == 1 and rejected[0].reason.split(", column")[0] == rejection.reason.split(", column")[0]
    assert rejected[0].id == rejection.id and len(before) < len(items) - 1 < len(whole)  # the ranges after it read


def test_citygml_saved_as_xml_is_read_and_other_xml_is_not(tmp_path):
    """Some states save their CityGML tiles as ``.xml`` (Hamburg's LoD 2): read by its namespace as the same file
    named ``.gml`` (gzipped too); an XML file that is not CityGML (a tile's ISO metadata beside it) is refused saying
    so, and listed as skipped where a folder is read."""
    from meshsom.io import expand_inputs, input_kind

    text = to_citygml(json.loads((DATA / REAL[0][0] / REAL[0][1]).read_text()))
    (tmp_path / "tiles").mkdir()
    (tmp_path / "tiles" / "LoD2_32_565_5933_1_HH.xml").write_text(text)
    (tmp_path / "tiles" / "LoD2_32_565_5933_1_HH.xml.gz").write_bytes(gzip.compress(text.encode()))
    (tmp_path / "tiles" / "metadata.xml").write_text('<?xml version="1.0"?><gmd:MD_Metadata '
                                                     'xmlns:gmd="http://www.isotc211.org/2005/gmd"/>')
    (tmp_path / "tile.gml").write_text(text)
    want = list(read_file(tmp_path / "tile.gml"))
    for name in ("LoD2_32_565_5933_1_HH.xml", "LoD2_32_565_5933_1_HH.xml.gz"):
        assert input_kind(tmp_path / "tiles" / name) == "citygml"
        got = list(read_file(tmp_path / "tiles" / name))
        assert_same_buildings(got, [dataclasses.replace(w, id=w.id.replace("tile.gml", name)) for w in want], name)
    (refused,) = read_file(tmp_path / "tiles" / "metadata.xml")
    assert isinstance(refused, Rejection) and "is an XML file that is not CityGML" in refused.reason
    skipped = []
    files, _ = expand_inputs([tmp_path / "tiles"], skipped)
    assert sorted(f.name for f in files) == ["LoD2_32_565_5933_1_HH.xml", "LoD2_32_565_5933_1_HH.xml.gz"]
    assert [(Path(p).name, "not CityGML" in why) for p, why in skipped] == [("metadata.xml", True)]


def test_an_energy_ade_thermal_zone_is_not_the_buildings_shell(tmp_path):
    """The Energy ADE (as CityGML2Eplus's Alderaan samples write it) gives a building thermal zones with solids of their
    own, at LoD 3 where the building stops at LoD 2: the zone was read as the building's highest LoD (lod "3", the
    heated volume for the building's). An ADE's elements (a namespace not OGC's) are not the shell: the building is
    its LoD 2 solid at every --lod, whatever volume the zone has."""
    from meshsom.preprocess import preprocess

    base = (391000.0, 5820000.0, 34.0)
    zone = ('<energy:thermalZone><energy:ThermalZone gml:id="zone1">'
            + _box_solid("energy:lod3Solid", (base[0] + 0.3, base[1] + 0.3, base[2] + 0.3), (9.4, 7.4, 5.4))
            + '<energy:boundedBy><energy:ThermalBoundary gml:id="tb1"><energy:lod2MultiSurface><gml:MultiSurface>'
            + '<gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing><gml:posList>'
            + " ".join(f"{base[0] + x} {base[1] + y} {base[2]}" for x, y in ((0, 0), (0, 30), (30, 30), (30, 0), (0, 0)))
            + "</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"
            + "</energy:lod2MultiSurface></energy:ThermalBoundary></energy:boundedBy>"
            + "</energy:ThermalZone></energy:thermalZone>")
    xml = ('<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:gml="http://www.opengis.net/gml" '
           'xmlns:bldg="http://www.opengis.net/citygml/building/2.0" '
           'xmlns:energy="http://www.sig3d.org/citygml/2.0/energy/1.0">'
           '<cityObjectMember><bldg:Building gml:id="b">' + _box_solid("bldg:lod2Solid", base, (10, 8, 6))
           + zone + "</bldg:Building></cityObjectMember></CityModel>")
    (tmp_path / "energy.gml").write_text(xml)
    for lod in ("highest", "lowest", "2"):
        (b,) = read_file(tmp_path / "energy.gml", ReaderOptions(lod=lod))
        assert isinstance(b, RawMesh) and b.lod == "2", (lod, b)
        assert preprocess(b.vertices, b.faces).volume_out == pytest.approx(480, rel=1e-9)


@pytest.mark.parametrize("srs, lat_first", [("EPSG:4326", False), ("http://www.opengis.net/gml/srs/epsg.xml#4326", False),
                                            ("urn:ogc:def:crs:EPSG::4326", True),
                                            ("http://www.opengis.net/def/crs/EPSG/0/4326", True)])
def test_gml_srs_name_forms_say_the_axis_order(tmp_path, srs, lat_first):
    """An FME export of Gran Canaria (srsName "EPSG:4326", longitude first, as GML writers write that form) was read
    latitude first: the building mirrored, moved to Zambia and 9 % too large (cos 27.9 / cos 15.4). The short and
    the gml/srs/epsg.xml forms are read longitude first, the URN and def/crs forms latitude first (EPSG's order):
    each gives the volume of the footprint's geodesic area (pyproj.Geod) times its height, not mirrored."""
    import pyproj

    from meshsom.preprocess import preprocess

    lon0, lat0, z0, height = -15.4402, 27.9031, 263.26, 11.87
    plan = [(0, 0), (0.00021, 0), (0.00021, 0.00013), (0.0001, 0.00019), (0, 0.00013)]  # a pentagon, ccw in lon/lat
    ring = [(lon0 + dx, lat0 + dy) for dx, dy in plan]

    def pos(points, z):
        return " ".join(f"{lat:.9f} {lon:.9f} {z}" if lat_first else f"{lon:.9f} {lat:.9f} {z}"
                        for lon, lat in (*points, points[0]))

    walls = [[ring[k], ring[(k + 1) % 5]] for k in range(5)]
    polygons = [pos(ring[::-1], z0), pos(ring, z0 + height)]  # floor facing down, roof up
    for a, b in walls:
        polygons.append(" ".join(f"{lat:.9f} {lon:.9f} {z}" if lat_first else f"{lon:.9f} {lat:.9f} {z}"
                                 for (lon, lat), z in ((a, z0), (b, z0), (b, z0 + height), (a, z0 + height), (a, z0))))
    members = "".join(f"<gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing><gml:posList>{p}</gml:posList>"
                      f"</gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember>" for p in polygons)
    xml = (BLDG2 + f'<cityObjectMember><bldg:Building gml:id="b18"><bldg:lod1Solid><gml:Solid srsName="{srs}" '
           f'srsDimension="3"><gml:exterior><gml:CompositeSurface>{members}</gml:CompositeSurface></gml:exterior>'
           f"</gml:Solid></bldg:lod1Solid></bldg:Building></cityObjectMember></CityModel>")
    (tmp_path / "b.gml").write_text(xml)
    (b,) = read_file(tmp_path / "b.gml")
    result = preprocess(b.vertices, b.faces)
    area = abs(pyproj.Geod(ellps="WGS84").polygon_area_perimeter([p[0] for p in ring], [p[1] for p in ring])[0])
    assert result.volume_out == pytest.approx(area * height, rel=2e-4)
    assert not any("flipped" in r for r in result.repairs), result.repairs  # outward as written: not mirrored
    assert any("read longitude first" in n for n in b.notes) != lat_first


def _box_shell_xml(lo, hi) -> str:
    """A box's six faces as a gml:CompositeSurface of polygons (counter-clockwise seen from outside)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    c = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0), (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    members = "".join(f"<gml:surfaceMember><gml:Polygon><gml:exterior>{_ring_xml([c[i] for i in q])}</gml:exterior>"
                      f"</gml:Polygon></gml:surfaceMember>" for q in quads)
    return f"<gml:CompositeSurface>{members}</gml:CompositeSurface>"


def _solids_building(kind: str, boxes) -> str:
    """A CityGML 2.0 Building whose lod2Solid is a ``kind`` (CompositeSolid, MultiSolid: a gml:Solid per box;
    Solid: the first box its exterior, the others interiors) of boxes (metres, lo/hi pairs)."""
    if kind == "Solid":
        shells = "".join(f"<gml:{'exterior' if k == 0 else 'interior'}>{_box_shell_xml(*b)}"
                         f"</gml:{'exterior' if k == 0 else 'interior'}>" for k, b in enumerate(boxes))
        solid = f"<gml:Solid>{shells}</gml:Solid>"
    else:
        solid = f"<gml:{kind}>" + "".join(f"<gml:solidMember><gml:Solid><gml:exterior>{_box_shell_xml(*b)}</gml:exterior>"
                                          f"</gml:Solid></gml:solidMember>" for b in boxes) + f"</gml:{kind}>"
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0"
 xmlns:gml="http://www.opengis.net/gml"><core:cityObjectMember><bldg:Building gml:id="S">
 <bldg:lod2Solid>{solid}</bldg:lod2Solid></bldg:Building></core:cityObjectMember></core:CityModel>
"""


@pytest.mark.parametrize("kind, boxes, want", [
    ("MultiSolid", [((0, 0, 0), (2, 1, 1)), ((1, 0, 0), (3, 1, 1))], 3.0),  # 2 + 2 - 1
    ("CompositeSolid", [((0, 0, 0), (2, 0.2, 2)), ((0.5, 0.1, 0.5), (1.5, 0.3, 1.5))], 0.9),  # 0.8 + 0.2 - 0.1
    ("Solid", [((0, 0, 0), (2, 2, 1)), ((1, 0.5, 0), (3, 1.5, 2))], 7.0),  # an interior shell reaching out: 4 + 4 - 1
    ("Solid", [((0, 0, 0), (3, 3, 3)), ((1, 1, 1), (2, 2, 2))], 26.0),  # a cavity: 27 - 1
])
def test_the_shells_of_a_building_s_solids_are_united(tmp_path, kind, boxes, want):
    """Each shell of a gml:Solid (its exterior, its interiors) is read as a shell of its own, as CityJSON's reader
    reads a MultiSolid's, so that shells touching or overlapping are united and a cavity stays one
    (test_io.test_shells_of_a_solid_geometry_that_touch_or_overlap_are_united). The CityGML reader made every
    polygon of a LoD one MultiSurface: the overlaps were counted twice. Volumes by hand."""
    from pipelines.ingest import process_one
    from meshsom.preprocess import PreprocessParams

    path = tmp_path / "solids.gml"
    path.write_text(_solids_building(kind, boxes))
    (raw,) = read_file(path, ReaderOptions())
    record, _ = process_one(raw, PreprocessParams())
    assert record["status"] == "accepted", record
    assert record["volume"] == pytest.approx(want, rel=1e-9)
    assert (record.get("union", {}).get("status") == "united") == (want != 26.0)
