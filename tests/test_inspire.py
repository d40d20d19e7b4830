"""INSPIRE Buildings 2D (meshsom.inspire), as Spain's Catastro publishes a municipality: ``building.gml`` (footprints),
``buildingpart.gml`` (each building's parts with their storeys; a part's id its building's with ``_part<N>``) and
``otherconstruction.gml``, written here as the Catastro writes them (GML 3.2, EPSG:25830, ``gml:Surface`` patches),
and checked against volumes computed by hand (rectangles times storeys times ``storey_height``)."""

from __future__ import annotations

import dataclasses
import gzip
import json
import subprocess
import sys

import pytest

from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, input_kind, read_file

HEADER = ('<?xml version="1.0" encoding="UTF-8"?>\n'
          '<gml:FeatureCollection xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
          'xmlns:gml="http://www.opengis.net/gml/3.2" xmlns:xlink="http://www.w3.org/1999/xlink" '
          'xmlns:bu-core2d="http://inspire.jrc.ec.europa.eu/schemas/bu-core2d/2.0" '
          'xmlns:bu-ext2d="http://inspire.jrc.ec.europa.eu/schemas/bu-ext2d/2.0" '
          'xmlns:base="urn:x-inspire:specification:gmlas:BaseTypes:3.2" '
          'xmlns:cp="urn:x-inspire:specification:gmlas:CadastralParcels:3.0" gml:id="ES.SDGC.BU">\n')
SRS = "http://www.opengis.net/def/crs/EPSG/0/25830"
X0, Y0 = 440000.0, 4474000.0

#: Buildings: reference, its parts (x0, y0, w, d, storeys above ground); the last has no parts file entry.
BUILDINGS = {
    "9872023VH5797S": [(0, 0, 10, 10, 2), (10, 0, 10, 10, 5)],
    "9872024VH5797S": [(30, 0, 12, 8, 3), (42, 0, 4, 8, 0)],  # and a patio: no storey above the ground
    "9872025VH5797S": [(50, 0, 6, 6, 1), (56, 0, 6, 6, 1), (50, 6, 12, 4, 4)],
    "9872026VH5797S": [],
}
ALONE = (70, 0, 9, 7)  # the footprint of the building without parts


def _surface(gml_id, x0, y0, w, d) -> str:
    ring = [(x0, y0), (x0 + w, y0), (x0 + w, y0 + d), (x0, y0 + d), (x0, y0)]
    pos = " ".join(f"{X0 + x:.2f} {Y0 + y:.2f}" for x, y in ring)
    return (f'<gml:Surface gml:id="Surface_{gml_id}" srsName="{SRS}"><gml:patches><gml:PolygonPatch><gml:exterior>'
            f'<gml:LinearRing><gml:posList srsDimension="2" count="5">{pos}</gml:posList></gml:LinearRing>'
            f'</gml:exterior></gml:PolygonPatch></gml:patches></gml:Surface>')


def _feature(element, gml_id, rect, extra="") -> str:
    x0, y0, w, d = rect
    local = gml_id.removeprefix("ES.SDGC.BU.")
    return (f'<gml:featureMember>\n<bu-ext2d:{element} gml:id="{gml_id}">\n'
            f'<gml:boundedBy><gml:Envelope srsName="{SRS}"><gml:lowerCorner>{X0 + x0} {Y0 + y0}</gml:lowerCorner>'
            f'<gml:upperCorner>{X0 + x0 + w} {Y0 + y0 + d}</gml:upperCorner></gml:Envelope></gml:boundedBy>\n'
            f'<bu-core2d:beginLifespanVersion>2011-03-17T00:00:00</bu-core2d:beginLifespanVersion>\n'
            f'<bu-core2d:conditionOfConstruction xsi:nil="true" nilReason="other:unpopulated"></bu-core2d:conditionOfConstruction>\n'
            f'<bu-core2d:inspireId><base:Identifier><base:localId>{local}</base:localId>'
            f'<base:namespace>ES.SDGC.BU</base:namespace></base:Identifier></bu-core2d:inspireId>\n'
            f'<bu-ext2d:geometry><bu-core2d:BuildingGeometry><bu-core2d:geometry>{_surface(gml_id, *rect)}</bu-core2d:geometry>'
            f'<bu-core2d:horizontalGeometryEstimatedAccuracy uom="m">0.1</bu-core2d:horizontalGeometryEstimatedAccuracy>'
            f'<bu-core2d:horizontalGeometryReference>footPrint</bu-core2d:horizontalGeometryReference>'
            f'<bu-core2d:referenceGeometry>true</bu-core2d:referenceGeometry></bu-core2d:BuildingGeometry></bu-ext2d:geometry>\n'
            f'{extra}</bu-ext2d:{element}>\n</gml:featureMember>\n')


