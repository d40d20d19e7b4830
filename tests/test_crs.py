"""Buildings in geographic or foot-based CRSs are read in metres (meshsom.crs).

The reference is PROJ itself, through pyproj pipelines written here (topocentric conversion, unit
conversion), independent of meshsom's own NumPy geodesy: a real district in metres is placed on
the ellipsoid as latitude and longitude (PLATEAU's EPSG:6697, WGS 84's 4979 and 4326, OGC:CRS84),
or written in US survey feet (New York's EPSG:2263), in CityJSON, CityJSONSeq and CityGML, and must
read back as the same buildings in metres: the same faces, the same distances between vertices
(a geographic building comes back in its own east-north-up frame, a rigid motion of the original),
the same orientation, z still up.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyproj
import pytest

from cityjson_samples import to_cityjsonseq, write_lines
from meshsom.crs import CoordinateSystem, UnknownCRS, coordinate_system, east_north_up, looks_geographic
from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file
from test_citygml import to_citygml

ROOT = Path(__file__).resolve().parents[1]
DELFT = ROOT / "data" / "real" / "delft-lod1-3dfier" / "delft.city.json"
TOKYO = (35.6812, 139.7671, 40.0)  # latitude, longitude, ellipsoidal height of the district's centre


def _to_geodetic(enu: np.ndarray, centre) -> np.ndarray:
    """PROJ: east-north-up metres about ``centre`` -> latitude, longitude (degrees), height (GRS80)."""
    lat0, lon0, h0 = centre
    pipeline = (f"+proj=pipeline +step +inv +proj=topocentric +lat_0={lat0} +lon_0={lon0} +h_0={h0} +ellps=GRS80 "
                f"+step +inv +proj=cart +ellps=GRS80 +step +proj=unitconvert +xy_in=rad +xy_out=deg "
                f"+step +proj=axisswap +order=2,1")
    t = pyproj.Transformer.from_pipeline(pipeline)
    lat, lon, h = t.transform(enu[:, 0], enu[:, 1], enu[:, 2])
    return np.stack([lat, lon, h], axis=1)


def _meshes(items) -> dict[str, RawMesh | Rejection]:
    return {i.id.split("#", 1)[1]: i for i in items}


def _delft_geographic(order: str = "latlon", scale=(1e-9, 1e-9, 1e-4)) -> tuple[dict, dict]:
    """The Delft district placed at Tokyo in latitude/longitude: (original document, geographic one)."""
    original = json.loads(DELFT.read_text())
    t = original["transform"]
    world = np.asarray(original["vertices"], float) * t["scale"] + t["translate"]
    enu = world - (world.min(axis=0) + world.max(axis=0)) / 2
    geo = _to_geodetic(enu, TOKYO)
    if order == "lonlat":
        geo = geo[:, [1, 0, 2]]
    translate = np.round(geo.min(axis=0), 3)
    doc = copy.deepcopy(original)
    doc.pop("metadata", None)  # its referenceSystem is the original's (EPSG:7415)
    doc["transform"] = {"scale": list(scale), "translate": translate.tolist()}
    doc["vertices"] = np.round((geo - translate) / scale).astype(np.int64).tolist()
    return original, doc


def _distances(v: np.ndarray) -> np.ndarray:
    return np.linalg.norm(v[:, None, :] - v[None, :, :], axis=2)


def _signed_volume(v, f) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def assert_rigid_copies(got: dict, expected: dict, tol: float, note: str = "geographic coordinates"):
    """Every building read from the geographic file is its metric original moved rigidly."""
    assert set(got) == set(expected)
    compared = 0
    for key, e in expected.items():
        g = got[key]
        assert type(g) is type(e), (key, g, e)
        if isinstance(e, Rejection):
            continue
        assert np.array_equal(g.faces, e.faces), key
        np.testing.assert_allclose(_distances(g.vertices), _distances(e.vertices), atol=tol, err_msg=key)
        vg, ve = _signed_volume(g.vertices, g.faces), _signed_volume(e.vertices, e.faces)
        assert vg == pytest.approx(ve, rel=1e-4, abs=1e-3), key
        # z stays up: the building's own vertical extent is the original's
        span_g, span_e = np.ptp(g.vertices[:, 2]), np.ptp(e.vertices[:, 2])
        assert span_g == pytest.approx(span_e, abs=2e-3), key
        assert any(note in n for n in g.notes), g.notes
        compared += 1
    assert compared > 100


def assert_same_meshes(got: dict, expected: dict, tol: float = 1e-6):
    """The same buildings up to the order of their vertices (another container numbers them
    otherwise): vertices matched after centring, then the same triangles."""
    from scipy.spatial import cKDTree

    assert set(got) == set(expected)
    for key, e in expected.items():
        g = got[key]
        assert type(g) is type(e), (key, g, e)
        if isinstance(e, Rejection):
            continue
        vg, ve = g.vertices - g.vertices.mean(axis=0), e.vertices - e.vertices.mean(axis=0)
        dist, match = cKDTree(ve).query(vg)
        assert dist.max() < tol and len(set(match)) == len(ve), key

        def canonical(faces):
            return sorted(tuple(np.roll(t, -int(np.argmin(t)))) for t in faces)

        assert canonical(match[g.faces]) == canonical(e.faces), key


# ----------------------------------------------------------------------------- identification


@pytest.mark.parametrize("reference,geographic,latitude_first,horizontal_m", [
    ("EPSG:7415", False, True, 1.0),
    ("urn:ogc:def:crs:EPSG::7415", False, True, 1.0),
    ("https://www.opengis.net/def/crs/EPSG/0/2056", False, True, 1.0),
    ("http://www.opengis.net/def/crs/EPSG/0/6697", True, True, 1.0),
    ("urn:ogc:def:crs:EPSG::4979", True, True, 1.0),
    ("EPSG:4326", True, True, 1.0),
    ("OGC:CRS84", True, False, 1.0),
    ("EPSG:2263", False, True, 1200 / 3937),
    ("urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783", False, True, 1.0),
    ("urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH", False, True, 1.0),
])
def test_coordinate_systems_are_identified(reference, geographic, latitude_first, horizontal_m):
    crs = coordinate_system(reference)
    assert isinstance(crs, CoordinateSystem)
    assert crs.geographic == geographic
    if geographic:
        assert crs.latitude_first == latitude_first
        assert crs.semi_major == pytest.approx(6378137.0)
        assert not crs.metric
    else:
        assert crs.horizontal_m == pytest.approx(horizontal_m, rel=1e-12)
        assert crs.metric == (horizontal_m == 1.0)


@pytest.mark.parametrize("reference,expected", [
    # geoRES's CityGML 1.0 test data: one part, its version field left out (PROJ: "invalid crs component")
    ("urn:ogc:def:crs,crs:EPSG:31467", "EPSG:31467"),
    ("urn:ogc:def:crs,crs:EPSG::31467", "EPSG:31467"),  # one part (PROJ refuses a compound of one)
    ("urn:ogc:def:crs,crs:EPSG:31467,crs:EPSG:5783", "EPSG:31467+5783"),
    ("urn:ogc:def:crs,crs:EPSG:6.12:31467,crs:EPSG:6.12:5783", "EPSG:31467+5783"),  # with versions, as PROJ reads it
    ("urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::7837", "EPSG:25832+7837"),
    ("urn:ogc:def:crs,crs:EPSG::4326", "EPSG:4326"),
])
def test_ogc_compound_urns_read_as_their_parts(reference, expected):
    """OGC's compound-CRS URN in the forms PROJ refuses is the CRS of its parts, as pyproj names them."""
    crs = coordinate_system(reference)
    reference_crs = pyproj.CRS.from_user_input(expected)
    assert crs.name == reference_crs.name
    assert crs.geographic == reference_crs.is_geographic
    assert crs.metric == (not reference_crs.is_geographic)


