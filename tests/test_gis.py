"""Buildings from GIS files (meshsom.gis): GeoPackage, Shapefile (also multipatch), FlatGeobuf,
File Geodatabase and GeoJSONSeq written by GDAL (fiona), GeoParquet written by pyarrow.

The WKB decoder is checked against what GEOS (shapely) encodes, and against a writer of the OGC's
layouts written here for the types GEOS lacks. Footprint volumes are computed by hand, placed on
the ellipsoid by PROJ (tests/footprints.py). 3D layers are made from the bundled Zürich LoD2
CityJSON file's own polygons, and every building part must come out as the CityJSON reader gives
it: accepted with the same volume, or rejected by both.
"""

from __future__ import annotations

import gzip
import json
import struct
import subprocess
import sys
from pathlib import Path

import fiona
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pyproj
import pytest
import shapely
from hypothesis import given, settings, strategies as st

from meshsom.errors import InputFileError
from meshsom.gis import NO_CRS_NOTE, horizontal, wkb_polygons
from meshsom.io import RawMesh, ReaderOptions, Rejection, expand_inputs, read_file
from meshsom.preprocess import preprocess

from footprints import (COURT_IN, COURT_OUT, HOUSE, L_SHAPE, area, closed, gabled_house, lonlat, rectangle,
                        write_geoparquet)

ZURICH = Path(__file__).resolve().parents[1] / "data/real/zurich-lod2-subset/zurich_subset_lod2.city.json"


# ----------------------------------------------------------------------------- WKB, as the OGC lays it out


def _wkb_ring(ring, order):
    ring = [tuple(p) for p in ring]
    if ring[0] != ring[-1]:
        ring = ring + [ring[0]]
    dims = len(ring[0])
    return struct.pack(order + "I", len(ring)) + b"".join(struct.pack(order + "d" * dims, *p) for p in ring)


def _wkb_polygon(rings, order="<", code=1003):
    return bytes([1 if order == "<" else 0]) + struct.pack(order + "II", code, len(rings)) + b"".join(
        _wkb_ring(r, order) for r in rings)


def _wkb_collection(code, members, order="<"):
    return bytes([1 if order == "<" else 0]) + struct.pack(order + "II", code, len(members)) + b"".join(members)


def polyhedral_surface(polygons, order="<"):
    """ISO WKB PolyhedralSurface Z (1015) of polygons (lists of rings of (x, y, z))."""
    return _wkb_collection(1015, [_wkb_polygon(p, order) for p in polygons], order)


def tin(triangles, order="<"):
    """ISO WKB TIN Z (1016) of Triangle Z (1017) members."""
    return _wkb_collection(1016, [_wkb_polygon([t], order, 1017) for t in triangles], order)


def _rings_of(geom):
    """Each polygon of a shapely geometry as its rings' coordinate arrays (the outer first)."""
    out = []
    for part in shapely.get_parts(geom):
        if isinstance(part, shapely.GeometryCollection):
            out += _rings_of(part)
        elif isinstance(part, (shapely.Polygon, shapely.MultiPolygon)):
            for poly in shapely.get_parts(part):
                out.append([np.asarray(poly.exterior.coords)] + [np.asarray(r.coords) for r in poly.interiors])
    return out


def test_wkb_polygons_read_what_geos_writes():
    hole = shapely.Polygon([(0, 0), (10, 0), (10, 10), (0, 10)], [[(2, 2), (2, 4), (4, 4), (4, 2)]])
    z = shapely.Polygon([(0, 0, 1), (5, 0, 1.5), (5, 5, 2), (0, 5, 2.5)])
    multi = shapely.MultiPolygon([z, shapely.Polygon([(7, 0, 3), (9, 0, 3), (9, 2, 4)])])
    mixed = shapely.GeometryCollection([z, shapely.LineString([(0, 0, 0), (1, 1, 1)]), shapely.Point(3, 3, 3), multi])
    for geom, has_z, kinds in [(hole, False, {"Polygon"}), (z, True, {"Polygon"}), (multi, True, {"MultiPolygon", "Polygon"}),
                               (mixed, True, {"GeometryCollection", "Polygon", "LineString", "Point", "MultiPolygon"})]:
        for flavor in ("iso", "extended"):
            for byte_order in (0, 1):
                data = shapely.to_wkb(shapely.set_srid(geom, 2056), output_dimension=3 if has_z else 2, flavor=flavor,
                                      byte_order=byte_order, include_srid=flavor == "extended")
                polygons, got_kinds, got_z = wkb_polygons(data, "x")
                want = _rings_of(geom)
                assert got_z == has_z and got_kinds == kinds
                assert len(polygons) == len(want)
                for p, q in zip(polygons, want):
                    assert len(p) == len(q) and all(np.array_equal(a, b) for a, b in zip(p, q))


def test_wkb_surfaces_measures_and_damage():
    faces, _ = gabled_house()
    rings = [[list(f) + [f[0]]] for f in faces]
    for order in ("<", ">"):
        polygons, kinds, has_z = wkb_polygons(polyhedral_surface(rings, order), "x")
        assert kinds == {"PolyhedralSurface", "Polygon"} and has_z
        assert [p[0].tolist() for p in polygons] == [[list(map(float, q)) for q in r[0]] for r in rings]
    triangles = [[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 0, 0), (0, 1, 0), (0, 0, 1)]]
    polygons, kinds, _ = wkb_polygons(tin(triangles), "x")
    assert kinds == {"TIN", "Triangle"} and [p[0][:3].tolist() for p in polygons] == [[list(map(float, q)) for q in t] for t in triangles]
    # XYZM (3003): m dropped; XYM (2003): two coordinates kept
    zm = _wkb_polygon([[(0, 0, 1, 9), (1, 0, 1, 9), (1, 1, 1, 9)]], code=3003)
    assert wkb_polygons(zm, "x")[0][0][0].tolist() == [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 0, 1]]
    xym = _wkb_polygon([[(0, 0, 9), (1, 0, 9), (1, 1, 9)]], code=2003)
    polygons, _, has_z = wkb_polygons(xym, "x")
    assert not has_z and polygons[0][0].shape == (4, 2)
    good = polyhedral_surface(rings)
    for damaged, problem in [(good[:-5], "ends early"), (good + b"\0", "bytes after its end"), (b"\7" + good[1:], "is not WKB"),
                             (struct.pack("<BII", 1, 8, 0), "curved geometry"), (struct.pack("<BI", 1, 99), "unknown type code"),
                             (struct.pack("<BII", 1, 1015, 10**9), "ends early")]:
        with pytest.raises(InputFileError, match=problem):
            wkb_polygons(damaged, "x")
    deep = _wkb_polygon([[(0, 0), (1, 0), (1, 1)]])
    for _ in range(40):
        deep = _wkb_collection(7, [deep])
    with pytest.raises(InputFileError, match="nests deeper"):
        wkb_polygons(deep, "x")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200), st.integers(0, 120))
def test_wkb_damage_is_an_input_error_never_a_crash(noise, cut):
    """Random bytes, and real WKB cut short or with bytes overwritten: a clear error or polygons."""
    from meshsom.gis import _WKB_NAMES

    faces, _ = gabled_house()
    good = polyhedral_surface([[list(f) + [f[0]]] for f in faces])
    assert len(good) > 120
    with pytest.raises(InputFileError, match="ends early|is not WKB"):  # cut short: always refused
        wkb_polygons(good[:cut], "x")
    for data in (noise, good[:cut] + noise + good[cut + len(noise):]):
        try:
            polygons, kinds, has_z = wkb_polygons(data, "x")
        except InputFileError as err:
            assert err.source == "x" and err.problem  # names the feature and the problem
            continue
        assert kinds <= set(_WKB_NAMES.values()) and isinstance(has_z, bool)
        for poly in polygons:  # what decoded is rings of finite-width positions, as documented
            assert poly and all(r.dtype == np.float64 and r.ndim == 2 and r.shape[1] in (2, 3) for r in poly)


def test_horizontal_tells_footprints_from_solids():
    faces, _ = gabled_house()
    house = [[np.asarray(f + [f[0]], float)] for f in faces]
    assert not horizontal(house)
    draped = [[np.array([(0, 0, 10.0), (20, 0, 10.4), (20, 8, 10.9), (0, 8, 10.5)])]]  # on sloping ground
    assert horizontal(draped) and horizontal([[np.array([(0, 0), (1, 0), (1, 1.0)])]])


# ----------------------------------------------------------------------------- footprints in GDAL's formats

FOOTPRINT_SCHEMA = {"geometry": "MultiPolygon", "properties": {
    "id": "str", "height": "float", "min_height": "float", "num_floors": "int", "family": "str"}}