def _outline(parts):
    x0, y0 = min(p[0] for p in parts), min(p[1] for p in parts)
    return x0, y0, max(p[0] + p[2] for p in parts) - x0, max(p[1] + p[3] for p in parts) - y0


def write_municipality(folder, gzipped=False):
    """The three files of a Catastro municipality (``A.ES.SDGC.BU.99999.*.gml``)."""
    folder.mkdir(parents=True, exist_ok=True)
    buildings = "".join(
        _feature("Building", f"ES.SDGC.BU.{ref}", _outline(parts) if parts else ALONE,
                 "<bu-core2d:currentUse>1_residential</bu-core2d:currentUse>\n") for ref, parts in BUILDINGS.items())
    parts = "".join(
        _feature("BuildingPart", f"ES.SDGC.BU.{ref}_part{k}", (x0, y0, w, d),
                 f'<bu-ext2d:heightBelowGround uom="m">0</bu-ext2d:heightBelowGround>\n'
                 f'<bu-ext2d:numberOfFloorsAboveGround>{n}</bu-ext2d:numberOfFloorsAboveGround>\n'
                 f'<bu-ext2d:numberOfFloorsBelowGround>0</bu-ext2d:numberOfFloorsBelowGround>\n')
        for ref, members in BUILDINGS.items() for k, (x0, y0, w, d, n) in enumerate(members, 1))
    others = _feature("OtherConstruction", "ES.SDGC.BU.9872023VH5797S_OC1", (0, 20, 5, 4))
    paths = []
    for kind, body in (("building", buildings), ("buildingpart", parts), ("otherconstruction", others)):
        text = HEADER + body + "</gml:FeatureCollection>\n"
        path = folder / f"A.ES.SDGC.BU.99999.{kind}.gml{'.gz' if gzipped else ''}"
        path.write_bytes(gzip.compress(text.encode()) if gzipped else text.encode())
        paths.append(path)
    return paths


def expected_volumes(storey=3.0) -> dict[str, float]:
    return {f"ES.SDGC.BU.{ref}": sum(w * d * n * storey for _, _, w, d, n in parts)
            for ref, parts in BUILDINGS.items() if parts}


def _united_volumes(items) -> dict[str, float]:
    from meshsom.preprocess import PreprocessParams
    from pipelines.ingest import process_one

    out = {}
    for item in items:
        assert isinstance(item, RawMesh), item
        record, _ = process_one(item, PreprocessParams())
        assert record["status"] == "accepted", record
        out[item.id.split("#", 1)[1]] = record["volume"]
    return out


@pytest.mark.parametrize("gzipped", [False, True])
def test_a_parts_file_alone_gives_each_building_as_its_parts(tmp_path, gzipped):
    """buildingpart.gml (also gzipped): each building once, its id the building's, its parts united to the sum of
    their storeys' volumes; GDAL writes no .gfs file beside it; a CityGML file is not taken for INSPIRE."""
    _, parts, _ = write_municipality(tmp_path / "m", gzipped)
    before = sorted(p.name for p in (tmp_path / "m").iterdir())
    assert input_kind(parts) == "gis"
    items = list(read_file(parts))
    assert _united_volumes(items) == pytest.approx(expected_volumes(), rel=1e-9)
    three = next(i for i in items if i.id.endswith("9872025VH5797S"))
    assert len(three.parts) == 3 and "3 INSPIRE BuildingParts of ES.SDGC.BU.9872025VH5797S, read as its parts" in three.notes
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == before  # no .gfs
    patio = next(i for i in items if i.id.endswith("9872024VH5797S"))
    assert any("numberOfFloorsAboveGround = 0: no storey above the ground" in n and n.endswith("left out")
               for n in patio.notes), patio.notes
    assert not any("--default-height" in n for n in patio.notes), patio.notes  # never raised to it: no such hint
    citygml = tmp_path / "c.gml"
    citygml.write_text('<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" '
                       'xmlns:bldg="http://www.opengis.net/citygml/building/2.0"></core:CityModel>')
    assert input_kind(citygml) == "citygml"