def test_a_malformed_compound_urn_is_still_unknown():
    with pytest.raises(UnknownCRS, match="not known to pyproj"):
        coordinate_system("urn:ogc:def:crs,crs:EPSG:a b,crs:EPSG::5783")


@pytest.mark.parametrize("reference,problem", [
    ("EPSG:99999999", "not known to pyproj"),
    ("no such crs", "not known to pyproj"),
    ("EPSG:4978", "geocentric"),
])
def test_unusable_crs_references_say_why(reference, problem):
    with pytest.raises(UnknownCRS, match=problem):
        coordinate_system(reference)
    with pytest.raises(ValueError, match=f"crs: .*{problem}"):
        ReaderOptions(crs=reference)


@pytest.mark.parametrize("centre", [TOKYO, (60.17, 24.94, 15.0), (-33.86, 151.21, 30.0), (52.0, 179.9995, 0.0), (0.0, -0.0004, -5.0)])
def test_east_north_up_is_proj_topocentric(centre):
    rng = np.random.default_rng(0)
    enu = rng.uniform([-300, -300, -20], [300, 300, 120], size=(200, 3))
    geo = _to_geodetic(enu, centre)
    got = east_north_up(geo, np.asarray(centre, float), 6378137.0, 1 / 298.257222101)
    np.testing.assert_allclose(got, enu, atol=1e-6)


