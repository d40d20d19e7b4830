"""Footprints and solids drawn in metres, shared by the GeoJSON and GIS reader tests.

Footprints in longitude/latitude are placed on the ellipsoid by PROJ (pyproj, independent of
meshsom's geodesy); volumes are computed by hand (shoelace area x height).
"""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pyproj
import shapely

CENTRE = (52.0116, 4.3571, 0.0)  # Delft: latitude, longitude, height


def lonlat(ring_m):
    """A footprint ring drawn in metres east/north of CENTRE, as GeoJSON [longitude, latitude]."""
    lat0, lon0, h0 = CENTRE
    t = pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +inv +proj=topocentric +lat_0={lat0} +lon_0={lon0} +h_0={h0} +ellps=WGS84 "
        f"+step +inv +proj=cart +ellps=WGS84 +step +proj=unitconvert +xy_in=rad +xy_out=deg")
    e, n = np.asarray(ring_m, float).T
    lon, lat, _ = t.transform(e, n, np.zeros_like(e))
    return [[float(x), float(y)] for x, y in zip(lon, lat)]


def area(ring):
    x, y = np.asarray(ring, float).T
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def closed(ring):
    return [list(p) for p in ring] + [list(ring[0])]


L_SHAPE = [(0, 0), (20, 0), (20, 8), (8, 8), (8, 15), (0, 15)]
COURT_OUT = [(30, 0), (50, 0), (50, 20), (30, 20)]
COURT_IN = [(36, 6), (36, 14), (44, 14), (44, 6)]


def gabled_house():
    """A 10 x 6 m house, walls 4 m, ridge 7 m along x: JSON-FG Polyhedron faces (outward)."""
    a, b, c, d = (0, 0, 0), (10, 0, 0), (10, 6, 0), (0, 6, 0)
    A, B, C, D = (0, 0, 4), (10, 0, 4), (10, 6, 4), (0, 6, 4)
    r, s = (0, 3, 7), (10, 3, 7)
    faces = [[a, d, c, b], [a, b, B, A], [b, c, C, s, B], [c, d, D, C], [d, a, A, r, D], [A, B, s, r], [C, D, r, s]]
    return faces, 10 * 6 * 4 + 0.5 * 6 * 3 * 10


def write_geoparquet(path, features, crs="absent", wkb=None, extra=()):
    """GeoParquet 1.1 as its specification lays it out: a WKB column and the "geo" metadata;
    ``extra`` names more property columns (nulls where a feature has none)."""
    geometries = wkb or [shapely.to_wkb(shapely.geometry.shape(g)) for _, g, _ in features]
    columns = {"id": [f for f, _, _ in features],
               **{k: [p.get(k) for _, _, p in features] for k in ("height", "min_height", "num_floors", "family", *extra)},
               "geometry": geometries}
    column_meta = {"encoding": "WKB", "geometry_types": []}
    if crs != "absent":
        column_meta["crs"] = crs
    table = pa.table(columns).replace_schema_metadata(
        {b"geo": json.dumps({"version": "1.1.0", "primary_column": "geometry", "columns": {"geometry": column_meta}}).encode()})
    pq.write_table(table, path)


def _mansard(W, D, e, r, knots=((0.0, 0.0), (0.5, 0.75), (1.0, 1.0))):
    """A mansard's volume: its height a profile of the distance t to the nearest wall (up to D / 2),
    integrated as the sum over the profile's stretches of their slope times the integral of the area
    farther in than t, (W - 2t) (D - 2t), whose antiderivative is W D t - (W + D) t^2 + 4 t^3 / 3."""
    def F(t):
        return W * D * t - (W + D) * t ** 2 + 4 * t ** 3 / 3
    T = D / 2
    return W * D * e + sum(r * (h1 - h0) / (T * (s1 - s0)) * (F(s1 * T) - F(s0 * T))
                           for (s0, h0), (s1, h1) in zip(knots[:-1], knots[1:]))


#: A W x D house (W along x, the longer side), eaves e, roof rise r: its volume by hand for each
#: roof shape built on a rectangle (the hipped roof's height is the pitch times the distance to the
#: nearest wall, whose integral over the rectangle is D^2 (3W - D) / 12).
HOUSE = {
    "mansard": _mansard,
    "gabled": lambda W, D, e, r: W * D * e + 0.5 * D * r * W,
    "hipped": lambda W, D, e, r: W * D * e + r * D * (3 * W - D) / 6,
    "pyramidal": lambda W, D, e, r: W * D * (e + r / 3),
    "skillion": lambda W, D, e, r: W * D * (e + r / 2),
}


def rectangle(x0, y0, w, d):
    """A w x d rectangle's ring (metres), from its corner (x0, y0)."""
    return [(x0, y0), (x0 + w, y0), (x0 + w, y0 + d), (x0, y0 + d)]


def united_volume(mesh) -> float:
    """The volume of a building as ingest preprocesses it (its parts united), accepted."""
    from meshsom.preprocess import PreprocessParams
    from pipelines.ingest import process_one

    record, clean = process_one(mesh, PreprocessParams())
    assert record["status"] == "accepted", record
    t = clean.vertices[clean.faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)