def test_a_building_file_alone_and_other_constructions(tmp_path):
    """building.gml without storeys: each footprint refused with the options that would read it, or extruded to the
    default height; otherconstruction.gml: each feature refused as not a building."""
    building, _, other = write_municipality(tmp_path / "m")
    got = {i.id.split("#", 1)[1]: i for i in read_file(building)}
    assert len(got) == 4 and all(isinstance(i, Rejection) and "--default-height M" in i.reason for i in got.values())
    got = {i.id.split("#", 1)[1]: i for i in read_file(building, dataclasses.replace(ReaderOptions(), default_height=6.0))}
    alone = got["ES.SDGC.BU.9872026VH5797S"]
    assert _united_volumes([alone]) == pytest.approx({"ES.SDGC.BU.9872026VH5797S": ALONE[2] * ALONE[3] * 6}, rel=1e-9)
    (item,) = read_file(other)
    assert isinstance(item, Rejection) and item.reason == "is an INSPIRE OtherConstruction, not a building (Building or BuildingPart)"


def test_parts_read_in_ranges_as_whole(tmp_path):
    """The parts file read in ranges of one feature: each building once, by the range of its first part."""
    from meshsom.gis import gis_ranges, read_gis

    _, parts, _ = write_municipality(tmp_path / "m")
    options = ReaderOptions()
    ranges = gis_ranges(parts, 1, options)
    assert ranges is not None and len(ranges) == sum(len(p) for p in BUILDINGS.values())
    pieces = [i for r in ranges for i in read_gis(parts, options, feature_range=r)]
    assert _united_volumes(pieces) == pytest.approx(expected_volumes(), rel=1e-9)


def test_a_municipality_through_meshsom_ingest(tmp_path):
    """`meshsom ingest` of the municipality's folder: each building once (from its parts where it has them, else
    from its footprint at the default height; a patio of no storeys not raised to it), the other construction
    refused; nothing read twice."""
    write_municipality(tmp_path / "m")
    files, rejected = expand_inputs([tmp_path / "m"])
    assert len(files) == 3 and not rejected
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(tmp_path / "m"), "--out",
                          str(tmp_path / "m.zarr"), "--default-height", "6"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    records = json.loads((tmp_path / "m.zarr" / "manifest.json").read_text())["records"]
    accepted = {r["id"]: r["volume"] for r in records if r["status"] == "accepted"}
    assert accepted == pytest.approx({
        **{f"A.ES.SDGC.BU.99999.buildingpart.gml#{k}": v for k, v in expected_volumes().items()},
        "A.ES.SDGC.BU.99999.building.gml#ES.SDGC.BU.9872026VH5797S": ALONE[2] * ALONE[3] * 6}, rel=1e-9)
    assert [r["id"] for r in records if r["status"] != "accepted"] == [
        "A.ES.SDGC.BU.99999.otherconstruction.gml#ES.SDGC.BU.9872023VH5797S_OC1"]