def _footprints(ring_to_crs):
    """The footprints of the GeoJSON test as MultiPolygons with properties, in a CRS."""
    def multi(*polygons):
        return {"type": "MultiPolygon", "coordinates": [[closed(ring_to_crs(r)) for r in p] for p in polygons]}
    return [
        ("L", multi([L_SHAPE]), {"height": 12.5, "family": "L"}),
        ("court", multi([COURT_OUT, COURT_IN]), {"num_floors": 4}),
        ("raised", multi([[(60, 0), (70, 0), (70, 5), (60, 5)]], [[(75, 0), (80, 0), (80, 5), (75, 5)]]),
         {"height": 9.0, "min_height": 3.0}),
        ("nohigh", multi([L_SHAPE]), {}),
    ]


def _write_fiona(path, driver, features, crs, schema=FOOTPRINT_SCHEMA, **options):
    with fiona.open(path, "w", driver=driver, schema=schema, crs=crs, **options) as out:
        for fid, geometry, props in features:
            row = {k: None for k in schema["properties"]} | {"id": fid} | props
            out.write({"geometry": geometry, "properties": row})


def _volume(mesh) -> float:
    return preprocess(mesh.vertices, mesh.faces).volume_out


def _by_id(items):
    return {i.id.split("#", 1)[1]: i for i in items}


def _check_footprints(got):
    assert sorted(got) == ["L", "court", "nohigh", "raised"]
    assert got["L"].label == "L" and got["L"].lod == "1"
    assert _volume(got["L"]) == pytest.approx(area(L_SHAPE) * 12.5, rel=1e-5)
    assert _volume(got["court"]) == pytest.approx((area(COURT_OUT) - area(COURT_IN)) * 4 * 3.0, rel=1e-5)
    assert any("4 storeys x 3 m" in n for n in got["court"].notes)
    assert _volume(got["raised"]) == pytest.approx((50 + 25) * 6, rel=1e-5)  # from 3 m up to 9 m
    assert isinstance(got["nohigh"], Rejection) and "height" in got["nohigh"].reason


@pytest.mark.parametrize("driver,name", [("GPKG", "b.gpkg"), ("ESRI Shapefile", "b.shp"), ("FlatGeobuf", "b.fgb"),
                                         ("OpenFileGDB", "b.gdb"), ("GeoJSONSeq", "b.geojsonl"), (None, "b.parquet"),
                                         ("GML", "b.gml")])  # GML: ogr2ogr -f GML, GDAL's own namespace
def test_footprints_in_longitude_latitude(tmp_path, driver, name):
    """WGS 84 footprints: GDAL and GeoParquet give longitude first, whatever EPSG:4326's axis order."""
    features = _footprints(lonlat)
    path = tmp_path / name
    if driver is None:
        write_geoparquet(path, features)  # no "crs": OGC:CRS84, as the specification says
    else:  # GeoJSONSeq: GDAL writes 7 decimals (1 cm) unless told
        _write_fiona(path, driver, features, "EPSG:4326", **({"COORDINATE_PRECISION": 15} if driver == "GeoJSONSeq" else {}))
    got = _by_id(read_file(path))
    _check_footprints(got)
    assert any("geographic coordinates" in n for n in got["L"].notes)
    assert np.ptp(got["raised"].vertices[:, 2]) == pytest.approx(6, abs=1e-4)


def test_projected_feet_and_unknown_crs(tmp_path):
    feet = 1200 / 3937  # US survey foot
    ring = lambda r: [((984000 + x / feet), (190000 + y / feet)) for x, y in r]  # noqa: E731 (New York, EPSG:2263)
    features = [(f, g, {k: (v / feet if k in ("height", "min_height") else v) for k, v in p.items()})
                for f, g, p in _footprints(ring)]
    features[1][2]["num_floors"] = None
    features[1][2]["height"] = 12 / feet
    _write_fiona(tmp_path / "ny.gpkg", "GPKG", features, "EPSG:2263")
    got = _by_id(read_file(tmp_path / "ny.gpkg"))
    assert _volume(got["L"]) == pytest.approx(area(L_SHAPE) * 12.5, rel=1e-9)
    assert _volume(got["raised"]) == pytest.approx((50 + 25) * 6, rel=1e-9)
    assert any("scaled to metres from US survey foot" in n for n in got["L"].notes)
    # a shapefile without its .prj, in degrees: refused with the hint, read with --crs
    _write_fiona(tmp_path / "deg.shp", "ESRI Shapefile", _footprints(lonlat), "EPSG:4326")
    (tmp_path / "deg.prj").unlink()
    got = _by_id(read_file(tmp_path / "deg.shp"))
    assert isinstance(got["L"], Rejection) and "look like degrees" in got["L"].reason
    _check_footprints(_by_id(read_file(tmp_path / "deg.shp", ReaderOptions(crs="EPSG:4326"))))
    # GeoParquet: "crs": null is unknown (read as metres); PROJJSON is honoured
    rd = lambda r: [(84600 + x, 447400 + y) for x, y in r]  # noqa: E731 (RD New)
    write_geoparquet(tmp_path / "rd.parquet", _footprints(rd), crs=None)
    _check_footprints(_by_id(read_file(tmp_path / "rd.parquet")))
    import pyproj

    write_geoparquet(tmp_path / "ny.parquet", features, crs=pyproj.CRS("EPSG:2263").to_json_dict())
    assert _volume(_by_id(read_file(tmp_path / "ny.parquet"))["L"]) == pytest.approx(area(L_SHAPE) * 12.5, rel=1e-9)


def test_overture_roofs_in_geoparquet_and_a_crs_in_feet(tmp_path):
    """Overture Maps' buildings as GeoParquet (roof_shape, roof_height, roof_direction columns,
    nulls where a building has none) and a GeoPackage in New York's feet: each house gets its roof,
    at the volume worked out by hand; a roof without a height is pitched at 30 degrees whatever the
    footprint's unit (degrees, US survey feet)."""
    pitch = np.tan(np.radians(30.0)) * 4.0  # over half of an 8 m width, metres
    def multi(ring):
        return {"type": "MultiPolygon", "coordinates": [[closed(ring)]]}
    features = [("g", multi(lonlat(rectangle(0, 0, 12, 8))), {"height": 9.0, "roof_shape": "gabled", "roof_height": 3.0}),
                ("h", multi(lonlat(rectangle(20, 0, 12, 8))), {"height": 9.0, "roof_shape": "hipped", "roof_direction": 90.0}),
                ("s", multi(lonlat(rectangle(40, 0, 10, 6))), {"height": 8.0, "roof_shape": "skillion", "roof_height": 2.0}),
                ("b", multi(lonlat(rectangle(60, 0, 10, 6))), {"height": 8.0})]
    write_geoparquet(tmp_path / "overture.parquet", features, extra=("roof_shape", "roof_height", "roof_direction"))
    got = _by_id(read_file(tmp_path / "overture.parquet"))
    assert _volume(got["g"]) == pytest.approx(HOUSE["gabled"](12, 8, 6, 3), rel=1e-5)
    assert _volume(got["h"]) == pytest.approx(HOUSE["hipped"](12, 8, 9 - pitch, pitch), rel=1e-5)
    assert _volume(got["s"]) == pytest.approx(HOUSE["skillion"](10, 6, 6, 2), rel=1e-5)
    assert _volume(got["b"]) == pytest.approx(10 * 6 * 8, rel=1e-5) and got["b"].lod == "1"
    assert any("roof:shape=hipped built (S3DB)" in n for n in got["h"].notes), got["h"].notes
    feet = 1200 / 3937  # US survey foot
    in_feet = lambda r: [((984000 + x / feet), (190000 + y / feet)) for x, y in r]  # noqa: E731 (EPSG:2263)
    schema = {"geometry": "MultiPolygon", "properties": {"id": "str", "height": "float", "roof_shape": "str",
                                                         "roof_height": "float"}}
    _write_fiona(tmp_path / "ny.gpkg", "GPKG", [
        ("g", multi(in_feet(rectangle(0, 0, 12, 8))), {"height": 9 / feet, "roof_shape": "gabled"}),
        ("p", multi(in_feet(rectangle(20, 0, 10, 10))), {"height": 10 / feet, "roof_shape": "pyramidal",
                                                          "roof_height": 5 / feet})], "EPSG:2263", schema=schema)
    got = _by_id(read_file(tmp_path / "ny.gpkg"))
    assert _volume(got["g"]) == pytest.approx(HOUSE["gabled"](12, 8, 9 - pitch, pitch), rel=1e-9)
    assert _volume(got["p"]) == pytest.approx(HOUSE["pyramidal"](10, 10, 5, 5), rel=1e-9)


# ----------------------------------------------------------------------------- 3D layers from real LoD2


def _zurich_parts():
    """(part id, polygons as lists of rings of (x, y, z)) of every BuildingPart of the Zürich file."""
    cj = json.loads(ZURICH.read_text())
    scale, translate = np.array(cj["transform"]["scale"]), np.array(cj["transform"]["translate"])
    vertices = np.asarray(cj["vertices"], float) * scale + translate
    parts = []
    for oid, obj in cj["CityObjects"].items():
        for g in obj.get("geometry", []):
            parts.append((oid, [[vertices[ring].tolist() for ring in poly] for poly in g["boundaries"]]))
    return parts