# ----------------------------------------------------------------------------- whole files


@pytest.mark.parametrize("reference,order", [
    ("https://www.opengis.net/def/crs/EPSG/0/6697", "latlon"),
    ("urn:ogc:def:crs:EPSG::4979", "latlon"),
    ("OGC:CRS84h", "lonlat"),
    ("EPSG:4326", "lonlat"),  # declared latitude first, written longitude first (as GIS tools often do)
])
def test_a_district_in_latitude_longitude_reads_in_metres(tmp_path, reference, order):
    original, geographic = _delft_geographic(order)
    geographic["metadata"] = {"referenceSystem": reference}
    expected = _meshes(read_file(DELFT))
    path = tmp_path / "tokyo.city.json"
    path.write_text(json.dumps(geographic))
    got = _meshes(read_file(path))
    assert_rigid_copies(got, expected, tol=3e-4)  # the file's grid: 1e-9 degrees, 0.1 mm of height
    if order == "lonlat" and reference == "EPSG:4326":
        assert all("other order" in " ".join(m.notes) for m in got.values() if isinstance(m, RawMesh))
    # the world position stays in the file's own coordinates
    some = next(m for m in got.values() if isinstance(m, RawMesh))
    lat_lon = some.origin[[0, 1]] if order == "latlon" else some.origin[[1, 0]]
    assert np.allclose(lat_lon, TOKYO[:2], atol=0.01)


def test_cityjsonseq_and_citygml_in_latitude_longitude(tmp_path):
    _, geographic = _delft_geographic()
    geographic["metadata"] = {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/6697"}
    (tmp_path / "tokyo.city.json").write_text(json.dumps(geographic))
    expected = _meshes(read_file(tmp_path / "tokyo.city.json"))  # tested against the metric original above
    write_lines(tmp_path / "tokyo.city.jsonl", to_cityjsonseq(geographic))
    assert_same_meshes(_meshes(read_file(tmp_path / "tokyo.city.jsonl")), expected)
    gml = to_citygml(geographic)
    # PLATEAU declares the CRS once, on the model's envelope ...
    envelope = ('<gml:boundedBy><gml:Envelope srsName="http://www.opengis.net/def/crs/EPSG/0/6697" srsDimension="3">'
                '<gml:lowerCorner>35.67 139.76 30</gml:lowerCorner><gml:upperCorner>35.69 139.77 60</gml:upperCorner>'
                '</gml:Envelope></gml:boundedBy>')
    start = gml.index(">", gml.index("<core:CityModel")) + 1
    (tmp_path / "envelope.gml").write_text(gml[:start] + envelope + gml[start:])
    assert_same_meshes(_meshes(read_file(tmp_path / "envelope.gml")), expected)
    # ... other writers on every geometry
    (tmp_path / "geometry.gml").write_text(gml.replace("<gml:Solid>", '<gml:Solid srsName="EPSG:6697">')
                                           .replace("<gml:MultiSurface>", '<gml:MultiSurface srsName="EPSG:6697">'))
    assert_same_meshes(_meshes(read_file(tmp_path / "geometry.gml")), expected)
    # and without any srsName, the buildings are refused as degrees, each with its reason
    assert all(isinstance(m, Rejection) and "look like degrees" in m.reason for m in read_file(tmp_path / "tokyo.gml")
               ) if (tmp_path / "tokyo.gml").write_text(gml) else False


@pytest.mark.parametrize("reference, scale", [("EPSG:3857", 1.231), ("urn:ogc:def:crs:EPSG::3857", 1.231)])
def test_web_mercator_is_read_in_true_metres(tmp_path, reference, scale):
    """The Delft district placed at Tokyo in Web Mercator (EPSG:3857, as web services export), whose lengths are
    1 / cos(latitude) = 1.23 times too long there while its heights are metres: every building is its metric
    original moved rigidly (read as it was, its footprints were 23 % too wide and its volumes 52 % too large)."""
    _, geographic = _delft_geographic("latlon")
    t = geographic["transform"]
    geo = np.asarray(geographic["vertices"], float) * t["scale"] + t["translate"]  # latitude, longitude, height
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(geo[:, 1], geo[:, 0])
    world = np.stack([x, y, geo[:, 2]], axis=1)
    translate = np.round(world.min(axis=0), 3)
    doc = copy.deepcopy(geographic)
    doc["metadata"] = {"referenceSystem": reference}
    doc["transform"] = {"scale": [1e-4, 1e-4, 1e-4], "translate": translate.tolist()}
    doc["vertices"] = np.round((world - translate) / 1e-4).astype(np.int64).tolist()
    (tmp_path / "mercator.city.json").write_text(json.dumps(doc))
    got = _meshes(read_file(tmp_path / "mercator.city.json"))
    assert_rigid_copies(got, _meshes(read_file(DELFT)), tol=5e-4, note="scales lengths there by")
    some = next(m for m in got.values() if isinstance(m, RawMesh))
    assert any(f"scales lengths there by {scale}" in n for n in some.notes), some.notes


def test_national_grids_and_utm_are_read_as_they_are():
    """Projections within MAX_SCALE_ERROR of true scale (Swiss LV95, RD New, UTM on its central meridian) are read as
    they are; Lambert-93 near Lille (2.2e-3) and Web Mercator are converted."""
    from meshsom.crs import MAX_SCALE_ERROR, point_scale, to_metres

    local = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 5.0]])
    for reference, xy in (("EPSG:2056", (2683000, 1248000)), ("EPSG:28992", (85000, 447000)), ("EPSG:32632", (500000, 5200000))):
        crs = coordinate_system(reference)
        assert abs(point_scale(crs, *xy) - 1) <= MAX_SCALE_ERROR
        same, note = to_metres(local, np.array([*xy, 400.0]), crs)
        assert same is local and note is None
    lille = coordinate_system("EPSG:2154")
    out, note = to_metres(local, np.array([704000.0, 7059000.0, 30.0]), lille)
    assert "scales lengths there by 1.002" in note
    assert np.linalg.norm(out[1] - out[0]) == pytest.approx(10 / point_scale(lille, 704000.0, 7059000.0), rel=1e-5)  # 30 m up: 5e-6