def test_a_municipality_as_the_catastro_zips_it(tmp_path):
    """The ATOM download's zip of the three files: its parts paired with its buildings inside the archive, so each
    building is read once (from its parts, else from its footprint at the default height)."""
    import zipfile

    paths = write_municipality(tmp_path / "m")
    with zipfile.ZipFile(tmp_path / "A.ES.SDGC.BU.99999.zip", "w") as archive:
        for path in paths:
            archive.write(path, path.name)
    items = list(read_file(tmp_path / "A.ES.SDGC.BU.99999.zip", dataclasses.replace(ReaderOptions(), default_height=6.0)))
    meshes = [i for i in items if isinstance(i, RawMesh)]
    assert _united_volumes(meshes) == pytest.approx(
        {**expected_volumes(), "ES.SDGC.BU.9872026VH5797S": ALONE[2] * ALONE[3] * 6}, rel=1e-9)
    assert sorted(i.id.split("#")[0] for i in meshes) == ["A.ES.SDGC.BU.99999.zip/A.ES.SDGC.BU.99999.building.gml"] + [
        "A.ES.SDGC.BU.99999.zip/A.ES.SDGC.BU.99999.buildingpart.gml"] * 3
    assert [i.reason for i in items if isinstance(i, Rejection)] == [
        "is an INSPIRE OtherConstruction, not a building (Building or BuildingPart)"]


def test_a_height_above_ground_to_the_top(tmp_path):
    """An INSPIRE Building with ``heightAboveGround`` to its ``top`` (12.5 m) and storeys: the height is read; one to
    its eaves only (``generalEave``) is not a height, its storeys are."""
    def height(reference, value):
        return (f"<bu-core2d:heightAboveGround><bu-core2d:HeightAboveGround><bu-core2d:heightReference>{reference}"
                f"</bu-core2d:heightReference><bu-core2d:value uom=\"m\">{value}</bu-core2d:value>"
                f"</bu-core2d:HeightAboveGround></bu-core2d:heightAboveGround>\n")

    floors = "<bu-ext2d:numberOfFloorsAboveGround>2</bu-ext2d:numberOfFloorsAboveGround>\n"
    body = (_feature("Building", "ES.SDGC.BU.1", (0, 0, 10, 8), height("top", 12.5) + floors)
            + _feature("Building", "ES.SDGC.BU.2", (30, 0, 10, 8), height("generalEave", 4.5) + floors))
    path = tmp_path / "b.gml"
    path.write_text(HEADER + body + "</gml:FeatureCollection>\n")
    volumes = _united_volumes(read_file(path))
    assert volumes == pytest.approx({"ES.SDGC.BU.1": 80 * 12.5, "ES.SDGC.BU.2": 80 * 6}, rel=1e-9)


# Other producers link a Building to its parts (bu-core2d:parts xlink:href), the parts' ids their own: a Building
# (gml:id, x0, y0, w, d, storeys or None) with its linked parts (href as written, part gml:id, rect, storeys).
LINKED = {
    ("DE.B1", (0, 0, 20, 10), 5): [("#DE.P1", "DE.P1", (0, 0, 10, 10), 2),
                                   ("urn:adv:oid:DE.P2", "DE.P2", (10, 0, 10, 10), None)],  # the building's 5
    ("DE.B2", (30, 0, 10, 10), None): [("https://example.org/inspire/BuildingPart/DE.P3", "DE.P3", (30, 0, 10, 10), 1)],
    ("DE.B3", (50, 0, 9, 7), 4): [],
}
UNLINKED = ("DE.P9", (70, 0, 6, 5), 2)  # a part no building links: read as a feature of its own


def _floors(n):
    return "" if n is None else f"<bu-ext2d:numberOfFloorsAboveGround>{n}</bu-ext2d:numberOfFloorsAboveGround>\n"


def _linked_features():
    buildings = "".join(_feature("Building", gid, rect, _floors(n) + "".join(
        f'<bu-core2d:parts xlink:href="{href}"/>\n' for href, *_ in parts)) for (gid, rect, n), parts in LINKED.items())
    parts = "".join(_feature("BuildingPart", pid, rect, _floors(n))
                    for members in LINKED.values() for _, pid, rect, n in members)
    return buildings, parts + _feature("BuildingPart", UNLINKED[0], UNLINKED[1], _floors(UNLINKED[2]))


def _linked_volumes(storey=3.0):
    out = {}
    for (gid, (_, _, w, d), n), parts in LINKED.items():
        out[gid] = sum(pw * pd * (pn if pn is not None else n) * storey for _, _, (_, _, pw, pd), pn in parts) if parts \
            else w * d * n * storey
    return out


