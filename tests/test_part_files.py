"""Overture's building parts in files of their own (meshsom.part_files): read with their buildings.

Overture ships buildings and building parts as two feature types, downloaded as two files; a part
names its building by ``building_id``. Volumes below are worked out by hand from footprints drawn
in metres (placed in longitude and latitude by PROJ, tests/footprints.py) and checked on the
building as ingest preprocesses it (its parts united).
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from meshsom.io import RawMesh, ReaderOptions, read_file
from meshsom.part_files import holds_parts, pair

from footprints import closed, lonlat, rectangle, united_volume, write_geoparquet


def _multi(rect):
    return {"type": "MultiPolygon", "coordinates": [[closed(lonlat(rect))]]}


BUILDINGS = [("b1", _multi(rectangle(0, 0, 20, 10)), {"height": 12.0, "has_parts": True, "family": "church"}),
             ("b2", _multi(rectangle(30, 0, 10, 10)), {"height": 6.0})]
PARTS = [("p1", _multi(rectangle(0, 0, 10, 10)), {"building_id": "b1"}),  # no height: its building's 12 m
         ("p2", _multi(rectangle(10, 0, 10, 10)), {"building_id": "b1", "height": 8.0, "min_height": 4.0}),
         ("p3", _multi(rectangle(60, 0, 5, 5)), {"building_id": "gone", "height": 3.0})]  # its building not here


def _geoparquet_pair(folder):
    write_geoparquet(folder / "buildings.parquet", BUILDINGS, extra=("has_parts",))
    write_geoparquet(folder / "parts.parquet", PARTS, extra=("building_id",))
    return folder / "buildings.parquet", folder / "parts.parquet"


def _geojson_pair(folder):
    def collection(rows):
        return {"type": "FeatureCollection", "features": [
            {"type": "Feature", "id": fid, "geometry": g, "properties": {"id": fid, **props}} for fid, g, props in rows]}
    (folder / "buildings.geojson").write_text(json.dumps(collection(BUILDINGS)))
    (folder / "parts.geojson").write_text(json.dumps(collection(PARTS)))
    return folder / "buildings.geojson", folder / "parts.geojson"


@pytest.mark.parametrize("make", [_geoparquet_pair, _geojson_pair], ids=["geoparquet", "geojson"])
def test_overture_parts_are_read_with_their_buildings(tmp_path, make):
    """Two Overture downloads, buildings and building_parts: the church b1 is its two parts (10 x 10 x 12 m, the
    nave taking the church's height, and a part from 4 to 8 m: 1,200 + 400 m^3), not its own 12 m block; b2 has no
    parts and is its block; the part p3, whose building is in neither file, is a building of its own, noted; the
    parts file yields nothing else. Every feature is read once."""
    buildings, parts = make(tmp_path)
    options = pair([buildings, parts], ReaderOptions())
    assert options.part_files == (str(parts),) and options.building_files == (str(buildings), str(parts))
    got = {m.id.split("#", 1)[1]: m for m in read_file(buildings, options)}
    assert sorted(got) == ["b1", "b2"] and all(isinstance(m, RawMesh) for m in got.values()), got
    assert united_volume(got["b1"]) == pytest.approx(10 * 10 * 12 + 10 * 10 * 4, rel=1e-5)
    assert any("2 building:part areas" in n for n in got["b1"].notes), got["b1"].notes
    assert got["b1"].label == "church"
    assert united_volume(got["b2"]) == pytest.approx(10 * 10 * 6, rel=1e-5)
    (alone,) = list(read_file(parts, options))
    assert alone.id.endswith("#p3") and any("building_part whose building is in no input, read as a building of its own; building_id gone" in n
                                           for n in alone.notes)
    assert united_volume(alone) == pytest.approx(5 * 5 * 3, rel=1e-5)
    # read apart (no pairing), as before: each part a building of its own beside the church's block
    apart = [m.id.split("#", 1)[1] for f in (buildings, parts) for m in read_file(f)]
    assert sorted(apart) == ["b1", "b2", "p1", "p2", "p3"]


def test_a_building_id_that_is_the_features_own_is_no_part(tmp_path):
    """A footprint layer whose own id column is called building_id (as some cities name it) holds no parts."""
    rows = [(fid, g, {**props, "building_id": fid}) for fid, g, props in BUILDINGS]
    write_geoparquet(tmp_path / "city.parquet", rows, extra=("building_id",))
    assert not holds_parts(tmp_path / "city.parquet", ReaderOptions())
    buildings, parts = _geoparquet_pair(tmp_path)
    assert holds_parts(parts, ReaderOptions()) and not holds_parts(buildings, ReaderOptions())
    assert pair([tmp_path / "city.parquet", buildings], ReaderOptions()).part_files == ()
    # LINZ's NZ Building Outlines: the key column is building_id, and no id column beside it (the features' own ids,
    # a FlatGeobuf's or GeoJSON's, are row numbers): outlines, not parts
    linz = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": g, "properties": {"building_id": 1_000_000 + k, "height": 6.0}}
        for k, (_, g, _) in enumerate(BUILDINGS)]}
    (tmp_path / "nz-building-outlines.geojson").write_text(json.dumps(linz))
    assert not holds_parts(tmp_path / "nz-building-outlines.geojson", ReaderOptions())


def test_overture_downloads_through_meshsom_ingest(tmp_path):
    """``meshsom ingest`` on a folder of the two downloads (a Dask client, a zarr store): three buildings, the
    church of its parts, the lone part noted; no part read twice, no file listed as holding nothing."""
    folder = tmp_path / "overture"
    folder.mkdir()
    _geoparquet_pair(folder)
    summary, records = _ingested(folder, tmp_path / "o.zarr")
    assert (summary["inputs"], summary["accepted"], summary["rejected"]) == (3, 3, 0), summary
    assert sorted(records) == ["buildings.parquet#b1", "buildings.parquet#b2", "parts.parquet#p3"]
    assert records["buildings.parquet#b1"]["volume"] == pytest.approx(1600, rel=1e-5)  # the church, of its parts


def _ingested(folder, store) -> tuple[dict, dict]:
    """``meshsom ingest --json`` of a folder: its summary, and its records by id (the command must succeed)."""
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(folder), "--out", str(store), "--json"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    manifest = json.loads((store / "manifest.json").read_text())
    return json.loads(out.stdout.strip().splitlines()[-1]), {r["id"]: r for r in manifest["records"]}


def test_buildings_and_their_parts_in_one_geoparquet_file(tmp_path):
    """One GeoParquet file of both (a query that unions Overture's two types, the parts last, beyond the first rows a
    file is sniffed by): read as the two downloads are."""
    others = [(f"x{k}", BUILDINGS[1][1], {"height": 6.0}) for k in range(118)]
    rows = BUILDINGS + others + PARTS  # the parts after 120 buildings
    write_geoparquet(tmp_path / "overture.parquet", rows, extra=("has_parts", "building_id"))
    options = pair([tmp_path / "overture.parquet"], ReaderOptions())
    assert options.part_files == (str(tmp_path / "overture.parquet"),)
    got = {m.id.split("#", 1)[1]: m for m in read_file(tmp_path / "overture.parquet", options)}
    assert "p1" not in got and "p2" not in got and "p3" in got
    assert united_volume(got["b1"]) == pytest.approx(10 * 10 * 12 + 10 * 10 * 4, rel=1e-5)
    assert len(got) == 120 + 1


def test_buildings_and_their_parts_in_one_geojson_file(tmp_path):
    """One GeoJSON collection of both: each part read once, with its building (grouped within the file and paired:
    not twice), the lone part alone."""
    rows = BUILDINGS + PARTS
    (tmp_path / "overture.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "id": fid, "geometry": g, "properties": {"id": fid, **props}} for fid, g, props in rows]}))
    options = pair([tmp_path / "overture.geojson"], ReaderOptions())
    got = {m.id.split("#", 1)[1]: m for m in read_file(tmp_path / "overture.geojson", options)}
    assert sorted(got) == ["b1", "b2", "p3"]
    assert sorted(got["b1"].parts) == ["p1", "p2"]
    assert united_volume(got["b1"]) == pytest.approx(10 * 10 * 12 + 10 * 10 * 4, rel=1e-5)


# OpenStreetMap's building parts saved as a file of their own: an Overpass query for building=* and one for
# building:part=*, each exported by Overpass turbo (GeoJSON, "@id", tags as properties) or saved by QGIS.
OSM_BUILDINGS = [("way/1", rectangle(0, 0, 20, 10), {"building": "church", "height": "12"}),
                 ("way/2", rectangle(30, 0, 10, 10), {"building": "house", "height": "6"})]
OSM_PARTS = [("way/11", rectangle(0, 0, 10, 10), {"building:part": "yes"}),  # no height: the church's 12 m
             ("way/12", rectangle(10, 0, 10, 10), {"building:part": "yes", "height": "8", "min_height": "4"}),
             ("way/13", rectangle(60, 0, 5, 5), {"building:part": "yes", "height": "3"})]  # inside no outline


def _overpass(path, rows):
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "id": oid, "geometry": {"type": "Polygon", "coordinates": [closed(lonlat(ring))]},
         "properties": {"@id": oid, **tags}} for oid, ring, tags in rows]}))
    return path


def test_osm_parts_in_a_file_of_their_own_are_read_with_their_buildings(tmp_path):
    """Overpass turbo's two exports: the church is its two parts (the nave at the church's 12 m, a part from 4 to
    8 m: 1,200 + 400 m^3), not its 12 m block; the house has none; the part inside no outline is a building of its
    own, noted; the parts file yields nothing else. Read apart, each part would be a building beside the block."""
    from meshsom.osm import STRAY
    from meshsom.part_files import holds_osm_parts

    buildings = _overpass(tmp_path / "buildings.geojson", OSM_BUILDINGS)
    parts = _overpass(tmp_path / "parts.geojson", OSM_PARTS)
    mixed = _overpass(tmp_path / "mixed.geojson", OSM_BUILDINGS + OSM_PARTS)
    assert holds_osm_parts(parts, ReaderOptions()) and holds_parts(parts, ReaderOptions())
    assert not holds_osm_parts(buildings, ReaderOptions()) and not holds_osm_parts(mixed, ReaderOptions())
    options = pair([buildings, parts], ReaderOptions())
    assert options.part_files == (str(parts),)
    got = {m.id.split("#", 1)[1]: m for m in read_file(buildings, options)}
    assert sorted(got) == ["way/1", "way/2"] and all(isinstance(m, RawMesh) for m in got.values()), got
    assert sorted(got["way/1"].parts) == ["way/11", "way/12"]
    assert united_volume(got["way/1"]) == pytest.approx(10 * 10 * 12 + 10 * 10 * 4, rel=1e-5)
    assert any("2 building:part areas" in n for n in got["way/1"].notes), got["way/1"].notes
    assert united_volume(got["way/2"]) == pytest.approx(10 * 10 * 6, rel=1e-5) and not got["way/2"].parts
    (alone,) = list(read_file(parts, options))
    assert alone.id.endswith("#way/13") and STRAY in alone.notes
    assert united_volume(alone) == pytest.approx(5 * 5 * 3, rel=1e-5)
    apart = sorted(m.id.split("#", 1)[1] for f in (buildings, parts) for m in read_file(f))
    assert apart == ["way/1", "way/11", "way/12", "way/13", "way/2"]


def test_osm_parts_in_degrees_with_buildings_in_a_national_grid(tmp_path):
    """Parts from Overpass (WGS 84) with buildings from a cadastre's GeoPackage in the Dutch grid (EPSG:28992, a
    QGIS layer of plain columns, ids from its ``id`` column): each part is moved into the buildings' grid and read
    there. The church's volume is its parts' areas in that grid (PROJ's, by hand) times their heights."""
    import fiona
    import pyproj
    import shapely
    from shapely.geometry import Polygon

    from footprints import area

    to_rd = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:28992", always_xy=True)

    def rd(ring):
        x, y = to_rd.transform(*np.asarray(lonlat(ring)).T)
        return list(zip(x.tolist(), y.tolist()))

    gpkg = tmp_path / "cadastre.gpkg"
    schema = {"geometry": "Polygon", "properties": {"id": "str", "building": "str", "height": "float"}}
    with fiona.open(gpkg, "w", driver="GPKG", schema=schema, crs="EPSG:28992") as out:
        for oid, ring, tags in OSM_BUILDINGS:
            out.write({"geometry": {"type": "Polygon", "coordinates": [closed(rd(ring))]},
                       "properties": {"id": oid.replace("way/", "B"), "building": tags["building"],
                                      "height": float(tags["height"])}})
    parts = _overpass(tmp_path / "parts.geojson", OSM_PARTS)
    options = pair([gpkg, parts], ReaderOptions())
    got = {m.id.split("#", 1)[1]: m for m in read_file(gpkg, options)}
    assert sorted(got) == ["B1", "B2"], sorted(got)
    assert sorted(got["B1"].parts) == ["way/11", "way/12"]
    nave, aisle = (area(rd(ring)) for _, ring, _ in OSM_PARTS[:2])
    assert nave == pytest.approx(100, rel=1e-3)  # the grid's scale at Delft: near 1, not 1
    assert united_volume(got["B1"]) == pytest.approx(nave * 12 + aisle * 4, rel=1e-6)
    assert shapely.area(Polygon(rd(OSM_BUILDINGS[1][1]))) * 6 == pytest.approx(united_volume(got["B2"]), rel=1e-6)
    assert [m.id.split("#", 1)[1] for m in read_file(parts, options)] == ["way/13"]


def test_osm_parts_files_through_meshsom_ingest(tmp_path):
    """``meshsom ingest`` of a folder of the two exports (a Dask client, a zarr store): three buildings, the church
    of its parts; no part read twice."""
    folder = tmp_path / "osm"
    folder.mkdir()
    _overpass(folder / "buildings.geojson", OSM_BUILDINGS)
    _overpass(folder / "parts.geojson", OSM_PARTS)
    summary, records = _ingested(folder, tmp_path / "o.zarr")
    assert (summary["inputs"], summary["accepted"], summary["rejected"]) == (3, 3, 0), summary
    assert sorted(records) == ["buildings.geojson#way/1", "buildings.geojson#way/2", "parts.geojson#way/13"]
    assert records["buildings.geojson#way/1"]["volume"] == pytest.approx(1600, rel=1e-5)  # the church, of its parts
