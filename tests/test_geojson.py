"""Buildings from GeoJSON footprints with heights and from JSON-FG solids (meshsom.geojson).

Every volume below is computed by hand from the footprint (shoelace area x height, or a gabled
house's prism); footprints in longitude/latitude are placed on the ellipsoid by PROJ (pyproj,
independent of meshsom's geodesy) from footprints drawn in metres, so the volume read back must be
the one drawn.
"""

from __future__ import annotations

import gzip
import json
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file
from meshsom.preprocess import preprocess

from footprints import (COURT_IN, COURT_OUT, HOUSE, L_SHAPE, area, closed, gabled_house, lonlat, rectangle,
                        united_volume)

def _feature(fid, geometry, **props):
    f = {"type": "Feature", "geometry": geometry, "properties": props}
    if fid is not None:
        f["id"] = fid
    return f


def _volume(mesh: RawMesh) -> float:
    return preprocess(mesh.vertices, mesh.faces).volume_out


def _by_id(items):
    return {i.id.split("#", 1)[1]: i for i in items}


def test_osm_like_footprints_in_longitude_latitude(tmp_path):
    """RFC 7946 GeoJSON: WGS 84 longitude/latitude, heights in metres as numbers or text."""
    features = [
        _feature("L", {"type": "Polygon", "coordinates": [closed(lonlat(L_SHAPE))]}, height="12.5 m", family="L"),
        _feature("court", {"type": "Polygon", "coordinates": [closed(lonlat(COURT_OUT)), closed(lonlat(COURT_IN))]},
                 **{"building:levels": "4"}),
        _feature("raised", {"type": "MultiPolygon", "coordinates": [[closed(lonlat([(60, 0), (70, 0), (70, 5), (60, 5)]))],
                                                                    [closed(lonlat([(75, 0), (80, 0), (80, 5), (75, 5)]))]]},
                 height=9, min_height=3),
        _feature(None, {"type": "Polygon", "coordinates": [closed(lonlat(L_SHAPE))]}),  # no height
        _feature("road", {"type": "LineString", "coordinates": lonlat([(0, -5), (50, -5)])}),
        _feature("nothing", None, height=3),
    ]
    path = tmp_path / "osm.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    got = _by_id(read_file(path))
    assert sorted(got) == ["L", "court", "feature-4", "nothing", "raised", "road"]
    assert got["L"].label == "L" and got["L"].lod == "1"
    assert _volume(got["L"]) == pytest.approx(area(L_SHAPE) * 12.5, rel=1e-5)
    assert _volume(got["court"]) == pytest.approx((area(COURT_OUT) - area(COURT_IN)) * 4 * 3.0, rel=1e-5)
    assert any("4 storeys x 3 m" in n for n in got["court"].notes)
    assert any("geographic coordinates" in n for n in got["L"].notes)
    assert _volume(got["raised"]) == pytest.approx((50 + 25) * 6, rel=1e-5)  # from 3 m up to 9 m (OSM's meaning)
    assert np.ptp(got["raised"].vertices[:, 2]) == pytest.approx(6, abs=1e-4)  # the earth curves 0.03 mm over 20 m
    assert isinstance(got["feature-4"], Rejection) and "footprint without a height" in got["feature-4"].reason
    assert isinstance(got["road"], Rejection) and "holds a LineString" in got["road"].reason
    assert isinstance(got["nothing"], Rejection) and "has no geometry" in got["nothing"].reason