def _volume_or_none(mesh):
    try:
        return _volume(mesh)
    except Exception:  # preprocessing refuses it (MeshError)
        return None


def test_3d_layers_read_as_the_cityjson_reader_reads_the_same_polygons(tmp_path):
    parts = _zurich_parts()[44:104]  # 60 parts (the slowest refusals, parts 12 and 41-42, left out)
    reference = {oid: mesh for oid, mesh in _by_id(read_file(ZURICH, ReaderOptions(parts="separate"))).items()
                 if oid in dict(parts)}
    volumes = {oid: _volume_or_none(mesh) for oid, mesh in reference.items()}
    schema = {"geometry": "3D MultiPolygon", "properties": {"id": "str"}}
    features = [(oid, {"type": "MultiPolygon", "coordinates": [[closed(r) for r in poly] for poly in polygons]}, {})
                for oid, polygons in parts]
    _write_fiona(tmp_path / "bag.gpkg", "GPKG", features, "EPSG:2056", schema)  # as the 3D BAG's lod22_3d layer
    _write_fiona(tmp_path / "patch.shp", "ESRI Shapefile", features, "EPSG:2056", schema, SHPT="MULTIPATCH")
    write_geoparquet(tmp_path / "ps.parquet", [(oid, None, {}) for oid, _ in parts], crs=None,
                      wkb=[polyhedral_surface([[closed(r) for r in poly] for poly in polygons]) for _, polygons in parts])
    assert sum(v is not None for v in volumes.values()) >= 25  # real LoD2: most parts close, some are refused
    for name in ("bag.gpkg", "patch.shp", "ps.parquet"):
        got = _by_id(read_file(tmp_path / name))
        assert sorted(got) == sorted(reference), name
        for oid, want in reference.items():
            mesh = got[oid]
            # the GeoParquet file was written without a CRS (crs=None): read as metres, noted
            assert mesh.lod == "2" and mesh.notes == ((NO_CRS_NOTE,) if name == "ps.parquet" else ()), (name, mesh.notes)
            volume = _volume_or_none(mesh)
            if volumes[oid] is None:
                assert volume is None, (name, oid)
                continue
            assert volume == pytest.approx(volumes[oid], rel=1e-9), (name, oid)
            assert np.allclose(np.unique(mesh.vertices + mesh.origin, axis=0), np.unique(want.vertices + want.origin, axis=0),
                               rtol=0, atol=1e-6)


def test_layers_ids_and_folders(tmp_path):
    """Every layer with geometry read (ids <layer>/<id>), or the one named; ids from a unique id column, else the
    feature ids (a 3D BAG GeoPackage's layout is read its own way: test_a_3d_bag_geopackage_...)."""
    parts = _zurich_parts()[:3]
    gpkg = tmp_path / "city" / "bag.gpkg"
    gpkg.parent.mkdir()
    solid = {"geometry": "3D MultiPolygon", "properties": {"identificatie": "str"}}
    flat = {"geometry": "Polygon", "properties": {"identificatie": "str", "hoogte": "float"}}
    with fiona.open(gpkg, "w", driver="GPKG", layer="solids", schema=solid, crs="EPSG:2056") as out:
        for oid, polygons in parts:
            out.write({"geometry": {"type": "MultiPolygon", "coordinates": [[closed(r) for r in p] for p in polygons]},
                       "properties": {"identificatie": oid}})
    with fiona.open(gpkg, "w", driver="GPKG", layer="footprints", schema=flat, crs="EPSG:2056") as out:
        for k in range(3):  # repeated ids: the feature ids are used
            out.write({"geometry": {"type": "Polygon", "coordinates": [closed([(2677000 + x + 40 * k, 1241800 + y) for x, y in L_SHAPE])]},
                       "properties": {"identificatie": "same", "hoogte": 7.5}})
    got = _by_id(read_file(gpkg))
    assert sorted(got) == sorted([f"solids/{oid}" for oid, _ in parts] + ["footprints/1", "footprints/2", "footprints/3"])
    assert all(isinstance(got[f"footprints/{k}"], Rejection) for k in (1, 2, 3))  # "hoogte" is not a default height
    heights = ReaderOptions(layer="footprints", height_attributes=("hoogte",))
    got = _by_id(read_file(gpkg, heights))
    assert sorted(got) == ["1", "2", "3"] and _volume(got["2"]) == pytest.approx(area(L_SHAPE) * 7.5, rel=1e-9)
    (bad,) = read_file(gpkg, ReaderOptions(layer="lod13_3d"))
    assert isinstance(bad, Rejection) and "has no layer 'lod13_3d'" in bad.reason and "'footprints'" in bad.reason
    # a folder: the FileGDB folder is one input, a shapefile's sidecars are read with it
    _write_fiona(tmp_path / "city" / "fp.shp", "ESRI Shapefile", _footprints(lonlat), "EPSG:4326")
    _write_fiona(tmp_path / "city" / "fp.gdb", "OpenFileGDB", _footprints(lonlat), "EPSG:4326")
    skipped = []
    files, rejected = expand_inputs([tmp_path / "city"], skipped)
    assert [f.name for f in files] == ["bag.gpkg", "fp.gdb", "fp.shp"] and not rejected
    assert {Path(p).suffix for p, why in skipped if why == "read with the shapefile fp.shp"} >= {".dbf", ".shx", ".prj"}
    # damaged and unreadable files are rejections that say so
    (tmp_path / "junk.gpkg").write_bytes(b"SQLite format 3\0" + bytes(2000))
    (tmp_path / "zipped.gpkg").write_bytes(gzip.compress(gpkg.read_bytes()))
    pq.write_table(pa.table({"x": [1, 2]}), tmp_path / "plain.parquet")
    for name, problem in [("junk.gpkg", "cannot be read through GDAL"), ("zipped.gpkg", "gzip-compressed"),
                          ("plain.parquet", "Parquet without geometry: no GeoParquet metadata")]:
        (item,) = read_file(tmp_path / name)
        assert isinstance(item, Rejection) and problem in item.reason, (name, item)