def test_feet_are_scaled_to_metres(tmp_path):
    original = json.loads(DELFT.read_text())
    feet = 1200 / 3937  # metres per US survey foot
    doc = copy.deepcopy(original)
    shift = np.array([84000 / feet - 984000, 446000 / feet - 190000, 0.0])  # Delft moved to Manhattan, where k = 1
    doc["transform"] = {"scale": [s / feet for s in original["transform"]["scale"]],
                        "translate": (np.array(original["transform"]["translate"]) / feet - shift).tolist()}
    doc["metadata"] = {"referenceSystem": "EPSG:2263"}  # NAD83 / New York Long Island (ftUS)
    path = tmp_path / "feet.city.json"
    path.write_text(json.dumps(doc))
    expected, got = _meshes(read_file(DELFT)), _meshes(read_file(path))
    assert set(got) == set(expected)
    for key, e in expected.items():
        if isinstance(e, RawMesh):
            g = got[key]
            np.testing.assert_allclose(g.vertices, e.vertices, atol=1e-9)
            assert np.array_equal(g.faces, e.faces)
            np.testing.assert_allclose(g.origin, e.origin / feet - shift, rtol=1e-12)  # the file's own coordinates
            assert any("US survey foot" in n for n in g.notes)


def test_degrees_without_a_crs_are_refused_or_read_with_the_option(tmp_path):
    _, geographic = _delft_geographic()
    path = tmp_path / "tokyo.city.json"
    path.write_text(json.dumps(geographic))  # no metadata.referenceSystem
    refused = list(read_file(path))
    assert len(refused) == 160 and all(isinstance(r, Rejection) and "look like degrees" in r.reason
                                        and "--crs" in r.reason for r in refused)
    expected = _meshes(read_file(DELFT))
    assert_rigid_copies(_meshes(read_file(path, ReaderOptions(crs="EPSG:4979"))), expected, tol=3e-4)
    # a declared CRS wins over the option
    geographic["metadata"] = {"referenceSystem": "urn:ogc:def:crs:EPSG::4979"}
    path.write_text(json.dumps(geographic))
    assert_rigid_copies(_meshes(read_file(path, ReaderOptions(crs="EPSG:2263"))), expected, tol=3e-4)