def test_parts_linked_from_their_buildings_in_one_file_whole_or_in_ranges(tmp_path):
    """A file of Buildings and BuildingParts whose Buildings link their parts (by ``#id``, a URN, a URL): each linked
    building is read as its parts, with its own id and attributes (a part without storeys takes its building's),
    each part once; a building without parts is its footprint; a part no building links is a feature of its own.
    The same read in ranges of one feature."""
    from meshsom.gis import gis_ranges, read_gis

    buildings, parts = _linked_features()
    path = tmp_path / "bu.gml"
    path.write_text(HEADER + buildings + parts + "</gml:FeatureCollection>\n")
    options = ReaderOptions()
    items = list(read_gis(path, options))
    got = _united_volumes(items)
    expected = {f"Building/{k}": v for k, v in _linked_volumes().items()}
    expected[f"BuildingPart/{UNLINKED[0]}"] = UNLINKED[1][2] * UNLINKED[1][3] * UNLINKED[2] * 3.0
    assert got == pytest.approx(expected, rel=1e-9)
    b1 = next(i for i in items if i.id.endswith("#Building/DE.B1"))
    assert sorted(b1.parts) == ["BuildingPart/DE.P1", "BuildingPart/DE.P2"]
    assert "2 INSPIRE BuildingParts of it, read as its parts" in b1.notes
    ranges = gis_ranges(path, 1, options)
    assert ranges is not None and len(ranges) == 3 + 4
    pieces = [i for r in ranges for i in read_gis(path, options, feature_range=r)]
    assert _united_volumes(pieces) == pytest.approx(got, rel=1e-12)


def test_parts_linked_from_buildings_in_another_file(tmp_path):
    """Buildings (with their links) and parts in two files, paired among a run's inputs: each linked building is
    read once, from its parts (its id the building's), not again from its footprint; a building without parts from
    its footprint; the unlinked part on its own."""
    from meshsom.part_files import pair

    buildings, parts = _linked_features()
    (tmp_path / "buildings.gml").write_text(HEADER + buildings + "</gml:FeatureCollection>\n")
    (tmp_path / "parts.gml").write_text(HEADER + parts + "</gml:FeatureCollection>\n")
    files = [tmp_path / "buildings.gml", tmp_path / "parts.gml"]
    options = pair(files, ReaderOptions())
    assert options.part_files == (str(tmp_path / "parts.gml"),)
    got = _united_volumes(i for f in files for i in read_file(f, options))
    expected = dict(_linked_volumes())
    expected[UNLINKED[0]] = UNLINKED[1][2] * UNLINKED[1][3] * UNLINKED[2] * 3.0
    assert got == pytest.approx(expected, rel=1e-9)


def _inline(gid, rect, n, parts) -> str:
    """A Building with its parts written inside it (``bu-core2d:parts`` holding each ``BuildingPart``)."""
    inside = "".join(
        "<bu-core2d:parts>\n" + _feature("BuildingPart", pid, prect, _floors(pn)).split("<gml:featureMember>\n", 1)[1]
        .rsplit("</gml:featureMember>", 1)[0] + "</bu-core2d:parts>\n" for pid, prect, pn in parts)
    return _feature("Building", gid, rect, _floors(n) + inside)