def test_gis_files_through_meshsom_ingest(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    flat = {"geometry": "Polygon", "properties": {"code": "str", "hoogte": "float"}}
    with fiona.open(folder / "district.gpkg", "w", driver="GPKG", layer="pand", schema=flat, crs="EPSG:28992") as out:
        for k in range(3):
            out.write({"geometry": {"type": "Polygon", "coordinates": [closed([(84600 + x + 30 * k, 447400 + y) for x, y in L_SHAPE])]},
                       "properties": {"code": f"b{k}", "hoogte": 5.0 + k}})
    with fiona.open(folder / "more.gdb", "w", driver="OpenFileGDB", layer="pand", schema=flat, crs="EPSG:28992") as out:
        out.write({"geometry": {"type": "Polygon", "coordinates": [closed([(84700 + x, 447400 + y) for x, y in L_SHAPE])]},
                   "properties": {"code": "g", "hoogte": 4.0}})
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(folder), "--out", str(tmp_path / "g.zarr"),
                          "--layer", "pand", "--height-attribute", "hoogte"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "4 meshes: 4 accepted, 0 rejected" in out.stdout, out.stdout
    manifest = json.loads((tmp_path / "g.zarr" / "manifest.json").read_text())
    volumes = {r["id"]: r["volume"] for r in manifest["records"]}
    assert volumes == pytest.approx({"district.gpkg#1": area(L_SHAPE) * 5, "district.gpkg#2": area(L_SHAPE) * 6,
                                     "district.gpkg#3": area(L_SHAPE) * 7, "more.gdb#1": area(L_SHAPE) * 4}, rel=1e-9)


def test_overtures_min_floor_counts_storeys_of_the_walls_own_height(tmp_path):
    """Overture's min_floor on a GeoParquet footprint with a height and num_floors counts storeys of its walls' own
    height (meshsom.osm.level_base, as OSM extracts read building:min_level): 3 floors in 12 m from min_floor 1 stand
    from 4 m, 12 x 8 x 8 m3 by hand (3 m storeys before: 12 x 8 x 9)."""
    box = shapely.geometry.mapping(shapely.box(84600, 447400, 84612, 447408))
    write_geoparquet(tmp_path / "floors.parquet", [("f", box, {"height": 12.0, "num_floors": 3, "min_floor": 1})],
                     crs=None, extra=("min_floor",))
    (mesh,) = read_file(tmp_path / "floors.parquet")
    z = mesh.vertices[:, 2] + mesh.origin[2]
    assert (z.min(), z.max()) == pytest.approx((4.0, 12.0), abs=1e-9), mesh
    assert any("base from min_floor = 1 storeys of 4 m" in n for n in mesh.notes), mesh.notes


def test_geoparquet_ranges_start_at_their_row_group(tmp_path):
    """A range of a GeoParquet file is read from the row group that holds its first row: the same
    rows as the whole file's, at every boundary."""
    from meshsom.gis import _parquet_records, gis_ranges

    rows = [(f"r{k}", shapely.geometry.mapping(shapely.box(k, 0, k + 1, 1)), {"height": 3.0}) for k in range(1000)]
    write_geoparquet(tmp_path / "rg.parquet", rows, crs=None)
    pq.write_table(pq.read_table(tmp_path / "rg.parquet"), tmp_path / "groups.parquet", row_group_size=97)
    path = tmp_path / "groups.parquet"
    assert [r[0] for r in _parquet_records(path, None, 0, None)] == [str(k) for k in range(1, 1001)]
    for a, b in [(0, 50), (96, 98), (97, 300), (450, 1000), (999, 1000), (1000, 1000), (300, None)]:
        assert [r[0] for r in _parquet_records(path, "id", a, b)] == [f"r{k}" for k in range(a, 1000 if b is None else b)]
    ranges = gis_ranges(path, 300, ReaderOptions())
    assert [r[4:] for r in ranges] == [[0, 300], [300, 600], [600, 900], [900, 1000]] and ranges[0][3] == "id"
    whole = [m.id for m in read_file(path)]
    assert [m.id for r in ranges for m in read_file(path, feature_range=r)] == whole


def _overture_like(path, n, row_group_size, start=0, extra=None, null_geometries=0, geo=True):
    """A GeoParquet file laid out as Overture's buildings are: an ``id``, the geometry, and a wide ``sources`` column
    (random text, which does not compress) that the planner never reads; ``extra`` more columns by name."""
    rng = np.random.default_rng(5)
    geometries = [None if k < null_geometries else shapely.to_wkb(shapely.box(84600 + 3 * k, 447400, 84602 + 3 * k, 447402))
                  for k in range(start, start + n)]  # Delft, in the Dutch CRS (EPSG:28992)
    columns = {"id": [f"b{k}" for k in range(start, start + n)], "height": [3.0 + k % 5 for k in range(start, start + n)],
               "sources": [rng.bytes(200).hex() for _ in range(n)], **(extra or {}), "geometry": geometries}
    table = pa.table(columns)
    if geo:
        table = table.replace_schema_metadata({b"geo": json.dumps({"version": "1.1.0", "primary_column": "geometry",
                                                                    "columns": {"geometry": {"encoding": "WKB",
                                                                                             "crs": "EPSG:28992"}}})})
    pq.write_table(table, path, row_group_size=row_group_size)
    return path


def _sparse_copy(path, spans, target):
    """``path`` with only the bytes of ``spans`` copied (zeros elsewhere), as the mirror's partial copies are."""
    data = Path(path).read_bytes()
    with open(target, "wb") as out:
        out.truncate(len(data))
        for a, b in spans:
            out.seek(a)
            out.write(data[a:b])
    return target


def test_the_planner_reads_a_geoparquet_file_from_its_footer_first_row_groups_and_id_columns(tmp_path):
    """What the planner reads of a large GeoParquet file on object storage is copied, found from its footer: a copy
    holding only those bytes plans as the whole file does (its layer, its ranges and their id column, whether it
    holds Overture's or OpenStreetMap's parts), and is a small share of an Overture-like file; a WKB column without
    metadata whose first footprints are empty is found in the first row groups; a file that is not Parquet gives
    None (copied whole; its reader says why). A range's task copies the first row group only where the file does not
    declare its geometry."""
    from meshsom.gis import (PLANNER_ROWS, _parquet_layers, gis_ranges, parquet_planned_spans, parquet_spans,
                             planner_columns)
    from meshsom.part_files import holds_osm_parts, pair

    columns = planner_columns(ReaderOptions())
    assert {"id", "building_id", "building:part"} <= set(columns)
    whole, sparse = tmp_path / "whole", tmp_path / "sparse"
    whole.mkdir()
    sparse.mkdir()
    files = {
        "buildings.parquet": _overture_like(whole / "buildings.parquet", 3000, 100),
        "parts.parquet": _overture_like(whole / "parts.parquet", 2000, 100, start=5000,
                                        extra={"building_id": [f"b{k % 3000}" for k in range(2000)]}),
        "osm_parts.parquet": _overture_like(whole / "osm_parts.parquet", 1500, 100, extra={"building:part": ["yes"] * 1500}),
        "wkb.parquet": _overture_like(whole / "wkb.parquet", 2000, 100, null_geometries=300, geo=False),
    }
    for name, path in files.items():
        spans = parquet_planned_spans(path, path.stat().st_size, columns)
        assert spans == sorted(spans) and all(a < b <= c for (a, b), (c, _) in zip(spans, spans[1:] + [[10**12, 0]]))
        copy = _sparse_copy(path, spans, sparse / name)
        assert _parquet_layers(copy) == _parquet_layers(path), name
        assert gis_ranges(copy, 400, ReaderOptions()) == gis_ranges(path, 400, ReaderOptions()), name
        assert holds_osm_parts(copy, ReaderOptions()) == holds_osm_parts(path, ReaderOptions()) == (name == "osm_parts.parquet")
        meta = pq.ParquetFile(path).metadata
        firsts = next(g for g in range(meta.num_row_groups) if sum(meta.row_group(h).num_rows for h in range(g + 1))
                      >= PLANNER_ROWS)
        later = meta.row_group(firsts + 1).column(list(pq.read_schema(path).names).index("sources"))
        a = later.dictionary_page_offset or later.data_page_offset
        assert copy.read_bytes()[a:a + later.total_compressed_size].strip(b"\0") == b"", "a later group's sources"
    assert gis_ranges(whole / "buildings.parquet", 400, ReaderOptions())[0][3] == "id"
    for name, first in (("buildings.parquet", False), ("wkb.parquet", True)):  # a range's task: the first row group
        meta = pq.ParquetFile(files[name]).metadata  # only where the file does not declare its geometry
        chunk = meta.row_group(0).column(0)
        a = chunk.dictionary_page_offset or chunk.data_page_offset
        assert any(x <= a < y for x, y in parquet_spans(files[name], 1200, 1300)) == first, name
    share = sum(b - a for a, b in parquet_planned_spans(files["buildings.parquet"], files["buildings.parquet"].stat().st_size,
                                                         columns)) / files["buildings.parquet"].stat().st_size
    assert share < 0.5, share  # a third of the rows whole (PLANNER_ROWS of 3,000), and the id column
    got = pair([sparse / n for n in ("buildings.parquet", "parts.parquet")], ReaderOptions())
    want = pair([whole / n for n in ("buildings.parquet", "parts.parquet")], ReaderOptions())
    assert got.part_files == (str(sparse / "parts.parquet"),) and want.part_files == (str(whole / "parts.parquet"),)
    (tmp_path / "not.parquet").write_bytes(b"PAR1 but nothing after it")
    assert parquet_planned_spans(tmp_path / "not.parquet", 25, columns) is None


def _curved_gpkg(path, srs_id=2056):
    """A GeoPackage written as cadastres export footprints with arcs (ALKIS, the Swiss official survey):
    a CURVEPOLYGON of a CompoundCurve, a 10 x 10 m square whose east side is a semicircular bay of
    radius 5 m (a CircularString through (15, 5)), 6 m high; built with sqlite3 by the GeoPackage
    specification (fiona writes no curves)."""
    import sqlite3

    e0, n0 = 2_600_000.0, 1_200_000.0
    def points(ps):
        return struct.pack("<I", len(ps)) + b"".join(struct.pack("<dd", e0 + x, n0 + y) for x, y in ps)
    line = b"\x01" + struct.pack("<I", 2) + points([(10, 10), (0, 10), (0, 0), (10, 0)])
    arc = b"\x01" + struct.pack("<I", 8) + points([(10, 0), (15, 5), (10, 10)])
    compound = b"\x01" + struct.pack("<II", 9, 2) + line + arc
    wkb = b"\x01" + struct.pack("<II", 10, 1) + compound  # CurvePolygon, one ring
    blob = b"GP" + bytes([0, 1]) + struct.pack("<i", srs_id) + wkb  # version 0, little endian, no envelope
    db = sqlite3.connect(path)
    db.executescript(f"""
        PRAGMA application_id = 1196444487; PRAGMA user_version = 10200;
        CREATE TABLE gpkg_spatial_ref_sys (srs_name TEXT NOT NULL, srs_id INTEGER PRIMARY KEY, organization TEXT NOT NULL,
            organization_coordsys_id INTEGER NOT NULL, definition TEXT NOT NULL, description TEXT);
        INSERT INTO gpkg_spatial_ref_sys VALUES ('undefined cartesian', -1, 'NONE', -1, 'undefined', NULL),
            ('undefined geographic', 0, 'NONE', 0, 'undefined', NULL),
            ('CH1903+ / LV95', {srs_id}, 'EPSG', {srs_id}, '{pyproj.CRS.from_epsg(srs_id).to_wkt()}', NULL);
        CREATE TABLE gpkg_contents (table_name TEXT NOT NULL PRIMARY KEY, data_type TEXT NOT NULL, identifier TEXT UNIQUE,
            description TEXT DEFAULT '', last_change DATETIME NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')),
            min_x DOUBLE, min_y DOUBLE, max_x DOUBLE, max_y DOUBLE, srs_id INTEGER);
        INSERT INTO gpkg_contents (table_name, data_type, identifier, srs_id) VALUES ('gebaeude', 'features', 'gebaeude', {srs_id});
        CREATE TABLE gpkg_geometry_columns (table_name TEXT NOT NULL, column_name TEXT NOT NULL, geometry_type_name TEXT NOT NULL,
            srs_id INTEGER NOT NULL, z TINYINT NOT NULL, m TINYINT NOT NULL, CONSTRAINT pk PRIMARY KEY (table_name, column_name));
        INSERT INTO gpkg_geometry_columns VALUES ('gebaeude', 'geom', 'CURVEPOLYGON', {srs_id}, 0, 0);
        CREATE TABLE gebaeude (fid INTEGER PRIMARY KEY AUTOINCREMENT, geom BLOB, id TEXT, height REAL);
    """)
    db.execute("INSERT INTO gebaeude (geom, id, height) VALUES (?, 'bay', 6.0)", (blob,))
    db.commit()
    db.close()


def test_curved_footprints_are_linearised_by_gdal(tmp_path):
    """Arcs in a GDAL-read layer come as segments (fiona asks GDAL for the linear geometry, 4 degree steps):
    the bay is read, its volume that of the square and the half disc to within the chords' 0.1 %."""
    _curved_gpkg(tmp_path / "kataster.gpkg")
    (m,) = read_file(tmp_path / "kataster.gpkg")
    assert isinstance(m, RawMesh), m
    assert _volume(m) == pytest.approx((100 + np.pi * 25 / 2) * 6, rel=1e-3)
    assert len(m.vertices) > 2 * 20  # the half circle in many segments, top and bottom


# ----------------------------------------------------------------------------- footprints in CSV files (WKT)


def _wkt(geometry) -> str:
    return shapely.geometry.shape(geometry).wkt


def test_open_buildings_csv_plain_gzipped_and_in_ranges(tmp_path):
    """Google's Open Buildings as it ships (a gzipped CSV: latitude, longitude, area_in_meters, confidence, a WKT
    ``geometry``, full_plus_code; no CRS, no height): read as WGS 84, noted, extruded to ``--default-height``,
    volumes by hand; the same read plain, gzipped and in ranges of one feature; ``meshsom ingest`` of the folder
    stores every footprint, a ``labels.csv`` beside it not taken for footprints, a CSV of points refused by name."""
    rows = [(L_SHAPE, 0.81), ([(0, 0), (12, 0), (12, 7), (0, 7)], 0.93), (COURT_OUT, 0.7)]
    header = "latitude,longitude,area_in_meters,confidence,geometry,full_plus_code\n"
    lines = []
    for k, (ring, confidence) in enumerate(rows):
        polygon = shapely.geometry.Polygon([(x + 40 * k, y) for x, y in lonlat(ring)])
        c = polygon.centroid
        lines.append(f'{c.y:.7f},{c.x:.7f},{area(ring):.2f},{confidence},"{polygon.wkt}",6GCRPR{k}C+4Q\n')
    folder = tmp_path / "in"
    folder.mkdir()
    (folder / "0e1_buildings.csv.gz").write_bytes(gzip.compress((header + "".join(lines)).encode()))
    (tmp_path / "plain.csv").write_text(header + "".join(lines))
    options = ReaderOptions(default_height=6.0)
    expected = [area(ring) * 6 for ring, _ in rows]
    for path in (folder / "0e1_buildings.csv.gz", tmp_path / "plain.csv"):
        got = _by_id(read_file(path, options))
        assert sorted(got) == ["1", "2", "3"], got
        assert [_volume(got[k]) for k in ("1", "2", "3")] == pytest.approx(expected, rel=1e-5)
        assert all(any("declares no CRS" in n and "WGS 84 longitude, latitude" in n for n in got[k].notes) for k in got)
    from meshsom.gis import gis_ranges, read_gis

    ranges = gis_ranges(folder / "0e1_buildings.csv.gz", 1, options)
    assert ranges is not None and len(ranges) == 3
    pieces = [i for r in ranges for i in read_gis(folder / "0e1_buildings.csv.gz", options, feature_range=r)]
    assert [i.id.split("#")[1] for i in pieces] == ["1", "2", "3"]
    assert [_volume(i) for i in pieces] == pytest.approx([_volume(got[k]) for k in ("1", "2", "3")], rel=1e-12)
    # without a default height: each footprint a rejection naming what was looked for
    assert all(isinstance(i, Rejection) and "without a height" in i.reason for i in read_file(tmp_path / "plain.csv"))
    (folder / "labels.csv").write_text("file,label\n0e1_buildings.csv.gz#1,L\n")
    (tmp_path / "points.csv").write_text("latitude,longitude,name\n47.37,8.54,tower\n")
    files, rejected = expand_inputs([folder, tmp_path / "points.csv"])
    assert [f.name for f in files] == ["0e1_buildings.csv.gz"]
    assert [r.reason for r in rejected] == ["is a CSV file without a geometry column (one named geometry, wkt, the_geom, "
                                            "geom, wkb_geometry, any case, holding footprints as WKT) or lines of GeoJSON features"]
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(folder), "--out", str(tmp_path / "o.zarr"),
                          "--default-height", "6"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "3 meshes: 3 accepted, 0 rejected" in out.stdout, out.stdout
    manifest = json.loads((tmp_path / "o.zarr" / "manifest.json").read_text())
    assert {r["id"]: r["volume"] for r in manifest["records"]} == pytest.approx(
        {f"0e1_buildings.csv.gz#{k}": v for k, v in zip("123", expected)}, rel=1e-5)


def test_a_csv_in_a_projected_crs_with_heights(tmp_path):
    """A CSV as QGIS exports a layer (a ``WKT`` column, a height column, EPSG:28992 metres): its coordinates beyond
    +/-180 are not taken for degrees, so ``--crs`` places it; volumes by hand."""
    rd = lambda r: [(84600 + x, 447400 + y) for x, y in r]  # noqa: E731 (RD New)
    text = "WKT,fid,hoogte\n" + "".join(
        f'"{_wkt({"type": "Polygon", "coordinates": [closed(rd(ring))]})}",{k},{h}\n'
        for k, (ring, h) in enumerate([(L_SHAPE, 12.5), (COURT_OUT, 4.0)]))
    (tmp_path / "pand.csv").write_text(text)
    options = ReaderOptions(crs="EPSG:28992", height_attributes=("hoogte",))
    got = _by_id(read_file(tmp_path / "pand.csv", options))
    assert _volume(got["1"]) == pytest.approx(area(L_SHAPE) * 12.5, rel=1e-9)
    assert _volume(got["2"]) == pytest.approx(area(COURT_OUT) * 4, rel=1e-9)
    assert not any("declares no CRS" in n for n in got["1"].notes)


def test_storeys_and_default_heights_are_metres_in_a_crs_in_feet(tmp_path):
    """In New York's EPSG:2263 (US survey feet, heights in feet too), a height from storeys (4 x 3 m) and the default
    height (9 m) are metres: 12 m and 9 m, not 12 and 9 feet as they were read before."""
    feet = 1200 / 3937
    ring = [((984000 + x / feet), (190000 + y / feet)) for x, y in L_SHAPE]
    features = [(name, {"type": "MultiPolygon", "coordinates": [[closed(ring)]]}, props)
                for name, props in (("floors", {"num_floors": 4}), ("none", {}), ("feet", {"height": 30 / feet}))]
    _write_fiona(tmp_path / "ny.gpkg", "GPKG", features, "EPSG:2263")
    got = _by_id(read_file(tmp_path / "ny.gpkg", ReaderOptions(default_height=9.0)))
    assert _volume(got["floors"]) == pytest.approx(area(L_SHAPE) * 12, rel=1e-9)
    assert _volume(got["none"]) == pytest.approx(area(L_SHAPE) * 9, rel=1e-9)
    assert _volume(got["feet"]) == pytest.approx(area(L_SHAPE) * 30, rel=1e-9)


def test_height_unit_reads_heights_in_feet_over_degrees(tmp_path):
    """New York's building footprints as GeoJSON: coordinates in degrees, ``heightroof`` and ``roof:height`` in feet
    (``height_unit: ft``); a value written with its unit is read in it; storeys stay metres; an unknown unit is
    refused by name."""
    import dataclasses

    w, d = 12.0, 8.0

    def feature(fid, dx, **props):
        return {"type": "Feature", "id": fid, "properties": props,
                "geometry": {"type": "Polygon", "coordinates": [closed(lonlat(rectangle(dx, 0, w, d)))]}}

    ft = 0.3048
    features = [feature("nyc", 0, heightroof=40.0), feature("text", 30, heightroof="12 m"),
                feature("floors", 60, num_floors=3),
                feature("gabled", 90, heightroof=30.0, **{"roof:shape": "gabled", "roof:height": 10.0})]
    path = tmp_path / "nyc.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    options = dataclasses.replace(ReaderOptions(), height_unit="ft", height_attributes=("heightroof",))
    got = _by_id(read_file(path, options))
    base = w * d
    assert _volume(got["nyc"]) == pytest.approx(base * 40 * ft, rel=1e-5)
    assert _volume(got["text"]) == pytest.approx(base * 12, rel=1e-5)
    assert _volume(got["floors"]) == pytest.approx(base * 9, rel=1e-5)
    assert _volume(got["gabled"]) == pytest.approx(HOUSE["gabled"](w, d, 20 * ft, 10 * ft), rel=1e-5)
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(path), "--out", str(tmp_path / "n.zarr"),
                          "--height-attribute", "heightroof", "--height-unit", "ft"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    volumes = {r["id"]: r["volume"] for r in json.loads((tmp_path / "n.zarr" / "manifest.json").read_text())["records"]}
    assert volumes["nyc.geojson#nyc"] == pytest.approx(base * 40 * ft, rel=1e-5)
    with pytest.raises(ValueError, match="height_unit must be one of m, ft, us-ft"):
        dataclasses.replace(ReaderOptions(), height_unit="yard")


def test_a_storey_count_column_is_named_on_the_command_line(tmp_path):
    """ShelterBetShemesh's 5,419 footprints hold their storeys in ``Floors``: every one was rejected "without a height",
    with no way to name that column from the command line (--height-attribute would read storeys as metres).
    ``--levels-attribute Floors`` reads it: 4 storeys x 3 m; the rejection's hint names the option."""
    w, d = 12.0, 9.0
    features = [{"type": "Feature", "id": "flat", "properties": {"Floors": 4},
                 "geometry": {"type": "Polygon", "coordinates": [closed(lonlat(rectangle(0, 0, w, d)))]}}]
    path = tmp_path / "shelters.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    (refused,) = read_file(path)
    assert isinstance(refused, Rejection) and "--levels-attribute NAME" in refused.reason
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(path), "--out", str(tmp_path / "s.zarr"),
                          "--levels-attribute", "Floors"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    (record,) = json.loads((tmp_path / "s.zarr" / "manifest.json").read_text())["records"]
    assert record["status"] == "accepted" and record["volume"] == pytest.approx(w * d * 4 * 3.0, rel=1e-5)


def test_damaged_csv_inputs_say_what_is_wrong(tmp_path):
    """A row whose WKT GDAL cannot read, a row of a point, and a gzipped CSV cut short (a truncated download): each a
    rejection naming the problem, the truncated file listed as an input that is rejected, not skipped."""
    (tmp_path / "rows.csv").write_text('geometry,height\n"POLYGON((0 0, 1 0, 1 1",5\n"POINT(1 2)",3\n'
                                       '"POLYGON((2600000 1200000,2600010 1200000,2600010 1200010,2600000 1200010,2600000 1200000))",4\n')
    got = list(read_file(tmp_path / "rows.csv", ReaderOptions(crs="EPSG:2056")))
    assert [getattr(i, "reason", None) for i in got] == [
        "has no geometry (its WKT is empty, or not WKT GDAL can read)", "holds a Point, not a building's polygons or solid",
        None]
    assert _volume(got[2]) == pytest.approx(400, rel=1e-9)
    (tmp_path / "cut.csv.gz").write_bytes(gzip.compress(b'WKT\n"POLYGON((0 0,10 0,10 10,0 10,0 0))"\n' * 50)[:40])
    files, rejected = expand_inputs([tmp_path])
    assert sorted(f.name for f in files) == ["cut.csv.gz", "rows.csv"] and not rejected
    (item,) = read_file(tmp_path / "cut.csv.gz")
    assert isinstance(item, Rejection) and item.reason == "gzip data ends early (a truncated download?)"  # as every gzip input says it


def test_a_gabled_house_in_web_mercator(tmp_path):
    """A 12 x 8 m house with a gabled roof at the default 30 degree pitch, written in EPSG:3857 (lengths 1.6 times too
    long at 52 degrees north): its volume is the house's by hand, its roof pitched as tagged, in true metres."""
    import math

    w, d, e = 12.0, 8.0, 6.0
    lon, lat = np.array(lonlat(rectangle(0, 0, w, d))).T
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(lon, lat)
    ring = [[float(a), float(b)] for a, b in zip(x, y)]
    rise = math.tan(math.radians(30)) * d / 2
    schema = {"geometry": "Polygon", "properties": {"id": "str", "height": "float", "roof:shape": "str"}}
    with fiona.open(tmp_path / "m.gpkg", "w", driver="GPKG", schema=schema, crs="EPSG:3857") as out:
        out.write({"geometry": {"type": "Polygon", "coordinates": [closed(ring)]},
                   "properties": {"id": "house", "height": e + rise, "roof:shape": "gabled"}})
    (house,) = read_file(tmp_path / "m.gpkg")
    assert any("Pseudo-Mercator scales lengths there by 1.625" in n for n in house.notes), house.notes
    assert _volume(house) == pytest.approx(HOUSE["gabled"](w, d, e, rise), rel=1e-4)


def test_an_arcgis_rest_query_answer_in_esri_json(tmp_path):
    """An ArcGIS REST query saved with f=json (Esri JSON, Web Mercator 102100, upper-case fields as Esri layers name
    them: HEIGHT, NUM_FLOORS), plain and gzipped: true-metre volumes by hand; an error response says what it is."""
    lon, lat = np.array(lonlat(L_SHAPE)).T
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(lon, lat)
    ring = closed([[float(a), float(b)] for a, b in zip(x, y)])
    far = [[a + 60.0, b] for a, b in ring]
    doc = {"displayFieldName": "", "geometryType": "esriGeometryPolygon",
           "spatialReference": {"wkid": 102100, "latestWkid": 3857},
           "fields": [{"name": "OBJECTID", "type": "esriFieldTypeOID"}, {"name": "HEIGHT", "type": "esriFieldTypeDouble"},
                      {"name": "NUM_FLOORS", "type": "esriFieldTypeInteger"}],
           "features": [{"attributes": {"OBJECTID": 1, "HEIGHT": 12.5, "NUM_FLOORS": None}, "geometry": {"rings": [ring]}},
                        {"attributes": {"OBJECTID": 2, "HEIGHT": None, "NUM_FLOORS": 4}, "geometry": {"rings": [far]}}]}
    (tmp_path / "query.json").write_text(json.dumps(doc))
    (tmp_path / "query.json.gz").write_bytes(gzip.compress(json.dumps(doc).encode()))
    for name in ("query.json", "query.json.gz"):
        got = _by_id(read_file(tmp_path / name))
        assert sorted(got) == ["1", "2"], got
        assert _volume(got["1"]) == pytest.approx(area(L_SHAPE) * 12.5, rel=1e-5)
        assert _volume(got["2"]) == pytest.approx(area(L_SHAPE) * 12, rel=1e-5)
    (tmp_path / "error.json").write_text(json.dumps({"error": {"code": 498, "message": "Invalid token.", "details": []}}))
    (item,) = read_file(tmp_path / "error.json")
    assert isinstance(item, Rejection) and item.reason == "is an ArcGIS REST error response, not data (code 498: Invalid token.)"


def test_mapinfo_and_spatialite_files(tmp_path):
    """MapInfo TAB (with its .dat, .map, .id), MIF (with its .mid: a driver that cannot count its features) and
    SpatiaLite, written by GDAL in LV95 with an upper-case HEIGHT: the footprints' volumes by hand (a TAB stores
    coordinates on its own integer grid: 1e-3), the sidecars listed as read with their table."""
    folder = tmp_path / "mi"
    folder.mkdir()
    schema = {"geometry": "Polygon", "properties": {"id": "str", "HEIGHT": "float"}}
    ring = closed([(2600000 + x, 1200000 + y) for x, y in L_SHAPE])
    for driver, name, options in (("MapInfo File", "b.tab", {}), ("MapInfo File", "c.mif", {"FORMAT": "MIF"}),
                                  ("SQLite", "d.sqlite", {})):
        with fiona.open(folder / name, "w", driver=driver, schema=schema, crs="EPSG:2056", **options) as out:
            out.write({"geometry": {"type": "Polygon", "coordinates": [ring]}, "properties": {"id": "x", "HEIGHT": 7.0}})
    skipped = []
    files, rejected = expand_inputs([folder], skipped)
    assert [f.name for f in files] == ["b.tab", "c.mif", "d.sqlite"] and not rejected
    assert sorted((Path(p).name, why) for p, why in skipped) == [
        ("b.dat", "read with the MapInfo file b.tab"), ("b.id", "read with the MapInfo file b.tab"),
        ("b.map", "read with the MapInfo file b.tab"), ("c.mid", "read with the MapInfo file c.mif")]
    for f, rel in zip(files, (1e-3, 1e-9, 1e-9)):
        (item,) = read_file(f.path)
        assert item.id == f"{f.name}#x" and _volume(item) == pytest.approx(area(L_SHAPE) * 7, rel=rel), f.name


@pytest.mark.parametrize("layout", ["separated", "interleaved"])
def test_geoparquet_in_native_geoarrow_encodings(tmp_path, layout):
    """GeoParquet 1.1's native encodings (GeoArrow, as geopandas writes with geometry_encoding="geoarrow"):
    ``multipolygon`` (an L with a courtyard-less ring, and a block of two polygons) and ``polygon``, coordinates as
    x/y structs or interleaved [x, y] lists; volumes by hand; a ring of two points refused naming the problem."""
    def coord(x, y):
        return {"x": 2600000.0 + x, "y": 1200000.0 + y} if layout == "separated" else [2600000.0 + x, 1200000.0 + y]

    coordinate = (pa.struct([("x", pa.float64()), ("y", pa.float64())]) if layout == "separated"
                  else pa.list_(pa.float64(), 2))
    rings = {"L": [[[coord(x, y) for x, y in closed(L_SHAPE)]]],
             "two": [[[coord(x + 40, y) for x, y in closed(rectangle(0, 0, 5, 5))]],
                     [[coord(x + 50, y) for x, y in closed(rectangle(0, 0, 4, 5))]]],
             "bad": [[[coord(0, 0), coord(1, 1)]]]}
    for encoding in ("multipolygon", "polygon"):
        ids = list(rings) if encoding == "multipolygon" else ["L", "bad"]
        values = [rings[k] if encoding == "multipolygon" else rings[k][0] for k in ids]
        kind = pa.list_(pa.list_(pa.list_(coordinate))) if encoding == "multipolygon" else pa.list_(pa.list_(coordinate))
        table = pa.table({"id": ids, "height": [6.0] * len(ids), "geometry": pa.array(values, kind)})
        meta = {"version": "1.1.0", "primary_column": "geometry",
                "columns": {"geometry": {"encoding": encoding, "geometry_types": [], "crs": None}}}
        path = tmp_path / f"{encoding}-{layout}.parquet"
        pq.write_table(table.replace_schema_metadata({b"geo": json.dumps(meta).encode()}), path)
        got = _by_id(read_file(path, ReaderOptions(crs="EPSG:2056")))
        assert _volume(got["L"]) == pytest.approx(area(L_SHAPE) * 6, rel=1e-9)
        if encoding == "multipolygon":
            assert _volume(got["two"]) == pytest.approx((25 + 20) * 6, rel=1e-9)
        assert isinstance(got["bad"], Rejection) and got["bad"].reason.startswith(
            f"its {encoding} geometry (GeoArrow) cannot be read"), got["bad"]


class _WkbType(pa.ExtensionType):
    """The GeoArrow WKB extension type, as geoarrow-pyarrow registers it: pyarrow writes a column of it as Parquet's
    own GEOMETRY (or GEOGRAPHY) logical type, the CRS in the type."""

    def __init__(self, meta: bytes = b"{}"):
        self._meta = meta
        super().__init__(pa.binary(), "geoarrow.wkb")

    def __arrow_ext_serialize__(self):
        return self._meta

    @classmethod
    def __arrow_ext_deserialize__(cls, storage_type, serialized):
        return cls(serialized)


def _native_parquet(path, rings, heights, meta):
    """Parquet 2.11 / GeoParquet 2.0: a GEOMETRY column (``meta``: GeoArrow's crs and edges), no "geo" key."""
    wkb = [shapely.to_wkb(shapely.Polygon(r)) for r in rings]
    pa.register_extension_type(_WkbType())
    try:
        column = pa.ExtensionArray.from_storage(_WkbType(json.dumps(meta).encode()), pa.array(wkb, pa.binary()))
        pq.write_table(pa.table({"id": [f"b{k}" for k in range(len(rings))], "height": heights, "geometry": column}),
                       path, store_schema=False)
    finally:
        pa.unregister_extension_type("geoarrow.wkb")
    assert b"geo" not in (pq.read_schema(path).metadata or {})
    return path


def test_parquet_of_its_own_geometry_type_and_plain_wkb(tmp_path):
    """Parquet that carries no GeoParquet metadata: a column of Parquet's GEOMETRY type with its CRS (an EPSG code,
    an SRID, PROJJSON) or none (OGC:CRS84, as the specification says), a GEOGRAPHY column in degrees, and a query's
    output (DuckDB's ST_AsWKB: a binary "geometry" column, no CRS) in degrees (read as WGS 84, noted) or in metres
    (--crs names its CRS). Volumes by hand: RD metres as they are, degrees placed by PROJ (tests/footprints.py)."""
    rd = [closed([(84600 + x + 30 * k, 447400 + y) for x, y in L_SHAPE]) for k in range(2)]
    degrees = [closed(lonlat([(x + 30 * k, y) for x, y in L_SHAPE])) for k in range(2)]
    heights = [7.5, 9.0]
    by_rd = [area(L_SHAPE) * h for h in heights]
    cases = {
        "epsg": (_native_parquet(tmp_path / "epsg.parquet", rd, heights, {"crs": "EPSG:28992"}), ReaderOptions()),
        "srid": (_native_parquet(tmp_path / "srid.parquet", rd, heights, {"crs": "srid:28992", "crs_type": "srid"}),
                 ReaderOptions()),
        "projjson": (_native_parquet(tmp_path / "projjson.parquet", rd, heights,
                                     {"crs": pyproj.CRS("EPSG:28992").to_json_dict()}), ReaderOptions()),
        "crs84": (_native_parquet(tmp_path / "crs84.parquet", degrees, heights, {}), ReaderOptions()),
        "geography": (_native_parquet(tmp_path / "geography.parquet", degrees, heights, {"edges": "spherical"}),
                      ReaderOptions()),
    }
    for name, rings in (("duckdb", degrees), ("metres", rd)):
        pq.write_table(pa.table({"id": ["b0", "b1"], "height": heights,
                                 "geometry": [shapely.to_wkb(shapely.Polygon(r)) for r in rings]}), tmp_path / f"{name}.parquet")
    cases["duckdb"] = (tmp_path / "duckdb.parquet", ReaderOptions())
    cases["metres"] = (tmp_path / "metres.parquet", ReaderOptions(crs="EPSG:28992"))
    for name, (path, options) in cases.items():
        got = _by_id(read_file(path, options))
        assert sorted(got) == ["b0", "b1"] and all(isinstance(m, RawMesh) for m in got.values()), (name, got)
        volumes = [_volume(got[f"b{k}"]) for k in range(2)]
        # degrees: drawn in metres about Delft at height 0 (tests/footprints.py), read back east-north-up
        assert volumes == pytest.approx(by_rd, rel=1e-9 if name in ("epsg", "srid", "projjson", "metres") else 1e-5), name
        assumed = [n for n in got["b0"].notes if "declares no CRS" in n]
        assert bool(assumed) == (name == "duckdb"), (name, got["b0"].notes)


def _box(x0, y0, w, d, h):
    """A w x d x h box's six faces, outward, as a 3D MultiPolygon's polygons (the 3D BAG's lod*_3d rows)."""
    a, b, c, e = (x0, y0), (x0 + w, y0), (x0 + w, y0 + d), (x0, y0 + d)
    lo = [(*p, 0.0) for p in (a, b, c, e)]
    hi = [(*p, float(h)) for p in (a, b, c, e)]
    faces = [[lo[0], lo[3], lo[2], lo[1]], [hi[0], hi[1], hi[2], hi[3]]]
    faces += [[lo[k], lo[(k + 1) % 4], hi[(k + 1) % 4], hi[k]] for k in range(4)]
    return [[f + f[:1]] for f in faces]


def test_a_3d_bag_geopackage_reads_each_building_once_at_one_lod(tmp_path):
    """A 3D BAG tile as the GeoPackage it downloads as (docs.3dbag.nl): pand (a row per building, its fid the key,
    identificatie), lod12_3d / lod13_3d / lod22_3d (a row per part above the terrain, fid naming its building) and
    2D layers of roof planes. Read, each building is one mesh, id its identificatie, at the LoD asked for (the
    highest by default), its parts (two disjoint boxes of one fid) one building, its pand attributes its own (a
    label); the other layers are other forms of the same buildings, not read again; whole or in ranges of one row.
    Before, every layer was read: each building three times, and a rejection per roof plane and per pand row."""
    from meshsom.gis import gis_ranges, read_gis

    from footprints import united_volume

    path = tmp_path / "7-368-544.gpkg"
    x0, y0 = 84600.0, 447400.0
    pand = {"geometry": "MultiPolygon", "properties": {"fid": "int", "identificatie": "str", "b3_dak_type": "str"}}
    with fiona.open(path, "w", driver="GPKG", layer="pand", schema=pand, crs="EPSG:7415") as out:
        for fid, roof in ((11, "slanted"), (12, "multiple horizontal")):
            out.write({"geometry": {"type": "MultiPolygon", "coordinates": [[[(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0, y0)]]]},
                       "properties": {"fid": fid, "identificatie": f"NL.IMBAG.Pand.05031000000000{fid}", "b3_dak_type": roof}})
    heights = {"1.2": 6.0, "1.3": 7.0, "2.2": 8.0}
    parts = {11: [(0, 0, 10, 8)], 12: [(30, 0, 6, 6), (46, 0, 4, 4)]}  # 12: two parts above the terrain
    three = {"geometry": "3D MultiPolygon", "properties": {"fid": "int", "pand_deel_id": "int"}}
    for lod, h in heights.items():
        with fiona.open(path, "w", driver="GPKG", layer=f"lod{lod.replace('.', '')}_3d", schema=three, crs="EPSG:7415",
                        FID="gid") as out:
            for fid, boxes in parts.items():
                for k, (x, y, w, d) in enumerate(boxes):
                    out.write({"geometry": {"type": "MultiPolygon", "coordinates": _box(x0 + x, y0 + y, w, d, h)},
                               "properties": {"fid": fid, "pand_deel_id": k}})
    flat = {"geometry": "Polygon", "properties": {"fid": "int", "b3_h_maaiveld": "float", "b3_h_dak_70p": "float"}}
    with fiona.open(path, "w", driver="GPKG", layer="lod13_2d", schema=flat, crs="EPSG:7415", FID="gid") as out:
        for fid, boxes in parts.items():
            for x, y, w, d in boxes:
                for half, rise in ((0, 8.0), (w / 2, 5.0)):  # two roof planes each: 8 and 5 m above the ground
                    ring = [(x0 + x + half, y0 + y), (x0 + x + half + w / 2, y0 + y), (x0 + x + half + w / 2, y0 + y + d),
                            (x0 + x + half, y0 + y + d)]
                    out.write({"geometry": {"type": "Polygon", "coordinates": [ring + ring[:1]]},
                               "properties": {"fid": fid, "b3_h_maaiveld": 1.5, "b3_h_dak_70p": 1.5 + rise}})
    ids = ["NL.IMBAG.Pand.0503100000000011", "NL.IMBAG.Pand.0503100000000012"]
    for options, lod in ((ReaderOptions(), "2.2"), (ReaderOptions(lod="lowest"), "1.2"), (ReaderOptions(lod="1.3"), "1.3"),
                         (ReaderOptions(layer="lod13_3d"), "1.3")):
        got = list(read_file(path, options))
        assert [m.id.split("#")[1] for m in got] == ids and all(m.lod == lod for m in got), (options.lod, got)
        assert united_volume(got[0]) == pytest.approx(10 * 8 * heights[lod], rel=1e-9)
        assert united_volume(got[1]) == pytest.approx((36 + 16) * heights[lod], rel=1e-9)
        assert any(f"a 3D BAG GeoPackage: its LoD {lod} layer read" in n for n in got[0].notes), got[0].notes
        assert any("2 parts above the terrain" in n for n in got[1].notes), got[1].notes
    labelled = list(read_file(path, ReaderOptions(label_attribute="b3_dak_type")))
    assert [m.label for m in labelled] == ["slanted", "multiple horizontal"]
    ranges = gis_ranges(path, 1, ReaderOptions())
    assert ranges is not None and len(ranges) == 3  # the rows of lod22_3d alone
    ranged = [m for r in ranges for m in read_gis(path, ReaderOptions(), feature_range=r)]
    assert [m.id for m in ranged] == [m.id for m in read_file(path)]
    assert [united_volume(m) for m in ranged] == pytest.approx([10 * 8 * 8, 52 * 8], rel=1e-9)
    # its 2D layer named: each roof plane a part, from the ground to its roof (b3_h_dak_70p - b3_h_maaiveld)
    flat_got = list(read_file(path, ReaderOptions(layer="lod13_2d")))
    assert [m.id.split("#")[1] for m in flat_got] == ids, flat_got
    assert united_volume(flat_got[0]) == pytest.approx(40 * 8 + 40 * 5, rel=1e-9)
    assert united_volume(flat_got[1]) == pytest.approx(26 * 8 + 26 * 5, rel=1e-9)
    assert any("4 3D BAG roof planes, each from the ground to its roof" in n for n in flat_got[1].notes), flat_got[1].notes
    flat_labelled = list(read_file(path, ReaderOptions(layer="lod13_2d", label_attribute="b3_dak_type")))
    assert [m.label for m in flat_labelled] == ["slanted", "multiple horizontal"]  # pand's, as the 3D layers have
    (none,) = read_file(path, ReaderOptions(lod="2"))  # a LoD the file has not: the file says which it has
    assert isinstance(none, Rejection) and "is a 3D BAG GeoPackage of LoD 1.2, 1.3, 2.2" in none.reason, none
    # a layer named that is not a 3D one: read as any layer (pand: footprints without a height)
    (first, _) = read_file(path, ReaderOptions(layer="pand"))
    assert isinstance(first, Rejection) and "without a height" in first.reason


def test_a_footprint_without_a_height_names_the_columns_that_may_hold_one(tmp_path):
    """The City Energy Analyst's zone.shp holds its heights in ``height_ag`` and ``floors_ag`` (with ``height_bg``,
    ``floors_bg`` below the ground), URBANopt's GeoJSON its storeys in ``number_of_stories``, San Francisco's
    footprints theirs in ``hgt_maxcm`` (centimetres): all were rejected
    "without a height", the hint naming only the options. It now names the columns whose names and positive values
    say they may be one (not those below the ground, nor a floor area), in the option that reads them; read so, the
    volume is the footprint's area (by hand) times that column."""
    import dataclasses

    w, d = 12.0, 9.0
    ring = closed(rectangle(2600000, 1200000, w, d))
    schema = {"geometry": "Polygon", "properties": {"Name": "str", "floors_ag": "int", "floors_bg": "int",
                                                    "height_ag": "int", "height_bg": "int", "floor_area": "float"}}
    with fiona.open(tmp_path / "zone.shp", "w", driver="ESRI Shapefile", schema=schema, crs="EPSG:2056") as out:
        out.write({"geometry": {"type": "Polygon", "coordinates": [ring]},
                   "properties": {"Name": "B1000", "floors_ag": 7, "floors_bg": 1, "height_ag": 21, "height_bg": 3,
                                  "floor_area": 756.0}})
    (refused,) = read_file(tmp_path / "zone.shp")
    assert isinstance(refused, Rejection), refused
    assert ("its property height_ag = 21 may be its height: --height-attribute height_ag; its property floors_ag = 7 "
            "may be its storey count: --levels-attribute floors_ag; --height-attribute NAME") in refused.reason
    assert "height_bg" not in refused.reason and "floor_area" not in refused.reason
    options = ReaderOptions()
    (read,) = read_file(tmp_path / "zone.shp", dataclasses.replace(
        options, height_attributes=("height_ag",) + options.height_attributes))
    assert _volume(read) == pytest.approx(w * d * 21, rel=1e-9)
    features = [{"type": "Feature", "properties": {"name": "Office 1", "number_of_stories": 6, "floor_area": 30000},
                 "geometry": {"type": "Polygon", "coordinates": [closed(lonlat(rectangle(0, 0, w, d)))]}}]
    features.append({"type": "Feature", "properties": {"sf16_bldgid": "201006_1", "hgt_maxcm": 1530},
                     "geometry": features[0]["geometry"]})
    (tmp_path / "urbanopt.json").write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    refused, centimetres = read_file(tmp_path / "urbanopt.json")
    assert isinstance(refused, Rejection) and isinstance(centimetres, Rejection)
    assert "its property number_of_stories = 6 may be its storey count: --levels-attribute number_of_stories" in refused.reason
    # San Francisco's heights are centimetres by their names: the hint names the unit, and --height-unit cm reads them
    assert ("its property hgt_maxcm = 1530 may be its height, in centimetres by its name: --height-attribute hgt_maxcm "
            "--height-unit cm") in centimetres.reason
    (_, in_cm) = read_file(tmp_path / "urbanopt.json", dataclasses.replace(
        options, height_attributes=("hgt_maxcm",), height_unit="cm"))
    features[1]["properties"] = {"height": 15.3}
    (tmp_path / "metres.json").write_text(json.dumps({"type": "FeatureCollection", "features": features[1:]}))
    (in_m,) = read_file(tmp_path / "metres.json")
    assert _volume(in_cm) == pytest.approx(_volume(in_m), rel=1e-12)  # 15.3 m, not 1,530 m