def test_an_unknown_declared_crs_is_read_as_metres_with_a_note(tmp_path):
    doc = json.loads(DELFT.read_text())
    doc["metadata"] = {"referenceSystem": "urn:ogc:def:crs:EPSG::99999999"}
    path = tmp_path / "odd.city.json"
    path.write_text(json.dumps(doc))
    got, expected = _meshes(read_file(path)), _meshes(read_file(DELFT))
    for key, e in expected.items():
        if isinstance(e, RawMesh):
            np.testing.assert_array_equal(got[key].vertices, e.vertices)
            assert any("not known to pyproj" in n and "read as metres" in n for n in got[key].notes)


def test_looks_geographic_only_for_needles_at_degree_coordinates():
    needle = np.array([[0, 0, 0], [2e-4, 0, 0], [0, 2e-4, 0], [0, 0, 25.0]])
    assert looks_geographic(needle, np.array([139.7, 35.6, 40.0])) is not None
    assert looks_geographic(needle, np.array([84616.0, 447422.0, 0.0])) is None  # far beyond any degree
    box = np.array([[0, 0, 0], [20.0, 0, 0], [0, 12.0, 0], [0, 0, 9.0]])
    assert looks_geographic(box, np.array([10.0, 50.0, 0.0])) is None
    assert looks_geographic(box * 1e-3, np.array([10.0, 50.0, 0.0])) is None  # a model in km: all axes alike


def test_ingest_cli_reads_an_obj_in_degrees_with_crs(tmp_path):
    rng_box = np.array([[0, 0, 0], [18, 0, 0], [18, 11, 0], [0, 11, 0], [0, 0, 7], [18, 0, 7], [18, 11, 7], [0, 11, 7.0]])
    geo = _to_geodetic(rng_box - rng_box.mean(axis=0), TOKYO)[:, [1, 0, 2]]  # x = longitude, as OBJ exports do
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in geo] + ["f " + " ".join(str(i + 1) for i in q) for q in quads]
    folder = tmp_path / "in"
    folder.mkdir()
    (folder / "house.obj").write_text("\n".join(lines) + "\n")
    cmd = [sys.executable, "-m", "pipelines.cli", "ingest", str(folder), "--json"]
    refused = subprocess.run(cmd + ["--out", str(tmp_path / "a.zarr")], capture_output=True, text=True, cwd=ROOT)
    assert refused.returncode == 1 and "no accepted mesh" in refused.stderr, (refused.stdout, refused.stderr)
    read = subprocess.run(cmd + ["--out", str(tmp_path / "b.zarr"), "--crs", "OGC:CRS84h"], capture_output=True, text=True, cwd=ROOT)
    assert read.returncode == 0, read.stderr
    assert json.loads(read.stdout.strip().splitlines()[-1])["accepted"] == 1
    from meshsom.store import open_store, read_mesh

    v, f = read_mesh(open_store(tmp_path / "b.zarr"), 0)  # the store holds the house in metres
    assert _signed_volume(v, f) == pytest.approx(18 * 11 * 7, rel=1e-6)


def test_projected_coordinates_declared_as_degrees_are_refused(tmp_path):
    """The Delft district (RD New metres) labelled EPSG:4326: every building refused, saying its coordinates are
    beyond the degrees its CRS declares (before, each was read as a building thousands of kilometres wide)."""
    doc = json.loads(DELFT.read_text())
    doc["metadata"] = {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/4326"}
    (tmp_path / "wrong.city.json").write_text(json.dumps(doc))
    items = list(read_file(tmp_path / "wrong.city.json"))
    assert len(items) > 100 and all(isinstance(i, Rejection) for i in items)
    assert all("beyond the +/-90 and +/-180 degrees of the geographic CRS it declares (WGS 84)" in i.reason for i in items)


def test_degrees_declared_as_a_projected_crs_are_refused(tmp_path):
    """The Delft district in latitude and longitude labelled RD New (EPSG:7415): every building, a needle 1e-4 wide
    and metres tall, refused saying its coordinates look like degrees though the file declares a projected CRS."""
    _, geographic = _delft_geographic()
    geographic["metadata"] = {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/7415"}
    (tmp_path / "wrong.city.json").write_text(json.dumps(geographic))
    items = [i for i in read_file(tmp_path / "wrong.city.json")]
    refused = [i for i in items if isinstance(i, Rejection) and "look like degrees" in i.reason]
    assert len(refused) > 100 and "though the file declares the projected CRS Amersfoort / RD New + NAP height" in (
        refused[0].reason)
    assert not any(isinstance(i, RawMesh) for i in items)