def test_parts_written_inside_their_buildings_whole_or_in_ranges(tmp_path):
    """Buildings whose BuildingParts are written inside them (GDAL flattens those into list columns, their
    footprints lost): each such building is read as its parts (a part without storeys takes its building's), not as
    its own footprint; one without parts as its footprint; a part without a geometry is left out, noted. Plain and
    gzipped; whole and in ranges of one feature."""
    from meshsom.gis import gis_ranges, read_gis

    body = (_inline("DE.B1", (0, 0, 20, 10), 5, [("DE.P1", (0, 0, 10, 10), 2), ("DE.P2", (10, 0, 10, 10), None)])
            + _inline("DE.B2", (30, 0, 12, 10), 1, [("DE.P3", (30, 0, 6, 10), 3), ("DE.P4", (36, 0, 6, 10), 4)])
            + _feature("Building", "DE.B3", (50, 0, 9, 7), _floors(4)))
    broken = _inline("DE.B4", (70, 0, 10, 10), 2, [("DE.P5", (70, 0, 5, 10), 6), ("DE.P6", (75, 0, 5, 10), 1)])
    start, end = broken.index('<bu-ext2d:geometry>', broken.index("DE.P6")), broken.index("</bu-ext2d:geometry>", broken.index("DE.P6"))
    body += broken[:start] + broken[end + len("</bu-ext2d:geometry>"):]  # DE.P6 without its geometry
    text = HEADER + body + "</gml:FeatureCollection>\n"
    expected = {"DE.B1": (100 * 2 + 100 * 5) * 3.0, "DE.B2": (60 * 3 + 60 * 4) * 3.0, "DE.B3": 63 * 4 * 3.0,
                "DE.B4": 50 * 6 * 3.0}
    for name, data in (("bu.gml", text.encode()), ("bu.gml.gz", gzip.compress(text.encode()))):
        path = tmp_path / name
        path.write_bytes(data)
        items = list(read_file(path))
        assert _united_volumes(items) == pytest.approx(expected, rel=1e-9), name
        b1 = next(i for i in items if i.id.endswith("#DE.B1"))
        assert sorted(b1.parts) == ["BuildingPart/DE.P1", "BuildingPart/DE.P2"], b1.parts
        assert "2 INSPIRE BuildingParts of it, read as its parts" in b1.notes
        b4 = next(i for i in items if i.id.endswith("#DE.B4"))
        assert any("its part BuildingPart/DE.P6" in n and "left out" in n for n in b4.notes), b4.notes
        options = ReaderOptions()
        ranges = gis_ranges(path, 1, options)
        if ranges is not None:
            pieces = [i for r in ranges for i in read_gis(path, options, feature_range=r)]
            assert _united_volumes(pieces) == pytest.approx(expected, rel=1e-12)
    assert not list(tmp_path.glob("*.gfs"))


def test_parts_neither_linked_nor_named_go_to_the_outline_holding_them(tmp_path):
    """A file of Buildings and BuildingParts whose parts neither are linked from a building nor name one in their
    ids: each part goes to the Building whose outline holds it (read as its parts, not as three buildings where one
    stands), as OpenStreetMap's parts do, noted; a part inside no outline is a building of its own. Whole and in
    ranges of one feature."""
    from meshsom.gis import gis_ranges, read_gis

    body = (_feature("Building", "NL.B1", (0, 0, 20, 10), _floors(5))
            + _feature("Building", "NL.B2", (40, 0, 10, 10), _floors(2))
            + _feature("BuildingPart", "NL.X7", (0, 0, 10, 10), _floors(2))
            + _feature("BuildingPart", "NL.X8", (10, 0, 10, 10), _floors(6))
            + _feature("BuildingPart", "NL.X9", (70, 0, 5, 4), _floors(1)))
    path = tmp_path / "bu.gml"
    path.write_text(HEADER + body + "</gml:FeatureCollection>\n")
    options = ReaderOptions()
    items = list(read_gis(path, options))
    expected = {"Building/NL.B1": (100 * 2 + 100 * 6) * 3.0, "Building/NL.B2": 100 * 2 * 3.0,
                "BuildingPart/NL.X9": 20 * 1 * 3.0}
    assert _united_volumes(items) == pytest.approx(expected, rel=1e-9)
    b1 = next(i for i in items if i.id.endswith("#Building/NL.B1"))
    assert sorted(b1.parts) == ["BuildingPart/NL.X7", "BuildingPart/NL.X8"]
    assert ("2 INSPIRE BuildingParts of it, read as its parts (parts neither linked nor naming a building go to the "
            "outline holding them)") in b1.notes
    pieces = [i for r in gis_ranges(path, 1, options) for i in read_gis(path, options, feature_range=r)]
    assert _united_volumes(pieces) == pytest.approx(expected, rel=1e-12)