@pytest.mark.parametrize("height,metres", [
    ("12,5", 12.5), ("12,5 m", 12.5), ("40'", 40 * 0.3048), ("40 ft", 40 * 0.3048), ("12'6\"", 12 * 0.3048 + 6 * 0.0254),
    ("12' 6\"", 12 * 0.3048 + 6 * 0.0254), ("9 m", 9.0), ("9", 9.0), (" 7.5 ", 7.5),
    ("360\"", 360 * 0.0254), ("350 cm", 3.5), ("30 yd", 30 * 0.9144), ("8.5 metres", 8.5), ("12;15", 12.0),
])
def test_heights_as_openstreetmap_writes_them(tmp_path, height, metres):
    """OpenStreetMap heights are metres unless a unit says otherwise: feet (40', 40 ft), feet and
    inches (12'6"), and a decimal comma (12,5: common in European data) were read as 40 m, 12 m and
    12 m; each block now has the volume of its height in metres."""
    feature = _feature("b", {"type": "Polygon", "coordinates": [closed(lonlat(L_SHAPE))]}, height=height)
    (tmp_path / "osm.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    (block,) = read_file(tmp_path / "osm.geojson")
    assert _volume(block) == pytest.approx(area(L_SHAPE) * metres, rel=1e-5), block


@pytest.mark.parametrize("height", ["3 storeys", "12 m high", "tall"])
def test_a_height_that_is_not_a_length_is_no_height(tmp_path, height):
    """A number followed by a word that is no unit (OSMBuilding's samples: ``3600"`` was read as 3,600 m; a count of
    storeys in the height) is not read as metres: the footprint has no height, and its rejection says so, naming the
    value (it said "no property height ... gives one", though the property was there)."""
    feature = _feature("b", {"type": "Polygon", "coordinates": [closed(lonlat(L_SHAPE))]}, height=height)
    (tmp_path / "osm.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    (item,) = read_file(tmp_path / "osm.geojson")
    assert isinstance(item, Rejection), item
    assert item.reason.startswith(f"is a footprint without a height it can read (height = {height!r} is not a number; "
                                  "no other property height, "), item.reason


@pytest.mark.parametrize("props,metres,said", [
    ({"height": "~10"}, 10.0, "height = '~10' is approximate: read as 10"),
    ({"height": "ca. 10 m"}, 10.0, "height = 'ca. 10 m' is approximate: read as 10 m"),
    ({"height": "approx 10"}, 10.0, "height = 'approx 10' is approximate: read as 10"),
    ({"height": ">10"}, 10.0, "height = '>10' is a lower bound: read as 10"),
    ({"height": "10-12"}, 11.0, "height = '10-12' is a range: read as its middle, 11"),
    ({"height": "30 - 40 ft"}, 35 * 0.3048, "height = '30 - 40 ft' is a range: read as its middle, 35 ft"),
    ({"building:levels": "3-4"}, 3.5 * 3.0, "building:levels = '3-4' is a range: read as its middle, 3.5"),
    ({"height": "~10", "building:levels": "5"}, 10.0, "height = '~10' is approximate"),  # the height wins
])
def test_approximate_heights_bounds_and_ranges(tmp_path, props, metres, said):
    """OpenStreetMap's estimates (``~10``, ``ca. 10``, ``>10``, ``10-12``: probeG's tags.osm) were rejected as "no
    property height ... gives one": an approximate value or a bound is read as its number, a range as its middle (the
    estimate never off by more than half the range), each noted; volumes: the L's shoelace area x that height."""
    feature = _feature("b", {"type": "Polygon", "coordinates": [closed(lonlat(L_SHAPE))]}, **props)
    (tmp_path / "osm.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    (block,) = read_file(tmp_path / "osm.geojson")
    assert isinstance(block, RawMesh), block
    assert _volume(block) == pytest.approx(area(L_SHAPE) * metres, rel=1e-5)
    assert any(n.startswith(said) for n in block.notes), block.notes


@pytest.mark.parametrize("props,metres,said", [
    ({"min_height": "~3"}, 7.0, "min_height = '~3' is approximate: read as 3"),
    ({"min_height": "2-4"}, 7.0, "min_height = '2-4' is a range: read as its middle, 3"),
    ({"building:min_level": "~1"}, 7.0, "building:min_level = '~1' is approximate: read as 1"),
    ({"min_height": "low"}, 10.0, "min_height = 'low' is not a number"),
])
def test_bases_written_as_estimates(tmp_path, props, metres, said):
    """A base written as an estimate (``min_height`` "~3") was read as no base, the part standing on the ground
    without a word; it is read as heights are (approximate, bounds, ranges), noted, and a base that is no number is
    named: the L's shoelace area x (10 m less the base)."""
    feature = _feature("b", {"type": "Polygon", "coordinates": [closed(lonlat(L_SHAPE))]}, height=10, **props)
    (tmp_path / "osm.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    (block,) = read_file(tmp_path / "osm.geojson")
    assert _volume(block) == pytest.approx(area(L_SHAPE) * metres, rel=1e-5)
    assert any(n.startswith(said) for n in block.notes), block.notes


def test_storeys_below_the_bottom_raise_it(tmp_path):
    """Overture's ``min_floor`` and OpenStreetMap's ``building:min_level`` (a skybridge, an overhang) raise the base by
    their storeys where no ``min_height`` is given: 5 floors from floor 2 stand from 6 m to 15 m; ``min_height``
    wins where both are given."""
    ring = [(84600 + x, 447400 + y) for x, y in L_SHAPE]
    polygon = {"type": "Polygon", "coordinates": [closed(ring)]}
    doc = {"type": "FeatureCollection", "features": [
        _feature("overture", polygon, num_floors=5, min_floor=2),
        _feature("osm", polygon, **{"building:levels": 5, "building:min_level": 2}),
        _feature("both", polygon, num_floors=5, min_floor=2, min_height=3)]}
    (tmp_path / "floors.geojson").write_text(json.dumps(doc))
    items = _by_id(read_file(tmp_path / "floors.geojson"))
    for key in ("overture", "osm"):
        z = items[key].vertices[:, 2] + items[key].origin[2]
        assert (z.min(), z.max()) == pytest.approx((6.0, 15.0), abs=1e-9), key
        assert _volume(items[key]) == pytest.approx(area(L_SHAPE) * 9, rel=1e-9), key
    assert any("base from min_floor = 2 storeys x 3 m" in n for n in items["overture"].notes), items["overture"].notes
    assert _volume(items["both"]) == pytest.approx(area(L_SHAPE) * 12, rel=1e-9)


def test_a_lowest_storey_starts_at_the_walls_own_storey_height(tmp_path):
    """building:min_level on a footprint with a height and a storey count counts storeys of its walls' own height
    (its height less its roof's, over its storeys: meshsom.osm.level_base), on GeoJSON footprints as on OSM extracts
    (OpenStreetMap read through osm.building_meshes alone did; here 3 m storeys stood): 3 storeys in 12 m from
    min_level 1 stand from 4 m (was 3 m: A x 9); 2 storeys under a 4 m gabled roof in 12 m, from min_level 1: walls
    4-8 m, the roof 8-12 m (was walls 3-8 m). Volumes by hand: 12 x 8 x 8; HOUSE gabled (12, 8, 4, 4)."""
    def block(fid, x0, **props):
        return _feature(fid, {"type": "Polygon", "coordinates": [closed([(84600 + x, 447400 + y)
                                                                         for x, y in rectangle(x0, 0, 12, 8)])]}, **props)

    got, _ = _all_read(tmp_path / "levels.geojson", [
        block("tower", 0, height=12, **{"building:levels": 3, "building:min_level": 1}),
        block("roofed", 20, height=12, roof_shape="gabled", roof_height=4, **{"building:levels": 2, "building:min_level": 1})])
    z = got["tower"].vertices[:, 2] + got["tower"].origin[2]
    assert (z.min(), z.max()) == pytest.approx((4.0, 12.0), abs=1e-9)
    assert _volume(got["tower"]) == pytest.approx(12 * 8 * 8, rel=1e-9)
    assert any("base from building:min_level = 1 storeys of 4 m" in n for n in got["tower"].notes), got["tower"].notes
    assert _volume(got["roofed"]) == pytest.approx(HOUSE["gabled"](12, 8, 4, 4), rel=1e-9)


def test_a_storey_count_above_any_buildings_is_refused_naming_it(tmp_path):
    """``building:levels=1e3`` (probeG's tags.osm) was read as a 3 km tower (600,642 m3 on 200 m2): a storey count above
    MAX_STOREYS (the tallest building has 163) is refused, naming its value; 200 storeys are still read (the L's
    shoelace area x 200 x 3 m), as is a height beside an implausible count (the height wins, the count unused)."""
    from meshsom.geojson import MAX_STOREYS

    polygon = {"type": "Polygon", "coordinates": [closed([(84600 + x, 447400 + y) for x, y in L_SHAPE])]}  # metres
    doc = {"type": "FeatureCollection", "features": [
        _feature("big", polygon, **{"building:levels": "1e3"}),
        _feature("under", polygon, **{"building:levels": 5, "building:min_level": 1000}),
        _feature("tall", polygon, **{"building:levels": MAX_STOREYS}),
        _feature("height", polygon, height=12, **{"building:levels": "1e3"})]}
    (tmp_path / "levels.geojson").write_text(json.dumps(doc))
    got = _by_id(read_file(tmp_path / "levels.geojson"))
    assert isinstance(got["big"], Rejection) and got["big"].reason.startswith(
        "building:levels = '1e3' is 1000 storeys, more than any building has"), got["big"]
    assert isinstance(got["under"], Rejection) and got["under"].reason.startswith(
        "building:min_level = 1000 is 1000 storeys"), got["under"]
    assert _volume(got["tall"]) == pytest.approx(area(L_SHAPE) * MAX_STOREYS * 3.0, rel=1e-5)
    assert _volume(got["height"]) == pytest.approx(area(L_SHAPE) * 12, rel=1e-5)


def test_underground_footprints_are_refused_saying_so(tmp_path):
    """A garage under a square (OpenStreetMap's ``location=underground``, Overture's ``is_underground``) is no block
    above it, whatever height stands in: a rejection saying so, with ``default_height`` set too; a building above
    ground beside it is read; a building's underground part is left out, noted."""
    import dataclasses

    ring = [(84600 + x, 447400 + y) for x, y in L_SHAPE]
    polygon = {"type": "Polygon", "coordinates": [closed(ring)]}
    doc = {"type": "FeatureCollection", "features": [
        _feature("garage", polygon, building="parking", location="underground"),
        _feature("overture", polygon, is_underground=True),
        _feature("house", polygon, building="house", is_underground=False)]}
    (tmp_path / "under.geojson").write_text(json.dumps(doc))
    items = _by_id(read_file(tmp_path / "under.geojson", dataclasses.replace(ReaderOptions(), default_height=9.0)))
    assert items["garage"].reason == "lies underground (location=underground): not a building above the ground, not read"
    assert items["overture"].reason == "lies underground (is_underground=True): not a building above the ground, not read"
    assert _volume(items["house"]) == pytest.approx(area(L_SHAPE) * 9, rel=1e-9)


def test_projected_footprints_with_or_without_a_crs_member(tmp_path):
    ring = [(84600 + x, 447400 + y) for x, y in L_SHAPE]  # RD New metres: beyond +/-180, read as metres
    doc = {"type": "FeatureCollection", "features": [_feature(1, {"type": "Polygon", "coordinates": [closed(ring)]}, height=6)]}
    (tmp_path / "rd.json").write_text(json.dumps(doc))
    (m,) = read_file(tmp_path / "rd.json")
    assert m.id == "rd.json#1" and m.notes == ()
    assert _volume(m) == pytest.approx(area(L_SHAPE) * 6, rel=1e-12)
    feet = 1200 / 3937
    doc["crs"] = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::2263"}}  # old GeoJSON: a named CRS
    doc["features"][0]["geometry"]["coordinates"] = [closed([(984000 + x / feet, 190000 + y / feet) for x, y in L_SHAPE])]
    doc["features"][0]["properties"]["height"] = 6 / feet
    with gzip.open(tmp_path / "ny.geojson.gz", "wt") as fh:
        json.dump(doc, fh)
    (m,) = read_file(tmp_path / "ny.geojson.gz")
    assert _volume(m) == pytest.approx(area(L_SHAPE) * 6, rel=1e-9)
    # local metres of a model (a game engine's, a planner's) within +/-180 in x but beyond +/-90 in y: no longitude
    # and latitude, read as metres as the other features of such a file are
    ring = [(-170 + x, -110 + y) for x, y in L_SHAPE]
    local = {"type": "FeatureCollection", "features": [_feature(1, {"type": "Polygon", "coordinates": [closed(ring)]}, height=6)]}
    (tmp_path / "local.geojson").write_text(json.dumps(local))
    (m,) = read_file(tmp_path / "local.geojson")
    assert isinstance(m, RawMesh) and _volume(m) == pytest.approx(area(L_SHAPE) * 6, rel=1e-9), m


def test_json_fg_solids_and_prisms(tmp_path):
    faces, house_volume = gabled_house()
    x0, y0 = 479800.0, 5705800.0
    shell = [[closed([(x0 + x, y0 + y, 100 + z) for x, y, z in face])] for face in faces]
    features = [
        {"type": "Feature", "id": "house", "featureType": "app:building", "geometry": None,
         "place": {"type": "Polyhedron", "coordinates": [shell]}, "properties": {"family": "gabled"}},
        {"type": "Feature", "id": "two", "geometry": None,
         "place": {"type": "MultiPolyhedron", "coordinates": [[shell], [[[closed([(x0 + 20 + x, y0 + y, 100 + z) for x, y, z in face])]
                                                                        for face in faces]]]}},
        {"type": "Feature", "id": "prism", "geometry": None,
         "place": {"type": "Prism", "base": {"type": "Polygon", "coordinates": [closed([(x0 + x, y0 + y) for x, y in L_SHAPE])]},
                   "lower": 100, "upper": 107.5}},
        {"type": "Feature", "id": "flat", "geometry": None, "place": {"type": "Prism", "lower": 5, "upper": 5,
                                                                       "base": {"type": "Polygon", "coordinates": [closed(L_SHAPE)]}}},
    ]
    doc = {"type": "FeatureCollection", "coordRefSys": "http://www.opengis.net/def/crs/EPSG/0/25832", "features": features}
    (tmp_path / "b.fg.json").write_text(json.dumps(doc))
    got = _by_id(read_file(tmp_path / "b.fg.json"))
    assert got["house"].label == "gabled" and got["house"].lod == "2"
    assert _volume(got["house"]) == pytest.approx(house_volume, rel=1e-12)
    assert _volume(got["two"]) == pytest.approx(2 * house_volume, rel=1e-12)
    assert _volume(got["prism"]) == pytest.approx(area(L_SHAPE) * 7.5, rel=1e-12)
    assert isinstance(got["flat"], Rejection) and "no height" in got["flat"].reason


def _all_read(path, features):
    """The meshes of ``features`` written as a FeatureCollection to ``path``, by id, each read (no rejection)."""
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    got = _by_id(read_file(path))
    assert all(isinstance(m, RawMesh) for m in got.values()), got
    return got, path


def _house(fid, x0, w, d, **props):
    return _feature(fid, {"type": "Polygon", "coordinates": [closed(lonlat(rectangle(x0, 0, w, d)))]}, **props)


def test_roofs_from_overture_and_openstreetmap_properties(tmp_path):
    """Footprints with roof attributes, as Overture Maps writes them (roof_shape, roof_height,
    roof_direction, roof_orientation), as Overpass turbo exports OpenStreetMap (roof:shape, ...)
    and as osmtogeojson nests OSM's tags (properties.tags): each house is built with its roof, at
    the volume worked out by hand for its shape; the pitch of a roof without a height is measured
    in metres although the footprint is in degrees."""
    pitch = np.tan(np.radians(30.0)) * 4.0  # the 30 degree default over half of an 8 m width
    features = [
        _house("gabled", 0, 12, 8, height=9, roof_shape="gabled", roof_height=3, family="house"),
        _house("hipped", 20, 12, 8, height=9.0, roof_shape="hipped", roof_height=3.0),
        _house("pyramid", 40, 10, 10, height="10", **{"roof:shape": "pyramidal", "roof:angle": "45"}),
        _feature("way/7", {"type": "Polygon", "coordinates": [closed(lonlat(rectangle(60, 0, 10, 6)))]}, type="way", id=7,
                 tags={"building": "house", "height": "8", "roof:shape": "skillion", "roof:height": "2",
                       "roof:direction": "S"}, relations=[], meta={}),
        _house("pitched", 80, 12, 8, height=9, roof_shape="gabled"),
        _house("across", 100, 12, 8, height=9, roof_shape="gabled", roof_height=3, roof_orientation="across"),
        _house("north", 120, 10, 6, height=8, roof_shape="skillion", roof_height=2, roof_direction=0),
        _house("half", 140, 12, 8, height=9, roof_shape="half_hipped", roof_height=3),
        _house("mansard", 160, 12, 8, height=9, roof_shape="mansard", roof_height=3),
        _house("sawtooth", 220, 12, 8, height=9, roof_shape="sawtooth", roof_height=3),
        _feature("hexagon", {"type": "Polygon", "coordinates": [closed(lonlat(
            [(240 + 5 * np.cos(a), 5 * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 7)[:-1]]))]},
            height=9, roof_shape="half_hipped", roof_height=3),  # no wing end: hipped, noted
        _house("flat", 180, 12, 8, height=9, roof_shape="flat", roof_height=None),
        _house("many", 200, 12, 8, height=9, roof_shape="gabled", roof_height=3, roof_direction=None),
    ]
    features[-1]["geometry"] = {"type": "MultiPolygon", "coordinates": [
        [closed(lonlat(rectangle(200, 0, 5, 8)))], [closed(lonlat(rectangle(210, 0, 5, 8)))]]}
    got, path = _all_read(tmp_path / "overture.geojson", features)
    for fid, shape, (w, d, e, r) in [("gabled", "gabled", (12, 8, 6, 3)), ("hipped", "hipped", (12, 8, 6, 3)),
                                     ("pyramid", "pyramidal", (10, 10, 5, 5)), ("way/7", "skillion", (10, 6, 6, 2)),
                                     ("pitched", "gabled", (12, 8, 9 - pitch, pitch)),
                                     ("across", "gabled", (12, 8, 6, 3)), ("north", "skillion", (10, 6, 6, 2)),
                                     ("mansard", "mansard", (12, 8, 6, 3))]:
        assert _volume(got[fid]) == pytest.approx(HOUSE[shape](w, d, e, r), rel=1e-5), fid
        assert got[fid].lod == "2" and any(f"roof:shape={shape} built (S3DB)" in n for n in got[fid].notes), got[fid].notes
    assert got["gabled"].label == "house"
    # the ridge along the longer sides (12 m east-west), or across them (8 m north-south)
    for fid, spread in (("gabled", 0), ("across", 1)):
        v = got[fid].vertices
        top = v[v[:, 2] > v[:, 2].max() - 1e-6]
        assert np.ptp(top[:, spread]) == pytest.approx((12, 8)[spread], abs=1e-4), (fid, top)
    # a skillion faces the way roof:direction says: its low side to the south (S), to the north (0)
    for fid, low_side_north in (("way/7", False), ("north", True)):
        v = got[fid].vertices
        low, high = v[np.isclose(v[:, 2], v[:, 2].min() + 6, atol=1e-4)], v[np.isclose(v[:, 2], v[:, 2].max(), atol=1e-4)]
        assert (low[:, 1].mean() > high[:, 1].mean()) == low_side_north, fid
    assert any("roof:shape=half-hipped built (S3DB) (roof:shape=half_hipped read as half-hipped)" in n
               for n in got["half"].notes), got["half"].notes
    assert any("roof:shape=sawtooth not modelled: a flat roof at the height" in n for n in got["sawtooth"].notes)
    hexagon = np.array([(5 * np.cos(a), 5 * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 7)[:-1]])
    assert any("(roof:shape=half_hipped read as half-hipped) (roof:shape=half-hipped built as hipped (no wing end" in n
               for n in got["hexagon"].notes), got["hexagon"].notes
    assert _volume(got["hexagon"]) == pytest.approx(area(hexagon) * (6 + 3 / 3), rel=1e-5)  # a pyramid on its walls
    assert any("roof:shape=gabled built (S3DB): eaves 6 m, top 9 m above its base, on 2 polygons" in n
               for n in got["many"].notes), got["many"].notes  # a building in two pieces: a roof on each
    assert _volume(got["many"]) == pytest.approx(2 * HOUSE["gabled"](8, 5, 6, 3), rel=1e-5)
    for fid, volume in (("sawtooth", 12 * 8 * 9), ("flat", 12 * 8 * 9)):
        assert _volume(got[fid]) == pytest.approx(volume, rel=1e-5) and got[fid].lod == "1", fid
    # roofs off: every footprint a flat block at its height
    flat = _by_id(read_file(path, ReaderOptions(roofs=False)))
    assert _volume(flat["gabled"]) == pytest.approx(12 * 8 * 9, rel=1e-5) and flat["gabled"].lod == "1"
    assert _volume(flat["way/7"]) == pytest.approx(10 * 6 * 8, rel=1e-5)


def test_a_roof_as_high_as_its_footprint_is_all_roof(tmp_path):
    """A roof as high as its footprint's height (a roof storey: OSM2World's issue-203, roof:height 2.2 on a part from
    2.8 to 5 m) kept 5 % walls under it (the roof cut to 95 %: +5 %), and a roof higher than the footprint was cut so
    without a note: such a roof now takes the whole height, no walls, noted; a roof of 95 to 100 % is cut to 95 %,
    noted. Volumes by hand (footprints.HOUSE, eaves 0): gabled W D r / 2, pyramidal W D r / 3, hipped r D (3W - D) / 6."""
    def _house(fid, x0, w, d, **props):  # in metres (a projected CRS): no earth's curve in the volumes
        return _feature(fid, {"type": "Polygon", "coordinates": [closed([(84600 + x, 447400 + y)
                                                                         for x, y in rectangle(x0, 0, w, d)])]}, **props)

    features = [
        _house("gabled", 0, 12, 8, height=5, roof_shape="gabled", roof_height=5),
        _house("pyramid", 20, 10, 10, height=6, roof_shape="pyramidal", roof_height=8),  # higher: cut to 6 m
        _house("hipped", 40, 12, 8, height=10, min_height=7, roof_shape="hipped", roof_height=3),  # 7-10 m, all roof
        _house("skillion", 60, 10, 6, height=4, roof_shape="skillion", roof_height=4, roof_direction=0),
        _house("capped", 80, 12, 8, height=10, roof_shape="gabled", roof_height=9.8),  # cut to 9.5 m, eaves 0.5 m
        _feature("L", {"type": "Polygon", "coordinates": [closed([(84700 + x, 447400 + y) for x, y in L_SHAPE])]},
                 height=4, roof_shape="hipped", roof_height=4),  # the straight skeleton's hipped roof, no walls
    ]
    got, _ = _all_read(tmp_path / "roofs.geojson", features)
    for fid, shape, (w, d, e, r) in [("gabled", "gabled", (12, 8, 0, 5)), ("pyramid", "pyramidal", (10, 10, 0, 6)),
                                     ("hipped", "hipped", (12, 8, 0, 3)), ("skillion", "skillion", (10, 6, 0, 4)),
                                     ("capped", "gabled", (12, 8, 0.5, 9.5))]:
        assert _volume(got[fid]) == pytest.approx(HOUSE[shape](w, d, e, r), rel=1e-5), fid
    assert _volume(got["gabled"]) == pytest.approx(12 * 8 * 5 / 2, rel=1e-5)  # was 12 x 8 x (0.25 + 4.75 / 2) = 252
    for fid, said in (("gabled", "(the roof fills its whole height, no walls): eaves 0 m, top 5 m"),
                      ("pyramid", "(a roof of 8 m, more than its 6 m: cut to it, no walls): eaves 0 m, top 6 m"),
                      ("capped", "(a roof of 9.8 m leaves walls under 5% of its 10 m: cut to 9.5 m): eaves 0.5 m")):
        assert any(said in n for n in got[fid].notes), (fid, got[fid].notes)
    z = got["hipped"].vertices[:, 2] + got["hipped"].origin[2]
    assert np.ptp(z) == pytest.approx(3, abs=1e-4)
    assert united_volume(got["L"]) == pytest.approx(_volume(got["L"]), rel=1e-9)  # closed, accepted
    assert 0 < _volume(got["L"]) < area(L_SHAPE) * 4 / 2  # under half the block: a hipped roof, no walls


def test_attributes_spelled_otherwise_in_case_and_punctuation(tmp_path):
    """Heights, bases, storeys and roofs under the names other tools give them: OSM Buildings' camel case (minHeight,
    roofShape, roofHeight), a layer's upper case with underscores (ROOF_SHAPE), OpenStreetMap's keys with the colon a
    column's name may not hold (building_levels, roof_shape): each read as the key it spells, volumes by hand."""
    features = [
        _house("camel", 0, 12, 8, height=15, minHeight=6, roofShape="gabled", roofHeight=3),
        _house("upper", 20, 12, 8, HEIGHT=9, ROOF_SHAPE="hipped", ROOF_HEIGHT=3),
        _house("levels", 40, 10, 10, building_levels=4),
        _house("colonless", 60, 12, 8, height=9, roof_shape="gabled", roof_height=3, building_min_level=None),
    ]
    path = tmp_path / "spellings.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    got = _by_id(read_file(path))
    assert all(isinstance(m, RawMesh) for m in got.values()), got
    assert _volume(got["camel"]) == pytest.approx(HOUSE["gabled"](12, 8, 6, 3), rel=1e-5)  # 6 m to 15 m
    z = got["camel"].vertices[:, 2] + got["camel"].origin[2]
    assert z.min() - (got["levels"].vertices[:, 2] + got["levels"].origin[2]).min() == pytest.approx(6, abs=1e-6)
    assert _volume(got["upper"]) == pytest.approx(HOUSE["hipped"](12, 8, 6, 3), rel=1e-5)
    assert _volume(got["levels"]) == pytest.approx(10 * 10 * 12, rel=1e-5)
    assert _volume(got["colonless"]) == pytest.approx(HOUSE["gabled"](12, 8, 6, 3), rel=1e-5)


def test_buildings_made_of_parts_in_one_collection(tmp_path):
    """Buildings and their parts in one collection, as an Overpass turbo export of building and building:part
    ways gives them (OSM tags as properties; osmtogeojson nests them under tags), and as Overture Maps' building
    and building_part features (building_id): each building is its parts, united (S3DB), the outline's own block
    not added (a flat nave is kept beside its roofed tower: both were LoD-labelled apart, and the reader kept the
    tower alone as the building's "highest"); a part without a height takes its building's; a part inside no
    outline is a building of its own,
    noted; a building_id that names no feature is just a property. Every feature is read or rejected."""
    def way(fid, rect, **tags):
        return _feature(fid, {"type": "Polygon", "coordinates": [closed(lonlat(rect))]}, **tags)

    features = [
        way("way/1", rectangle(0, 0, 20, 10), building="church", height="10"),  # the outline: nave + tower
        way("way/2", rectangle(0, 0, 12, 10), **{"building:part": "yes"}),  # no height: the church's 10 m
        _feature("way/3", {"type": "Polygon", "coordinates": [closed(lonlat(rectangle(12, 1, 8, 8)))]},
                 type="way", id=3, tags={"building:part": "tower", "height": "30", "roof:shape": "pyramidal",
                                         "roof:height": "6"}),
        way("way/4", rectangle(40, 0, 10, 10), **{"building:part": "yes", "height": "5"}),  # inside no outline
        way("b1", rectangle(60, 0, 20, 10), id="b1", height=12.0, has_parts=True),  # Overture
        way("p1", rectangle(60, 0, 10, 10), id="p1", building_id="b1", height=12.0),
        way("p2", rectangle(70, 0, 10, 10), id="p2", building_id="b1", min_height=4.0, height=8.0),
        way("solo", rectangle(90, 0, 10, 10), height=6.0, building_id="nowhere"),
    ]
    path = tmp_path / "overpass.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    got = _by_id(read_file(path))
    assert sorted(got) == ["b1", "solo", "way/1", "way/4"]
    church = got["way/1"]
    assert any("2 building:part areas inside its outline, read as its parts (S3DB)" in n for n in church.notes)
    assert united_volume(church) == pytest.approx(12 * 10 * 10 + 8 * 8 * (24 + 6 / 3), rel=1e-5)
    assert np.ptp(church.vertices[:, 2]) == pytest.approx(30, abs=1e-3)
    assert united_volume(got["b1"]) == pytest.approx(10 * 10 * 12 + 10 * 10 * 4, rel=1e-5)
    assert any("a building:part inside no building outline" in n for n in got["way/4"].notes)
    assert _volume(got["way/4"]) == pytest.approx(10 * 10 * 5, rel=1e-5)
    assert _volume(got["solo"]) == pytest.approx(10 * 10 * 6, rel=1e-5) and got["solo"].notes[0].startswith("converted")
    separate = _by_id(read_file(path, ReaderOptions(parts="separate")))
    assert sorted(separate) == ["p1", "p2", "solo", "way/2", "way/3", "way/4"]  # each part a building of its own


@pytest.mark.parametrize("suffix", [".geojson", ".geojsonl", ".csv.gz"])
def test_microsofts_unknown_height_of_minus_one(tmp_path, suffix):
    """Microsoft's building footprints write "height": -1 where the height is not known (GeoJSON, and line-delimited
    GeoJSONSeq read through GDAL, also as its global release ships it: gzipped lines of GeoJSON named ``.csv.gz``):
    no height, said so in the rejection; with default_height the footprint is
    extruded to it (before, the footprint was refused as an extrusion from 0 to -1 m even with a default), a
    positive height another property gives is taken."""
    features = [_feature("a", {"type": "Polygon", "coordinates": [closed(lonlat(L_SHAPE))]}, height=-1.0, confidence=-1.0),
                _feature("b", {"type": "Polygon", "coordinates": [closed(lonlat([(x + 30, y) for x, y in L_SHAPE]))]},
                         height=-1.0, **{"building:height": "7"})]
    path = tmp_path / f"ms{suffix}"
    if suffix == ".geojson":
        path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    elif suffix == ".csv.gz":
        path.write_bytes(gzip.compress("".join(json.dumps(f) + "\n" for f in features).encode()))
    else:
        path.write_text("".join(json.dumps(f) + "\n" for f in features))
    got = _by_id(read_file(path))
    key = "a" if suffix == ".geojson" else next(k for k in got if got[k].id.endswith(("#a", "#1", "#0")))
    assert isinstance(got[key], Rejection) and "height = -1 read as no height" in got[key].reason, got[key]
    assert got[key].reason.startswith("is a footprint without a height (no property height, ")  # said as it is: not
    # wrapped as "its geometry is not nested as GeoJSON says (InputFileError: ...", cut at 80 characters, as before
    other = next(k for k in got if k != key)
    assert _volume(got[other]) == pytest.approx(area(L_SHAPE) * 7, rel=1e-5)
    got = _by_id(read_file(path, ReaderOptions(default_height=6.0)))
    assert _volume(got[key]) == pytest.approx(area(L_SHAPE) * 6, rel=1e-5)
    assert any("height = -1 read as no height" in n for n in got[key].notes), got[key].notes


def test_geojson_files_through_meshsom_ingest(tmp_path):
    import subprocess

    folder = tmp_path / "in"
    folder.mkdir()
    features = [_feature(f"b{k}", {"type": "Polygon", "coordinates": [closed(lonlat([(x + 30 * k, y) for x, y in L_SHAPE]))]},
                         height=5 + k) for k in range(3)]
    (folder / "district.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(folder), "--out", str(tmp_path / "g.zarr")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "3 meshes: 3 accepted, 0 rejected" in out.stdout
    # what the reader did, counted by kind (the CRS named whole, its numbers kept)
    assert "read with notes" in out.stdout
    assert "3 x converted to metres from geographic coordinates (WGS 84 longitude-latitude-height)" in out.stdout, out.stdout


def _big_collection(n, pretty=False):
    """A FeatureCollection of ``n`` L-shaped footprints in degrees, with what trips a scanner that does not know
    JSON's strings: braces, brackets, escaped quotes and backslashes in property values, the text
    ``"features": [`` inside a string, a crs member of nested objects and a bbox array before the features; some
    features without an id (named by their place in the file), one that is not a Feature."""
    from footprints import L_SHAPE

    features = []
    for k in range(n):
        ring = closed(lonlat([(x + 30 * (k % 25), y + 30 * (k // 25)) for x, y in L_SHAPE]))
        props = {"height": 3.0 + k % 7, "note": ['{"a": [1, 2]}', 'say \\"hi\\" \\\\', '"features": [{', "]}]"][k % 4]}
        feature = {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]}, "properties": props}
        if k % 3:
            feature["id"] = f"b{k}"
        features.append(feature)
    features[17] = {"type": "NotAFeature", "x": [{"y": "}"}]}
    document = {"type": "FeatureCollection", "name": 'odd "features": [ name',
                "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}},
                "bbox": [4.0, 52.0, 4.5, 52.1], "features": features}
    if pretty:
        return json.dumps(document, indent=2).replace("\n", "\r\n")
    return "{" + ",\n".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in document.items() if k != "features") + \
        ',\n"features": [\n' + ",\n".join(json.dumps(f) for f in features) + "\n]}\n"


@pytest.mark.parametrize("pretty,scan_bytes", [(False, 8 << 20), (False, 13), (True, 64), (True, 4097)])
def test_a_large_feature_collection_is_read_in_ranges_as_whole(tmp_path, monkeypatch, pretty, scan_bytes):
    """geojson_ranges finds each feature of the top-level "features" array, outside strings, whatever the chunks
    the file is looked at in (13 bytes: escapes and strings across them): the ranges read (read_geojson_range)
    give the items a whole reading gives, ids, reasons and vertices; a file that names building parts, a gzipped
    one and one of too few features are read whole."""
    import meshsom.geojson as geojson

    monkeypatch.setattr(geojson, "SCAN_BYTES", scan_bytes)
    path = tmp_path / "city.geojson"
    path.write_text(_big_collection(120, pretty))
    whole = list(read_file(path))
    assert len(whole) == 120 and sum(isinstance(i, Rejection) for i in whole) == 1
    ranges = geojson.geojson_ranges(path, 25, ReaderOptions())
    assert ranges is not None and [r[2] for r in ranges] == [0, 25, 50, 75, 100]
    ranged = [i for r in ranges for i in read_file(path, ReaderOptions(), None, tuple(r))]
    assert [i.id for i in ranged] == [i.id for i in whole]
    for a, b in zip(whole, ranged):
        if isinstance(a, Rejection):
            assert a.reason == b.reason
        else:
            assert np.array_equal(a.vertices + a.origin, b.vertices + b.origin) and np.array_equal(a.faces, b.faces)
    assert geojson.geojson_ranges(path, 61, ReaderOptions()) is None  # fewer than twice 61 features
    parts = tmp_path / "parts.geojson"
    parts.write_text(_big_collection(120, pretty).replace('"note"', '"building:part"', 1))
    assert geojson.geojson_ranges(parts, 25, ReaderOptions()) is None
    (tmp_path / "city.geojson.gz").write_bytes(gzip.compress(path.read_bytes()))
    assert geojson.geojson_ranges(tmp_path / "city.geojson.gz", 25, ReaderOptions()) is None


_JSON_TEXT = st.text(alphabet=st.sampled_from(list('{}[]",:\\ab \n\t/') + ["\u00e9", "\u2028", "\U0001f3e0"]),
                     max_size=12)


@settings(max_examples=60, deadline=None)
@given(values=st.lists(st.one_of(_JSON_TEXT, st.lists(_JSON_TEXT, max_size=3), st.integers()), min_size=1, max_size=30),
       indent=st.sampled_from([None, 0, 2]), ascii_only=st.booleans(), chunk=st.sampled_from([1, 2, 3, 7, 64, 4096]))
def test_the_feature_scanner_finds_every_feature_whatever_its_strings(values, indent, ascii_only, chunk):
    """meshsom.geojson._feature_spans against json's own parse: for documents whose property names and values hold
    braces, brackets, quotes, backslashes, colons and non-ASCII text (escaped or not), written compact or indented,
    and looked at in chunks of 1 byte up: each span found is one feature of the "features" array, in order, all
    of them, and nothing else."""
    import tempfile
    from pathlib import Path

    import meshsom.geojson as geojson

    features = [{"type": "Feature", "properties": {str(v): v, "k": [v, {"n": v}]},
                 "geometry": {"type": "Point", "coordinates": [k, 0]}} for k, v in enumerate(values)]
    document = {"name": str(values[0]), "type": "FeatureCollection", "crs": {"p": {"q": values[-1]}},
                "features": features, "after": [str(values[-1])]}
    data = json.dumps(document, indent=indent, ensure_ascii=ascii_only).encode()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "c.geojson"
        path.write_bytes(data)
        saved = geojson.SCAN_BYTES
        geojson.SCAN_BYTES = chunk
        try:
            found = geojson._feature_spans(path)
        finally:
            geojson.SCAN_BYTES = saved
    assert found is not None
    opened, closed, starts, ends = found
    assert data[opened:opened + 1] == b"[" and data[closed:closed + 1] == b"]"
    assert [json.loads(data[a:b + 1]) for a, b in zip(starts.tolist(), ends.tolist())] == features


def test_a_cityjson_file_is_not_scanned_for_features(tmp_path, monkeypatch):
    """The planner asks every large .json input for its feature ranges: a CityJSON file says its type in its first
    bytes and is not scanned (a pass over a city's bytes that would find nothing), nor is a file that is not a JSON
    object (a placeholder of zeros); a GeoJSON collection still is."""
    import meshsom.geojson as geojson
    from meshsom.io import ReaderOptions

    scanned = []
    scan = geojson._feature_spans
    monkeypatch.setattr(geojson, "_feature_spans", lambda path: scanned.append(path.name) or scan(path))
    city = {"type": "CityJSON", "version": "2.0", "CityObjects": {f"b{k}": {"type": "Building"} for k in range(3000)},
            "vertices": []}
    (tmp_path / "city.json").write_text(json.dumps(city))
    (tmp_path / "zeros.json").write_bytes(b"\0" * 100_000)
    (tmp_path / "footprints.geojson").write_text(_big_collection(120))
    assert geojson.geojson_ranges(tmp_path / "city.json", 10, ReaderOptions()) is None
    assert geojson.geojson_ranges(tmp_path / "zeros.json", 10, ReaderOptions()) is None
    assert geojson.geojson_ranges(tmp_path / "footprints.geojson", 10, ReaderOptions()) is not None
    assert scanned == ["footprints.geojson"]


def test_a_repeated_corner_is_no_dropped_polygon(tmp_path):
    """A footprint ring with a corner written twice in a row (the Kampala and Catastro footprints) extrudes a wall of
    zero width there: nothing is left out, and no note says that polygons were dropped, leaving holes."""
    ring = [(84600 + x, 447400 + y) for x, y in [(0, 0), (10, 0), (10, 5), (10, 10), (10, 10), (5, 10), (0, 10)]]
    doc = {"type": "FeatureCollection", "features": [_feature(1, {"type": "Polygon", "coordinates": [closed(ring)]}, height=3)]}
    (tmp_path / "twice.geojson").write_text(json.dumps(doc))
    (m,) = read_file(tmp_path / "twice.geojson")
    assert isinstance(m, RawMesh) and not any("dropped" in n for n in m.notes), m.notes
    assert _volume(m) == pytest.approx(10 * 10 * 3, rel=1e-12)


def test_a_footprint_that_crosses_itself_is_read_as_the_areas_it_encloses(tmp_path):
    """A bow-tie footprint (a way drawn across itself, as osmnx's test extract and OSM2World's have one): read as its
    two triangles (25 m^2 each), noted with where it crosses, not rejected for walls that cannot close."""
    ring = [(84600 + x, 447400 + y) for x, y in [(0, 0), (10, 0), (0, 10), (10, 10)]]
    doc = {"type": "FeatureCollection", "features": [_feature(1, {"type": "Polygon", "coordinates": [closed(ring)]}, height=6)]}
    (tmp_path / "bowtie.geojson").write_text(json.dumps(doc))
    (m,) = read_file(tmp_path / "bowtie.geojson")
    assert isinstance(m, RawMesh), m
    assert any("Self-intersection[84605 447405]" in n and "2 polygon(s)" in n for n in m.notes), m.notes
    assert _volume(m) == pytest.approx(2 * 25 * 6, rel=1e-9)


@pytest.mark.parametrize("parts, area", [
    ([[(0, 0), (10, 0), (10, 10), (0, 10)], [(5, 0), (15, 0), (15, 10), (5, 10)]], 150),  # two halves drawn across
    ([[(0, 0), (10, 0), (10, 10), (0, 10)], [(2, 2), (6, 2), (6, 6), (2, 6)]], 100),  # an outline inside another
    ([[(0, 0), (10, 0), (10, 10), (0, 10)], [(0, 0), (10, 0), (10, 10), (0, 10)]], 100),  # a part written twice
    ([[(0, 0), (10, 0), (10, 10), (0, 10)], [(8, 8), (14, 8), (14, 14), (8, 14)], [(20, 0), (24, 0), (24, 4), (20, 4)]],
     100 + 36 - 4 + 16),  # two that overlap beside one apart
])
def test_overlapping_parts_of_a_multipolygon_are_read_as_their_union(tmp_path, parts, area):
    """A MultiPolygon whose parts overlap (invalid: a municipal layer's parts drawn over each other, an outline
    inside another, a part written twice): each was extruded alone, the overlap built twice through itself and its
    volume counted twice (two 10 x 10 halves crossing by 5 m gave 2,000 m3 for 10 x 15 x 10 = 1,500). Read as the
    area the building covers, the parts' union, noted; the volume is that area (by hand) times the height."""
    ring = lambda pts: closed([(84600 + x, 447400 + y) for x, y in pts])  # noqa: E731
    geometry = {"type": "MultiPolygon", "coordinates": [[ring(p)] for p in parts]}
    doc = {"type": "FeatureCollection", "features": [_feature(1, geometry, height=10)]}
    (tmp_path / "parts.geojson").write_text(json.dumps(doc))
    (m,) = read_file(tmp_path / "parts.geojson")
    assert isinstance(m, RawMesh), m
    assert any("overlap" in n and "their union" in n for n in m.notes), m.notes
    assert _volume(m) == pytest.approx(area * 10, rel=1e-9)


def test_a_geometry_collection_of_polygons_is_a_footprint(tmp_path):
    """A feature whose geometry is a GeometryCollection (PostGIS's ST_Collect, QGIS's "collect geometries"; GDAL
    writes it so) was refused as holding no polygons. Its polygons, nested collections' too, are the footprint (a
    10 x 10 and a 4 x 6 apart, 124 m2 x 5 m by hand), its lines and points left out, noted; one of no polygon is
    still refused, naming what it holds."""
    ring = lambda pts: closed([(84600 + x, 447400 + y) for x, y in pts])  # noqa: E731
    geometry = {"type": "GeometryCollection", "geometries": [
        {"type": "Polygon", "coordinates": [ring([(0, 0), (10, 0), (10, 10), (0, 10)])]},
        {"type": "LineString", "coordinates": ring([(0, 0), (10, 0), (10, 10), (0, 10)])},
        {"type": "GeometryCollection", "geometries": [
            {"type": "MultiPolygon", "coordinates": [[ring([(20, 0), (24, 0), (24, 6), (20, 6)])]]},
            {"type": "Point", "coordinates": [84600, 447400]}]}]}
    lines = {"type": "GeometryCollection", "geometries": [{"type": "LineString", "coordinates": [[0, 0], [1, 1]]}]}
    doc = {"type": "FeatureCollection", "features": [_feature(1, geometry, height=5), _feature(2, lines, height=5)]}
    (tmp_path / "collected.geojson").write_text(json.dumps(doc))
    m, lined = read_file(tmp_path / "collected.geojson")
    assert isinstance(m, RawMesh), m
    assert any("GeometryCollection read as its 2 polygon(s) (left out: 1 LineString, 1 Point)" in n for n in m.notes), m.notes
    assert _volume(m) == pytest.approx((100 + 24) * 5, rel=1e-9)
    assert isinstance(lined, Rejection) and "holds a GeometryCollection" in lined.reason, lined


def test_a_footprint_that_encloses_no_area_says_so(tmp_path):
    """A footprint whose corners lie on one line (a way drawn back on itself, a traced sliver) or are one point was
    extruded into a flat wall and refused as 'one planar polygon ... 90 degrees from horizontal'; it is refused as a
    footprint that encloses no area. A thin one that does enclose some (0.01 m x 10 m) is still read (0.1 m2 x 10)."""
    ring = lambda pts: closed([(84600 + x, 447400 + y) for x, y in pts])  # noqa: E731
    doc = {"type": "FeatureCollection", "features": [
        _feature(1, {"type": "Polygon", "coordinates": [ring([(0, 0), (10, 0), (10, 0), (4, 0)])]}, height=10),
        _feature(2, {"type": "Polygon", "coordinates": [ring([(0, 0), (0, 0), (0, 0)])]}, height=10),
        _feature(3, {"type": "Polygon", "coordinates": [ring([(0, 0), (10, 0), (10, 0.01), (0, 0.01)])]}, height=10)]}
    (tmp_path / "flat.geojson").write_text(json.dumps(doc))
    line, point, thin = read_file(tmp_path / "flat.geojson")
    assert isinstance(line, Rejection) and line.reason == ("has a footprint that encloses no area (its 5 corners lie "
                                                           "on one line, 10 units long): no building to extrude"), line
    assert isinstance(point, Rejection) and "its 4 corners are one point" in point.reason, point
    assert isinstance(thin, RawMesh) and _volume(thin) == pytest.approx(0.1 * 10, rel=1e-6)


def test_parts_of_a_multipolygon_that_only_touch_are_not_united(tmp_path):
    """Parts that share a wall or a corner, and an island in a courtyard, do not overlap: read as they are."""
    ring = lambda pts: closed([(84600 + x, 447400 + y) for x, y in pts])  # noqa: E731
    square = [(0, 0), (10, 0), (10, 10), (0, 10)]
    geometry = {"type": "MultiPolygon", "coordinates": [
        [ring(square), ring([(3, 3), (3, 7), (7, 7), (7, 3)])], [ring([(4, 4), (6, 4), (6, 6), (4, 6)])],
        [ring([(10, 0), (20, 0), (20, 10), (10, 10)])], [ring([(20, 10), (24, 10), (24, 14), (20, 14)])]]}
    doc = {"type": "FeatureCollection", "features": [_feature(1, geometry, height=10)]}
    (tmp_path / "touching.geojson").write_text(json.dumps(doc))
    (m,) = read_file(tmp_path / "touching.geojson")
    assert isinstance(m, RawMesh) and not any("overlap" in n for n in m.notes), m.notes
    assert _volume(m) == pytest.approx((100 - 16 + 4 + 100 + 16) * 10, rel=1e-9)


@pytest.mark.parametrize("holes, area", [
    ([[(4, 3), (4, 9), (8, 9), (8, 3)], [(8, 3), (8, 9), (14, 9), (14, 3)]], 240 - 24 - 36),  # touching (784)
    ([[(4, 3), (4, 9), (10, 9), (10, 3)], [(8, 3), (8, 9), (14, 9), (14, 3)]], 240 - 48),  # overlapping: an island (778)
    ([[(4, 3), (4, 9), (8, 9), (8, 3)], [(8, 3), (4, 3), (4, 9), (8, 9)]], 240 - 24),  # one hole drawn twice (795)
])
def test_courtyards_of_an_invalid_footprint_by_the_even_odd_rule(tmp_path, holes, area):
    """A multipolygon whose inner rings touch (valid in OpenStreetMap: osm-testdata's case 784; invalid as a GeoJSON
    polygon): make_valid of the whole took the shared strip back as area (+6 %). Its rings are read as libosmium
    assembles them, by the even-odd rule within the shell: touching courtyards come out together (20 x 12 less 4 x 6
    and 6 x 6), where two overlap the doubly covered strip stays as an island (2 x 6 of 6 x 6 and 6 x 6), and a
    courtyard drawn twice is one."""
    ring = lambda pts: closed([(84600 + x, 447400 + y) for x, y in pts])  # noqa: E731
    shell = ring([(0, 0), (20, 0), (20, 12), (0, 12)])
    doc = {"type": "FeatureCollection", "features": [
        _feature(1, {"type": "Polygon", "coordinates": [shell, *[ring(h) for h in holes]]}, height=6)]}
    (tmp_path / "courts.geojson").write_text(json.dumps(doc))
    (m,) = read_file(tmp_path / "courts.geojson")
    assert isinstance(m, RawMesh), m
    assert any("even-odd rule" in n for n in m.notes), m.notes
    assert _volume(m) == pytest.approx(area * 6, rel=1e-9)
